"""Node-graph benchmarks (issue: ROS node graph). Prints figures; asserts nothing.

    .venv/bin/python benchmarks/bench_graph.py
    .venv/bin/python benchmarks/bench_graph.py --rates 1 2 4 --duration 10 --cpu-seconds 20
    .venv/bin/python benchmarks/bench_graph.py --sim-engine reference
    .venv/bin/python benchmarks/bench_graph.py --compare-engines --load 2   # before/after, loaded machine

1. Highest real-time factor at which the graph (sim + controller + recorder, launched by
   soil_launch) still drops nothing: for each rate, one episode of ``--duration`` simulated
   seconds is recorded; "drops nothing" = the bag has every tick on every topic AND the
   simulator never had to hold a late command. Period, jitter and loop latency are printed per rate.
2. One long real-time run (rate 1, ``--long-seconds``, default 60 s at 60 Hz): late commands,
   publish period, jitter and loop latency of the episode (the graph tests check that no
   tick is missing and every tick is answered in time or counted late; these are the
   figures for how often late and how steady).
3. CPU per node at 60 Hz (rate 1): user+system CPU time of each node process over a
   steady window, as % of one core.

``--sim-engine`` picks the simulator's engine (soil_sim_node parameter ``engine``: 'compiled',
the default, or 'reference', the NumPy path it replaced). ``--compare-engines`` runs sections 2
and 3 once per engine, one after the other (reference first: before, then compiled: after), and prints them side by side (section 1 runs with
``--sim-engine``). ``--load N`` keeps N busy-looping processes running during every run (a
loaded machine; on 2 cores, 2 takes every core from the graph's share).

Loopback DDS only, on its own ROS_DOMAIN_ID (--domain-id; default $ROS_DOMAIN_ID, else 65); every run is bounded by a timeout
and every process it starts is stopped at the end (graph_procs.py).
"""
from __future__ import annotations

import argparse
import contextlib
import os
import tempfile
import threading

from graph_procs import Graph, Load, cpu_per_node  # sets loopback-only DDS
from soil_bringup.launch import add_domain_id_option  # noqa: E402

import rclpy  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from std_msgs.msg import String  # noqa: E402

from soil_msgs_py import graph as G  # noqa: E402
from soil_bag_tools.bag_io import find_episode_bags, read_episode  # noqa: E402
from soil_msgs_py.params import ticks_in  # noqa: E402
from soil_msgs_py.ros_adapter import init_context, topic_qos  # noqa: E402

from soil_sim_node.simulator import ENGINES  # noqa: E402


class StatusListener:
    """Collects /sim/status events in a background executor (its own context)."""

    def __init__(self, domain_id: int):
        self.context = init_context(domain_id)
        self.node = rclpy.create_node("bench_graph_status", context=self.context)
        self.events: list[G.EpisodeEvent] = []
        self.node.create_subscription(String, G.SIM_STATUS_TOPIC,
                                      lambda m: self.events.append(G.EpisodeEvent.from_json(m.data)),
                                      topic_qos(G.SIM_STATUS_TOPIC))
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self):
        while not self.stop.is_set():
            self.executor.spin_once(timeout_sec=0.05)

    def close(self):
        self.stop.set()
        self.thread.join(timeout=5)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def engine_args(engine: str) -> list[str]:
    return ["--sim-param", f"engine:={engine}"]


def run_rate(rate: float, duration_s: float, domain: int, engine: str = "compiled") -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        listener = StatusListener(domain)
        try:
            # the simulator waits for this listener too: on a short episode episode_end went out before it had matched
            with Graph(["--rate", str(rate), "--record", tmp, "--sim-param", f"duration_s:={duration_s}",
                        "--wait-for", f"{G.SIM_STATUS_TOPIC}:1",
                        *engine_args(engine), "--timeout", str(duration_s / rate + 60)], domain) as graph:
                rc = graph.wait(timeout=duration_s / rate + 90)
            end = next((e for e in listener.events if e.event == G.EVENT_EPISODE_END), None)
        finally:
            listener.close()
        bags = find_episode_bags(tmp)
        ticks = len(read_episode(bags[0])) if bags else 0
    planned = ticks_in(duration_s)
    stats = end.stats if end else {}
    return {"rate": rate, "rc": rc, "planned": planned, "recorded": ticks,
            "late": stats.get("late_commands"), "period": stats.get("period", {}), "jitter": stats.get("jitter", {}),
            "loop": stats.get("loop_latency", {}),
            "clean": rc == 0 and ticks == planned and stats.get("late_commands") == 0, "stats_received": end is not None}


def figures(s: dict) -> str:
    """p50/p99/max of one timing entry of the episode_end stats."""
    return f"{s.get('p50_ms')}/{s.get('p99_ms')}/{s.get('max_ms')} ms"


def run_line(r: dict) -> str:
    if not r["stats_received"]:
        return (f"recorded {r['recorded']}/{r['planned']} ticks, episode_end (the timing figures) not received, "
                f"launch exit {r['rc']}: not judged")
    return (f"recorded {r['recorded']}/{r['planned']} ticks, late commands {r['late']}, "
            f"period p50/p99/max {figures(r['period'])}, jitter p50/p99/max {figures(r['jitter'])}, "
            f"loop latency p50/p99/max {figures(r['loop'])}, {'clean' if r['clean'] else 'DROPS'}")


