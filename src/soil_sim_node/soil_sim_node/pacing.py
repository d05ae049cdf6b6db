"""When the live simulator may start an episode and step a tick (no ROS; the node owns the timers).

The node asks ``Pacer`` what to do whenever its tick timer fires, a tick's commands are
complete, or the grace timer fires, and does what it says (``Do``). Two pacings:

* ``realtime``: a wall-clock timer at 60 Hz × ``rate``; each tick applies the commands that
  answered the previous tick. A tick whose commands are not in yet when the timer fires waits
  up to ``COMMAND_GRACE`` of a period for them (rclpy serves ready timers before ready
  subscriptions, so a command that arrived with the timer would otherwise count as late);
  after that the previous command is held and the tick is counted as late.
* ``lockstep``: the next tick is stepped as soon as both commands for the current one arrived
  (or, when the node held the completion back, ``hold``, by the timer after ``HOLD_S``),
  so a run is reproducible to the bit; a wait of over ``STALL_WARN_S`` is reported, one of
  over ``lockstep_timeout_s`` ends the episode (nothing would ever come).

``StartWait`` decides when a queued episode may start (endpoints matched, then a settle
pause); ``TickTiming`` keeps the wall-clock figures each ``episode_end`` reports.
"""
from __future__ import annotations

import enum
import time
from array import array
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from soil_msgs_py.graph import COUNT_RE, PACING_LOCKSTEP, PACINGS, REALTIME_FACTOR_RANGE, ROS_PATH_RE
from soil_msgs_py.params import SAMPLE_RATE_HZ

RATE_RANGE = REALTIME_FACTOR_RANGE  # real-time factors the node accepts, the player's
COMMAND_GRACE = 0.3  # fraction of a real-time period a tick waits for late commands
HOUSEKEEPING_PERIOD_S = 0.01  # idle or lockstep: the timer only checks starts and stalls
STALL_WARN_S = 1.0  # lockstep: report a wait for commands longer than this [s]
# lockstep: a completion the node holds back (a command in it implausible, ``CommandGate.ready``)
# waits at least this long for the controller's own command before the timer steps it [s]
HOLD_S = HOUSEKEEPING_PERIOD_S


def check_pacing(pacing: str, rate: float) -> None:
    """ValueError naming the parameter unless ``pacing`` and ``rate`` can be used."""
    if pacing not in PACINGS:
        raise ValueError(f"parameter pacing={pacing!r} is not one of {PACINGS}")
    if not RATE_RANGE[0] <= float(rate) <= RATE_RANGE[1]:
        raise ValueError(f"parameter rate={rate!r} outside [{RATE_RANGE[0]}, {RATE_RANGE[1]:g}]")


def _percentiles_ms(values_s) -> dict[str, float]:
    if not len(values_s):
        return {"n": 0}
    a = np.asarray(values_s) * 1e3
    return {"n": int(a.size), "p50_ms": round(float(np.percentile(a, 50)), 4),
            "p99_ms": round(float(np.percentile(a, 99)), 4), "max_ms": round(float(a.max()), 4)}


@dataclass
class TickTiming:
    """Wall-clock figures of one episode: publish periods, loop latency, late commands. The times
    are kept as packed doubles (8 B a tick, where a list's floats took ~32 B: an hour-long episode
    grew the simulator by ~18 MB, an outside soak test)."""

    nominal_period_s: float
    publish_times: array = field(default_factory=lambda: array("d"))
    loop_latencies: array = field(default_factory=lambda: array("d"))
    late_commands: int = 0

    def published(self, t: float) -> None:
        """A tick went out at wall time ``t`` [s, monotonic]."""
        self.publish_times.append(t)

    def answered(self, t: float) -> None:
        """Both commands for the last published tick arrived at wall time ``t``."""
        if self.publish_times:
            self.loop_latencies.append(t - self.publish_times[-1])

    @property
    def awaiting_answer(self) -> bool:
        """The last published tick has no loop latency yet (its commands are not all in)."""
        return len(self.loop_latencies) < len(self.publish_times)

    def summary(self) -> dict:
        periods = np.diff(np.asarray(self.publish_times))  # (empty for fewer than two ticks)
        out = {"nominal_period_ms": round(self.nominal_period_s * 1e3, 4), "period": _percentiles_ms(periods)}
        if self.nominal_period_s > 0:  # lockstep has no nominal period, hence no jitter
            out["jitter"] = _percentiles_ms(np.abs(periods - self.nominal_period_s))
        out.update(loop_latency=_percentiles_ms(self.loop_latencies), late_commands=self.late_commands)
        return out


