"""`soil_sim_batch`: generate a §3.1-style dataset, one rosbag2 MCAP bag per episode.

soil x I_d grid x target speed x target depth x seeds, 10 s episodes at 60 Hz, in the `fee`
or `default` world, simulated in vectorised chunks in parallel over cores (progress bar),
each episode written atomically (no partial bag ever looks complete) with its metadata.
The defaults reproduce the paper's sizes: 576 episodes in `default` (D_default), 432 in
`fee` (D_FEE).

    soil_sim_batch --mode default --out bags/d_default
    soil_sim_batch --mode fee --out bags/d_fee --workers 2
    soil_sim_batch --patch 0:Sand:20 --patch 5:Clay:90 --out bags/sand_clay   # soil changing along x
    soil_sim_batch --ray 10.0.0.5:6379 --out /shared/bags/d_default            # chunks as tasks on a Ray cluster

With ``--ray`` the same chunks run as Ray tasks instead of pool processes and write the same
bags, byte for byte, and the same dataset.json (its timing fields aside) for the same --workers
and seeds. A chunk that fails is named with its episodes after every other chunk has finished;
the bags written are kept (never a partial one) and dataset.json is not written.

A run refuses, before simulating anything, to write where a bag of the same name exists (unless
--overwrite, or --skip-existing, which keeps those bags and simulates the rest: an interrupted run
resumed; Ctrl-C keeps the bags finished, never a partial one) or where a killed recorder's journal of that name waits for ``soil_bag_repair``. A
run into a directory an earlier run wrote keeps that run's record in dataset.json's
``earlier_runs`` (and a resumed run's bags of an interrupted one under ``kept_existing``), so
the file still says what the directory holds.
"""
from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import math
import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from tqdm import tqdm

from soil_bag_tools.bag_io import PARTIAL_SUFFIX, is_bag, journal_path, write_episode
from soil_msgs_py.interrupts import (Terminated, interrupt_exit_code, stop_requests,
                                     terminate_as_interrupt)
from soil_msgs_py import cli_numbers, strict_json
from soil_msgs_py.cli_paths import bags_dir, refuse_directories, write_text_atomically, written_since
from soil_msgs_py.episode import MAX_SEED, WORLD_MODES
from soil_msgs_py.params import MIN_CUT_DEPTH_M, WINDOW_SAMPLES, beyond_lift_reach, beyond_table1_speed, ticks_in
from soil_msgs_py.patches import check_patches, glue_negative_patches
from soil_msgs_py.process_pool import WorkerDied, map_in_processes
from soil_physics.soils import CATALOGUE, SoilFile, get_soil, load_soil_file, path_patches, soil_file_notes

from .effects import Effects, PluginError, effects_for_mode, load_plugins
from .ray_cluster import (CLUSTER_LOST_AFTER_S, LOCAL as LOCAL_RAY, ClusterLost, add_ray_option, cluster_cpus,
                          parse_ray_options, ray_session, run_tasks)
from .rollout import episode_meta, run_episodes
from .simulator import ENGINES, Dynamics, EpisodeSpec, SimConfig, check_engine, resolve_checked

# Paper §3.1 grids. 4 soils x 6 I_d x speeds x depths x 2 seeds = 576 (default) / 432 (fee).
DEFAULT_RELATIVE_DENSITIES = (0.0, 20.0, 40.0, 60.0, 80.0, 100.0)
GRID_SPEEDS = {"default": (0.3, 0.5333, 0.7667, 1.0), "fee": (0.3, 0.65, 1.0)}
GRID_DEPTHS = (0.05, 0.175, 0.3)
DEFAULT_SEEDS = 2
# A failed Ray run removes the staging directories of its bags once nothing was written to them for
# STAGING_QUIET_S, waiting at most STAGING_WAIT_S: a lost cluster's worker that outlived the failure for
# a moment had left one half-written when it died (seen once in a CI run beside a busy core).
STAGING_QUIET_S = 1.0
STAGING_WAIT_S = 10.0


@dataclass
class DatasetPlan:
    """What to generate; validated before any worker starts or any file is written."""

    mode: str
    out: Path
    specs: list[EpisodeSpec]
    effects: Effects
    plugins: tuple = ()
    custom_soils: dict = field(default_factory=dict)
    overwrite: bool = False
    engine: str = "compiled"  # one of simulator.ENGINES
    skip_existing: bool = False  # keep the bags that exist, simulate the rest (an interrupted run resumed)

    def config(self) -> SimConfig:
        return SimConfig(world_mode=self.mode, effects=self.effects, plugins=self.plugins, engine=self.engine)


def grid_specs(soils, relative_densities, speeds, depths, n_seeds, seed_base, duration_s, patches=()) -> list[EpisodeSpec]:
    """Full factorial grid of soils × relative densities I_d [%] × target speeds [m/s] × target
    depths [m] × ``n_seeds``; every episode gets its own seed (seed_base + index), ``duration_s``
    [s] and ``patches`` (with patches, give the first patch's soil and I_d as the only soil and density)."""
    combos = itertools.product(soils, relative_densities, speeds, depths, range(n_seeds))
    return [
        EpisodeSpec(soil, float(i_d), float(v), float(d), seed=seed_base + k, duration_s=duration_s, patches=patches)
        for k, (soil, i_d, v, d, _) in enumerate(combos)
    ]


