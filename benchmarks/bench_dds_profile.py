"""What the graph's Fast DDS profile (soil_msgs_py/dds_profile.py) buys, side by side in one run
against Fast DDS's defaults and against the writer timing alone: how long a reliable writer waits
for its readers' acknowledgement, how long a node that starts late waits to be matched, and what
that makes of a short launch. Prints figures; asserts nothing.

    .venv/bin/python benchmarks/bench_dds_profile.py                # ~4 min
    .venv/bin/python benchmarks/bench_dds_profile.py --samples 10 --repeats 5

1. One subscriber process and one publisher process on /sim/status's QoS, loopback DDS: the
   publisher sends ``--samples`` small messages 0.3 s apart and times each ``wait_for_all_acked``
   (bound 5 s): p50 / max per profile.
2. Late joiners: six processes started 0.8 s apart, each with a node that publishes a latched
   topic and reads every other's; for each pair, the seconds from the later node's creation until
   both have heard each other: p50 / max over the 15 pairs of each of ``--repeats`` runs, and how
   many pairs took over a second. (The pairs of one run are not independent: a run where no pair
   waited for a periodic announcement happens, so the maximum needs several runs.)
3. ``soil_launch --pacing lockstep`` with the estimator and the planner, one 1 s episode: seconds
   from the start to the simulator's first episode (it waits for every node's endpoints) and to
   the launch's end, the mean of ``--repeats`` launches.
4. ``soil_launch --pacing lockstep`` of four 1 s episodes (sim + controller): wall time (each
   episode_start waits for the acknowledgement of every /sim/status reader).
"""
from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
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
node = rclpy.create_node("bench_dds_" + sys.argv[1])
qos = topic_qos(G.SIM_STATUS_TOPIC)
if sys.argv[1] == "sub":
    node.create_subscription(String, "/bench_dds", lambda m: None, qos)
    end = time.monotonic() + float(sys.argv[2])
    try:
        while time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.05)
    except (KeyboardInterrupt, ExternalShutdownException):  # stopped by the benchmark
        pass
else:
    pub = node.create_publisher(String, "/bench_dds", qos)
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


WRITER_ONLY_PROFILE_NAME = "writer_profile.xml"  # the graph's profile without its participant part
# the profiles compared: (what the table calls it, the file in main's scratch directory; None: the graph's own)
PROFILES = (("Fast DDS defaults (heartbeat 3 s, announcements 3 s)", EMPTY_PROFILE_NAME),
            ("writer heartbeat 0.1 s only (announcements 3 s)", WRITER_ONLY_PROFILE_NAME),
            ("the graph's profile (heartbeat 0.1 s, announcements 0.5 s)", None))
JOINERS = 6  # late-joiner processes, started JOIN_STAGGER_S apart
JOIN_STAGGER_S = 0.8
JOIN_WAIT_S = 15.0  # the most a joiner waits to hear the others


def write_scratch_profiles(scratch: Path) -> None:
    """The empty profile (Fast DDS's defaults) and the graph's profile with only its writer part."""
    ET.register_namespace("", PROFILES_NAMESPACE)
    (scratch / EMPTY_PROFILE_NAME).write_text(
        f'<?xml version="1.0" encoding="UTF-8"?>\n<profiles xmlns="{PROFILES_NAMESPACE}"/>\n')
    tree = ET.parse(PROFILE_FILE)
    root = tree.getroot()
    for participant in root.findall(f"{{{PROFILES_NAMESPACE}}}participant"):
        root.remove(participant)
    tree.write(scratch / WRITER_ONLY_PROFILE_NAME, encoding="UTF-8", xml_declaration=True)


def env_for(profile: str | None, domain: int, scratch: Path) -> dict[str, str]:
    """The environment of a run under ``profile`` (a scratch file's name; None: the graph's own)."""
    env = {k: v for k, v in loopback_env(domain).items() if k not in PROFILE_ENV_VARS}
    # a profile file of the benchmark's is the user's own to use_graph_profile, which leaves it alone
    env.update({name: str(PROFILE_FILE if profile is None else scratch / profile) for name in PROFILE_ENV_VARS})
    return env


JOINER = r"""
import sys, time, rclpy
from std_msgs.msg import String
from soil_msgs_py import graph as G
from soil_msgs_py.ros_adapter import topic_qos
me, n, wait_s = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3])
rclpy.init()
node = rclpy.create_node(f"bench_join_{me}")
print("created", time.time(), flush=True)
qos = topic_qos(G.ESTIMATOR_PHYSICS_TOPIC)  # latched: a late reader gets the sample
heard = {}
pub = node.create_publisher(String, f"/bench_join_{me}", qos)
pub.publish(String(data=str(me)))
for other in range(n):
    if other != me:
        node.create_subscription(String, f"/bench_join_{other}", lambda m, o=other: heard.setdefault(o, time.time()), qos)
end = time.monotonic() + wait_s
while len(heard) < n - 1 and time.monotonic() < end:
    rclpy.spin_once(node, timeout_sec=0.02)
print("heard", " ".join(f"{o}:{t}" for o, t in sorted(heard.items())), flush=True)
end = time.monotonic() + 2.0  # still there while the last ones hear it
while time.monotonic() < end:
    rclpy.spin_once(node, timeout_sec=0.05)
"""


