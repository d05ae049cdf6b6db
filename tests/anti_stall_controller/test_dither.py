"""Depth dither of the anti-stall controller (controller.py, item 4): A sin(2π t / T) on the
target depth, off by default; validated like every gain."""
from __future__ import annotations

import math
import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from anti_stall_controller.controller import AntiStallController, AntiStallGains
from anti_stall_controller.node import GAIN_FIELDS, PARAMETERS
from soil_msgs_py.params import SAMPLE_RATE_HZ

pytestmark = pytest.mark.live

DT = 1.0 / SAMPLE_RATE_HZ


def commands(ctrl, v, pz, n):
    return np.array([[*(c[0] for c in ctrl.step(v[k], pz[k]))] for k in range(n)])  # (n, 3) u_zr, u_za, u_x


def test_dither_is_off_by_default_and_eq12_is_unchanged():
    g = AntiStallGains()
    assert (g.dither_amplitude_m, g.dither_period_s) == (0.0, 2.0)
    assert PARAMETERS["dither_amplitude_m"][0] == 0.0 and PARAMETERS["dither_period_s"][0] == 2.0
    rng = np.random.default_rng(0)
    v, pz = rng.uniform(0.0, 0.8, 300), rng.uniform(-0.3, 0.05, 300)
    ctrl = AntiStallController(g, 0.5, 0.2)
    offsets = []
    for k in range(300):
        u_za = ctrl.step(v[k], pz[k]).u_za[0]
        offsets.append(ctrl.depth_offset_m[0])
        assert u_za == -(0.2 - offsets[-1])  # Eq. 12 to the bit
    assert max(offsets) > 0.02  # the anti-stall action did act
    other_period = AntiStallController(AntiStallGains(dither_period_s=0.7), 0.5, 0.2)
    np.testing.assert_array_equal(commands(other_period, v, pz, 300),
                                  commands(AntiStallController(g, 0.5, 0.2), v, pz, 300))


def test_dither_sweeps_the_depth_target_and_restarts_with_each_episode():
    amplitude, period = 0.04, 1.5
    ctrl = AntiStallController(AntiStallGains(dither_amplitude_m=amplitude, dither_period_s=period), 0.5, 0.2)
    n = 3 * SAMPLE_RATE_HZ
    first = commands(ctrl, np.full(n, 0.5), np.zeros(n), n)  # on speed: no anti-stall offset
    t = np.arange(n) * DT
    np.testing.assert_allclose(first[:, 1], -(0.2 + amplitude * np.sin(2 * np.pi * t / period)), rtol=0, atol=1e-15)
    assert first[:, 1].max() - first[:, 1].min() == pytest.approx(2 * amplitude, rel=1e-3)
    ctrl.reset()
    np.testing.assert_array_equal(commands(ctrl, np.full(n, 0.5), np.zeros(n), n), first)
    ctrl.set_gains(dither_amplitude_m=0.0)  # switched off at run time
    assert ctrl.step(0.5, 0.0).u_za[0] == -0.2


def test_under_a_planners_ceiling_the_dither_sweeps_below_the_target_never_deeper():
    """A planner's target is the deepest cut within the force limits: a dither around it had cut A
    deeper than the plan (an outside reviewer's). Below it, the sweep keeps its 2A."""
    amplitude, period = 0.05, 1.0
    ctrl = AntiStallController(AntiStallGains(dither_amplitude_m=amplitude, dither_period_s=period), 0.5, 0.15)
    ctrl.dither_below_target = True  # (the node's with depth_source planner, the cut trial's soil-aware policy)
    n = 2 * SAMPLE_RATE_HZ
    depth = -commands(ctrl, np.full(n, 0.5), np.zeros(n), n)[:, 1]
    assert depth.max() <= 0.15 + 1e-12 and depth.max() == pytest.approx(0.15)
    assert depth.max() - depth.min() == pytest.approx(2 * amplitude, rel=1e-3)