def _run_chunk(args) -> list[tuple[str, int, dict]]:
    """Worker: simulate one vectorised chunk and write its bags; returns (name, bytes, the chunk's
    plugin peaks: {plugin spec: largest |force| [N]}) per bag."""
    plan_dict, chunk = args
    plan = DatasetPlan(**plan_dict, specs=chunk)
    peaks: dict = {}
    try:
        episodes = run_episodes(plan.config(), chunk, custom_soils=plan.custom_soils, plugin_peaks=peaks)
    except PluginError as err:  # which episodes (simulated together): Ray's tasks named them, the local pool did not
        names = _bag_names(plan.config(), [x.resolve(plan.custom_soils) for x in chunk])
        shown = ", ".join(names[:3]) + (f" and {len(names) - 3} more" if len(names) > 3 else "")
        raise PluginError(f"{err} (simulating episodes {shown})") from None
    written = []
    for ep in episodes:
        path = write_episode(plan.out / ep.meta.name, ep, overwrite=plan.overwrite)
        written.append((ep.meta.name, sum(f.stat().st_size for f in path.iterdir()), peaks))
    return written


def _chunks(specs: list[EpisodeSpec], workers: int, max_chunk: int) -> list[list[EpisodeSpec]]:
    # Big chunks vectorise better; enough chunks keep every core busy and the bar moving.
    n = max(1, min(max_chunk, math.ceil(len(specs) / (workers * 4))))
    return [specs[i : i + n] for i in range(0, len(specs), n)]


class ChunksFailed(RuntimeError):
    """Some chunks of a Ray run failed; the message names their episodes and the causes."""

    def __init__(self, message: str, bad_input: bool):
        super().__init__(message)
        self.bad_input = bad_input  # every cause was a refusal of the input (CLI exit code 2)


def generate(plan: DatasetPlan, workers: int = 0, max_chunk: int = 48, progress: bool = True,
             ray_address: str | None = None, ray_give_up_after_s: float = CLUSTER_LOST_AFTER_S) -> dict:
    """Generate the dataset of ``plan``; returns a summary (also written as dataset.json).

    ``ray_address``: run the chunks as Ray tasks (``ray_cluster.LOCAL`` or a cluster's address;
    ``workers`` 0 then means every CPU of the cluster) instead of in a local process pool;
    ``ray_give_up_after_s``: how long its head may refuse connections (``run_tasks``)."""
    effects_for_mode(plan.mode)  # fail fast, before forking or writing anything
    load_plugins(plan.plugins)  # a plugin that does not load or take its parameters (PluginError, a ValueError)
    if not plan.specs:  # its dataset.json would replace the record of what the directory holds
        raise ValueError(f"the plan for {plan.out} has no episode: nothing to generate")
    check_engine(plan.engine)
    # every soil one the FEE can cut: refused before any bag is written
    pairs = [resolve_checked(plan.config(), spec, plan.custom_soils) for spec in plan.specs]
    resolved = [spec for spec, _ in pairs]
    keys = [(str(s.soil).lower(), s.relative_density_pct, s.target_speed_m_s, s.target_depth_m, s.seed, s.patches)
            for s in resolved]
    if len(set(keys)) != len(keys):
        raise ValueError("two episodes have the same soil, I_d, targets and seed (their bags would collide)")
    names = _bag_names(plan.config(), pairs)
    others = _other_bags(plan.out, names)
    kept: list[str] = []  # bags of the plan that exist and are kept (--skip-existing)
    if plan.skip_existing and not plan.overwrite:
        exists = [is_bag(plan.out / n) for n in names]
        todo = [i for i, e in enumerate(exists) if not e]
        kept = sorted(n for n, e in zip(names, exists) if e)
        _check_kept_alike(plan, [pair for pair, e in zip(pairs, exists) if e])
        if len(todo) < len(names):
            print(f"soil_sim_batch: {len(names) - len(todo)} of the {len(names)} bags exist in {plan.out} and are kept "
                  f"(--skip-existing); simulating the other {len(todo)}", file=sys.stderr)
        if not todo and (plan.out / "dataset.json").is_file():
            return {"mode": plan.mode, "episodes": len(kept), "wall_time_s": 0.0, "bytes_total": 0,
                    "bytes_per_episode": 0, "simulated_s_per_wall_s": 0.0, "episode_names": kept,
                    "kept_existing": kept, "simulated_episodes": 0}  # (dataset.json stays as it is)
        # (none left but no dataset.json: the interrupted run wrote every bag and died before its
        # record, an outside tester's killed Ray head; the record is written below, all kept)
        plan = dataclasses.replace(plan, specs=[plan.specs[i] for i in todo])
        pairs, resolved, names = [pairs[i] for i in todo], [resolved[i] for i in todo], [names[i] for i in todo]
    _check_names_free(plan, names)
    if others:  # the readers (pinn_train, soil_discrepancy) take every bag of the directory
        print(f"soil_sim_batch: note: {plan.out} already holds {others} episode bag(s) of earlier runs; with these "
              f"{len(names)} it holds {others + len(names)}, and pinn_train and soil_discrepancy read them all "
              "(dataset.json keeps the earlier runs' records under earlier_runs)", file=sys.stderr)
    created = not plan.out.exists()
    plan.out.mkdir(parents=True, exist_ok=True)
    base = dict(mode=plan.mode, out=plan.out, effects=plan.effects, plugins=plan.plugins,
                custom_soils=plan.custom_soils, overwrite=plan.overwrite, engine=plan.engine)
    try:
        start = time.perf_counter()
        bar = tqdm(total=len(plan.specs), unit="ep", desc=f"{plan.mode} episodes", disable=not progress)
        if not plan.specs:  # (--skip-existing found every bag)
            results = []
        elif ray_address:
            with ray_session(ray_address, num_cpus=workers or cli_numbers.cores()):
                chunks = _chunks(plan.specs, workers or cluster_cpus(), max_chunk)
                # a cluster's workers start where `ray start` ran: they write to --out by its absolute
                # path (on storage every machine mounts there), not to a relative one of their own
                done = run_tasks(_run_chunk, [(dict(base, out=plan.out.absolute()), c) for c in chunks],
                                 on_done=lambda r: bar.update(0 if isinstance(r, Exception) else len(r)),
                                 lost_after_s=ray_give_up_after_s)
            bar.close()
            if any(isinstance(r, Exception) for r in done):
                _remove_staging(plan)  # bags dead or given-up tasks were writing
            _raise_failed(plan, chunks, done)
            results = [r for chunk_result in done for r in chunk_result]
        else:
            workers = workers or cli_numbers.cores()
            results = _run_in_pool([(base, c) for c in _chunks(plan.specs, workers, max_chunk)], workers, bar)
    except BaseException:
        if created and not any(plan.out.iterdir()):  # (a run that wrote nothing leaves no empty --out behind)
            plan.out.rmdir()
        raise
    wall = time.perf_counter() - start
    paths = []  # the distinct soil paths (patches) of the episodes
    for spec in resolved:
        path = [patch.as_dict() for patch in spec.patches]
        if path and path not in paths:
            paths.append(path)
    summary = {
        "mode": plan.mode,
        # every bag of the plan, those an interrupted run had written and this one kept too (a resumed
        # run's record said "episodes: 0" of a complete dataset, an outside tester's)
        "episodes": len(results) + len(kept),
        "wall_time_s": round(wall, 3),
        "bytes_total": int(sum(r[1] for r in results)),
        "bytes_per_episode": int(sum(r[1] for r in results) / max(1, len(results))),
        "simulated_s_per_wall_s": round(sum(s.duration_s for s in plan.specs) / max(wall, 1e-9), 1),
        "engine": plan.engine,
        "effects": plan.effects.enabled(),
        "plugins": [str(p) for p in plan.plugins],
        # the largest |force| each plugin gave in any substep of the episodes simulated (0: it never acted)
        **({"plugin_peak_force_n": _plugin_peaks(plan, results)} if plan.plugins and results else {}),
        **({"soil_paths": paths} if paths else {}),
        "episode_names": sorted([r[0] for r in results] + kept),
        # the plan's bags an earlier, interrupted run wrote; the bytes and speed above are of those simulated
        **({"kept_existing": kept, "simulated_episodes": len(results)} if kept else {}),
    }
    earlier = _earlier_runs(plan.out / "dataset.json")
    if earlier:
        summary["earlier_runs"] = earlier
    write_text_atomically(plan.out / "dataset.json", strict_json.dumps(summary, indent=1))
    return summary


