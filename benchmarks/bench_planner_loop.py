"""The planner in the live loop: does the new node cost the 60 Hz graph its deadlines? Prints figures; asserts nothing.

    .venv/bin/python benchmarks/bench_planner_loop.py
    .venv/bin/python benchmarks/bench_planner_loop.py --duration 60 --repeats 3 --load 1
    .venv/bin/python benchmarks/bench_planner_loop.py --force-lift 1.0   # the controller also joins /blade/force

Runs the same real-time episode (rate 1, a path of changing soil, the default world) through
``soil_launch`` alternately without the planner (simulator, controller, estimator, recorder)
and with it (``--planner``: the controller follows /planner/target_depth), ``--repeats``
times each, and prints side by side the simulator's timing figures of each episode (late
commands, publish period and jitter, loop latency) and the CPU of every node over the
episode. ``--load N`` keeps N busy-looping processes running throughout (a loaded machine).

Loopback DDS only, on its own ROS_DOMAIN_ID (--domain-id; default $ROS_DOMAIN_ID, else 66); every launch is bounded by a
timeout and cleaned up (graph_procs.py).
"""
from __future__ import annotations

import argparse
import ast
import contextlib
import os
import re
import tempfile
import time

from graph_procs import Graph, Load, children, cpu_seconds  # sets loopback-only DDS
from soil_bringup.launch import add_domain_id_option  # noqa: E402

PATCHES = "['0:Sand:20','10:Clay:80','16:Loam:50']"
_TIMING = re.compile(r"episode \d+ end \(\w+\): \d+ ticks; timing (\{.*\})")


def run(planner: bool, duration_s: float, domain: int, controller_args: tuple[str, ...] = ()) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        args = ["--planner" if planner else "--estimator", "--rate", "1", "--record", tmp,
                "--sim-param", f"patches:={PATCHES}", "--sim-param", f"duration_s:={duration_s}",
                "--timeout", str(duration_s + 90), *controller_args]
        with Graph(args, domain) as graph:
            pids, cpu0, t0 = {}, {}, None
            deadline = time.monotonic() + duration_s + 120
            while graph.proc.poll() is None and time.monotonic() < deadline:
                if not pids and "episode 0 start" in graph.text():
                    pids = children(graph.proc.pid)
                    cpu0, t0 = {n: cpu_seconds(p) for n, p in pids.items()}, time.monotonic()
                if pids and "episode 0 end" in graph.text():
                    break
                time.sleep(0.05)
            cpu = {}
            if pids:
                wall = time.monotonic() - t0
                for n, p in pids.items():
                    with contextlib.suppress(OSError):
                        cpu[n] = 100.0 * (cpu_seconds(p) - cpu0[n]) / wall
            rc = graph.wait(timeout=60)
            match = _TIMING.search(graph.text())
    stats = ast.literal_eval(match.group(1)) if match else {}
    return {"rc": rc, "stats": stats, "cpu": cpu}


def line(name: str, r: dict) -> str:
    s = r["stats"]
    if not s:
        return f"  {name:<16} no episode_end timing (launch exit {r['rc']})"
    f = lambda k: f"{s[k]['p50_ms']:.1f}/{s[k]['p99_ms']:.1f}/{s[k]['max_ms']:.1f}"  # noqa: E731
    cpu = " ".join(f"{n.replace('soil_', '').replace('anti_stall_', '')}={v:.0f}%" for n, v in sorted(r["cpu"].items()))
    return (f"  {name:<16} late commands {s['late_commands']:4d} of {s['period']['n'] + 1}, period p50/p99/max "
            f"{f('period')} ms, jitter p50/p99/max {f('jitter')} ms, "
            f"loop latency {f('loop_latency')} ms | CPU {cpu}")


def main() -> None:
    import dataclasses

    from soil_bringup.cut_report import add_force_lift_option, controller_text

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--duration", type=float, default=30.0, help="simulated seconds per episode (real time)")
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--load", type=int, default=0, help="busy-looping processes during the runs")
    add_domain_id_option(p, 66)
    add_force_lift_option(p, "the controller's force lift in every run (soil_cut_report --force-lift); default off, "
                             "Eq. 11 alone")
    args = p.parse_args()
    gains = args.gains
    controller_args = () if gains.force_lift_m_s == 0.0 else (
        "--controller-param", f"force_lift_m_s:={gains.force_lift_m_s}",
        "--controller-param", f"force_lift_share:={gains.force_lift_share}")
    print(f"bench_planner_loop: {args.repeats} x {args.duration:g} s real-time episodes each, default world, path "
          f"{PATCHES}, load {args.load}, {os.cpu_count()} cores"
          + (f", controller {controller_text(dataclasses.asdict(gains))}" if controller_args else ""))
    late = {False: [], True: []}
    with Load(args.load, max_s=args.repeats * 2 * (args.duration + 120)):
        for i in range(args.repeats):
            for planner in (False, True):
                r = run(planner, args.duration, args.domain_id, controller_args)
                late[planner].append(r["stats"].get("late_commands"))
                print(line(("with planner" if planner else "without") + f" #{i + 1}", r), flush=True)
    total = {k: sum(v for v in vs if v is not None) for k, vs in late.items()}
    print(f"late commands in all: without the planner {total[False]}, with it {total[True]} "
          f"(load average {os.getloadavg()[0]:.2f})")


if __name__ == "__main__":
    main()
