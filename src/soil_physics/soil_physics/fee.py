"""The Fundamental Equation of Earthmoving (FEE), paper Eq. 2-10, written once.

Every function takes arrays of one namespace (NumPy or torch, any broadcastable shapes,
float32 or float64) and returns arrays of the same namespace, so the simulator (NumPy) and
the PINN (torch, differentiable) share one implementation. Angles in rad, SI throughout.

Geometry (Holz et al. 2013; paper Fig. 1): a flat blade at angle rho to a soil surface that
is inclined at alpha to the horizon cuts at depth d and fails a wedge along a plane at
angle beta to the surface. eta = delta + rho + phi + beta.

Sign convention: the force returned is the force the blade exerts ON the soil (x forward,
z up), i.e. Eq. 8 literally. A resisting soil gives F_x > 0.

Two corrections to the printed equations (both tested in tests/soil_physics/test_fee.py):
* Eq. 2 prints the adhesion term as ``c_a w N_a``, which has units N/m, not N. The
  adhesion acts on the blade-soil contact of length d / sin(rho); N_a already carries the
  1/sin(rho), so the dimensionally right term is ``c_a d w N_a``. An independent wedge
  equilibrium (test_wedge_equilibrium) confirms it.
* Eq. 10 prints ``c_a' = tanh(...) c_a'`` (circular) and the text says delta', c_a' replace
  "delta and c". The intended correction scales the *soil-tool* terms: c_a' = tanh(...) c_a,
  and delta', c_a' replace delta and c_a (cohesion c is a soil-soil property and does not
  change sign with the wedge's motion relative to the blade).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from . import xp as _xp

# C_1 of Eq. 9-10 [s/m]. The paper gives no value. At 50 s/m the correction is 0.989 of
# the full friction for a blade advancing at the dataset's slowest target (0.3 m/s,
# iota_b . v = -0.05 m/s) and reverses smoothly within ~2 cm/s of the blade sliding
# upward past the wedge.
FEE_VELOCITY_GAIN_S_M = 50.0
# |sin(eta)| is kept at least this far from 0: eta = 180 deg is the FEE's singularity
# (paper §2.2.2, the reason lambda_eta = 10). Inside Table 1's limits this keeps every
# output finite, so masked samples cannot poison gradients with inf * 0 = NaN.
SIN_ETA_FLOOR = 1e-6
# A root of Eq. 7 counts as a failure angle β* only this far [rad] inside (0, π − (δ + ρ + φ)): at the
# ends the wedge degenerates (β → 0: a failure plane along the surface; the upper end: η → 180°, the
# FEE's singularity).
BETA_MARGIN_RAD = 1e-6


@dataclass(frozen=True)
class FeeCoefficients:
    n_gamma: object
    n_c: object
    n_q: object
    n_a: object
    eta: object


def _safe_sin_eta(xp, eta):
    s = xp.sin(eta)
    floor = xp.where(s < 0, -SIN_ETA_FLOOR, SIN_ETA_FLOOR)
    if _xp.is_torch(xp):
        floor = floor + 0.0 * s  # carries torch's gradient through; NumPy's values are the same without it
    return xp.where(xp.abs(s) < SIN_ETA_FLOOR, floor, s)


def _n_gamma(xp, rho, beta, s_wedge, sin_eta):
    """N_gamma of Eq. 3 from the wedge's sin(alpha + phi + beta) and the safe sin(eta)."""
    return (1.0 / xp.tan(rho) + 1.0 / xp.tan(beta)) * s_wedge / (2.0 * sin_eta)


def coefficients(phi, delta, rho, alpha, beta) -> FeeCoefficients:
    """N_gamma, N_c, N_Q, N_a and eta of Eq. 3-6 (Holz et al. 2013 form)."""
    xp, phi, delta, rho, alpha, beta = _xp.coerce(phi, delta, rho, alpha, beta)
    eta = delta + rho + phi + beta
    sin_eta = _safe_sin_eta(xp, eta)
    s_wedge = xp.sin(alpha + phi + beta)
    n_gamma = _n_gamma(xp, rho, beta, s_wedge, sin_eta)
    n_c = xp.cos(phi) / (xp.sin(beta) * sin_eta)
    n_q = s_wedge / sin_eta
    n_a = -xp.cos(rho + phi + beta) / (xp.sin(rho) * sin_eta)
    return FeeCoefficients(n_gamma, n_c, n_q, n_a, eta)


