"""A second graph on the simulator's domain: two launches on one domain had cut each other's bags
short and mixed their state, both ending in 0. The simulator finds another simulator's (or a bag
player's) /sim/status writer before its first episode, names it, starts none and exits with
EXIT_ANOTHER_GRAPH. (A writer of another name changes nothing: tests/graph/test_hostile_node.py.)"""
from __future__ import annotations

import pytest

from soil_msgs_py import graph as G
from tests.ros_probe import NodeProc, RosProbe, next_domain_id

pytestmark = pytest.mark.live


@pytest.mark.timeout(120)
def test_a_simulator_on_a_domain_with_another_graph_starts_no_episode(tmp_path):
    domain = next_domain_id()
    with RosProbe(domain, name="soil_sim_node") as probe:  # another launch's simulator
        probe.publisher(G.SIM_STATUS_TOPIC, G.STRING_MSGTYPE)  # another simulator's (or a player's) writer
        probe.subscribe(G.SIM_STATUS_TOPIC, G.STRING_MSGTYPE)  # what the simulator waits for: discovered by then
        sim = NodeProc("soil_sim_node", ["--ros-args", "-p", "duration_s:=1.0", "-p", "wait_timeout_s:=30.0",
                                         "-p", f"wait_for:=['{G.SIM_STATUS_TOPIC}:1']"], domain, tmp_path)
        try:
            code = sim.wait(90)
        finally:
            sim.stop()
        assert code == G.EXIT_ANOTHER_GRAPH, sim.output[-2000:]
        assert "1 other simulator(s) or bag player(s) publish /sim/status on ROS_DOMAIN_ID" in sim.output, sim.output
        assert "starting no episode" in sim.output
        assert not [m for m in probe.messages(G.SIM_STATUS_TOPIC) if "episode_start" in m.data]
