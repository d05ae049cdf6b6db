"""The simulator node's pacing core (soil_sim_node.pacing) without ROS, on a fake clock:
when a tick is stepped, how long it waits for commands, late commands, the lockstep
watchdog, episode starts and the timing figures."""
from __future__ import annotations

import pytest

from soil_sim_node.pacing import COMMAND_GRACE, HOLD_S, HOUSEKEEPING_PERIOD_S, STALL_WARN_S, Do, Pacer, StartWait


class FakeClock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


@pytest.fixture
def clock():
    return FakeClock()


def running(pacing: str, clock: FakeClock, rate: float = 1.0, timeout_s: float = 10.0) -> Pacer:
    pacer = Pacer(pacing, rate, timeout_s, clock=clock)
    pacer.start_episode()
    pacer.published()  # tick 0
    return pacer


def test_periods_follow_pacing_rate_and_whether_an_episode_runs(clock):
    pacer = Pacer("realtime", 2.0, 10.0, clock=clock)
    assert pacer.period_s == HOUSEKEEPING_PERIOD_S, "idle: the timer only checks for starts"
    pacer.start_episode()
    assert pacer.period_s == pytest.approx(1 / 120) and pacer.grace_s == pytest.approx(COMMAND_GRACE / 120)
    assert pacer.timing.nominal_period_s == pytest.approx(1 / 120)
    pacer.set_rate(0.5)
    assert pacer.period_s == pytest.approx(1 / 30) and pacer.timing.nominal_period_s == pytest.approx(1 / 30)
    pacer.end_episode()
    assert pacer.period_s == HOUSEKEEPING_PERIOD_S
    lockstep = running("lockstep", clock)
    assert lockstep.period_s == HOUSEKEEPING_PERIOD_S and lockstep.timing.nominal_period_s == 0.0


@pytest.mark.parametrize("pacing, rate, needle", [("sometimes", 1.0, "pacing='sometimes'"),
                                                  ("realtime", 0.001, r"rate=0.001 outside \[0.01, 1000\]"),
                                                  ("lockstep", 2000.0, "rate=2000.0")])
def test_bad_pacing_or_rate_is_named(pacing, rate, needle):
    with pytest.raises(ValueError, match=needle):
        Pacer(pacing, rate, 10.0)


def test_realtime_commands_in_before_the_timer_are_stepped_by_the_timer(clock):
    pacer = running("realtime", clock)
    clock.t += 0.004
    assert pacer.on_commands(complete=False) is Do.NOTHING
    assert pacer.on_commands(complete=True) is Do.NOTHING, "early: the timer keeps the 60 Hz grid"
    assert pacer.on_timer(commands_complete=True) is Do.STEP
    assert list(pacer.timing.loop_latencies) == [pytest.approx(0.004)] and pacer.timing.late_commands == 0


def test_realtime_commands_just_after_the_timer_are_waited_for(clock):
    pacer = running("realtime", clock)
    assert pacer.on_timer(commands_complete=False) is Do.WAIT_GRACE
    assert pacer.on_timer(commands_complete=False) is Do.NOTHING, "the grace timer is already armed"
    clock.t += 0.018
    assert pacer.on_commands(complete=True) is Do.STEP
    assert pacer.on_grace() is Do.NOTHING, "answered in time: nothing is late"
    assert pacer.timing.late_commands == 0 and list(pacer.timing.loop_latencies) == [pytest.approx(0.018)]


def test_realtime_commands_later_than_the_grace_are_held_and_counted_late(clock):
    pacer = running("realtime", clock)
    assert pacer.on_timer(commands_complete=False) is Do.WAIT_GRACE
    assert pacer.on_grace() is Do.STEP and pacer.timing.late_commands == 1
    pacer.published()  # tick 1 goes out with tick 0's commands held
    clock.t += 0.002
    assert pacer.on_commands(complete=True) is Do.NOTHING  # tick 1's, early
    stats = pacer.end_episode()
    assert stats["late_commands"] == 1 and stats["loop_latency"]["n"] == 1, "each tick answered in time or late"
    assert list(pacer.timing.loop_latencies) == [pytest.approx(0.002)]


def test_restarted_timers_drop_a_pending_grace(clock):
    pacer = running("realtime", clock)
    assert pacer.on_timer(commands_complete=False) is Do.WAIT_GRACE
    pacer.timers_restarted()  # e.g. the rate changed
    assert pacer.on_grace() is Do.NOTHING and pacer.timing.late_commands == 0
    assert pacer.on_timer(commands_complete=False) is Do.WAIT_GRACE


def test_lockstep_steps_on_every_complete_command_set_and_the_timer_only_on_one_held_back(clock):
    """The node holds a completion back when a command in it is implausible (an intruder's copy
    the controller's own may still replace); the housekeeping timer then steps it."""
    pacer = running("lockstep", clock)
    for k in range(3):
        clock.t += 0.5
        assert pacer.on_timer(commands_complete=False) is Do.NOTHING
        assert pacer.on_commands(complete=True) is Do.STEP
        pacer.published()
    clock.t += 0.5
    pacer.hold()  # the node holds the completion back
    assert pacer.on_commands(complete=False) is Do.NOTHING
    clock.t += 0.4 * HOLD_S  # the timer may fire at once: the hold still lasts HOLD_S
    assert pacer.on_timer(commands_complete=True) is Do.NOTHING
    clock.t += 0.6 * HOLD_S
    assert pacer.on_timer(commands_complete=True) is Do.STEP
    pacer.published()
    assert list(pacer.timing.loop_latencies) == [pytest.approx(0.5)] * 3 + [pytest.approx(0.5 + HOLD_S)]
    clock.t += 0.5  # the next tick holds nothing: the timer alone never steps it
    assert pacer.on_timer(commands_complete=False) is Do.NOTHING
    pacer.hold()
    assert pacer.on_commands(complete=True) is Do.STEP  # the controller's own command came: at once
    pacer.published()
    stats = pacer.end_episode()
    assert "jitter" not in stats and stats["period"]["n"] == 5 and stats["late_commands"] == 0


