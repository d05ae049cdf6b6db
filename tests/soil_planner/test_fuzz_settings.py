"""Property-based tests of the planner's settings checks: any value is accepted in range or
refused with a ValueError naming the setting, never another exception."""
from __future__ import annotations

import math

import pytest

from hypothesis import given, settings
from hypothesis import strategies as st

from soil_planner.node import MAX_LOG_PERIOD_S, check_log_period
from soil_planner.planner import CUT_SPEED_LIMIT_M_S, D_MAX_LIMIT_M, check_settings

FUZZ = settings(max_examples=200, deadline=None, derandomize=True, database=None)
# What a ROS 2 parameter can hold: int64, double, string, bool, arrays.
value = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-(2**63), 2**63 - 1),
                  st.text(max_size=6), st.none(), st.booleans(), st.lists(st.floats(), max_size=2))


@FUZZ
@given(value, value, value)
def test_check_settings_accepts_in_range_or_names_the_setting(margin, d_max, speed):
    try:
        m, d, v = check_settings(margin, d_max, speed)
    except ValueError as err:
        assert str(err).split("=")[0] in ("margin", "d_max_m", "cut_speed_m_s"), str(err)
        return
    assert 0 < m <= 1 and 0 < d <= D_MAX_LIMIT_M and 0 < v <= CUT_SPEED_LIMIT_M_S


@FUZZ
@given(value)
def test_log_period_accepts_finite_non_negative_or_names_it(period):
    try:
        p = check_log_period(period)
    except ValueError as err:
        assert str(err).startswith("log_period_s="), str(err)
        return
    assert math.isfinite(p) and p >= 0


def test_a_log_period_too_long_for_the_nanosecond_count_is_refused():
    """1e300 s had passed as finite and overflowed int(period · 1e9): the node died at start and on
    a run-time set (an outside tester's finding)."""
    for period in (1e300, MAX_LOG_PERIOD_S * 2, math.inf):
        with pytest.raises(ValueError, match=r"log_period_s=.* must be a number in \[0, 86400\] s"):
            check_log_period(period)
    assert check_log_period(MAX_LOG_PERIOD_S) == MAX_LOG_PERIOD_S and check_log_period(0) == 0.0
