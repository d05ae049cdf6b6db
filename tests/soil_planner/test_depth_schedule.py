"""The depth schedule between the planner's plans and the controller's target: deeper slowly,
shallower fast, shallow before the first plan, hold then back off without one."""
from __future__ import annotations

import dataclasses
import math

import pytest

from soil_planner.depth_schedule import NS_PER_S, DepthSchedule, ScheduleSettings, follows_at_its_pace

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


def test_a_retreat_under_way_goes_on_to_the_newest_plan_when_plans_stop():
    """A plan that found the target too deep, then none: the hold had kept the target half-way up
    its retreat for the hold, and backed off only to the start depth, deeper than the plan (an
    outside reviewer's)."""
    cfg = ScheduleSettings(start_depth_m=0.1, deepen_rate_m_s=1.0, shallow_rate_m_s=1.0, hold_s=1.0)
    s = DepthSchedule(cfg)
    run(s, [0.25] * 30)
    assert run(s, [0.05], first_tick=30)[0] == pytest.approx(0.25 - 1.0 / 60)  # one tick up the retreat
    held = run(s, [None] * 120, first_tick=31)
    assert max(held) <= 0.25 - 1.0 / 60 and held[15] == pytest.approx(0.05)  # on up to the plan within the hold
    assert held[-1] == pytest.approx(0.05)  # backed off: never deeper than the newest plan (nor the start depth)


def test_a_gap_in_the_plans_backs_off_as_its_ticks_would_have_and_earns_no_deepening():
    """Estimates lost for 2 s mid-cut: the next plan had deepened the target by the whole gap's
    worth of the ramp at once (0.1 m/s x 2 s = 20 cm in one tick). Now the target is where the
    missing ticks would have left it, and the ramp resumes at its pace."""
    cfg = ScheduleSettings(start_depth_m=0.1, deepen_rate_m_s=0.1, shallow_rate_m_s=1.0, hold_s=1.0)
    s = DepthSchedule(cfg)
    before = run(s, [0.3] * 60)[-1]  # ramping: 0.1 -> ~0.2 m
    after = run(s, [0.3] * 2, first_tick=60 + 120)  # 2 s of ticks missing
    assert after[0] == pytest.approx(0.1 + 0.1 / 60)  # backed off to the start depth, then one tick of the ramp
    assert before > after[0] and after[1] - after[0] == pytest.approx(0.1 / 60)
    short = DepthSchedule(cfg)  # a gap within the hold: no back-off, and no deepening earned either
    ramped = run(short, [0.3] * 60)[-1]
    assert run(short, [0.3], first_tick=60 + 57)[0] == pytest.approx(ramped + 0.1 / 60)
    shallower = DepthSchedule(cfg)  # a gap, then a plan far shallower: risen to at once (a reviewer's)
    run(shallower, [0.3] * 200)
    assert run(shallower, [0.05], first_tick=200 + 62)[0] == pytest.approx(0.05)
    retreat = DepthSchedule(cfg)  # a gap, then a shallower plan: a retreat, deepened from cautiously after
    run(retreat, [0.3] * 250)
    run(retreat, [0.05] * 30, first_tick=250 + 63)
    after = run(retreat, [0.3] * 60, first_tick=250 + 93)
    assert retreat.cautious((250 + 93 + 59) * TICK) and after[-1] - after[0] == pytest.approx(0.03 * 59 / 60)
    slow = DepthSchedule(cfg)  # an estimator of one estimate every 1.5 s (stride 90): its pace, no gap
    paced = [slow.update(k * 90 * TICK, 0.3) for k in range(3)]
    assert paced == pytest.approx([0.1, 0.25, 0.3])