def _plugin_peaks(plan: DatasetPlan, results: list) -> dict[str, float]:
    """{plugin spec: the largest |force| [N] it returned over every chunk of ``results``}."""
    return {str(p): max(float(r[2].get(str(p), 0.0)) for r in results) for p in plan.plugins}


def idle_plugins(summary: dict) -> list[str]:
    """The plugins of a batch's ``summary`` that returned 0 N in every substep of every episode."""
    return [spec for spec, peak in (summary.get("plugin_peak_force_n") or {}).items() if peak == 0.0]


def unreached_patches(specs: list[EpisodeSpec]) -> list[str]:
    """A line for each patch that starts beyond where the blade's edge gets at the target speed
    in the episode's duration (too short, too slow), or ends behind where it starts: the
    episodes never cut it (nor names them: ``EpisodeSpec.resolve`` names an episode after the patch
    under the edge at the start)."""
    notes = []
    start = Dynamics().blade_offset_m
    for speed, duration, patches in dict.fromkeys((s.target_speed_m_s, s.duration_s, tuple(s.patches)) for s in specs):
        reach = start + speed * duration
        checked = check_patches(list(patches))
        for i, (patch, following) in enumerate(zip(checked, checked[1:])):
            if following.x_start_m <= start:
                notes.append(f"patches[{i}] ({patch.soil} from x = {patch.x_start_m:g} m) ends at x = "
                             f"{following.x_start_m:g} m, behind where the blade's edge starts (x = {start:g} m): never cut")
        for i, patch in enumerate(checked[1:], start=1):
            if patch.x_start_m > reach:
                notes.append(f"patches[{i}] ({patch.soil} from x = {patch.x_start_m:g} m) starts beyond where the blade's "
                             f"edge gets in {duration:g} s at {speed:g} m/s (x ≈ {reach:.2f} m): never cut")
    return notes


def _bag_names(config: SimConfig, resolved) -> list[str]:
    """The bag names the workers give the episodes of ``resolved`` ((spec, soil) pairs, as
    ``EpisodeSpec.resolve`` returns them): their metadata's names."""
    return [episode_meta(config, spec, soil.name, []).name for spec, soil in resolved]


# What a kept bag's metadata must share with the episode this run would write in its place
KEPT_FIELDS = ("duration_s", "effects", "plugins", "patches")
OVERWRITE_ALL = "--overwrite instead of --skip-existing simulates every bag of the plan again"


