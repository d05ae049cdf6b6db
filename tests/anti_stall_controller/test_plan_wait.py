"""``plan_wait``: in lockstep the controller answers tick k once the planner's target for tick
k − lag came, in stamp order, and cuts to that target (not a newer one that raced in)."""
from __future__ import annotations

import pytest

from anti_stall_controller.plan_wait import MAX_LAG_TICKS, PlanWait
from soil_msgs_py import graph as G
from soil_msgs_py.params import tick_stamp_ns as stamp_ns


def test_a_tick_waits_for_the_target_of_its_tick_minus_lag_and_ticks_leave_in_order():
    wait = PlanWait(lag_ticks=2, wait_s=5.0)
    wait.start_episode(stamp_ns(0), lockstep=True)
    assert wait.offer(stamp_ns(0), "t0", 0.0) == (["t0"], 0)  # no plan can exist before tick 2
    assert wait.offer(stamp_ns(1), "t1", 0.0) == (["t1"], 0)
    assert wait.offer(stamp_ns(2), "t2", 0.0) == ([], 0)  # needs the target of tick 0
    assert wait.offer(stamp_ns(3), "t3", 0.0) == ([], 0)
    wait.note_target(stamp_ns(0), 0.10)
    assert wait.release(0.1) == (["t2"], 0)  # t3 needs tick 1's
    wait.note_target(stamp_ns(1), 0.11)
    wait.note_target(stamp_ns(2), 0.12)
    assert wait.release(0.1) == (["t3"], 0)
    assert wait.target_for(stamp_ns(3)) == (stamp_ns(1), 0.11)  # tick 3 cuts to tick 1's plan, not tick 2's
    assert wait.target_for(stamp_ns(4)) == (stamp_ns(2), 0.12)


def test_a_silent_planner_holds_one_tick_wait_s_then_none_until_it_speaks_again():
    wait = PlanWait(lag_ticks=2, wait_s=1.0)
    wait.start_episode(stamp_ns(100), lockstep=True)
    answered = [item for k in range(100, 106) for item in wait.offer(stamp_ns(k), k, 10.0)[0]]
    assert answered == [100, 101]  # the first two need no plan
    assert wait.release(10.5) == ([], 0)
    assert wait.release(11.5) == ([102, 103, 104, 105], 1)  # one waited; then the planner counts as silent
    assert wait.target_for(stamp_ns(105)) is None
    assert wait.offer(stamp_ns(106), 106, 11.6) == ([106], 0)  # silent: no wait
    wait.note_target(stamp_ns(105), 0.2)  # it speaks again: ticks wait again
    assert wait.offer(stamp_ns(108), 108, 11.7) == ([], 0)  # it needs tick 106's target


def test_a_tick_that_timed_out_when_the_next_came_is_counted_late():
    wait = PlanWait(lag_ticks=2, wait_s=1.0)
    wait.start_episode(stamp_ns(0), lockstep=True)
    for k in range(3):
        wait.offer(stamp_ns(k), k, 0.0)  # tick 2 waits for tick 0's plan
    assert wait.offer(stamp_ns(3), 3, 1.5) == ([2, 3], 1)  # the caller warns: the planner is silent


def test_outside_lockstep_or_with_lag_0_nothing_waits_and_the_newest_target_counts():
    for lockstep, lag in ((False, 2), (True, 0)):
        wait = PlanWait(lag_ticks=lag)
        wait.start_episode(0, lockstep=lockstep)
        wait.note_target(stamp_ns(7), 0.2)
        wait.note_target(stamp_ns(5), 0.1)  # an older one arriving late does not win
        assert wait.offer(stamp_ns(9), "x", 0.0) == (["x"], 0)
        assert wait.target_for(stamp_ns(9)) == (stamp_ns(7), 0.2)
        wait.note_target(stamp_ns(10**6), 0.3)  # a stray stamped far ahead does not become the plan
        assert wait.target_for(stamp_ns(9)) == (stamp_ns(7), 0.2)


def test_a_stray_target_stamped_ahead_does_not_release_ticks_without_their_plan():
    wait = PlanWait(lag_ticks=2, wait_s=5.0)
    wait.start_episode(stamp_ns(0), lockstep=True)
    wait.note_target(stamp_ns(10**6), 0.3)  # (another node, a restarted simulator's stamps)
    for k in range(5):
        wait.offer(stamp_ns(k), k, 0.0)
    assert wait.release(0.1) == ([], 0) and [s for s, _, _ in wait.pending] == [stamp_ns(2), stamp_ns(3), stamp_ns(4)]
    wait.note_target(stamp_ns(0), 0.1)
    assert wait.release(0.1) == ([2], 0)
    assert wait.target_for(stamp_ns(2)) == (stamp_ns(0), 0.1)


def test_a_plan_for_a_tick_whose_state_has_not_come_yet_is_kept_for_when_it_does():
    wait = PlanWait(lag_ticks=2, wait_s=5.0)
    wait.start_episode(stamp_ns(0), lockstep=True)
    for k in range(3):
        wait.offer(stamp_ns(k), k, 0.0)
    wait.note_target(stamp_ns(3), 0.2)  # overtook tick 3's state: not yet a plan tick 2 may use
    assert wait.release(0.1) == ([], 0)
    wait.note_target(stamp_ns(0), 0.1)
    assert wait.release(0.1) == ([2], 0)
    assert wait.offer(stamp_ns(3), 3, 0.2) == ([3], 0)  # its state came: tick 3's plan is genuine
    assert wait.target_for(stamp_ns(3)) == (stamp_ns(0), 0.1)  # (it cuts to the newest plan lag ticks back)
    assert wait.target_for(stamp_ns(5)) == (stamp_ns(3), 0.2)