def test_after_a_retreat_the_target_deepens_at_the_cautious_rate_for_the_memory_then_at_full_rate():
    cfg = ScheduleSettings(start_depth_m=0.1, deepen_rate_m_s=0.12, shallow_rate_m_s=6.0, retreat_m=0.01,
                           retreat_memory_s=1.0, cautious_deepen_rate_m_s=0.03)
    s = DepthSchedule(cfg)
    first = run(s, [0.3] * 61)
    assert first[60] == pytest.approx(0.1 + 0.12)  # a fresh cut deepens at the full rate
    # the plan finds 0.22 m too deep: up at once, then down again at 3 cm/s, not 12
    back = run(s, [0.15] * 2 + [0.3] * 30, first_tick=61)
    assert back[1] == pytest.approx(0.15) and s.cautious(92 * TICK)
    assert back[-1] == pytest.approx(0.15 + 0.03 * 30 / 60)
    # a plan at most retreat_m shallower than the target is no retreat
    s2 = DepthSchedule(cfg)
    run(s2, [0.2] * 60)
    run(s2, [s2.target_m - 0.009] * 3, first_tick=60)
    assert not s2.cautious(63 * TICK)
    # a second after the retreat the memory has passed: the full rate again
    later = run(s, [0.3] * 61, first_tick=92)
    assert not s.cautious(152 * TICK)
    steps = [b - a for a, b in zip(later, later[1:])]
    assert steps[-1] == pytest.approx(0.12 / 60) and steps[0] == pytest.approx(0.03 / 60)
    # the start depth is no plan's: a plan below it, even after a few millimetres of the first
    # ramp, is no retreat; nor a plan below the shallowest target, where the target cannot go
    s4 = DepthSchedule(cfg)
    run(s4, [0.05] * 3)
    assert not s4.cautious(3 * TICK) and s4.target_m == pytest.approx(0.05)
    s5 = DepthSchedule(cfg)
    run(s5, [None, 0.3, 0.3, 0.3, 0.085])
    assert s5.target_m == pytest.approx(0.085) and not s5.cautious(5 * TICK)
    s6 = DepthSchedule(dataclasses.replace(cfg, min_depth_m=0.08))
    run(s6, [0.3] * 61)
    run(s6, [0.08] * 30 + [0.01] * 30, first_tick=61)
    assert s6.target_m == pytest.approx(0.08) and not s6.cautious(150 * TICK)  # the last retreat was at tick 62
    # backing off to the start depth without plans: the target is no plan's again
    s7 = DepthSchedule(dataclasses.replace(cfg, hold_s=0.1))
    run(s7, [0.3] * 61)
    run(s7, [None] * 60, first_tick=61)
    assert s7.target_m == pytest.approx(0.1) and not s7.deepened
    # no memory: a retreat changes nothing
    s3 = DepthSchedule(ScheduleSettings(start_depth_m=0.1, deepen_rate_m_s=0.12, shallow_rate_m_s=6.0,
                                        retreat_memory_s=0.0))
    run(s3, [0.3] * 61)
    again = run(s3, [0.15] * 2 + [0.3] * 30, first_tick=61)
    assert again[-1] == pytest.approx(0.15 + 0.12 * 30 / 60)


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
                                         ("hold_s", True), ("retreat_m", -0.01), ("retreat_memory_s", -1.0),
                                         ("cautious_deepen_rate_m_s", 0.0),
                                         ("cautious_deepen_rate_m_s", 0.5)])  # faster than deepen_rate_m_s 0.1: not cautious
def test_bad_settings_are_refused_naming_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        ScheduleSettings(**{field: value})


def test_a_floor_raised_at_run_time_is_reached_at_the_deepening_rate_a_ceiling_lowered_at_once():
    """``min_target_m`` raised by a parameter change while plans keep the target shallow: the clamp
    had taken the target to the new floor in one tick (5 -> 25 cm, an outside reviewer's)."""
    cfg = ScheduleSettings(start_depth_m=0.1, deepen_rate_m_s=0.1, shallow_rate_m_s=1.0, min_depth_m=0.05)
    s = DepthSchedule(cfg)
    run(s, [0.05] * 30)
    assert s.target_m == pytest.approx(0.05)
    s.settings = dataclasses.replace(cfg, min_depth_m=0.25, start_depth_m=0.25)
    ramp = run(s, [0.05] * 121, first_tick=30)
    assert ramp[0] == pytest.approx(0.05 + 0.1 / 60) and ramp[60] == pytest.approx(0.05 + 0.1 * 61 / 60)
    assert ramp[-1] == pytest.approx(0.25)
    s.settings = dataclasses.replace(cfg, max_depth_m=0.15)
    assert run(s, [0.3], first_tick=151)[0] == pytest.approx(0.15)


def test_a_tick_following_a_jump_at_its_spacing_is_the_estimators_pace_and_a_time_jump_is_not():
    s = NS_PER_S
    assert follows_at_its_pace(0, 2 * s, 4 * s)  # a stride of 2 s
    assert follows_at_its_pace(0, 2 * s, 3 * s) and follows_at_its_pace(0, 2 * s, 6 * s)  # an estimate lost
    assert not follows_at_its_pace(0, 10 * s, 10 * s + s // 60)  # time jumped ahead, ticks at 60 Hz from there
    assert not follows_at_its_pace(10 * s, 2 * s, 4 * s)  # time went back: a new cut, not a pace
    assert not follows_at_its_pace(0, 3600 * s, 7200 * s)  # two strays an hour apart: rarer than any stride