def _check_kept_alike(plan: DatasetPlan, resolved) -> None:
    """FileExistsError, before anything is simulated, if a bag ``--skip-existing`` would keep (of
    ``resolved``, (spec, soil) pairs) was made with other settings than this run's (its duration,
    effects, plugins or patches: a bag's name says its soil, density, targets, seed and world only).
    A resume with another --plugin or --duration had mixed two datasets under one dataset.json
    without a word (an outside tester's). A plugin's parameters and a custom soil's properties are
    not in a bag's metadata: a resume with another k of the same plugin, or another φ of a soil of
    the same name, is not caught."""
    from soil_bag_tools.bag_io import read_meta

    config = plan.config()
    for spec, soil in resolved:
        mine = episode_meta(config, spec, soil.name, plan.effects.enabled())
        path = plan.out / mine.name
        try:
            theirs = read_meta(path)
        except (ValueError, OSError) as err:
            raise FileExistsError(f"{path}, which --skip-existing would keep, cannot be read: {err}; nothing written "
                                  f"({OVERWRITE_ALL})") from None
        for name in KEPT_FIELDS:
            if getattr(theirs, name) != getattr(mine, name):
                raise FileExistsError(
                    f"{path}, which --skip-existing would keep, was made with {name} {getattr(theirs, name)!r}, this run "
                    f"with {getattr(mine, name)!r}: keeping it would mix two datasets; nothing written ({OVERWRITE_ALL}, "
                    "or give another --out)")


def _check_names_free(plan: DatasetPlan, names: list[str]) -> None:
    """FileExistsError, before anything is simulated, if a bag of the plan exists (without
    ``overwrite``) or a recorder's journal of that name waits for ``soil_bag_repair``."""
    taken = [n for n in names if not plan.overwrite and is_bag(plan.out / n)]
    journals = [n for n in names if journal_path(plan.out / f"{n}{PARTIAL_SUFFIX}").exists()]
    if journals:
        raise FileExistsError(
            f"{len(journals)} episode(s) would be written where a recorder's journal waits to be recovered, e.g. "
            f"{plan.out / (journals[0] + PARTIAL_SUFFIX)}: soil_bag_repair recovers it (or move it away); nothing written")
    if taken:
        raise FileExistsError(f"{len(taken)} of the {len(names)} bags exist in {plan.out}, e.g. {taken[0]}; nothing "
                              "written (--skip-existing keeps them and simulates the rest, as after an interrupted "
                              "run; --overwrite replaces them; or give another --out or --seed-base)")


def _bags_in(out: Path) -> set[str]:
    """The names of the episode bags ``out`` holds (none if it does not exist)."""
    return {p.name for p in out.iterdir() if is_bag(p)} if out.is_dir() else set()


def _other_bags(out: Path, names: list[str]) -> int:
    """How many episode bags ``out`` holds that are not among ``names`` (0 if it does not exist)."""
    return len(_bags_in(out) - set(names))


def resume_hint(stale: bool) -> str:
    """How to finish a run that stopped: the rest simulated beside the bags it finished, or, where an
    ``overwrite`` run left ``stale`` bags (the earlier run's, not reached yet: a resume with
    --skip-existing kept them, a dataset of two runs without a word, an outside tester's), all again."""
    if stale:
        return ("the others there are the earlier run's, not overwritten yet: the same command (with --overwrite) "
                "makes them all this run's")
    return "the same command with --skip-existing simulates the rest"


def left_stale(out: Path, before: set[str], since: float, planned: set[str] | None) -> bool:
    """Whether an ``overwrite`` run into ``out`` left bags of the earlier run there: bags of
    ``before`` among ``planned`` (the plan's names; None: all of ``before``) not written since
    ``since`` (time.time())."""
    return any(not written_since(out / n, since) for n in before & (before if planned is None else planned) & _bags_in(out))


def planned_names(plan: DatasetPlan) -> set[str] | None:
    """The bag names of the plan's episodes (None where a spec is refused: a run that failed on it)."""
    try:
        return set(_bag_names(plan.config(), [s.resolve(plan.custom_soils) for s in plan.specs]))
    except ValueError:
        return None


def bags_of_this_run(out: Path, before: set[str], overwrite: bool, since: float | None) -> set[str]:
    """The bags under ``out`` a run finished: those not in ``before``, and with ``overwrite`` those of
    ``before`` written since ``since`` (time.time(); None: none of them)."""
    return {n for n in _bags_in(out) if n not in before or (overwrite and since is not None and written_since(out / n, since))}


def kept_after_failure(out: Path, before: set[str], bad_input: bool, said: str = "", *,
                       overwrite: bool = False, since: float | None = None, planned: set[str] | None = None) -> str:
    """Words for the bags a failed run finished before it failed ('' if none): they stay (each is
    whole), without the dataset.json that a finished run writes, and a reader takes them. ``said``:
    the error's own words (the resume hint is not said twice). ``overwrite``: the run replaced bags
    of ``before``; those written since ``since`` (time.time()) count as its own too, and those of
    ``planned`` (the plan's names; None: every bag of ``before``) it had not reached are stale."""
    new = sorted(bags_of_this_run(out, before, overwrite, since))
    if not new:
        return ""
    hint = resume_hint(overwrite and since is not None and left_stale(out, before, since, planned))
    if bad_input:
        then = ", made with the input that failed: after mending it, run again with --overwrite"
    else:
        then = "" if "--skip-existing" in said or hint in said else f": {hint}"
    return (f"{len(new)} episode bag(s) finished before the failure are kept under {out} (e.g. {new[0]}; no "
            f"dataset.json){then}")


