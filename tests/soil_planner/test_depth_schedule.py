"""The depth schedule between the planner's plans and the controller's target: deeper slowly,
shallower fast, shallow before the first plan, hold then back off without one."""
from __future__ import annotations

import math

import pytest

from soil_planner.depth_schedule import NS_PER_S, DepthSchedule, ScheduleSettings

TICK = NS_PER_S // 60


def run(schedule: DepthSchedule, plans, first_tick: int = 0) -> list[float]:
    return [schedule.update((first_tick + k) * TICK, p) for k, p in enumerate(plans)]


def test_before_any_plan_the_target_is_the_start_depth():
    s = DepthSchedule(ScheduleSettings(start_depth_m=0.08))
    assert run(s, [None] * 30) == [0.08] * 30 and not s.plan_valid


def test_deepening_is_rate_limited_and_rising_is_fast():
    cfg = ScheduleSettings(start_depth_m=0.1, deepen_rate_m_s=0.06, shallow_rate_m_s=0.6)
    s = DepthSchedule(cfg)
    deeper = run(s, [0.3] * 61)
    assert deeper[0] == pytest.approx(0.1)  # the first plan: no time has passed yet
    assert deeper[60] == pytest.approx(0.1 + 0.06)  # one second later: 6 cm deeper, not 20
    assert all(b - a <= 0.06 / 60 + 1e-12 for a, b in zip(deeper, deeper[1:]))
    rising = run(s, [0.05] * 30, first_tick=61)
    assert rising[-1] == pytest.approx(0.05)  # 11 cm up within half a second (0.6 m/s)
    assert rising[1] - rising[0] == pytest.approx(-0.01)  # a tick's worth of 0.6 m/s
    assert s.plan_valid


def test_without_a_plan_the_target_holds_then_backs_off_to_the_start_depth():
    cfg = ScheduleSettings(start_depth_m=0.1, deepen_rate_m_s=1.0, shallow_rate_m_s=0.3, hold_s=0.5)
    s = DepthSchedule(cfg)
    run(s, [0.25] * 20)
    assert s.target_m == pytest.approx(0.25)
    held = run(s, [None] * 30, first_tick=20)
    assert held == pytest.approx([0.25] * 30) and not s.plan_valid
    backing = run(s, [None] * 60, first_tick=50)
    assert backing[-1] == pytest.approx(0.1) and backing[5] < 0.25


def test_never_deeper_than_max_nor_shallower_than_min_and_non_finite_is_no_plan():
    s = DepthSchedule(ScheduleSettings(min_depth_m=0.03, max_depth_m=0.2, deepen_rate_m_s=10.0, shallow_rate_m_s=10.0))
    assert max(run(s, [0.6] * 30)) == pytest.approx(0.2)
    assert run(s, [0.0] * 30, first_tick=30)[-1] == pytest.approx(0.03)
    assert run(s, [math.nan], first_tick=60) == pytest.approx([0.03]) and not s.plan_valid


def test_a_stamp_that_goes_back_is_a_new_cut():
    s = DepthSchedule(ScheduleSettings(start_depth_m=0.1, deepen_rate_m_s=1.0))
    run(s, [0.25] * 30, first_tick=100)
    assert s.update(0, None) == pytest.approx(0.1)


@pytest.mark.parametrize("field,value", [("deepen_rate_m_s", 0.0), ("shallow_rate_m_s", -1.0), ("hold_s", -0.1),
                                         ("start_depth_m", 0.5), ("max_depth_m", 0.9), ("min_depth_m", math.nan),
                                         ("hold_s", True)])
def test_bad_settings_are_refused_naming_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        ScheduleSettings(**{field: value})
