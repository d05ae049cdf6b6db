"""The controller node with ``depth_source:=planner``: its target depth follows
/planner/target_depth over real DDS, falls back to its parameter when the planner's target is
stale or absent (a deeper one at the fallback's rate, a shallower one at once), and ignores a
target that is no depth."""
from __future__ import annotations

import contextlib

import pytest
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient

from soil_msgs_py.episode import EpisodeMeta
from tests.anti_stall_controller.controller_probe import PlannerSide
from tests.ros_probe import call_service, RosProbe, next_domain_id

pytestmark = pytest.mark.live

PARAM_DEPTH = 0.2  # the episode's target: the fallback


@contextlib.contextmanager
def clay_cut(tmp_path, args=()):
    """A controller (``PlannerSide``) in a started 30 s clay episode of target depth PARAM_DEPTH:
    (probe, side, meta); the controller stopped after (its output: ``side.ctl.output``)."""
    domain = next_domain_id()
    meta = EpisodeMeta("Clay", 40.0, "fee", 3, 0.5, PARAM_DEPTH, 30.0, source="test")
    with RosProbe(domain) as probe:
        side = PlannerSide(probe, list(args), domain, tmp_path)
        try:
            side.start(meta)
            yield probe, side, meta
        finally:
            side.stop()


@pytest.mark.timeout(120)
def test_controller_follows_the_planners_target_and_falls_back_when_it_is_stale(tmp_path):
    with clay_cut(tmp_path, ["-p", "planner_timeout_s:=0.5"]) as (probe, side, meta):
        tick, plan = side.tick, side.plan

        def until(depth: float, first: int) -> int:
            """Ticks from ``first`` on until one is answered at ``depth`` (topics are not
            ordered with each other: the target may reach the node a tick later)."""
            for k in range(first, first + 10):
                if tick(k) == pytest.approx(-depth):
                    return k
            raise AssertionError(f"u_za never reached {-depth} m: {sorted(side.u_za().items())[-10:]}")

        assert tick(0) == pytest.approx(-PARAM_DEPTH)  # no planner target yet: the parameter
        plan(1, 0.12)
        k = until(0.12, 1)
        plan(k, float("nan"))  # no depth: ignored, the last target holds
        plan(k, 0.9)  # deeper than the blade: ignored
        assert [tick(k + i) for i in (1, 2, 3)] == pytest.approx([-0.12] * 3)
        # 0.5 s of ticks (30) after the plan's stamp it is stale: on the way back to the parameter,
        # deeper than the plan at most 0.03 m/s (it had plunged 8 cm in one tick into soil the
        # planner had ruled out), 28 ticks after the last answered one
        assert tick(k + 31) == pytest.approx(-(0.12 + 0.03 * 28 / 60), abs=1e-6)
        assert tick(k + 91) == pytest.approx(-(0.12 + 0.03 * 88 / 60), abs=1e-6)
        # a target set at run time on the way does not jump the ramp to the fallback (it had, a reviewer found)
        client = AsyncParameterClient(probe.node, "anti_stall_controller")
        assert client.wait_for_services(timeout_sec=20)
        ok = call_service(lambda: client.set_parameters([Parameter("target_speed_m_s", value=0.5)]))
        assert all(r.successful for r in ok.results)
        assert tick(k + 92) == pytest.approx(-(0.12 + 0.03 * 89 / 60), abs=1e-6)
        plan(k + 93, 0.25)
        k = until(0.25, k + 93)
        plan(k, 0.24)  # a second target for one stamp: a second planner on the domain, said
        assert tick(k + 31) == pytest.approx(-PARAM_DEPTH)  # a shallower fallback: at once
        k += 31
        # switched back to its parameter at run time: the next tick cuts to 0.2 m again, and
        # a changed target speed does not make the planner's depth the parameter's
        bad = call_service(lambda: client.set_parameters([Parameter("depth_source", value="map")]))
        assert not bad.results[0].successful and "depth_source='map'" in bad.results[0].reason
        ok = call_service(lambda: client.set_parameters([Parameter("depth_source", value="parameter"),
                                          Parameter("target_speed_m_s", value=0.5)]))
        assert all(r.successful for r in ok.results)
        plan(k + 1, 0.11)
        assert tick(k + 2) == pytest.approx(-PARAM_DEPTH)
    out = side.ctl.output
    assert "following the planner's target depth" in out and "no planner target within 0.5 s" in out, out
    assert "target_depth_m=nan" in out and "target_depth_m=0.9" in out, out
    assert "two targets for stamp" in out and "(0.2500 m, then 0.2400 m): is a second planner" in out, out


@pytest.mark.timeout(120)
def test_switched_from_the_planner_to_its_parameter_a_deeper_depth_is_ramped_to(tmp_path):
    """depth_source planner -> parameter at run time while the plan held the cut at 0.12 m: the
    parameter's 0.2 m had been taken in one tick, 8 cm into soil the planner had ruled out (an
    outside reviewer's); now the fallback's rate takes it there, as from a silent planner."""
    with clay_cut(tmp_path) as (probe, side, meta):
        tick, plan = side.tick, side.plan
        plan(0, 0.12)
        k = next(k for k in range(0, 10) if tick(k) == pytest.approx(-0.12))
        client = AsyncParameterClient(probe.node, "anti_stall_controller")
        assert client.wait_for_services(timeout_sec=20)
        ok = call_service(lambda: client.set_parameters([Parameter("depth_source", value="parameter")]))
        assert all(r.successful for r in ok.results)
        assert tick(k + 1) == pytest.approx(-(0.12 + 0.03 / 60), abs=1e-9)  # one tick of 0.03 m/s deeper
        assert tick(k + 61) == pytest.approx(-(0.12 + 0.03 * 61 / 60), abs=1e-9)


@pytest.mark.timeout(120)
def test_controller_says_when_the_simulators_state_stops_mid_episode_and_when_it_comes_back(tmp_path):
    """A killed simulator left the controller (and the estimator and planner) up and silent: now
    it says, after 5 s without state in an episode, and again when the state comes back."""
    import time

    with clay_cut(tmp_path) as (probe, side, meta):
        side.tick(0)
        deadline = time.monotonic() + 30
        while "no state from the simulator for" not in side.ctl.output and time.monotonic() < deadline:
            time.sleep(0.2)
        side.tick(1)
        while "state from the simulator again after" not in side.ctl.output and time.monotonic() < deadline:
            time.sleep(0.2)
    out = side.ctl.output
    assert f"in episode {meta.name}: has its publisher stopped?" in out, out[-3000:]
    assert out.index("no state from the simulator for") < out.index("state from the simulator again after"), out[-3000:]
