"""The controller node keeping step with the planner in lockstep (``plan_wait`` wired to DDS):
tick k is answered with the planner's target for tick k − 2 once it came; a planner that falls
silent holds one tick for ``planner_wait_s`` (warned), after which ticks are answered without
waiting, on the last target while it is fresh and then on the parameter's depth; a planner that
speaks again is waited for again. Real node process, real DDS on loopback, the probe playing the
simulator and the planner."""
from __future__ import annotations

import pytest
from std_msgs.msg import String

from soil_msgs_py import graph as G
from soil_msgs_py import messages as M
from soil_msgs_py import topics as T
from soil_msgs_py.episode import EpisodeMeta
from tests.anti_stall_controller.controller_probe import FIRST, send_until_answered, tick_stamp as _tick
from tests.ros_probe import NodeProc, RosProbe, next_domain_id

TWIST, POSE, BLADE = T.CHASSIS_TWIST.name, T.CHASSIS_POSE.name, T.BLADE_CMD.name
PARAM_DEPTH = 0.2  # the episode's target: the fallback
WAIT_S = 1.0  # planner_wait_s here


@pytest.mark.timeout(120)
def test_in_lockstep_a_tick_waits_for_its_plan_and_a_silent_planner_is_waited_for_once(tmp_path):
    domain = next_domain_id()
    classes = M.ros_message_classes()
    meta = EpisodeMeta("Clay", 40.0, "default", 3, 0.5, PARAM_DEPTH, 30.0, source="test")
    with RosProbe(domain) as probe:
        probe.subscribe(BLADE, T.BLADE_CMD.msgtype)
        status = probe.publisher(G.SIM_STATUS_TOPIC, G.STRING_MSGTYPE)
        twist = probe.publisher(TWIST, T.CHASSIS_TWIST.msgtype)
        pose = probe.publisher(POSE, T.CHASSIS_POSE.msgtype)
        target = probe.publisher(T.TARGET_DEPTH.name, T.TARGET_DEPTH.msgtype)
        ctl = NodeProc("anti_stall_controller", ["--ros-args", "-p", "depth_source:=planner",
                                                 "-p", "planner_timeout_s:=0.5", "-p", f"planner_wait_s:={WAIT_S}",
                                                 "-p", "planner_lag_ticks:=2"], domain, tmp_path)
        try:
            probe.wait_for(lambda: all(p.get_subscription_count() >= 1 for p in (status, twist, pose, target))
                           and probe.matched_publishers(BLADE) >= 1, 30, "controller endpoints")
            status.publish(String(data=G.EpisodeEvent(G.EVENT_EPISODE_START, 0, meta.name, meta, FIRST,
                                                      planned_ticks=1800, pacing=G.PACING_LOCKSTEP).to_json()))

            def u_za() -> dict[int, float]:
                return {s: v[1] for s, v in (M.parse_message(BLADE, m) for m in probe.messages(BLADE))}

            def send(k: int) -> None:
                twist.publish(M.build_message(classes, TWIST, _tick(k), [0.5, 0.0]))
                pose.publish(M.build_message(classes, POSE, _tick(k), [0.0, 0.0]))

            def tick(k: int) -> float:
                """One state tick at the target speed (no anti-stall offset); the answer's u_za."""
                send_until_answered(probe, lambda: send(k), lambda: _tick(k) in u_za(), f"the answer to tick {k}")
                return u_za()[_tick(k)]

            def answer(k: int) -> float:
                """The answer's u_za to tick k, sent already (not sent again: it is held, not lost)."""
                probe.wait_for(lambda: _tick(k) in u_za(), 20, f"the answer to tick {k}")
                return u_za()[_tick(k)]

            def plan(k: int, depth: float) -> None:
                target.publish(M.make_labelled(classes, _tick(k), T.TARGET_DEPTH_FIELDS, [depth, depth, 1.0]))

            # ticks 0 and 1 come before any plan can exist: answered at once, on the parameter
            assert [tick(0), tick(1)] == pytest.approx([-PARAM_DEPTH] * 2)
            plan(0, 0.12)
            plan(1, 0.12)
            assert [tick(2), tick(3)] == pytest.approx([-0.12] * 2)  # each on the plan of two ticks before
            # tick 4 is sent before the plan of tick 2 exists: it is held until that plan comes and cut
            # to it (answered at once, it would cut to tick 1's 0.12 m)
            send(4)
            plan(2, 0.15)
            assert answer(4) == pytest.approx(-0.15)
            # the planner falls silent: tick 5 (whose plan, tick 3's, never comes) is answered after
            # planner_wait_s on the newest target before it, still fresh ...
            assert tick(5) == pytest.approx(-0.15)
            # ... and later ticks do not wait; 0.5 s of ticks after the last plan its target is stale
            assert [tick(k) for k in range(6, 9)] == pytest.approx([-0.15] * 3)
            assert tick(33) == pytest.approx(-PARAM_DEPTH)
            # it speaks again: tick 34 cuts to the plan of tick 32, and tick 35, sent before the plan
            # of tick 33, waits for it again
            plan(32, 0.11)
            assert tick(34) == pytest.approx(-0.11)
            send(35)
            plan(33, 0.13)
            assert answer(35) == pytest.approx(-0.13)
        finally:
            ctl.stop()
        out = ctl.output
    assert "answered without its planner target" in out and "planner_wait_s" in out, out
    assert "Traceback" not in out, out
