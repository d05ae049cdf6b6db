"""Step 3: name the missing effect — every catalogue term, cross-validated across θ-groups.

For each candidate term, K-fold cross-validation over θ-groups (GroupKFold: the episodes that
share a soil stay together, so no held-out soil is seen in training):

* training groups: k fitted **jointly** with their θ_g (one least-squares problem, see
  ``fee_fit.fit_joint``; alternating between k and the θ_g converges to the same point, slower);
* held-out groups: θ_g refitted with that k fixed — how the augmented model would be used on a
  new soil — and the force error per held-out episode compared with the model without the
  term's (θ_g refitted without it, i.e. the initial fit of that group).

Score: the share of the held-out error without the term that it removes, gain = 1 − SSE_after/SSE_before
(normalised x and z), and a one-sided Wilcoxon signed-rank test over held-out episodes of the
per-episode MSE before vs after. p-values are Holm-corrected over the candidates of a round.
k ± SE: k from the joint fit on every selection group; SE the grouped (delete-a-fold)
jackknife over the K fold estimates, sqrt((K−1)/K Σ (k_i − k̄)²).

Greedy forward selection: accept the best term whose Holm p < alpha, gain ≥ min_gain and whose
coefficient is determined (the fold estimates agree: |mean k| > K_SIGMA · SE; a term that helps
with wildly different k per fold is absorbing something else, it is not that effect), fix
its k, refit every θ_g with it and repeat for the remaining terms; stop when none
qualifies. Nothing is accepted on a term's training fit alone.
"""
from __future__ import annotations

K_SIGMA = 3.0  # a named effect's k must exceed its jackknife SE this many times

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from soil_msgs_py.process_pool import fork_is_safe, map_in_processes
from soil_msgs_py.strict_json import finite_or_none as _f
from soil_physics import force_terms
from soil_physics.augmented_fee import AugmentedFEE

from pinn_estimator.classical import FORCE_SCALE_N, UNDEFINED_RESIDUAL
from .fee_fit import ThetaFit, fit_fixed, fit_joint, residuals
from .frame import Frame
from .regimes import ALPHA, holm

MAX_TERMS = 3
# The workflow's defaults (``run_discrepancy``, the command line): the share of soil groups held
# out for the test, cross-validation folds over the selection's groups, and the least share of
# the held-out error a term must remove to be named.
HOLDOUT_SHARE = 0.3
FOLDS = 5
MIN_GAIN = 0.05
CV_MAX_NFEV = 30  # joint fits inside the folds: a term that needs more is no clean fit anyway


def limit_blas_threads(n: int = 1) -> bool:
    """Best effort: cap OpenBLAS threads in this process (a forked worker on a small machine).

    OpenBLAS worker threads spin after each call; two fit processes on two cores with
    multithreaded BLAS each run ~5x slower than with one thread each. Returns True if capped.
    """
    import ctypes

    done = False
    try:
        with open("/proc/self/maps") as fh:
            libs = sorted({ln.split()[-1] for ln in fh if "openblas" in ln.lower() and ln.split()[-1].startswith("/")})
    except OSError:
        return False
    for path in libs:
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for sym in ("openblas_set_num_threads", "openblas_set_num_threads64_",
                    "scipy_openblas_set_num_threads", "scipy_openblas_set_num_threads64_"):
            fn = getattr(lib, sym, None)
            if fn is not None:
                fn(int(n))
                done = True
    return done


# ------------------------------------------------------------------------------------ splits
def check_holdout(holdout: float) -> None:
    """ValueError naming ``holdout`` (the share of θ-groups held out) unless it is in (0, 1): a name is
    one the held-out groups confirm (and a form one they pin down), so without them the verdict
    would state a cross-validated guess as found (0 had been taken, and said "explained")."""
    if not 0.0 < holdout < 1.0:
        raise ValueError(f"holdout={holdout} must be in (0, 1): the held-out soil groups are what confirms a "
                         "named term")


# A candidate whose basis is 0 on every analysed tick: never tested (``--hidden`` reads it: such a
# hidden term never acted on the data)
ZERO_BASIS_NOTE = ("not testable: its basis is 0 on every analysed tick (e.g. no surcharge Q), so the data say "
                   "nothing about k")


