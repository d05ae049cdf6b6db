"""Step 3b: when no catalogue term explains the residual, find its *form* by sparse regression.

The library (``soil_physics.term_forms``) holds a few hundred candidate forms, each a force [N] up
to a dimensionless coefficient: a scale (the FEE force, γ d² w, w d P_ref, (γ/g) w d v_x², Q, the
edge's bearing capacity, the model's downward push, a constant 1 kN) times a factor or gate (v_x,
v_x², d, travel s, saturating tanh(v_x/v0), fading exp(−v_x/v0), entering exp(−s/s0), growing 1 − exp(−s/s0), time in
soil τ and the same shapes of it, the share of the cut below a layer's top (d − d0)+/d, and the
gates "edge sinking", "edge rising", "holding depth", "at a force limit").

1. Linearise the current model around its fitted θ per θ-group: r ≈ J_g Δθ_g + Σ_j k_j B_j.
   θ is refitted whenever a term is added, so what a form can explain is only the part of its
   basis that θ cannot absorb. Both the residual and every form's basis are projected, group by
   group, onto the orthogonal complement of that group's three θ-columns J_g (finite
   differences of the model force in φ, c, δ): the profile likelihood of k with θ free, to
   first order. A form that θ absorbs entirely (|projected| < ``MIN_IDENTIFIABLE`` of its
   norm) is not identifiable and is dropped. Where soil tests hold a parameter (``soil_tests``), θ
   may move only within the test's interval, so that parameter's column is not projected off:
   what the held θ cannot take is left to the forms.
2. Orthogonal matching pursuit (scikit-learn ``OrthogonalMatchingPursuitCV``: greedy forward
   selection with a least-squares refit at every step) on the projected, unit-norm columns, the
   number of terms chosen by cross-validation with ``GroupKFold`` over θ-groups (a soil is never
   in its own fold's training part). Rows are the ticks' normalised x and z residuals (the
   machine force limits 20 kN, 30 kN, as in every fit here). The lasso was tried first: with
   hundreds of strongly correlated columns it spreads the weight over dozens of them and its
   largest coefficients were not the hidden form; the greedy path's first entries were.
3. The first forms on that path (``MAX_CANDIDATES``), each signed so that k > 0, are refitted
   together by ordinary least squares on the projected columns, with cluster-robust (by
   episode: ticks of one episode are autocorrelated) standard errors.

The forms so found are only *candidates*: the workflow passes them, with the remaining catalogue
terms, to the same held-out test every catalogue term faces (``candidates.select_terms``: k and θ
refitted jointly on the training groups, θ refitted on the held-out groups, a Wilcoxon test over
held-out episodes, Holm, a least gain, a determined k). A form is accepted only if it beats every
catalogue term there; nothing passes on the regression alone.
"""
from __future__ import annotations

import math
import warnings

import numpy as np

from soil_msgs_py.values import finite_number, short_repr, yaml_exponent
from soil_physics import force_terms, term_forms
from soil_physics.augmented_fee import AugmentedFEE

from pinn_estimator.classical import FORCE_SCALE_N
from .candidates import FOLDS, paired_tests
from .fee_fit import ThetaFit
from .regimes import holm
from .frame import Frame
from .soil_tests import held_parameters
from soil_msgs_py.yaml_file import read_yaml

MAX_CANDIDATES = 3  # forms passed on to the held-out test
MAX_PATH = 8  # longest greedy path the cross-validation considers
MAX_TICKS = 20_000  # the regression reads at most this many ticks (evenly thinned): 2 rows per tick, one column per form
MIN_IDENTIFIABLE = 0.05  # a form's projected norm below this share of its norm: θ absorbs it
DUPLICATE_COS = 0.999  # projected columns this parallel are one column (the first is kept)
CATALOGUE_COS = 0.99  # a form this parallel to a catalogue candidate (projected) is that term: not searched where the term can take it (k >= 0)
CLOSE_COS = 0.9  # a form this parallel to a catalogue term (after projection, same sign) is that mechanism
_THETA_STEPS = (1e-3, None, 1e-3)  # φ [rad], c [Pa: 1e-3 c + 10 Pa], δ [rad]


def _c_step(c):
    return 1e-3 * np.abs(c) + 10.0


def theta_jacobian(frame: Frame, model: AugmentedFEE, fit: ThetaFit) -> np.ndarray:
    """(N, 2, 3) ∂F_model/∂(φ, c, δ) per tick, normalised by the force scales (forward differences)."""
    theta = [np.asarray(a, float) for a in fit.per_tick(frame)]
    f0 = np.stack(model.force(theta, frame.known, frame.distance, time_in_soil=frame.time_in_soil), -1)
    cols = []
    for j in range(3):
        th = [a.copy() for a in theta]
        h = _c_step(th[1]) if j == 1 else np.full(len(frame), _THETA_STEPS[j])
        th[j] = th[j] + h
        f1 = np.stack(model.force(th, frame.known, frame.distance, time_in_soil=frame.time_in_soil), -1)
        cols.append((f1 - f0) / h[:, None] / FORCE_SCALE_N)
    J = np.stack(cols, -1)
    # a parameter a soil test holds (``soil_tests``) moves only within the test's interval: what it
    # cannot take is the residual's, so its direction is not taken off the residual or the forms
    J = np.where(held_parameters(frame)[:, None, :], 0.0, J)
    return np.where(np.isfinite(J), J, 0.0)


