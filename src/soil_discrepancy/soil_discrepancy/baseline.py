"""Step 1 of the discrepancy workflow: simulate the model against the measurement.

The model is the FEE (paper Eq. 2-10, β = β* of Eq. 7, the Eq. 9-10 velocity correction) plus
any named catalogue terms with fixed coefficients (``AugmentedFEE``). Its soil parameters
θ = (φ, c, δ) are not known on a real machine, so they are fitted to the measured force by least
squares, once per *θ-group*: the episodes that dug the same soil (same soil name and relative
density in the bag metadata), or every episode on its own when the metadata does not say
(``group_by="episode"``, or a real machine's bags with soil 'unknown'). The residual
r = F_meas − F_model per tick is what steps 2-5 analyse.

Why θ-groups and not only one θ per episode: an episode of the fee world runs at constant
target speed and depth, and three free soil parameters per episode reproduce any constant
(F_x, F_z) — so an effect that depends on speed or depth (soil inertia ∝ d v_x², rate-dependent
strength ∝ d v_x) is absorbed into a per-episode θ and is invisible. It only shows when one θ
has to explain the same soil at several speeds/depths, which is what a group does (the soil
does not know how fast the machine goes). Effects that vary within an episode (compaction
with distance) show either way.

Nothing here reads the simulator's ground truth (``Dataset.truth``) or the bag metadata's
record of which effects/plugins were switched on: only Θ_k, the measured force, time and the
soil name / relative density used as a grouping label.

Units: SI; residuals for the fit are normalised per axis by the machine force limits
(20 kN in x, 30 kN in z, ``FORCE_LIMITS_N``) like the classical fit and the PINN loss.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Mapping

import numpy as np
from scipy import sparse
from scipy.optimize import least_squares

from soil_physics import force_terms as extra_terms
from soil_msgs_py.params import KNOWN_PARAMS, SAMPLE_RATE_HZ

from pinn_estimator import classical as _cl
from pinn_estimator.dataset import distance_in_soil as _distance

FORCE_SCALE_N = _cl.FORCE_SCALE_N  # (20e3, 30e3): per-axis normalisation of force residuals
FIT_PARAMS = _cl.FIT_PARAMS  # ("phi", "c", "delta")
MIN_DEPTH_M = 0.01  # ticks with the blade in the soil deeper than this are analysed
SKIP_S = 1.0  # the start transient (blade entering the soil) is left out
UNKNOWN_SOILS = ("", "unknown", "none", "?")
PLUGIN_TARGET = "soil_physics.force_terms:plugin"
_KI = {n: i for i, n in enumerate(KNOWN_PARAMS)}
_FD_STEP = _cl.FD_STEP
_PENALTY = _cl.UNDEFINED_RESIDUAL
_DENSE_LIMIT = 0  # Jacobian entries above which the joint fit goes sparse

# Coarse start grid (normalised units of TABLE1): phi, c, delta; the best point per group
# starts its least-squares fit (clipped into the group's bounds).
_GRID_PHI = np.linspace(-0.35, 1.5, 6)  # ~7°..59°
_GRID_C = np.array([0.0, 0.15, 0.4, 0.8, 1.4, 2.5])  # 0..25 kPa
_GRID_DELTA = np.linspace(-0.3, 1.0, 5)  # ~4°..35°


# ------------------------------------------------------------------------------------ model
class AugmentedFEE:
    """The FEE model with named catalogue terms: F = F_FEE(θ, Θ_k) + Σ_j k_j B_j(inputs).

    ``terms`` are (name, k) pairs or 'name=k' strings (``extra_terms.parse_terms``). The terms'
    inputs are θ, Θ_k, the model's own FEE force and the blade's travel in soil, as in the
    simulator's effect plugin, so ``plugin_specs()`` switches on the same model in the simulator.
    """

    def __init__(self, terms=()):
        self.terms: tuple[tuple[str, float], ...] = extra_terms.parse_terms(terms)

    def __repr__(self) -> str:
        return f"AugmentedFEE(terms={self.terms!r})"

    def __eq__(self, other) -> bool:
        return isinstance(other, AugmentedFEE) and self.terms == other.terms

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(n for n, _ in self.terms)

    def with_term(self, name: str, k: float) -> "AugmentedFEE":
        """A new model with ``name`` added (or its k replaced)."""
        kept = [(n, v) for n, v in self.terms if n != name]
        return AugmentedFEE(kept + [(name, float(k))])

    def plugin_specs(self) -> list[str]:
        """Simulator plugin specs that switch the same terms on (``soil_sim_batch --plugin ...``)."""
        return [plugin_spec(n, k) for n, k in self.terms]

    def extra_term_args(self) -> list[str]:
        """``name=k`` strings, e.g. for ``pinn_train --extra-term``."""
        return [f"{n}={k:.6g}" for n, k in self.terms]

    # -- evaluation
    @staticmethod
    def fee(theta, known) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pure FEE (F_x, F_z, defined): see ``classical.fee_forces`` (0 out of the soil)."""
        phi, c, delta = _theta_tuple(theta)
        return _cl.fee_forces(phi, c, delta, _known_array(known))

    @staticmethod
    def inputs(theta, known, distance, f_fee_x, f_fee_z) -> extra_terms.TermInputs:
        phi, c, delta = _theta_tuple(theta)
        k = _known_array(known)
        col = {n: k[..., i] for n, i in _KI.items()}
        return extra_terms.TermInputs(
            d=col["d"], q=col["q"], v_x=col["v_x"], v_z=col["v_z"], gamma=col["gamma"], w=col["w"],
            rho=col["rho"], alpha=col["alpha"], phi=phi, c=c, delta=delta,
            distance_in_soil=np.asarray(distance, dtype=float), f_fee_x=f_fee_x, f_fee_z=f_fee_z,
        )

    def basis(self, name: str, theta, known, distance) -> tuple[np.ndarray, np.ndarray]:
        """(B_x, B_z) [N per unit k] of one catalogue term for this θ (0 where the FEE is undefined)."""
        fx, fz, ok = self.fee(theta, known)
        with np.errstate(all="ignore"):
            bx, bz = extra_terms.get_term(name).basis(self.inputs(theta, known, distance, fx, fz))
        bx, bz = np.broadcast_arrays(np.asarray(bx, float), np.asarray(bz, float))
        good = ok & np.isfinite(bx) & np.isfinite(bz)
        return np.where(good, bx, 0.0), np.where(good, bz, 0.0)

    def force(self, theta, known, distance, with_defined: bool = False):
        """Model force (F_x, F_z) [N, blade on soil] per tick; NaN where the FEE is undefined.

        theta: mapping with phi, c, delta (rad, Pa, rad) or a (phi, c, delta) tuple, arrays that
        broadcast against the ticks; known: (..., 9) Θ_k in KNOWN_PARAMS order or a mapping of
        those names; distance: blade travel in soil [m] per tick (``distance_in_soil``).
        """
        fx, fz, ok = self.fee(theta, known)
        if self.terms:
            with np.errstate(all="ignore"):
                dx, dz = extra_terms.apply(self.terms, self.inputs(theta, known, distance, fx, fz))
            fx, fz = fx + dx, fz + dz
            ok = ok & np.isfinite(fx) & np.isfinite(fz)
        fx = np.where(ok, fx, np.nan)
        fz = np.where(ok, fz, np.nan)
        return (fx, fz, ok) if with_defined else (fx, fz)