def test_lockstep_watchdog_reports_a_stall_then_ends_the_episode(clock):
    pacer = running("lockstep", clock, timeout_s=1.5)
    clock.t += STALL_WARN_S
    assert pacer.on_timer(commands_complete=False) is Do.NOTHING
    clock.t += 0.01
    assert pacer.on_timer(commands_complete=False) is Do.STALLED
    pacer.lockstep_timeout_s = 1.5  # (a run-time parameter)
    clock.t += 0.5
    assert pacer.on_timer(commands_complete=False) is Do.TIMED_OUT
    assert pacer.waited_s() == pytest.approx(1.51)


def test_nothing_happens_between_episodes(clock):
    for pacing in ("realtime", "lockstep"):
        pacer = running(pacing, clock)
        pacer.end_episode()
        clock.t += 60.0
        assert pacer.on_timer(commands_complete=True) is Do.NOTHING
        assert pacer.on_commands(complete=True) is Do.NOTHING
        assert pacer.on_grace() is Do.NOTHING


def test_timing_summary_of_a_realtime_episode(clock):
    pacer = running("realtime", clock, rate=100 / 60)  # 10 ms nominal
    for _ in range(4):
        clock.t += 0.001
        pacer.on_commands(complete=True)
        clock.t += 0.010
        assert pacer.on_timer(commands_complete=True) is Do.STEP
        pacer.published()
    s = pacer.end_episode()
    assert s["nominal_period_ms"] == pytest.approx(10.0) and s["period"]["p50_ms"] == pytest.approx(11.0)
    assert s["jitter"]["max_ms"] == pytest.approx(1.0) and s["loop_latency"]["n"] == 4


def test_start_waits_for_the_endpoints_then_settles(clock):
    wait = StartWait(wait_timeout_s=10.0, settle_s=0.3, clock=clock)
    assert wait.poll(ready=False) == (False, False)
    clock.t += 5.0
    assert wait.poll(ready=True) == (False, False), "matched: settle first"
    clock.t += 0.29
    assert not wait.poll(ready=True).go
    clock.t += 0.02
    assert wait.poll(ready=True) == (True, False)
    assert wait.poll(ready=True) == (False, False), "the next episode settles again"


def test_start_gives_up_waiting_after_the_timeout_and_says_so_once(clock):
    wait = StartWait(wait_timeout_s=2.0, settle_s=0.0, clock=clock)
    assert wait.poll(ready=False) == (False, False)
    clock.t += 2.01
    assert wait.poll(ready=False) == (True, True)
    assert wait.poll(ready=False) == (False, False), "a new wait for the next episode"
    slow = StartWait(wait_timeout_s=2.0, settle_s=1.0, clock=clock)
    slow.poll(ready=False)
    clock.t += 2.01
    assert slow.poll(ready=False) == (False, True)
    clock.t += 0.5
    assert slow.poll(ready=False) == (False, False), "said once"
    clock.t += 0.5
    assert slow.poll(ready=False).go


def test_an_endpoint_given_up_on_is_not_awaited_again_until_it_returns(clock):
    """A dead advisory node (the estimator) cost each later episode the whole wait_timeout_s."""
    wait = StartWait(wait_timeout_s=2.0, settle_s=0.0, clock=clock)
    dead = {"/blade/force": (2, 3), "/chassis/cmd_vel": (1, 1)}
    assert wait.poll_endpoints(dead) == ((False, False), ["/blade/force 2/3"])
    clock.t += 2.01
    assert wait.poll_endpoints(dead) == ((True, True), ["/blade/force 2/3"]), "gave up once, saying on what"
    assert wait.poll_endpoints(dead) == ((True, False), []), "the next episode does not wait for it again"
    assert wait.poll_endpoints({**dead, "/chassis/cmd_vel": (0, 1)}) == ((False, False), ["/chassis/cmd_vel 0/1"])
    fewer = {"/blade/force": (1, 3), "/chassis/cmd_vel": (1, 1)}  # another of its subscribers gone too
    assert wait.poll_endpoints(fewer) == ((False, False), ["/blade/force 1/3"])
    clock.t += 2.01
    assert wait.poll_endpoints(fewer) == ((True, True), ["/blade/force 1/3"])
    back = {"/blade/force": (3, 3), "/chassis/cmd_vel": (1, 1)}
    assert wait.poll_endpoints(back)[0].go and not wait.gone, "matched again: awaited again"
    assert wait.poll_endpoints(dead) == ((False, False), ["/blade/force 2/3"])


def test_start_waits_forever_with_no_timeout(clock):
    wait = StartWait(wait_timeout_s=0.0, settle_s=0.0, clock=clock)
    wait.poll(ready=False)
    clock.t += 3600.0
    assert wait.poll(ready=False) == (False, False)
    assert wait.poll(ready=True) == (True, False)
