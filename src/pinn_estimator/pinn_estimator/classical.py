"""Classical baseline: fit the FEE to measured blade forces by nonlinear least squares.

What a user without the PINN would do (after Tan et al. 2005, "Online soil parameter
estimation scheme based on Newton-Raphson method for autonomous excavation"): take a window
of T ticks, assume the soil (phi, c, delta) is constant over it, take every other FEE input
from the same known parameters Θ_k the PINN gets (c_a, gamma, rho, alpha, w, d, Q, v), put
the soil failure angle at beta* = argmin N_gamma per tick (paper Eq. 7, closed form in
``soil_physics.fee.beta_star``) and solve

    min_{phi, c, delta}  sum_t sum_{x,z} ((F_fee,t - F_meas,t) / F_limit)^2

with ``scipy.optimize.least_squares``. Dividing by the machine force limits (20 kN in x,
30 kN in z, paper §2.1.2) makes both axes dimensionless and comparable, as the PINN's
loss does with its normalised forces.

Solver: method 'trf' (a trust-region reflective Gauss-Newton/Levenberg-Marquardt variant
that, unlike MINPACK's 'lm', accepts bounds; the bounds are needed to keep the FEE
defined). The Jacobian is a forward difference whose three perturbed points are evaluated
in one vectorised FEE call, and the fit is repeated from up to ``len(STARTS)`` start points
if the first one fails (on the sample bags every start reached the same minimum, so the
extra starts are a fallback, not a default cost).

Identifiability: the FEE force direction fixes delta (F is at 90° - rho - delta' + alpha);
phi and c are only separable when the depth varies within the window (gamma d^2 vs c d).
At constant depth the fit reproduces the force but phi/c lie anywhere along a valley; that
is the FEE ambiguity the paper discusses in §3.2, not a solver failure.

SI units throughout (rad, Pa, N, m); the solver works in Table 1 normalised units so that
one step size suits phi, c and delta alike.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from soil_physics import fee
from soil_physics.augmented_fee import THETA_PARAMS, fee_forces
from soil_msgs_py import cli_numbers
from soil_msgs_py.params import DEG, FORCE_FIELDS, FORCE_LIMITS_N, KNOWN_PARAMS, TABLE1

FIT_PARAMS: tuple[str, ...] = THETA_PARAMS  # the soil the fit estimates: phi, c, delta

# Search box [SI]. Table 1's normalisation ranges (phi 17-45°, c 0-10 kPa, delta 11-35°)
# widened so that a soil just outside them is still found rather than pinned to a bound:
# phi 5-60° (dry loose sand to dense gravel), c 0-50 kPa (stiff clay), delta 0-45°.
# phi > 0 keeps N_c finite; delta >= 0 is physical (the fitted delta is the full-friction
# value, velocity scaling by Eq. 9-10 is applied per tick as in the PINN).
PHI_BOUNDS_RAD = (5.0 * DEG, 60.0 * DEG)
C_BOUNDS_PA = (0.0, 50e3)
DELTA_BOUNDS_RAD = (0.0, 45.0 * DEG)
# beta* needs delta' + rho + phi < 180° (else eta >= 180° for every beta > 0); for rho = 80°
# a 1° grid shows that this and phi + delta' > 0 are also sufficient, and then
# eta = delta' + rho + phi + beta* < 180°. Since |delta'| <= delta, the box is narrowed per
# window so that phi + delta <= 180° - max(rho) - this margin
# (close to the limit N_c ~ 1/(sin beta sin eta) explodes). delta gives way first, but not
# below Table 1's upper normalisation value (35°); then phi. For rho = 80° (every
# experiment, §3.1) this means delta <= 38°, phi <= 60°.
ETA_MARGIN_RAD = 2.0 * DEG
# Residual (in units of the machine limit, per axis) given to a tick in the soil (d > 0)
# where beta* does not exist for the trial parameters (e.g. a rising blade, delta' < 0,
# with phi < |delta'|). Large and finite, so the optimiser backs out instead of seeing NaN.
UNDEFINED_RESIDUAL = 10.0
FORCE_SCALE_N = np.array(FORCE_LIMITS_N)
# Start points in normalised units (phi, c, delta): the centre of the Table 1 ranges first;
# only if that fit fails, a frictional/weakly cohesive and then a cohesive/low-friction soil.
STARTS: tuple[tuple[float, float, float], ...] = ((0.5, 0.5, 0.5), (0.75, 0.05, 0.3), (0.2, 1.5, 0.7))
# Forward-difference step in normalised units (x ~ O(1); well above sqrt(eps) * |x|).
FD_STEP = 1e-7
MAX_NFEV = 200
_CHUNK = 64


@dataclass
class ClassicalFit:
    """Per-window result, arrays of shape (W,) unless noted. SI units."""

    phi: np.ndarray  # rad
    c: np.ndarray  # Pa
    delta: np.ndarray  # rad
    beta: np.ndarray  # rad, beta* of the fitted params at the window's last tick (NaN if none)
    f_fee: np.ndarray  # (W, 2) FEE force [N] at the window's last tick from the fitted params
    success: np.ndarray  # bool, converged (scipy status > 0), finite, FEE defined at every tick
    cost: np.ndarray  # final normalised RMS residual (1.0 = machine force limit)

    def __len__(self) -> int:
        return len(self.phi)


# ---------------------------------------------------------------------------- validation


def _check_inputs(known, forces) -> tuple[np.ndarray, np.ndarray]:
    """Shapes, dtypes and finiteness; ValueError names the array, field and first bad index."""
    arrays = {}
    for name, arr, fields in (("known", known, KNOWN_PARAMS), ("forces", forces, FORCE_FIELDS)):
        try:
            a = np.asarray(arr, dtype=float)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{name} must be a numeric array: {exc}") from exc
        if a.ndim != 3 or a.shape[2] != len(fields):
            raise ValueError(
                f"{name} has shape {a.shape}, expected (W, T, {len(fields)}) with the last axis {fields}"
            )
        bad = ~np.isfinite(a)
        if bad.any():
            w, t, j = (int(i) for i in np.argwhere(bad)[0])
            raise ValueError(
                f"{name} has a non-finite value ({a[w, t, j]}) in field {fields[j]!r} "
                f"at window {w}, tick {t} ({int(bad.sum())} non-finite values in total)"
            )
        arrays[name] = a
    k, f = arrays["known"], arrays["forces"]
    if k.shape[:2] != f.shape[:2]:
        raise ValueError(f"known has (W, T) = {k.shape[:2]} but forces has {f.shape[:2]}")
    if k.shape[1] < 2:
        raise ValueError(f"windows need T >= 2 ticks (4 residuals for 3 unknowns), got T = {k.shape[1]}")
    lo, hi = TABLE1["rho"].limits
    rho = k[..., KNOWN_PARAMS.index("rho")]
    out = (rho < lo) | (rho > hi)
    if out.any():
        w, t = (int(i) for i in np.argwhere(out)[0])
        raise ValueError(
            f"known field 'rho' = {rho[w, t]:.4g} rad at window {w}, tick {t} is outside "
            f"Table 1's limits [{lo:.4g}, {hi:.4g}] rad; the FEE is undefined there"
        )
    return k, f


# ------------------------------------------------------------------------------ the model


def normalised_bounds(rho_max: float) -> tuple[np.ndarray, np.ndarray] | None:
    """Normalised (lb, ub) of the search box for ticks whose largest blade angle is ``rho_max``
    [rad], narrowed so beta* exists for every tick's rho; None if no useful soil fits."""
    phi_lo, phi_hi = PHI_BOUNDS_RAD
    d_lo, d_hi = DELTA_BOUNDS_RAD
    room = math.pi - rho_max - ETA_MARGIN_RAD
    if phi_hi + d_hi > room:
        d_hi = max(room - phi_hi, min(d_hi, TABLE1["delta"].norm[1]))
        phi_hi = min(phi_hi, room - d_hi)
        if phi_hi <= phi_lo + 1.0 * DEG:  # rho so steep that no useful soil fits: give up
            return None
    lo = np.array([TABLE1["phi"].normalise(phi_lo), TABLE1["c"].normalise(C_BOUNDS_PA[0]), TABLE1["delta"].normalise(d_lo)])
    hi = np.array([TABLE1["phi"].normalise(phi_hi), TABLE1["c"].normalise(C_BOUNDS_PA[1]), TABLE1["delta"].normalise(d_hi)])
    return lo, hi