def dn_gamma_dbeta(phi, delta, rho, alpha, beta):
    """Analytic dN_gamma/dbeta (used by the beta-consistency loss and by tests)."""
    xp, phi, delta, rho, alpha, beta = _xp.coerce(phi, delta, rho, alpha, beta)
    eta = delta + rho + phi + beta
    cot_sum = 1.0 / xp.tan(rho) + 1.0 / xp.tan(beta)
    a = alpha + phi + beta
    sin_eta = _safe_sin_eta(xp, eta)
    d_num = -xp.sin(a) / xp.sin(beta) ** 2 + cot_sum * xp.cos(a)
    return d_num / (2.0 * sin_eta) - cot_sum * xp.sin(a) * xp.cos(eta) / (2.0 * sin_eta**2)


def beta_star(phi, delta, rho, alpha):
    """beta* = argmin_beta N_gamma on the valid interval 0 < beta < pi - (delta + rho + phi).

    Closed form. With A = alpha + phi and B = delta + rho + phi, N_gamma is proportional to
    g(theta) = (cos(rho - A) - cos(theta + rho + A)) / (cos B - cos(theta + B)), theta = 2 beta.
    g'(theta) = 0  <=>  X sin(theta) + Y cos(theta) = sin(rho + A - B) with
    X = cos B cos(rho + A) - cos(rho - A) cos B,  Y = cos B sin(rho + A) - cos(rho - A) sin B,
    i.e. M sin(theta + psi) = sin(rho + A - B). Both roots are evaluated and the valid one with
    the smaller N_gamma is returned. NaN where no stationary point lies in the interval
    (physically meaningless inputs, e.g. eta >= 180 deg for every beta).
    """
    xp, phi, delta, rho, alpha = _xp.coerce(phi, delta, rho, alpha)
    a_ = alpha + phi
    b_ = delta + rho + phi
    a = xp.cos(rho - a_)
    p = rho + a_
    b = xp.cos(b_)
    q = b_
    # b is cos(q): taken once with NumPy (the same bits); torch computes it again, so that its
    # gradients keep their rounding (autograd sums a reused node's gradients in another order)
    x = b * xp.cos(p) - a * (xp.cos(q) if _xp.is_torch(xp) else b)
    y = b * xp.sin(p) - a * xp.sin(q)
    m = xp.sqrt(x * x + y * y)
    with np.errstate(divide="ignore", invalid="ignore"):  # m = 0: no failure wedge, NaN as said above
        s = _xp.clip(xp, xp.sin(p - q) / m, -1.0, 1.0)
    psi = xp.arctan2(y, x)
    root = xp.arcsin(s)
    upper = math.pi - b_
    best = None
    best_n = None
    for theta in (root - psi, math.pi - root - psi):
        beta = _xp.remainder(xp, theta / 2.0, math.pi)
        valid = (beta > BETA_MARGIN_RAD) & (beta < upper - BETA_MARGIN_RAD)
        # N_gamma alone (the other coefficients are not needed to compare the roots), with the
        # arithmetic of ``coefficients``, so beta* is the same to the bit
        sin_eta = _safe_sin_eta(xp, delta + rho + phi + beta)
        n = _n_gamma(xp, rho, beta, xp.sin(alpha + phi + beta), sin_eta)
        n = xp.where(valid & (n > 0), n, math.inf)
        if best is None:
            best, best_n = beta, n
        else:
            take = n < best_n
            best = xp.where(take, beta, best)
            best_n = xp.where(take, n, best_n)
    return xp.where(best_n < math.inf, best, math.nan)


def recorded_beta_star(phi, delta, rho, alpha):
    """β* as the simulator records it in the ground truth: ``beta_star`` where a failure wedge
    resists, else π − ρ, the plane along the blade where the wedge vanishes.

    Why: a rising blade reverses the soil-tool friction (Eq. 9-10), and in a soil weaker than
    that friction (δ' < −φ, e.g. φ 12° under the fee world's δ 15°) N_γ has no minimum over wedges
    of non-negative area (cot ρ + cot β ≥ 0): it falls to 0 at β = π − ρ. The simulator's soil then
    resists nothing (its failure force is 0), and a bag's truth must stay finite. The FEE at this β
    is not 0: c·N_c and the adhesion's c_a·N_a remain (kN with the worlds' 200 Pa adhesion alone,
    tens of kN with cohesion: N_c grows as φ + δ' → 0⁻), so on those ticks the truth's FEE is not
    the measured force. Only soils with φ below the world's δ (none of the catalogue's: its least φ
    is 17°); ``check_failure_wedges`` warns of them."""
    xp, phi, delta, rho, alpha = _xp.coerce(phi, delta, rho, alpha)
    beta = beta_star(phi, delta, rho, alpha)
    return xp.where(xp.isfinite(beta), beta, math.pi - rho + xp.zeros_like(beta))


