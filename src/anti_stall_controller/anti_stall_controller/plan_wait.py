"""The closed loop in lockstep: the controller keeps step with the planner.

Why: a lockstep simulator steps as soon as the controller answers, faster than real time, and
the estimator and planner behind it (a 60-sample window, a posterior update, a plan) fall
behind; the controller then cuts to a stale target or, a second later, to its fallback depth,
and the run depends on the machine's load. Here the controller's answer to tick k waits until
the planner's target for tick k − lag has come (the planner answers every tick in lockstep), and
it cuts to that target: the plan acts ``lag`` ticks after the tick it was made from, as in the
in-process loop of ``soil_cut_report``, whatever the load. The chain cannot deadlock for lag ≥ 1:
the target for tick k − 1 needs only commands already sent. A planner that stops answering
costs ``wait_s`` of wall time once: its tick is answered with the target there is (the caller
warns), and later ticks do not wait until a target comes again.

No rclpy: the node feeds it stamps, targets and the wall clock.
"""
from __future__ import annotations

import collections
from typing import Any

from soil_msgs_py.params import SAMPLE_RATE_HZ, TICK_PERIOD_NS
from soil_msgs_py.values import number_in

DEFAULT_LAG_TICKS = 2  # also soil_bringup.cut_trial.DEFAULT_PLAN_DELAY_TICKS, the in-process loop's
DEFAULT_WAIT_S = 2.0
MAX_LAG_TICKS = 2 * SAMPLE_RATE_HZ  # 2 s of ticks; a plan older than that is no plan for this tick
MAX_PLAN_WAIT_S = 60.0  # planner_wait_s: a lockstep tick held longer for a plan is a planner that is gone
MAX_TARGETS = 2 * MAX_LAG_TICKS  # targets kept by stamp: the one tick k cuts to is always among them


def check_plan_wait(lag_ticks, wait_s, timeout_s: float | None = None) -> tuple[int, float]:
    """(lag, wait) as the node's parameters give them; ValueError naming the bad one. With the
    node's ``planner_timeout_s``: a lag longer than it would make every tick's plan too old to follow."""
    if isinstance(lag_ticks, bool) or not isinstance(lag_ticks, int) or not 0 <= lag_ticks <= MAX_LAG_TICKS:
        raise ValueError(f"planner_lag_ticks={lag_ticks!r} must be an integer in [0, {MAX_LAG_TICKS}] (0: never wait)")
    number_in("planner_wait_s", wait_s, 0.0, MAX_PLAN_WAIT_S, lo_open=True, what="a number of seconds")
    if timeout_s is not None and lag_ticks * TICK_PERIOD_NS > timeout_s * 1e9:
        raise ValueError(f"planner_lag_ticks={lag_ticks!r} ({lag_ticks * TICK_PERIOD_NS / 1e9:g} s) is longer than "
                         f"planner_timeout_s={timeout_s!r}: every tick's plan would be too old to follow")
    return int(lag_ticks), float(wait_s)


