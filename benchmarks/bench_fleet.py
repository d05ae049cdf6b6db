"""Fleet-scale figures on this machine (prints, never asserts): the inputs of the README's
"Running on a cluster" estimate.

* Episodes/s of soil_sim_batch for the same 24 ten-second episodes: the local fork pool with 1
  and 2 workers against Ray tasks on a local Ray instance of 1 and 2 CPUs (each in a fresh process,
  timed after a warm-up in the same instance; the instance's start-up is printed apart). Two rounds, the second in
  reverse order, best of the two: the load of a shared machine drifts.
* Ray's cost per task: many no-op tasks in flight at once (throughput), and one at a time
  (round trip).
* Reading bags into training arrays (load_dataset, no cache): bags/s with 1 and 2 local
  processes and as Ray tasks on 2 CPUs (instance already started).
* pinn_train's training throughput (windows/s over whole epochs, validation included) in one
  process with --threads 2 and 1, against 2 DDP processes under torchrun with 1 thread each
  (--threads 2 shared out), on the same 12-episode dataset and model.

Everything Ray or torchrun starts stays on loopback: a local Ray instance bound to 127.0.0.1 with
usage statistics off, and torchrun inside a private network namespace (``unshare -rn``; skipped
where that is not allowed). The machine may be shared: compare the ratios of one run.

Usage: .venv/bin/python benchmarks/bench_fleet.py
"""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")

from pinn_estimator.checkpoint import read_checkpoint  # noqa: E402
from pinn_estimator.dataset import load_dataset  # noqa: E402
from soil_sim_node.batch import DatasetPlan, generate, grid_specs  # noqa: E402
from soil_sim_node.effects import effects_for_mode  # noqa: E402
from soil_sim_node.ray_cluster import LOCAL, ray_session, run_tasks  # noqa: E402

EPISODES = grid_specs(["Clay", "Loam", "Sand", "Gravel"], [30.0, 70.0], [0.4, 0.7, 1.0], [0.15], 1, 0, 10.0)  # 24
WARM_UP = grid_specs(["Loam"], [50.0], [0.5], [0.1, 0.2], 2, 1000, 2.0)  # 4 short ones: imports, kernel load
TRAIN_DATA = grid_specs(["Clay", "Sand"], [50.0], [0.4, 0.7, 1.0], [0.1, 0.2], 1, 0, 10.0)  # 12, 6 per stratum
TRAIN_ARGS = ["--epochs", "4", "--patience", "100", "--batch-size", "512", "--quiet", "--no-cache"]


def _plan(out: Path, specs) -> DatasetPlan:
    return DatasetPlan("fee", out, list(specs), effects_for_mode("fee"))


def episodes_per_s(tmp: Path, workers: int, ray: bool) -> tuple[float, float]:
    """(episodes/s over EPISODES, start-up s of the Ray instance or 0), measured in a fresh process:
    one that has run Ray cannot fork safely, so a pool after Ray would spawn its workers (slower to
    start) and the rounds would not compare like with like."""
    out = subprocess.run([sys.executable, __file__], check=True, stdout=subprocess.PIPE, text=True,
                         env={**os.environ, MEASURE_ENV: json.dumps([str(tmp), workers, ray])})
    rate, startup = json.loads(out.stdout.strip().splitlines()[-1])
    return rate, startup


def _episodes_per_s(tmp: Path, workers: int, ray: bool) -> tuple[float, float]:
    """``episodes_per_s`` in this process."""
    tag = f"{'ray' if ray else 'pool'}{workers}"
    address = LOCAL if ray else None
    t0 = time.perf_counter()
    if ray:
        with ray_session(LOCAL, num_cpus=workers):
            startup = time.perf_counter() - t0
            generate(_plan(tmp / f"{tag}_warm", WARM_UP), workers=workers, progress=False, ray_address=address)
            t0 = time.perf_counter()
            generate(_plan(tmp / tag, EPISODES), workers=workers, progress=False, ray_address=address)
            wall = time.perf_counter() - t0
    else:
        startup = 0.0
        generate(_plan(tmp / f"{tag}_warm", WARM_UP), workers=workers, progress=False)
        t0 = time.perf_counter()
        generate(_plan(tmp / tag, EPISODES), workers=workers, progress=False)
        wall = time.perf_counter() - t0
    return len(EPISODES) / wall, startup