def _earlier_runs(path: Path) -> list[dict]:
    """The records of the runs that wrote into this directory before (oldest first), so that a
    second run's dataset.json still says what the directory holds; [] if there were none."""
    try:
        old = json.loads(path.read_text())
    except FileNotFoundError:
        return []
    except (OSError, ValueError) as err:
        print(f"soil_sim_batch: warning: {path} unreadable ({err}); its record of earlier runs is not kept",
              file=sys.stderr)
        return []
    if not isinstance(old, dict):
        return []
    runs = old.pop("earlier_runs", [])
    return [*(runs if isinstance(runs, list) else []), old]


def _run_in_pool(jobs: list, workers: int, bar) -> list[tuple[str, int, dict]]:
    """The chunks in a local process pool (in this process for one worker); ``_run_chunk``'s tuple per bag."""
    results: list[tuple[str, int, dict]] = []
    if workers == 1:
        for job in jobs:
            done = _run_chunk(job)
            results += done
            bar.update(len(done))
    else:
        # after Ray, spawned workers (they write the same bags and end with the pool; a fork server
        # would outlive it, with Ray's path in its command line)
        # the workers ignore Ctrl-C (no traceback from each) and die on SIGTERM, whatever handler they
        # inherited (map_in_processes): this process takes Ctrl-C and the map's end stops them (a bag
        # half written is staged apart, never in place); a worker killed (out of memory) ends the run
        # with WorkerDied, where multiprocessing.Pool waited for its chunk for ever
        for done in map_in_processes(_run_chunk, jobs, max(1, min(workers, len(jobs))), what="simulating episodes",
                                     stop_workers=True):
            results += done
            bar.update(len(done))
    bar.close()
    return results


def _remove_staging(plan: DatasetPlan, quiet_s: float = STAGING_QUIET_S, limit_s: float = STAGING_WAIT_S) -> None:
    """The staging directories of this plan's bags a stopped run left mid-write (another
    run's, a recorder's journal and an old bag an --overwrite parked there are left alone).

    One still written to within ``quiet_s`` is waited for (at most ``limit_s``): a worker of a lost
    cluster may outlive the failure its driver saw for a moment, finishing its bag (the staging goes)
    or dying mid-write (the staging stops changing, and is removed). A worker that outlives that
    too can still leave one; the next run writing that bag removes it, and no reader takes it."""
    candidates = [plan.out / f"{name}{PARTIAL_SUFFIX}" for name in sorted(planned_names(plan) or ())]
    deadline = time.monotonic() + limit_s
    while True:
        busy = False
        for staging in candidates:
            if not staging.is_dir() or journal_path(staging).exists() or (staging / "replaced").exists():
                continue
            if time.time() - _last_written(staging) < quiet_s and time.monotonic() < deadline:
                busy = True
            else:
                shutil.rmtree(staging, ignore_errors=True)
        if not busy:
            return
        time.sleep(0.1)


def _last_written(directory: Path) -> float:
    """When anything in ``directory`` was last changed [s since the epoch] (0: gone meanwhile)."""
    try:
        return max([directory.stat().st_mtime] + [p.stat().st_mtime for p in directory.rglob("*")])
    except OSError:
        return 0.0


def _raise_failed(plan: DatasetPlan, chunks: list[list[EpisodeSpec]], done: list) -> None:
    """ChunksFailed naming the episodes of every chunk whose task failed, if any did."""
    failed = [(c, r) for c, r in zip(chunks, done) if isinstance(r, Exception)]
    if not failed:
        return
    lines = []
    lost = [(c, r) for c, r in failed if isinstance(r, ClusterLost)]
    for chunk, err in failed:
        if not isinstance(err, ClusterLost):
            names = _bag_names(plan.config(), [x.resolve(plan.custom_soils) for x in chunk])
            lines.append(f"  episodes {', '.join(names)}: {type(err).__name__}: {err}")
    if lost:  # one line, not every unfinished episode's name: the rerun finds them
        # (a lost task's worker may still finish its bags: what is on disk is counted after this)
        lines.append(f"  {len(lost)} tasks ({sum(len(c) for c, _ in lost)} episodes) not confirmed before the cluster was "
                     f"lost (their workers may have written some of those bags all the same): {lost[0][1]}")
    bad_input = all(isinstance(err, (ValueError, FileNotFoundError, FileExistsError)) for _, err in failed)
    if not bad_input:  # a lost cluster, a dead worker or raylet (Ray says either, whichever it notices first)
        back = " once the cluster is back" if lost or any(_cluster_gone(e) for _, e in failed) else ""
        stale = plan.overwrite and any(is_bag(plan.out / n) for n in _bag_names(plan.config(), [
            x.resolve(plan.custom_soils) for c, _ in failed for x in c]))  # (not rewritten: their tasks failed)
        lines.append(f"  {resume_hint(True)}{back}" if stale else
                     f"  the same command with --skip-existing simulates the missing episodes{back}")
    kept = sum(len(r) for r in done if not isinstance(r, Exception))
    raise ChunksFailed(
        f"{len(failed)} of {len(chunks)} Ray tasks failed; the bags of the other {kept} episodes are written under "
        f"{plan.out} (plus any of the failed tasks' episodes finished before the failure, never a partial bag); "
        "dataset.json is not written:\n" + "\n".join(lines), bad_input=bad_input)