def form_bases(frame: Frame, fit: ThetaFit, names) -> np.ndarray:
    """(N, 2, P) basis of each named term (form or catalogue) at the fitted θ, normalised by the force scales."""
    theta = fit.per_tick(frame)
    out = np.zeros((len(frame), 2, len(names)))
    for i, (bx, bz) in enumerate(AugmentedFEE().bases(names, theta, frame.known, frame.distance, frame.time_in_soil)):
        out[:, 0, i], out[:, 1, i] = bx, bz
    return out / FORCE_SCALE_N[None, :, None]


def _project(frame: Frame, J: np.ndarray, *arrays: np.ndarray) -> list[np.ndarray]:
    """Per θ-group, remove from each (N, 2, ...) array its least-squares fit by the group's columns J
    (N, 2, m): the θ-columns, and any terms whose k is profiled out with them."""
    out = [a.reshape(len(frame), 2, -1).copy() for a in arrays]
    group = frame.group
    for g in np.unique(group):
        m = group == g
        Jg = J[m].reshape(-1, J.shape[-1])
        u, s, _ = np.linalg.svd(Jg, full_matrices=False)
        u = u[:, s > 1e-9 * max(float(s.max()), 1e-300)]
        for a in out:
            block = a[m].reshape(-1, a.shape[-1])
            a[m] = (block - u @ (u.T @ block)).reshape(-1, 2, a.shape[-1])
    return out


def _normalised_residual(frame: Frame, model: AugmentedFEE, fit: ThetaFit) -> tuple[Frame, np.ndarray]:
    """(frame, (N, 2) residual normalised by the force scales) on the ticks where the model is
    defined and finite, at most ``MAX_TICKS`` of them (thinned evenly: ticks of an episode are
    autocorrelated, little is lost)."""
    theta = fit.per_tick(frame)
    fx, fz, ok = model.force(theta, frame.known, frame.distance, with_defined=True, time_in_soil=frame.time_in_soil)
    resid = (frame.forces - np.stack((fx, fz), -1)) / FORCE_SCALE_N
    ok = ok & np.isfinite(resid).all(-1)
    if len(ok) > MAX_TICKS:
        ok &= np.arange(len(ok)) % math.ceil(len(ok) / MAX_TICKS) == 0
    if not ok.all():
        frame, resid = frame.subset(ok), resid[ok]
    return frame, resid