def _noop(x):
    return x


def ray_task_overhead(n: int = 400, serial: int = 50) -> tuple[float, float]:
    """(s per task with ``n`` no-op tasks in flight on 2 CPUs, s per task one at a time)."""
    with ray_session(LOCAL, num_cpus=2) as ray:
        run_tasks(_noop, list(range(20)))  # workers started
        t0 = time.perf_counter()
        run_tasks(_noop, list(range(n)))
        batch = (time.perf_counter() - t0) / n
        t0 = time.perf_counter()
        for i in range(serial):
            ray.get(ray.remote(_noop).remote(i))
        one = (time.perf_counter() - t0) / serial
    return batch, one


def bags_per_s(data: Path) -> dict[str, float]:
    """Bags read per second, no cache: 1 and 2 local processes, Ray tasks on 2 CPUs."""
    n = len(TRAIN_DATA)
    rates = {}
    for workers in (1, 2):
        t0 = time.perf_counter()
        load_dataset(data, cache=False, workers=workers)
        rates[f"{workers} local process{'es' if workers > 1 else ''}"] = n / (time.perf_counter() - t0)
    with ray_session(LOCAL, num_cpus=2):
        load_dataset(data, cache=False, ray_address=LOCAL)  # workers warm
        t0 = time.perf_counter()
        load_dataset(data, cache=False, ray_address=LOCAL)
        rates["Ray tasks, 2 CPUs"] = n / (time.perf_counter() - t0)
    return rates


def _netns() -> bool:
    return bool(shutil.which("unshare") and shutil.which("ip")) and subprocess.run(
        ["unshare", "-rn", "ip", "link", "set", "lo", "up"], capture_output=True).returncode == 0


def training_windows_per_s(data: Path, out: Path, processes: int, threads: int) -> float:
    """Training windows (partner windows included) per wall second over whole epochs."""
    ckpt = out / f"ddp{processes}_{threads}.pt"
    if processes == 1:
        cmd = ["sh", "-c", '"$0" -m pinn_estimator.train "$@"', sys.executable]
    else:
        cmd = ["unshare", "-rn", "sh", "-c", 'ip link set lo up && exec "$0" -m torch.distributed.run '
               f'--nproc-per-node {processes} --master-addr 127.0.0.1 --master-port 29500 -m pinn_estimator.train "$@"',
               sys.executable]
    # TMPDIR: torchrun's own scratch directories go with the benchmark's, not into /tmp for good
    env = {**os.environ, "GLOO_SOCKET_IFNAME": "lo", "MASTER_ADDR": "127.0.0.1", "TMPDIR": str(out)}
    subprocess.run([*cmd, "--data", str(data), "--out", str(ckpt), "--threads", str(threads), *TRAIN_ARGS], env=env, check=True,
                   capture_output=True)
    m = read_checkpoint(ckpt)["metrics"]
    return m["train_windows_per_epoch"] * m["epochs_run"] / m["train_seconds"]


SCRATCH_ENV = "BENCH_FLEET_SCRATCH"
MEASURE_ENV = "BENCH_FLEET_MEASURE"  # a child measuring one configuration of episodes_per_s: [dir, workers, ray]


def run_in_scratch() -> int:
    """Run the benchmark in a child process with a scratch directory this process removes
    however the child ends: Ray replaces the SIGTERM handler of the process it runs in, so a
    stopped run (timeout, kill) could not clean up its ~130 MB of bags itself."""
    with tempfile.TemporaryDirectory(prefix="bench_fleet_") as scratch:
        child = subprocess.Popen([sys.executable, __file__], env={**os.environ, SCRATCH_ENV: scratch})
        signal.signal(signal.SIGTERM, lambda signum, frame: child.terminate())
        try:
            code = child.wait()
        except KeyboardInterrupt:  # Ctrl-C reached the child too (same process group)
            code = child.wait()
        return 128 - code if code < 0 else code  # killed by signal N: 128 + N, as a shell says