def plugin_spec(name: str, k: float) -> str:
    """``soil_physics.force_terms:plugin term=<name> k=<k>``: the simulator side of a term."""
    extra_terms.get_term(name)
    return f"{PLUGIN_TARGET} term={name} k={k:.6g}"


def _theta_tuple(theta):
    if isinstance(theta, Mapping):
        return tuple(np.asarray(theta[n], dtype=float) for n in FIT_PARAMS)
    phi, c, delta = theta
    return np.asarray(phi, float), np.asarray(c, float), np.asarray(delta, float)


def _known_array(known) -> np.ndarray:
    if isinstance(known, Mapping):
        return np.stack(np.broadcast_arrays(*(np.asarray(known[n], float) for n in KNOWN_PARAMS)), axis=-1)
    return np.asarray(known, dtype=float)


def distance_in_soil(known: np.ndarray, dt: float = 1.0 / SAMPLE_RATE_HZ) -> np.ndarray:
    """Blade travel in soil since the start of ONE episode [m], per tick, from Θ_k's v_x and d
    (no ground truth): the PINN's and the online estimator's definition (``data.distance_in_soil``)."""
    k = np.asarray(known, float)
    return _distance(k[:, _KI["v_x"]], k[:, _KI["d"]], dt) if len(k) else np.zeros(0)


