"""Node-graph benchmarks (issue: ROS node graph). Prints figures; asserts nothing.

    .venv/bin/python benchmarks/bench_graph.py
    .venv/bin/python benchmarks/bench_graph.py --rates 1 2 4 --duration 10 --cpu-seconds 20

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

Loopback DDS only, on its own ROS_DOMAIN_ID (default 199); every run is bounded by a timeout.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

BIN = Path(sys.executable).parent
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.pop("ROS_LOCALHOST_ONLY", None)

import rclpy  # noqa: E402
from rclpy.context import Context  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from std_msgs.msg import String  # noqa: E402

from soil_msgs_py import graph as G  # noqa: E402
from soil_bag_tools.bag_io import find_episode_bags, read_episode  # noqa: E402
from soil_msgs_py.ros_adapter import topic_qos  # noqa: E402

CLK_TCK = os.sysconf("SC_CLK_TCK")


class StatusListener:
    """Collects /sim/status events in a background executor (its own context)."""

    def __init__(self, domain_id: int):
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain_id)
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


def launch(args: list[str], domain: int) -> subprocess.Popen:
    return subprocess.Popen([str(BIN / "soil_launch"), "--domain-id", str(domain), *args],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def children(pid: int) -> dict[str, int]:
    """name -> pid of the launcher's node processes."""
    out = {}
    res = subprocess.run(["pgrep", "-P", str(pid)], capture_output=True, text=True)
    for child in res.stdout.split():
        cmd = Path(f"/proc/{child}/cmdline").read_bytes().split(b"\0")
        script = next((Path(c.decode()).name for c in cmd if b"soil_" in c or b"anti_stall" in c or b"pinn" in c), "?")
        out[script] = int(child)
    return out


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLK_TCK  # utime + stime


def run_rate(rate: float, duration_s: float, domain: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        listener = StatusListener(domain)
        try:
            proc = launch(["--rate", str(rate), "--record", tmp, "--sim-param", f"duration_s:={duration_s}",
                           "--timeout", str(duration_s / rate + 60)], domain)
            rc = proc.wait(timeout=duration_s / rate + 90)
            end = next((e for e in listener.events if e.event == G.EVENT_EPISODE_END), None)
        finally:
            listener.close()
        bags = find_episode_bags(tmp)
        ticks = len(read_episode(bags[0])) if bags else 0
    planned = int(round(duration_s * 60))
    stats = end.stats if end else {}
    return {"rate": rate, "rc": rc, "planned": planned, "recorded": ticks,
            "late": stats.get("late_commands"), "period": stats.get("period", {}), "jitter": stats.get("jitter", {}),
            "loop": stats.get("loop_latency", {}),
            "clean": rc == 0 and ticks == planned and stats.get("late_commands") == 0}


def cpu_per_node(seconds: float, domain: int) -> dict[str, float]:
    with tempfile.TemporaryDirectory() as tmp:
        proc = launch(["--record", tmp, "--sim-param", f"duration_s:={seconds + 20}", "--timeout", str(seconds + 60)],
                      domain)
        try:
            time.sleep(8.0)  # start-up, discovery, first ticks
            pids = children(proc.pid)
            before = {n: cpu_seconds(p) for n, p in pids.items()}
            t0 = time.monotonic()
            time.sleep(seconds)
            after = {n: cpu_seconds(p) for n, p in pids.items()}
            wall = time.monotonic() - t0
        finally:
            proc.send_signal(2)
            proc.wait(timeout=60)
    return {n: 100.0 * (after[n] - before[n]) / wall for n in pids}


def figures(s: dict) -> str:
    """p50/p99/max of one timing entry of the episode_end stats."""
    return f"{s.get('p50_ms')}/{s.get('p99_ms')}/{s.get('max_ms')} ms"


def run_line(r: dict) -> str:
    return (f"recorded {r['recorded']}/{r['planned']} ticks, late commands {r['late']}, "
            f"period p50/p99/max {figures(r['period'])}, jitter p50/p99/max {figures(r['jitter'])}, "
            f"loop latency p50/p99/max {figures(r['loop'])}, {'clean' if r['clean'] else 'DROPS'}")


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--rates", type=float, nargs="+", default=[1, 2, 3, 4, 6, 8])
    p.add_argument("--duration", type=float, default=10.0, help="simulated seconds per rate")
    p.add_argument("--long-seconds", type=float, default=60.0, help="simulated seconds of the real-time run (0: skip)")
    p.add_argument("--cpu-seconds", type=float, default=20.0)
    p.add_argument("--domain-id", type=int, default=199)
    args = p.parse_args()

    print(f"== real-time factor sweep ({args.duration} s episodes, sim + controller + recorder)")
    best = prev = None
    for rate in args.rates:
        r = run_rate(rate, args.duration, args.domain_id)
        print(f"rate {rate:5.1f}: {run_line(r)}")
        if r["clean"] and (best is None or best == prev):
            best = rate
        prev = rate
        if r["recorded"] < r["planned"] or (r["late"] or 0) > 0.1 * r["planned"]:
            break  # far past the limit: higher rates only take longer to say so
    print(f"highest rate factor with no drops: {best}")

    if args.long_seconds > 0:
        print(f"== real time at 60 Hz for {args.long_seconds:g} s (rate 1, sim + controller + recorder)")
        r = run_rate(1.0, args.long_seconds, args.domain_id)
        share = 100.0 * (r["late"] or 0) / max(r["planned"], 1)
        print(f"{run_line(r)}; late commands {share:.2f} % of ticks; load average {os.getloadavg()[0]:.2f}")

    print(f"== CPU per node at 60 Hz (rate 1), over {args.cpu_seconds} s")
    for name, pct in sorted(cpu_per_node(args.cpu_seconds, args.domain_id).items()):
        print(f"{name:24s} {pct:6.1f} % of one core")


if __name__ == "__main__":
    main()