def search_forms(frame: Frame, model: AugmentedFEE, fit: ThetaFit, *, folds: int = FOLDS, names=None,
                 max_candidates: int = MAX_CANDIDATES, catalogue=(), log=None) -> dict:
    """Sparse regression of ``model``'s residual (θ per group ``fit``) on the library of forms.

    Returns {'candidates': [signed form names, in the order they entered the greedy path],
    'library_size', 'identifiable', 'n_terms_cv' (the path length cross-validation chose),
    'cv_r2' (held-out-group share of the θ-projected residual that path explains),
    'ols': [{'name', 'k', 'k_se', 't'}], 'dropped_absorbed'}. ``names``: the library (default all forms).
    """
    from sklearn.linear_model import LinearRegression, OrthogonalMatchingPursuitCV, orthogonal_mp
    from sklearn.model_selection import GroupKFold

    names = list(names or term_forms.form_names())
    frame, resid = _normalised_residual(frame, model, fit)
    J = theta_jacobian(frame, model, fit)
    B = form_bases(frame, fit, names)
    norm0 = np.sqrt((B**2).sum((0, 1)))
    y, X = _project(frame, J, resid[..., None], B)
    y, X = y.reshape(-1), X.reshape(-1, len(names))
    norm = np.sqrt((X**2).sum(0))
    keep = np.nonzero((norm0 > 0) & (norm > MIN_IDENTIFIABLE * np.maximum(norm0, 1e-300)))[0]
    absorbed = [names[i] for i in range(len(names)) if norm0[i] > 0 and i not in set(keep)]
    Xn = X[:, keep] / norm[keep]
    keep, Xn = _dedupe(keep, Xn)
    same = []  # forms that are a catalogue candidate's column: the catalogue's name is kept for it
    catalogue = [c for c in catalogue if not str(c).startswith(term_forms.PREFIX)]
    if catalogue and len(keep):
        (C,) = _project(frame, J, form_bases(frame, fit, catalogue))
        C = C.reshape(-1, len(catalogue))
        cn = np.sqrt((C**2).sum(0))
        C = C[:, cn > 0] / cn[cn > 0]
        # a form parallel to a catalogue term is that term, but only where the term can take the
        # residual: its k >= 0 (``fee_fit.fit_joint``), so a residual the term would need k < 0 for
        # (e.g. less drag from the pile than the model's, against surcharge_drag's +k Q) is left to
        # the form, which is signed (before: dropped here and refused k < 0 there, nothing took it)
        takes = (C.T @ y > 0) if C.shape[1] else np.zeros(0, bool)  # (catalogue,) would fit with k > 0
        dup = ((np.abs(Xn.T @ C) > CATALOGUE_COS) & takes[None, :]).any(1) if C.shape[1] else np.zeros(len(keep), bool)
        same = [names[i] for i in keep[dup]]
        keep, Xn = keep[~dup], Xn[:, ~dup]
    rows_group = np.repeat(frame.group, 2)
    n_groups = len(np.unique(rows_group))
    result = {"library_size": len(names), "identifiable": int(len(keep)), "dropped_absorbed": len(absorbed),
              "same_as_catalogue": same,
              "candidates": [], "ols": [], "n_terms_cv": 0, "cv_r2": None}
    if len(keep) == 0 or n_groups < 2:
        return result
    cv = list(GroupKFold(n_splits=min(folds, n_groups)).split(Xn, y, rows_group))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # near-collinear columns
        omp = OrthogonalMatchingPursuitCV(fit_intercept=False, cv=cv, max_iter=MAX_PATH).fit(Xn, y)
        path = orthogonal_mp(Xn, y, n_nonzero_coefs=max(omp.n_nonzero_coefs_, 1), return_path=True)
    path = np.asarray(path).reshape(Xn.shape[1], -1)
    entered = []  # columns in the order they entered the greedy path
    for step in range(path.shape[1]):
        entered += [int(i) for i in np.nonzero(path[:, step])[0] if int(i) not in entered]
    coef = omp.coef_
    order = [i for i in entered if coef[i] != 0][:max_candidates]
    chosen = [names[keep[i]] if coef[i] > 0 else term_forms.negated(names[keep[i]]) for i in order]
    # held-out-group share of the θ-projected residual explained at the chosen number of terms
    held_mse, null_mse = [], []
    for tr, te in cv:
        sub = orthogonal_mp(Xn[tr], y[tr], n_nonzero_coefs=max(omp.n_nonzero_coefs_, 1))
        held_mse.append(float(np.mean((y[te] - Xn[te] @ sub) ** 2)))
        null_mse.append(float(np.mean(y[te] ** 2)))
    result.update(n_terms_cv=int(omp.n_nonzero_coefs_), candidates=chosen,
                  cv_r2=1.0 - float(np.sum(held_mse)) / max(float(np.sum(null_mse)), 1e-300))
    if order:
        cols = X[:, [keep[i] for i in order]] * np.sign(coef[order])
        ols = LinearRegression(fit_intercept=False).fit(cols, y)
        se = _cluster_se(cols, y - ols.predict(cols), np.repeat(frame.episode, 2))
        result["ols"] = [{"name": n, "k": float(k), "k_se": float(s), "t": float(k / s) if s > 0 else math.inf}
                         for n, k, s in zip(chosen, ols.coef_, se)]
    if log:
        log(f"form search: {len(names)} forms, {len(keep)} identifiable beside θ ({len(absorbed)} absorbed by θ); "
            f"orthogonal matching pursuit (GroupKFold over {n_groups} θ-groups) chose {result['n_terms_cv']} term(s), "
            f"cross-validated R² {result['cv_r2']:.2f}; candidates: {', '.join(chosen) or 'none'}")
    return result


