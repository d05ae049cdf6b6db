"""Step 5: show the gap shrink on held-out episodes — and the hook for other models (the PINN).

``compare_predictions(frame, before, after)`` is model-agnostic: it takes the force predictions
of any model at the held-out ticks (``frame.rows`` are their rows in the ``Dataset``; every row
has a full 60-tick window before it) without and with the named terms, and reports MAE/RMSE in x
and z, the RMS force-error magnitude, a paired test over episodes and the same per regime bin.
``fee_gap`` does it for the FEE model (θ refitted per held-out group, before with the initial
terms, after with the accepted ones). A PINN comparison passes its own predictions, e.g. through
``run_discrepancy(..., predictors={"PINN": fn})`` with ``fn(test_frame, model_before, model_after,
context) -> (F_before (N, 2), F_after (N, 2))`` (or a finished result dict); ``context`` names the
selection episodes (train on these only) and the held-out test episodes.
"""
from __future__ import annotations

import math

import numpy as np

from soil_physics.augmented_fee import AugmentedFEE

from .candidates import paired_test
from .fee_fit import ThetaFit, fit_fixed, residuals
from .frame import Frame
from .regimes import bin_edges, regime_bins

# What a named term that earns no place leaves when it is removed (the term-by-term held-out
# test, ``workflow``): one wording for the log, the verdict and the report.
NO_WORSE_WITHOUT = "the held-out force error and the forecast at another depth no worse"


def confirmation(sse_reduction: float | None, forecast_reduction: float | None, forecast_p: float | None,
                 min_gain: float, alpha: float) -> tuple[bool, str]:
    """Whether held-out figures confirm named terms, and if not, why in words (": …", for a verdict).

    They confirm when they remove >= ``min_gain`` of the force error's squares (``sse_reduction``), or,
    without making that worse, of the error of the force at another depth from a fit at one depth
    (``forecast_reduction``, paired p < ``alpha``); and in neither case make that forecast worse by
    more than ``min_gain`` (an undefined forecast fails too). Why both: a wrong depth profile (a
    force term that does not scale with depth like the FEE) costs a joint fit over every depth of a
    group little, because θ bends to it, but it is what a planner's forecast misses (a constant 1.5 kN
    drag, which no form holds, was named as a relief below 0.1 m: the held-out force error −4 %, the
    forecast at another depth 8.3 → 10.3 %). The reason is said because a force error that fell by
    half beside "not the held-out test" read as a contradiction."""
    least = f"the least gain ({100 * min_gain:.0f} %)"
    sse, red = sse_reduction, forecast_reduction
    if red is not None and not red >= -min_gain:
        if not math.isfinite(red):
            return False, (": the force at another depth is undefined with them on the held-out pairs, which fails a "
                           "name however much the force error falls")
        return False, (f": the force at another depth gets worse, its error up {-100 * red:.0f} %, more than {least}, "
                       "which fails a name however much the force error falls")
    if sse is None or not math.isfinite(sse):
        return False, ": the force error is undefined on the held-out ticks"
    if sse >= min_gain:
        return True, ""
    if sse < 0.0:
        return False, f": the force error rises, its squares up {-100 * sse:.0f} %"
    fell = f": the force error's squares fall by {100 * sse:.0f} %, less than {least}"
    if red is None:
        return False, fell + ", and the force at another depth is not measured (no two depths in a held-out group)"
    if red < min_gain:
        return False, fell + f", and the force at another depth's error by {100 * red:.0f} %, less than it too"
    p = 1.0 if forecast_p is None else forecast_p
    if not p < alpha:
        return False, fell + f", and the force at another depth's error by {100 * red:.0f} %, not significantly (paired p {p:.2g})"
    return True, ""


