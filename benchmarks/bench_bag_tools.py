"""Bag tool benchmarks. Prints figures; asserts nothing.

    .venv/bin/python benchmarks/bench_bag_tools.py
    .venv/bin/python benchmarks/bench_bag_tools.py --rates 1 2 4 --reads 20

1. Reading an episode bag: wall time of ``read_episode`` on the 600-tick sample bag.
2. Replay timing of ``soil_bag_play`` through DDS at each ``--rates`` factor, side by side:
   an in-process raw subscriber to every episode topic stamps each arrival with
   perf_counter; timing error of message i = (arrival_i - arrival_0) - (t_i - t_0) / rate,
   pairing each topic's k-th message with the bag's (the tests check that every message
   arrives, in order; these are the figures for how close to the bag's clock). The player's
   own publish lateness (from its log) separates pacing from DDS delivery.

Loopback DDS only, on its own ROS_DOMAIN_ID (--domain-id; default $ROS_DOMAIN_ID, else 63); every run is bounded by a timeout.
"""
from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import time
from pathlib import Path

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.pop("ROS_LOCALHOST_ONLY", None)

import numpy as np  # noqa: E402
from bench_graph import StatusListener  # noqa: E402 - sits next to this script

from soil_bag_tools import playback  # noqa: E402
from soil_bag_tools.bag_io import read_episode  # noqa: E402
from soil_bringup.launch import add_domain_id_option, loopback_env  # noqa: E402
from soil_msgs_py import graph as G  # noqa: E402
from soil_msgs_py.ros_adapter import message_class, qos_profile  # noqa: E402
from soil_msgs_py.topics import EPISODE_TOPICS  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
BIN = Path(sys.executable).parent
SAMPLE = REPO / "bags" / "samples" / "default_loam_id060_v0.50_d0.200_s7"
PLAYER_LATENESS = re.compile(r"lateness p50 ([\d.]+) ms, p99 ([\d.]+) ms, max ([\d.]+) ms")


class ArrivalListener(StatusListener):
    """bench_graph's background listener plus a raw subscriber on every episode topic."""

    def __init__(self, domain_id: int):
        super().__init__(domain_id)
        self.arrivals: list[tuple[int, str]] = []  # (perf_counter_ns, topic)
        qos = qos_profile(G.RECORDER_QOS)
        for topic in EPISODE_TOPICS:
            self.node.create_subscription(
                message_class(topic.msgtype), topic.name,
                lambda _raw, name=topic.name: self.arrivals.append((time.perf_counter_ns(), name)), qos, raw=True)


def timing_errors_ms(arrivals, bag_msgs, rate: float) -> np.ndarray:
    """Each bag message's arrival against the bag's clock scaled by ``rate``, relative to the first."""
    by_topic: dict[str, list[int]] = {}
    for recv, topic in arrivals:
        by_topic.setdefault(topic, []).append(recv)
    seen: dict[str, int] = {}
    pairs = []
    for t, topic, _ in bag_msgs:
        k = seen.get(topic, 0)
        seen[topic] = k + 1
        pairs.append((t, by_topic[topic][k]))
    t0, r0 = pairs[0]
    return np.array([((r - r0) - (t - t0) / rate) * 1e-6 for t, r in pairs])


def replay(rate: float, domain_id: int) -> dict:
    bag_msgs = playback.load_bag(SAMPLE).messages
    listener = ArrivalListener(domain_id)
    try:
        res = subprocess.run([str(BIN / "soil_bag_play"), str(SAMPLE), "--rate", str(rate),
                              "--wait-for-subscribers", "1"], env=loopback_env(domain_id),
                             capture_output=True, text=True, timeout=30 + 20 / rate)
        end = time.monotonic() + 5
        while len(listener.arrivals) < len(bag_msgs) and time.monotonic() < end:
            time.sleep(0.02)
        arrivals = list(listener.arrivals)
    finally:
        listener.close()
    out = {"rate": rate, "rc": res.returncode, "sent": len(bag_msgs), "received": len(arrivals),
           "bag_span_s": (bag_msgs[-1][0] - bag_msgs[0][0]) * 1e-9 / rate}
    m = PLAYER_LATENESS.search(res.stdout + res.stderr)
    out["player_lateness"] = tuple(float(x) for x in m.groups()) if m else None
    if len(arrivals) == len(bag_msgs):
        err = np.abs(timing_errors_ms(arrivals, bag_msgs, rate))
        out["error"] = (np.percentile(err, 50), np.percentile(err, 99), err.max())
        out["arrival_span_s"] = (arrivals[-1][0] - arrivals[0][0]) * 1e-9
    return out


def read_times_ms(reads: int) -> np.ndarray:
    read_episode(SAMPLE)  # imports and caches warm
    times = []
    for _ in range(reads):
        t0 = time.perf_counter()
        read_episode(SAMPLE)
        times.append(time.perf_counter() - t0)
    return np.array(times) * 1e3


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--rates", type=float, nargs="+", default=[1, 2])
    p.add_argument("--reads", type=int, default=10)
    add_domain_id_option(p, 63)
    args = p.parse_args()
    print(f"machine: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f}; sample bag {SAMPLE.name}")

    ms = read_times_ms(args.reads)
    n = len(read_episode(SAMPLE))
    print(f"== read_episode, {n} ticks, {args.reads} reads: p50 {np.percentile(ms, 50):.1f} ms, "
          f"max {ms.max():.1f} ms")

    print("== soil_bag_play replay timing through DDS (|arrival error| against the bag's clock / rate)")
    print(f"{'rate':>5s} {'received':>11s} {'p50 ms':>8s} {'p99 ms':>8s} {'max ms':>8s}  "
          f"{'arrivals/bag span s':>20s}  player lateness p50/p99/max ms")
    for rate in args.rates:
        r = replay(rate, args.domain_id)
        e = r.get("error")
        err = f"{e[0]:8.3f} {e[1]:8.3f} {e[2]:8.3f}" if e else f"{'-':>8s} {'-':>8s} {'-':>8s}"
        span = f"{r['arrival_span_s']:.3f}/{r['bag_span_s']:.3f}" if e else f"-/{r['bag_span_s']:.3f}"
        late = "/".join(f"{x:.3f}" for x in r["player_lateness"]) if r["player_lateness"] else "?"
        print(f"{rate:5.1f} {r['received']:5d}/{r['sent']:<5d} {err}  {span:>20s}  {late}"
              + ("" if r["rc"] == 0 else f"  (player exit code {r['rc']})"))
    print(f"load average now {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