def _dedupe(keep: np.ndarray, Xn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Drop columns (unit norm) parallel to an earlier one."""
    gram = np.abs(Xn.T @ Xn)
    drop = set()
    for i in range(len(keep)):
        if i in drop:
            continue
        for j in np.nonzero(gram[i, i + 1:] > DUPLICATE_COS)[0] + i + 1:
            drop.add(int(j))
    idx = [i for i in range(len(keep)) if i not in drop]
    return keep[idx], Xn[:, idx]


def _cluster_se(X: np.ndarray, e: np.ndarray, cluster: np.ndarray) -> np.ndarray:
    """Cluster-robust (sandwich, CR1) standard errors of an OLS fit."""
    xtx_inv = np.linalg.pinv(X.T @ X)
    meat = np.zeros((X.shape[1], X.shape[1]))
    ids = np.unique(cluster)
    for c in ids:
        m = cluster == c
        s = X[m].T @ e[m]
        meat += np.outer(s, s)
    G, n, p = len(ids), len(e), X.shape[1]
    factor = G / max(G - 1, 1) * (n - 1) / max(n - p, 1)
    return np.sqrt(np.maximum(np.diag(xtx_inv @ meat @ xtx_inv) * factor, 0.0))


# ------------------------------------------------------------------------------------ pinned down?
RIVALS_SHOWN = 5  # rivals the report lists (the count is kept)
# A rival significantly better that takes this many times the named term's share makes it a
# stand-in: the layer that was not there took 11 % where an F_z form took 23 %, the hard spot's
# entry relief 18 % against 27 %; a rate law's linear drag, the right mechanism, 91.0 % against a
# concave form's 91.2 % (significant over 75 episodes, but the same story).
STAND_IN_SHARE_RATIO = 1.2
# A factor of a variable each episode holds at a set level (a grid's target depth or speed): over
# fewer than MIN_SHAPE_LEVELS levels of it no factor of it can be told from another, k, θ and a
# characteristic value matching any of them at two levels. An outside tester's drag ∝ 0.3 / v_x on
# two speeds was "explained" as exp(−v_x / 0.3 m/s), "its shape pinned down"; on three speeds the
# same workflow found rivals. A catalogue term's form claims such a factor too (its
# ``factor_variable``: rate_strength's v_x): a √v_x drag on two speeds was named rate_strength,
# "pinned down", before the check read it.
# The analysed ticks' values are split where the gap to the next value exceeds half a window's
# width, and each part grouped from its lowest value up, a window spanning LEVEL_WIDTH_OF_SPAN of
# the whole span or LEVEL_WIDTH_OF_VALUE of its lowest value, whichever is wider; a window counts
# as a level if it holds MIN_LEVEL_SHARE of the ticks: the three of 36 episodes a dense soil slowed
# from 1 m/s to 0.8 m/s are no level of their own (confounded with their soil's θ, they cannot pin
# a shape); cuts held short of their targets, and depths or speeds that vary within the episodes
# (a planner's, a machine's), make levels of their own. Why the gaps: a window begun by a few
# slowed episodes (0.72 m/s) reached across the gap into a two-speed grid's 0.86-0.89 m/s, took
# part of that level, and made a level of episodes that were too few to be one (a held-out part
# counted three speeds; an outside reviewer's 8 % of slowed ticks, 0.727 m/s, did too). Within a
# part, windows whose medians lie within half a width of each other are one level: slowed ticks
# nearer a level than half a window (0.70 m/s beside 0.73-0.79 m/s) began a window that cut that
# level in two (another reviewer's).
LEVEL_VARIABLES = ("d", "v_x")
MIN_SHAPE_LEVELS = 3
LEVEL_WIDTH_OF_SPAN = 0.25
LEVEL_WIDTH_OF_VALUE = 0.1
MIN_LEVEL_SHARE = 0.1


def held_levels(frame: Frame, variable: str) -> list[float]:
    """The levels [SI] at which the analysed ticks of ``frame`` hold ``variable``, each its window's
    median, ascending (windows of at least ``MIN_LEVEL_SHARE`` of the ticks)."""
    values = np.sort(np.asarray(frame.column(variable), float))
    values = values[np.isfinite(values)]
    if not len(values):
        return []
    span = float(values[-1] - values[0])
    widths = np.maximum(LEVEL_WIDTH_OF_SPAN * span, LEVEL_WIDTH_OF_VALUE * np.abs(values))  # of a window from each
    cuts = np.flatnonzero(np.diff(values) > widths[:-1] / 2) + 1
    least = MIN_LEVEL_SHARE * len(values)
    levels = []
    for part in np.split(values, cuts):
        windows, i = [], 0  # [start, end) in ``part`` and the width of each
        while i < len(part):
            start = float(part[i])
            width = max(LEVEL_WIDTH_OF_SPAN * span, LEVEL_WIDTH_OF_VALUE * abs(start))
            end = max(int(np.searchsorted(part, start + width, side="right")), i + 1)
            if windows and abs(float(np.median(part[i:end])) - float(np.median(part[slice(*windows[-1][:2])]))) < \
                    max(width, windows[-1][2]) / 2:  # one level cut where a window began (a ramp's are a width apart)
                windows[-1] = (windows[-1][0], end, max(width, windows[-1][2]))
            else:
                windows.append((i, end, width))
            i = end
        levels += [float(np.median(part[a:b])) for a, b, _ in windows if b - a >= least]
    return levels


def rival_forms(frame: Frame, model: AugmentedFEE, fit: ThetaFit, name: str, *, alpha: float, names=None) -> dict:
    """Do these data pin the term ``name`` (a form or a catalogue term of ``model``, θ ``fit``) down,
    or would another form do?

    What the term takes is the residual of ``model`` with its k set to 0, profiled to first order
    over θ (per θ-group) and the other terms' k (one each, over all groups): projected off their
    columns. Each form of the library (``names``, default all) is fitted to it alone and scored
    per episode (ticks of an episode are autocorrelated). A *rival* is a form whose fit is not
    significantly worse than the term's own (one-sided Wilcoxon over episodes, p >= ``alpha``):
    the data cannot tell the two apart, so naming one would be a guess. A rival significantly
    *better* (Holm over the library) makes the term a stand-in, chosen on a path through other
    terms, if it also takes ``STAND_IN_SHARE_RATIO`` times the share. Measured on hidden effects:
    the right forms had every rival at p < 1e-3; the stand-ins (a hard spot along the path, a
    layer that was not there) had rivals taking 1.5-2.8× as much. On the episodes the term was
    chosen on it is favoured (it won its place against these very forms): the workflow asks both
    its parts and keeps the ``weaker_pin``.
    Returns {'pinned': True / False / None (not testable: no form fits anything, or too few
    episodes for a one-sided Wilcoxon to reach ``alpha`` with two of them against the term,
    ``wilcoxon_p_two_against``), 'why' (when None), 'n_episodes',
    'share' (of what is left, the term's), 'rivals': [{'name' (signed: k > 0), 'k', 'share',
    'p_worse', 'better'}] best first, at most ``RIVALS_SHOWN``, 'n_rivals', 'n_better',
    'stand_in', 'same_column' / 'n_same_column' (forms that are the term's own column on these
    data, |cos| >= ``DUPLICATE_COS``, or ``CATALOGUE_COS`` for a catalogue term: the same
    statement, no rival), 'factor_pinned' / 'scale_pinned' (every rival shares the form's factor
    / scale), 'shape_pinned' (every rival is the form at another characteristic value: exp(−s /
    0.5 m) for exp(−s / 2 m)), all three only where none of the rivals, nor the form, has a factor
    of a variable its scale varies with (``term_forms.separable``), 'runner_up' (the best other
    form, rival or not)}; ``pin_kind``
    reads it.
    """
    terms = dict(model.terms)
    if name not in terms:
        raise ValueError(f"form {name!r} is not a term of the model ({', '.join(terms) or 'none'})")
    names = [n for n in (names or term_forms.form_names()) if _unsigned(n) != _unsigned(name)]
    frame, resid = _normalised_residual(frame, model, fit)
    own = form_bases(frame, fit, [name])[..., 0]
    resid = resid + terms[name] * own
    others = [n for n in terms if n != name]
    arrays = [resid[..., None], form_bases(frame, fit, names), own[..., None]]
    if others:
        arrays.append(form_bases(frame, fit, others))
    projected = _project(frame, theta_jacobian(frame, model, fit), *arrays)
    y, X, c0 = projected[0].reshape(-1), projected[1].reshape(-1, len(names)), projected[2].reshape(-1)
    if others and len(y):  # the other terms' k: one each over all groups, their columns already off θ's
        u, sv, _ = np.linalg.svd(projected[3].reshape(len(y), -1), full_matrices=False)
        u = u[:, sv > 1e-9 * max(float(sv.max()), 1e-300)]
        y, X, c0 = y - u @ (u.T @ y), X - u @ (u.T @ X), c0 - u @ (u.T @ c0)
    # a form that is the named term's own column on these data (−Q tanh(v_x / 0.1 m/s) is −Q at
    # v_x >= 0.3 m/s; (γ/g) w d v_x² is soil inertia) says the same thing: listed, no rival
    norms = np.sqrt((X**2).sum(0)) * max(float(np.sqrt(c0 @ c0)), 1e-300)
    cos = np.abs(X.T @ c0) / np.maximum(norms, 1e-300)
    same_cos = DUPLICATE_COS if name.startswith(term_forms.PREFIX) else CATALOGUE_COS
    episode = np.unique(np.repeat(frame.episode, 2), return_inverse=True)[1]
    n_episodes = int(episode.max()) + 1 if len(episode) else 0
    total = float(y @ y)

    def fitted(col):
        nn = float(col @ col)
        k = float(col @ y) / nn if nn > 0 else 0.0
        return k, np.bincount(episode, (y - k * col) ** 2, minlength=n_episodes)

    def share(sse):
        return 1.0 - float(sse.sum()) / total if total > 0 else 0.0

    _, own_sse = fitted(c0)
    rows, sses = [], []
    for j, n in enumerate(names):
        k, sse = fitted(X[:, j])
        if k == 0.0:
            continue
        signed = n if k > 0 else term_forms.negated(n)
        if cos[j] >= same_cos:
            rows.append({"name": signed, "same": True})
            continue
        rows.append({"name": signed, "k": abs(k), "share": share(sse), "p_worse": None, "p_better": None, "same": False})
        sses.append(sse)
    if sses:  # every form's two tests against the term at once
        sses = np.array(sses)
        tested = [r for r in rows if not r["same"]]
        for r, p_worse, p_better in zip(tested, paired_tests(sses, own_sse), paired_tests(own_sse, sses)):
            r["p_worse"], r["p_better"] = float(p_worse), float(p_better)
    same = [r["name"] for r in rows if r["same"]]
    rows = sorted((r for r in rows if not r["same"]), key=lambda r: -r["share"])
    for r, p_better in zip(rows, holm([r["p_better"] for r in rows])):
        r["better"] = bool(p_better < alpha)  # of hundreds of forms some beat it by chance at alpha each
    rivals = [r for r in rows if r["p_worse"] >= alpha]
    parts = [term_forms.parse(r["name"])[1:] for r in rivals]
    scale = factor = None  # a catalogue term's is neither any form's
    if name.startswith(term_forms.PREFIX):
        _, scale, factor = term_forms.parse(name)

    def clean(r):
        return {key: (v if key in ("name", "better") else float(v)) for key, v in r.items()
                if key not in ("p_better", "same")}

    own_share = share(own_sse)
    # too few episodes: where two episodes against it (the two of least weight) would keep a
    # one-sided Wilcoxon from showing any rival worse, "not pinned down" says nothing about the form
    why = ("no form of the library fits what it takes" if not rows or total <= 0 else
           f"{n_episodes} episodes, too few for a one-sided Wilcoxon to reach p < {alpha:g} with two of them "
           "against it" if wilcoxon_p_two_against(n_episodes) >= alpha else None)
    # a scale and a factor of one variable make one law of it: neither is pinned down apart (SCALE_VARIABLES)
    apart = factor is not None and all(term_forms.separable(a.name, f.name) for a, f in parts + [(scale, factor)])
    variable = force_terms.get_term(name).factor_variable
    few = None
    if variable in LEVEL_VARIABLES and len(episode):
        levels = held_levels(frame, variable)
        # ('form': a library form's, whose characteristic value matches too; a catalogue term has none)
        few = ({"variable": variable, "levels": levels, "form": name.startswith(term_forms.PREFIX)}
               if len(levels) < MIN_SHAPE_LEVELS else None)
    return {"pinned": None if why else not rivals and few is None, "why": why, "n_episodes": n_episodes,
            "few_levels": few,
            "share": own_share, "n_rivals": len(rivals), "n_better": sum(r["better"] for r in rivals),
            "stand_in": any(r["better"] and r["share"] >= STAND_IN_SHARE_RATIO * own_share for r in rivals),
            "factor_pinned": apart and few is None and all(f.name == factor.name for _, f in parts),
            "shape_pinned": apart and few is None and all(
                a.name == scale.name and term_forms.factor_shape(f.name) == term_forms.factor_shape(factor.name)
                for a, f in parts),
            "scale_pinned": apart and all(a.name == scale.name for a, _ in parts),
            "same_column": same[:RIVALS_SHOWN], "n_same_column": len(same),
            "rivals": [clean(r) for r in rivals[:RIVALS_SHOWN]], "runner_up": clean(rows[0]) if rows else None}


def wilcoxon_p_two_against(n: int) -> float:
    """The one-sided Wilcoxon signed-rank p over ``n`` paired episodes when all but the two of least
    |difference| favour one side: of the 2^n sign patterns, those whose ranks against it sum to at
    most 3 ({}, {1}, {2}, {3}, {1, 2}) are as extreme. (2^-n, all episodes agreeing, is reached
    by a form that merely wins each episode by a hair; a part this small cannot say more.)"""
    if n < 1:
        return 1.0
    extreme = {1: 2, 2: 4}.get(n, 5)
    return min(1.0, extreme / 2.0**n)


PIN_KINDS = {  # pin_kind -> what is not pinned down, in words
    "pinned": "", "unknown": "whether it is pinned down is not known",
    "stand-in": "a STAND-IN, its form not pinned down", "beaten": "its form is NOT pinned down",
    "value": "its shape is pinned down, not its characteristic value",
    "scale": "its factor is pinned down, its scale is not", "factor": "its scale is pinned down, its factor is not",
    "levels": "its scale is pinned down, its factor is not (too few levels of its variable)",
    "form": "its form is NOT pinned down"}


def pin_kind(pin: dict | None) -> str | None:
    """One word for a ``rival_forms`` result (a key of ``PIN_KINDS``; None if none was asked):
    the summary, the report and the proposed name all read it."""
    if not pin:
        return None
    if pin.get("pinned") is None:
        return "unknown"
    if pin["pinned"]:
        return "pinned"
    if pin.get("stand_in"):
        return "stand-in"
    if pin["n_better"]:
        return "beaten"
    if pin.get("few_levels"):
        return "levels" if pin["scale_pinned"] else "form"
    if pin.get("shape_pinned"):
        return "value"
    if pin["factor_pinned"]:
        return "scale"
    return "factor" if pin["scale_pinned"] else "form"


# pin_kind, from the claim that says least about the mechanism to the one that says most
PIN_ORDER = ("stand-in", "beaten", "form", "levels", "factor", "scale", "value", "unknown", "pinned")


def weaker_pin(*pins: dict | None) -> dict | None:
    """Of one term's ``rival_forms`` results on different episodes, the one that claims least
    (``PIN_ORDER``; the first given where two claim as little): a term is pinned down only where
    every part pins it. Why both parts: on the episodes it was chosen on, it won its place against
    these very forms, so there it is favoured (a hard spot's drag growing with time in soil was
    pinned there, and on the held-out part 52 forms fit as well); on the held-out part, half as many
    episodes may not tell a right form from a rival that the selection part does tell, and what a
    stand-in fails to take shows on either (a layer that was not there was a stand-in on the
    selection part, merely "not pinned" on the held-out one). A part too small to judge (``pin_kind``
    "unknown") is left out, unless none can judge."""
    given = [p for p in pins if p]
    if not given:
        return None
    judged = [p for p in given if pin_kind(p) != "unknown"] or given  # a part too small to judge says nothing
    return min(judged, key=lambda p: PIN_ORDER.index(pin_kind(p)))


def _unsigned(name: str) -> str:
    """A form's name without its sign: both signs are one column."""
    return name.replace(f"{term_forms.PREFIX}-", term_forms.PREFIX, 1)


