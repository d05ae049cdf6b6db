"""Deepest cut within the machine's force limits from one /soil/estimate (no rclpy).

What an autonomy stack does with the estimator's output: given the estimated soil
(φ̂, ĉ, δ̂, Δd̂ and the force F̂ at the current depth) and the known parameters Θ_k of the
same tick, predict the cutting force F(d) for candidate depths d with the FEE
(``soil_msgs_py.fee``, paper Eq. 2-10) and return the deepest d in [0, d_max] for which

    |F_x(d)| <= margin * 20 kN (tractive limit)  and  |F_z(d)| <= margin * 30 kN (lift limit).

Design choices (why)
--------------------
Failure angle β: the critical angle β* of Eq. 7 (``fee.fee_xz(beta=None)``), not the
estimated β̂. β* = argmin N_γ is the model the simulator cuts with and the point the PINN's
∂N_γ/∂β loss pulls β̂ towards; β̂ is a soft fit at the *current* depth that may trade
accuracy there for consistency elsewhere (paper §2.2.2), so carrying it to other depths
extrapolates a local fit. Note that β* of Eq. 7 does not depend on d or Q (N_γ contains
neither), so one β* holds for every candidate depth. A d-dependent angle would come from
minimising the *total* force over β instead; with a surcharge that drives β below Table 1's
11.5° (e.g. 16° at 0.3 m, 5° at 0.05 m in loose sand with a 5 kN pile) and under-predicts
the force by up to half, i.e. an optimistic plan, so it is not used.

Depth: the plan is in the commanded/geometric depth d of Θ_k; the FEE is evaluated at
d' = d + Δd̂ as in the PINN (Δd̂ is a depth-independent offset of the effective soil
surface, so it carries over to every d). d' <= 0 means no wedge and no force.

Residual force: the plan is anchored to the PINN's force prediction at the current depth.
r_now = F̂ − F_FEE(d'_now; β*) (the network's residual F_r plus the small β̂-vs-β* difference)
is what the FEE misses there. It is carried to other depths in proportion to the depth in
soil, r(d') = r_now · d'/d'_now for d' > 0 (0 out of the soil), so the prediction at the
current depth is exactly F̂ (the best estimate of the force actually felt) and the missing
force vanishes with the cut. Why proportional: what the FEE leaves out acts on the submerged
blade (edge bearing/penetration resistance ~ γ d N_q, contact damping ~ wetted area
w d / sin ρ, lost grip ~ force), i.e. to first order a force per metre of cut. It matters:
in a dense-gravel run the lift joint saturates and F_r,z ≈ −27 kN (FEE alone: −6 kN); the
FEE-only plan (0.20 m, x binds) ignores that the z force at 0.165 m is already beyond
0.8 × 30 kN, while a *constant* residual would put all 27 kN on a blade that just touches
the soil and answer −Δd̂ = 0.04 m; proportional gives 0.13 m, z binding. It is not used when
the blade was (almost) out of the soil at the estimate, d'_now < MIN_ANCHOR_DEPTH_M (F̂ = F_r
is unregularised at d' <= 0, paper §2.2.2, and dividing by a tiny d'_now amplifies noise),
nor with ``include_residual=False`` (pure FEE plan). Far from the current depth the
extrapolation is less certain: re-plan with every estimate.

Operating point: Θ_k's γ, ρ, α, w, c_a, surcharge Q and blade velocity (which sets the
Eq. 9-10 friction correction) are those of the estimate's tick; the plan is for cutting
at that speed with that pile in front of the blade, and is refreshed at every estimate.

Search: a dense grid on [0, d_max] (one vectorised FEE call), then bisection between the
last admissible grid depth and the first inadmissible one. The answer is the largest d
such that *every* depth in [0, d] is admissible: the blade reaches d through all shallower
depths, so a deeper admissible band behind an inadmissible one (force can be
non-monotonic, e.g. a residual of opposite sign) is not a plan. The surcharge term makes
F jump at d' = 0+; bisection does not need continuity. If d = 0 is already inadmissible
(Δd̂ > 0 and a large force), the depth is 0; the flags say which limit binds.
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from soil_msgs_py import fee
from soil_msgs_py.params import DEG, FORCE_LIMITS_N, KNOWN_PARAMS, MACHINE, TABLE1
from soil_msgs_py.topics import ESTIMATE_FIELDS, PLAN_FIELDS

# The blade edge reaches 0.30 m below the chassis ground reference: the deepest cut at all.
DEFAULT_D_MAX_M = -MACHINE.blade_min_rel_m
# FEE geometry ends at the blade height (Table 1's d' limit, 0.66 m): deeper, the blade is buried.
D_MAX_LIMIT_M = TABLE1["d"].limits[1]
DEFAULT_MARGIN = 0.8
GRID_POINTS = 257
TOLERANCE_M = 1e-5
# The residual is carried to other depths only from an estimate with the blade this deep in soil.
MIN_ANCHOR_DEPTH_M = 0.02
# The PINN clips its outputs to Table 1 in float32; the float64 value published can sit a
# hair outside the float64 limit. Within this relative tolerance a value counts as inside.
LIMIT_RTOL = 1e-6
# Estimate fields the plan reads (all are checked: a broken estimate is not trusted at all).
ESTIMATE_LIMITS: dict[str, tuple[float, float]] = {
    name: TABLE1[name].limits for name in ("phi", "c", "delta", "beta", "delta_d")
}
# Θ_k as published can lie outside Table 1 where the table is about the FEE's inputs, not the
# state: d < 0 is the blade above the surface (only d + Δd enters the FEE, clipped at 0).
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
    beta_rad: float  # β* used at every depth
    residual_x_n: float  # r_now: what the FEE misses at the estimate's depth [N] (0 if not used)
    residual_z_n: float
    residual_used: bool  # r(d') = r_now d'/d'_now was added (see module docstring)

    def values(self) -> list[float]:
        """Payload of /planner/max_cut_depth in ``topics.PLAN_FIELDS`` order (valid = 1)."""
        return [self.max_depth_m, self.f_x_n, self.f_z_n, float(self.limited_by_x),
                float(self.limited_by_z), 1.0]

    @property
    def binding(self) -> str:
        """'x', 'z', 'x+z' or 'reach' (d_max)."""
        axes = "+".join(a for a, hit in (("x", self.limited_by_x), ("z", self.limited_by_z)) if hit)
        return axes or "reach"


NO_PLAN_VALUES: tuple[float, ...] = (0.0,) * len(PLAN_FIELDS)  # valid = 0: every field 0.0, never NaN
assert PLAN_FIELDS == ("max_depth_m", "f_x_n", "f_z_n", "limited_by_x", "limited_by_z", "valid"), "Plan.values"


def check_settings(margin: float, d_max_m: float) -> tuple[float, float]:
    """(margin, d_max_m) as floats; ValueError naming the setting and value if out of range."""
    m, d = _number("margin", margin), _number("d_max_m", d_max_m)
    if not 0.0 < m <= 1.0:
        raise ValueError(f"margin={margin!r} must be in (0, 1] (fraction of the force limits)")
    if not 0.0 < d <= D_MAX_LIMIT_M:
        raise ValueError(f"d_max_m={d_max_m!r} must be in (0, {D_MAX_LIMIT_M}] m (blade height)")
    return m, d


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
    include_residual: bool = True,
    grid_points: int = GRID_POINTS,
    tol_m: float = TOLERANCE_M,
) -> Plan | None:
    """Deepest admissible cut for ``estimate`` (ESTIMATE_FIELDS) with Θ_k ``known`` (KNOWN_PARAMS).

    None for an invalid estimate (valid = 0: there is nothing to plan from). ValueError,
    naming the field and value, for a missing, non-finite or out-of-limits field, a bad
    setting, or parameters for which the FEE has no failure wedge (non-finite force).
    See the module docstring for β, the residual and the search.
    """
    margin, d_max_m = check_settings(margin, d_max_m)
    if int(grid_points) != grid_points or grid_points < 2:
        raise ValueError(f"grid_points={grid_points!r} must be an integer >= 2")
    if not 0.0 < tol_m:
        raise ValueError(f"tol_m={tol_m!r} must be > 0 m")
    valid = _number("estimate valid", _get(estimate, "valid", "estimate"))
    if valid not in (0.0, 1.0):
        raise ValueError(f"estimate valid={valid!r} must be 1.0 or 0.0")
    if valid == 0.0:
        return None
    est = _checked(estimate, ESTIMATE_FIELDS, ESTIMATE_LIMITS, "estimate")
    kn = _checked(known, KNOWN_PARAMS, KNOWN_LIMITS, "known")
    limits = np.array([margin * FORCE_LIMITS_N[0], margin * FORCE_LIMITS_N[1]])
    model = _ForceModel(est, kn, include_residual)

    grid = np.linspace(0.0, d_max_m, int(grid_points))
    fx, fz = model(grid)
    ok = (np.abs(fx) <= limits[0]) & (np.abs(fz) <= limits[1])
    if ok.all():
        depth, hit_x, hit_z = d_max_m, False, False
    elif not ok[0]:
        depth, hit_x, hit_z = 0.0, bool(abs(fx[0]) > limits[0]), bool(abs(fz[0]) > limits[1])
    else:
        k = int(np.argmin(ok))  # first inadmissible grid depth
        lo, hi = float(grid[k - 1]), float(grid[k])
        while hi - lo > tol_m:
            mid = 0.5 * (lo + hi)
            mx, mz = model(np.array([mid]))
            if abs(mx[0]) <= limits[0] and abs(mz[0]) <= limits[1]:
                lo = mid
            else:
                hi = mid
        hx, hz = model(np.array([hi]))
        depth, hit_x, hit_z = lo, bool(abs(hx[0]) > limits[0]), bool(abs(hz[0]) > limits[1])
    f_x, f_z = model(np.array([depth]))
    return Plan(
        max_depth_m=float(depth), f_x_n=float(f_x[0]), f_z_n=float(f_z[0]),
        limited_by_x=hit_x, limited_by_z=hit_z, limit_x_n=float(limits[0]), limit_z_n=float(limits[1]),
        d_max_m=d_max_m, beta_rad=model.beta_rad,
        residual_x_n=float(model.residual[0]), residual_z_n=float(model.residual[1]),
        residual_used=model.residual_used,
    )


class _ForceModel:
    """F(d) = F_FEE(d'; β*) + r_now d'/d'_now [d' > 0], d' = d + Δd̂, for arrays of depths d [m]."""

    def __init__(self, est: dict[str, float], known: dict[str, float], include_residual: bool):
        self.theta = {**known, "phi": est["phi"], "c": est["c"], "delta": est["delta"]}
        self.delta_d = est["delta_d"]
        # β* as fee_xz(beta=None) computes it, here only to report it and to fail clearly
        delta_v, _ = fee.velocity_corrected(est["delta"], known["c_a"], known["rho"], known["alpha"],
                                            known["v_x"], known["v_z"])
        self.beta_rad = float(fee.beta_star(est["phi"], delta_v, known["rho"], known["alpha"]))
        if not math.isfinite(self.beta_rad):
            raise ValueError(
                f"no FEE failure wedge (no critical β) for phi={est['phi'] / DEG:.2f}°, "
                f"delta={est['delta'] / DEG:.2f}°, "
                f"rho={known['rho'] / DEG:.2f}°, alpha={known['alpha'] / DEG:.2f}°")
        d_now = known["d"] + self.delta_d  # d' of the estimate
        self.residual = np.zeros(2)
        self.residual_per_m = np.zeros(2)
        self.residual_used = bool(include_residual and d_now >= MIN_ANCHOR_DEPTH_M)
        if self.residual_used:
            fx_now, fz_now = self._fee(np.array([known["d"]]))
            self.residual = np.array([est["f_x_hat"] - fx_now[0], est["f_z_hat"] - fz_now[0]])
            self.residual_per_m = self.residual / d_now

    def _fee(self, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        fx, fz, _ = fee.fee_xz({**self.theta, "d": d + self.delta_d})
        return fx, fz

    def __call__(self, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        fx, fz = self._fee(d)
        depth_in_soil = np.maximum(d + self.delta_d, 0.0)  # d' > 0, else no soil and no residual
        fx = fx + self.residual_per_m[0] * depth_in_soil
        fz = fz + self.residual_per_m[1] * depth_in_soil
        if not (np.isfinite(fx).all() and np.isfinite(fz).all()):
            bad = float(d[~(np.isfinite(fx) & np.isfinite(fz))][0])
            raise ValueError(f"FEE force is not finite at depth d={bad:.4f} m "
                             f"(phi={self.theta['phi'] / DEG:.2f}°, delta={self.theta['delta'] / DEG:.2f}°)")
        return fx, fz


def describe(plan: Plan, estimate: Mapping[str, float], known: Mapping[str, float]) -> str:
    """One human log line: the depth, what binds, and the soil and state it was planned for."""
    if plan.binding == "reach":
        why = f"reach d_max={plan.d_max_m:.2f} m binds; F_x {plan.f_x_n / 1e3:.1f} of {plan.limit_x_n / 1e3:.1f} kN"
    else:
        lim = {"x": plan.limit_x_n, "z": plan.limit_z_n}
        why = ", ".join(f"{a} limit binds: {lim[a] / 1e3:.1f} kN" for a in plan.binding.split("+"))
    residual = (f"F_r now ({plan.residual_x_n / 1e3:+.1f}, {plan.residual_z_n / 1e3:+.1f}) kN"
                if plan.residual_used else "FEE only")
    return (
        f"deepest cut {plan.max_depth_m:.2f} m ({why}) from φ={estimate['phi'] / DEG:.1f}°, "
        f"c={estimate['c'] / 1e3:.1f} kPa, δ={estimate['delta'] / DEG:.1f}°, "
        f"Δd={estimate['delta_d'] * 100:+.1f} cm, "
        f"β*={plan.beta_rad / DEG:.1f}°, {residual}; "
        f"now d={known['d']:.2f} m, Q={known['q'] / 1e3:.1f} kN, v_x={known['v_x']:.2f} m/s"
    )


# --- validation ----------------------------------------------------------------------------

def _number(name: str, value) -> float:
    if isinstance(value, bool):
        raise ValueError(f"{name}={value!r} must be a number")
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name}={value!r} must be a number") from None
    if not math.isfinite(x):
        raise ValueError(f"{name}={value!r} must be finite")
    return x


def _get(data: Mapping[str, float], name: str, what: str):
    try:
        return data[name]
    except KeyError:
        raise ValueError(f"{what} has no field {name!r}") from None


def _checked(data: Mapping[str, float], names: Sequence[str], limits: Mapping[str, tuple[float, float]],
             what: str) -> dict[str, float]:
    """Every field finite and inside its limits (snapped in within LIMIT_RTOL)."""
    out = {}
    for name in names:
        x = _number(f"{what} {name}", _get(data, name, what))
        lo, hi = limits.get(name, (-math.inf, math.inf))
        slack = lambda b: LIMIT_RTOL * max(1.0, abs(b)) if math.isfinite(b) else 0.0  # noqa: E731
        if x < lo - slack(lo) or x > hi + slack(hi):
            unit = f" [{TABLE1[name].unit}]" if name in TABLE1 else ""
            raise ValueError(f"{what} {name}={x!r} is outside the limits [{lo!r}, {hi!r}]{unit}")
        out[name] = min(max(x, lo), hi)
    return out