def denormalise_theta(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The solver's normalised (..., 3) -> SI (phi, c, delta)."""
    return tuple(TABLE1[n].denormalise(x[..., i]) for i, n in enumerate(FIT_PARAMS))


def normalise_theta(theta_si) -> np.ndarray:
    """SI (phi, c, delta) -> the solver's normalised (3,), e.g. to start a fit from a known soil."""
    return np.array([TABLE1[n].normalise(v) for n, v in zip(FIT_PARAMS, theta_si)], float)


def normalised_residuals(fx, fz, defined, target: np.ndarray) -> np.ndarray:
    """(..., 2) residual F / F_limit − target per tick; UNDEFINED_RESIDUAL where the FEE is not defined."""
    r = np.stack((fx, fz), axis=-1) / FORCE_SCALE_N - target
    return np.where(defined[..., None], r, UNDEFINED_RESIDUAL)


def forward_steps(x: np.ndarray, ub: np.ndarray) -> np.ndarray:
    """Forward-difference steps that stay inside the box: +FD_STEP, or −FD_STEP at the upper bound."""
    return np.where(x + FD_STEP <= ub, FD_STEP, -FD_STEP)


def forward_jacobian(residuals_at, x: np.ndarray, r0: np.ndarray, ub: np.ndarray) -> np.ndarray:
    """(M, 3) Jacobian at x (3,) from one call ``residuals_at(points (3, 3)) -> (3, M)``, r0 (M,) at x."""
    h = forward_steps(x, ub)
    r = residuals_at(x[None, :] + np.diag(h))
    return ((r - r0[None, :]) / h[:, None]).T


class _Window:
    """Residuals and a one-call forward-difference Jacobian for one window."""

    def __init__(self, known: np.ndarray, forces: np.ndarray, lb: np.ndarray, ub: np.ndarray):
        self.known = known  # (T, 9)
        self.target = forces / FORCE_SCALE_N  # (T, 2)
        self.lb, self.ub = lb, ub
        self._last_x = None
        self._last_r = None

    def _residuals(self, xs: np.ndarray, with_defined: bool = False):
        """xs (K, 3) normalised -> (K, 2T) residuals, NaN-free."""
        phi, c, delta = denormalise_theta(xs[:, None, :])
        fx, fz, defined = fee_forces(phi, c, delta, self.known)
        r = normalised_residuals(fx, fz, defined, self.target).reshape(len(xs), -1)
        return (r, defined) if with_defined else r

    def fun(self, x: np.ndarray) -> np.ndarray:
        r = self._residuals(x[None])[0]
        self._last_x, self._last_r = x.copy(), r
        return r

    def jac(self, x: np.ndarray) -> np.ndarray:
        if self._last_x is not None and np.array_equal(x, self._last_x):
            r0 = self._last_r
        else:
            r0 = self.fun(x)
        return forward_jacobian(self._residuals, x, r0, self.ub)

    def fit(self) -> tuple[np.ndarray, float, bool]:
        """Best of the starts: (x normalised, RMS residual, success)."""
        best = None
        for start in STARTS:
            x0 = np.clip(np.asarray(start, dtype=float), self.lb, self.ub)
            x0 = np.minimum(np.maximum(x0, self.lb + 1e-6), self.ub - 1e-6)
            try:
                res = least_squares(self.fun, x0, jac=self.jac, bounds=(self.lb, self.ub), method="trf", max_nfev=MAX_NFEV)
            except (ValueError, np.linalg.LinAlgError):
                continue
            rms = math.sqrt(2.0 * res.cost / res.fun.size)
            finite = bool(np.all(np.isfinite(res.x)) and math.isfinite(rms))
            # An optimum that leans on the penalty (beta* undefined in the soil) is no FEE fit.
            defined = finite and bool(self._residuals(res.x[None], with_defined=True)[1].all())
            ok = bool(res.success) and finite and defined
            if finite and (best is None or (ok, -rms) > (best[2], -best[1])):
                best = (res.x, rms, ok)
            if ok:
                break
        if best is None:
            return np.full(3, np.nan), math.nan, False
        return best


def _fit_chunk(args) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fit windows known (w, T, 9), forces (w, T, 2) -> (x (w, 3), rms (w,), success (w,))."""
    known, forces = args
    n = len(known)
    xs = np.full((n, 3), np.nan)
    rms = np.full(n, np.nan)
    ok = np.zeros(n, dtype=bool)
    rho_i = KNOWN_PARAMS.index("rho")
    d_i = KNOWN_PARAMS.index("d")
    for i in range(n):
        bounds = normalised_bounds(float(known[i, :, rho_i].max()))
        if bounds is None or not np.any(known[i, :, d_i] > 0):
            continue  # no blade in the soil: the FEE is 0 whatever the soil, nothing to fit
        xs[i], rms[i], ok[i] = _Window(known[i], forces[i], *bounds).fit()
    return xs, rms, ok


def fit_windows(known: np.ndarray, forces: np.ndarray, *, workers: int = 1, progress: bool = False) -> ClassicalFit:
    """Fit (phi, c, delta) per window by least squares on the FEE.

    known (W, T, 9) Θ_k per tick in KNOWN_PARAMS order [SI], forces (W, T, 2) measured blade
    force per tick in FORCE_FIELDS order [N, blade on soil, x forward, z up]. One fit of
    (phi, c, delta) per window, beta = beta* per tick, the same known parameters as the PINN
    gets. ``workers > 1`` fits chunks of windows in a fork-based process pool; ``progress``
    shows a tqdm bar over windows. Windows that cannot be fitted (no tick with d > 0, or a
    blade angle leaving no room for a failure wedge) get NaN and success False.
    """
    k, f = _check_inputs(known, forces)
    n_win = len(k)
    chunks = [(k[s : s + _CHUNK], f[s : s + _CHUNK]) for s in range(0, n_win, _CHUNK)]
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=n_win, desc="classical FEE fit", unit="win")
    results = []
    try:
        if workers > 1 and len(chunks) > 1:
            from soil_msgs_py.process_pool import map_in_processes

            for out, (kc, _) in zip(map_in_processes(_fit_chunk, chunks, min(workers, len(chunks)),
                                                     what="fitting the classical FEE"), chunks):
                results.append(out)
                if bar is not None:
                    bar.update(len(kc))
        else:
            for chunk in chunks:
                results.append(_fit_chunk(chunk))
                if bar is not None:
                    bar.update(len(chunk[0]))
    finally:
        if bar is not None:
            bar.close()
    if results:
        xs = np.concatenate([r[0] for r in results])
        rms = np.concatenate([r[1] for r in results])
        ok = np.concatenate([r[2] for r in results])
    else:
        xs, rms, ok = np.zeros((0, 3)), np.zeros(0), np.zeros(0, dtype=bool)
    phi, c, delta = denormalise_theta(xs)
    return _finish(phi, c, delta, k, rms, ok)


def _finish(phi, c, delta, known, rms, ok) -> ClassicalFit:
    """beta* and the FEE force at each window's last tick from the fitted parameters."""
    last = known[:, -1, :] if len(known) else np.zeros((0, len(KNOWN_PARAMS)))
    fx, fz, _ = fee_forces(phi, c, delta, last)
    theta = {n: last[:, i] for i, n in enumerate(KNOWN_PARAMS)}
    with np.errstate(all="ignore"):
        beta = fee.critical_beta(phi, delta, theta["c_a"], theta["rho"], theta["alpha"], theta["v_x"], theta["v_z"])
    ok = ok & np.isfinite(phi) & np.isfinite(c) & np.isfinite(delta) & np.isfinite(rms)
    return ClassicalFit(
        phi=np.asarray(phi, float), c=np.asarray(c, float), delta=np.asarray(delta, float),
        beta=np.asarray(beta, float), f_fee=np.stack((fx, fz), axis=-1), success=ok, cost=np.asarray(rms, float),
    )


def default_workers() -> int:
    """Cores this process may use (for callers that want a sensible ``workers``)."""
    return cli_numbers.cores()
