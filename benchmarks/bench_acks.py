"""How long a reliable writer waits for its readers' acknowledgement (``wait_for_all_acked``)
with Fast DDS's default writer timing and with the graph's profile (soil_msgs_py/dds_profile.py),
side by side in one run, and what that makes of a short launch. Prints figures; asserts nothing.

    .venv/bin/python benchmarks/bench_acks.py                # ~40 s
    .venv/bin/python benchmarks/bench_acks.py --samples 10

1. One subscriber process and one publisher process on /sim/status's QoS, loopback DDS: the
   publisher sends ``--samples`` small messages 0.3 s apart and times each ``wait_for_all_acked``
   (bound 5 s): p50 / max per profile.
2. ``soil_launch --pacing lockstep`` of four 1 s episodes (sim + controller): wall time per
   profile (each episode_start waits for the acknowledgement of every /sim/status reader).
"""
from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from graph_procs import BIN  # sets loopback-only DDS

from soil_bringup.launch import add_domain_id_option, loopback_env

from soil_msgs_py.dds_profile import PROFILE_ENV_VARS, PROFILE_FILE, PROFILES_NAMESPACE

EMPTY_PROFILE_NAME = "empty_profile.xml"  # written in main's scratch directory, removed with it
CHILD = r"""
import sys, time, rclpy
from rclpy.duration import Duration
from rclpy.executors import ExternalShutdownException
from std_msgs.msg import String
from soil_msgs_py import graph as G
from soil_msgs_py.ros_adapter import topic_qos
rclpy.init()
node = rclpy.create_node("bench_acks_" + sys.argv[1])
qos = topic_qos(G.SIM_STATUS_TOPIC)
if sys.argv[1] == "sub":
    node.create_subscription(String, "/bench_acks", lambda m: None, qos)
    end = time.monotonic() + float(sys.argv[2])
    try:
        while time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.05)
    except (KeyboardInterrupt, ExternalShutdownException):  # stopped by the benchmark
        pass
else:
    pub = node.create_publisher(String, "/bench_acks", qos)
    end = time.monotonic() + 20
    while pub.get_subscription_count() < 1 and time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.05)
    time.sleep(1.0)
    for _ in range(int(sys.argv[2])):
        pub.publish(String(data="x"))
        t = time.perf_counter()
        ok = pub.wait_for_all_acked(Duration(seconds=5.0))
        print(f"{time.perf_counter() - t:.4f} {int(ok)}", flush=True)
        time.sleep(0.3)
"""


def env_for(profile: bool, domain: int, scratch: Path) -> dict[str, str]:
    env = {k: v for k, v in loopback_env(domain).items() if k not in PROFILE_ENV_VARS}
    if profile:
        env.update({name: str(PROFILE_FILE) for name in PROFILE_ENV_VARS})
    else:  # a profile file that sets nothing: Fast DDS's defaults (and use_graph_profile leaves it alone)
        env.update({name: str(scratch / EMPTY_PROFILE_NAME) for name in PROFILE_ENV_VARS})
    return env


def ack_waits(profile: bool, samples: int, domain: int, scratch: Path) -> list[tuple[float, bool]]:
    env = env_for(profile, domain, scratch)
    sub = subprocess.Popen([sys.executable, "-c", CHILD, "sub", str(samples * 6 + 25)], env=env)
    try:
        out = subprocess.run([sys.executable, "-c", CHILD, "pub", str(samples)], env=env, capture_output=True,
                             text=True, timeout=samples * 6 + 30)
    finally:
        sub.terminate()
        try:
            sub.wait(timeout=10)
        except subprocess.TimeoutExpired:
            sub.kill()
            sub.wait()
    rows = [line.split() for line in out.stdout.splitlines()]
    return [(float(r[0]), r[1] == "1") for r in rows if len(r) == 2 and r[1] in ("0", "1")]


def launch_seconds(profile: bool, domain: int, scratch: Path) -> float:
    """Wall time of a short lockstep launch; soil_launch's own --timeout stops its nodes on a hang."""
    t = time.perf_counter()
    res = subprocess.run([str(BIN / "soil_launch"), "--domain-id", str(domain), "--pacing", "lockstep",
                          "--sim-param", "duration_s:=1.0", "--sim-param", "episodes:=2",
                          "--sim-param", "sequence_soils:=['Clay','Sand']", "--timeout", "60"],
                         env=env_for(profile, domain, scratch), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    if res.returncode != 0:
        raise SystemExit(f"soil_launch exited {res.returncode}:\n{res.stdout[-3000:]}")
    return time.perf_counter() - t


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--samples", type=int, default=6)
    add_domain_id_option(p, 67)
    args = p.parse_args()
    rows = []
    print("(Fast DDS says 'Could not extract any profile' for the empty profile file that gives its defaults: expected)",
          flush=True)
    with tempfile.TemporaryDirectory(prefix="bench_acks_") as d:
        scratch = Path(d)
        (scratch / EMPTY_PROFILE_NAME).write_text(
            f'<?xml version="1.0" encoding="UTF-8"?>\n<profiles xmlns="{PROFILES_NAMESPACE}"/>\n')
        for profile in (False, True):
            waits = ack_waits(profile, args.samples, args.domain_id, scratch)
            secs = [w for w, _ in waits]
            rows.append(("the graph's profile (heartbeat 0.1 s)" if profile else "Fast DDS defaults (heartbeat 3 s)",
                         statistics.median(secs) if secs else float("nan"), max(secs, default=float("nan")),
                         sum(ok for _, ok in waits), len(waits), launch_seconds(profile, args.domain_id, scratch)))
    print("| writer timing | wait_for_all_acked p50 [s] | max [s] | acknowledged | 4 lockstep episodes of 1 s [s] |")
    print("|---|---|---|---|---|")
    for name, p50, top, ok, n, launch in rows:
        print(f"| {name} | {p50:.3f} | {top:.3f} | {ok}/{n} | {launch:.1f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
