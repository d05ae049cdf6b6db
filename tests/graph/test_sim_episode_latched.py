"""/sim/episode: a node that joins mid-cut learns the episode under way (its soil patches, its
graph id), which /sim/status, VOLATILE, said before it joined (an outside planner author's node
started 8 s into a cut had no way to know the patches); once the episode ended, a latecomer is
sent its end alone, the newest event, with the same metadata."""
from __future__ import annotations

import json
import time

import pytest
from std_msgs.msg import String

from soil_msgs_py import graph as G
from tests.ros_probe import NodeProc, RosProbe, next_domain_id

pytestmark = [pytest.mark.live, pytest.mark.timeout(120)]

PATCHES = ["0:Sand:40", "1.5:Clay:60"]


def _events(probe: RosProbe, topic: str) -> list[G.EpisodeEvent]:
    return [G.EpisodeEvent.from_json(m.data) for m in probe.messages(topic)]


def _said(probe: RosProbe, event: str):
    return lambda: [e for e in _events(probe, G.SIM_STATUS_TOPIC) if e.event == event] or None


def test_a_node_joining_mid_cut_learns_the_episode_and_after_its_end_only_the_end(tmp_path):
    domain = next_domain_id()
    # an episode far longer than the test: it ends when the test resets it, however slow the machine
    params = ["episodes:=1", "duration_s:=600.0", "graph_id:=cut_a", "wait_for:=['/sim/status:1']",
              "patches:=[" + ",".join(f"'{p}'" for p in PATCHES) + "]"]
    args = ["--ros-args", *[a for p in params for a in ("-p", p)]]
    with RosProbe(domain, "status_reader") as status:
        status.subscribe(G.SIM_STATUS_TOPIC, G.STRING_MSGTYPE)
        cmd = status.publisher(G.SIM_COMMAND_TOPIC, G.STRING_MSGTYPE)
        sim = NodeProc("soil_sim_node", args, domain, tmp_path)
        try:
            (start,) = status.wait_for(_said(status, G.EVENT_EPISODE_START), 60, "episode_start")
            with RosProbe(domain, "late_planner") as late:  # joins after the start went out
                late.subscribe(G.SIM_EPISODE_TOPIC, G.STRING_MSGTYPE)
                (mid,) = late.wait_for(lambda: _events(late, G.SIM_EPISODE_TOPIC) or None, 30, "the latched episode")
                status.wait_for(lambda: cmd.get_subscription_count() > 0, 30, "the simulator's /sim/command reader")
                sent = [-1.0]

                def ended_by_a_reset():  # said again each second until heard (our writer may match first)
                    if time.monotonic() - sent[0] > 1.0:
                        cmd.publish(String(data=json.dumps({"action": "reset"})))
                        sent[0] = time.monotonic()
                    return _said(status, G.EVENT_EPISODE_END)()

                (ended,) = status.wait_for(ended_by_a_reset, 30, "episode_end")
                late.wait_for(lambda: len(late.messages(G.SIM_EPISODE_TOPIC)) == 2 or None, 30, "the end, latched too")
            with RosProbe(domain, "after_the_cut") as after:
                after.subscribe(G.SIM_EPISODE_TOPIC, G.STRING_MSGTYPE)
                after.wait_for(lambda: after.messages(G.SIM_EPISODE_TOPIC) or None, 30, "the latched end")
                time.sleep(0.5)  # anything older would come with it
                afterwards = _events(after, G.SIM_EPISODE_TOPIC)
        finally:
            sim.stop()
    assert mid.event == G.EVENT_EPISODE_START and mid == start
    assert [f"{p['x_start_m']:g}:{p['soil']}:{p['relative_density_pct']:g}" for p in mid.meta.patches] == PATCHES
    assert mid.graph == "cut_a"
    (end,) = afterwards  # the newest event alone: the writer keeps one
    assert end == ended and end.reason == "reset" and end.meta == start.meta