def late_joiners(profile: str | None, domain: int, scratch: Path) -> list[float]:
    """Per pair of joiners, seconds from the later one's creation until both have heard each other
    (JOIN_WAIT_S where one never did)."""
    env = env_for(profile, domain, scratch)
    procs = []
    for me in range(JOINERS):
        procs.append(subprocess.Popen([sys.executable, "-c", JOINER, str(me), str(JOINERS), str(JOIN_WAIT_S)], env=env,
                                      stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True))
        time.sleep(JOIN_STAGGER_S)
    created, heard = {}, {}
    for me, proc in enumerate(procs):
        try:
            out, _ = proc.communicate(timeout=JOIN_WAIT_S + 30)
        except subprocess.TimeoutExpired:
            proc.kill()
            out, _ = proc.communicate()
        for line in out.splitlines():
            kind, _, rest = line.partition(" ")
            if kind == "created":
                created[me] = float(rest)
            elif kind == "heard":
                heard[me] = {int(o): float(t) for o, t in (item.split(":") for item in rest.split())}
    if missing := [me for me in range(JOINERS) if me not in created]:
        print(f"  (joiner(s) {missing} never made their node: their pairs are left out)", file=sys.stderr, flush=True)
    pairs = []
    for a in range(JOINERS):
        for b in range(a + 1, JOINERS):
            if a in created and b in created:
                later = max(created[a], created[b])
                both = max(heard.get(a, {}).get(b, later + JOIN_WAIT_S), heard.get(b, {}).get(a, later + JOIN_WAIT_S))
                pairs.append(both - later)
    return pairs


def first_episode_seconds(profile: str | None, domain: int, scratch: Path) -> tuple[float, float]:
    """(seconds to the first episode's start, to the launch's end) of a lockstep launch with the
    estimator and the planner, one 1 s episode; soil_launch's own --timeout stops a hang."""
    t = time.perf_counter()
    proc = subprocess.Popen([str(BIN / "soil_launch"), "--domain-id", str(domain), "--pacing", "lockstep",
                             "--estimator", "--planner", "--sim-param", "duration_s:=1.0", "--sim-param", "episodes:=1",
                             "--timeout", "90"], env=env_for(profile, domain, scratch), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    first, lines = float("nan"), []
    for line in proc.stdout:
        lines.append(line)
        if "episode 0 start" in line and first != first:
            first = time.perf_counter() - t
    if proc.wait() != 0:
        raise SystemExit(f"soil_launch exited {proc.returncode}:\n{''.join(lines)[-3000:]}")
    return first, time.perf_counter() - t


def ack_waits(profile: str | None, samples: int, domain: int, scratch: Path) -> list[tuple[float, bool]]:
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


def launch_seconds(profile: str | None, domain: int, scratch: Path) -> float:
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
    p.add_argument("--repeats", type=int, default=3, help="late-joiner runs and launches per profile (default 3)")
    add_domain_id_option(p, 67)
    args = p.parse_args()
    rows = []
    print("(Fast DDS says 'Could not extract any profile' for the empty profile file that gives its defaults: expected)",
          flush=True)
    with tempfile.TemporaryDirectory(prefix="bench_dds_") as d:
        scratch = Path(d)
        write_scratch_profiles(scratch)
        for name, profile in PROFILES:
            waits = ack_waits(profile, args.samples, args.domain_id, scratch)
            secs = [w for w, _ in waits]
            joins = [s for _ in range(args.repeats) for s in late_joiners(profile, args.domain_id, scratch)]
            starts = [first_episode_seconds(profile, args.domain_id, scratch) for _ in range(args.repeats)]
            rows.append((name, statistics.median(secs) if secs else float("nan"), max(secs, default=float("nan")),
                         sum(ok for _, ok in waits), len(waits), statistics.median(joins), max(joins),
                         sum(j > 1.0 for j in joins), len(joins),
                         statistics.mean(s[0] for s in starts), statistics.mean(s[1] for s in starts),
                         launch_seconds(profile, args.domain_id, scratch)))
            print(f"  {name}: done", flush=True)
    print("| profile | wait_for_all_acked p50 [s] | max [s] | acknowledged | late joiner matched p50 [s] | max [s] "
          "| pairs over 1 s | lockstep launch with estimator and planner: first episode [s] | end [s] "
          "| 4 lockstep episodes of 1 s [s] |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name, p50, top, ok, n, j50, jmax, slow, pairs, first, end, launch in rows:
        print(f"| {name} | {p50:.3f} | {top:.3f} | {ok}/{n} | {j50:.2f} | {jmax:.2f} | {slow}/{pairs} | {first:.1f} | "
              f"{end:.1f} | {launch:.1f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
