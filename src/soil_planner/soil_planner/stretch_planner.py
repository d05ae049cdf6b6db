"""The plan kept along a cut (no rclpy): what ``planner.max_cut_depth`` is given from tick to tick.

One estimate gives one plan (``planner``); a cut gives a stream of them, and what the machine
did meanwhile tells the plan more than any one estimate: the force over the recent steady cut
(``SteadyAnchor``, raised to the blade's measured force where the model's is clearly low), the
depths where the cut stalled (``StallMemory``), and when a fused plan must be made afresh
(``StretchPlanner``). The planner node and the cut trial both run ``StretchPlanner``, so the
live loop and ``soil_cut_report`` plan alike. Ticks are counted, not stamped: a replay or a
lockstep graph plans as real time does.
"""
from __future__ import annotations

import collections
import dataclasses
import math
from collections.abc import Mapping

import numpy as np

from soil_msgs_py.messages import plausible_values
from soil_msgs_py.params import (KNOWN_PARAMS, MIN_CUT_DEPTH_M, SAMPLE_RATE_HZ, STEADY_CUT_MAX_ABS_V_Z_M_S,
                                 stall_speed_m_s)
from soil_physics import force_terms
from soil_physics.predictive import mean_standard_error

from .depth_schedule import ScheduleSettings
from .planner import (DEFAULT_CUT_SPEED_M_S, DEFAULT_D_MAX_M, DEFAULT_FORCE_QUANTILE, DEFAULT_MARGIN, KNOWN_LIMITS,
                      MIN_FUSED_ANCHOR_DEPTH_M, Plan, check_bound_law, check_quantile, check_settings, check_switch,
                      checked_fields, checked_inputs, field_of, max_cut_depth, planning_terms, plausible_number)

