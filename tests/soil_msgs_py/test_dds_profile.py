"""The graph's Fast DDS profile: every node process loads it unless its user chose their own,
and it is a profile Fast DDS reads (a reliable writer's acknowledgements come back). What it
buys, how fast acknowledgements come and a node started late is matched, is measured, not
asserted: benchmarks/bench_dds_profile.py."""
from __future__ import annotations

import subprocess
import sys
import xml.etree.ElementTree as ET

import pytest

from soil_msgs_py.dds_profile import PROFILE_ENV_VARS, PROFILE_FILE, PROFILES_NAMESPACE, use_graph_profile
from tests.ros_domains import next_domain_id
from tests.ros_probe import loopback_env

pytestmark = pytest.mark.live

NS = {"f": PROFILES_NAMESPACE}


def _seconds(period) -> float:
    return int(period.find("f:sec", NS).text) + int(period.find("f:nanosec", NS).text) * 1e-9


def test_the_profile_sets_only_a_writers_heartbeat_and_a_participants_announcements():
    """A default writer's heartbeat every 0.1 s; a default participant's announcements every 0.5 s
    after its first five 0.1 s apart; nothing else (lease durations stay Fast DDS's 20 s)."""
    root = ET.parse(PROFILE_FILE).getroot()
    (writer,) = root.findall("f:data_writer", NS)
    (participant,) = root.findall("f:participant", NS)
    assert len(root) == 2 and all(p.get("is_default_profile") == "true" for p in (writer, participant))
    assert len(writer) == 1 and _seconds(writer.find("f:times/f:heartbeatPeriod", NS)) == 0.1
    (rtps,) = participant
    (builtin,) = rtps
    (discovery,) = builtin
    tags = [f"{{{PROFILES_NAMESPACE}}}{name}" for name in ("rtps", "builtin", "discovery_config")]
    assert [rtps.tag, builtin.tag, discovery.tag] == tags and len(discovery) == 2
    assert _seconds(discovery.find("f:leaseAnnouncement", NS)) == 0.5
    initial = discovery.find("f:initialAnnouncements", NS)
    assert int(initial.find("f:count", NS).text) == 5 and _seconds(initial.find("f:period", NS)) == 0.1


def test_use_graph_profile_sets_both_names_and_leaves_a_users_own_profiles_alone():
    env = {}
    assert use_graph_profile(env) and env == {name: str(PROFILE_FILE) for name in PROFILE_ENV_VARS}
    for name in PROFILE_ENV_VARS:  # a user's file under either name: theirs under both (Fast DDS 2 and 3)
        mine = {name: "/etc/my_profiles.xml"}
        assert not use_graph_profile(mine) and mine == {n: "/etc/my_profiles.xml" for n in PROFILE_ENV_VARS}
    both = {PROFILE_ENV_VARS[0]: "/etc/a.xml", PROFILE_ENV_VARS[1]: "/etc/b.xml"}
    assert not use_graph_profile(both) and both == {PROFILE_ENV_VARS[0]: "/etc/a.xml", PROFILE_ENV_VARS[1]: "/etc/b.xml"}
    blank = {PROFILE_ENV_VARS[0]: ""}  # set but empty: not a choice
    assert use_graph_profile(blank) and blank[PROFILE_ENV_VARS[0]] == str(PROFILE_FILE)


CHILD = r"""
import sys, time, rclpy
from rclpy.duration import Duration
from std_msgs.msg import String
from soil_msgs_py import graph as G
from soil_msgs_py.ros_adapter import init_rclpy, topic_qos
from soil_msgs_py.dds_profile import PROFILE_ENV_VARS
import os
init_rclpy([], lambda *a: None)  # what every node's entry point calls
print("profile", os.environ[PROFILE_ENV_VARS[0]], flush=True)
node = rclpy.create_node("ack_" + sys.argv[1])
if sys.argv[1] == "sub":
    got = []
    def on_msg(m):
        got.append(m.data)
        print("got", m.data, flush=True)
    node.create_subscription(String, "/ack_test", on_msg, topic_qos(G.SIM_STATUS_TOPIC))
    end = time.monotonic() + 60  # only a hang ends here
    while len(got) < 3 and time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.05)
    time.sleep(1.0)  # (still acknowledging) while the publisher waits for the last acknowledgement
else:
    pub = node.create_publisher(String, "/ack_test", topic_qos(G.SIM_STATUS_TOPIC))
    end = time.monotonic() + 30
    while pub.get_subscription_count() < 1 and time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.05)
    for i in range(3):
        pub.publish(String(data=str(i)))
        print("acked", pub.wait_for_all_acked(Duration(seconds=10.0)), flush=True)
"""


def test_a_node_process_loads_the_profile_and_its_writer_is_acknowledged(tmp_path):
    """Two processes as nodes start (``init_rclpy``), nothing set by the caller: both run with the
    graph's profile, Fast DDS parses it without an error (it would print one and run on with its
    own 3 s timing), and each of the publisher's samples is acknowledged by the subscriber. (How
    fast: benchmarks/bench_dds_profile.py.)"""
    domain = next_domain_id()
    env = {k: v for k, v in loopback_env(domain).items() if k not in PROFILE_ENV_VARS}
    sub = subprocess.Popen([sys.executable, "-c", CHILD, "sub"], env=env, stdout=subprocess.PIPE,
                           stderr=subprocess.STDOUT, text=True)
    try:
        pub = subprocess.run([sys.executable, "-c", CHILD, "pub"], env=env, capture_output=True, text=True, timeout=90)
        out, _ = sub.communicate(timeout=90)
    finally:
        sub.kill()
        sub.wait()
    assert pub.returncode == 0, pub.stderr[-2000:]
    assert "XMLPARSER" not in pub.stdout + pub.stderr + out, pub.stdout + pub.stderr + out
    lines = pub.stdout.splitlines()
    assert f"profile {PROFILE_FILE}" in lines and f"profile {PROFILE_FILE}" in out.splitlines()
    assert [line for line in lines if line.startswith("acked")] == ["acked True"] * 3, pub.stdout
    assert [line for line in out.splitlines() if line.startswith("got")] == ["got 0", "got 1", "got 2"], out