class Do(enum.Enum):
    """What the node is to do now."""

    NOTHING = "nothing"
    STEP = "step"  # apply this tick's commands (the last ones where missing) and step; disarm the grace timer
    WAIT_GRACE = "wait_grace"  # arm the grace timer: the commands may still come
    STALLED = "stalled"  # lockstep: commands overdue by more than STALL_WARN_S; say so
    TIMED_OUT = "timed_out"  # lockstep: no commands within lockstep_timeout_s; end the episode


class Pacer:
    """The real-time/lockstep decision core of the simulator node (see module doc).

    ``clock`` returns wall time [s] (monotonic); tests pass a fake one."""

    def __init__(self, pacing: str, rate: float, lockstep_timeout_s: float,
                 clock: Callable[[], float] = time.perf_counter):
        check_pacing(pacing, rate)
        self.pacing = pacing
        self.rate = float(rate)
        self.lockstep_timeout_s = float(lockstep_timeout_s)
        self.clock = clock
        self.running = False  # an episode is being stepped
        self.timing: TickTiming | None = None  # the current (or last) episode's figures
        self.due = False  # realtime: the timer fired before the tick's commands were complete
        self.held_at: float | None = None  # lockstep: when the node held a completion back

    @property
    def lockstep(self) -> bool:
        return self.pacing == PACING_LOCKSTEP

    @property
    def realtime_period_s(self) -> float:
        return 1.0 / (SAMPLE_RATE_HZ * self.rate)

    @property
    def period_s(self) -> float:
        """The tick timer's period [s]."""
        return HOUSEKEEPING_PERIOD_S if self.lockstep or not self.running else self.realtime_period_s

    @property
    def grace_s(self) -> float:
        """The grace timer's period [s]."""
        return COMMAND_GRACE * self.period_s

    def set_rate(self, rate: float) -> None:
        """A new real-time factor; the node then restarts its timers."""
        check_pacing(self.pacing, rate)
        self.rate = float(rate)
        if self.timing is not None and not self.lockstep:
            self.timing.nominal_period_s = self.realtime_period_s  # jitter from here on is against the new rate

    def timers_restarted(self) -> None:
        """The node recreated its timers: no grace timer is armed."""
        self.due = False

    def start_episode(self) -> None:
        self.running, self.held_at = True, None
        self.timing = TickTiming(0.0 if self.lockstep else self.realtime_period_s)

    def end_episode(self) -> dict:
        """The episode's timing figures (for its ``episode_end``)."""
        self.running = False
        return self.timing.summary() if self.timing else {}

    def published(self) -> None:
        """A tick went out now."""
        self.held_at = None
        self.timing.published(self.clock())

    def hold(self) -> None:
        """The node holds this tick's completion back (lockstep: ``on_timer`` steps it after HOLD_S)."""
        if self.held_at is None:
            self.held_at = self.clock()

    def waited_s(self) -> float:
        """Wall time since the last tick went out [s] (0 before the first)."""
        if self.timing is None or not self.timing.publish_times:
            return 0.0
        return self.clock() - self.timing.publish_times[-1]

    # ------------------------------------------------------------------ events
    def on_timer(self, commands_complete: bool) -> Do:
        """The tick timer fired while an episode runs."""
        if not self.running:
            return Do.NOTHING
        if not self.lockstep:
            if commands_complete:
                return Do.STEP
            if not self.due:
                self.due = True
                return Do.WAIT_GRACE
            return Do.NOTHING
        if not self.timing.publish_times:
            return Do.NOTHING
        if commands_complete:  # a completion held back by the node (a suspect command): step after HOLD_S
            if self.held_at is None or self.clock() - self.held_at >= HOLD_S:
                return self.on_commands(True)
            return Do.NOTHING
        waited = self.waited_s()
        if waited > self.lockstep_timeout_s:
            return Do.TIMED_OUT
        if waited > STALL_WARN_S:
            return Do.STALLED
        return Do.NOTHING

    def on_commands(self, complete: bool) -> Do:
        """A command for the current tick was taken; ``complete``: both are in."""
        if not (self.running and complete):
            return Do.NOTHING
        if self.timing.awaiting_answer:
            self.timing.answered(self.clock())
        if self.lockstep:
            return Do.STEP
        if self.due:
            self.due = False
            return Do.STEP
        return Do.NOTHING  # realtime, early: the timer steps

    def on_grace(self) -> Do:
        """The grace timer fired: step with the held commands, counted as late."""
        if not (self.due and self.running):
            return Do.NOTHING
        self.due = False
        self.timing.late_commands += 1
        return Do.STEP


