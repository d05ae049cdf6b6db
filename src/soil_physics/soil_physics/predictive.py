"""The force a soil posterior predicts: quantiles of a Gaussian mixture, vectorised.

Shared by the estimator's fused posterior (``pinn_estimator.fusion``: its forecasts and
calibration) and the planner (``soil_planner.planner``: the deepest cut whose upper force
quantile stays within the limits): one bisection of a Gaussian mixture's CDF, for the
estimator's signed quantiles (``mixture_quantiles``) and the planner's quantile of |F|
(``upper_magnitude``, ``within_magnitude``). Their mixtures differ: the estimator's holds its
posterior's components, the planner's fixed draws from the one Gaussian of the moments
``/soil/estimate`` publishes, all a node reading the topic has. No ROS.
"""
from __future__ import annotations

import numpy as np
from scipy.special import ndtr

from soil_msgs_py.params import FORCE_LIMITS_N, PLANNER_FORCE_MARGIN, SAMPLE_RATE_HZ

BISECTIONS = 50  # halvings of the search interval: 16 sigma / 2^50, far below a newton
TAIL = 1e-9  # components lighter than this share of the heaviest are left out

# Rows per batch of ``mean_standard_error``: half a second, well beyond how long a force's errors
# persist (a particle event drops the grip for up to 0.08 s).
SE_BLOCK_ROWS = SAMPLE_RATE_HZ // 2
SE_MIN_BATCHES = 5  # fewer batch means estimate their spread too poorly


def mean_standard_error(values: np.ndarray, block: int = SE_BLOCK_ROWS) -> np.ndarray:
    """Standard error of the mean of ``values`` (n, ...) along axis 0 by batch means (blocks of
    ``block`` consecutive rows: errors that persist over several ticks, which the rows' spread over
    √n understates), never below that (a batch-means estimate from few batches can come out near 0).
    With fewer than SE_MIN_BATCHES batches, the rows' spread over √(n / block): one independent
    value per block, the cautious side."""
    values = np.asarray(values, float)
    n = len(values)
    if n < 2:
        return np.zeros(values.shape[1:])
    spread = values.std(axis=0, ddof=1)
    k = n // block
    if k < SE_MIN_BATCHES:
        return spread / np.sqrt(max(n / block, 1.0))
    means = values[: k * block].reshape(k, block, *values.shape[1:]).mean(axis=1)
    return np.maximum(means.std(axis=0, ddof=1) / np.sqrt(k), spread / np.sqrt(n))


def mixture_quantiles(w: np.ndarray, mu: np.ndarray, sd: np.ndarray, quantiles) -> np.ndarray:
    """Quantiles of Σ_i w_i N(mu_i, sd_i²) by bisection on the mixture's CDF.

    w: (S,) weights (any positive scale); mu, sd: (S,) or (D, S) for D mixtures with the same
    weights (e.g. one per candidate depth). Returns (len(quantiles),) or (len(quantiles), D)."""
    w = np.asarray(w, float)
    keep = w > TAIL * w.max()
    w = w[keep] / w[keep].sum()
    mu, sd = np.asarray(mu, float)[..., keep], np.asarray(sd, float)[..., keep]
    batched = mu.ndim == 2
    mu2, sd2 = (mu, sd) if batched else (mu[None], sd[None])
    lo0, hi0 = (mu2 - 8 * sd2).min(axis=1), (mu2 + 8 * sd2).max(axis=1)
    out = np.array([_bisect(lambda x: ndtr((x[:, None] - mu2) / sd2) @ w, lo0, hi0, q) for q in quantiles])
    return out if batched else out[:, 0]


def _bisect(cdf, lo: np.ndarray, hi: np.ndarray, level: float) -> np.ndarray:
    """Where the non-decreasing ``cdf`` (D,) -> (D,) reaches ``level``, per entry in [lo, hi]."""
    for _ in range(BISECTIONS):
        mid = 0.5 * (lo + hi)
        below = cdf(mid) < level
        lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
    return 0.5 * (lo + hi)


def mixture_cdf(w: np.ndarray, mu: np.ndarray, sd: np.ndarray, x: np.ndarray) -> np.ndarray:
    """P(F <= x) under Σ_i w_i N(mu_i, sd_i²); mu, sd (D, S) against x (D,) -> (D,)."""
    w = np.asarray(w, float)
    return ndtr((np.asarray(x, float)[:, None] - mu) / sd) @ (w / w.sum())


def magnitude_cdf(w: np.ndarray, mu: np.ndarray, sd: np.ndarray, x: np.ndarray) -> np.ndarray:
    """P(|F| <= x) = P(F <= x) − P(F < −x) under each mixture; mu, sd (D, S) against x (D,) -> (D,)."""
    x = np.asarray(x, float)
    return mixture_cdf(w, mu, sd, x) - mixture_cdf(w, mu, sd, -x)