def _cluster_gone(err: Exception) -> bool:
    """Whether Ray failed a task because its node's raylet died (a stopped cluster, a lost node)."""
    return type(err).__name__ in ("LocalRayletDiedError", "NodeDiedError")


def _items(text: str, name: str, what: str = "numbers") -> list[str]:
    """A comma-separated grid axis' items; empty ('' or ',') is refused: it made a plan of no
    episodes. An empty item ('0.1,,0.2') is refused too: it was dropped without a word, most likely
    a value left out."""
    items = [x.strip() for x in text.split(",")]
    if not any(items):
        raise ValueError(f"--{name}={text!r} gives no value; give a comma-separated list of {what}")
    if not all(items):
        raise ValueError(f"--{name}={text!r}: item {items.index('') + 1} is empty; give a comma-separated list of {what}")
    return items


def _floats(text: str, name: str) -> tuple[float, ...]:
    """A grid axis of numbers (``_items``)."""
    items = _items(text, name)
    try:
        return tuple(float(x) for x in items)
    except ValueError:
        raise ValueError(f"--{name}={text!r} must be a comma-separated list of numbers") from None


def _depths(text: str) -> tuple[float, ...]:
    """--depths: from ``MIN_CUT_DEPTH_M`` (shallower the blade skims the surface, an episode with no
    cut in it; ``soil_demo`` refuses it alike); the simulator checks the rest of the range."""
    depths = _floats(text, "depths")
    for d in depths:
        if 0.0 <= d < MIN_CUT_DEPTH_M:
            raise ValueError(f"--depths {d:g}: the blade cuts from {MIN_CUT_DEPTH_M:g} m (shallower it skims the "
                             "surface: an episode without a cut)")
    return depths


# the effects that draw on an episode's seed: without them an episode is the same under any seed
SEEDED_EFFECTS = ("noise", "particles")


def identical_seeds_note(plan: "DatasetPlan", n_seeds: int) -> str:
    """A note where ``n_seeds`` seeds of each grid point give identical episodes ('' where they do
    not): without noise and particles (the fee world, or --effects-off both) nothing draws on the
    seed, and a user asking for 3 seeds had three copies of each episode without a word."""
    if n_seeds < 2 or any(getattr(plan.effects, name) for name in SEEDED_EFFECTS):
        return ""
    return (f"--seeds {n_seeds}: without noise or particles (the {plan.mode} world"
            + (" with --effects-off" if plan.mode != "fee" else "") + ") nothing draws on an episode's seed, so the "
            f"{n_seeds} seeds of each grid point give identical episodes (pinn_train splits such twins as one); more "
            "grid points give more data")