# The fused plan's anchor is F̂ averaged over the recent *steady* cut, not one tick's F̂: the
# force of a cut fluctuates by ±20 % from half a second to the next (the default world's
# particle events drop the grip for a moment), and while the edge sinks it carries the
# penetration reaction, a transient the planned level cut never meets. Anchored to one tick,
# the plan followed that noise (on soil_cut_report's default-world path it retreated from 0.30
# to 0.10 m in sand that takes 0.30 m). Steady: |v_z| at most ANCHOR_MAX_ABS_V_Z_M_S
# (params.STEADY_CUT_MAX_ABS_V_Z_M_S); the ticks averaged are the last ANCHOR_WINDOW_TICKS
# steady ones within ANCHOR_DEPTH_BAND_M of the newest one's depth, none older than
# ANCHOR_MAX_AGE_TICKS; without any, this tick's F̂ as before. Shallower fast: when, at the
# newest depth, the mean F̂_x of the last ANCHOR_RECENT_TICKS steady ticks exceeds the older
# ticks' mean by more than ANCHOR_CHANGE_SIGMAS of their per-tick spread (a stronger soil, not
# the cut's own fluctuation), the window restarts from the first of them beyond that band and
# the plan follows at once; a weaker soil is followed as the window fills (deeper slowly).
ANCHOR_WINDOW_TICKS = 60
ANCHOR_RECENT_TICKS = 12
ANCHOR_CHANGE_SIGMAS = 2.0
ANCHOR_MIN_SPREAD_N = 100.0  # floor of that spread [N]: a perfectly steady force still has sensor noise
ANCHOR_MAX_ABS_V_Z_M_S = STEADY_CUT_MAX_ABS_V_Z_M_S
ANCHOR_DEPTH_BAND_M = 0.01
ANCHOR_MAX_AGE_TICKS = 180
# An edge this far [m] above the depth the controller commands (−u_za of /blade/cmd: its target
# less the anti-stall offset) while it holds its depth is held there by the floor: the lift
# presses it down and the soil's penetration reaction holds it up (the
# default world's dense gravel: F_z -20 to -28 kN at 0.17-0.21 m, 1 cm short of the target;
# -5 kN once it held its target). That z force is the push of a deepening the edge cannot
# follow, not what a steady cut at that depth meets (a fixed 0.225 m cut through the same
# gravel: F_z p95 7 % of its limit). Carried in proportion to depth it met the z bound at the
# depth being cut, the plan fell 6-8 cm, the blade rose, the push vanished and the plan came
# back: a retreat every few seconds. So a held tick's F̂_z is not evidence of the cut's z force
# (``SteadyAnchor.add``); its F̂_x is kept (base friction riding on the push makes it larger,
# never smaller: the bound stays on the safe side in x). 2 mm: the lift joint is stiff (2 MN/m in
# the simulator), so a few millimetres of lead already push ~10 kN; at 5 mm the ticks counted
# free carried half the push into the z force per metre the held ones took. A free edge
# tracking its depth sits within about 2 mm of the command.
HELD_GAP_M = 0.002
# Where the blade's measured force says the PINN's F̂ is too low, the sensor anchors the plan
# (``SteadyAnchor.anchor``): over the same steady ticks, when the measured F_x's mean exceeds F̂_x's
# by more than SENSOR_GAP_SHARE of F̂_x and SENSOR_GAP_SIGMAS standard errors of that gap
# (``predictive.mean_standard_error``: over the anchor's at most 60 ticks, fewer than its five
# half-second batches, the per-tick spread over √(ticks / 30), so at least 2.1 spreads: a gap the
# default world's particle events cannot make) on at least SENSOR_MIN_TICKS ticks, the x anchor is
# the measured mean. Why: F̂ is a model's, and outside its training it can be far off (a hardpan,
# φ 10-12° and c 30-40 kPa: F̂_x 11.6 kN where the blade measured 18 kN; the plan scaled from it
# made 0.088 m look admissible and the cut stalled 0.8-1.0 s in 20 s). One-sided: a measured
# force below F̂ never makes a plan deeper (the default world's particle events drop the grip
# for a moment; anchored to the measured mean both ways its main path stalled 0.47 s instead of
# 0.30 s). x only: the tractive limit is where a cut stalls, and the measured F_z of an edge the
# lift holds short of its command is the lift's push, not the cut's (HELD_GAP_M). 15 %: more
# than twice the PINN's force error at the cut depth on held-out episodes (6.3 % in the default
# world; on soil_cut_report's main path the measured mean is more than 15 % above F̂_x in 1 % of
# the default world's plans, and in 13 % of the fee world's, whose PINN misses the loam at
# 0.26 m by 15-20 %); 4 ticks: a plan made at the start of a cut, before a full window, is the
# one that plunged into the hardpan. Once taken over, the sensor keeps the anchor while its mean
# stays more than SENSOR_RELEASE_SHARE above F̂_x, with no test of significance: the default
# world's force spreads so much from tick to tick that the test, passed on the few ticks of a new
# depth band, failed a few ticks later at the same gap (a light cohesive soil, F̂_x 30 % low
# throughout: the anchor flipped at every new depth, each flip a re-plan and a fall of the
# target; 0.45 m³/m and 0.13 s of stall, against 0.50 m³/m and none held; the main path's default
# world 1.33x / 0.30 s against 1.37x / 0.17 s).
SENSOR_GAP_SHARE = 0.15
SENSOR_RELEASE_SHARE = 0.05
SENSOR_GAP_SIGMAS = 3.0
SENSOR_MIN_TICKS = 4
# A fused plan is re-made at least this often [ticks] (StretchPlanner): 4 Hz at ~7 ms a plan.
REPLAN_TICKS = 15
# What the machine did overrides what the model says (``StallMemory``): after a stall that began
# at depth d (forward speed below ``params.stall_speed_m_s`` of the cut speed, the anti-stall
# controller's threshold at its default c_vx, once the cut had reached speed), no plan is deeper than
# d − STALL_BACKOFF_M for STALL_MEMORY_TICKS. Why: a posterior that is wrong about the soil (a
# stiff clay far beyond the prior, fused as a sand) kept planning 0.085 m where every cut deeper
# than 0.06 m stalled: 685 ticks at the limit and 10 s of stall in a 20 s cut, the controller's
# lift the only thing between the plan and the stall.
STALL_BACKOFF_M = 0.01
STALL_MEMORY_TICKS = 10 * SAMPLE_RATE_HZ