class PlanWait:
    """Ticks held until their plan came (``offer``/``release``), in stamp order, and the target
    each one cuts to (``target_for``). Inactive (``start_episode(..., lockstep=False)`` or lag 0):
    every tick passes at once and the newest target counts."""

    def __init__(self, lag_ticks: int = DEFAULT_LAG_TICKS, wait_s: float = DEFAULT_WAIT_S,
                 timeout_s: float | None = None):
        self.lag_ticks, self.wait_s = check_plan_wait(lag_ticks, wait_s, timeout_s)
        self.active = False
        self.silent = False  # the planner missed a tick's wait_s: nothing waits until it speaks again
        self.first_stamp_ns = 0
        self.pending: collections.deque[tuple[int, float, Any]] = collections.deque()  # (stamp, since [s], item)
        self.targets: collections.OrderedDict[int, float] = collections.OrderedDict()  # stamp -> depth [m]

    def start_episode(self, first_stamp_ns: int, lockstep: bool) -> list:
        """A new episode: the targets of earlier ones forgotten (those of this one, come before its
        start, kept where time goes forward), and the held ticks of the last one returned (the node
        drops them: its reset core must not step on the old episode's state)."""
        left = self.drain()
        first = int(first_stamp_ns)
        ahead = [(s, d) for s, d in self.targets.items() if s >= first] if first > self.first_stamp_ns else []
        self.targets = collections.OrderedDict(ahead)
        self.first_stamp_ns = first
        self.active = bool(lockstep) and self.lag_ticks > 0
        self.silent = False
        return left

    def end_episode(self) -> list:
        """The episode is over: nothing waits any more (the held ticks returned, to answer now); its
        targets are kept for its last ticks still to come (cleared, those had been cut to the
        fallback depth, a reviewer's)."""
        left = self.drain()
        self.active = self.silent = False
        return left

    def set_lag(self, lag_ticks: int, wait_s: float) -> None:
        lag, self.wait_s = check_plan_wait(lag_ticks, wait_s)
        self.active = self.active and lag > 0
        self.lag_ticks = lag

    def _plan_stamp(self, stamp_ns: int) -> float:
        """The latest stamp whose plan tick ``stamp_ns`` cuts to (half a tick of rounding allowed):
        lag ticks before it in lockstep, else the tick itself (never a plan stamped after the tick)."""
        lag = self.lag_ticks if self.active else 0
        return stamp_ns - lag * TICK_PERIOD_NS + TICK_PERIOD_NS / 2

    def note_target(self, stamp_ns: int, depth_m: float) -> bool:
        """Keep a planner target; False (ignored) if it is stamped before this episode began."""
        if stamp_ns < self.first_stamp_ns:
            return False
        self.silent = False
        late = bool(self.targets) and stamp_ns < next(reversed(self.targets))
        self.targets[int(stamp_ns)] = float(depth_m)
        if late:  # an older target that came late: keep them in stamp order
            self.targets = collections.OrderedDict(sorted(self.targets.items()))
        while len(self.targets) > MAX_TARGETS:
            self.targets.popitem(last=False)
        return True

    def target_for(self, stamp_ns: int) -> tuple[int, float] | None:
        """(stamp, depth) of the target tick ``stamp_ns`` cuts to: the newest made at least lag ticks
        before it (active), else the newest not after it (a stray stamped in the future never wins).
        None: none yet."""
        limit = self._plan_stamp(stamp_ns)
        for stamp in reversed(self.targets):
            if stamp <= limit:
                return stamp, self.targets[stamp]
        return None

    def _ready(self, stamp_ns: int) -> bool:
        limit = self._plan_stamp(stamp_ns)
        if not self.active or self.silent or limit < self.first_stamp_ns:
            return True  # no plan can exist that early in the episode (or the planner is silent)
        # a plan for tick k − lag or later (± half a tick), but none stamped after the newest tick
        # there is (the last one held: ticks come in stamp order): a stray from elsewhere must not
        # release every tick without its plan
        newest = (self.pending[-1][0] if self.pending else stamp_ns) + TICK_PERIOD_NS / 2
        for stamp in reversed(self.targets):  # (in stamp order)
            if stamp <= newest:
                return stamp >= limit - TICK_PERIOD_NS
        return False

    def drain(self) -> list:
        """Every held tick, in order, to answer now (the controller stopped following the planner)."""
        out = [item for _, _, item in self.pending]
        self.pending.clear()
        return out

    def offer(self, stamp_ns: int, item, now_s: float) -> tuple[list, int]:
        """Hold the tick ``item`` (answered in stamp order); as ``release``."""
        self.pending.append((int(stamp_ns), float(now_s), item))
        return self.release(now_s)

    def release(self, now_s: float) -> tuple[list, int]:
        """(items that may be answered now, in order; how many of them waited longer than wait_s
        without their plan: the first such one, after which nothing waits until a target comes)."""
        out, late = [], 0
        while self.pending:
            stamp, since, item = self.pending[0]
            if not self._ready(stamp):
                if now_s - since <= self.wait_s:
                    break
                late += 1
                self.silent = True
            self.pending.popleft()
            out.append(item)
        return out, late