def velocity_corrected(delta, c_a, rho, alpha, v_x, v_z, c1: float = FEE_VELOCITY_GAIN_S_M):
    """Eq. 9-10: delta' = tanh(-C1 iota_b . v) delta, c_a' = tanh(-C1 iota_b . v) c_a.

    iota_b, the unit vector up along the blade, is (-cos(rho - alpha), sin(rho - alpha)) in
    the world x-z frame (rho measured from the surface on the soil side, surface at alpha).
    A blade advancing into the soil gives iota_b . v < 0 and full friction; a blade sliding
    up past the wedge reverses the soil-tool friction and adhesion.
    """
    xp, delta, c_a, rho, alpha, v_x, v_z = _xp.coerce(delta, c_a, rho, alpha, v_x, v_z)
    iota_dot_v = -xp.cos(rho - alpha) * v_x + xp.sin(rho - alpha) * v_z
    scale = xp.tanh(-c1 * iota_dot_v)
    return scale * delta, scale * c_a


def failure_force(phi, c, delta, c_a, gamma, rho, alpha, w, d, q, beta):
    """Eq. 2 with the adhesion length fixed: F = gamma d^2 w N_g + c d w N_c + Q N_Q + c_a d w N_a.

    F [N] is 0 where d <= 0 (no wedge, the blade is out of the soil); Q only acts through a
    wedge. Pass delta', c_a' from ``velocity_corrected`` for the Eq. 9-10 behaviour.
    """
    xp, phi, c, delta, c_a, gamma, rho, alpha, w, d, q, beta = _xp.coerce(phi, c, delta, c_a, gamma, rho, alpha, w, d, q, beta)
    k = coefficients(phi, delta, rho, alpha, beta)
    d_pos = _xp.clip_min(xp, d, 0.0)
    force = gamma * d_pos**2 * w * k.n_gamma + c * d_pos * w * k.n_c + c_a * d_pos * w * k.n_a
    return force + xp.where(d > 0, q * k.n_q, 0.0 * q)


def force_xz(force, rho, delta, alpha):
    """Eq. 8: F along the direction 90 deg - rho - delta + alpha from the x axis."""
    xp, force, rho, delta, alpha = _xp.coerce(force, rho, delta, alpha)
    angle = 0.5 * math.pi - rho - delta + alpha
    return force * xp.cos(angle), force * xp.sin(angle)


def critical_beta(phi, delta, c_a, rho, alpha, v_x, v_z, c1: float = FEE_VELOCITY_GAIN_S_M):
    """β* [rad] (Eq. 7) at the δ' the blade's motion gives (Eq. 9-10): the failure angle ``fee_xz``
    uses when given none. NaN where there is no failure wedge (e.g. the soil-tool friction
    reversed by a fast lift in soil with δ > φ)."""
    delta_v, _ = velocity_corrected(delta, c_a, rho, alpha, v_x, v_z, c1)
    return beta_star(phi, delta_v, rho, alpha)


def fee_xz_of_truth(truth_rows):
    """FEE (F_x, F_z) of pseudo-ground-truth rows (..., len(GROUND_TRUTH_PARAMS)), with their beta."""
    from soil_msgs_py.params import GROUND_TRUTH_PARAMS

    theta = {name: truth_rows[..., j] for j, name in enumerate(GROUND_TRUTH_PARAMS)}
    fx, fz, _ = fee_xz(theta, beta=theta["beta"])
    return fx, fz


def fee_xz(theta: Mapping[str, object], beta=None, correct_velocity: bool = True, c1: float = FEE_VELOCITY_GAIN_S_M):
    """Full FEE layer: Θ (dict of arrays keyed by params.GROUND_TRUTH_PARAMS names) -> (F_x, F_z, F).

    ``beta`` defaults to beta* of the (velocity-corrected) parameters. ``theta['d']`` is the
    depth actually used (d' = d + delta_d for the PINN).
    """
    phi, delta, c_a = theta["phi"], theta["delta"], theta["c_a"]
    rho, alpha = theta["rho"], theta["alpha"]
    if correct_velocity:
        delta, c_a = velocity_corrected(delta, c_a, rho, alpha, theta["v_x"], theta["v_z"], c1)
    if beta is None:
        beta = beta_star(phi, delta, rho, alpha)
    force = failure_force(phi, theta["c"], delta, c_a, theta["gamma"], rho, alpha, theta["w"], theta["d"], theta["q"], beta)
    fx, fz = force_xz(force, rho, delta, alpha)
    return fx, fz, force