def pinned_caveat(pin: dict | None) -> str:
    """The words a summary adds to a named term its data do not pin down ('' if they do, or were not asked)."""
    kind = pin_kind(pin)
    if kind in (None, "pinned"):
        return ""
    if kind == "unknown":
        return f"; {PIN_KINDS[kind]}: {pin['why']}"
    if pin.get("few_levels"):
        few = pin["few_levels"]
        tail = f"; {levels_text(few)} over the {pin.get('part', 'selection')} episodes"
        if kind == "levels" or not pin["n_rivals"]:
            said = PIN_KINDS["factor" if kind == "levels" else "form"]
            rivals = f"; {pin['n_rivals']} forms fit it not significantly worse" if pin["n_rivals"] else ""
            return f"; {said}{tail}{rivals}"
        return pinned_caveat({**pin, "few_levels": None}) + tail  # its best rival, as any form not pinned down
    best = next((r for r in pin["rivals"] if r.get("better")), pin["rivals"][0])
    formula = force_terms.get_term(best["name"]).formula
    others = (f"; {pin['n_rivals']} forms fit it not significantly worse, {pin['n_better']} significantly better"
              if pin["n_rivals"] > 1 else "")
    shares = (f"({100 * best['share']:.1f} % of what it takes against its {100 * pin['share']:.1f} %, "
              f"{pin.get('part', 'selection')} episodes)")
    how = ("takes more" if kind == "stand-in" else "fits significantly better" if kind == "beaten" else
           "fits at least as well" if best["share"] > pin["share"] else "fits as well")
    return f"; {PIN_KINDS[kind]}: {formula} ({best['name']}) {how} {shares}{others}"


