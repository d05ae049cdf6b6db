"""The controller node keeping step with the planner in lockstep (``plan_wait`` wired to DDS):
tick k is answered with the planner's target for tick k − 2 once it came; a planner that falls
silent holds one tick for ``planner_wait_s`` (warned), after which ticks are answered without
waiting, on the last target while it is fresh and then on the parameter's depth; a planner that
speaks again is waited for again; a switch of ``depth_source`` away from the planner answers the
tick held for it at once. Real node process, real DDS on loopback, the probe playing the
simulator and the planner."""
from __future__ import annotations

import pytest
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient

from soil_msgs_py import graph as G
from soil_msgs_py.episode import EpisodeMeta
from tests.anti_stall_controller.controller_probe import PlannerSide
from tests.ros_probe import call_service, RosProbe, next_domain_id

pytestmark = pytest.mark.live

PARAM_DEPTH = 0.2  # the episode's target: the fallback
WAIT_S = 3.0  # the controller's planner_wait_s [s of wall time] in the lockstep test


@pytest.mark.timeout(120)
def test_in_lockstep_a_tick_waits_for_its_plan_and_a_silent_planner_is_waited_for_once(tmp_path):
    domain = next_domain_id()
    meta = EpisodeMeta("Clay", 40.0, "default", 3, 0.5, PARAM_DEPTH, 30.0, source="test")
    with RosProbe(domain) as probe:
        # planner_wait_s is wall time: a plan sent right after its tick must reach the node within it
        # on a loaded machine too (at 1 s a delivery slowed by load could release a held tick on the old target)
        side = PlannerSide(probe, ["-p", "planner_timeout_s:=0.5", "-p", f"planner_wait_s:={WAIT_S}",
                                   "-p", "planner_lag_ticks:=2"], domain, tmp_path)
        try:
            side.start(meta, pacing=G.PACING_LOCKSTEP)
            tick, send, answer, plan = side.tick, side.send, side.answer, side.plan
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
            send(5)  # not tick(5): that would send it again while it is held
            assert answer(5) == pytest.approx(-0.15)
            # ... and later ticks do not wait; 0.5 s of ticks after the last plan its target is stale
            assert [tick(k) for k in range(6, 9)] == pytest.approx([-0.15] * 3)
            # (the parameter's deeper depth, from the plan's at most 0.03 m/s: 25 ticks after tick 8)
            assert tick(33) == pytest.approx(-(0.15 + 0.03 * 25 / 60), abs=1e-6)
            # it speaks again (plans of ticks 32-40): once its target is in, each tick cuts to the
            # plan of two ticks before (a tick that comes before the first target is not held: the
            # planner was silent) ...
            for j in range(32, 41):
                plan(j, 0.11)
            k = next((k for k in range(34, 43) if tick(k) == pytest.approx(-0.11)), None)
            assert k is not None, sorted(side.u_za().items())[-10:]
            assert [tick(j) for j in range(k + 1, 43)] == pytest.approx([-0.11] * (42 - k))
            # ... and a tick sent before its plan waits for it again
            send(43)
            plan(41, 0.13)
            assert answer(43) == pytest.approx(-0.13)
        finally:
            out = side.stop()
    assert "answered without its planner target" in out and "planner_wait_s" in out, out
    assert "Traceback" not in out, out


@pytest.mark.timeout(120)
def test_a_switch_away_from_the_planner_answers_the_tick_held_for_it_at_once(tmp_path):
    """In lockstep no next tick comes to release a held one: the switch itself must answer it, on
    the way to the parameter's depth, a tick of the fallback rate deeper than the plan's (before,
    it waited out planner_wait_s, here 60 s, and was then warned about as a silent planner's)."""
    domain = next_domain_id()
    meta = EpisodeMeta("Clay", 40.0, "default", 3, 0.5, PARAM_DEPTH, 30.0, source="test")
    with RosProbe(domain) as probe:
        side = PlannerSide(probe, ["-p", "planner_wait_s:=60.0", "-p", "planner_lag_ticks:=2"], domain, tmp_path)
        try:
            side.start(meta, pacing=G.PACING_LOCKSTEP)
            assert [side.tick(0), side.tick(1)] == pytest.approx([-PARAM_DEPTH] * 2)
            plan_depth = 0.12
            side.plan(0, plan_depth)
            assert side.tick(2) == pytest.approx(-plan_depth)
            side.send(3)  # held: tick 1's plan never comes
            client = AsyncParameterClient(probe.node, "anti_stall_controller")
            assert client.wait_for_services(timeout_sec=20)
            ok = call_service(lambda: client.set_parameters([Parameter("depth_source", value="parameter")]))
            assert all(r.successful for r in ok.results)
            # within 20 s, not after planner_wait_s; 0.03 m/s deeper than the plan, not the parameter's at once
            assert side.answer(3) == pytest.approx(-(plan_depth + 0.03 / 60), abs=1e-9)
        finally:
            out = side.stop()
    assert "answered without its planner target" not in out, out
    assert "Traceback" not in out, out
