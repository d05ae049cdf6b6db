"""Property-based tests of the controller's gain and target checks: any value is accepted in
range or refused with a ValueError naming the field (what the node turns into a rejected
``ros2 param set``), never another exception."""
from __future__ import annotations

import math

from hypothesis import given, settings
from hypothesis import strategies as st

from anti_stall_controller.controller import AntiStallController, AntiStallGains
from anti_stall_controller.node import GAIN_FIELDS, TARGET_FIELDS
from soil_msgs_py.params import MAX_TARGET_DEPTH_M, MAX_TARGET_SPEED_M_S

FUZZ = settings(max_examples=200, deadline=None, derandomize=True, database=None)
# What a ROS 2 parameter can hold: int64, double, string, bool, arrays.
value = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-(2**63), 2**63 - 1),
                  st.text(max_size=6), st.none(), st.booleans())


@FUZZ
@given(value, value, value)
def test_gains_are_accepted_in_range_or_named(k_v, c_vx, delta):
    try:
        gains = AntiStallGains(k_v_m_s=k_v, c_vx=c_vx, delta_d_max_m=delta)
    except ValueError as err:
        assert any(str(err).startswith(f) for f in GAIN_FIELDS), str(err)
        return
    assert all(math.isfinite(getattr(gains, f)) and getattr(gains, f) >= 0 for f in GAIN_FIELDS)


number = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-(2**63), 2**63 - 1))


@FUZZ
@given(number, number)  # declared as doubles: rclpy refuses a value of another type before the node sees it
def test_targets_are_accepted_in_range_or_named(speed, depth):
    try:
        ctrl = AntiStallController(AntiStallGains(), speed, depth)
    except ValueError as err:
        assert any(f in str(err) for f in TARGET_FIELDS), str(err)
        return
    assert 0 < ctrl.target_speed_m_s[0] <= MAX_TARGET_SPEED_M_S and 0 <= ctrl.target_depth_m[0] <= MAX_TARGET_DEPTH_M