def long_line(r: dict) -> str:
    share = 100.0 * (r["late"] or 0) / max(r["planned"], 1)
    return f"{run_line(r)}; late commands {share:.2f} % of ticks; load average {os.getloadavg()[0]:.2f}"


def side_by_side(rows: list[tuple[str, str, str]], engines: tuple[str, ...]) -> None:
    """rows of (figure, value for engines[0], value for engines[1])."""
    w = max(len(r[0]) for r in rows)
    v = max(12, *(len(x) for r in rows for x in r[1:]))
    labels = [f"{e} ({'old' if e == 'reference' else 'new'})" for e in engines]
    print(f"{'':{w}s}  {labels[0]:>{v}s}  {labels[1]:>{v}s}")
    for name, a, b in rows:
        print(f"{name:{w}s}  {a:>{v}s}  {b:>{v}s}")


def compare_long(runs: dict[str, dict]) -> None:
    engines = tuple(runs)
    rows = [("recorded ticks", *(f"{runs[e]['recorded']}/{runs[e]['planned']}" for e in engines)),
            ("late commands", *(f"{runs[e]['late']} ({100.0 * (runs[e]['late'] or 0) / max(runs[e]['planned'], 1):.2f} %)"
                                for e in engines))]
    for key, label in (("period", "period"), ("jitter", "jitter"), ("loop", "loop latency")):
        rows.append((f"{label} p50/p99/max", *(figures(runs[e][key]) for e in engines)))
    rows.append(("clean (every tick, none late)", *("yes" if runs[e]["clean"] else "no" for e in engines)))
    side_by_side(rows, engines)


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--rates", type=float, nargs="*", default=[1, 2, 3, 4, 6, 8], help="(none: skip the sweep)")
    p.add_argument("--duration", type=float, default=10.0, help="simulated seconds per rate")
    p.add_argument("--long-seconds", type=float, default=60.0, help="simulated seconds of the real-time run (0: skip)")
    p.add_argument("--cpu-seconds", type=float, default=20.0, help="CPU window (0: skip)")
    add_domain_id_option(p, 65)
    p.add_argument("--sim-engine", choices=ENGINES, default="compiled", help="simulator engine (default: compiled)")
    p.add_argument("--compare-engines", action="store_true",
                   help="run the real-time run and the CPU figures for both engines, side by side")
    p.add_argument("--load", type=int, default=0, help="busy-looping processes running alongside (a loaded machine)")
    args = p.parse_args()
    # before (the NumPy reference) then after (the compiled kernel)
    engines = ("reference", "compiled") if args.compare_engines else (args.sim_engine,)
    budget = (len(args.rates) * (args.duration + 100) + len(engines) * (args.long_seconds + args.cpu_seconds + 200))
    load = Load(args.load, budget) if args.load else contextlib.nullcontext()
    print(f"cores: {os.cpu_count()}, busy-loop load processes: {args.load}, engine(s): {', '.join(engines)}")
    with load:
        sections(args, engines)


def sections(args: argparse.Namespace, engines: tuple[str, ...]) -> None:
    if args.rates:
        print(f"== real-time factor sweep ({args.duration} s episodes, sim + controller + recorder, "
              f"engine {args.sim_engine})")
        best = prev = None
        for rate in args.rates:
            r = run_rate(rate, args.duration, args.domain_id, args.sim_engine)
            print(f"rate {rate:5.1f}: {run_line(r)}", flush=True)
            if r["clean"] and (best is None or best == prev):
                best = rate
            prev = rate
            if r["recorded"] < r["planned"] or (r["late"] or 0) > 0.1 * r["planned"]:
                break  # far past the limit: higher rates only take longer to say so
        print(f"highest rate factor with no drops: {best}")

    if args.long_seconds > 0:
        runs = {}
        for engine in engines:
            print(f"== real time at 60 Hz for {args.long_seconds:g} s (rate 1, sim + controller + recorder, "
                  f"engine {engine})")
            runs[engine] = run_rate(1.0, args.long_seconds, args.domain_id, engine)
            print(long_line(runs[engine]), flush=True)
        if len(engines) > 1:
            print(f"== real time at 60 Hz for {args.long_seconds:g} s, side by side "
                  f"(timing figures from the simulator's episode_end stats)")
            compare_long(runs)

    if args.cpu_seconds > 0:
        cpu = {}
        for engine in engines:
            print(f"== CPU per node at 60 Hz (rate 1), over {args.cpu_seconds:g} s, engine {engine}")
            cpu[engine] = cpu_per_node(args.cpu_seconds, args.domain_id, engine_args(engine))
            for name, pct in sorted(cpu[engine].items()):
                print(f"{name:24s} {pct:6.1f} % of one core", flush=True)
        if len(engines) > 1:
            print(f"== CPU per node at 60 Hz, side by side (% of one core over {args.cpu_seconds:g} s)")
            names = sorted(set().union(*(c.keys() for c in cpu.values())))
            side_by_side([(n, *(f"{cpu[e].get(n, float('nan')):.1f} %" for e in engines)) for n in names], engines)


if __name__ == "__main__":
    main()
