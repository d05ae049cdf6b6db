"""A simulator starts an episode once its own endpoints have matched; the matches between two
other nodes it cannot see. So the controller (following the planner) and the planner join the
simulator's topics only once the other nodes' writers they read have matched, and a simulator
waiting for them waits for those matches too: on a loaded machine the planner's first targets
once went out before its writer had matched the controller's reader, and a lockstep tick waited
``planner_wait_s`` for them."""
from __future__ import annotations

import time

import pytest

from soil_msgs_py import graph as G
from soil_msgs_py import topics as T
from tests.ros_probe import NodeProc, RosProbe, next_domain_id, wait_until

pytestmark = pytest.mark.live


@pytest.mark.timeout(240)
def test_the_controller_and_the_planner_join_the_simulators_topics_once_the_writers_they_read_matched(tmp_path):
    domain = next_domain_id()
    with RosProbe(domain) as probe:
        status = probe.publisher(G.SIM_STATUS_TOPIC, G.STRING_MSGTYPE)
        twist = probe.publisher(T.CHASSIS_TWIST.name, T.CHASSIS_TWIST.msgtype)  # the controller's state
        known = probe.publisher(T.KNOWN.name, T.KNOWN.msgtype)  # the planner's Θ_k
        controller = NodeProc("anti_stall_controller", ["--ros-args", "-p", "depth_source:=planner",
                                                        "-p", "inputs_wait_s:=600.0"], domain, tmp_path)
        planner = None
        try:
            wait_until(lambda: status.get_subscription_count() >= 1, 60, "the controller's /sim/status reader")
            time.sleep(1.0)
            assert twist.get_subscription_count() == 0, controller.output  # no planner yet
            planner = NodeProc("soil_planner", ["--ros-args", "-p", "inputs_wait_s:=600.0"], domain, tmp_path)
            wait_until(lambda: twist.get_subscription_count() >= 1, 60,
                       "the controller's state reader once the planner's target writer matched")
            wait_until(lambda: status.get_subscription_count() >= 2, 60, "the planner's /sim/status reader")
            time.sleep(1.0)
            # the controller's /blade/cmd writer is there, the estimator's /soil/estimate not yet
            assert known.get_subscription_count() == 0, planner.output
            probe.publisher(T.ESTIMATE.name, T.ESTIMATE.msgtype)
            wait_until(lambda: known.get_subscription_count() >= 1, 60, "the planner's Θ_k reader")
        finally:
            assert controller.stop() == 0, controller.output
            if planner is not None:
                assert planner.stop() == 0, planner.output
        assert "without a publisher of" not in controller.output + planner.output
    domain = next_domain_id()
    with RosProbe(domain) as probe:  # no planner ever: the controller joins after inputs_wait_s, and says so
        twist = probe.publisher(T.CHASSIS_TWIST.name, T.CHASSIS_TWIST.msgtype)
        alone = NodeProc("anti_stall_controller", ["--ros-args", "-p", "depth_source:=planner",
                                                   "-p", "inputs_wait_s:=1.0"], domain, tmp_path)
        try:
            wait_until(lambda: twist.get_subscription_count() >= 1, 60, "the state reader after inputs_wait_s")
        finally:
            alone.stop()
        assert "without a publisher of" in alone.output and T.TARGET_DEPTH.name in alone.output, alone.output


@pytest.mark.timeout(180)
def test_the_recorder_joins_the_simulators_topics_once_the_controllers_writers_matched(tmp_path):
    """A bag must hold the first ticks' commands too: the recorder subscribes to the simulator's
    topics only once the controller's command writers have matched (or after --inputs-wait)."""
    domain = next_domain_id()
    with RosProbe(domain) as probe:
        status = probe.publisher(G.SIM_STATUS_TOPIC, G.STRING_MSGTYPE)
        twist = probe.publisher(T.CHASSIS_TWIST.name, T.CHASSIS_TWIST.msgtype)
        recorder = NodeProc("soil_bag_record", ["--out", str(tmp_path / "bags"), "--inputs-wait", "600"],
                            domain, tmp_path)
        try:
            wait_until(lambda: status.get_subscription_count() >= 1, 60, "the recorder's /sim/status reader")
            probe.publisher(T.BLADE_CMD.name, T.BLADE_CMD.msgtype)
            time.sleep(1.0)
            assert twist.get_subscription_count() == 0, recorder.output  # /chassis/cmd_vel has no writer yet
            probe.publisher(T.CMD_VEL.name, T.CMD_VEL.msgtype)
            wait_until(lambda: twist.get_subscription_count() >= 1, 60, "the recorder's state reader")
        finally:
            assert recorder.stop() == 0, recorder.output
        assert "without a publisher of" not in recorder.output, recorder.output