# ------------------------------------------------------------------------------------ frame
@dataclass
class Frame:
    """The analysed ticks (blade in soil, after the start transient, every ``stride``-th).

    Episode-level arrays have length E (all episodes of the dataset, global indices); tick
    arrays length N. ``rows`` are the ticks' global row indices in the ``Dataset`` (for a PINN
    to predict at exactly these ticks; with ``skip_s`` >= 59/60 s each has a full 60-tick window).
    """

    names: list[str]
    soils: list[str]  # metadata soil name per episode ('unknown' if the bag does not say)
    densities: list[float]  # metadata relative density [%] per episode (NaN if unknown)
    group_of: np.ndarray  # (E,) θ-group index per episode
    group_names: list[str]
    episode: np.ndarray  # (N,) episode index per tick
    rows: np.ndarray  # (N,) row in the Dataset
    t: np.ndarray  # (N,) time since the episode started [s]
    known: np.ndarray  # (N, 9) Θ_k [SI]
    forces: np.ndarray  # (N, 2) measured force [N]
    distance: np.ndarray  # (N,) blade travel in soil since the start [m]
    stride: int = 1
    group_by: str = "auto"
    source: str = ""

    def __len__(self) -> int:
        return len(self.episode)

    @property
    def group(self) -> np.ndarray:
        """(N,) θ-group index per tick."""
        return self.group_of[self.episode]

    @property
    def episodes(self) -> np.ndarray:
        """Episode indices present (sorted)."""
        return np.unique(self.episode)

    @property
    def groups(self) -> np.ndarray:
        return np.unique(self.group)

    def episode_names(self, groups=None) -> list[str]:
        """Names of the episodes present (in episode order), only those of ``groups`` if given."""
        keep = None if groups is None else {int(g) for g in groups}
        return [self.names[int(e)] for e in self.episodes if keep is None or int(self.group_of[e]) in keep]

    def select(self, *, episodes=None, groups=None) -> "Frame":
        """The ticks of some episodes or θ-groups (global indices kept)."""
        mask = np.ones(len(self), bool)
        if episodes is not None:
            mask &= np.isin(self.episode, np.asarray(list(episodes), int))
        if groups is not None:
            mask &= np.isin(self.group, np.asarray(list(groups), int))
        return replace(self, episode=self.episode[mask], rows=self.rows[mask], t=self.t[mask],
                       known=self.known[mask], forces=self.forces[mask], distance=self.distance[mask])

    def column(self, name: str) -> np.ndarray:
        """A per-tick variable: a Θ_k name, 't' or 'distance'."""
        if name == "t":
            return self.t
        if name == "distance":
            return self.distance
        return self.known[:, _KI[name]]

    def has_metadata(self) -> bool:
        return any(s != "unknown" for s in self.soils)


def _soil_label(meta) -> str:
    soil = str(getattr(meta, "soil", "") or "").strip()
    return "unknown" if soil.lower() in UNKNOWN_SOILS else soil


