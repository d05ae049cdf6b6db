"""The controller node with ``depth_source:=planner``: its target depth follows
/planner/target_depth over real DDS, falls back to its parameter when the planner's target is
stale or absent, and ignores a target that is no depth."""
from __future__ import annotations

import pytest
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from std_msgs.msg import String

from soil_msgs_py import graph as G
from soil_msgs_py import messages as M
from soil_msgs_py import topics as T
from soil_msgs_py.episode import EpisodeMeta
from tests.anti_stall_controller.controller_probe import FIRST, send_until_answered, tick_stamp as _tick
from tests.ros_probe import call_service, NodeProc, RosProbe, next_domain_id, wait_until

TWIST, POSE, BLADE = T.CHASSIS_TWIST.name, T.CHASSIS_POSE.name, T.BLADE_CMD.name
PARAM_DEPTH = 0.2  # the episode's target: the fallback


@pytest.mark.timeout(120)
def test_controller_follows_the_planners_target_and_falls_back_when_it_is_stale(tmp_path):
    domain = next_domain_id()
    classes = M.ros_message_classes()
    meta = EpisodeMeta("Clay", 40.0, "fee", 3, 0.5, PARAM_DEPTH, 30.0, source="test")
    with RosProbe(domain) as probe:
        probe.subscribe(BLADE, T.BLADE_CMD.msgtype)
        status = probe.publisher(G.SIM_STATUS_TOPIC, G.STRING_MSGTYPE)
        twist = probe.publisher(TWIST, T.CHASSIS_TWIST.msgtype)
        pose = probe.publisher(POSE, T.CHASSIS_POSE.msgtype)
        target = probe.publisher(T.TARGET_DEPTH.name, T.TARGET_DEPTH.msgtype)
        ctl = NodeProc("anti_stall_controller", ["--ros-args", "-p", "depth_source:=planner",
                                                 "-p", "planner_timeout_s:=0.5"], domain, tmp_path)
        try:
            probe.wait_for(lambda: all(p.get_subscription_count() >= 1 for p in (status, twist, pose, target))
                           and probe.matched_publishers(BLADE) >= 1, 30, "controller endpoints")
            status.publish(String(data=G.EpisodeEvent(G.EVENT_EPISODE_START, 0, meta.name, meta, FIRST,
                                                      planned_ticks=1800).to_json()))

            def u_za() -> dict[int, float]:
                return {s: v[1] for s, v in (M.parse_message(BLADE, m) for m in probe.messages(BLADE))}

            def tick(k: int) -> float:
                """One state tick at the target speed (no anti-stall offset); the answer's u_za."""
                def send() -> None:
                    twist.publish(M.build_message(classes, TWIST, _tick(k), [0.5, 0.0]))
                    pose.publish(M.build_message(classes, POSE, _tick(k), [0.0, 0.0]))

                send_until_answered(probe, send, lambda: _tick(k) in u_za(), f"the answer to tick {k}")
                return u_za()[_tick(k)]

            def plan(k: int, depth: float) -> None:
                target.publish(M.make_labelled(classes, _tick(k), T.TARGET_DEPTH_FIELDS, [depth, depth, 1.0]))

            def until(depth: float, first: int) -> int:
                """Ticks from ``first`` on until one is answered at ``depth`` (topics are not
                ordered with each other: the target may reach the node a tick later)."""
                for k in range(first, first + 10):
                    if tick(k) == pytest.approx(-depth):
                        return k
                raise AssertionError(f"u_za never reached {-depth} m: {sorted(u_za().items())[-10:]}")

            assert tick(0) == pytest.approx(-PARAM_DEPTH)  # no planner target yet: the parameter
            plan(1, 0.12)
            k = until(0.12, 1)
            plan(k, float("nan"))  # no depth: ignored, the last target holds
            plan(k, 0.9)  # deeper than the blade: ignored
            assert [tick(k + i) for i in (1, 2, 3)] == pytest.approx([-0.12] * 3)
            # 0.5 s of ticks (30) after the plan's stamp it is stale: back to the parameter
            assert tick(k + 31) == pytest.approx(-PARAM_DEPTH)
            plan(k + 32, 0.25)
            k = until(0.25, k + 32)
            # switched back to its parameter at run time: the next tick cuts to 0.2 m again, and
            # a changed target speed does not make the planner's depth the parameter's
            client = AsyncParameterClient(probe.node, "anti_stall_controller")
            assert client.wait_for_services(timeout_sec=20)
            bad = call_service(lambda: client.set_parameters([Parameter("depth_source", value="map")]))
            assert not bad.results[0].successful and "depth_source='map'" in bad.results[0].reason
            ok = call_service(lambda: client.set_parameters([Parameter("depth_source", value="parameter"),
                                              Parameter("target_speed_m_s", value=0.5)]))
            assert all(r.successful for r in ok.results)
            plan(k + 1, 0.11)
            assert tick(k + 2) == pytest.approx(-PARAM_DEPTH)
        finally:
            ctl.stop()
        out = ctl.output
    assert "following the planner's target depth" in out and "no planner target within 0.5 s" in out, out
    assert "target_depth_m=nan" in out and "target_depth_m=0.9" in out, out