def levels_text(few: dict) -> str:
    """``rival_forms``' few_levels in words: the variable, its levels and why they pin no factor of it."""
    unit = {"d": "m", "v_x": "m/s"}[few["variable"]]
    values = ", ".join(f"{v:.3g}" for v in few["levels"])
    return (f"{few['variable']} takes values in only {len(few['levels'])} group(s) (about {values} {unit}; a group holds "
            f"at least {100 * MIN_LEVEL_SHARE:g} % of the ticks, its values within a quarter of their span or a tenth of its "
            "value), too few to tell one factor of it from another")


# ------------------------------------------------------------------------------------ describing
def closest_index(cos: np.ndarray) -> int:
    """Index of the catalogue term to name from the form's cosines with each: a term the form runs
    with (cos >= CLOSE_COS) before one it runs against, however close; else the largest |cos|."""
    cos = np.asarray(cos, dtype=float)
    return int(np.argmax(cos)) if cos.max() >= CLOSE_COS else int(np.argmax(np.abs(cos)))


def closest_catalogue(frame: Frame, fit: ThetaFit, name: str, model: AugmentedFEE | None = None) -> dict:
    """The catalogue term whose basis (θ-projected) is most parallel (or, none within CLOSE_COS,
    anti-parallel) to the form's: {'name', 'cos', 'same_mechanism' (cos >= CLOSE_COS), 'opposite' (cos <= −CLOSE_COS)}."""
    model = model or AugmentedFEE()
    cat = list(force_terms.CATALOGUE)
    B = form_bases(frame, fit, [name] + cat)
    J = theta_jacobian(frame, model, fit)
    (P,) = _project(frame, J, B)
    P = P.reshape(-1, len(cat) + 1)
    n = np.sqrt((P**2).sum(0))
    cos = np.where(n[1:] > 0, (P[:, 1:] * P[:, :1]).sum(0) / np.maximum(n[1:] * n[0], 1e-300), 0.0)
    i = closest_index(cos)
    # the form (signed, k > 0) is the term's mechanism only if it pushes the same way: every catalogue
    # term's physics has k > 0, so an anti-parallel form is the opposite effect (less of it), not it
    return {"name": cat[i], "cos": float(cos[i]), "same_mechanism": bool(cos[i] >= CLOSE_COS),
            "opposite": bool(cos[i] <= -CLOSE_COS)}


