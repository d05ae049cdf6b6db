"""Simulator and dataset benchmarks: the compiled engine (Numba kernel, the default) side by side
with the NumPy reference it replaced, in the same run, with the ratio new/old. Prints figures;
asserts nothing (tests never assert timing).

    .venv/bin/python benchmarks/bench_sim.py              # everything (~6 min on 2 cores)
    .venv/bin/python benchmarks/bench_sim.py --quick      # smoke run: short windows, subsets
    .venv/bin/python benchmarks/bench_sim.py --no-dataset --cpu-seconds 0

Sections (targets of the compiled engine in brackets; "new/old" is compiled / reference):

0. Start-up: the first compiled call in a fresh process (Numba cache load, or compile when the
   cache is stale or missing) for the closed-loop rollout and for the node's per-tick path, and
   a cold compile from an empty cache (skipped by --quick).
1. One episode, B = 1, controller in the loop (run_episodes, one 10 s spec), fee and default
   worlds: simulated s per wall s, best of a few repeats (one repeat for the reference)
   [>= 1000].
2. A batch of episodes in one process (one core): simulated s per wall s per core [>= 10,000].
3. The 576-episode default dataset including bags on all cores (soil_sim_batch's generate):
   wall time [< 60 s on 2 cores]. The reference runs the full dataset too, unless
   --ref-dataset-episodes N asks for an evenly spread subset, extrapolated linearly (labelled).
4. soil_sim_node at 60 Hz real time (launched by soil_launch with the controller, so commands
   arrive; no recorder): the node's user+system CPU time over a steady window, as % of one
   core [< 5 %]; the controller's for context.

Loopback DDS only (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST) on ROS_DOMAIN_ID $ROS_DOMAIN_ID, else 64, by default (--domain-id);
every subprocess is bounded by a timeout and stopped at the end.
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

from graph_procs import cpu_per_node  # sets loopback-only DDS
from soil_bringup.launch import add_domain_id_option  # noqa: E402

from soil_sim_node import kernel  # noqa: E402
from soil_sim_node.batch import (  # noqa: E402
    DEFAULT_RELATIVE_DENSITIES,
    GRID_DEPTHS,
    GRID_SPEEDS,
    DatasetPlan,
    generate,
    grid_specs,
)
from soil_sim_node.effects import effects_for_mode  # noqa: E402
from soil_sim_node.rollout import run_episodes  # noqa: E402
from soil_sim_node.simulator import ENGINES, EpisodeSpec, SimConfig  # noqa: E402

OLD, NEW = "reference", "compiled"
assert set(ENGINES) == {OLD, NEW}
SOILS = ("Clay", "Loam", "Sand", "Gravel")


# ---------------------------------------------------------------- printing
def fmt(x: float | None, unit: str = "") -> str:
    if x is None:
        return "-"
    return (f"{x:,.0f}" if abs(x) >= 100 else f"{x:.3g}") + unit


def table(title: str, rows: list[tuple], unit: str, lower_is_better: bool = False, target=None) -> None:
    """rows of (label, old value, new value[, note[, held to the target]]); prints old, new, new/old and
    whether the new value meets the target."""
    print(f"== {title}")
    head = f"{'':22s} {OLD + ' (old)':>18s} {NEW + ' (new)':>18s} {'new/old':>9s}"
    if target is not None:
        head += f"   target {target[0]}"
    print(head)
    for row in rows:
        label, old, new = row[:3]
        note = row[3] if len(row) > 3 else ""
        held = row[4] if len(row) > 4 else True
        ratio = fmt(new / old) if old and new is not None else "-"
        line = f"{label:22s} {fmt(old, unit):>18s} {fmt(new, unit):>18s} {ratio:>9s}"
        if target is not None and new is not None and held:
            line += f"   {'met' if target[1](new) else 'NOT met'}"
        print(line + (f"   {note}" if note else ""))
    if lower_is_better:
        print(f"{'':22s} (lower is better: new/old < 1 is an improvement)")
    sys.stdout.flush()


# ---------------------------------------------------------------- 0. start-up
_FIRST_CALL = textwrap.dedent("""
    import json, time
    t0 = time.perf_counter()
    from soil_sim_node.rollout import run_episodes
    from soil_sim_node.simulator import EpisodeSpec, SimConfig, SoilSimulator
    t1 = time.perf_counter()
    spec = EpisodeSpec("Loam", 60.0, 0.6, 0.2, seed=0, duration_s=0.1)
    if "{what}" == "rollout":
        run_episodes(SimConfig(world_mode="default", engine="compiled"), [spec])
        t2 = time.perf_counter()
        run_episodes(SimConfig(world_mode="default", engine="compiled"), [spec])
    else:  # the node's path: SoilSimulator.reset then step, one tick at a time
        sim = SoilSimulator(SimConfig(world_mode="default", engine="compiled"), [spec])
        sim.reset(); sim.step(0.0, 0.0, 0.0)
        t2 = time.perf_counter()
        sim.step(0.0, 0.0, 0.0)
    t3 = time.perf_counter()
    print(json.dumps(dict(imports=t1 - t0, first=t2 - t1, second=t3 - t2)))