def split_holdout(frame: Frame, holdout: float, seed: int) -> tuple[list[int], list[int]]:
    """(selection groups, test groups): ~``holdout`` of the θ-groups held out, by group.

    Stratified by soil name when the metadata has it: groups are shuffled within each soil
    (seeded), then taken round-robin across soils, so the test part spans soils. Without a soil
    label (bags of a real machine, ``group_by='gamma'``) the strata are as many contiguous bands
    of the groups' measured unit weight γ as there are test groups, so the test part still spans
    the soils' range instead of landing where chance puts it. At least two groups stay in the
    selection part (cross-validation needs them) and at least one goes to the test part.
    """
    check_holdout(holdout)
    groups = [int(g) for g in frame.groups]
    n = len(groups)
    n_test = min(max(int(round(holdout * n)), 1), n - 2)
    if n_test < 1:
        raise ValueError(
            f"{n} θ-group(s) ({frame.group_by} grouping): need at least 3 "
            "(two to cross-validate the candidate terms, one held out for the test); "
            f"record more episodes or soils"
            + (", or fit θ per episode (--group-by episode)" if frame.group_by in ("auto", "gamma") and n < len(frame.episodes) else "")
        )
    rng = np.random.default_rng(seed)
    strata: dict[str, list[int]] = {}
    if frame.has_metadata():
        for g in groups:
            ep = int(np.nonzero(frame.group_of == g)[0][0])
            strata.setdefault(frame.soils[ep], []).append(g)
    else:
        gamma = frame.column("gamma")
        by_gamma = sorted(groups, key=lambda g: (float(np.median(gamma[frame.group == g])), g))
        bands = max(n_test, 1)
        for rank, g in enumerate(by_gamma):
            strata.setdefault(f"γ band {rank * bands // n}", []).append(g)
    keys = sorted(strata)
    for k in keys:
        rng.shuffle(strata[k])
    rng.shuffle(keys)
    order = []
    while any(strata[k] for k in keys):
        for k in keys:
            if strata[k]:
                order.append(strata[k].pop(0))
    test = sorted(order[:n_test])
    return sorted(g for g in groups if g not in test), test


def group_folds(groups, folds: int, seed: int) -> list[tuple[list[int], list[int]]]:
    """GroupKFold over θ-groups (shuffled, seeded): [(train groups, held-out groups), ...]."""
    groups = [int(g) for g in groups]
    k = min(int(folds), len(groups))
    if k < 2:
        raise ValueError(f"{len(groups)} selection group(s): cross-validation needs at least 2")
    rng = np.random.default_rng(seed + 7919)
    perm = list(rng.permutation(groups))
    parts = [sorted(int(g) for g in perm[i::k]) for i in range(k)]
    return [(sorted(set(groups) - set(p)), p) for p in parts]


# ------------------------------------------------------------------------------------ scoring
def episode_sse(frame: Frame, resid: np.ndarray) -> dict[int, tuple[float, int]]:
    """{episode: (Σ normalised squared residual over ticks and both axes, ticks)}; NaN ticks count as the penalty."""
    r = resid / FORCE_SCALE_N
    r = np.where(np.isfinite(r), r, UNDEFINED_RESIDUAL)
    sq = (r**2).sum(1)
    out = {}
    for e in frame.episodes:
        m = frame.episode == e
        out[int(e)] = (float(sq[m].sum()), int(m.sum()))
    return out


def paired_test(before: np.ndarray, after: np.ndarray) -> float:
    """One-sided Wilcoxon signed-rank p that ``after`` < ``before`` (paired per episode)."""
    d = np.asarray(before, float) - np.asarray(after, float)
    d = d[np.isfinite(d)]
    if len(d) < 2 or np.all(d == 0):
        return 1.0
    try:
        return float(stats.wilcoxon(d, alternative="greater").pvalue)
    except ValueError:
        return 1.0


def paired_tests(before, after) -> np.ndarray:
    """``paired_test`` of each row of ``before`` against the same row of ``after`` (rows broadcast),
    the same p to the bit. Why: a report tests hundreds of library forms against a term, and
    scipy's per-call overhead (about 1 ms) was a seventh of a report's time. Rows whose differences
    are all finite, non-zero and distinct in size go to scipy in one call along the rows (it then
    takes the test each would get alone: exact up to 50 episodes, else the normal approximation,
    as each row's ties and zeros are what make it choose otherwise); the rest one by one."""
    before, after = np.broadcast_arrays(np.atleast_2d(np.asarray(before, float)), np.atleast_2d(np.asarray(after, float)))
    d = before - after
    p = np.ones(len(d))
    if d.shape[1] < 2:
        return p
    magnitudes = np.sort(np.abs(d), axis=1)
    clean = np.isfinite(d).all(1) & (d != 0).all(1) & (np.diff(magnitudes, axis=1) != 0).all(1)
    if clean.any():
        p[clean] = stats.wilcoxon(d[clean], alternative="greater", axis=1).pvalue
    for i in np.flatnonzero(~clean):
        p[i] = paired_test(before[i], after[i])
    return p