def repeated_grid_values(args: argparse.Namespace) -> list[str]:
    """Notes for a grid axis that lists one value twice (``--speeds 0.5,0.5``, ``--soils Sand,sand``):
    its episodes run again under the next seeds, most likely not what was meant (more seeds is
    --seeds). The lists are already checked by ``plan_from_args``."""
    notes = []
    for flag, text, key in (("--soils", args.soils, str.lower), ("--relative-densities", args.relative_densities, float),
                            ("--speeds", args.speeds, float), ("--depths", args.depths, float)):
        items = [x.strip() for x in (text or "").split(",") if x.strip()]
        keys = [key(x) for x in items]
        twice = [x for i, x in enumerate(items) if keys[i] in keys[:i]]
        if twice:
            notes.append(f"{flag} lists {twice[0]} more than once: its episodes run again under other seeds "
                         "(for more seeds of each, --seeds N)")
    return notes


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="soil_sim_batch", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--mode", choices=WORLD_MODES, default="default", help="world mode (default: default)")
    p.add_argument("--out", type=bags_dir, help="output directory (default: bags/d_<mode>)")
    p.add_argument("--soils", help=f"comma-separated soil names (default: {','.join(CATALOGUE)})")
    p.add_argument("--soil-file", type=Path, help="YAML with custom soil(s), usable in --soils, and named paths (--path)")
    p.add_argument("--relative-densities",
                   help=f"I_d grid [%%] (default: {','.join(f'{x:g}' for x in DEFAULT_RELATIVE_DENSITIES)})")
    p.add_argument("--patch", action="append", default=[], metavar="X:SOIL:ID",
                   help="a soil patch along the path, from blade edge x = X [m] on: SOIL at I_d = ID [%%]; repeat in "
                        "order of x (the first also covers everything before the second). Every episode cuts through "
                        "them; replaces --soils and --relative-densities")
    p.add_argument("--path", metavar="NAME", help="the patches of the path NAME in --soil-file's 'paths:' section (like --patch)")
    p.add_argument("--speeds", help="target speeds [m/s] (default: 4 values in 0.3-1.0 for default, 3 for fee)")
    p.add_argument("--depths", default=",".join(f"{x:g}" for x in GRID_DEPTHS), help="target depths [m] (default: %(default)s)")
    p.add_argument("--seeds", type=int, default=DEFAULT_SEEDS, help="repetitions of each grid point (default: %(default)s)")
    p.add_argument("--seed-base", type=int, default=0, help="first episode seed (default: %(default)s)")
    p.add_argument("--duration", type=float, default=10.0, help="episode length [s] (default: %(default)s)")
    p.add_argument("--workers", type=int, default=0,
                   help="processes (default: all cores; with --ray ADDRESS: all CPUs of the cluster); it also sets "
                        "the chunk size, so compare runs of the same --workers")
    add_ray_option(p, "simulate the chunks as Ray tasks, --out on shared storage")
    p.add_argument("--engine", choices=ENGINES, default=ENGINES[0],
                   help="simulator engine: compiled (default) or reference (the NumPy reference of the physics)")
    p.add_argument("--plugin", action="append", default=[], help="extra force term package.module:function (repeatable)")
    p.add_argument("--effects-off", default="", help="default-world effects to switch off, comma-separated")
    p.add_argument("--overwrite", action="store_true", help="replace existing bags of the same name")
    p.add_argument("--skip-existing", action="store_true",
                   help="keep existing bags of the same name and simulate the rest (resume an interrupted run)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return parse_ray_options(p, glue_negative_patches(sys.argv[1:] if argv is None else list(argv)))


def _patches_from_args(args: argparse.Namespace, paths: dict, custom: dict) -> tuple:
    """The soil patches every episode cuts through (``--patch`` or ``--path``), () if none."""
    if args.path:
        patches = path_patches(SoilFile(custom, paths) if args.soil_file else None, args.path, args.patch,
                               file_shown=str(args.soil_file))
    else:
        patches = check_patches(args.patch, "--patch")
        for i, patch in enumerate(patches):
            try:
                get_soil(patch.soil, custom)
            except ValueError as err:
                raise ValueError(f"--patch[{i}]={args.patch[i]!r}: {err}") from None
    grid = [f"--{name}" for name in ("soils", "relative_densities") if getattr(args, name) is not None]
    if patches and grid:
        raise ValueError(f"{' and '.join(g.replace('_', '-') for g in grid)} cannot be combined with --patch or "
                         "--path: the patches set the soil along the path")
    return patches


def plan_from_args(args: argparse.Namespace) -> DatasetPlan:
    soil_file = load_soil_file(args.soil_file) if args.soil_file else None
    custom = soil_file.soils if soil_file else {}
    patches = _patches_from_args(args, soil_file.paths if soil_file else {}, custom)
    if patches:
        soils, relative_densities = [patches[0].soil], [patches[0].relative_density_pct]
    else:
        # ('--soils ""' had meant all four soils, '--soils ,' none and an empty dataset.json)
        soils = list(CATALOGUE) if args.soils is None else _items(args.soils, "soils", "soil names, e.g. Sand,Clay")
        relative_densities = (DEFAULT_RELATIVE_DENSITIES if args.relative_densities is None
                              else _floats(args.relative_densities, "relative-densities"))
    effects = effects_for_mode(args.mode)
    off = [x.strip() for x in args.effects_off.split(",") if x.strip()]
    if off:
        effects = effects.with_switches(**{name: False for name in off})
    speeds = GRID_SPEEDS[args.mode] if args.speeds is None else _floats(args.speeds, "speeds")
    if args.seeds < 1:
        raise ValueError(f"seeds={args.seeds} must be >= 1")
    depths = _depths(args.depths)
    n_episodes = len(soils) * len(relative_densities) * len(speeds) * len(depths) * args.seeds
    if n_episodes - 1 > MAX_SEED:
        raise ValueError(f"seeds={args.seeds} makes {n_episodes} episodes, more than there are seeds ({MAX_SEED} + 1)")
    if not 0 <= args.seed_base <= MAX_SEED - (n_episodes - 1):  # each episode's seed is seed_base + its index
        raise ValueError(f"--seed-base={args.seed_base} must be in [0, {MAX_SEED - (n_episodes - 1)}] for "
                         f"{n_episodes} episode(s): episode i is seeded seed_base + i, at most {MAX_SEED}")
    specs = grid_specs(soils, relative_densities, speeds, depths, args.seeds, args.seed_base,
                       args.duration, patches)
    if specs and ticks_in(specs[0].duration_s) < WINDOW_SAMPLES:  # (made all the same: a plot needs no window)
        print(f"soil_sim_batch: warning: --duration {args.duration:g} s gives episodes of fewer ticks than one "
              f"{WINDOW_SAMPLES}-sample window; pinn_train, pinn_eval and soil_discrepancy refuse such bags",
              file=sys.stderr)
    out = args.out or Path("bags") / f"d_{args.mode}"
    if args.overwrite and args.skip_existing:
        raise ValueError("--overwrite and --skip-existing contradict each other: give one")
    return DatasetPlan(args.mode, out, specs, effects, tuple(args.plugin), custom, args.overwrite, args.engine,
                       args.skip_existing)


def main(argv=None) -> int:
    args = parse_args(argv)
    plan = before = None  # (before: the bags the output held when the run began)
    try:
        plan = plan_from_args(args)
        refuse_directories([plan.out / "dataset.json"])
        if args.workers < 0:
            raise ValueError(f"--workers={args.workers} must be >= 0 (0: all cores)")
        if not args.ray or args.ray == LOCAL_RAY:  # processes of this machine (a cluster's --workers are its CPUs)
            cli_numbers.check_local_count("--workers", args.workers)
        for depth in sorted({spec.target_depth_m for spec in plan.specs}):
            if note := beyond_lift_reach("--depths", depth):
                print(f"soil_sim_batch: warning: {note}", file=sys.stderr)
        for speed in sorted({spec.target_speed_m_s for spec in plan.specs}):
            if note := beyond_table1_speed("--speeds", speed):
                print(f"soil_sim_batch: warning: {note}", file=sys.stderr)
        notes = repeated_grid_values(args) + [identical_seeds_note(plan, args.seeds)]
        for note in filter(None, notes + unreached_patches(plan.specs) + soil_file_notes(plan.custom_soils)):
            print(f"soil_sim_batch: warning: {note}", file=sys.stderr)
        # (a custom soil named like a catalogue soil replaces it: that one is simulated)
        unused = sorted(n for n in plan.custom_soils if n.lower() not in {c.lower() for c in CATALOGUE})
        if unused and args.soils is None and not plan.specs[0].patches:
            print(f"soil_sim_batch: warning: --soil-file's soils {unused} are not simulated without --soils naming "
                  f"them (e.g. --soils {','.join(unused)}); the catalogue's are", file=sys.stderr)
        before, started = _bags_in(plan.out), time.time()
        with terminate_as_interrupt():
            summary = generate(plan, workers=args.workers, progress=not args.quiet, ray_address=args.ray,
                               ray_give_up_after_s=args.ray_give_up_after)
    except (ValueError, FileNotFoundError, FileExistsError) as exc:
        print(f"soil_sim_batch: error: {exc}", file=sys.stderr)
        # a bag that came into being after this run checked --out: another run writing into it
        raced = isinstance(exc, FileExistsError) and "not replaced" in str(exc)
        if raced:
            print(f"soil_sim_batch: that bag was written after this run began: is another run writing into "
                  f"{plan.out}? Let it finish, then the same command with --skip-existing simulates what is "
                  "missing", file=sys.stderr)
        if before is not None and (kept := kept_after_failure(plan.out, before, bad_input=not raced,
                                                              said="--skip-existing" if raced else "",
                                                              overwrite=plan.overwrite, since=started,
                                                              planned=planned_names(plan))):
            print(f"soil_sim_batch: {kept}", file=sys.stderr)
        return 2
    except (ChunksFailed, RuntimeError) as exc:
        bad_input = bool(getattr(exc, "bad_input", False))
        print(f"soil_sim_batch: error: {exc}", file=sys.stderr)
        if plan is not None and isinstance(exc, WorkerDied):  # the dead worker's bag, and the others' stopped mid-write
            _remove_staging(plan)
        if before is not None and (kept := kept_after_failure(plan.out, before, bad_input, str(exc), overwrite=plan.overwrite,
                                                                         since=started, planned=planned_names(plan))):
            print(f"soil_sim_batch: {kept}", file=sys.stderr)
        return 2 if bad_input else 1
    except OSError as exc:  # a disk full mid-run (a pool worker's too: its traceback said no more)
        print(f"soil_sim_batch: error: writing the bags failed: {exc}", file=sys.stderr)
        if plan is not None:
            _remove_staging(plan)
        if before is not None and (kept := kept_after_failure(plan.out, before, bad_input=False, overwrite=plan.overwrite,
                                                                         since=started, planned=planned_names(plan))):
            print(f"soil_sim_batch: {kept}", file=sys.stderr)
        return 1
    except KeyboardInterrupt as exc:  # Ctrl-C or SIGTERM; the bags finished are whole (write_episode renames a finished bag into place)
        how = " (SIGTERM)" if isinstance(exc, Terminated) else ""
        if plan is None:  # (a SIGTERM reaches here through the console script's run_tool)
            print(f"soil_sim_batch: interrupted{how} before anything was written", file=sys.stderr)
            return interrupt_exit_code(exc)
        # a second signal (an impatient Ctrl-C, timeout's SIGTERM after the terminal's) waits for the clean-up:
        # it had interrupted the staging's removal, leaving half-written bags' folders and a traceback
        with stop_requests():
            _remove_staging(plan)
            stale = before is not None and plan.overwrite and left_stale(plan.out, before, started, planned_names(plan))
            # (a stop before this run finished any bag said "the bags finished are kept" of none, an outside tester's)
            finished = before is not None and bool(bags_of_this_run(plan.out, before, plan.overwrite, started))
            kept = (f"the bags finished under {plan.out} are kept ({resume_hint(stale)})" if finished else
                    f"it had finished no bag under {plan.out} ("
                    + (resume_hint(stale) if stale else "the same command runs it again") + ")")
            print(f"soil_sim_batch: interrupted{how}; {kept}", file=sys.stderr)
        return interrupt_exit_code(exc)
    for spec in idle_plugins(summary):
        # (of the episodes this run simulated: those an interrupted run left are not known, an outside reviewer's)
        which = (f"of the {summary['simulated_episodes']} episodes simulated now (the {len(summary['kept_existing'])} "
                 "kept from the run before are not known)" if summary.get("kept_existing") else "of every episode")
        print(f"soil_sim_batch: warning: plugin {spec!r} returned 0 N in every substep {which}: it never acted in "
              f"these {plan.mode}-world episodes (e.g. surcharge_drag where no pile stands before the blade, Q = 0, "
              "as in the fee world), so their bags hold no such effect", file=sys.stderr)
    kept = (f" ({summary['simulated_episodes']} simulated, {len(summary['kept_existing'])} kept from the run before)"
            if summary.get("kept_existing") else "")
    print(
        f"{summary['episodes']} {summary['mode']} episodes{kept} -> {plan.out} in {summary['wall_time_s']:.1f} s "
        f"({summary['simulated_s_per_wall_s']:.0f} simulated s per wall s, "
        f"{summary['bytes_per_episode'] / 1e3:.0f} kB per episode)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