def where_it_acts(frame: Frame, fit: ThetaFit, name: str, k: float) -> dict:
    """Where the form is non-zero: share of ticks, and the 5-95 % range of d, v_x, v_z, s there."""
    B = form_bases(frame, fit, [name])[..., 0] * FORCE_SCALE_N * k
    mag = np.hypot(B[:, 0], B[:, 1])
    on = mag > 1e-3 * max(float(mag.max()), 1e-300)
    out = {"share_of_ticks": float(on.mean()), "mean_abs_force_n": float(mag[on].mean()) if on.any() else 0.0,
           "max_abs_force_n": float(mag.max()) if len(mag) else 0.0, "ranges": {}}
    for v in ("d", "v_x", "v_z", "distance", "time_in_soil"):
        x = frame.column(v)[on]
        if len(x):
            lo, hi = np.percentile(x, [5, 95])
            out["ranges"][v] = [float(lo), float(hi)]
    return out


def describe_form(frame: Frame, fit: ThetaFit, score: dict) -> dict:
    """The report's entry for an accepted form: formula, words, k ± SE, regimes, closest catalogue term, name."""
    name = score["name"]
    info = term_forms.describe(name)
    close = closest_catalogue(frame, fit, name)
    acts = where_it_acts(frame, fit, name, score["k"] or 0.0)
    return {"name": name, "formula": info["formula"], "words": info["words"], "axis": info["axis"],
            "scale": info["scale"], "factor": info["factor"], "gate": info["gate"],
            "k": score["k"], "k_se": score["k_se"], "gain": score["gain"], "p_holm": score["p_holm"],
            "regime": acts, "closest_catalogue": close,
            "proposed_name": (f"{close['name']} in another form ({info['words']})" if close["same_mechanism"]
                              else term_forms.proposed_name(name))}


