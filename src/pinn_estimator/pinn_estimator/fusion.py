"""Evidence fused along the path: a Bayesian posterior over the soil θ = (φ, c, δ) (no rclpy, no torch).

Why not the PINN's per-window θ̂: a 1 s window sees one depth, where γd²wN_γ(φ) + c·d·w·N_c(φ)
is one number, so φ and c trade off and the window's θ̂ says nothing reliable about another
depth. Here every stretch of cutting (``update_ticks`` samples, averaged) is evidence through
the physics model itself, F = F_FEE(θ, Θ_k) (+ the checkpoint's catalogue terms, the same
``AugmentedFEE`` the PINN's physics part uses), and successive stretches at different depths,
speeds and surcharges multiply into one posterior that pins φ and c down jointly. F_x/F_z
fixes δ (Eq. 8: the force's direction depends on ρ, δ, α only).

Representation: a sum of ``components`` Gaussians side by side along φ's prior box (Table 1's
normalisation ranges, widened to hold every catalogue soil in both worlds; c through a
softplus, see ``SoilPosterior``), each updated per stretch by an iterated extended Kalman step
(Gauss-Newton to the stretch's MAP) and weighted by its predictive likelihood (the Laplace
approximation at that MAP). Why not
particles: in the fee world the model is exact, the likelihood of one stretch is a ridge a few
tenths of a percent wide, and a particle cloud (tried: fixed Sobol support and resample-move,
4k-65k particles) never has points on it (φ error 7-11° where two depths give ~1-4° here).
Why a sum: one depth leaves a curved φ-c ridge that one Gaussian cannot follow (its forecasts
missed in 13 of 24 sand and gravel pairs). ``/soil/estimate`` carries the sum's moments.

Evidence is the soil's force: the measured force minus the blade's inertia m_b·a, against the
model at the conditions of the tick the force is the mean of (``PathFusion``,
``soil_physics.blade_inertia``). Likelihood of a stretch's mean force F̄ given θ: independent
Gaussians per axis with standard deviation σ_j = abs_j + rel_j·|F_model,j|, widened by the
force's spread within the stretch (a transient is not a steady cut), and the model averaged over
the stretch's Θ_k sub-means. With ``shape_evidence`` the stretch is its sub-means, which share
that error and each add their own in how they depart from the others (``_Evidence``): the
force's change along a ramp in depth is what tells φ from c at one target depth. Only ticks the
quasi-static FEE describes count there (``quasi_static``), and a sub-mean the prediction says is
an outlier is down-weighted. Residuals of successive stretches are correlated (the same missing
physics), so each stretch's evidence can be tempered by ``evidence_weight`` κ ≤ 1. The error
model's numbers are calibrated on episodes other than the ones the evaluation scores.

Prior: broad over Table 1's ranges, plus (``cohesionless_prior``) a row of components at c = 0,
the clean sands' and gravels' own state, at the end of c's coordinate (``SoilPosterior``), and
(``stiff_prior``) one at c = 30 kPa, stiff soils beyond Table 1's cohesions.

Soil that changes: between stretches the covariance grows with the blade's travel (a random
walk of the soil along the path, ``drift_per_sqrt_m``), and the soil may have jumped to a new
one (a patch boundary, probability 1 − exp(−travel/``patch_length_m``)): each stretch weighs
that hypothesis, the prior updated by the stretch, against the current soil by their
predictive likelihoods (a change point; the heaviest ``components`` of both are kept), so a
new soil whose force differs by a few σ per stretch takes over within a few stretches. A
stretch the current soil cannot explain at all (normalised innovation beyond ``change_nis``
for every component) restarts from the prior at once.

Forecast: the force at other conditions (another depth) is the model's force over fixed
samples of the posterior plus the forecast error law (``forecast_*``); its mean and quantiles
are exact for that mixture (``soil_physics.predictive.mixture_quantiles``).

Every setting named here (``update_ticks``, ``evidence_weight``, the error laws, ...) is a field of
``fusion_config.FusionConfig``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from soil_msgs_py.params import DEG, FORCE_LIMITS_N, KNOWN_PARAMS, MIN_CUT_DEPTH_M, SAMPLE_RATE_HZ, STEADY_CUT_MAX_ABS_V_Z_M_S, TABLE1
from soil_physics import fee
from soil_physics.augmented_fee import AugmentedFEE
from soil_physics.blade_inertia import blade_position, blade_velocity, inertia_force_n
from soil_physics.predictive import extrapolated_part, mixture_quantiles, model_error_std, near_limit_error_std
from soil_physics.travel import soil_advance, time_in_soil_of_known

from .fusion_config import FusionConfig

THETA = ("phi", "c", "delta")
# Prior box of φ and δ [rad]: Table 1's normalisation ranges (17-45°, 11-35°) widened so that
# every soil of the catalogue and both worlds' δ (10° default, 15° fee) lie well inside: the
# prior is a Gaussian centred on the box with ``prior_std`` of its width. c: see C_SCALE_PA.
PRIOR_BOX: dict[str, tuple[float, float]] = {
    "phi": (TABLE1["phi"].norm[0] - 7 * DEG, TABLE1["phi"].norm[1] + 5 * DEG),
    "delta": (TABLE1["delta"].norm[0] - 6 * DEG, TABLE1["delta"].norm[1]),
}
# A stiff prior component's c (``stiff_prior``): u = 1.75 ± 0.3, c = 30 ± 6 kPa, stiff clays and
# hardpans beyond Table 1's cohesions (the broad row's c is 5 kPa ± 6 kPa per standard deviation
# of u, so a 30 kPa soil lay 4-5 of them out and sat on the old 20 kPa bound).
STIFF_U, STIFF_STD_U = 1.75, 0.3
# Internal coordinates u (φ, c, δ) are kept within [U_LOWER, U_UPPER] by every update: far outside
# the prior box is not physical. c's reaches 5 standard deviations above the stiff row's centre
# (u = 3.25, c = 60 kPa).
U_LOWER = -0.25
U_UPPER = np.array([1.25, STIFF_U + 5 * STIFF_STD_U, 1.25])
U_UPPER.setflags(write=False)
# Internal coordinate of c (see SoilPosterior): c = C_SCALE_PA·(softplus(V_LO + u·V_SPAN) −
# softplus(V_ZERO)), 0 at and below u = U_LOWER (V_ZERO); u = 0 is c ≈ 7 Pa, u = 0.5
# c ≈ 5 kPa, u = 1 c ≈ 15 kPa (Table 1's 0-10 kPa and more), above that 20 kPa per unit of u.
C_SCALE_PA = 1e3
V_LO, V_SPAN = -5.0, 20.0
V_ZERO = V_LO + U_LOWER * V_SPAN
SOFTPLUS_AT_ZERO = math.log1p(math.exp(V_ZERO))  # softplus(V_ZERO), what c's map subtracts
# A model force beyond this [N] is the FEE near its singularity (η → 180°), taken as undefined
# (``SoilPosterior.model_point_forces``): 30 times the machine's largest force limit, far beyond any
# soil it can cut. Not ``params.MAX_PLAUSIBLE_FORCE_N`` (10× more), which bounds what any soil,
# effect or plugin may put on a blade at all.
FEE_SINGULAR_FORCE_N = 30.0 * max(FORCE_LIMITS_N)
# A cohesionless prior component's c: u = U_LOWER ± 0.05, where c is 0 (below) or under
# 0.3 Pa (within two standard deviations above): c = 0 in effect, with the same Gaussian algebra
# as every other component.
COHESIONLESS_U, COHESIONLESS_STD_U = U_LOWER, 0.05
_D, _VX, _VZ = KNOWN_PARAMS.index("d"), KNOWN_PARAMS.index("v_x"), KNOWN_PARAMS.index("v_z")
# A fused δ above φ by more than this [rad] is said (``SoilPosterior.not_a_soil``): a posterior
# whose components sit on δ = φ has a sample mean a few tenths of a degree either side.
NOT_A_SOIL_MARGIN_RAD = 1.0 * DEG
# Stretches in a row (4 s) a posterior must be no soil before it is said (``online``): a catalogue
# soil's early posteriors pass such corners for up to 5 stretches (the default world's held-out and
# strong-gravel episodes), the posteriors that end as no soil hold it 15-19 stretches.
NOT_A_SOIL_STRETCHES = 8
# Share of the posterior's weight whose mean sits at the end of a coordinate's range
# (U_LOWER / U_UPPER, within HELD_AT_BOUND_U: 0.2° of φ, 0.15° of δ) beyond which that parameter
# is said to be held there (a strong gravel's φ component ended at u = -0.2497 ± 0.0002).
HELD_AT_BOUND_SHARE = 0.5
HELD_AT_BOUND_U = 0.005
MIN_STRETCH_DEPTH_M = MIN_CUT_DEPTH_M  # a stretch with the blade (almost) out of the soil carries no evidence
# Halvings of a Gauss-Newton step that landed where the model is undefined, back towards the last
# iterate it was defined at (``SoilPosterior._update_components``): the step reaches 1/8 of its length.
MAX_STEP_HALVINGS = 3


@dataclass
class Summary:
    """Posterior moments of θ (and of β* at the last stretch's motion) [SI]."""

    mean: dict[str, float]
    std: dict[str, float]
    corr: dict[str, float]  # "phi_c", "phi_delta", "c_delta"
    updates: int
    changes: int  # stretches that the current soil could not explain: a new soil began




def _inverses(mats: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(inverses, invertible) of a stack of matrices (A, n, n): one at a time where the batch
    holds a singular one (whose inverse is left NaN)."""
    try:
        return np.linalg.inv(mats), np.ones(len(mats), bool)
    except np.linalg.LinAlgError:
        out, ok = np.full_like(mats, np.nan), np.ones(len(mats), bool)
        for i, m in enumerate(mats):
            try:
                out[i] = np.linalg.inv(m)
            except np.linalg.LinAlgError:
                ok[i] = False
        return out, ok


def _normalised(u, p, log_joint, nis):
    """A Gaussian sum from ``SoilPosterior._update_components``'s per-component results:
    (means, covariances, normalised log-weights, smallest NIS, log predictive likelihood of the
    stretch under the sum); None if no component's model is defined."""
    defined = np.isfinite(log_joint)
    if not defined.any():
        return None
    log_z = float(np.logaddexp.reduce(log_joint[defined]))
    return u, p, log_joint - log_z, float(nis[defined].min()), log_z


# Sub-means whose departure from the stretch's other sub-means the component's prediction
# misses by this many standard deviations are down-weighted (``_Evidence.robust_inflation``).
ROBUST_SIGMAS = 3.0


class _Evidence:
    """One stretch as the observation of a Kalman update: y, the model's h(θ) in the same
    layout, and the covariance R(h) of their difference.

    Without shape evidence: y = the stretch's mean force (x, z), R = diag(σ_x², σ_z²) of the
    model error law (``SoilPosterior.sigma``). With it (``FusionConfig.shape_evidence``):
    y = the G sub-means of force, x then z, and per axis R = σ²·11ᵀ + diag(σ_dev,g²): the
    sub-means share the stretch's model error σ (so their mean teaches exactly what the stretch
    mean did) and each has its own error σ_dev,g in how it departs from the others
    (``FusionConfig.shape_*``), which is what lets the force's change along a ramp in depth tell
    φ from c; plus, over both axes, vvᵀ with v = g·τ·(the force's rate of change at each sub-mean),
    g = ``shape_noise_gain``, τ = ``SAMPLE_TIMING_TICKS``: one error in when force and conditions
    were sampled, common to the stretch (see there). Sub-means in which the blade was not quasi-static (``quasi_static``)
    are left out; in a stretch where it never was, nothing is learnt."""

    def __init__(self, post: "SoilPosterior", force_n, known, spread_n, point_force_n=None, point_noise_n=None,
                 point_unsteady=None, point_rate_n=None):
        self.post, self.spread = post, spread_n
        self.known = np.atleast_2d(known)
        points = len(self.known)
        self.shape = bool(post.cfg.shape_evidence and point_force_n is not None and points > 1)
        if self.shape:
            point_force_n, point_noise_n = np.asarray(point_force_n, float), np.asarray(point_noise_n, float)
            keep = np.ones(points, bool) if point_unsteady is None else ~np.asarray(point_unsteady, bool)
            rate = np.zeros((points, 2)) if point_rate_n is None else np.asarray(point_rate_n, float)
            if (point_force_n.shape != (points, 2) or point_noise_n.shape != (points, 2) or keep.shape != (points,)
                    or rate.shape != (points, 2)):
                raise ValueError(f"stretch sub-means of shape {point_force_n.shape} / {point_noise_n.shape} / {keep.shape} / "
                                 f"{rate.shape} (force / noise / unsteady / rate), "
                                 f"expected ({points}, 2) / ({points}, 2) / ({points},) / ({points}, 2) for {points} Θ_k sub-means")
            self.known = self.known[keep]
            self.y = point_force_n[keep].T.reshape(-1)  # x sub-means, then z
            self.noise = point_noise_n[keep].T  # (2, G kept)
            # what a common error in the timing of force and conditions does to the sub-means (x then
            # z), the same at every iterate: its covariance once
            timing = post.cfg.shape_noise_gain * SAMPLE_TIMING_TICKS * rate[keep].T.reshape(-1)
            self.timing_cov = np.outer(timing, timing)
        else:
            self.y = np.asarray(force_n, float)
        self.points = len(self.known)

    def observe(self, fx: np.ndarray, fz: np.ndarray) -> np.ndarray:
        """The model's forces at the sub-means (K, G) each -> h (K, dim)."""
        if self.shape:
            return np.concatenate([fx, fz], axis=1)
        return np.stack([fx.mean(axis=1), fz.mean(axis=1)], axis=1)

    def covariance(self, h: np.ndarray, inflation: np.ndarray | None = None) -> np.ndarray:
        """R (K, dim, dim) at model observations h (K, dim), untempered; ``inflation`` (K, dim)
        multiplies each sub-mean's σ_dev (``robust_inflation``)."""
        k = len(h)
        if not self.shape:
            sx, sz = self.post.sigma(h[:, 0], h[:, 1], self.spread)
            r = np.zeros((k, 2, 2))
            r[:, 0, 0], r[:, 1, 1] = sx ** 2, sz ** 2
            return r
        g, cfg = self.points, self.post.cfg
        hx, hz = h[:, :g], h[:, g:]
        shared = self.post.sigma(hx.mean(axis=1), hz.mean(axis=1), self.spread)
        r = np.zeros((k, 2 * g, 2 * g))
        for j, hj in enumerate((hx, hz)):
            block = slice(j * g, (j + 1) * g)
            departure = np.abs(hj - hj.mean(axis=1, keepdims=True))
            dev = np.hypot(cfg.shape_abs_std_n[j] + cfg.shape_rel_std[j] * departure, cfg.shape_noise_gain * self.noise[j])
            if inflation is not None:
                dev = dev * inflation[:, block]
            r[:, block, block] = shared[j][:, None, None] ** 2 + dev[:, :, None] * np.eye(g) * dev[:, None, :]
        return r + self.timing_cov[None]

    def robust_inflation(self, innovation: np.ndarray, s_mat: np.ndarray) -> np.ndarray:
        """(K, dim) factors on σ_dev from each component's prediction of the stretch (innovation
        y − h at its prior mean, its covariance S): √(1 + (z/k)²), z how far a sub-mean's departure
        from the others' mean lies from the predicted one, in the predicted standard deviations of
        that departure, k = ``ROBUST_SIGMAS`` (the weights of a Cauchy error: a gross outlier's
        influence falls off). Why: a transient the quasi-static model lacks and the quasi-static
        test misses (the lift joint's motion within a tick reversing some of the soil-tool
        friction while the samples say the blade holds its depth) departs from the others by
        10-20 of their σ_dev and decays over a few sub-means as the depth does; with full weight
        the posterior took it for the φ-c trade that explains a change with depth (fee-world clay
        moved 3° in one stretch). Judged against the prediction, not the updated fit, which has
        already bent θ towards it. All 1 without shape evidence."""
        if not self.shape:
            return np.ones_like(innovation)
        g = self.points
        centre = np.eye(g) - 1.0 / g
        out = np.ones_like(innovation)
        for j in range(2):
            block = slice(j * g, (j + 1) * g)
            departure = innovation[:, block] @ centre.T
            var = np.einsum("ij,ajk,ik->ai", centre, s_mat[:, block, block], centre)
            out[:, block] = np.sqrt(1.0 + (departure / np.sqrt(np.maximum(var, 1e-12)) / ROBUST_SIGMAS) ** 2)
        return out

    def mean_nis(self, innovation: np.ndarray, s_mat: np.ndarray, s_inv: np.ndarray) -> np.ndarray:
        """Normalised innovation of the stretch's mean force (2 dof, what ``change_nis`` is for);
        ``s_inv`` is ``s_mat``'s inverse, which without shape evidence is already the answer's."""
        if self.shape:
            mean = np.kron(np.eye(2), np.full((1, self.points), 1.0 / self.points))  # (2, dim)
            innovation, s_mat = innovation @ mean.T, mean @ s_mat @ mean.T
            s_inv = np.linalg.inv(s_mat)
        return np.einsum("ai,aij,aj->a", innovation, s_inv, innovation)


class SoilPosterior:
    """The Gaussian posterior over θ = (φ, c, δ) of the soil being cut (see module docstring).

    Inside, the state u is θ scaled so the three are comparable: φ and δ linearly onto their
    prior box (u = (θ − lo)/(hi − lo)), and c through a softplus, c = C_SCALE_PA·(softplus(v) −
    softplus(V_ZERO)), v = V_LO + u·V_SPAN, 0 at and below u = U_LOWER. Why: c ≥ 0, and a
    cohesionless soil (c = 0) sits at the end of the φ-c ridge one depth leaves; linear and
    clipped at c = 0 the Gaussian broke the ridge there and its forecasts missed in 13 of 24 sand
    and gravel pairs; through the softplus the ridge runs on to c = 0 with φ where it belongs.
    What the posterior says in SI is from samples (``summary``) or exact (``quantiles``)."""

    def __init__(self, cfg: FusionConfig | None = None):
        self.cfg = cfg or FusionConfig()
        self.model = AugmentedFEE(self.cfg.terms)
        draws = np.random.default_rng(self.cfg.seed).standard_normal((self.cfg.forecast_samples, len(THETA)))
        self._draws = draws  # fixed: the same posterior always gives the same forecast
        self.reset()

    def _prior(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(means, covariances (·, 3, 3), log-weights) of the prior as a Gaussian sum: K components
        side by side along φ's box, each as wide as their spacing, weighted by the broad Gaussian
        prior (centre of the box, ``prior_std``) at their centre; with ``cohesionless_prior`` > 0
        the same K again at c = 0 (u_c ``COHESIONLESS_U`` ± ``COHESIONLESS_STD_U``), that share of the
        weight, and with ``stiff_prior`` > 0 the same K at a stiff c (``STIFF_U`` ± ``STIFF_STD_U``)."""
        k, sd = self.cfg.components, self.cfg.prior_std
        centres = np.linspace(0.0, 1.0, k) if k > 1 else np.array([0.5])  # the φ box, 10-50°
        u = np.tile(np.full(len(THETA), 0.5), (k, 1))
        u[:, THETA.index("phi")] = centres
        width = 1.0 / (k - 1) if k > 1 else sd
        p = np.tile(np.diag([sd ** 2] * len(THETA)), (k, 1, 1))
        p[:, THETA.index("phi"), THETA.index("phi")] = width ** 2
        log_w = -0.5 * ((centres - 0.5) / sd) ** 2
        log_w = log_w - np.logaddexp.reduce(log_w)
        rows_u, rows_p = [u], [p]
        with np.errstate(divide="ignore"):  # shares summing to 1: the broad row has no weight
            rows_w = [log_w + np.log1p(-(self.cfg.cohesionless_prior + self.cfg.stiff_prior))]
        ic = THETA.index("c")
        for share, c_u, c_std_u in ((self.cfg.cohesionless_prior, COHESIONLESS_U, COHESIONLESS_STD_U),
                                    (self.cfg.stiff_prior, STIFF_U, STIFF_STD_U)):
            if share > 0:
                row_u, row_p = u.copy(), p.copy()
                row_u[:, ic], row_p[:, ic, ic] = c_u, c_std_u ** 2
                rows_u.append(row_u), rows_p.append(row_p), rows_w.append(log_w + math.log(share))
        return np.concatenate(rows_u), np.concatenate(rows_p), np.concatenate(rows_w)

    def reset(self) -> None:
        """Back to the prior."""
        self.u, self.p, self.log_w = self._prior()
        self.updates = 0
        self.changes = 0
        self.rejected = 0  # sinking stretches no component could explain (left out, see update)
        self.rising = 0  # stretches whose edge rose (left out, see update)
        self.last_known: np.ndarray | None = None
        self.log_no_jump = 0.0  # log of the probability that the soil is the same since the last stretch weighed it (``forget``)

    @property
    def weights(self) -> np.ndarray:
        """Component weights (sum 1)."""
        return np.exp(self.log_w - np.logaddexp.reduce(self.log_w))

    # -- the soil model between stretches
    def forget(self, travel_m: float) -> None:
        """Soil that varies along the path: every component's covariance grows by
        ``drift_per_sqrt_m``² per metre of blade travel (a random walk of θ, internal units),
        and the soil may have jumped to a new one (a patch boundary) with probability
        1 − exp(−travel / ``patch_length_m``), which the next ``update`` weighs."""
        if travel_m > 0:
            self.p = self.p + np.eye(len(THETA)) * self.cfg.drift_per_sqrt_m ** 2 * travel_m
            if self.cfg.patch_length_m > 0:
                self.log_no_jump -= travel_m / self.cfg.patch_length_m  # summed in logs: never rounds to certainty

    # -- the physics model
    @staticmethod
    def theta_of(u: np.ndarray) -> dict[str, np.ndarray]:
        """SI θ of internal points u (..., 3)."""
        u = np.asarray(u, float)
        out = {n: PRIOR_BOX[n][0] + u[..., j] * (PRIOR_BOX[n][1] - PRIOR_BOX[n][0]) for j, n in enumerate(THETA) if n in PRIOR_BOX}
        softplus = np.logaddexp(0.0, V_LO + u[..., THETA.index("c")] * V_SPAN)
        out["c"] = C_SCALE_PA * np.maximum(softplus - SOFTPLUS_AT_ZERO, 0.0)
        return {n: out[n] for n in THETA}

    def model_force(self, u: np.ndarray, known: np.ndarray, distance_m: float = 0.0,
                    time_s: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """(F_x, F_z) [N] of the model at scaled points u (K, 3) for Θ_k (9,) or the mean over
        the rows of (G, 9) (a stretch's sub-means: the model averaged over the stretch, not the
        force at its mean Θ_k, which the tanh of the Eq. 9-10 velocity correction makes a
        different number whenever v_z moves). NaN where the model is undefined."""
        fx, fz = self.model_point_forces(u, known, distance_m, time_s)
        return fx.mean(axis=1), fz.mean(axis=1)

    def model_point_forces(self, u: np.ndarray, known: np.ndarray, distance_m: float = 0.0,
                           time_s: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """(F_x, F_z) [N], each (K, G): the model at scaled points u (K, 3) for each row of Θ_k
        (G, 9) (or (9,), G = 1), at travel ``distance_m`` [m] and time ``time_s`` [s] in soil (for
        terms that look at them). NaN where the model is undefined: no failure wedge, or a force
        beyond ``FEE_SINGULAR_FORCE_N``, which is the FEE's singularity (η → 180°, paper §2.2.2)
        rather than a soil, and whose derivatives (~1e15 N per unit of u) make a component's
        predictive covariance singular."""
        known = np.atleast_2d(np.asarray(known, float))
        theta = {n: v[:, None] for n, v in self.theta_of(np.atleast_2d(u)).items()}
        fx, fz = self.model.force(theta, known[None, :, :], np.full(known.shape[0], distance_m),
                                  time_in_soil=np.full(known.shape[0], time_s))
        with np.errstate(invalid="ignore"):
            wild = (np.abs(fx) > FEE_SINGULAR_FORCE_N) | (np.abs(fz) > FEE_SINGULAR_FORCE_N)
        return np.where(wild, np.nan, fx), np.where(wild, np.nan, fz)

    def sigma(self, fx, fz, spread_n=(0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
        """The evidence's model error (x, z) [N]: floor + share of the force, widened by a
        stretch's unsteadiness (the forecast's law: ``forecast_from``)."""
        (ax, az), (rx, rz), g = self.cfg.abs_std_n, self.cfg.rel_std, self.cfg.unsteady_gain
        return (np.hypot(model_error_std(fx, ax, rx), g * spread_n[0]), np.hypot(model_error_std(fz, az, rz), g * spread_n[1]))

    # -- evidence
    def update(self, force_n: np.ndarray, known: np.ndarray, spread_n=(0.0, 0.0), distance_m: float = 0.0, *,
               time_s: float = 0.0,
               point_force_n: np.ndarray | None = None, point_noise_n: np.ndarray | None = None,
               point_unsteady: np.ndarray | None = None, point_rate_n: np.ndarray | None = None) -> bool:
        """One stretch of evidence: its mean measured force (F_x, F_z) [N], Θ_k (its sub-means)
        and the force's standard deviation within it [N] (a stretch whose force moves, the blade
        entering or the controller acting, is widened by ``unsteady_gain`` × that spread); with
        ``shape_evidence`` also the force's sub-means (G, 2) [N], their noise (G, 2) [N],
        whether the blade was quasi-static in each (G,) and the force's rate of change at each
        (G, 2) [N per tick; None: 0] (``Stretch``; ``_Evidence``).

        Per component an iterated extended Kalman update (Gauss-Newton to the stretch's MAP;
        Jacobians by forward differences), and its weight times its predictive likelihood
        (Laplace, at the updated mean). A
        stretch that not even the best component can explain (normalised innovation beyond
        ``change_nis``) means a new soil: the posterior restarts from the prior for it, unless
        the edge was sinking (mean v_z below −``params.STEADY_CUT_MAX_ABS_V_Z_M_S``): then it is
        a transient the quasi-static model lacks (the penetration reaction while the edge
        sinks), not a new soil, and the stretch is left out. A stretch whose edge rises (mean v_z
        above ``params.STEADY_CUT_MAX_ABS_V_Z_M_S``) is left out too: no equilibrium. False
        (nothing learnt) for such a stretch, when the blade was not in the soil, a value is not
        finite or no component's model has a failure wedge here."""
        force_n, known, spread_n = np.asarray(force_n, float), np.asarray(known, float), np.asarray(spread_n, float)
        finite = np.isfinite(force_n).all() and np.isfinite(known).all() and np.isfinite(spread_n).all()
        if not finite or np.atleast_2d(known)[:, _D].mean() < MIN_STRETCH_DEPTH_M:
            return False
        evidence = _Evidence(self, force_n, known, spread_n, point_force_n, point_noise_n, point_unsteady, point_rate_n)
        if not len(evidence.y):
            return False
        if np.atleast_2d(known)[:, _VZ].mean() > STEADY_CUT_MAX_ABS_V_Z_M_S:
            # the blade rising (the controller's anti-stall lift): no equilibrium of the FEE (the
            # lift joint's motion reverses part of the Eq. 9-10 friction and the floor lets go of
            # the held edge, F_z -13 -> -5 kN in one stretch), and taken as evidence it moved a
            # loam's posterior by 8° or widened it as a new soil, the planner retreating to 0 m
            self.rising += 1
            return False
        sinking = np.atleast_2d(known)[:, _VZ].mean() < -STEADY_CUT_MAX_ABS_V_Z_M_S
        # a new soil (restart or change point) is never weighed before the first stretch nor on a
        # sinking one; a change point's prior components are updated with the current ones, in one batch
        weigh_jump = self.updates > 0 and not sinking and self.log_no_jump < 0
        k = len(self.log_w)
        u0, p0, log_w0 = self.u, self.p, self.log_w
        if weigh_jump:
            pu, pp, pw = self._prior()
            u0, p0, log_w0 = np.concatenate([u0, pu]), np.concatenate([p0, pp]), np.concatenate([log_w0, pw])
        step = self._update_components(u0, p0, log_w0, evidence, distance_m, time_s)
        current = _normalised(*(part[:k] for part in step))
        fresh = _normalised(*(part[k:] for part in step)) if weigh_jump else None
        # nothing the current soil can explain (no component defined here counts as that too)
        if self.updates and (current is None or current[3] > self.cfg.change_nis):
            if sinking:
                self.rejected += 1
                return False
            if fresh is None:
                fresh = _normalised(*self._update_components(*self._prior(), evidence, distance_m, time_s))
            if fresh is not None:
                current = fresh
                self.changes += 1
                self.log_no_jump = 0.0
        elif fresh is not None:
            current = self._weigh_jump(current, fresh)
            self.log_no_jump = 0.0
        if current is None:
            return False
        if not self.updates:
            self.log_no_jump = 0.0
        self.u, self.p, self.log_w = current[:3]
        self.updates += 1
        self.last_known = np.atleast_2d(known).mean(axis=0)
        return True

    def _weigh_jump(self, kept, fresh):
        """The soil kept or a new one since the last stretch: both hypotheses updated by the
        stretch (the current components; the prior's), weighted by their prior probability
        (1 − h, h the jump probability since the last weighing, ``forget``) times the stretch's
        predictive likelihood under each (the Bayes factor of a change point), and the heaviest
        ``components`` kept (with ``components`` = 1 the new soil must win within one stretch).

        Why, beside the restart on a stretch nothing explains: a new soil whose force differs
        from the old one's by less than that (a few σ per stretch) used to be absorbed only by
        the slow drift (fee world, Loam 30 % → Gravel 70 %: never, the posterior stayed on the
        loam's φ); here its evidence adds up over a few stretches. In a steady soil the fresh
        hypothesis, as wide as the prior along the φ-c ridge, predicts worse than the current
        one and stays light. A sinking stretch weighs nothing, and the jump probability carries
        over to the next stretch that does."""
        log_stay, log_jump = self.log_no_jump, math.log(-math.expm1(self.log_no_jump))
        log_w = np.concatenate([kept[2] + kept[4] + log_stay, fresh[2] + fresh[4] + log_jump])
        keep = np.argsort(-log_w, kind="stable")[: self.cfg.components]
        u, p = np.concatenate([kept[0], fresh[0]])[keep], np.concatenate([kept[1], fresh[1]])[keep]
        log_w = log_w[keep]
        return u, p, log_w - np.logaddexp.reduce(log_w)

    def _update_components(self, u0, p0, log_w0, evidence: "_Evidence", distance_m: float = 0.0, time_s: float = 0.0,
                           iterations: int = 6, eps: float = 1e-4):
        """(means, covariances, log prior weight + log predictive likelihood, NIS) per component
        after one stretch; a component whose model is undefined here keeps its mean and
        covariance with log weight −inf and NIS inf (``_normalised`` makes a sum of them).

        Every component's iterated extended Kalman update at once (one model call per
        Gauss-Newton iteration for all components and their forward differences): for
        component k from (m_k, P_k), u ← m + K(y − h(u) − J(m − u)) with J and the error law at
        the current iterate. Its NIS (the test for a new soil, on the stretch's mean force) is
        the one at the prior mean; the likelihood its weight takes is the Laplace approximation
        of the stretch's evidence at the updated mean (one more model call)."""
        k_n, n, dim, kappa = len(log_w0), len(THETA), len(evidence.y), self.cfg.evidence_weight
        y = evidence.y
        m, u = u0, u0.copy()
        active = np.ones(k_n, bool)  # still iterating
        defined = np.zeros(k_n, bool)  # its model was defined at its prior mean
        nis, log_lik = np.full(k_n, np.inf), np.full(k_n, -np.inf)
        gain, jac, r = np.zeros((k_n, n, dim)), np.zeros((k_n, dim, n)), np.zeros((k_n, dim, dim))
        inflation = np.ones((k_n, dim))  # on σ_dev per sub-mean, from the prediction (``_Evidence.robust_inflation``)
        steps = np.concatenate([np.zeros((1, n)), np.eye(n) * eps])  # (n + 1, n)
        previous = u.copy()  # each component's last iterate its model was defined at
        halvings = np.zeros(k_n, int)  # of the step from ``previous`` (each step its own MAX_STEP_HALVINGS)
        retry = np.zeros(k_n, bool)  # at a halved step not yet tried
        for it in range(iterations):
            pts = (u[:, None, :] + steps[None]).reshape(-1, n)
            f = evidence.observe(*self.model_point_forces(pts, evidence.known, distance_m, time_s)).reshape(k_n, n + 1, dim)
            ok = np.isfinite(f).all(axis=(1, 2)) & active
            if it == 0:
                defined = ok.copy()
            # A step that lands where the model is undefined (no failure wedge) is halved back
            # towards the last good iterate, whose gain and Jacobian the covariance still holds, and
            # tried again. Put straight back there instead, a component the first step took out of
            # the model's domain kept its prior mean beside a covariance the step had already
            # contracted, and its Laplace evidence, taken at that mean, all but dropped it.
            lost = active & ~ok
            retry = lost & (halvings < MAX_STEP_HALVINGS) if it else retry
            u[retry] = 0.5 * (previous[retry] + u[retry])
            halvings[retry] += 1
            u[lost & ~retry] = previous[lost & ~retry]
            halvings[ok] = 0
            active = ok | retry
            if not ok.any():
                if not retry.any():
                    break
                continue
            a = np.flatnonzero(ok)
            h = f[a, 0]  # (A, dim)
            j_a = np.transpose(f[a, 1:] - f[a, :1], (0, 2, 1)) / eps  # (A, dim, n)
            pj = p0[a] @ np.transpose(j_a, (0, 2, 1))  # (A, n, dim)
            innovation = y - h - np.einsum("aij,aj->ai", j_a, m[a] - u[a])
            if it == 0:  # at the prior mean: which sub-means the prediction says are outliers
                inflation[a] = evidence.robust_inflation(innovation, j_a @ pj + evidence.covariance(h) / kappa)
            r_a = evidence.covariance(h, inflation[a]) / kappa
            s_mat = j_a @ pj + r_a  # (A, dim, dim)
            s_inv, invertible = _inverses(s_mat)
            if not invertible.all():  # numerically singular: undefined here, like a model without a wedge
                bad = a[~invertible]
                u[bad], active[bad] = previous[bad], False
                if it == 0:
                    defined[bad] = False
                a, h, j_a, r_a, pj, innovation, s_mat, s_inv = (
                    v[invertible] for v in (a, h, j_a, r_a, pj, innovation, s_mat, s_inv))
                if not len(a):
                    if not active.any():
                        break
                    continue  # (halved steps still to try)
            jac[a], r[a] = j_a, r_a
            gain[a] = pj @ s_inv
            if it == 0:  # at the prior mean: how well each component predicted the stretch
                nis[a] = evidence.mean_nis(innovation, s_mat, s_inv)
                whole = np.einsum("ai,aij,aj->a", innovation, s_inv, innovation)
                log_lik[a] = kappa * -0.5 * (whole + np.linalg.slogdet(2 * math.pi * s_mat)[1])
            u_next = np.clip(m[a] + np.einsum("aij,aj->ai", gain[a], innovation), U_LOWER, U_UPPER)
            moved = np.abs(u_next - u[a]).max(axis=1)
            previous[a] = u[a]
            u[a] = u_next
            active[a[moved < 1e-7]] = False
            if not active.any():
                break
        u[retry] = previous[retry]  # a halved step the iterations ran out before trying: the last good iterate
        k_h = np.eye(n)[None] - gain @ jac
        p = k_h @ p0 @ np.transpose(k_h, (0, 2, 1)) + gain @ r @ np.transpose(gain, (0, 2, 1))  # Joseph form: stays SPD
        # the stretch's evidence under each component, Laplace at its updated mean u*:
        # log N(y; h(u*), R) + log N(u*; m, P0) + ½ log det 2πP. Linearised at the prior mean
        # instead (the EKF's predictive likelihood) it misjudged components far from the φ-c
        # ridge by up to 2.5 nats per stretch, always against high φ (against a Monte Carlo
        # integral over the component: Laplace within 0.3), and the posterior drifted to low φ.
        h = evidence.observe(*self.model_point_forces(u, evidence.known, distance_m, time_s))
        # the last step, made when the iterations ran out (or converged) and never tried, may have
        # left the model's domain: the point it was made from, whose gain and Jacobian P holds
        redo = defined & ~np.isfinite(h).all(axis=1)
        if redo.any():
            u[redo] = previous[redo]
            h[redo] = evidence.observe(*self.model_point_forces(u[redo], evidence.known, distance_m, time_s))
        data = np.full(k_n, np.nan)
        fine = np.isfinite(h).all(axis=1)
        if fine.any():
            res = y - h[fine]
            cov = evidence.covariance(h[fine], inflation[fine])
            # the tempered likelihood κ·log N(y; h, R) = −½ resᵀ(R/κ)⁻¹res − κ·½ log det 2πR
            data[fine] = (-0.5 * kappa * np.einsum("ki,ki->k", res, np.linalg.solve(cov, res[..., None])[..., 0])
                          - 0.5 * kappa * np.linalg.slogdet(2 * math.pi * cov)[1])
        d = u - m
        prior = -0.5 * (np.einsum("ki,ki->k", d, np.linalg.solve(p0, d[..., None])[..., 0]) + np.linalg.slogdet(2 * math.pi * p0)[1])
        laplace = data + prior + 0.5 * np.linalg.slogdet(2 * math.pi * p)[1]
        log_lik = np.where(np.isfinite(laplace), laplace, log_lik)  # not finite at u*: the linearised one
        u_out = np.where(defined[:, None], u, u0)
        p_out = np.where(defined[:, None, None], p, p0)
        return u_out, p_out, np.where(defined, log_w0 + log_lik, -np.inf), np.where(defined, nis, np.inf)

    # -- what the posterior says
    def samples(self) -> tuple[np.ndarray, np.ndarray]:
        """(internal points (K·S, 3), weights) of the posterior: the same ``forecast_samples``
        normal draws through every component, weighted by the component's weight."""
        out = []
        for u, p in zip(self.u, self.p):
            out.append(u + self._draws @ np.linalg.cholesky(p + np.eye(len(THETA)) * 1e-12).T)
        w = np.repeat(self.weights, len(self._draws)) / len(self._draws)
        keep = w > 1e-9 * w.max()  # components too light to matter
        return np.concatenate(out)[keep], w[keep] / w[keep].sum()

    def summary(self) -> Summary:
        """SI moments of θ over the posterior's samples, and of β* at the last stretch's motion."""
        u, w = self.samples()
        theta = self.theta_of(u)
        x = np.stack([theta[n] for n in THETA], axis=1)
        mu = w @ x
        mean = {n: float(v) for n, v in zip(THETA, mu)}
        cov = (x - mu).T @ ((x - mu) * w[:, None])
        sd = np.sqrt(np.diag(cov))
        std = {n: float(v) for n, v in zip(THETA, sd)}
        corr = {}
        for a, b in (("phi", "c"), ("phi", "delta"), ("c", "delta")):
            i, j = THETA.index(a), THETA.index(b)
            corr[f"{a}_{b}"] = float(cov[i, j] / (sd[i] * sd[j])) if sd[i] * sd[j] > 0 else 0.0
        beta = self.beta_star(u)
        ok = np.isfinite(beta)
        if ok.any():
            wb = w[ok] / w[ok].sum()
            mean["beta"] = float(wb @ beta[ok])
            std["beta"] = float(math.sqrt(max(wb @ (beta[ok] - mean["beta"]) ** 2, 0.0)))
        else:
            mean["beta"] = std["beta"] = float("nan")
        return Summary(mean, std, corr, self.updates, self.changes)

    def not_a_soil(self, summary: Summary) -> str | None:
        """Why the posterior is no soil the model can be, or None: δ above φ (a blade's wall
        friction cannot exceed the soil's own: the soil shears within itself first), or φ or δ
        held at the end of the range the updates keep them in (most of the weight there: the std
        is then the bound's, not the soil's). Why say it: where the model misses physics (the
        default world's floor reaction in F_z) the posterior takes such an effective soil, whose
        forces at other depths are calibrated but whose θ reads as a soil it cannot be (a strong
        gravel's φ 0.0° ± 0.4° beside δ 42.5°, docs/soil_posterior.md). The simulator's worlds fix δ
        (10°, fee 15°) for every soil, so a simulated soil of φ below that is said too, rightly: no
        real soil is so."""
        def deg(rad: float) -> float:  # (+ 0.0: a mean a hair below 0° is said 0.0°, not -0.0°)
            return round(float(rad) / DEG, 1) + 0.0

        held = []
        for name in ("phi", "delta"):
            j = THETA.index(name)
            for bound, end in ((U_LOWER, "lowest"), (U_UPPER[j], "highest")):
                if self.weights @ (np.abs(self.u[:, j] - bound) <= HELD_AT_BOUND_U) >= HELD_AT_BOUND_SHARE:
                    held.append(f"{name} at its {end} value ({deg(self.theta_of(np.full(len(THETA), bound))[name]):.1f}°)")
        phi, delta = summary.mean["phi"], summary.mean["delta"]
        parts = ([f"delta {deg(delta):.1f}° above phi {deg(phi):.1f}°, a wall friction above the soil's own, which a real "
                  "soil does not have"] if delta > phi + NOT_A_SOIL_MARGIN_RAD else [])
        if held:
            parts.append(f"{' and '.join(held)}, the end of the range it is kept in (its std there is the bound's, not the soil's)")
        if not parts:
            return None
        return (f"the fused soil is no soil the model can be: {'; '.join(parts)}. The force likely has physics the "
                "model lacks (or the soil lies beyond the prior); θ is then an effective soil, its forces at other depths "
                "what is calibrated, not θ; soil_discrepancy looks for what is missing")

    def quantiles(self, levels) -> dict[str, np.ndarray]:
        """Quantiles of φ, c, δ [SI] at ``levels`` (probabilities), exact for the Gaussian sum:
        each is a monotone map of one internal coordinate, so its quantile is the map of that
        coordinate's mixture quantile. Why not mean ± z·std: the sum is skewed and c is bounded
        at 0 (a sand's posterior is mostly the cohesionless row's point at c = 0)."""
        u = np.zeros((len(levels), len(THETA)))
        for j in range(len(THETA)):
            sd = np.sqrt(np.maximum(self.p[:, j, j], 1e-30))
            u[:, j] = mixture_quantiles(self.weights, self.u[:, j], sd, levels)
        return self.theta_of(u)

    def beta_star(self, u: np.ndarray) -> np.ndarray:
        """β* (Eq. 7, with the velocity-corrected δ of Eq. 9-10) at scaled points u, at the last
        stretch's motion (a level cut before any)."""
        known = self.last_known if self.last_known is not None else _level_cut()
        k = dict(zip(KNOWN_PARAMS, known))
        theta = self.theta_of(u)
        with np.errstate(all="ignore"):
            return fee.critical_beta(theta["phi"], theta["delta"], k["c_a"], k["rho"], k["alpha"], k["v_x"], k["v_z"])

    def forecast(self, known: np.ndarray, quantiles=(0.05, 0.25, 0.5, 0.75, 0.95), distance_m: float = 0.0,
                 time_s: float = 0.0) -> dict:
        """The force at conditions ``known`` (Θ_k, e.g. another depth): mean, std and quantiles
        per axis [N] of the posterior predictive (θ samples through the model + model error).

        The forecast law's relative part applies to what each sample extrapolates from the
        newest stretch's conditions (``predictive.extrapolated_part``: |F_s(known) − F_s(newest
        stretch)|, at most |F_s(known)|): the model is fitted where the evidence is and misses
        more the further a forecast reaches in depth, speed or surcharge. Before any stretch,
        all of |F_s|."""
        return self.forecast_from(self.predictive(known, distance_m, time_s), quantiles)

    def predictive(self, known: np.ndarray, distance_m: float = 0.0, time_s: float = 0.0) -> "Predictive":
        """The posterior's samples through the model at ``known``, before any forecast law."""
        u, w = self.samples()
        fx, fz = self.model_force(u, known, distance_m, time_s)
        if self.last_known is not None:
            fx0, fz0 = self.model_force(u, self.last_known, distance_m, time_s)
        else:
            fx0 = fz0 = np.full(len(fx), np.nan)
        ok = np.isfinite(fx) & np.isfinite(fz)
        return Predictive(w[ok] / w[ok].sum() if ok.any() else w[ok], np.stack([fx[ok], fz[ok]]),
                          np.stack([extrapolated_part(fx, fx0, fx)[ok], extrapolated_part(fz, fz0, fz)[ok]]))

    def forecast_from(self, pred: "Predictive", quantiles, cfg: "FusionConfig | None" = None) -> dict:
        """``forecast``'s answer from a ``predictive`` under the forecast law of ``cfg`` (default:
        the posterior's own): a calibration tries many laws on the same samples."""
        cfg = cfg or self.cfg
        out = {"mean": np.full(2, np.nan), "std": np.full(2, np.nan), "quantiles": {q: np.full(2, np.nan) for q in quantiles}}
        if not len(pred.weights):
            return out
        w = pred.weights
        for j in range(2):
            f, sd = pred.force_n[j], forecast_error_std(pred, cfg, j)
            m = float(w @ f)
            out["mean"][j] = m
            out["std"][j] = math.sqrt(float(w @ ((f - m) ** 2 + sd ** 2)))
            for q, v in zip(quantiles, mixture_quantiles(w, f, sd, quantiles)):
                out["quantiles"][q][j] = v
        return out


class Predictive(NamedTuple):
    """A posterior's samples through the model at one forecast's conditions (``SoilPosterior.predictive``)."""

    weights: np.ndarray  # (S,) of the samples with a force, summing to 1
    force_n: np.ndarray  # (2, S) the model's force (x, z) [N]
    extrapolated_n: np.ndarray  # (2, S) what each extrapolates from the newest stretch [N] (``extrapolated_part``)


def forecast_error_std(pred: Predictive, cfg: FusionConfig, axis: int) -> np.ndarray:
    """(S,) the forecast law's model error [N] around each sample's force on ``axis`` (0 x, 1 z):
    ``cfg``'s floor + share of what the sample extrapolates + its part near the F_x limit (from
    the sample's own forecast F_x, ``near_limit_error_std``)."""
    return (model_error_std(pred.extrapolated_n[axis], cfg.forecast_abs_std_n[axis], cfg.forecast_rel_std[axis])
            + near_limit_error_std(pred.force_n[0], cfg.forecast_limit_std[axis], axis))


def fused_values(summary: Summary | None, cfg: FusionConfig) -> np.ndarray:
    """``topics.FUSED_FIELDS`` values of a posterior summary (None: nothing learnt yet, all 0 with
    ``fused_valid`` 0). Never NaN: a summary with a non-finite moment is published as invalid."""
    from soil_msgs_py.topics import FUSED_FIELDS

    out = np.zeros(len(FUSED_FIELDS))
    if summary is None:
        return out
    values = {f"{n}_fused": summary.mean[n] for n in (*THETA, "beta")}
    values.update({f"{n}_std": summary.std[n] for n in (*THETA, "beta")})
    values.update({f"corr_{k}": v for k, v in summary.corr.items()})
    values.update(model_std_abs_x=cfg.forecast_abs_std_n[0], model_std_abs_z=cfg.forecast_abs_std_n[1],
                  model_std_rel_x=cfg.forecast_rel_std[0], model_std_rel_z=cfg.forecast_rel_std[1],
                  model_std_limit_x=cfg.forecast_limit_std[0], model_std_limit_z=cfg.forecast_limit_std[1],
                  fused_valid=1.0, fused_stretches=float(summary.updates))
    out[:] = [values[n] for n in FUSED_FIELDS]
    if not np.isfinite(out).all():
        return np.zeros(len(FUSED_FIELDS))
    return out


def _level_cut() -> np.ndarray:
    """Θ_k of a level cut at the controller's default speed (β* needs a motion before any stretch)."""
    from soil_msgs_py.params import ADHESION_PA, MACHINE

    values = {"c_a": ADHESION_PA, "gamma": 17e3, "rho": MACHINE.blade_angle_rad, "alpha": 0.0, "w": MACHINE.blade_width_m,
              "d": 0.1, "q": 0.0, "v_x": 0.5, "v_z": 0.0}
    return np.array([values[n] for n in KNOWN_PARAMS])


# A tick is quasi-static (``quasi_static``) while the blade rises no faster than this [m/s] (a
# steady cut's vertical velocity jitters by ±3 mm/s) and its sampled vertical velocity changes by
# no more than QUASI_STATIC_MAX_DV_Z_M_S between two samples (1.8 m/s² at 60 Hz; a steady ramp in
# depth changes it by ~1 mm/s). Within the tick the blade may reach WITHIN_TICK_REACH times as far
# beyond its mean velocity (from the positions) as that mean lies from the mean of its two
# sampled ends (the lift joint's motion between two samples, which they miss).
QUASI_STATIC_MAX_RISE_M_S = 0.005
QUASI_STATIC_MAX_DV_Z_M_S = 0.03
WITHIN_TICK_REACH = 2.0


def quasi_static(velocity_m_s: np.ndarray, previous_m_s: np.ndarray | None, mean_m_s: np.ndarray | None = None) -> bool:
    """Whether the tick between two samples of the blade's velocity (x, z) [m/s] was one the FEE
    describes; ``mean_m_s``: the tick's mean velocity from the blade's positions (None: unknown).
    The FEE is a quasi-static equilibrium (paper §1.1.2: neither the soil nor the blade
    accelerates), and through Eq. 9-10 the force depends on the blade's vertical velocity: its
    soil-tool friction reverses where v_z passes v_x·cot ρ, a few cm/s above a level cut. A blade
    that rises or whose vertical velocity changes quickly (the edge plunging in, the chassis
    dropping into its own cut, the anti-stall lift; ``QUASI_STATIC_MAX_*``) moves within the tick
    in ways two samples do not show, and may cross that reversal between them: fee world, the true
    soil's FEE 20-50 % off the force for a few ticks, and still 3 % off F_z while the samples said
    the blade rose at 1.3 cm/s. The positions tell where the samples miss it: after the chassis
    settled into its cut the lift joint kicked the blade up within each tick, 2 cm/s by the edge's
    positions where its sampled velocity said 0-4 mm/s, and the posterior took the friction it
    lost for a soil 9° off. A steady ramp down in depth is quasi-static (its ticks' mean velocity
    is ~1 cm/s from their sampled ends, still far below the reversal)."""
    rise = velocity_m_s[1] if previous_m_s is None else max(velocity_m_s[1], previous_m_s[1])
    change = 0.0 if previous_m_s is None else abs(velocity_m_s[1] - previous_m_s[1])
    if mean_m_s is not None:
        ends = velocity_m_s[1] if previous_m_s is None else 0.5 * (velocity_m_s[1] + previous_m_s[1])
        rise = max(rise, mean_m_s[1] + WITHIN_TICK_REACH * abs(mean_m_s[1] - ends))
    return rise <= QUASI_STATIC_MAX_RISE_M_S and change <= QUASI_STATIC_MAX_DV_Z_M_S


# How well a sample's force and its conditions are known to belong to the same instant [ticks]:
# a sub-mean's force is uncertain by its rate of change times this. Why: on a ramp in depth the
# force changes by ~100 N a tick, and a few hundredths of a tick between when the simulator
# integrates the force and when it samples the depth (its substeps) left a bias of 5 N, which
# the fee world's sharp shape law (2 N + 0.2 %) took for soil, stretch after stretch under a
# depth dither (φ 1-1.5° off with a 0.4° std); a real machine's force and position sensors are
# no closer in time. The error is one offset for the whole stretch, not one per sub-mean (a
# sensor's latency does not change from one sub-mean to the next): the fee world's residuals at
# the true soil under a 3 cm dither are −0.037 tick × the force's rate on every sub-mean (R² 0.8
# of their variance), and taken as independent per sub-mean they still read as the φ-c trade
# that a change with depth shows: a sharp law's 90 % intervals held φ in 6 of 12 dithered cuts
# (clay and loam 1-2° off, z ≈ 2), against 12 of 12 as one common error (``_Evidence``).
SAMPLE_TIMING_TICKS = 0.1


class Stretch(NamedTuple):
    """One stretch of evidence: ``update_ticks`` consecutive samples in ``model_points`` sub-means."""

    force: np.ndarray  # (2,) mean soil force (x, z) [N]
    known: np.ndarray  # (G, 9) Θ_k sub-means
    spread: np.ndarray  # (2,) the force's standard deviation over the stretch [N]
    point_force: np.ndarray  # (G, 2) the force's sub-means [N]
    point_noise: np.ndarray  # (G, 2) noise of each sub-mean [N]: the tick noise (``tick_noise_n``) / √(ticks per sub-mean)
    point_unsteady: np.ndarray  # (G,) bool: the blade was not quasi-static within the sub-mean (no shape evidence)
    point_rate: np.ndarray  # (G, 2) the force's rate of change at each sub-mean [N per tick]


def tick_noise_n(second_differences_sq: np.ndarray, count: int) -> np.ndarray:
    """(2,) the force's tick-to-tick noise [N] from the sum of its squared second differences
    F_{t+1} − 2F_t + F_{t−1} over ``count`` triples: white noise of σ gives 6σ² each, while a
    force that changes linearly with time (a ramp in depth) gives none, so a steady change is not
    taken for noise."""
    return np.sqrt(second_differences_sq / (6.0 * count)) if count else np.zeros(2)


class StretchAccumulator:
    """Samples -> stretches (``Stretch``): the mean force and its spread over ``update_ticks``
    consecutive samples, the force and Θ_k as ``model_points`` sub-means, the force's tick noise,
    its rate of change at each sub-mean, and the blade's travel in soil since the last stretch
    (for ``SoilPosterior.forget``)."""

    def __init__(self, update_ticks: int, model_points: int = 1):
        self.update_ticks = update_ticks
        self.per_point = update_ticks // model_points
        self.model_points = model_points
        self.clear()
        self.travel_m = 0.0

    def clear(self) -> None:
        self.count = 0
        g = self.model_points
        self.known = np.zeros((g, len(KNOWN_PARAMS)))
        self.force = np.zeros((g, 2))
        self.force_sq = np.zeros(2)
        self.unsteady = np.zeros(g, bool)
        self.last = []  # the stretch's last two forces (for its second differences)
        self.curvature_sq = np.zeros(2)

    def add(self, force_n: np.ndarray, known: np.ndarray, unsteady: bool = False) -> Stretch | None:
        """One sample (``unsteady``: the blade was not quasi-static during its tick); the ``Stretch``
        when complete, else None."""
        force_n = np.asarray(force_n, float)
        g = min(self.count // self.per_point, self.model_points - 1)
        self.unsteady[g] |= bool(unsteady)
        self.force[g] += force_n
        self.force_sq += np.square(force_n)
        if len(self.last) == 2:
            self.curvature_sq += np.square(force_n - 2.0 * self.last[1] + self.last[0])
        self.last = [*self.last[-1:], force_n]
        self.known[g] += known
        self.count += 1
        self.travel_m += float(soil_advance(known[_VX], known[_D]))
        if self.count < self.update_ticks:
            return None
        point = self.force / self.per_point
        mean = point.mean(axis=0)
        spread = np.sqrt(np.maximum(self.force_sq / self.update_ticks - mean ** 2, 0.0))
        noise = tick_noise_n(self.curvature_sq, self.update_ticks - 2) / math.sqrt(self.per_point)
        # the force's rate of change per tick at each sub-mean, from its neighbours (one-sided at the ends)
        rate = np.gradient(point, axis=0) / self.per_point if self.model_points > 1 else np.zeros_like(point)
        point_noise = np.tile(noise, (self.model_points, 1))
        out = Stretch(mean, self.known / self.per_point, spread, point, point_noise, self.unsteady.copy(), rate)
        self.clear()
        return out


class PathFusion:
    """Samples in order -> stretches -> the posterior: the one loop the online estimator and the
    offline tools (``fuse_episode``, ``fused_track``) run, so both learn the same.

    The evidence is the soil's force: the measured force minus the blade's inertia
    (``soil_physics.blade_inertia``), from the blade velocity of consecutive samples. Without
    it the blade's m_b·a in the measured F_z (22 % of it under a 3 cm depth dither, about all
    of it while the edge enters the soil) reads as soil, and the posterior settles off the
    truth (fee world, 3 cm dither: φ 13° off at 10 s; without the inertia, 3°). The first
    sample after a reset or a gap has no predecessor: its acceleration is taken as zero.

    The model is evaluated at the conditions of the tick whose mean force a sample carries:
    Θ_k averaged with the previous sample's (the force is the tick's mean, depth is sampled at
    its end: on a depth ramp Θ_k's d runs half a tick ahead of the force, 0.6 % of F_x at
    7 cm/s), with the blade's mean velocity over the tick from its edge positions (not Θ_k's
    10-sample mean of paper §3.1, which lags a reversal of the blade by ~5 ticks and with it the
    Eq. 9-10 friction; nor the sampled velocity, which misses the lift joint's motion within a tick)."""

    def __init__(self, posterior: SoilPosterior):
        self.posterior = posterior
        self.stretch = StretchAccumulator(posterior.cfg.update_ticks, posterior.cfg.model_points)
        self._velocity: np.ndarray | None = None  # blade velocity (x, z) of the previous sample
        self._position: np.ndarray | None = None  # blade edge position (x, z) of the previous sample
        self._known: np.ndarray | None = None  # the previous sample's Θ_k with its blade velocity

    def reset(self) -> None:
        """A new path: the prior, no stretch in progress, no travel counted."""
        self.posterior.reset()
        self.stretch = StretchAccumulator(self.posterior.cfg.update_ticks, self.posterior.cfg.model_points)
        self._velocity = self._position = self._known = None

    def gap(self) -> None:
        """A missing or broken sample: the stretch in progress is dropped, the posterior kept."""
        self.stretch.clear()
        self._velocity = self._position = self._known = None

    def add(self, force_n: np.ndarray, known: np.ndarray, distance_m: float = 0.0,
            observation: np.ndarray | None = None, time_s: float = 0.0) -> bool:
        """One sample (measured force, Θ_k, travel in soil, its observation row, paper §2.1.2's
        o_t in ``params.OBSERVATION_FIELDS`` order, or None: no inertia removed, Θ_k as it is;
        time in soil [s]); True when it completed a stretch the posterior learnt from."""
        force_n = np.asarray(force_n, float)
        velocity = position = mean = None
        if observation is not None:
            velocity, position = blade_velocity(observation), blade_position(observation)
            if self._position is not None:  # the tick's mean velocity, whatever happened within it
                mean = (position - self._position) * SAMPLE_RATE_HZ
        if velocity is not None and self._velocity is not None:
            force_n = force_n - inertia_force_n(velocity, self._velocity)
        known = np.array(known, float)
        if velocity is not None:  # the conditions over the tick the force is the mean of
            here = known.copy()
            here[[_VX, _VZ]] = velocity
            if self._known is not None:
                known = 0.5 * (here + self._known)
                known[[_VX, _VZ]] = mean
            else:
                known = here
            self._known = here
        unsteady = velocity is not None and not quasi_static(velocity, self._velocity, mean)
        self._velocity, self._position = velocity, position
        stretch = self.stretch.add(force_n, known, unsteady)
        if stretch is None:
            return False
        self.posterior.forget(self.stretch.travel_m)
        self.stretch.travel_m = 0.0
        return self.posterior.update(stretch.force, stretch.known, stretch.spread, distance_m=distance_m, time_s=time_s,
                                     point_force_n=stretch.point_force, point_noise_n=stretch.point_noise,
                                     point_unsteady=stretch.point_unsteady, point_rate_n=stretch.point_rate)


def fused_track(cfg: FusionConfig, forces: np.ndarray, known: np.ndarray, distance_m: np.ndarray | None = None,
                observations: np.ndarray | None = None, gap_before: np.ndarray | None = None,
                time_s: np.ndarray | None = None) -> np.ndarray:
    """(n, len(FUSED_FIELDS)): the fused fields in effect after each of one episode's n samples,
    as the online estimator publishes them (offline, for comparing the two)."""
    from soil_msgs_py.topics import FUSED_FIELDS

    out = np.zeros((len(forces), len(FUSED_FIELDS)))
    current = fused_values(None, cfg)
    learnt: dict[int, np.ndarray] = {}
    fuse_episode(SoilPosterior(cfg), forces, known, distance_m, observations, gap_before, time_s=time_s,
                 on_update=lambda row, post: learnt.__setitem__(row, fused_values(post.summary(), cfg)))
    for row in range(len(forces)):
        current = learnt.get(row, current)
        out[row] = current
    return out


def fuse_episode(posterior: SoilPosterior, forces: np.ndarray, known: np.ndarray, distance_m: np.ndarray | None = None,
                 observations: np.ndarray | None = None, gap_before: np.ndarray | None = None,
                 on_update=None, time_s: np.ndarray | None = None) -> SoilPosterior:
    """Run the posterior over one episode's samples in order (offline: the same as online).
    ``observations`` (n, len(OBSERVATION_FIELDS)): the episode's observation rows, whose blade
    velocities and positions ``PathFusion.add`` reads (None: the measured force is taken as the
    soil's, at Θ_k as it is). ``gap_before``
    (n,) bool: ticks missing before the row (a repaired bag, ``Dataset.gap_before``): as
    online, the stretch in progress is dropped and no acceleration spans the gap. ``distance_m``,
    ``time_s`` (n,): the blade's travel [m] and time [s] in soil (``soil_physics.travel``; None:
    the time from Θ_k's depth, the travel 0).
    ``on_update(row, posterior)`` after every stretch learnt from (row = its last sample)."""
    fusion = PathFusion(posterior)
    if time_s is None and len(known):
        time_s = time_in_soil_of_known(known)
    for row in range(len(forces)):
        if gap_before is not None and gap_before[row]:
            fusion.gap()
        learnt = fusion.add(forces[row], known[row], float(distance_m[row]) if distance_m is not None else 0.0,
                            None if observations is None else observations[row], float(time_s[row]))
        if learnt and on_update is not None:
            on_update(row, posterior)
    return posterior