class AwaitedEndpoint(NamedTuple):
    """One ``wait_for`` entry: ``count`` matched endpoints on ``topic``, or, with ``node`` (its fully
    qualified name), that node's own endpoint there (count 1)."""

    topic: str
    count: int
    node: str = ""


def parse_wait_for(entries, known_topics) -> list[AwaitedEndpoint]:
    """The simulator's ``wait_for`` entries: 'topic:count' (that many matched endpoints, whoever
    owns them) or 'topic@/namespace/node' (that node's). Why the second: soil_launch counted its
    own readers, and readers outside the launch (a monitor, another recorder on the domain) met the
    count before its recorder listened: the first episode went unrecorded and the launch exited 0.
    ValueError naming the entry for anything else."""
    known = sorted(known_topics)
    out = []
    for entry in entries:
        entry = str(entry)
        topic, at, node = entry.partition("@")
        if at:
            if topic not in known or not ROS_PATH_RE.fullmatch(node):
                raise ValueError(f"parameter wait_for entry {entry!r}: expected 'topic@/namespace/node' with a "
                                 f"topic of {known} and a fully qualified node name")
            out.append(AwaitedEndpoint(topic, 1, node))
            continue
        topic, _, count = entry.rpartition(":")
        if topic not in known or not COUNT_RE.fullmatch(count):
            raise ValueError(f"parameter wait_for entry {entry!r}: expected 'topic:count' with a topic of "
                             f"{known} and a count >= 0, or 'topic@/namespace/node'")
        out.append(AwaitedEndpoint(topic, int(count)))
    return out


class StartPoll(NamedTuple):
    go: bool  # start the episode now
    gave_up: bool  # the endpoints did not match within wait_timeout_s (say so, once per start)


class StartWait:
    """When a queued episode may start: once the awaited endpoints matched (or ``wait_timeout_s``
    passed; 0: wait forever), and then ``settle_s`` more so reverse-direction DDS matches complete too."""

    def __init__(self, wait_timeout_s: float, settle_s: float, clock: Callable[[], float] = time.monotonic):
        self.wait_timeout_s = float(wait_timeout_s)
        self.settle_s = float(settle_s)
        self.clock = clock
        self._wait_started: float | None = None
        self._matched_at: float | None = None
        self._gave_up = False
        self.gone: dict[str, int] = {}  # endpoints given up on -> matched count then: not awaited again until they match

    def waited_s(self) -> float:
        """How long the current start has been waiting [s] (0 before the first poll)."""
        return 0.0 if self._wait_started is None else self.clock() - self._wait_started

    def poll(self, ready: bool) -> StartPoll:
        """Called by the idle timer with whether the endpoints are matched now."""
        now = self.clock()
        if self._wait_started is None:
            self._wait_started = now
        gave_up = False
        if not ready:
            if not (self.wait_timeout_s and now - self._wait_started > self.wait_timeout_s):
                return StartPoll(False, False)
            gave_up, self._gave_up = not self._gave_up, True
        if self._matched_at is None:
            self._matched_at = now
        if now - self._matched_at < self.settle_s:
            return StartPoll(False, gave_up)
        self._wait_started = self._matched_at = None
        self._gave_up = False
        return StartPoll(True, gave_up)

    def poll_endpoints(self, counts: dict[str, tuple[int, int]]) -> tuple[StartPoll, list[str]]:
        """``poll`` on the awaited endpoints' matched counts {topic: (have, need)}. One given up on
        (its node died, or never came) is not awaited at later starts until it matches again: a
        dead estimator cost each later episode the whole ``wait_timeout_s``. Returns the poll and
        the endpoints still awaited and missing ('topic have/need')."""
        missing = {t: have for t, (have, need) in counts.items() if have < need}
        # matched again, or fewer than when given up on (another node of it gone): awaited again
        self.gone = {t: had for t, had in self.gone.items() if t in missing and missing[t] >= had}
        awaited = sorted(set(missing) - set(self.gone))
        poll = self.poll(not awaited)
        if poll.gave_up:
            self.gone.update((t, missing[t]) for t in awaited)
        return poll, [f"{t} {counts[t][0]}/{counts[t][1]}" for t in awaited]