# ------------------------------------------------------------------------------------ a user's catalogue
CATALOGUE_FILE = "discovered_terms.yaml"


def catalogue_yaml(discovered) -> str | None:
    """The confirmed discovered forms as a YAML catalogue the next run reads (``--catalogue``); None if none."""
    import yaml

    rows = [{"term": d["name"], "name": d["proposed_name"], "k": d["k"], "k_se": d["k_se"], "formula": d["formula"],
             "plugin": f"soil_physics.force_terms:plugin term={d['name']} k={d['k']:.6g}",
             **({"pinned": d["pin"]["pinned"], "stand_in": d["pin"]["stand_in"],
                 "rivals": [r["name"] for r in d["pin"]["rivals"]]} if d.get("pin") else {})}
            for d in discovered or () if d.get("confirmed", True)]
    if not rows:
        return None
    head = ("# Forms found by soil_discrepancy (confirmed on held-out episodes). Rename 'name' as you like;\n"
            "# 'pinned: false': these data did not tell the form from its 'rivals' ('stand_in: true': one fits\n"
            "# much better, this form stands in for an effect it is not); the report says more\n"
            "# the next run tests 'term' as a candidate beside the catalogue: soil_discrepancy BAGS --catalogue THIS_FILE\n"
            "# ('term' defines it; 'formula', 'plugin' and the rest describe it and are not read back)\n")
    return head + yaml.safe_dump({"terms": rows}, sort_keys=False, allow_unicode=True)


CATALOGUE_FIELDS = ("term", "name", "k", "k_se", "formula", "plugin", "pinned", "stand_in", "rivals")  # catalogue_yaml's


def load_catalogue(path) -> list[dict]:
    """A user's catalogue of terms (YAML: terms: [{term, name?, k?}, ...]); each term a catalogue name or a
    'form:…'. Returns [{'term', 'name', 'k'}]; ValueError naming the file and the bad entry."""
    from pathlib import Path

    p = Path(path)
    data = read_yaml(p, "catalogue")
    rows = (data or {}).get("terms") if isinstance(data, dict) else None
    others = sorted(map(str, set(data) - {"terms"})) if isinstance(data, dict) else []
    if not isinstance(rows, list) or not rows:
        raise ValueError(f"catalogue {p}: expected a mapping with a non-empty list 'terms'"
                         + (f" (it has {others}: a misspelt key?)" if others else ""))
    if others:
        raise ValueError(f"catalogue {p}: unknown top-level key(s) {others}; a catalogue holds 'terms' only")
    out, seen, names = [], {}, {}
    for i, row in enumerate(rows):
        term = row.get("term") if isinstance(row, dict) else None
        if not isinstance(term, str):
            raise ValueError(f"catalogue {p}: terms[{i}] has no 'term' (a catalogue name or 'form:<scale>*<factor>')")
        unknown = sorted(str(key) for key in set(row) - set(CATALOGUE_FIELDS))
        if unknown:  # a misspelt key ('kk: 0.3') must not be dropped in silence
            raise ValueError(f"catalogue {p}: terms[{i}]: unknown field(s) {unknown}; known: {list(CATALOGUE_FIELDS)}")
        if term in seen:  # two names for one term: the report would show one of them
            raise ValueError(f"catalogue {p}: terms[{seen[term]}] and terms[{i}] are the same term {term!r}; give it once")
        seen[term] = i
        try:
            force_terms.get_term(term)
        except ValueError as exc:
            raise ValueError(f"catalogue {p}: terms[{i}]: {exc}") from None
        k = yaml_exponent(row.get("k"))  # (PyYAML reads 1e0 as a string)
        if k is not None and not finite_number(k):  # a 400-digit integer too: no OverflowError
            raise ValueError(f"catalogue {p}: terms[{i}].k={short_repr(k)} is not a finite number")
        name = row.get("name")
        if name is not None and (not isinstance(name, str) or not name.strip()):
            raise ValueError(f"catalogue {p}: terms[{i}].name={short_repr(name)} must be a non-empty text (quote it)")
        name = name or term
        if name in names:  # one name for two terms: the report could not say which it found
            raise ValueError(f"catalogue {p}: terms[{names[name]}] and terms[{i}] are both named {name!r}; name each once")
        names[name] = i
        out.append({"term": term, "name": name, "k": None if k is None else float(k)})
    return out