def test_a_target_stamped_before_the_episode_is_ignored():
    wait = PlanWait()
    wait.start_episode(stamp_ns(600), lockstep=True)
    assert wait.note_target(stamp_ns(599), 0.3) is False and wait.target_for(stamp_ns(700)) is None
    assert wait.note_target(stamp_ns(600), 0.2) is True


def test_drain_hands_back_every_held_tick_in_order():
    wait = PlanWait()
    wait.start_episode(0, lockstep=True)
    for k in (4, 5, 6):
        wait.offer(stamp_ns(k), k, 0.0)
    assert wait.drain() == [4, 5, 6] and not wait.pending


def test_a_new_episode_forgets_held_ticks_and_targets():
    wait = PlanWait()
    wait.start_episode(0, lockstep=True)
    wait.offer(stamp_ns(5), "old", 0.0)
    wait.note_target(stamp_ns(1), 0.3)
    assert wait.start_episode(stamp_ns(600), lockstep=True) == ["old"]
    assert not wait.pending and wait.target_for(stamp_ns(700)) is None


def test_an_ended_episode_keeps_its_targets_for_its_last_ticks_and_the_next_keeps_only_its_own():
    """After an episode_end, the episode's last ticks still to come (a controller behind) cut to its
    planner's targets, not the fallback depth (they had been cleared, a reviewer's); nothing waits.
    A target of the next episode come before its start is kept there; where time goes back (a
    replay started over) none is."""
    wait = PlanWait()
    wait.start_episode(stamp_ns(0), lockstep=True)
    wait.offer(stamp_ns(10), "held", 0.0)
    for k in range(8):
        wait.note_target(stamp_ns(k), 0.05)
    assert wait.end_episode() == ["held"] and not wait.active
    assert wait.note_target(stamp_ns(11), 0.06)  # a late target of the ended episode
    assert wait.target_for(stamp_ns(12)) == (stamp_ns(11), 0.06)
    assert wait.offer(stamp_ns(12), "late", 0.0)[0] == ["late"]  # nothing waits
    wait.note_target(stamp_ns(600), 0.2)  # the next episode's, come before its start
    wait.start_episode(stamp_ns(600), lockstep=True)
    assert list(wait.targets) == [stamp_ns(600)]
    wait.start_episode(stamp_ns(0), lockstep=True)  # time went back
    assert not wait.targets


@pytest.mark.parametrize("lag, wait_s, needle", [(-1, 1.0, "planner_lag_ticks"), (1.5, 1.0, "planner_lag_ticks"),
                                                 (True, 1.0, "planner_lag_ticks"), (2, 0.0, "planner_wait_s"),
                                                 (2, float("nan"), "planner_wait_s"),
                                                 (MAX_LAG_TICKS + 1, 1.0, "planner_lag_ticks")])
def test_bad_settings_are_refused_naming_the_parameter(lag, wait_s, needle):
    with pytest.raises(ValueError, match=needle):
        PlanWait(lag, wait_s)


def test_a_lag_longer_than_the_planner_timeout_is_refused_naming_both():
    with pytest.raises(ValueError, match="planner_lag_ticks=61 .*planner_timeout_s=1.0"):
        PlanWait(61, 1.0, timeout_s=1.0)
    assert PlanWait(60, 1.0, timeout_s=1.0).lag_ticks == 60


def test_episode_start_says_the_simulators_pacing_and_a_bad_one_is_refused():
    from soil_msgs_py.episode import EpisodeMeta
    meta = EpisodeMeta(soil="Clay", relative_density_pct=50.0, world_mode="fee", seed=1, target_speed_m_s=0.5,
                       target_depth_m=0.1, duration_s=1.0)
    event = G.EpisodeEvent(G.EVENT_EPISODE_START, 0, meta.name, meta, 0, planned_ticks=60, pacing=G.PACING_LOCKSTEP)
    assert G.EpisodeEvent.from_json(event.to_json()).pacing == "lockstep"
    with pytest.raises(ValueError, match="pacing='sometimes' is not one of"):
        G.EpisodeEvent.from_json(event.to_json().replace('"lockstep"', '"sometimes"'))
    assert G.EpisodeEvent.from_json(event.to_json().replace(', "pacing": "lockstep"', "")).pacing == ""  # (a replay's)


def test_a_silent_planners_fallback_is_taken_at_once_upward_and_at_its_rate_downward():
    from anti_stall_controller.planner_fallback import check_rate, fallback_depth

    assert fallback_depth(0.12, 0.2, 0.5, 0.03) == pytest.approx(0.135)
    assert fallback_depth(0.19, 0.2, 1.0, 0.03) == 0.2  # never past it
    assert fallback_depth(0.25, 0.2, 0.0, 0.03) == 0.2  # shallower: at once
    assert fallback_depth(0.12, 0.2, -1.0, 0.03) == 0.12  # a stamp going back moves nothing
    for bad in (0.0, -0.1, float("nan"), float("inf"), 11.0, True, "0.1"):
        with pytest.raises(ValueError, match="fallback_deepen_rate_m_s="):
            check_rate(bad)


def test_the_depth_source_and_planner_timeout_are_checked_naming_the_parameter():
    from anti_stall_controller.planner_fallback import check_depth_source

    assert check_depth_source("planner", 1.0) == ("planner", 1_000_000_000)
    assert check_depth_source("parameter", 3600) == ("parameter", 3_600_000_000_000)  # the graph's longest wait
    with pytest.raises(ValueError, match="depth_source='estimator' must be one of"):
        check_depth_source("estimator", 1.0)
    for bad in (0.0, -1.0, 3600.5, float("nan"), float("inf"), True, "1"):
        with pytest.raises(ValueError, match=r"planner_timeout_s=.* must be a number of seconds in \(0, 3600\]"):
            check_depth_source("planner", bad)