def build_frame(ds, *, stride: int = 2, min_depth_m: float = MIN_DEPTH_M, skip_s: float = SKIP_S,
                group_by: str = "auto") -> Frame:
    """Analysis ticks of a ``pinn_estimator.dataset.Dataset`` (never touches ``ds.truth``).

    group_by: 'auto' — episodes with the same metadata soil name and relative density share θ
    (an episode whose soil is unknown is its own group); 'episode' — one θ per episode.
    """
    if stride < 1:
        raise ValueError(f"stride={stride} must be >= 1 tick")
    if group_by not in ("auto", "episode"):
        raise ValueError(f"group_by={group_by!r} must be 'auto' or 'episode'")
    n_ep = len(ds.names)
    if n_ep == 0:
        raise ValueError("the dataset has no episodes")
    dt = 1.0 / SAMPLE_RATE_HZ
    soils = [_soil_label(m) for m in ds.metas]
    dens = []
    for m in ds.metas:
        try:
            v = float(m.relative_density_pct)
        except (TypeError, ValueError, AttributeError):
            v = math.nan
        dens.append(v if math.isfinite(v) else math.nan)
    keys, group_names, group_of = {}, [], np.zeros(n_ep, int)
    for e in range(n_ep):
        if group_by == "auto" and soils[e] != "unknown":
            key = f"{soils[e]} I_d={dens[e]:g}%" if math.isfinite(dens[e]) else soils[e]
        else:
            key = ds.names[e]
        if key not in keys:
            keys[key] = len(group_names)
            group_names.append(key)
        group_of[e] = keys[key]
    parts = {k: [] for k in ("episode", "rows", "t", "known", "forces", "distance")}
    for e in range(n_ep):
        r = ds.episode_rows(e)
        known = np.asarray(ds.known[r], float)
        forces = np.asarray(ds.forces[r], float)
        n = len(known)
        t = np.arange(n) * dt
        dist = distance_in_soil(known, dt)
        keep = np.nonzero((known[:, _KI["d"]] > min_depth_m) & (t >= skip_s - 1e-9))[0][::stride]
        parts["episode"].append(np.full(len(keep), e))
        parts["rows"].append(r.start + keep)
        parts["t"].append(t[keep])
        parts["known"].append(known[keep])
        parts["forces"].append(forces[keep])
        parts["distance"].append(dist[keep])
    cat = {k: np.concatenate(v) for k, v in parts.items()}
    if len(cat["episode"]) == 0:
        raise ValueError(
            f"no tick of the {n_ep} episode(s) has the blade in the soil (d > {min_depth_m} m) after the "
            f"first {skip_s:g} s: nothing to compare the model with"
        )
    return Frame(
        names=list(ds.names), soils=soils, densities=dens, group_of=group_of, group_names=group_names,
        episode=cat["episode"].astype(int), rows=cat["rows"].astype(np.int64), t=cat["t"],
        known=cat["known"].reshape(-1, len(KNOWN_PARAMS)), forces=cat["forces"].reshape(-1, 2),
        distance=cat["distance"], stride=stride, group_by=group_by, source=str(getattr(ds, "root", "")),
    )


