"""From plans to the cut depth the anti-stall controller follows: rate limits and fallbacks (no rclpy).

``planner.max_cut_depth`` answers, per estimate, the deepest cut whose upper force quantile
stays within margin x the 20 kN / 30 kN limits. Handing that answer to the controller as it
comes would move the blade in steps: a plan can jump by centimetres from one stretch of
evidence to the next, and a step deeper plunges the edge into the soil, where the
penetration reaction and the bearing load act while it sinks (the default world's largest
forces). The schedule turns plans into a target d̄_z(t):

* **Deeper slowly, shallower fast.** Per second of simulation time the target may deepen by
  at most ``deepen_rate_m_s`` (default 0.1 m/s: a 1:5 ramp at the 0.5 m/s cut speed) and rise
  by at most ``shallow_rate_m_s`` (default 1.0 m/s, faster than the controller's own
  anti-stall lift of K_v = 0.5 m/s: a plan that says "shallower" is a safety request).
* **After a retreat, deepen cautiously.** A plan shallower than the target by more than
  ``retreat_m`` (default 1 cm) found the target too deep; for ``retreat_memory_s`` (default
  5 s) after it the target deepens at ``cautious_deepen_rate_m_s`` (default 0.03 m/s; never faster
  than ``deepen_rate_m_s``) instead (0: no memory). Until plans have taken the target more than ``retreat_m`` below the start
  depth, and again after the schedule backed off to it, the target is the start depth, no
  plan's, and a plan shallower than it is no retreat. (``cut_metrics.target_falls`` counts what
  the controller sees: the target falling ≥ 2 cm.) Re-deepening at full rate into a depth just found too
  deep is how the loop cycled: in the default world's dense gravel each 0.1 m/s ramp ended
  with the lift pressing the edge onto a floor that held it (the penetration reaction, then the
  push, in F_z), the plan met its z bound (margin x 30 kN) there and retreated ~5 cm, and at the
  shallower depth, the push gone, allowed the deeper cut again: ±3 cm every ~1.5 s, F_z's p95 at
  its limit. Slower, the push stays lower and the cut settles. A first deepening into a fresh
  soil keeps the full rate (that is where the volume is).
* **Start shallow.** Before the first valid plan of a cut the target is ``start_depth_m``
  (default 0.10 m): the soil is unknown, and the estimator needs half a second of cutting
  before its posterior says anything.
* **Hold, then back off.** Without a valid plan (the estimator restarting its posterior after
  the soil changed, a planner with nothing to plan from) the last target is held for
  ``hold_s`` (default 1.0 s), then moves back towards ``start_depth_m`` at the shallow rate.
  Held or backing off, the target never goes deeper than the newest plan: a plan that had just
  found the target too deep, then fell silent, had left it held half-way up its retreat (an
  outside reviewer's). Plans that stop coming for longer than the hold (estimates lost on a
  loaded machine) are the same: the next plan finds the target backed off as the missing ticks
  would have left it, and deepens from there by no more than one plan interval of the ramp
  (the interval between the plans before the gap), not by the whole gap's worth in one step.
* **Clamp.** The target stays in [``min_depth_m``, ``max_depth_m``] (default [0.05, 0.30] m).
  The deep end is the lift joint's reach on level ground. The shallow end is a cut deep
  enough to learn from: at 2 cm the forces are too small to tell a weak soil from a strong
  one, so a plan made from a strong soil behind would keep the blade there for good (the
  controller's anti-stall lift still acts when a soil cannot take even 5 cm).

Time is the plans' stamps (simulation time), so a replayed bag or a lockstep graph gets the
same targets as real time. A stamp that goes back is a new cut (``reset``).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

from soil_msgs_py.messages import NS_PER_S
from soil_msgs_py.params import (CAUTIOUS_DEEPEN_RATE_M_S, LIFT_REACH_M, MACHINE, MAX_STRIDE_TICKS, MIN_PLANNED_DEPTH_M,
                                 TICK_PERIOD_NS)


GAP_PACES = 2.0  # an update more than this many of the plans' intervals after the one before follows a gap


def follows_at_its_pace(last_ns: int, jumped_ns: int, stamp_ns: int) -> bool:
    """Whether ``stamp_ns`` follows a tick stamped ``jumped_ns``, itself far ahead of the last one
    scheduled (``last_ns``), at about the same spacing (within a factor GAP_PACES either way): an
    estimator that estimates that seldom (its stride of seconds), not time jumping ahead, whose
    next tick follows the jump at the simulator's pace. A jump further than the rarest stride an
    estimator takes (MAX_STRIDE_TICKS) is no pace: two stray messages an hour apart are not one."""
    ahead, then = jumped_ns - last_ns, stamp_ns - jumped_ns  # (a tick's slack: stamps are whole ns of k/60 s)
    return (0 < ahead <= MAX_STRIDE_TICKS * TICK_PERIOD_NS
            and ahead / GAP_PACES - TICK_PERIOD_NS <= then <= ahead * GAP_PACES + TICK_PERIOD_NS)


@dataclass(frozen=True)
class ScheduleSettings:
    """Rate limits and fallbacks of the depth schedule (SI; module docstring)."""

    start_depth_m: float = 0.10
    deepen_rate_m_s: float = 0.10
    shallow_rate_m_s: float = 1.0
    hold_s: float = 1.0
    retreat_m: float = 0.01
    retreat_memory_s: float = 5.0
    cautious_deepen_rate_m_s: float = CAUTIOUS_DEEPEN_RATE_M_S
    min_depth_m: float = MIN_PLANNED_DEPTH_M
    max_depth_m: float = LIFT_REACH_M

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ValueError(f"{f.name}={value!r} must be a finite number")
            object.__setattr__(self, f.name, float(value))
        for name in ("deepen_rate_m_s", "shallow_rate_m_s"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"{name}={getattr(self, name)!r} must be > 0 m/s")
        if not 0.0 < self.cautious_deepen_rate_m_s <= self.deepen_rate_m_s:  # cautious: no faster than the rate it slows
            raise ValueError(f"cautious_deepen_rate_m_s={self.cautious_deepen_rate_m_s!r} must be > 0 m/s and at most "
                             f"deepen_rate_m_s={self.deepen_rate_m_s!r}")
        for name in ("hold_s", "retreat_memory_s"):
            if getattr(self, name) < 0.0:
                raise ValueError(f"{name}={getattr(self, name)!r} must be >= 0 s")
        if self.retreat_m < 0.0:
            raise ValueError(f"retreat_m={self.retreat_m!r} must be >= 0 m")
        if not 0.0 <= self.min_depth_m <= self.max_depth_m <= MACHINE.blade_height_m:
            raise ValueError(f"min_depth_m={self.min_depth_m!r} and max_depth_m={self.max_depth_m!r} must satisfy "
                             f"0 <= min_depth_m <= max_depth_m <= {MACHINE.blade_height_m} m (blade height)")
        if not self.min_depth_m <= self.start_depth_m <= self.max_depth_m:
            raise ValueError(f"start_depth_m={self.start_depth_m!r} must be in [min_depth_m, max_depth_m] = "
                             f"[{self.min_depth_m}, {self.max_depth_m}] m")

    def to_dict(self) -> dict:
        return asdict(self)


class DepthSchedule:
    """Plans (stamp, deepest admissible depth or None) -> the controller's target depth [m]."""

    def __init__(self, settings: ScheduleSettings | None = None):
        self.settings = settings or ScheduleSettings()
        self.reset()

    def reset(self) -> None:
        """A new cut: back to the start depth, no plan seen."""
        self.target_m = self.settings.start_depth_m
        self.last_stamp_ns: int | None = None
        self.last_plan_ns: int | None = None  # stamp of the newest valid plan
        self.last_retreat_ns: int | None = None  # stamp of the newest plan that found the target too deep
        self.deepened = False  # plans took the target > retreat_m past the start depth (before: no plan's)
        self.last_goal_m: float | None = None  # the newest valid plan's depth, clamped: no hold goes deeper
        self.interval_s: float | None = None  # between the newest two updates not across a gap: the plans' pace

    def update(self, stamp_ns: int, plan_depth_m: float | None) -> float:
        """The target at ``stamp_ns`` given this tick's plan (None or non-finite: no valid plan)."""
        s = self.settings
        stamp_ns = int(stamp_ns)
        if self.last_stamp_ns is not None and stamp_ns < self.last_stamp_ns:
            self.reset()
        dt = 0.0 if self.last_stamp_ns is None else (stamp_ns - self.last_stamp_ns) / NS_PER_S
        self.last_stamp_ns = stamp_ns
        planned = plan_depth_m is not None and math.isfinite(plan_depth_m)
        unplanned_s = None if self.last_plan_ns is None else (stamp_ns - self.last_plan_ns) / NS_PER_S
        # updates missing (a gap, not the estimator's pace: a stride of seconds is no gap): the gap earns
        # no deepening, the ramp resumes at the pace (rising keeps the whole gap: a retreat is never
        # slowed); beyond the hold, first the back-off the missing ticks would have made
        gap = self.interval_s is not None and dt > GAP_PACES * self.interval_s
        deepen_dt = self.interval_s if gap else dt
        if gap and planned and unplanned_s is not None and unplanned_s > s.hold_s:
            self._back_off(unplanned_s - s.hold_s)  # (the cut's plans had deepened it: a shallower plan now
            # is a retreat all the same, and the cautious re-deepening follows)
        if dt > 0.0 and not gap:
            self.interval_s = dt
        if planned:
            goal = min(max(float(plan_depth_m), s.min_depth_m), s.max_depth_m)
            self.last_plan_ns, self.last_goal_m = stamp_ns, goal
        elif unplanned_s is not None and unplanned_s <= s.hold_s:
            goal = min(self.target_m, self.last_goal_m)  # hold (a retreat under way goes on to the plan)
        else:
            goal = self._back_off_goal()
            self.deepened = False  # backing off to the start depth: the target is no plan's again
        goal = min(max(goal, s.min_depth_m), s.max_depth_m)
        if planned and self.deepened and s.retreat_memory_s > 0.0 and goal < self.target_m - s.retreat_m:
            self.last_retreat_ns = stamp_ns
        if self.last_plan_ns is None and plan_depth_m is None:
            self.target_m = goal  # nothing planned yet: the start depth as it is
            return self.target_m
        step = goal - self.target_m
        deepen = min(s.deepen_rate_m_s, s.cautious_deepen_rate_m_s) if self.cautious(stamp_ns) else s.deepen_rate_m_s
        step = min(step, deepen * deepen_dt) if step > 0 else max(step, -s.shallow_rate_m_s * dt)
        # the goal keeps the floor; the target reaches a floor raised at run time at the deepening rate
        # (clamped, it had jumped there in one tick: an outside reviewer's); a lowered ceiling at once
        self.target_m = min(self.target_m + step, s.max_depth_m)
        # plans took the target deeper than where the cut started by more than a retreat: from now
        # on a plan below it is one (a few millimetres of the first ramp are no plan's depth)
        self.deepened = self.deepened or (planned and self.target_m > s.start_depth_m + s.retreat_m)
        return self.target_m

    def _back_off_goal(self) -> float:
        """Without a plan past the hold: the start depth, never deeper than the target or the newest plan."""
        if self.last_plan_ns is None:
            return self.settings.start_depth_m
        return min(self.target_m, self.settings.start_depth_m, self.last_goal_m)

    def _back_off(self, elapsed_s: float) -> None:
        """``elapsed_s`` of backing off (at the shallow rate) without an update: a gap in the plans."""
        s = self.settings
        goal = min(max(self._back_off_goal(), s.min_depth_m), s.max_depth_m)
        self.target_m = max(goal, self.target_m - s.shallow_rate_m_s * elapsed_s) if goal < self.target_m else self.target_m

    def cautious(self, stamp_ns: int) -> bool:
        """Within ``retreat_memory_s`` of the newest retreat: deepening at the cautious rate."""
        return (self.last_retreat_ns is not None and self.settings.retreat_memory_s > 0.0
                and (int(stamp_ns) - self.last_retreat_ns) / NS_PER_S <= self.settings.retreat_memory_s)

    @property
    def plan_valid(self) -> bool:
        """A valid plan is in effect (the newest update had one)."""
        return self.last_plan_ns is not None and self.last_plan_ns == self.last_stamp_ns
