"""Deepest cut within the machine's force limits from one /soil/estimate (no rclpy).

What an autonomy stack does with the estimator's output: given the estimated soil
(φ̂, ĉ, δ̂, Δd̂ and the force F̂ at the current depth) and the known parameters Θ_k of the
same tick, predict the cutting force F(d) of a steady cut for candidate depths d with the
FEE (``soil_physics.fee``, paper Eq. 2-10) and return the deepest d in [0, d_max] for which

    |F_x(d)| <= margin * 20 kN (tractive limit)  and  |F_z(d)| <= margin * 30 kN (lift limit).

Design choices (why)
--------------------
Depth: d is Θ_k's d, the measured depth of the blade edge below the soil surface just
ahead of the blade (``soil_sim_node.simulator``: surface height ahead − edge height; Table 1's
d), not a command. The answer ``max_depth_m`` is such a cut depth below the soil surface; it
is the quantity to give the anti-stall controller as ``target_depth_m``, approximately: that
target is a depth below the *original* surface z = 0, and the two coincide on level, uncut
ground ahead (the normal case while cutting a pass), but differ by the height of the surface
ahead over a slope or previously cut ground. The FEE is evaluated at d' = d + Δd̂ clamped to
Table 1's d' limits [0, 0.66 m] exactly as the PINN does (``model.py``; 0.66 m is the blade
height); Δd̂ is a depth-independent offset of the effective soil surface, so it carries over
to every d. d' = 0 means no wedge and no force.

Reach (``d_max_m``): the default 0.3 m is ``params.LIFT_REACH_M``, how far the lift joint
can put the edge below the chassis ground reference p_z^c (the mean soil height under the
chassis). In d the machine reaches 0.3 m + (surface ahead − p_z^c): exactly 0.3 m with the
chassis standing on level, uncut ground (the start of a pass), more once the chassis rides on
its own cut floor (≈ 0.4 m at tick 200 of the loam sample below, 0.5 m once the whole chassis
stands on its 0.2 m floor), less where the ground ahead falls away. So the default is the
reach at the start of a pass on level ground, a conservative cap and not a bound of d; any
value up to the blade height 0.66 m can be set.

Operating point: the plan is for a steady, level cut: every candidate depth is evaluated at
blade velocity v_x = ``cut_speed_m_s`` (default 0.5 m/s, the anti-stall controller's default
target speed) and v_z = 0. Θ_k's v_x, v_z (the 10-sample average of the current motion) are
a transient near the limit: the anti-stall controller lifting the blade (v_z > 0) or a stall
(v ≈ 0). Through the Eq. 9-10 correction tanh(−C1 ι_b·v) they reverse or remove the soil-tool
friction and adhesion, push β* out of Table 1's range and make the plan optimistic exactly
when the machine is near its limit (loam sample default_loam_id060_v0.50_d0.200_s7, tick
200: 0.25 m with x binding at the recorded velocity, but 0.30 m "reach" with v_z = +0.15 m/s
if the current velocity were used). The residual r_now (below) is nevertheless computed at
Θ_k's *actual* velocity, because that is where F̂ was predicted. Θ_k's γ, ρ, α, w, c_a and
surcharge Q are used as they are at the estimate's tick (the plan is for cutting with that
pile in front of the blade); re-plan with every estimate.

Failure angle β: the critical angle β* of Eq. 7 (``fee.fee_xz(beta=None)``), not the
estimated β̂. β* = argmin N_γ is the model the simulator cuts with and the point the PINN's
∂N_γ/∂β loss pulls β̂ towards; β̂ is a soft fit at the *current* depth (and velocity) that
may trade accuracy there for consistency elsewhere (paper §2.2.2), so carrying it to other
depths extrapolates a local fit. β* of Eq. 7 depends on neither d nor Q (N_γ contains
neither) and on the velocity only through δ' (Eq. 9-10), so at the fixed operating point one
β* holds for every candidate depth and does not follow the transient. A d-dependent angle
would come from minimising the *total* force over β instead; with a surcharge that drives β
below Table 1's 11.5° (e.g. 16° at 0.3 m, 5° at 0.05 m in loose sand with a 5 kN pile) and
under-predicts the force by up to half, i.e. an optimistic plan, so it is not used.

Residual force: the plan is anchored to the PINN's force prediction at the current depth.
r_now = F̂ − F_FEE(d'_now; actual v, β*) (the network's residual F_r plus the β̂-vs-β*
difference, small in a steady cut) is what the FEE misses there. It is carried to other depths in
proportion to the (clamped) depth in soil, r(d') = r_now · d'/d'_now for d' > 0 (0 out of the
soil), and added to the steady-cut FEE: the prediction at the current depth is F̂ with the
FEE part moved to the steady operating point (exactly F̂ while the machine cuts level at
``cut_speed_m_s``), and the missing force vanishes with the cut. Why proportional: what the
FEE leaves out acts on the submerged blade (edge bearing/penetration resistance ~ γ d N_q,
contact damping ~ wetted area w d / sin ρ, lost grip ~ force), i.e. to first order a force
per metre of cut. It matters: in a dense-gravel run the lift joint saturates and
F_r,z ≈ −27 kN (FEE alone: −6 kN); the FEE-only plan (0.20 m, x binds) ignores that the z
force at 0.165 m is already beyond 0.8 × 30 kN, while a *constant* residual would put all
27 kN on a blade that just touches the soil and answer −Δd̂ = 0.04 m; proportional gives
0.13 m, z binding. It is not used (the plan is FEE only) when the blade was (almost) out of
the soil at the estimate, d'_now < MIN_ANCHOR_DEPTH_M (F̂ = F_r is unregularised at d' <= 0,
paper §2.2.2, and dividing by a tiny d'_now amplifies noise), when the FEE has no failure
wedge at the actual velocity (no β*: soil-tool friction reversed by a fast lift in soil with
δ̂ > φ̂, where F_FEE(d'_now) does not exist) or β* there is outside Table 1 (a strong transient:
the difference to the PINN's own FEE, whose β̂ is clipped to Table 1, would pass for a
residual), and with ``include_residual=False`` (pure FEE plan). Far from the current depth the extrapolation is less certain: re-plan with every
estimate. The fused plan's anchor (``stretch_planner.SteadyAnchor``) is F̂ averaged over the recent
steady cut, raised to the blade's measured force where that is clearly higher: the measured force,
not the model, is the truth at the depth being cut. What a plan keeps from tick to tick along a
cut (that anchor, the stall memory, when to re-plan) is ``stretch_planner``'s.

Search: a dense grid on [0, d_max] (one vectorised FEE call), then a search between the
last admissible grid depth and the first inadmissible one, 8 depths per vectorised call (a
bracket nine times narrower per call, where bisection halves it). The answer is the largest d
such that *every* depth in [0, d] is admissible: the blade reaches d through all shallower
depths, so a deeper admissible band behind an inadmissible one (force can be
non-monotonic, e.g. a residual of opposite sign) is not a plan. The surcharge term makes
F jump at d' = 0+; the search does not need continuity. If d = 0 is already inadmissible
(Δd̂ > 0 and a large force), the depth is 0; the flags say which limit binds.
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from soil_physics import fee, force_terms
from soil_physics.augmented_fee import AugmentedFEE
from soil_msgs_py.params import (DEFAULT_TARGET_SPEED_M_S, DEG, FORCE_LIMITS_N, KNOWN_PARAMS, LIFT_REACH_M,
                                 PLANNER_FORCE_MARGIN, TABLE1)
from soil_msgs_py.messages import PLAUSIBLE_ABS_LIMIT
from soil_msgs_py.topics import ESTIMATE_FIELDS, FUSED_FIELDS, PLAN_FIELDS
from soil_msgs_py.values import short_repr
from soil_physics.predictive import (extrapolated_part, model_error_std, near_limit_error_std, upper_magnitude,
                                     within_magnitude)

# The edge reaches 0.30 m below the chassis ground reference p_z^c: d = 0.3 m with the chassis
# on level, uncut ground; deeper in d once the chassis rides on its own cut (module docstring).
DEFAULT_D_MAX_M = LIFT_REACH_M
# Table 1's d' limits, [0, 0.66] m, as the PINN clamps d' = d + Δd (0.66 m: the blade height,
# where the FEE geometry ends; deeper, the blade is buried).
D_PRIME_LIMITS_M: tuple[float, float] = TABLE1["d"].limits
D_MAX_LIMIT_M = D_PRIME_LIMITS_M[1]
# Blade speed of the planned steady cut: the anti-stall controller's default target speed.
DEFAULT_CUT_SPEED_M_S = DEFAULT_TARGET_SPEED_M_S
CUT_SPEED_LIMIT_M_S = TABLE1["v_x"].limits[1]
DEFAULT_MARGIN = PLANNER_FORCE_MARGIN  # share of the force limits a planned cut may use (params: why 0.85)
GRID_POINTS = 257
TOLERANCE_M = 1e-5
SEARCH_PROBES = 8  # depths per step of the search between the last admissible and first inadmissible grid depth
# The residual is carried to other depths only from an estimate with the blade this deep in soil.
MIN_ANCHOR_DEPTH_M = 0.02
# The fused plan's anchor (``_FusedForceModel``) only from this deep: carried in proportion to
# depth, a residual seen at 2 cm would be multiplied tenfold at 20 cm, and a plan made from a
# blade just lifted out of a stall would stay shallow (the posterior's own forecast is better
# there). Just below the depth schedule's shallowest target (5 cm), so a cut held there is anchored.
MIN_FUSED_ANCHOR_DEPTH_M = 0.04
# x is scaled to F̂_x only where both forces exceed this [N] (a ratio of small forces is noise),
# by a factor within these limits (a posterior that far off is left to its own spread).
SCALE_FLOOR_N = 1e3
SCALE_LIMITS = (0.25, 4.0)
# The PINN clips its outputs to Table 1 in float32; the float64 value published can sit a
# hair outside the float64 limit. Within this relative tolerance a value counts as inside.
LIMIT_RTOL = 1e-6
# The plan from the fused posterior (fused_valid = 1): the deepest cut whose force_quantile
# upper bound of |F| stays within the limits. The posterior is taken as the Gaussian of the
# published moments, sampled with fixed draws (the same estimate always gives the same plan),
# each sample through the FEE at the planned steady cut plus the published error law.
DEFAULT_FORCE_QUANTILE = 0.95
FUSED_SAMPLES = 256
FUSED_GRID_POINTS = 33  # a coarser grid than the point plan's: each depth is a whole mixture
_DRAWS = np.random.default_rng(0).standard_normal((FUSED_SAMPLES, 3))
FUSED_LIMITS: dict[str, tuple[float, float]] = {
    **{f"{n}_fused": TABLE1[n].limits for n in ("phi", "c", "delta")},
    **{f"{n}_std": (0.0, math.inf) for n in ("phi", "c", "delta")},
    **{f"corr_{k}": (-1.0, 1.0) for k in ("phi_c", "phi_delta", "c_delta")},
    **{f"model_std_{k}": (0.0, math.inf) for k in ("abs_x", "abs_z", "rel_x", "rel_z", "limit_x", "limit_z")},
}
# Estimate fields the plan reads (all are checked: a broken estimate is not trusted at all).
ESTIMATE_LIMITS: dict[str, tuple[float, float]] = {
    name: TABLE1[name].limits for name in ("phi", "c", "delta", "beta", "delta_d")
}
# Θ_k as published can lie outside Table 1 where the table is about the FEE's inputs, not the
# state: d < 0 is the blade above the surface, d > 0.66 m a buried blade (only d + Δd enters
# the FEE, clamped to [0, 0.66] m).
KNOWN_LIMITS: dict[str, tuple[float, float]] = {
    name: ((-math.inf, math.inf) if name == "d" else TABLE1[name].limits) for name in KNOWN_PARAMS
}


@dataclass(frozen=True)
class Plan:
    """The deepest admissible cut and the predicted force there (SI).

    ``limited_by_x``/``limited_by_z``: that limit is exceeded just deeper than
    ``max_depth_m`` (both False: ``d_max_m`` was reached within the limits).
    """

    max_depth_m: float
    f_x_n: float  # predicted force at max_depth_m (blade on soil, world frame) [N]
    f_z_n: float
    limited_by_x: bool
    limited_by_z: bool
    limit_x_n: float  # margin * tractive limit [N]
    limit_z_n: float  # margin * lift limit [N]
    d_max_m: float
    cut_speed_m_s: float  # operating point of every candidate depth: v_x = this, v_z = 0
    beta_rad: float  # β* used at every depth (at the operating point)
    residual_x_n: float  # r_now: what the FEE misses at the estimate's depth and velocity [N] (0 if not used)
    residual_z_n: float
    residual_used: bool  # r(d') = r_now d'/d'_now was added (see module docstring)
    force_quantile: float = 0.0  # > 0: planned from the fused posterior, f_x_n/f_z_n are this upper quantile of |F|

    def values(self) -> list[float]:
        """Payload of /planner/max_cut_depth in ``topics.PLAN_FIELDS`` order (valid = 1)."""
        return [self.max_depth_m, self.f_x_n, self.f_z_n, float(self.limited_by_x),
                float(self.limited_by_z), 1.0, self.force_quantile]

    @property
    def binding(self) -> str:
        """'x', 'z', 'x+z' or 'reach' (d_max)."""
        axes = "+".join(a for a, hit in (("x", self.limited_by_x), ("z", self.limited_by_z)) if hit)
        return axes or "reach"


NO_PLAN_VALUES: tuple[float, ...] = (0.0,) * len(PLAN_FIELDS)  # valid = 0: every field 0.0, never NaN
assert PLAN_FIELDS == ("max_depth_m", "f_x_n", "f_z_n", "limited_by_x", "limited_by_z", "valid", "force_quantile"), "Plan.values"


def check_settings(margin: float, d_max_m: float, cut_speed_m_s: float) -> tuple[float, float, float]:
    """(margin, d_max_m, cut_speed_m_s) as floats; ValueError naming the setting and value if out of range."""
    m, d = plausible_number("margin", margin), plausible_number("d_max_m", d_max_m)
    v = plausible_number("cut_speed_m_s", cut_speed_m_s)
    if not 0.0 < m <= 1.0:
        raise ValueError(f"margin={margin!r} must be in (0, 1] (fraction of the force limits)")
    if not 0.0 < d <= D_MAX_LIMIT_M:
        raise ValueError(f"d_max_m={d_max_m!r} must be in (0, {D_MAX_LIMIT_M}] m (blade height)")
    if not 0.0 < v <= CUT_SPEED_LIMIT_M_S:
        raise ValueError(f"cut_speed_m_s={cut_speed_m_s!r} must be in (0, {CUT_SPEED_LIMIT_M_S}] m/s "
                         "(forward, within Table 1's v_x limit)")
    return m, d, v


def fields(values: Sequence[float], names: Sequence[str]) -> dict[str, float]:
    """Payload values in ``names`` order -> {name: float}; ValueError on a length mismatch."""
    if len(values) != len(names):
        raise ValueError(f"{len(values)} values for {len(names)} fields {tuple(names)}")
    return {n: float(v) for n, v in zip(names, values)}


def max_cut_depth(
    estimate: Mapping[str, float],
    known: Mapping[str, float],
    *,
    margin: float = DEFAULT_MARGIN,
    d_max_m: float = DEFAULT_D_MAX_M,
    cut_speed_m_s: float = DEFAULT_CUT_SPEED_M_S,
    include_residual: bool = True,
    force_quantile: float | None = DEFAULT_FORCE_QUANTILE,
    anchor: tuple[tuple[float, float], Mapping[str, float]] | None = None,
    grid_points: int | None = None,
    tol_m: float = TOLERANCE_M,
    terms=(),
    bound_law=(),
) -> Plan | None:
    """Deepest admissible cut for ``estimate`` (ESTIMATE_FIELDS) with Θ_k ``known`` (KNOWN_PARAMS).

    With a fused posterior (``fused_valid`` = 1) and ``force_quantile`` q set: every depth's
    force is the q upper bound of |F| over the posterior (module constants FUSED_*), so the
    plan keeps a 1 − q chance of meeting more than the limits; otherwise the PINN's point
    estimate with the residual (module docstring). ``anchor``: the force (x, z) [N] the fused
    plan is anchored to and the Θ_k it was predicted at (``stretch_planner.SteadyAnchor``); None: this
    estimate's F̂ at ``known``. ``terms``: the fused posterior's physics beside the FEE, (name, k)
    pairs or 'name=k' texts (``planning_terms``): its θ means what it means in that physics (the
    default world's calibrated posterior takes 76 % of the FEE's surcharge part away). ``bound_law``:
    the error law of the fused bound (``check_bound_law``; empty: the estimate's ``model_std_*``). None when
    neither is valid (nothing to plan
    from). ValueError, naming the field and value, for a missing, non-finite or out-of-limits
    field, a bad setting, or parameters for which the FEE has no failure wedge at the planned
    steady cut (v_x = ``cut_speed_m_s``, v_z = 0; non-finite force).
    """
    margin, d_max_m, cut_speed_m_s = check_settings(margin, d_max_m, cut_speed_m_s)
    terms = planning_terms(terms)
    bound_law = check_bound_law(bound_law)
    if force_quantile is not None:
        force_quantile = check_quantile(force_quantile)
    if grid_points is not None and (int(grid_points) != grid_points or grid_points < 2):
        raise ValueError(f"grid_points={grid_points!r} must be an integer >= 2")
    if not 0.0 < tol_m:
        raise ValueError(f"tol_m={tol_m!r} must be > 0 m")
    valid, fused, est, kn = checked_inputs(estimate, known, force_quantile)
    if kn is None:
        return None
    if grid_points is None:
        grid_points = FUSED_GRID_POINTS if fused else GRID_POINTS
    limits = np.array([margin * FORCE_LIMITS_N[0], margin * FORCE_LIMITS_N[1]])
    if fused:
        force_now, known_now, std_now = None, kn, (0.0, 0.0)
        if include_residual and anchor is not None:
            force_now, known_now, std_now = _checked_anchor(anchor)
        elif include_residual and valid == 1.0:  # the PINN's force now, where the plan is anchored
            force_now = (est["f_x_hat"], est["f_z_hat"])
        model = _FusedForceModel(est, kn, cut_speed_m_s, force_quantile, force_now, known_now, terms, std_now, bound_law)
    else:
        model = _ForceModel(est, kn, cut_speed_m_s, include_residual)

    grid = np.linspace(0.0, d_max_m, int(grid_points))
    in_x, in_z = model.within(grid, limits)
    ok = in_x & in_z
    if ok.all():
        depth, hit_x, hit_z = d_max_m, False, False
    elif not ok[0]:
        depth, hit_x, hit_z = 0.0, not bool(in_x[0]), not bool(in_z[0])
    else:
        k = int(np.argmin(ok))  # first inadmissible grid depth
        lo, hi = float(grid[k - 1]), float(grid[k])
        hit_x, hit_z = not bool(in_x[k]), not bool(in_z[k])  # what binds just deeper than lo
        while hi - lo > tol_m:
            # SEARCH_PROBES depths inside the bracket per model call: one vectorised evaluation
            # shrinks it ninefold where a bisection step halves it (a call costs, a depth hardly)
            probe = np.linspace(lo, hi, SEARCH_PROBES + 2)[1:-1]
            mx, mz = model.within(probe, limits)
            good = mx & mz
            if good.all():
                lo = float(probe[-1])
                continue
            j = int(np.argmin(good))  # the first inadmissible probe: every depth above it is admissible
            lo, hi = (float(probe[j - 1]) if j else lo), float(probe[j])
            hit_x, hit_z = not bool(mx[j]), not bool(mz[j])
        depth = lo
    f_x, f_z = model(np.array([depth]))
    return Plan(
        max_depth_m=float(depth), f_x_n=float(f_x[0]), f_z_n=float(f_z[0]),
        limited_by_x=hit_x, limited_by_z=hit_z, limit_x_n=float(limits[0]), limit_z_n=float(limits[1]),
        d_max_m=d_max_m, cut_speed_m_s=cut_speed_m_s, beta_rad=model.beta_rad,
        residual_x_n=float(model.residual[0]), residual_z_n=float(model.residual[1]),
        residual_used=model.residual_used, force_quantile=float(force_quantile) if fused else 0.0,
    )


# How far below 0° a fused angle is still the posterior's edge [rad] rather than a broken message.
# Why such an estimate is not planned from: an outside tester's stiff silt and the default world's
# dense gravel both drove the posterior to φ ≈ 0 for half a second; planned from, with φ held at 0,
# its high-c soil let the gravel's plan deepen into the z limit (4 target falls in
# tests/soil_bringup/test_cut_trial.py's dense gravel trial, none without).
RAN_OFF_RAD = 5.0 * DEG


def checked_inputs(estimate: Mapping[str, float], known: Mapping[str, float], force_quantile: float | None
                   ) -> tuple[float, bool, dict[str, float] | None, dict[str, float] | None]:
    """(the estimate's valid flag, whether it is planned from its fused posterior, the fields a plan
    reads and Θ_k, both checked; both None where there is nothing to plan from). ValueError naming
    the field and value for anything a plan may not use (missing, not finite, beyond a plausible
    magnitude, outside Table 1): checked on every tick, also where a plan is repeated for its
    stretch, so a broken message is refused whether or not a plan is made from it."""
    valid = _flag(estimate, "valid")
    # (an estimate without the fused fields, e.g. from an estimator without them: the point plan)
    fused = force_quantile is not None and "fused_valid" in estimate and _flag(estimate, "fused_valid") == 1.0
    if valid == 0.0 and not fused:
        return valid, fused, None, None
    kn = checked_fields(known, KNOWN_PARAMS, KNOWN_LIMITS, "known")
    if not fused:
        return valid, fused, checked_fields(estimate, ESTIMATE_FIELDS[: ESTIMATE_FIELDS.index("valid")], ESTIMATE_LIMITS,
                                      "estimate"), kn
    for name in ("phi_fused", "delta_fused"):  # (a posterior at the low edge of its box: its mean just below 0°)
        value = estimate.get(name)
        if isinstance(value, float) and -RAN_OFF_RAD <= (value := float(value)) < -LIMIT_RTOL:
            raise ValueError(f"estimate {name}={value!r} rad is below 0°: the fused posterior has run off the physical "
                             "range (a soil its model cannot explain, e.g. far from Table 1's); not planned from, the "
                             "target holds, then backs off")
    est = checked_fields(estimate, FUSED_FIELDS[:-2], FUSED_LIMITS, "estimate")
    if valid == 1.0:  # the PINN's force now: what the plan and its steady anchor are anchored to
        est |= checked_fields(estimate, ("f_x_hat", "f_z_hat"), {}, "estimate")
    return valid, fused, est, kn


def fused_upper_force(estimate: Mapping[str, float], known: Mapping[str, float], depths_m, *,
                      quantile: float = DEFAULT_FORCE_QUANTILE, cut_speed_m_s: float = DEFAULT_CUT_SPEED_M_S,
                      anchor: tuple[tuple[float, float], Mapping[str, float]] | None = None,
                      terms=(), bound_law=()) -> tuple[np.ndarray, np.ndarray]:
    """The ``quantile`` upper bound of |F_x| and |F_z| [N] the fused plan keeps within the limits, at
    each of ``depths_m`` (a steady, level cut at ``cut_speed_m_s`` with Θ_k ``known``): what
    ``max_cut_depth`` compares with the limits, for checking how often a measured force exceeds it.
    ``anchor``: ((F_x, F_z) [N], Θ_k) as in ``max_cut_depth``; ``bound_law`` as there. ValueError as
    there (no fused posterior in ``estimate`` is one)."""
    check_settings(DEFAULT_MARGIN, DEFAULT_D_MAX_M, cut_speed_m_s)
    quantile = check_quantile(quantile)
    if _flag(estimate, "fused_valid") != 1.0:
        raise ValueError("estimate: fused_valid is not 1 (no fused posterior to bound the force with)")
    est = checked_fields(estimate, FUSED_FIELDS[:-2], FUSED_LIMITS, "estimate")
    kn = checked_fields(known, KNOWN_PARAMS, KNOWN_LIMITS, "known")
    force_now, known_now, std_now = _checked_anchor(anchor) if anchor is not None else (None, None, (0.0, 0.0))
    model = _FusedForceModel(est, kn, cut_speed_m_s, quantile, force_now, known_now, planning_terms(terms), std_now,
                             check_bound_law(bound_law))
    return model(np.atleast_1d(np.asarray(depths_m, dtype=float)))


def _checked_anchor(anchor) -> tuple[tuple[float, float], dict[str, float], tuple[float, float]]:
    """((F_x, F_z) [N], Θ_k, (σ_x, σ_z) [N]) of a fused plan's anchor ((F_x, F_z), Θ_k[, (σ_x, σ_z)]:
    the anchor force's own standard error, 0 if not given), checked; ValueError naming what is wrong."""
    def pair(x) -> bool:
        return isinstance(x, (tuple, list, np.ndarray)) and len(x) == 2

    if not isinstance(anchor, (tuple, list)) or len(anchor) not in (2, 3) or not pair(anchor[0]) \
            or (len(anchor) == 3 and not pair(anchor[2])):
        raise ValueError(f"anchor={anchor!r} must be ((F_x, F_z) [N], Θ_k) or ((F_x, F_z), Θ_k, (σ_x, σ_z) [N])")
    force_now = tuple(plausible_number(f"anchor force {a}", v) for a, v in zip("xz", anchor[0]))
    std = (tuple(plausible_number(f"anchor force std {a}", v) for a, v in zip("xz", anchor[2])) if len(anchor) == 3
           else (0.0, 0.0))
    if min(std) < 0.0:
        raise ValueError(f"anchor force std={std!r} must be >= 0 N")
    return force_now, checked_fields(anchor[1], KNOWN_PARAMS, KNOWN_LIMITS, "anchor known"), std


def check_bound_law(law) -> tuple[float, float, float, float] | None:
    """The anchored bound's error law (abs_x [N], abs_z [N], rel_x, rel_z), σ = abs + rel·|ΔF| as
    the estimate's ``model_std_*``, or None for an empty one (the estimate's law is used). Why a law
    of its own: the published law is calibrated for the posterior's own forecast intervals, while
    the bound a plan keeps is anchored to the force now (``_FusedForceModel``), a different forecast
    whose errors ``bound_calibration`` (``soil_planner_calibrate``) measures apart. Any sequence of
    numbers (the parameter service gives an ``array.array``). ValueError naming the value unless
    four finite numbers >= 0 with floors > 0."""
    if law is None:
        return None
    try:
        values = None if isinstance(law, (str, bytes)) else list(law)
    except TypeError:
        values = None
    shown = short_repr(values if values is not None else law)  # (a list, not "array('d', [...])")
    wrong = ValueError(f"bound_law={shown} must be empty or four numbers: abs_x [N], abs_z [N], rel_x, rel_z")
    if values is None:
        raise wrong
    if not values:
        return None
    if len(values) != 4:
        raise wrong
    out = tuple(plausible_number(f"bound_law {name}", v)
                for name, v in zip(("abs_x", "abs_z", "rel_x", "rel_z"), values))
    if min(out) < 0.0 or min(out[:2]) <= 0.0:
        raise ValueError(f"bound_law={shown} must be >= 0 (its floors abs_x, abs_z > 0 N)")
    return out


def steady_cut_terms(terms) -> tuple[tuple[tuple[str, float], ...], tuple[str, ...]]:
    """(the terms a planned steady cut can evaluate as (name, k) pairs, the names of those it
    cannot): a plan is for a steady cut at any depth, which has no travel or time in soil, so a
    term that looks at either is left to the caller (e.g. a posterior fitted with compaction
    hardening: plan without it, and say so). ValueError naming an unknown term."""
    parsed = AugmentedFEE(terms).terms
    path = tuple(n for n, _ in parsed if force_terms.uses_distance(n) or force_terms.uses_time(n))
    return tuple(t for t in parsed if t[0] not in path), path


def planning_terms(terms) -> tuple[tuple[str, float], ...]:
    """The fused posterior's terms beside the FEE as (name, k) pairs; ValueError naming a term
    that is unknown or that looks at the blade's travel or time in soil (``steady_cut_terms``)."""
    usable, path = steady_cut_terms(terms)
    if path:
        raise ValueError(f"terms: {path[0]!r} looks at the travel or time in soil, which a planned steady cut "
                         "does not have")
    return usable


def check_switch(name: str, value) -> bool:
    """A setting that is on or off; ValueError naming it unless it is a bool (``bool("false")`` is True)."""
    if not isinstance(value, bool):
        raise ValueError(f"{name}={value!r} must be true or false")
    return value


def check_quantile(q, alternative: str = "") -> float:
    """The force quantile as a float; ValueError naming it unless 0.5 <= q < 1 (``alternative``:
    what else the caller takes, said after the range, e.g. the node's 0)."""
    x = plausible_number("force_quantile", q)
    if not 0.5 <= x < 1.0:
        raise ValueError(f"force_quantile={q!r} must be in [0.5, 1) (an upper quantile of the force)"
                         + (f", {alternative}" if alternative else ""))
    return x


def _flag(estimate: Mapping[str, float], name: str) -> float:
    value = plausible_number(f"estimate {name}", field_of(estimate, name, "estimate"))
    if value not in (0.0, 1.0):
        raise ValueError(f"estimate {name}={value!r} must be 1.0 or 0.0")
    return value


class _FusedForceModel:
    """|F|(d) at the force_quantile over the fused posterior, for arrays of depths d [m].

    θ samples: the Gaussian of the published means, standard deviations and correlations
    (covariance made positive semi-definite), fixed draws, φ and δ kept inside Table 1's
    limits and c >= 0; each through the posterior's physics, the FEE plus ``terms`` (its θ means
    what it means in the model it was fitted with; below, "FEE" is that model), at d (no Δd: the
    posterior's stretches were fitted at Θ_k's d), the planned steady cut (v_x = cut speed,
    v_z = 0) and β* per sample; the
    published error law σ = abs + rel·|ΔF| (+ its part near the F_x limit, from the sample's F_x,
    ``predictive.near_limit_error_std``; not with a bound law of its own) around each (ΔF below). Samples without a failure wedge there
    are left out; none left is a ValueError.

    Anchored (``anchor`` = the PINN's force F̂ now, (x, z) [N], or its average over the recent
    steady cut, predicted at ``anchor_known``, default ``known``): each sample's FEE misses
    F̂ − F_FEE,s(d_now; Θ_k's velocity) at the anchor's depth. In x (positive while cutting)
    the sample's force is scaled to the force now, F_x,s(d) = F_FEE,x,s(d) · F̂_x / F_FEE,x,s(d_now)
    (used where both exceed SCALE_FLOOR_N; a sample whose ratio lies beyond SCALE_LIMITS is no soil
    the force now allows and is left out, unless all are): the FEE's surcharge
    part, Q·N_q, does not vanish with depth, and a posterior whose Q·N_q is too large (the
    default world) would forbid every depth if only a depth-proportional residual corrected
    it. In z (either sign, often near 0) the residual r_s is carried in proportion to the
    depth as in the point plan (module docstring, "Residual force"), F_z,s(d) = F_FEE,z,s(d)
    + r_s d / d_now, and so is x where no ratio is used. Only from at least
    MIN_FUSED_ANCHOR_DEPTH_M deep. The level then follows the force
    measured now (a new, stronger soil is seen within the PINN's window, not after the
    posterior has moved), the posterior gives the shape and its spread. A sample without a
    wedge at the current velocity keeps r_s = 0.
    The error law is ``bound_law`` where anchored (it is calibrated on anchored bounds), else the
    one calibrated for the posterior's forecasts at other depths (``model_std_*``), its
    relative part applied to what is extrapolated, ΔF = min(|F_s(d) − F̂|, |F_FEE,s(d)|)
    (``predictive.extrapolated_part``); unanchored, from each sample's own FEE force at the
    current depth instead of F̂, as the posterior counts from its newest stretch. Either way a
    forecast at the depth being cut adds the law's floor only.
    """

    def __init__(self, est: dict[str, float], known: dict[str, float], cut_speed_m_s: float, quantile: float,
                 anchor: tuple[float, float] | None = None, anchor_known: dict[str, float] | None = None,
                 terms: tuple[tuple[str, float], ...] = (), anchor_std: tuple[float, float] = (0.0, 0.0),
                 bound_law: tuple[float, float, float, float] | None = None):
        self.physics = AugmentedFEE(terms)
        self.anchor_std = tuple(float(v) for v in anchor_std)
        names = ("phi", "c", "delta")
        mean = np.array([est[f"{n}_fused"] for n in names])
        std = np.array([est[f"{n}_std"] for n in names])
        corr = np.eye(3)
        for (i, a), (j, b) in (((0, "phi"), (1, "c")), ((0, "phi"), (2, "delta")), ((1, "c"), (2, "delta"))):
            corr[i, j] = corr[j, i] = est[f"corr_{a}_{b}"]
        vals, vecs = np.linalg.eigh(corr * np.outer(std, std))
        root = vecs * np.sqrt(np.clip(vals, 0.0, None))
        x = mean + _DRAWS @ root.T
        lo = np.array([TABLE1["phi"].limits[0] + 1e-6, 0.0, 0.0])
        hi = np.array([TABLE1["phi"].limits[1] - 1e-6, math.inf, TABLE1["delta"].limits[1]])
        x = np.clip(x, lo, hi)
        self.theta = {**known, "phi": x[:, 0], "c": x[:, 1], "delta": x[:, 2], "v_x": cut_speed_m_s, "v_z": 0.0}
        self.quantile = quantile
        self.law = ((est["model_std_abs_x"], est["model_std_rel_x"], est["model_std_limit_x"]),
                    (est["model_std_abs_z"], est["model_std_rel_z"], est["model_std_limit_z"]))
        self.beta_rad = float(fee.critical_beta(est["phi_fused"], est["delta_fused"], known["c_a"], known["rho"],
                                                known["alpha"], cut_speed_m_s, 0.0))
        if not math.isfinite(self.beta_rad):
            self.beta_rad = 0.0  # the mean has no wedge; the samples decide (reported only)
        self.residual_per_m = np.zeros((2, FUSED_SAMPLES))
        self.residual, self.residual_used = np.zeros(2), False
        self.scale_x = np.ones(FUSED_SAMPLES)
        self.ratio_used = np.zeros(FUSED_SAMPLES, bool)  # samples whose x is scaled to the anchor
        self.allowed = np.ones(FUSED_SAMPLES, bool)  # samples the force now does not rule out
        at = known if anchor_known is None else anchor_known  # Θ_k where the anchor force was predicted
        d_now = float(np.clip(at["d"], *D_PRIME_LIMITS_M))
        if anchor is not None and d_now >= MIN_FUSED_ANCHOR_DEPTH_M:
            with np.errstate(all="ignore"):
                fx_now, fz_now = self._force({**self.theta, **at, "d": np.array([d_now])})  # (Θ_k has no φ, c, δ)
            r = np.array(anchor)[:, None] - np.stack([np.broadcast_to(fx_now, (FUSED_SAMPLES,)),
                                                      np.broadcast_to(fz_now, (FUSED_SAMPLES,))])
            r = np.where(np.isfinite(r), r, 0.0)
            self.residual_per_m = r / d_now
            self.residual, self.residual_used = r.mean(axis=1), True
            # x: the sample's FEE scaled to the force now (its depth-independent surcharge part
            # scales too); a ratio only where both forces are clearly positive
            fx_now = np.broadcast_to(fx_now, (FUSED_SAMPLES,))
            with np.errstate(all="ignore"):
                scale = anchor[0] / fx_now
            usable = np.isfinite(scale) & (fx_now > SCALE_FLOOR_N) & (anchor[0] > SCALE_FLOOR_N)
            self.scale_x = np.where(usable, np.clip(scale, *SCALE_LIMITS), 1.0)
            self.ratio_used = usable
            self.residual_per_m[0] = np.where(usable, 0.0, self.residual_per_m[0])
            # a sample whose FEE at the depth being cut is beyond SCALE_LIMITS of the force measured
            # there is no soil that force allows: left out (all of them: kept, as a clipped ratio)
            consistent = ~usable | ((scale >= SCALE_LIMITS[0]) & (scale <= SCALE_LIMITS[1]))
            if consistent.any():
                self.allowed = consistent
        if bound_law is not None and self.residual_used:  # calibrated on anchored bounds; unanchored,
            # the bound is the posterior's own forecast, whose law is the published one
            self.law = ((bound_law[0], bound_law[2], 0.0), (bound_law[1], bound_law[3], 0.0))  # (no part near the limit)
        # what the error law's relative part counts from, per axis (S,): the force now when anchored,
        # else each sample's own force at the current depth (where the posterior's evidence is,
        # as ``SoilPosterior.forecast`` counts from its newest stretch)
        self.d_now = d_now
        if self.residual_used:
            self.reference = [np.full(FUSED_SAMPLES, float(a)) for a in anchor]
        else:
            with np.errstate(all="ignore"):
                ref_x, ref_z = self._force({**self.theta, "d": np.array([d_now])})
            self.reference = [np.broadcast_to(ref_x, (FUSED_SAMPLES,)), np.broadcast_to(ref_z, (FUSED_SAMPLES,))]

    def _force(self, theta: dict) -> tuple[np.ndarray, np.ndarray]:
        """(F_x, F_z) [N] of the posterior's physics, the FEE plus its terms (NaN: no wedge), at
        ``theta``: θ samples and Θ_k, arrays that broadcast."""
        if not self.physics.terms:  # (the FEE as the plan has always used it, its surcharge force at d = 0 too)
            fx, fz, _ = fee.fee_xz(theta)
            return fx, fz
        return self.physics.force((theta["phi"], theta["c"], theta["delta"]), theta, distance=0.0)

    def _mixtures(self, d: np.ndarray):
        """Per axis (x, z): (weights (S,), means (D, S), standard deviations (D, S)) at depths d."""
        d = np.clip(np.asarray(d, float), *D_PRIME_LIMITS_M)[:, None]  # (D, 1) against (S,) samples
        shape = (len(d), FUSED_SAMPLES)
        with np.errstate(all="ignore"):
            raw_x, raw_z = self._force({**self.theta, "d": d})
            raw_x, raw_z = np.broadcast_to(raw_x, shape), np.broadcast_to(raw_z, shape)
            fx = raw_x * self.scale_x + self.residual_per_m[0] * d
            fz = raw_z + self.residual_per_m[1] * d
        ok = (np.isfinite(fx) & np.isfinite(fz)).all(axis=0) & self.allowed  # a sample with a wedge at every depth
        if not ok.any():
            raise ValueError("no sample of the fused posterior has an FEE failure wedge at the planned steady cut")
        w = ok.astype(float)
        carried = self._anchor_error(fx, d)
        fx_ok = np.where(ok, fx, 0.0)  # each sample's own F_x: where the law's part near the F_x limit counts from
        out = []
        for axis, (f, raw, (a, r, near), now, extra) in enumerate(((fx, raw_x, self.law[0], self.reference[0], carried[0]),
                                                                   (fz, raw_z, self.law[1], self.reference[1], carried[1]))):
            f, raw = np.where(ok, f, 0.0), np.where(ok, raw, 0.0)
            # the relative error applies to what is extrapolated from the reference, and never
            # exceeds the sample's own force's share (an anchor adds knowledge, never doubt); the
            # published law's part near the F_x limit, from each sample's own F_x, as the posterior's
            law = (model_error_std(extrapolated_part(f, now, raw), a, r)
                   + near_limit_error_std(fx_ok, near, axis))
            out.append((w, f, np.sqrt(law ** 2 + np.where(ok, extra, 0.0) ** 2) + 1e-9))
        return out

    def _anchor_error(self, fx: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(D, S) per axis: the anchor force's own standard error, when the caller gives one, as each
        sample carries it to d [N], independent of the law's. A mean over a noisy window: a bound
        that ignores its error reads the window's noise, times the depth ratio, as the soil's (the
        fee world with a noisy sensor, whose forecast law is 5 N: exceeded in 25 % of forecasts at
        most 1.6x as deep, 8 % with it; ``bench_forecast.py --fee-noise``). x: scaled like the
        sample's force, F_x,s(d) / F̂_x (the ratio the anchor is multiplied by); z, and x where no
        ratio is used: d / d_now."""
        if not self.residual_used or not any(self.anchor_std):
            return np.zeros_like(fx), np.zeros_like(fx)
        by_depth = np.broadcast_to(d / self.d_now, fx.shape)
        with np.errstate(all="ignore"):
            ratio = np.where(self.ratio_used, np.abs(fx / self.reference[0]), by_depth)
        ratio = np.where(np.isfinite(ratio), ratio, by_depth)
        return self.anchor_std[0] * ratio, self.anchor_std[1] * by_depth

    def __call__(self, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        (wx, mx, sx), (wz, mz, sz) = self._mixtures(d)
        return upper_magnitude(wx, mx, sx, self.quantile), upper_magnitude(wz, mz, sz, self.quantile)

    def within(self, d: np.ndarray, limits: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Whether each depth's upper |F| quantile is within the limits (x, z): two CDF values each."""
        (wx, mx, sx), (wz, mz, sz) = self._mixtures(d)
        return (within_magnitude(wx, mx, sx, limits[0], self.quantile),
                within_magnitude(wz, mz, sz, limits[1], self.quantile))


class _ForceModel:
    """F(d) = F_FEE(d'; v_plan, β*) + r_now d'/d'_now for arrays of depths d [m].

    d' = clamp(d + Δd̂, 0, 0.66 m); v_plan = (cut_speed_m_s, 0), the steady, level cut;
    r_now = F̂ − F_FEE(d'_now; Θ_k's v, β*) (0 if not used).
    """

    def __init__(self, est: dict[str, float], known: dict[str, float], cut_speed_m_s: float,
                 include_residual: bool):
        soil = {"phi": est["phi"], "c": est["c"], "delta": est["delta"]}
        self.theta = {**known, **soil, "v_x": cut_speed_m_s, "v_z": 0.0}  # the planned steady cut
        self.delta_d = est["delta_d"]
        # β* as fee_xz(beta=None) computes it, here only to report it and to fail clearly
        self.beta_rad = float(fee.critical_beta(est["phi"], est["delta"], known["c_a"], known["rho"], known["alpha"],
                                                cut_speed_m_s, 0.0))
        if not math.isfinite(self.beta_rad):
            raise ValueError(
                f"no FEE failure wedge (no critical β) for phi={est['phi'] / DEG:.2f}°, "
                f"delta={est['delta'] / DEG:.2f}°, "
                f"rho={known['rho'] / DEG:.2f}°, alpha={known['alpha'] / DEG:.2f}° "
                f"at the planned v_x={cut_speed_m_s} m/s, v_z=0")
        d_now = float(self.d_prime(np.array([known["d"]]))[0])  # d'_now, clamped like the PINN's
        self.residual = np.zeros(2)
        self.residual_per_m = np.zeros(2)
        self.residual_used = False
        # F̂ was predicted at Θ_k's actual velocity: the FEE it is compared with must be too. In a
        # strong transient (a fast lift) β* there leaves Table 1's range and the difference to the
        # PINN's own FEE (β̂, clipped to Table 1) would pass for a residual: no anchor, FEE only.
        beta_now = float(fee.critical_beta(est["phi"], est["delta"], known["c_a"], known["rho"], known["alpha"],
                                           known["v_x"], known["v_z"]))
        beta_lo, beta_hi = TABLE1["beta"].limits
        if include_residual and d_now >= MIN_ANCHOR_DEPTH_M and beta_lo <= beta_now <= beta_hi:
            fx_now, fz_now, _ = fee.fee_xz({**known, **soil, "d": np.array([d_now])})
            if np.isfinite(fx_now[0]) and np.isfinite(fz_now[0]):  # else no wedge now: no anchor, FEE only
                self.residual = np.array([est["f_x_hat"] - fx_now[0], est["f_z_hat"] - fz_now[0]])
                self.residual_per_m = self.residual / d_now
                self.residual_used = True

    def within(self, d: np.ndarray, limits: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        fx, fz = self(d)
        return np.abs(fx) <= limits[0], np.abs(fz) <= limits[1]

    def d_prime(self, d: np.ndarray) -> np.ndarray:
        """d' = d + Δd̂ clamped to Table 1's [0, 0.66] m, as the PINN does (model.py)."""
        return np.clip(d + self.delta_d, *D_PRIME_LIMITS_M)

    def __call__(self, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        d_prime = self.d_prime(d)  # 0: no soil, no force and no residual
        fx, fz, _ = fee.fee_xz({**self.theta, "d": d_prime})
        fx = fx + self.residual_per_m[0] * d_prime
        fz = fz + self.residual_per_m[1] * d_prime
        if not (np.isfinite(fx).all() and np.isfinite(fz).all()):
            bad = float(d[~(np.isfinite(fx) & np.isfinite(fz))][0])
            raise ValueError(f"FEE force is not finite at depth d={bad:.4f} m "
                             f"(phi={self.theta['phi'] / DEG:.2f}°, delta={self.theta['delta'] / DEG:.2f}°)")
        return fx, fz


def describe(plan: Plan, estimate: Mapping[str, float], known: Mapping[str, float],
             sensor_gap_n: float | None = None) -> str:
    """One human log line: the depth, what binds, the operating point, the soil and the state now
    (``sensor_gap_n``: what the measured force added to F̂_x in the plan's anchor [N], if any)."""
    if plan.binding == "reach":
        why = f"reach d_max={plan.d_max_m:.2f} m binds; F_x {plan.f_x_n / 1e3:.1f} of {plan.limit_x_n / 1e3:.1f} kN"
    else:
        lim = {"x": plan.limit_x_n, "z": plan.limit_z_n}
        why = ", ".join(f"{a} limit binds: {lim[a] / 1e3:.1f} kN" for a in plan.binding.split("+"))
    if plan.force_quantile:
        soil = (f"the fused soil φ={estimate['phi_fused'] / DEG:.1f}±{estimate['phi_std'] / DEG:.1f}°, "
                f"c={estimate['c_fused'] / 1e3:.1f}±{estimate['c_std'] / 1e3:.1f} kPa, "
                f"δ={estimate['delta_fused'] / DEG:.1f}±{estimate['delta_std'] / DEG:.1f}°, "
                f"{plan.force_quantile:.0%} upper force quantile")
        if sensor_gap_n is not None:
            soil += f", anchored to the measured F_x ({sensor_gap_n / 1e3:.1f} kN above F̂_x)"
    else:
        residual = (f"F_r now ({plan.residual_x_n / 1e3:+.1f}, {plan.residual_z_n / 1e3:+.1f}) kN"
                    if plan.residual_used else "FEE only")
        soil = (f"φ={estimate['phi'] / DEG:.1f}°, c={estimate['c'] / 1e3:.1f} kPa, δ={estimate['delta'] / DEG:.1f}°, "
                f"Δd={estimate['delta_d'] * 100:+.1f} cm, β*={plan.beta_rad / DEG:.1f}°, {residual}")
    return (
        f"deepest cut {plan.max_depth_m:.2f} m below the surface ({why}) "
        f"at v_x={plan.cut_speed_m_s:.2f} m/s level, from {soil}; "
        f"now d={known['d']:.2f} m, Q={known['q'] / 1e3:.1f} kN, "
        f"v=({known['v_x']:+.2f}, {known['v_z']:+.2f}) m/s"
    )


# --- validation ----------------------------------------------------------------------------

def plausible_number(name: str, value) -> float:
    """``value`` as a float; ValueError naming ``name`` unless it is a finite number (not a bool)
    within ±PLAUSIBLE_ABS_LIMIT, a magnitude some part of the graph can give."""
    if isinstance(value, bool):
        raise ValueError(f"{name}={value!r} must be a number")
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name}={value!r} must be a number") from None
    if not math.isfinite(x):
        raise ValueError(f"{name}={value!r} must be finite")
    if abs(x) > PLAUSIBLE_ABS_LIMIT:  # (a 1e300 force or std overflowed the plan's squares)
        raise ValueError(f"{name}={value!r} is beyond ±{PLAUSIBLE_ABS_LIMIT:g}, a value no part of the graph gives")
    return x


def field_of(data: Mapping[str, float], name: str, what: str):
    """``data[name]``; ValueError "<what> has no field <name>" where it is missing."""
    try:
        return data[name]
    except KeyError:
        raise ValueError(f"{what} has no field {name!r}") from None


def checked_fields(data: Mapping[str, float], names: Sequence[str], limits: Mapping[str, tuple[float, float]],
             what: str) -> dict[str, float]:
    """``names`` of ``data`` as floats, every one finite and inside its ``limits`` (snapped in within
    LIMIT_RTOL); ValueError naming ``what``, the field and its value otherwise."""
    out = {}
    for name in names:
        x = plausible_number(f"{what} {name}", field_of(data, name, what))
        lo, hi = limits.get(name, (-math.inf, math.inf))
        slack = lambda b: LIMIT_RTOL * max(1.0, abs(b)) if math.isfinite(b) else 0.0  # noqa: E731
        if x < lo - slack(lo) or x > hi + slack(hi):
            unit = f" [{TABLE1[name].unit}]" if name in TABLE1 else ""
            raise ValueError(f"{what} {name}={x!r} is outside the limits [{lo!r}, {hi!r}]{unit}")
        out[name] = min(max(x, lo), hi)
    return out