@dataclass
class TermScore:
    name: str
    k: float  # joint fit on every selection group
    k_se: float  # grouped jackknife over folds
    k_folds: list[float]
    gain: float  # 1 - SSE_after / SSE_before on held-out episodes
    p: float  # one-sided Wilcoxon, per-episode MSE before vs after
    p_holm: float = math.nan
    n_episodes: int = 0
    improved_episodes: int = 0
    mse_before: list[float] = field(default_factory=list)
    mse_after: list[float] = field(default_factory=list)
    accepted: bool = False
    note: str = ""

    def to_dict(self) -> dict:
        term = force_terms.get_term(self.name)
        return {
            "name": self.name, "title": term.title, "formula": term.formula, "k_unit": term.k_unit,
            "k": _f(self.k), "k_se": _f(self.k_se), "k_folds": [_f(v) for v in self.k_folds],
            "gain": _f(self.gain), "p": _f(self.p), "p_holm": _f(self.p_holm),
            "n_heldout_episodes": self.n_episodes, "improved_episodes": self.improved_episodes,
            "accepted": self.accepted, "note": self.note,
        }


# A fork-inherited job context (frames are large; with fork nothing is pickled).
_CTX: dict = {}


def _cv_task(args):
    name, fold = args
    frame, model, base, folds = _CTX["frame"], _CTX["model"], _CTX["base"], _CTX["folds"]
    train, held = folds[fold]
    ftr = frame.select(groups=train)
    try:
        fit = fit_joint(ftr, model, name, base, max_nfev=CV_MAX_NFEV, allow_negative_k=_CTX["allow_negative_k"])
        k = float(fit.k)
        aug = model.with_term(name, k)
        fho = frame.select(groups=held)
        ho = fit_fixed(fho, aug, base)
        r, _ = residuals(fho, aug, ho)
        return name, fold, k, episode_sse(fho, r)
    except (ValueError, np.linalg.LinAlgError, FloatingPointError):
        return name, fold, math.nan, None


def score_terms(frame: Frame, model: AugmentedFEE, base: ThetaFit, candidates, *, folds: int = FOLDS,
                seed: int = 0, workers: int = 1, allow_negative_k: bool = False, log=None) -> list[TermScore]:
    """Cross-validated score of every candidate against ``model`` (whose θ per group is ``base``)."""
    fold_list = group_folds(frame.groups, folds, seed)
    r0, _ = residuals(frame, model, base)
    sse0 = episode_sse(frame, r0)
    theta = base.per_tick(frame)
    untestable = []
    for n, (bx, bz) in zip(candidates, model.bases(candidates, theta, frame.known, frame.distance, frame.time_in_soil)):
        if not (np.any(bx != 0) or np.any(bz != 0)):
            untestable.append(n)  # e.g. surcharge_drag with Q = 0 throughout: k is not identifiable
    testable = [n for n in candidates if n not in untestable]
    tasks = [(n, f) for n in testable for f in range(len(fold_list))]
    _CTX.update(frame=frame, model=model, base=base, folds=fold_list, allow_negative_k=allow_negative_k)
    try:
        if workers > 1 and len(tasks) > 1 and fork_is_safe():  # the tasks read _CTX, which only a fork carries
            results = list(map_in_processes(_cv_task, tasks, min(workers, len(tasks)), what="cross-validating terms",
                                            initializer=limit_blas_threads, start_method="fork"))
        else:
            results = [_cv_task(t) for t in tasks]
    finally:
        _CTX.clear()
    scores = []
    for name in testable:
        ks, before, after = [], [], []
        for n, fold, k, sse in results:
            if n != name:
                continue
            ks.append(k)
            held = fold_list[fold][1]
            eps = [int(e) for e in frame.episodes if int(frame.group_of[e]) in held]
            for e in eps:
                b, nt = sse0[e]
                a = sse[e][0] if sse is not None else math.inf
                before.append(b / nt)
                after.append(a / nt)
        before, after = np.array(before), np.array(after)
        finite = np.isfinite(after)
        gain = 1.0 - float(after.sum() / before.sum()) if finite.all() and before.sum() > 0 else -math.inf
        p = paired_test(before, after) if finite.all() else 1.0
        kk = np.array(ks, float)
        K = len(kk)
        se = math.sqrt((K - 1) / K * float(((kk - kk.mean()) ** 2).sum())) if K > 1 and np.isfinite(kk).all() else math.nan
        scores.append(TermScore(name, math.nan, se, [float(v) for v in kk], gain, p, n_episodes=len(before),
                                improved_episodes=int((after < before).sum()),
                                mse_before=before.tolist(), mse_after=after.tolist()))
    for s, ph in zip(scores, holm([s.p for s in scores])):
        s.p_holm = float(ph)
    for name in untestable:
        scores.append(TermScore(name, math.nan, math.nan, [], math.nan, math.nan, note=ZERO_BASIS_NOTE))
    if log:
        for s in sorted(scores, key=lambda s: -s.gain if math.isfinite(s.gain) else math.inf):
            if s.note:
                log(f"  {s.name:22s} {s.note}")
            else:
                log(f"  {s.name:22s} held-out gain {100 * s.gain:7.1f} %  p_holm {s.p_holm:.2g}  "
                    f"k folds {np.round(s.k_folds, 4).tolist()}")
    return scores