def error_metrics(resid: np.ndarray) -> dict:
    """MAE/RMSE per axis and the RMS of the force-error magnitude, rmse = sqrt(mean(r_x² + r_z²)) [N]."""
    r = np.asarray(resid, float)
    ok = np.isfinite(r).all(1)
    r = r[ok]
    if len(r) == 0:
        return {"n_ticks": 0, "mae_x": None, "mae_z": None, "rmse_x": None, "rmse_z": None, "mae": None, "rmse": None,
                "undefined_ticks": int((~ok).sum())}
    return {
        "n_ticks": int(len(r)),
        "mae_x": float(np.abs(r[:, 0]).mean()), "mae_z": float(np.abs(r[:, 1]).mean()),
        "rmse_x": float(np.sqrt((r[:, 0] ** 2).mean())), "rmse_z": float(np.sqrt((r[:, 1] ** 2).mean())),
        "mae": float(np.hypot(r[:, 0], r[:, 1]).mean()), "rmse": float(np.sqrt((r**2).sum(1).mean())),
        "undefined_ticks": int((~ok).sum()),
    }


def compare_predictions(frame: Frame, before: np.ndarray, after: np.ndarray, *, label: str = "model",
                        edges: dict | None = None) -> dict:
    """Held-out force error of one model before/after the named terms (predictions (N, 2) [N] at ``frame``'s ticks)."""
    before, after = np.asarray(before, float), np.asarray(after, float)
    if before.shape != frame.forces.shape or after.shape != frame.forces.shape:
        raise ValueError(f"{label}: predictions must have shape {frame.forces.shape} (the held-out ticks x (F_x, F_z)), "
                         f"got {before.shape} and {after.shape}")
    rb, ra = frame.forces - before, frame.forces - after
    mb, ma = error_metrics(rb), error_metrics(ra)
    per_ep_b, per_ep_a, names = [], [], []
    for e in frame.episodes:
        m = frame.episode == e
        sb, sa = (rb[m] ** 2).sum(1), (ra[m] ** 2).sum(1)
        per_ep_b.append(float(np.nanmean(sb)) if np.isfinite(sb).any() else math.inf)
        per_ep_a.append(float(np.nanmean(sa)) if np.isfinite(sa).any() else math.inf)
        names.append(frame.names[int(e)])
    per_ep_b, per_ep_a = np.array(per_ep_b), np.array(per_ep_a)
    out = {
        "label": label, "n_episodes": len(names), "episodes": names, "before": mb, "after": ma,
        "rmse_ratio": (ma["rmse"] / mb["rmse"]) if mb["rmse"] and ma["rmse"] is not None else None,
        "sse_reduction": (1.0 - float(np.sum(per_ep_a) / np.sum(per_ep_b))) if np.isfinite(per_ep_a).all() and np.sum(per_ep_b) > 0 else None,
        "p_paired": paired_test(per_ep_b, per_ep_a),
        "improved_episodes": int((per_ep_a < per_ep_b).sum()),
        "by_regime": [],
    }
    edges = bin_edges(frame) if edges is None else edges
    for key, lab, mask, _, _ in regime_bins(frame, edges):
        if not mask.any():
            continue
        b, a = error_metrics(rb[mask]), error_metrics(ra[mask])
        out["by_regime"].append({"variable": key, "bin": str(lab), "n_ticks": int(mask.sum()),
                                 "n_episodes": int(len(np.unique(frame.episode[mask]))),
                                 **{f"{m}_before": b[m] for m in ("rmse_x", "rmse_z", "rmse", "mae")},
                                 **{f"{m}_after": a[m] for m in ("rmse_x", "rmse_z", "rmse", "mae")}})
    return out


def fee_gap(frame: Frame, before: AugmentedFEE, after: AugmentedFEE, start: ThetaFit | None = None, *,
            edges: dict | None = None) -> tuple[dict, dict]:
    """The FEE model's held-out comparison; θ refitted per held-out group for each model.

    Returns (comparison dict, {'before': (resid, fit), 'after': (resid, fit)}) for plots.
    """
    fit_b = fit_fixed(frame, before, start)
    fit_a = fit_b if after == before else fit_fixed(frame, after, start if start is not None else fit_b)
    rb, fb = residuals(frame, before, fit_b)
    ra, fa = residuals(frame, after, fit_a)
    out = compare_predictions(frame, fb, fa, label="FEE", edges=edges)
    out["model_before"] = [list(t) for t in before.terms]
    out["model_after"] = [list(t) for t in after.terms]
    return out, {"before": (rb, fit_b), "after": (ra, fit_a)}