# ------------------------------------------------------------------------------------ fits
@dataclass
class ThetaFit:
    """Fitted soil parameters per θ-group (global group indices), SI."""

    theta: dict[int, np.ndarray] = field(default_factory=dict)  # group -> (phi, c, delta)
    success: dict[int, bool] = field(default_factory=dict)
    k: float | None = None  # the free term's coefficient (joint fits only)

    def per_tick(self, frame: Frame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        g = frame.group
        table = np.full((len(frame.group_names), 3), np.nan)
        for gi, v in self.theta.items():
            table[gi] = v
        th = table[g]
        return th[:, 0], th[:, 1], th[:, 2]

    def merged(self, other: "ThetaFit") -> "ThetaFit":
        return ThetaFit({**self.theta, **other.theta}, {**self.success, **other.success}, self.k)

    def table(self, frame: Frame) -> list[dict]:
        out = []
        for gi in sorted(self.theta):
            phi, c, delta = self.theta[gi]
            out.append({"group": frame.group_names[gi], "phi_deg": math.degrees(phi), "c_pa": float(c),
                        "delta_deg": math.degrees(delta), "success": bool(self.success.get(gi, False))})
        return out


def _norm(theta_si) -> np.ndarray:
    return np.array([_cl.TABLE1[n].normalise(v) for n, v in zip(FIT_PARAMS, theta_si)], float)


def _denorm(x) -> np.ndarray:
    return np.stack(_cl._denorm(np.asarray(x, float)), axis=-1)


def _bounds_for(known: np.ndarray):
    b = _cl._norm_bounds(float(known[:, _KI["rho"]].max()))
    if b is None:
        raise ValueError("blade angle rho leaves no room for a failure wedge (beta* undefined)")
    return b


class _Problem:
    """Normalised residuals of a model over some ticks, θ per group (vectorised over ticks)."""

    def __init__(self, frame: Frame, model: AugmentedFEE, free: str | None = None):
        self.frame = frame
        self.model = model
        self.free = free
        self.target = frame.forces / FORCE_SCALE_N
        self.groups = frame.groups
        self.local = np.searchsorted(self.groups, frame.group)  # (N,) local group index
        self.G = len(self.groups)
        lbs, ubs = [], []
        for gi in self.groups:
            lb, ub = _bounds_for(frame.known[frame.group == gi])
            lbs.append(lb)
            ubs.append(ub)
        self.lb, self.ub = np.array(lbs), np.array(ubs)  # (G, 3)

    def residuals(self, x: np.ndarray, k: float = 0.0, known=None, distance=None, target=None):
        """x (..., N_or_1, 3) normalised θ per tick (broadcast) -> r (..., N, 2), defined (..., N), basis."""
        known = self.frame.known if known is None else known
        distance = self.frame.distance if distance is None else distance
        target = self.target if target is None else target
        theta = tuple(_cl.TABLE1[n].denormalise(x[..., i]) for i, n in enumerate(FIT_PARAMS))
        fx, fz, ok = AugmentedFEE.fee(theta, known)
        bx = bz = None
        if self.model.terms or self.free is not None:
            inputs = AugmentedFEE.inputs(theta, known, distance, fx, fz)
            with np.errstate(all="ignore"):
                if self.model.terms:
                    dx, dz = extra_terms.apply(self.model.terms, inputs)
                    fx, fz = fx + dx, fz + dz
                if self.free is not None:
                    bx, bz = extra_terms.get_term(self.free).basis(inputs)
                    bx, bz = np.broadcast_arrays(np.asarray(bx, float), np.asarray(bz, float))
                    fx, fz = fx + k * bx, fz + k * bz
            ok = ok & np.isfinite(fx) & np.isfinite(fz)
        r = np.stack((fx, fz), axis=-1) / FORCE_SCALE_N - target
        r = np.where(ok[..., None], r, _PENALTY)
        if bx is not None:
            bx = np.where(ok, bx, 0.0) / FORCE_SCALE_N[0]
            bz = np.where(ok, bz, 0.0) / FORCE_SCALE_N[1]
        return r, ok, (bx, bz)

    # -- grid start
    def grid_start(self) -> np.ndarray:
        """(G, 3) normalised start: the best coarse-grid point per group."""
        grid = np.stack(np.meshgrid(_GRID_PHI, _GRID_C, _GRID_DELTA, indexing="ij"), -1).reshape(-1, 3)
        best = np.full(self.G, np.inf)
        start = 0.5 * (self.lb + self.ub)
        n = len(self.frame)
        chunk = max(1, int(2_000_000 // max(n, 1)))
        for s in range(0, len(grid), chunk):
            pts = grid[s : s + chunk]  # (K, 3)
            xs = np.clip(pts[:, None, :], self.lb[self.local][None], self.ub[self.local][None])  # (K, N, 3)
            with np.errstate(all="ignore"):
                r, _, _ = self.residuals(xs)
            sse = (r**2).sum(-1)  # (K, N)
            per = np.zeros((len(pts), self.G))
            for j in range(len(pts)):
                per[j] = np.bincount(self.local, weights=sse[j], minlength=self.G)
            j = per.argmin(0)
            better = per[j, np.arange(self.G)] < best
            best = np.where(better, per[j, np.arange(self.G)], best)
            start[better] = np.clip(pts[j[better]], self.lb[better], self.ub[better])
        return start


def fit_fixed(frame: Frame, model: AugmentedFEE, start: ThetaFit | None = None, *, max_nfev: int = 100) -> ThetaFit:
    """θ per group with the model's terms fixed: one small least-squares problem per group.

    Starts from ``start`` (e.g. the baseline θ) where it has the group, else from the coarse grid;
    if a fit leans on the undefined-FEE penalty, the grid start is tried too.
    """
    prob = _Problem(frame, model)
    need_grid = start is None or any(int(g) not in start.theta for g in prob.groups)
    grid = prob.grid_start() if need_grid else None
    out = ThetaFit()
    for j, gi in enumerate(prob.groups):
        sel = prob.local == j
        known, dist, target = frame.known[sel], frame.distance[sel], prob.target[sel]
        lb, ub = prob.lb[j], prob.ub[j]
        starts = []
        if start is not None and int(gi) in start.theta:
            starts.append(_norm(start.theta[int(gi)]))
        if grid is not None:
            starts.append(grid[j])
        best = None
        for attempt in range(3):
            if attempt >= len(starts):
                if attempt == len(starts) and grid is None:
                    grid = prob.grid_start()
                    starts.append(grid[j])
                else:
                    break
            x0 = np.minimum(np.maximum(starts[attempt], lb + 1e-9), ub - 1e-9)
            res = _fit_one(prob, x0, lb, ub, known, dist, target, max_nfev)
            if best is None or (res[2], -res[1]) > (best[2], -best[1]):
                best = res
            if res[2]:
                break
        out.theta[int(gi)] = _denorm(best[0])
        out.success[int(gi)] = bool(best[2])
    return out


def _fit_one(prob: _Problem, x0, lb, ub, known, dist, target, max_nfev):
    cache = {}

    def fun(x):
        r, _, _ = prob.residuals(x[None, :], known=known, distance=dist, target=target)
        r = r.reshape(-1)
        cache["x"], cache["r"] = x.copy(), r
        return r

    def jac(x):
        r0 = cache["r"] if "x" in cache and np.array_equal(cache["x"], x) else fun(x)
        h = np.where(x + _FD_STEP <= ub, _FD_STEP, -_FD_STEP)
        xs = x[None, :] + np.diag(h)  # (3, 3)
        r, _, _ = prob.residuals(xs[:, None, :], known=known, distance=dist, target=target)
        return ((r.reshape(3, -1) - r0[None]) / h[:, None]).T

    with np.errstate(all="ignore"):
        res = least_squares(fun, x0, jac=jac, bounds=(lb, ub), method="trf", max_nfev=max_nfev,
                            ftol=1e-10, xtol=1e-10, gtol=1e-10)
        _, ok, _ = prob.residuals(res.x[None, :], known=known, distance=dist, target=target)
    rms = math.sqrt(2.0 * res.cost / max(res.fun.size, 1))
    success = bool(res.status > 0 and np.isfinite(res.x).all() and ok.all())
    return res.x, rms, success


def linear_k(frame: Frame, model: AugmentedFEE, thetas: ThetaFit, name: str) -> float:
    """k of one term by least squares on the residuals of ``model`` with θ fixed (normalised axes)."""
    phi, c, delta = thetas.per_tick(frame)
    fx, fz, ok = model.force((phi, c, delta), frame.known, frame.distance, with_defined=True)
    bx, bz = model.basis(name, (phi, c, delta), frame.known, frame.distance)
    r = np.stack((frame.forces[:, 0] - fx, frame.forces[:, 1] - fz), -1) / FORCE_SCALE_N
    b = np.stack((bx, bz), -1) / FORCE_SCALE_N
    ok = ok & np.isfinite(r).all(-1)
    den = float((b[ok] ** 2).sum())
    return float((b[ok] * r[ok]).sum() / den) if den > 0 else 0.0


def fit_joint(frame: Frame, model: AugmentedFEE, name: str, start: ThetaFit | None = None, *,
              max_nfev: int = 60, allow_negative_k: bool = False) -> ThetaFit:
    """θ per group jointly with the coefficient k of the free term ``name`` (one shared k).

    One least-squares problem over (θ_g for every group, k); the Jacobian's θ columns come from
    three vectorised FEE evaluations (every group perturbed at once: groups own disjoint rows),
    the k column is the term's basis (the model is linear in k). Starts from ``start`` (e.g. the
    baseline θ) and k by linear least squares on its residuals.

    k >= 0 unless ``allow_negative_k``: every catalogue term is written so that its physics has
    k > 0 (a negative "friction" or "hardening" is not that effect but a correction of
    something else, and is not named as the effect).
    """
    if name in model.names:
        raise ValueError(f"term {name!r} is already in the model with a fixed k")
    start = start if start is not None and all(int(g) in start.theta for g in frame.groups) else fit_fixed(frame, model, start)
    prob = _Problem(frame, model, free=name)
    G, N = prob.G, len(frame)
    k0 = linear_k(frame, model, start, name)
    b = np.stack(model.basis(name, start.per_tick(frame), frame.known, frame.distance), -1) / FORCE_SCALE_N
    scale_k = 1.0 / max(math.sqrt(float((b**2).mean())), 1e-12) * math.sqrt(float((prob.target**2).mean()) + 1e-12)
    x0 = np.array([_norm(start.theta[int(g)]) for g in prob.groups])
    x0 = np.minimum(np.maximum(x0, prob.lb + 1e-9), prob.ub - 1e-9)
    k_lo = -np.inf if allow_negative_k else 0.0
    p0 = np.concatenate([x0.reshape(-1), [max(k0, k_lo) / scale_k]])
    lb = np.concatenate([prob.lb.reshape(-1), [k_lo]])
    ub = np.concatenate([prob.ub.reshape(-1), [np.inf]])
    rows = np.arange(2 * N)
    tick_of_row = rows // 2
    col_group = prob.local[tick_of_row]
    dense = 2 * N * (3 * G + 1) <= _DENSE_LIMIT
    cache = {}

    def unpack(p):
        return p[:-1].reshape(G, 3), p[-1] * scale_k

    def fun(p):
        x, k = unpack(p)
        r, _, basis = prob.residuals(x[prob.local], k)
        r = r.reshape(-1)
        cache["p"], cache["r"], cache["b"] = p.copy(), r, basis
        return r

    def jac(p):
        if not ("p" in cache and np.array_equal(cache["p"], p)):
            fun(p)
        r0, (bx, bz) = cache["r"], cache["b"]
        x, k = unpack(p)
        h = np.where(x + _FD_STEP <= prob.ub, _FD_STEP, -_FD_STEP)  # (G, 3)
        cols = []
        for j in range(3):
            xp = x.copy()
            xp[:, j] += h[:, j]
            r, _, _ = prob.residuals(xp[prob.local], k)
            cols.append((r.reshape(-1) - r0) / h[col_group, j])
        kcol = np.stack((bx, bz), -1).reshape(-1) * scale_k
        if dense:
            J = np.zeros((2 * N, 3 * G + 1))
            for j in range(3):
                J[rows, 3 * col_group + j] = cols[j]
            J[:, -1] = kcol
            return J
        data = np.concatenate(cols + [kcol])
        ri = np.concatenate([rows] * 4)
        ci = np.concatenate([3 * col_group + j for j in range(3)] + [np.full(2 * N, 3 * G)])
        return sparse.csr_matrix((data, (ri, ci)), shape=(2 * N, 3 * G + 1))

    with np.errstate(all="ignore"):
        res = least_squares(fun, p0, jac=jac, bounds=(lb, ub), method="trf", max_nfev=max_nfev,
                            ftol=1e-10, xtol=1e-10, gtol=1e-10, tr_solver="exact" if dense else "lsmr")
    x, k = unpack(res.x)
    with np.errstate(all="ignore"):
        _, ok, _ = prob.residuals(x[prob.local], k)
    out = ThetaFit(k=float(k))
    for j, gi in enumerate(prob.groups):
        out.theta[int(gi)] = _denorm(x[j])
        out.success[int(gi)] = bool(ok[prob.local == j].all() and np.isfinite(x[j]).all())
    return out


def residuals(frame: Frame, model: AugmentedFEE, thetas: ThetaFit) -> tuple[np.ndarray, np.ndarray]:
    """(r (N, 2) = F_meas − F_model [N], F_model (N, 2)); NaN where the model is undefined."""
    fx, fz = model.force(thetas.per_tick(frame), frame.known, frame.distance)
    f_model = np.stack((fx, fz), -1)
    return frame.forces - f_model, f_model


def term_inputs(frame: Frame, thetas: ThetaFit) -> extra_terms.TermInputs:
    """The catalogue's TermInputs of the analysed ticks (θ of the fit, the model's FEE force)."""
    theta = thetas.per_tick(frame)
    fx, fz, _ = AugmentedFEE.fee(theta, frame.known)
    return AugmentedFEE.inputs(theta, frame.known, frame.distance, fx, fz)