""")


def first_call(what: str, cache_dir: str | None = None, timeout: float = 600.0) -> dict | None:
    import json

    env = dict(os.environ)
    if cache_dir:
        env["NUMBA_CACHE_DIR"] = cache_dir
    try:
        res = subprocess.run([sys.executable, "-c", _FIRST_CALL.format(what=what)], capture_output=True, text=True,
                             timeout=timeout, env=env)
    except subprocess.TimeoutExpired:
        print(f"  ({what}: no answer within {timeout:g} s)")
        return None
    if res.returncode != 0:
        print(f"  ({what} failed: {res.stderr.strip().splitlines()[-1:]})")
        return None
    return json.loads(res.stdout.strip().splitlines()[-1])


def startup(cold: bool) -> None:
    cache = Path(kernel.__file__).parent / "__pycache__"
    n_index = len(list(cache.glob("kernel.*.nbi"))) if cache.is_dir() else 0
    print(f"== start-up of the compiled engine in a fresh process (Numba cache: {n_index} index files in {cache})")
    for what, label in (("rollout", "closed-loop rollout (run_episodes)"), ("node", "node's path (reset + step)")):
        r = first_call(what)
        if r:
            print(f"{label:38s} imports {r['imports']:.2f} s, first call {r['first']:.2f} s "
                  f"(cache load or compile), second call {r['second'] * 1e3:.2f} ms", flush=True)
    if cold:
        with tempfile.TemporaryDirectory(prefix="bench_numba_cache_") as tmp:
            r = first_call("rollout", cache_dir=tmp)
            if r:
                print(f"{'cold compile (empty cache), rollout':38s} first call {r['first']:.1f} s "
                      f"(once per machine and kernel edit; later starts load the cache)", flush=True)


# ---------------------------------------------------------------- 1./2. throughput
def batch_specs(n: int, duration_s: float) -> list[EpisodeSpec]:
    return [EpisodeSpec(SOILS[i % 4], 20.0 * (i % 6), 0.3 + 0.1 * (i % 7), 0.05 + 0.05 * (i % 5), seed=i,
                        duration_s=duration_s) for i in range(n)]


PLUGIN = ("soil_physics.force_terms:plugin term=soil_inertia k=4",)  # a user plugin: Python in every substep


def sim_rate(mode: str, engine: str, specs: list[EpisodeSpec], repeats: int, plugins: tuple = ()) -> tuple[float, float]:
    """(simulated s per wall s, process CPU s per wall s) of run_episodes, best of ``repeats``."""
    cfg = SimConfig(world_mode=mode, engine=engine, plugins=plugins)
    if engine == NEW:
        run_episodes(cfg, specs[:1])  # warm: JIT cache load, not part of the rate
    best, cpu_share = float("inf"), 1.0
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        run_episodes(cfg, specs)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        if wall < best:
            best, cpu_share = wall, cpu / wall
    return sum(s.duration_s for s in specs) / best, cpu_share


def throughput(args) -> None:
    one = [EpisodeSpec("Loam", 60.0, 0.6, 0.2, seed=0, duration_s=args.episode_s)]
    rows = []
    for mode in ("fee", "default"):
        old, _ = sim_rate(mode, OLD, one, 1)
        new, _ = sim_rate(mode, NEW, one, args.repeats)
        rows.append((mode, old, new))
    table(f"one episode, B = 1, controller in the loop ({args.episode_s:g} s episode): simulated s per wall s, "
          f"one core (reference: 1 repeat, compiled: best of {args.repeats})", rows, "", target=(">= 1000", lambda v: v >= 1000))

    rows = []
    for mode in ("fee", "default"):
        old, old_cpu = sim_rate(mode, OLD, batch_specs(args.ref_batch, args.episode_s), 1)
        new, new_cpu = sim_rate(mode, NEW, batch_specs(args.batch, args.episode_s), args.repeats)
        rows.append((mode, old, new, f"(process CPU/wall: {old_cpu:.2f} old, {new_cpu:.2f} new)"))
    table(f"batch in one process (one core): simulated s per wall s per core; reference: B = {args.ref_batch} "
          f"(1 repeat), compiled: B = {args.batch} (best of {args.repeats}); {args.episode_s:g} s episodes",
          rows, "", target=(">= 10,000", lambda v: v >= 10_000))

    rows = []
    for batch in (1, 8):
        specs = batch_specs(batch, args.episode_s / 2)
        old, _ = sim_rate("fee", OLD, specs, 1, PLUGIN)
        new, _ = sim_rate("fee", NEW, specs, 1, PLUGIN)
        rows.append((f"fee + plugin, B = {batch}", old, new))
    table(f"with a user plugin in plain Python ({PLUGIN[0]}): simulated s per wall s, one core; the compiled engine "
          "runs the plugin between the kernel's two halves of every substep", rows, "")


# ---------------------------------------------------------------- 3. dataset
def dataset_wall(engine: str, specs: list[EpisodeSpec], workers: int) -> dict:
    out = Path(tempfile.mkdtemp(prefix=f"bench_d_default_{engine}_"))
    try:
        plan = DatasetPlan("default", out, specs, effects_for_mode("default"), engine=engine)
        return generate(plan, workers=workers, progress=False)
    finally:
        shutil.rmtree(out, ignore_errors=True)


def dataset(args) -> None:
    specs = grid_specs(list(SOILS), DEFAULT_RELATIVE_DENSITIES, GRID_SPEEDS["default"], GRID_DEPTHS, 2, 0, 10.0)
    workers = args.workers or os.cpu_count() or 1
    n = len(specs)
    if args.ref_dataset_episodes and args.ref_dataset_episodes < n:
        step = n / args.ref_dataset_episodes
        subset = [specs[int(i * step)] for i in range(args.ref_dataset_episodes)]
        s_old = dataset_wall(OLD, subset, workers)
        old_wall = s_old["wall_time_s"] * n / len(subset)
        old_note = (f"reference EXTRAPOLATED linearly from {len(subset)} episodes ({s_old['wall_time_s']:.1f} s; "
                    f"a subset runs in smaller chunks, which vectorise worse: this overstates the reference)")
    else:
        s_old = dataset_wall(OLD, specs, workers)
        old_wall, old_note = s_old["wall_time_s"], f"reference: all {n} episodes"
    s_new = dataset_wall(NEW, specs, workers)
    table(f"{n}-episode default dataset incl. bags, {workers} worker processes on {os.cpu_count()} cores: wall s",
          [("wall time", old_wall, s_new["wall_time_s"], old_note)], " s", lower_is_better=True,
          target=("< 60 s", lambda v: v < 60))
    print(f"{'':22s} compiled: {s_new['episodes']} episodes, {s_new['simulated_s_per_wall_s']:.0f} simulated s per "
          f"wall s, {s_new['bytes_per_episode'] / 1e3:.0f} kB per episode, {s_new['bytes_total'] / 1e6:.0f} MB total",
          flush=True)


# ---------------------------------------------------------------- 4. node CPU
def node_cpu(args) -> None:
    rows = {}
    for engine in (OLD, NEW):
        rows[engine] = cpu_per_node(args.cpu_seconds, args.domain_id, ["--sim-param", f"engine:={engine}",
                                                                        "--sim-param", "world_mode:=default"],
                                    record=False)
    sim = [("soil_sim_node", rows[OLD].get("soil_sim_node"), rows[NEW].get("soil_sim_node"))]
    ctl = ("anti_stall_controller", rows[OLD].get("anti_stall_controller"), rows[NEW].get("anti_stall_controller"),
           "(context: not the simulator, no target)", False)
    table(f"soil_sim_node at 60 Hz real time (default world, with the controller, no recorder): user+system CPU "
          f"over {args.cpu_seconds:g} s, % of one core", [*sim, ctl], " %", lower_is_better=True,
          target=("< 5 %", lambda v: v < 5))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="smoke run: short episodes and windows, dataset subsets")
    p.add_argument("--no-dataset", action="store_true", help="skip the 576-episode dataset")
    p.add_argument("--workers", type=int, default=0, help="dataset worker processes (default: all cores)")
    p.add_argument("--episode-s", type=float, default=10.0, help="episode length of sections 1-2 [s]")
    p.add_argument("--repeats", type=int, default=5, help="repeats of the compiled timings (best taken)")
    p.add_argument("--batch", type=int, default=48, help="batch size of the compiled batch figure")
    p.add_argument("--ref-batch", type=int, default=48, help="batch size of the reference batch figure")
    p.add_argument("--ref-dataset-episodes", type=int, default=0,
                   help="reference dataset: time this many episodes and extrapolate (0: the full dataset)")
    p.add_argument("--cpu-seconds", type=float, default=60.0, help="node CPU window per engine [s] (0: skip)")
    add_domain_id_option(p, 64)
    args = p.parse_args()
    if args.quick:
        args.episode_s, args.repeats, args.ref_batch = 2.0, 2, 8
        args.ref_dataset_episodes = args.ref_dataset_episodes or 24
        args.cpu_seconds = min(args.cpu_seconds, 10.0)
    print(f"cores: {os.cpu_count()}, load average {os.getloadavg()[0]:.2f}, python {sys.version.split()[0]}"
          + (" (--quick: short windows, not the reference figures)" if args.quick else ""), flush=True)
    startup(cold=not args.quick)
    throughput(args)
    if not args.no_dataset:
        dataset(args)
    if args.cpu_seconds > 0:
        node_cpu(args)
    print(f"load average at the end {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