@pytest.mark.parametrize("field, value, allowed", [
    ("dither_amplitude_m", -0.01, "[0, 0.1]"), ("dither_amplitude_m", math.nan, "[0, 0.1]"),
    ("dither_amplitude_m", math.inf, "[0, 0.1]"), ("dither_amplitude_m", "x", "[0, 0.1]"),
    ("dither_amplitude_m", 0.5, "[0, 0.1]"),  # a dither is a few cm: 0.5 m was taken
    ("dither_period_s", 0.0, "(0, inf)"), ("dither_period_s", -2.0, "(0, inf)"), ("dither_period_s", math.inf, "(0, inf)"),
])
def test_bad_dither_parameters_are_refused_naming_them(field, value, allowed):
    assert field in GAIN_FIELDS  # node parameters, validated and applied at run time like the gains
    with pytest.raises(ValueError, match=rf"{field} must be a finite number in {re.escape(allowed)}; got {re.escape(repr(value))}"):
        AntiStallGains(**{field: value})
    ctrl = AntiStallController(AntiStallGains(dither_amplitude_m=0.03), 0.5, 0.2)
    with pytest.raises(ValueError, match=field):
        ctrl.set_gains(**{field: value})
    assert ctrl.gains.dither_amplitude_m == 0.03  # a refused change leaves everything as it was


value = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-(2**63), 2**63 - 1),
                  st.text(max_size=6), st.none(), st.booleans())


@settings(max_examples=200, deadline=None, derandomize=True, database=None)
@given(value, value)
def test_dither_parameters_are_accepted_in_range_or_named(amplitude, period):
    try:
        gains = AntiStallGains(dither_amplitude_m=amplitude, dither_period_s=period)
    except ValueError as err:
        assert str(err).startswith(("dither_amplitude_m", "dither_period_s")), str(err)
        return
    assert math.isfinite(gains.dither_amplitude_m) and gains.dither_amplitude_m >= 0
    assert math.isfinite(gains.dither_period_s) and gains.dither_period_s > 0
    ctrl = AntiStallController(gains, 0.5, 0.2)
    assert all(np.isfinite(c[0]) for c in ctrl.step(0.3, 0.0))


def test_bad_dither_node_parameter_is_refused_at_start(tmp_path):
    from tests.ros_probe import NodeProc, next_domain_id

    node = NodeProc("anti_stall_controller", ["--ros-args", "-p", "dither_period_s:=0.0"], next_domain_id(), tmp_path)
    try:
        assert node.wait(timeout=60) == 2, node.output
    finally:
        node.stop()
    assert "cannot start" in node.output and "dither_period_s must be a finite number in (0, inf); got 0.0" in node.output


def test_a_dither_of_fewer_than_ten_ticks_a_period_is_refused():
    """Sampled at 60 Hz, a sinusoid of 2 ticks is 0 at every tick and one of 3 steps 1.7 A from tick
    to tick: no sweep of the depth (1e-9 s was accepted, and the blade command jumped 4-9 cm)."""
    from anti_stall_controller.controller import MIN_DITHER_TICKS

    dt = 1.0 / SAMPLE_RATE_HZ
    period = MIN_DITHER_TICKS * dt
    gains = AntiStallGains(dither_amplitude_m=0.03, dither_period_s=period)
    steps = np.diff([gains.dither_amplitude_m * math.sin(2 * math.pi * k * dt / period) for k in range(3 * MIN_DITHER_TICKS)])
    assert np.abs(steps).max() <= 2 * math.pi / MIN_DITHER_TICKS * 0.03 + 1e-12  # a sweep: at most 0.63 A a tick
    for bad in (1e-9, 2 * dt, 3 * dt, 0.99 * period):
        with pytest.raises(ValueError, match=rf"dither_period_s=.* must be at least {MIN_DITHER_TICKS} control periods"):
            AntiStallGains(dither_period_s=bad)