class SteadyAnchor:
    """The force the fused plan is anchored to: F̂ averaged over the recent steady cut (see
    ANCHOR_WINDOW_TICKS). Fed every tick's estimate; ticks are counted, not stamped, so a
    replay or a lockstep graph anchors as real time does."""

    def __init__(self, sensor: bool = True) -> None:
        self.sensor = check_switch("sensor_anchor", sensor)  # whether a measured F_x above F̂_x may anchor x
        self.reset()

    def reset(self) -> None:
        self.tick = 0
        self.restarts = 0  # times a stronger soil restarted the window
        # (tick, F̂_x, F̂_z [N], Θ_k row, measured F_x [N] or NaN)
        self.entries: collections.deque[tuple[int, float, float, np.ndarray, float]] = \
            collections.deque(maxlen=ANCHOR_WINDOW_TICKS)
        self.sensor_gap_n: float | None = None  # what the newest anchor added to F̂_x from the sensor [N]
        self.sensing = False  # the sensor has taken over the x anchor (SENSOR_RELEASE_SHARE)
        self.free_z_per_m: float | None = None  # F̂_z / d [N/m] of the newest steady tick whose edge was free
        self.held = 0  # steady ticks whose edge was held short of the commanded depth (their F̂_z replaced)

    def add(self, estimate: Mapping[str, float], known: Mapping[str, float],
            commanded_depth_m: float | None = None, measured_force_n=None) -> None:
        """One tick: kept if the PINN's estimate is valid and finite and the edge holds its depth
        (|v_z| <= ANCHOR_MAX_ABS_V_Z_M_S) at least MIN_FUSED_ANCHOR_DEPTH_M deep.
        ``commanded_depth_m``: the depth the controller commands for this tick [m], if known. An
        edge more than HELD_GAP_M short of it is held by the floor: its F̂_z is replaced by the
        newest free tick's F̂_z per metre of depth times its own depth (the z residual is carried
        in proportion to depth anyway; however long it is held, nothing new about the cut's z force
        can show meanwhile), or kept if no free tick was seen since the cut began or the window last
        restarted for a stronger soil (the push is then the safe side). ``measured_force_n``: the
        blade's measured (F_x, F_z) [N] of this tick (/blade/force), None if not known; a value
        that is not a finite number counts as not known.
        ValueError when ``measured_force_n`` is no pair of numbers."""
        measured_x = _measured_x(measured_force_n)  # ValueError for what is no (F_x, F_z) pair
        self.tick += 1
        try:  # a tick the plan would refuse never enters the average
            fx, fz = (plausible_number(f"estimate {n}", field_of(estimate, n, "estimate")) for n in ("f_x_hat", "f_z_hat"))
            k = checked_fields(known, KNOWN_PARAMS, KNOWN_LIMITS, "known")
        except ValueError:
            return
        if estimate.get("valid") != 1.0:
            return
        row = np.array([k[n] for n in KNOWN_PARAMS])
        if abs(k["v_z"]) <= ANCHOR_MAX_ABS_V_Z_M_S and k["d"] >= MIN_FUSED_ANCHOR_DEPTH_M:
            held = (commanded_depth_m is not None and math.isfinite(commanded_depth_m)
                    and commanded_depth_m - k["d"] > HELD_GAP_M)
            if not held:
                self.free_z_per_m = fz / k["d"]
            elif self.free_z_per_m is not None:
                fz = self.free_z_per_m * k["d"]
                self.held += 1
            # a held tick's measured F_x is kept as its F̂_x is (base friction riding on the push makes
            # it larger, never smaller: the safe side in x; dropped, the default world's hardpan, where
            # the floor holds the edge short of nearly every command, kept its 1.0 s of stall)
            self.entries.append((self.tick, fx, fz, row, measured_x))
            self._restart_on_a_stronger_soil()

    def _restart_on_a_stronger_soil(self) -> None:
        """At the newest depth (a deeper cut is not a stronger soil): restart the window from the
        first of the last ANCHOR_RECENT_TICKS whose F̂_x leaves the older ticks' band."""
        same = self._at_newest_depth()
        n = len(same)
        if n < 2 * ANCHOR_RECENT_TICKS:
            return
        fx = np.array([self.entries[i][1] for i in same])
        old, recent = fx[: n - ANCHOR_RECENT_TICKS], fx[n - ANCHOR_RECENT_TICKS:]
        level = old.mean() + ANCHOR_CHANGE_SIGMAS * max(old.std(), ANCHOR_MIN_SPREAD_N)
        if recent.mean() > level:
            first = same[n - ANCHOR_RECENT_TICKS + int(np.argmax(recent > level))]
            for _ in range(first):
                self.entries.popleft()
            self.restarts += 1
            self.free_z_per_m = None  # a stronger soil: the z force per metre of the one before says nothing

    def anchor(self) -> tuple[tuple[float, float], dict[str, float]] | None:
        """(mean F̂ (x, z) [N], mean Θ_k) over the steady ticks near the newest one's depth, F̂_x
        raised to the measured force where that is clearly higher (SENSOR_GAP_SHARE); None when
        no steady tick is recent enough. (Its standard error is not given to the plan: the
        ticks' spread over √n_eff, n_eff the windows their span holds, made the default world's
        plans shallower, 1.30 → 1.24x the conservative volume over 15 paths and seeds, with no
        less stall: its forecast law's 1 kN floor already holds that noise.)"""
        while self.entries and self.tick - self.entries[0][0] > ANCHOR_MAX_AGE_TICKS:
            self.entries.popleft()
        self.sensor_gap_n = None
        if not self.entries:
            return None
        near = [self.entries[i] for i in self._at_newest_depth()]
        force = (float(np.mean([e[1] for e in near])), float(np.mean([e[2] for e in near])))
        measured = self._measured_mean_x(near) if self.sensor else None
        if measured is not None:
            self.sensor_gap_n = measured - force[0]
            force = (measured, force[1])
        return force, dict(zip(KNOWN_PARAMS, np.mean([e[3] for e in near], axis=0).tolist()))

    def _measured_mean_x(self, near) -> float | None:
        """The measured F_x's mean [N] over the ticks of ``near`` with a measured force (at least
        SENSOR_MIN_TICKS of them) where it takes over the anchor: above their F̂_x's mean by more
        than SENSOR_GAP_SHARE of it and SENSOR_GAP_SIGMAS standard errors of the gap, or, once
        taken over, by more than SENSOR_RELEASE_SHARE; else None (F̂ anchors; also on a new depth
        band's first ticks, too few to tell: carrying the last ratio over them was tried, and
        moved the main path's default world 0.657 -> 0.634 m³/m, 4 -> 9 target falls)."""
        pairs = np.array([(e[1], e[4]) for e in near if math.isfinite(e[4])]).reshape(-1, 2)
        if len(pairs) < SENSOR_MIN_TICKS:
            return None
        gaps = pairs[:, 1] - pairs[:, 0]
        gap, f_hat = float(gaps.mean()), abs(float(pairs[:, 0].mean()))
        if self.sensing:
            self.sensing = gap > SENSOR_RELEASE_SHARE * f_hat
        else:
            self.sensing = gap > SENSOR_GAP_SHARE * f_hat and gap > SENSOR_GAP_SIGMAS * float(mean_standard_error(gaps))
        return float(pairs[:, 1].mean()) if self.sensing else None

    def _at_newest_depth(self) -> list[int]:
        """Indices of the entries within ANCHOR_DEPTH_BAND_M of the newest one's depth."""
        d_last = self.entries[-1][3][_KD]
        return [i for i, e in enumerate(self.entries) if abs(e[3][_KD] - d_last) <= ANCHOR_DEPTH_BAND_M]