def within_magnitude(w: np.ndarray, mu: np.ndarray, sd: np.ndarray, limit: float, quantile: float) -> np.ndarray:
    """Whether ``upper_magnitude(w, mu, sd, quantile) <= limit`` per mixture (D,), from the CDF of
    |F| at the limit: P(|F| <= L) >= q. (Q_q <= L and Q_{1−q} >= −L, the test before, let a force
    whose mixture straddles zero exceed L with up to twice 1 − q: 10 % at q = 0.95, an outside
    reviewer's; the same wherever the force keeps one sign.)"""
    d = np.asarray(mu).shape[0]
    return magnitude_cdf(w, mu, sd, np.full(d, float(limit))) >= quantile


def upper_magnitude(w: np.ndarray, mu: np.ndarray, sd: np.ndarray, quantile: float) -> np.ndarray:
    """The ``quantile`` of |F| per mixture (D,): a force magnitude the mixture exceeds with
    probability 1 − ``quantile``, whichever sign the force has (bisection on ``magnitude_cdf``).
    mu, sd (D, S), or (S,) for one mixture (a scalar then)."""
    mu, sd = np.asarray(mu, float), np.asarray(sd, float)
    single = mu.ndim == 1
    mu2, sd2 = (mu[None], sd[None]) if single else (mu, sd)
    out = _bisect(lambda x: magnitude_cdf(w, mu2, sd2, x), np.zeros(mu2.shape[0]), (np.abs(mu2) + 8 * sd2).max(axis=1),
                  quantile)
    return out[0] if single else out


def model_error_std(force_n: np.ndarray, abs_std_n: float, rel_std: float) -> np.ndarray:
    """σ = abs + rel·|F| [N]: the error law of the physics model a posterior assumes."""
    return abs_std_n + rel_std * np.abs(force_n)


def near_limit_error_std(force_x_n: np.ndarray, share: float, axis: int) -> np.ndarray:
    """share·L_axis·ramp [N]: the model error a forecast adds as its F_x nears the tractive limit,
    ramp = clip((|F_x| / L_x − m) / (1 − m), 0, 1) from the planner's margin m to the limit
    (``FORCE_LIMITS_N`` L, ``PLANNER_FORCE_MARGIN`` m; one value per sample's own F_x).

    Why: at the F_x limit the anti-stall controller lifts the blade (Eq. 11), and then the force
    is set by the lift as much as by the soil: in the default world F_z becomes the lift's push on
    the floor, in no soil model (held out, 2026-12-07: the F_z intervals held 87 / 56 % of the
    forecasts within the margin, 64 / 9 % of those beyond it). A share of |ΔF| cannot say that:
    wide enough beyond the margin it over-covers within it. The share is calibrated on the
    calibration pairs beyond the margin alone (``fusion_calibration.choose_limit_shares``); 0
    where the model holds there too (the fee world)."""
    if not share:
        return np.zeros(np.shape(force_x_n))
    ramp = np.clip((np.abs(force_x_n) / FORCE_LIMITS_N[0] - PLANNER_FORCE_MARGIN) / (1.0 - PLANNER_FORCE_MARGIN), 0.0, 1.0)
    return share * FORCE_LIMITS_N[axis] * ramp


def near_limit_text(share: float) -> str:
    """A forecast law's part near the F_x limit (``near_limit_error_std``) in words, as the tools add
    it after the law's floor and share ("" where it has none)."""
    return f" + {share:g} of its limit near the F_x limit" if share else ""


def error_law_text(law) -> str:
    """A per-axis error law (abs_x [N], abs_z [N], rel_x, rel_z), σ = abs + rel·|ΔF|, in words as
    the tools print it (the order a planner's ``bound_law`` takes)."""
    return f"x {law[0]:g} N + {law[2]:g}|ΔF|, z {law[1]:g} N + {law[3]:g}|ΔF|"


def extrapolated_part(force_n: np.ndarray, reference_n, cap_n: np.ndarray) -> np.ndarray:
    """min(|F − F_ref|, |cap|) [N]: how much of a forecast is extrapolated from a force known at
    the conditions the evidence came from, the force a forecast error law's relative part
    applies to. A model that is off by a share of what it extrapolates is off by nothing at the
    depth it was fitted at and by more the further it reaches (a fixed share of |F| would make
    intervals too wide near the evidence and too narrow far from it); never more than |cap|
    (the unanchored forecast's own force). A non-finite reference (no evidence) gives |cap|."""
    cap = np.abs(np.asarray(cap_n, float))
    with np.errstate(invalid="ignore"):
        part = np.abs(np.asarray(force_n, float) - np.asarray(reference_n, float))
    return np.where(np.isfinite(part), np.minimum(part, cap), cap)