__all__ = ["compare_predictions", "depth_forecast_gap", "error_metrics", "fee_gap"]


# Two episodes of one θ-group are "another depth" for the forecast when their steady depths
# differ by at least this [m]; steady = the second half of each episode's analysed ticks.
FORECAST_MIN_DEPTH_GAP_M = 0.02


def depth_forecast_gap(frame: Frame, before: AugmentedFEE, after: AugmentedFEE) -> dict:
    """The planner's question on held-out groups, before/after the named terms: θ fitted on one
    episode alone (one depth, as an estimator cutting sees it; from the coarse grid, nothing of
    the other episodes), the model's mean force over the steady half of another episode of the
    same group at another depth, against the measured mean there. Per ordered pair (A, B):
    |error| of F_x, F_z and of the force vector, % of the measured |F|; the mean over pairs,
    the signed bias going deeper and shallower, and a paired Wilcoxon over the source episodes A
    (each A's pairs averaged: pairs from one fit are not independent), after < before. Why: a
    joint fit over every depth of a group hides a wrong depth profile (θ bends to it), a fit at
    one depth does not."""
    alone, steady, depth = {}, {}, {}  # per episode: its ticks, a mask of their steady half, its depth there
    for e in frame.episodes:
        alone[int(e)] = sub = frame.select(episodes=[e])
        steady[int(e)] = np.arange(len(sub)) >= len(sub) // 2
        depth[int(e)] = float(np.median(sub.column("d")[steady[int(e)]]))
    pairs = [(int(a), int(b)) for a in frame.episodes for b in frame.episodes
             if a != b and frame.group_of[a] == frame.group_of[b] and abs(depth[int(a)] - depth[int(b)]) >= FORECAST_MIN_DEPTH_GAP_M]
    out = {"pairs": len(pairs), "min_depth_gap_m": FORECAST_MIN_DEPTH_GAP_M}
    if not pairs:
        return {**out, "before": None, "after": None, "reduction": None, "p_paired": 1.0, "p_worse": 1.0}
    errors = {}
    for label, model in (("before", before), ("after", after)):
        fits = {}
        for a in {p[0] for p in pairs}:
            fits[a] = fit_fixed(alone[a], model)
        rows = []
        for a, b in pairs:
            fb, m = alone[b], steady[b]
            _, pred = residuals(fb, model, fits[a])
            measured, predicted = fb.forces[m].mean(0), np.nanmean(pred[m], 0) if np.isfinite(pred[m]).any() else np.full(2, np.nan)
            scale = max(float(np.hypot(*measured)), 1.0)
            rows.append([*(100 * (predicted - measured) / np.maximum(np.abs(measured), 1.0)),
                         100 * float(np.hypot(*(predicted - measured))) / scale, depth[b] > depth[a], a])
        errors[label] = np.array(rows, float)
    summary = {}
    for label, r in errors.items():
        deeper = r[:, 3] == 1.0
        summary[label] = {"x_pct": float(np.nanmean(np.abs(r[:, 0]))), "z_pct": float(np.nanmean(np.abs(r[:, 1]))),
                          "vector_pct": float(np.nanmean(r[:, 2])),
                          "x_bias_deeper_pct": float(np.nanmean(r[deeper, 0])) if deeper.any() else None,
                          "x_bias_shallower_pct": float(np.nanmean(r[~deeper, 0])) if (~deeper).any() else None}
    b, a = errors["before"][:, 2], errors["after"][:, 2]
    reduction = 1.0 - summary["after"]["vector_pct"] / summary["before"]["vector_pct"] if summary["before"]["vector_pct"] > 0 else None
    sources = errors["before"][:, 4]
    per_a = [(np.nanmean(b[sources == s]), np.nanmean(a[sources == s])) for s in np.unique(sources)]
    before_a, after_a = np.array(per_a).T
    return {**out, **summary, "reduction": reduction, "p_paired": paired_test(before_a, after_a),
            "p_worse": paired_test(after_a, before_a), "source_episodes": len(per_a),
            "improved_pairs": int((a < b).sum())}