_KD = KNOWN_PARAMS.index("d")


def _measured_x(measured_force_n) -> float:
    """F_x [N] of a tick's measured (F_x, F_z), NaN when it is None or not a plausible number
    (``messages.plausible_values``: a measured 1e12 N had entered the steady anchor); ValueError
    naming it when it is no pair of numbers."""
    if measured_force_n is None:
        return math.nan
    try:
        pair = np.asarray(measured_force_n, dtype=float)
    except (TypeError, ValueError):
        pair = None
    if pair is None or pair.shape != (2,):
        raise ValueError(f"measured_force_n={measured_force_n!r} must be (F_x, F_z) [N] or None")
    return float(pair[0]) if plausible_values(pair[0], subnormal=True) else math.nan


class StallMemory:
    """Depths where the cut stalled recently (see STALL_MEMORY_TICKS); fed every tick's Θ_k,
    ticks counted, not stamped (a replay or a lockstep graph remembers as real time does)."""

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self.tick = 0
        self.moving = False  # the cut has reached speed (its start is no stall)
        self.stalled = False  # the newest tick was a stall's
        self.onsets: collections.deque[tuple[int, float]] = collections.deque()  # (tick, depth [m]) of each stall's start

    def add(self, known: Mapping[str, float], cut_speed_m_s: float) -> None:
        self.tick += 1
        v_x, d = known.get("v_x"), known.get("d")
        if not (isinstance(v_x, float) and isinstance(d, float) and math.isfinite(v_x) and math.isfinite(d)):
            return
        slow = v_x < stall_speed_m_s(cut_speed_m_s)
        if not slow:
            self.moving, self.stalled = True, False
        elif self.moving and not self.stalled and d >= MIN_CUT_DEPTH_M:
            self.stalled = True
            self.onsets.append((self.tick, d))
        while self.onsets and self.tick - self.onsets[0][0] > STALL_MEMORY_TICKS:
            self.onsets.popleft()

    def cap_m(self) -> float | None:
        """The deepest depth a plan may keep [m], None without a recent stall."""
        return max(min(d for _, d in self.onsets) - STALL_BACKOFF_M, 0.0) if self.onsets else None


