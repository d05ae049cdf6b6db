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

from soil_msgs_py.params import TICK_PERIOD_NS

DEFAULT_LAG_TICKS = 2  # soil_bringup.cut_trial.DEFAULT_PLAN_DELAY_TICKS, the in-process loop's
DEFAULT_WAIT_S = 2.0
MAX_TARGETS = 240  # targets kept by stamp (4 s of ticks)


def check_plan_wait(lag_ticks, wait_s) -> tuple[int, float]:
    """(lag, wait) as the node's parameters give them; ValueError naming the bad one."""
    if isinstance(lag_ticks, bool) or not isinstance(lag_ticks, int) or not 0 <= lag_ticks <= 600:
        raise ValueError(f"planner_lag_ticks={lag_ticks!r} must be an integer in [0, 600] (0: never wait)")
    if isinstance(wait_s, bool) or not isinstance(wait_s, (int, float)) or not 0.0 < wait_s <= 60.0:
        raise ValueError(f"planner_wait_s={wait_s!r} must be a number of seconds in (0, 60]")
    return int(lag_ticks), float(wait_s)


class PlanWait:
    """Ticks held until their plan came (``offer``/``release``), in stamp order, and the target
    each one cuts to (``target_for``). Inactive (``start_episode(..., lockstep=False)`` or lag 0):
    every tick passes at once and the newest target counts."""

    def __init__(self, lag_ticks: int = DEFAULT_LAG_TICKS, wait_s: float = DEFAULT_WAIT_S):
        self.lag_ticks, self.wait_s = check_plan_wait(lag_ticks, wait_s)
        self.active = False
        self.silent = False  # the planner missed a tick's wait_s: nothing waits until it speaks again
        self.first_stamp_ns = 0
        self.pending: collections.deque[tuple[int, float, Any]] = collections.deque()  # (stamp, since [s], item)
        self.targets: collections.OrderedDict[int, float] = collections.OrderedDict()  # stamp -> depth [m]

    def start_episode(self, first_stamp_ns: int, lockstep: bool) -> list:
        """A new episode: held ticks of the last one are returned (to answer now), targets forgotten."""
        left = [item for _, _, item in self.pending]
        self.pending.clear()
        self.targets.clear()
        self.first_stamp_ns = int(first_stamp_ns)
        self.active = bool(lockstep) and self.lag_ticks > 0
        self.silent = False
        return left

    def set_lag(self, lag_ticks: int, wait_s: float) -> None:
        lag, self.wait_s = check_plan_wait(lag_ticks, wait_s)
        self.active = self.active and lag > 0
        self.lag_ticks = lag

    def _plan_stamp(self, stamp_ns: int) -> int:
        """The latest stamp whose plan tick ``stamp_ns`` cuts to (half a tick of rounding allowed)."""
        return stamp_ns - self.lag_ticks * TICK_PERIOD_NS + TICK_PERIOD_NS / 2

    def note_target(self, stamp_ns: int, depth_m: float) -> None:
        self.silent = False
        late = bool(self.targets) and stamp_ns < next(reversed(self.targets))
        self.targets[int(stamp_ns)] = float(depth_m)
        if late:  # an older target that came late: keep them in stamp order
            self.targets = collections.OrderedDict(sorted(self.targets.items()))
        while len(self.targets) > MAX_TARGETS:
            self.targets.popitem(last=False)

    def target_for(self, stamp_ns: int) -> tuple[int, float] | None:
        """(stamp, depth) of the target tick ``stamp_ns`` cuts to: active, the newest made at least
        lag ticks before it; else the newest. None: none yet."""
        if not self.targets:
            return None
        if not self.active:
            stamp = next(reversed(self.targets))
            return stamp, self.targets[stamp]
        limit = self._plan_stamp(stamp_ns)
        for stamp in reversed(self.targets):
            if stamp <= limit:
                return stamp, self.targets[stamp]
        return None

    def _ready(self, stamp_ns: int) -> bool:
        limit = self._plan_stamp(stamp_ns)
        if not self.active or self.silent or limit < self.first_stamp_ns:
            return True  # no plan can exist that early in the episode (or the planner is silent)
        return bool(self.targets) and next(reversed(self.targets)) >= limit - TICK_PERIOD_NS  # k − lag, ± half a tick

    def drain(self) -> list:
        """Every held tick, in order, to answer now (the controller stopped following the planner)."""
        out = [item for _, _, item in self.pending]
        self.pending.clear()
        return out

    def offer(self, stamp_ns: int, item, now_s: float) -> list:
        """Hold the tick ``item`` (answered in stamp order); the items that may be answered now."""
        self.pending.append((int(stamp_ns), float(now_s), item))
        return self.release(now_s)[0]

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
