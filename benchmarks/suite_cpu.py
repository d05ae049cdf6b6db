"""Where the test suite's time and CPU go: runs ``pytest -n 2`` (as ``make test`` does) with a
plugin that records each test's wall and CPU time, and prints them per lane (the graphs', the
clusters', the modules that go to a worker whole: tests/conftest.py), per module and per test.
Beside a busy core the suite is CPU-bound, so a trim that counts there takes CPU out. Prints
figures; asserts nothing.

    .venv/bin/python benchmarks/suite_cpu.py                       # the whole suite, ~10 min
    .venv/bin/python benchmarks/suite_cpu.py tests/soil_discrepancy --top 10

CPU is the test process's own and that of the children it reaped (nodes, tools, worker pools it
started and waited for); a process left to run past its test is counted where it is reaped.
"""
from __future__ import annotations

import argparse
import collections
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from soil_bringup.launch import loopback_env

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from tests.conftest import is_live_module, live_lane  # noqa: E402


def lane_of(module: str) -> str:
    path = ROOT / module
    return live_lane(path) if is_live_module(path) else "whole modules"


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("paths", nargs="*", default=["tests"], help="what pytest runs (default: tests)")
    p.add_argument("--workers", type=int, default=2, help="pytest-xdist workers (default 2, as make test)")
    p.add_argument("--top", type=int, default=20, help="modules and tests listed (default 20)")
    p.add_argument("--domain-id", type=int, default=int(os.environ.get("ROS_DOMAIN_ID", "63")),
                   help="ROS_DOMAIN_ID (the live tests lease their own domains besides)")
    args = p.parse_args()
    with tempfile.TemporaryDirectory(prefix="suite_cpu_") as d:
        log = Path(d) / "cpu.tsv"
        env = {**loopback_env(args.domain_id), "SUITE_CPU_LOG": str(log),
               "PYTHONPATH": os.pathsep.join([str(Path(__file__).parent), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)}
        run = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-p", "suite_cpu_plugin",
                              "-n", str(args.workers), *args.paths], cwd=ROOT, env=env)
        rows = [line.rstrip("\n").split("\t") for line in log.read_text(encoding="utf-8").splitlines()] if log.exists() else []
    if not rows:
        print("no test ran", file=sys.stderr)
        return 1
    lanes, modules = collections.defaultdict(lambda: [0.0, 0.0]), collections.defaultdict(lambda: [0.0, 0.0])
    tests = []
    for nodeid, wall, own, children in rows:
        module, cpu = nodeid.split("::")[0], float(own) + float(children)
        for total in (lanes[lane_of(module)], modules[module]):
            total[0] += float(wall)
            total[1] += cpu
        tests.append((cpu, float(wall), nodeid))
    print(f"\n{len(rows)} tests, {sum(v[1] for v in lanes.values()):.0f} s of CPU (pytest exit code {run.returncode})")
    print("| lane | wall [s] | CPU [s] |\n|---|---|---|")
    for name, (wall, cpu) in sorted(lanes.items(), key=lambda kv: -kv[1][1]):
        print(f"| {name} | {wall:.1f} | {cpu:.1f} |")
    print(f"\n| module (the {args.top} with most CPU) | lane | wall [s] | CPU [s] |\n|---|---|---|---|")
    for module, (wall, cpu) in sorted(modules.items(), key=lambda kv: -kv[1][1])[:args.top]:
        print(f"| {module} | {lane_of(module)} | {wall:.1f} | {cpu:.1f} |")
    print(f"\n| test (the {args.top} with most CPU) | wall [s] | CPU [s] |\n|---|---|---|")
    for cpu, wall, nodeid in sorted(tests, reverse=True)[:args.top]:
        print(f"| {nodeid} | {wall:.1f} | {cpu:.1f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