class StretchPlanner:
    """``max_cut_depth`` with fixed settings, as the planner node and the cut trial both run it.

    A plan from the fused posterior is made with each new stretch of evidence (2 Hz), when the
    steady anchor restarts (a stronger soil) and at least every REPLAN_TICKS (the anchor moves
    with every tick, the lift rule needs this tick's F̂), with that tick's Θ_k, and repeated for
    the ticks between; a plan from the PINN's point estimate is made every tick. ``plan``
    raises ValueError like ``max_cut_depth`` (the caller decides what a refused estimate means)."""

    def __init__(self, *, margin: float = DEFAULT_MARGIN, d_max_m: float = DEFAULT_D_MAX_M,
                 cut_speed_m_s: float = DEFAULT_CUT_SPEED_M_S, include_residual: bool = True,
                 force_quantile: float | None = DEFAULT_FORCE_QUANTILE, terms=(), sensor_anchor: bool = True,
                 bound_law=()):
        self.margin, self.d_max_m, self.cut_speed_m_s = check_settings(margin, d_max_m, cut_speed_m_s)
        self.terms = planning_terms(terms)  # the fused posterior's physics beside the FEE
        self.bound_law = check_bound_law(bound_law)  # None: the estimate's model_std_*
        self.include_residual = check_switch("include_residual", include_residual)
        self.force_quantile = None if force_quantile is None else check_quantile(force_quantile)
        self._fused: tuple[tuple, Plan, int, float | None] | None = None
        self.anchor = SteadyAnchor(sensor_anchor)
        self.stalls = StallMemory()
        self.sensor_gap_n: float | None = None  # what the measured force added to the last plan's anchor [N]

    def keep_evidence_of(self, other: "StretchPlanner") -> None:
        """Go on with what ``other`` learnt of this cut, its steady anchor's ticks (and their
        measured forces) and its stall memory, under these settings: new settings (a ``ros2
        param set``) are no new cut. The next plan is made afresh."""
        sensor = self.anchor.sensor
        self.anchor, self.stalls = other.anchor, other.stalls
        self.anchor.sensor = sensor
        self.anchor.sensing = self.anchor.sensing and sensor  # switched off and on: taking over is tested afresh

    def forget(self) -> None:
        """A new cut: the next fused plan is made afresh, from a fresh anchor and no stall."""
        self._fused = None
        self.anchor.reset()
        self.stalls.reset()

    def settings(self) -> dict:
        return {"margin": self.margin, "d_max_m": self.d_max_m, "cut_speed_m_s": self.cut_speed_m_s,
                "include_residual": self.include_residual, "force_quantile": self.force_quantile,
                "terms": force_terms.term_texts(self.terms), "sensor_anchor": self.anchor.sensor,
                "bound_law": list(self.bound_law or ())}

    def plans_fused(self, estimate: Mapping[str, float]) -> bool:
        """Whether a tick with this (checked) estimate is planned from its fused posterior: this
        planner plans at a force quantile and the estimator's fused posterior is valid."""
        return self.force_quantile is not None and estimate.get("fused_valid") == 1.0

    def plan(self, estimate: Mapping[str, float], known: Mapping[str, float],
             commanded_depth_m: float | None = None, measured_force_n=None) -> tuple[Plan | None, bool]:
        """(the plan or None, whether it was newly made rather than repeated for this stretch).
        ``commanded_depth_m``: the depth the controller commands for this tick [m], −u_za of
        /blade/cmd; ``measured_force_n``: the blade's measured (F_x, F_z) [N] of this tick,
        /blade/force (both ``SteadyAnchor.add``)."""
        checked_inputs(estimate, known, self.force_quantile)  # before the anchor and a repeated plan take it
        fused = self.plans_fused(estimate)
        self.anchor.add(estimate, known, commanded_depth_m, measured_force_n)
        self.stalls.add(known, self.cut_speed_m_s)
        steady = self.anchor.anchor() if fused else None
        sensed = steady is not None and self.anchor.sensor_gap_n is not None
        # the sensor taking over the anchor (or letting go) re-plans at once, as a restart does
        key = (estimate.get("fused_stretches"), self.anchor.restarts, sensed, self.margin, self.d_max_m,
               self.cut_speed_m_s, self.force_quantile)
        if fused and self._fused is not None and self._fused[0] == key and self.anchor.tick - self._fused[2] < REPLAN_TICKS:
            self.sensor_gap_n = self._fused[3]
            return self._stall_capped(self._fused[1]), False
        settings = dict(margin=self.margin, d_max_m=self.d_max_m, cut_speed_m_s=self.cut_speed_m_s,
                        include_residual=self.include_residual, force_quantile=self.force_quantile, terms=self.terms,
                        bound_law=self.bound_law)
        plan = max_cut_depth(estimate, known, anchor=steady, **settings)
        self.sensor_gap_n = self.anchor.sensor_gap_n if sensed and plan is not None else None
        if steady is not None and plan is not None and float(known["v_z"]) > ANCHOR_MAX_ABS_V_Z_M_S:
            # rising (the controller's anti-stall lift): the steady anchor may be from the weaker
            # soil before it, so this tick's F̂ may only make the plan shallower, never deeper
            now = max_cut_depth(estimate, known, **settings)
            if now is not None and now.max_depth_m < plan.max_depth_m:
                plan, self.sensor_gap_n = now, None
        self._fused = (key, plan, self.anchor.tick, self.sensor_gap_n) if fused and plan is not None else None
        return self._stall_capped(plan), True

    def _stall_capped(self, plan: Plan | None) -> Plan | None:
        """``plan`` no deeper than the stall memory allows; capped, it is bound by x (a stall is
        the tractive limit reached) at that limit's force."""
        cap = self.stalls.cap_m()
        if plan is None or cap is None or plan.max_depth_m <= cap:
            return plan
        return dataclasses.replace(plan, max_depth_m=cap, limited_by_x=True, f_x_n=plan.limit_x_n)


def from_parameters(settings: dict) -> StretchPlanner:
    """The planner for the node's parameters ``node.PLANNER_SETTINGS`` (``force_quantile`` 0 or None:
    the PINN's point plan); ValueError naming a bad one."""
    q = settings["force_quantile"]
    off = q is None or (isinstance(q, (int, float)) and not isinstance(q, bool) and q == 0)
    if not off:
        check_quantile(q, "or 0 for the PINN's point plan")
    return StretchPlanner(**{**settings, "force_quantile": None if off else q})


def check_target_floor(planner: StretchPlanner, schedule: ScheduleSettings) -> None:
    """The target's floor within the planner's reach: a min_target_m above d_max_m kept the edge
    deeper than the deepest cut the planner admits, without a word (an outside tester's 0.02 m plan
    cut at 0.05 m)."""
    d_max = planner.settings()["d_max_m"]
    for name, depth in (("min_target_m", schedule.min_depth_m), ("start_depth_m", schedule.start_depth_m)):
        if depth > d_max:  # (the start depth is also where the target returns without a plan)
            raise ValueError(f"{name}={depth!r} is deeper than d_max_m={d_max!r}: the target would keep the "
                             "edge deeper than the deepest cut the planner admits")