def main() -> None:
    print(f"cores: {os.cpu_count()}; {len(EPISODES)} fee episodes of 10 s per run; load average "
          f"{os.getloadavg()[0]:.1f} (a shared machine: compare ratios within this run)")
    tmp = Path(os.environ[SCRATCH_ENV])
    rows = {}
    order = [(ray, workers) for ray in (False, True) for workers in (1, 2)]
    for n_round, configs in enumerate((order, order[::-1])):
        for ray, workers in configs:
            key = ("Ray tasks" if ray else "local pool", workers)
            rate, startup = episodes_per_s(tmp / str(n_round), workers, ray)
            rows[key] = max(rows.get(key, (0.0, 0.0)), (rate, startup))
    print(f"\n{'episodes/s':22s}{'1 worker':>12s}{'2 workers':>12s}{'2 vs 1':>9s}")
    for how in ("local pool", "Ray tasks"):
        one, two = rows[(how, 1)][0], rows[(how, 2)][0]
        print(f"{how:22s}{one:12.2f}{two:12.2f}{two / one:8.2f}x")
    print(f"{'Ray / pool':22s}{rows[('Ray tasks', 1)][0] / rows[('local pool', 1)][0]:11.2f}x"
          f"{rows[('Ray tasks', 2)][0] / rows[('local pool', 2)][0]:11.2f}x")
    startups = [rows[("Ray tasks", w)][1] for w in (1, 2)]
    print(f"local Ray instance start-up: {min(startups):.1f}-{max(startups):.1f} s (once per run, not per episode)")
    # the local pools before Ray runs in this process (after it they would spawn, not fork)
    data = tmp / "train"
    generate(_plan(data, TRAIN_DATA), workers=2, progress=False)
    size = sum(f.stat().st_size for f in data.rglob("*") if f.is_file()) / len(TRAIN_DATA)
    print(f"\nreading {len(TRAIN_DATA)} bags of 10 s ({size / 1e3:.0f} kB each) into training arrays, no cache:")
    for how, rate in bags_per_s(data).items():
        print(f"  {how:22s}{rate:7.1f} bags/s")
    batch, one = ray_task_overhead()
    print(f"\nRay cost per task: {batch * 1e3:.2f} ms with 400 no-op tasks in flight on 2 CPUs, "
          f"{one * 1e3:.2f} ms one at a time (a 48-episode chunk of 10 s episodes takes tens of s)")
    if not _netns():
        print("\ntraining: skipped (needs `unshare -rn` to keep torchrun's store on loopback)")
        return
    rates = {(p, t): training_windows_per_s(data, tmp, p, t) for p, t in ((1, 2), (1, 1), (2, 2))}
    print(f"\ntraining windows/s, PINN default model, {' '.join(TRAIN_ARGS[:6])}:")
    for (p, t), rate in rates.items():
        print(f"  {p} process{'es (DDP)' if p > 1 else '       '} --threads {t} ({t // p} per process): {rate:7.0f}"
              f"   {rate / rates[(1, 2)]:.2f}x of 1 process --threads 2")


if __name__ == "__main__":
    import argparse

    # no options: --help prints what the benchmark measures instead of starting its run
    argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter).parse_args()
    sys.stdout.reconfigure(line_buffering=True)  # a run stopped early still shows what it measured
    if MEASURE_ENV in os.environ:
        where, n_workers, on_ray = json.loads(os.environ[MEASURE_ENV])
        print(json.dumps(_episodes_per_s(Path(where), n_workers, on_ray)))
    elif SCRATCH_ENV in os.environ:
        main()
    else:
        sys.exit(run_in_scratch())