def select_terms(frame: Frame, model: AugmentedFEE, base: ThetaFit, candidates=None, *, folds: int = FOLDS,
                 seed: int = 0, alpha: float = ALPHA, min_gain: float = MIN_GAIN, max_terms: int = MAX_TERMS,
                 workers: int = 1, allow_negative_k: bool = False, log=None) -> dict:
    """Greedy forward selection on the selection part. Returns {'model', 'fit', 'rounds', 'accepted'}."""
    candidates = [n for n in (candidates or list(force_terms.CATALOGUE)) if n not in model.names]
    for n in candidates:
        force_terms.get_term(n)
    rounds, accepted = [], []
    current, cur_fit = model, base
    while candidates and len(accepted) < max_terms:
        if log:
            log(f"round {len(rounds) + 1}: {len(candidates)} candidate term(s) x {min(folds, len(frame.groups))} folds "
                f"on {len(frame.groups)} θ-groups / {len(frame.episodes)} episodes")
        scores = score_terms(frame, current, cur_fit, candidates, folds=folds, seed=seed, workers=workers,
                             allow_negative_k=allow_negative_k, log=log)
        ok = [s for s in scores if math.isfinite(s.gain) and s.p_holm < alpha and s.gain >= min_gain and _determined(s)]
        winner = max(ok, key=lambda s: s.gain) if ok else None
        if winner is not None:
            joint = fit_joint(frame, current, winner.name, cur_fit, allow_negative_k=allow_negative_k)
            winner.k = float(joint.k)
            winner.accepted = True
            current = current.with_term(winner.name, winner.k)
            cur_fit = fit_fixed(frame, current, joint)
            accepted.append(winner)
            candidates = [n for n in candidates if n != winner.name]
        ranked = sorted((s for s in scores if math.isfinite(s.gain)), key=lambda s: -s.gain)
        runner = None
        if winner is not None:
            others = [s for s in ranked if s.name != winner.name]
            if others:
                r = others[0]
                a, b = np.array(winner.mse_after), np.array(r.mse_after)
                d = b - a
                p_vs = float(stats.wilcoxon(d).pvalue) if len(d) > 1 and np.any(d != 0) else 1.0
                runner = {"name": r.name, "gain": _f(r.gain), "p_winner_vs_runner_up": _f(p_vs),
                          "winner_better_episodes": int((a < b).sum()), "n_episodes": int(len(d))}
        rounds.append({"model_terms": [list(t) for t in (current.terms if winner is None else current.terms[:-1])],
                       "scores": [s.to_dict() for s in ranked + [s for s in scores if not math.isfinite(s.gain)]],
                       "winner": winner.name if winner else None, "runner_up": runner})
        if winner is None:
            break
    return {"model": current, "fit": cur_fit, "rounds": rounds, "accepted": accepted}


def _determined(score) -> bool:
    """The cross-validated k is consistent across folds: |mean k| > K_SIGMA · SE."""
    ks = [k for k in score.k_folds if k is not None and math.isfinite(k)]
    return bool(ks) and math.isfinite(score.k_se) and abs(sum(ks) / len(ks)) > K_SIGMA * score.k_se
