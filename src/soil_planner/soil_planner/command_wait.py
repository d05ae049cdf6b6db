"""A tick is planned once the controller's command of that tick is in (no rclpy).

The plan of tick k reads the depth the controller commands at tick k (−u_za of /blade/cmd): an
edge held short of it does not anchor the plan's z force (``stretch_planner.SteadyAnchor``). The
estimator answers tick k only once it has /blade/cmd of tick k, so that command is sent before
the estimate, but by another writer, and DDS does not order two writers' messages: a plan made
before its command arrived would differ from one made after it, so the live loop would depend
on delivery order and could differ from ``soil_cut_report``'s in-process loop, which always has
the command. So while the controller's commands are coming in a cut, a tick waits until a
command of its stamp or a later one came (a lost command is not waited for once a later one
is in), at most ``max_wait_s`` of wall time and ``max_ticks`` ticks; ticks leave in the order
they came, so one waiting holds the ticks behind it (the depth schedule counts ticks in order).
Without commands (no controller, a replay of estimates alone) nothing waits.
"""
from __future__ import annotations

import collections
from dataclasses import dataclass
from typing import Any

from soil_msgs_py.graph import LOCKSTEP_TIMEOUT_S
from soil_msgs_py.params import SAMPLE_RATE_HZ
from soil_msgs_py.values import number_in

DEFAULT_COMMAND_WAIT_S = 0.5  # far beyond a DDS hop on loopback; well inside the controller's planner_timeout_s
MAX_COMMAND_WAIT_S = LOCKSTEP_TIMEOUT_S  # the simulator's lockstep_timeout_s: a longer wait would end a lockstep episode
MAX_WAITING_TICKS = 2 * SAMPLE_RATE_HZ  # 2 s of ticks


def check_command_wait(value) -> float:
    """``command_wait_s`` [s of wall time] in [0, MAX_COMMAND_WAIT_S]; ValueError naming it."""
    return number_in("command_wait_s", value, 0.0, MAX_COMMAND_WAIT_S, what="a number of seconds",
                     note=" (0: plan a tick without waiting for its command)")


@dataclass
class Waiting:
    stamp_ns: int
    item: Any
    since_s: float  # wall time it was offered [s]


class CommandWait:
    """Ticks in arrival order, each released once a command stamped at or after it came, or
    after ``max_wait_s`` (wall time), or when more than ``max_ticks`` wait."""

    def __init__(self, max_wait_s: float = DEFAULT_COMMAND_WAIT_S, max_ticks: int = MAX_WAITING_TICKS) -> None:
        self.max_wait_s = check_command_wait(max_wait_s)
        if isinstance(max_ticks, bool) or not isinstance(max_ticks, int) or max_ticks < 1:
            raise ValueError(f"max_ticks={max_ticks!r} must be an integer >= 1")
        self.max_ticks = max_ticks
        self.waiting: collections.deque[Waiting] = collections.deque()
        self.newest_command_ns: int | None = None  # of this cut; None: no command seen, nothing waits
        self.timed_out = 0  # ticks released without their command (waited max_wait_s or crowded out)
        self.waited = 0  # ticks that could not be planned when they came (their command, or one before theirs, was not in)

    def forget_commands(self) -> None:
        """A new cut: its commands are not in yet, so its ticks do not wait until one comes."""
        self.newest_command_ns = None

    def command(self, stamp_ns: int, now_s: float) -> list[Waiting]:
        """The controller commanded tick ``stamp_ns``: the ticks it releases, in order."""
        if self.newest_command_ns is None or stamp_ns > self.newest_command_ns:
            self.newest_command_ns = stamp_ns
        return self.expire(now_s)

    def offer(self, stamp_ns: int, item: Any, now_s: float) -> list[Waiting]:
        """A tick ready to plan: the ticks to plan now, in order (this one among them unless it,
        or one before it, waits for its command)."""
        self.waiting.append(Waiting(stamp_ns, item, now_s))
        out = self.expire(now_s)
        self.waited += bool(self.waiting)  # (this tick is the last one: it waits if any does)
        return out

    def expire(self, now_s: float) -> list[Waiting]:
        """The ticks at the front whose command came, that waited ``max_wait_s``, or beyond
        ``max_ticks``; in order."""
        out = []
        while self.waiting:
            first = self.waiting[0]
            commanded = (self.max_wait_s == 0.0 or self.newest_command_ns is None
                         or first.stamp_ns <= self.newest_command_ns)
            late = now_s - first.since_s >= self.max_wait_s or len(self.waiting) > self.max_ticks
            if not (commanded or late):
                break
            self.timed_out += not commanded
            out.append(self.waiting.popleft())
        return out

    def drain(self, planned: bool = True) -> list[Waiting]:
        """Every waiting tick, in order: a new episode answers them as they are (``planned``: those
        whose command is not in count in ``timed_out``); shutdown drops them (False)."""
        out = list(self.waiting)
        self.waiting.clear()
        if planned:
            self.timed_out += sum(self.newest_command_ns is None or w.stamp_ns > self.newest_command_ns for w in out)
        return out
