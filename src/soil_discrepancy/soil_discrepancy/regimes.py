"""Step 2: where do the model and the measurement disagree? Residuals by regime, tested honestly.

Ticks of one episode are strongly autocorrelated (60 Hz, a force that changes over seconds), so
a tick-level test would call everything significant. Every test here has the **episode** as its
unit: per regime bin, each episode's mean residual (episodes with at least ``min_ticks`` ticks in
the bin), tested across episodes with a one-sample t-test (H0: mean 0); per variable, a trend
test within episodes (each episode's Spearman ρ of residual vs the variable, Fisher-z, t-test
across episodes) and between episodes (Spearman ρ of episode-mean residual vs episode-mean
variable). All p-values of one analysis (bins × axes and trends × axes) are Holm-corrected
together.

A finding is *flagged* only if it is significant (Holm p < alpha, 0.01) **and** large enough to
matter: the bin's mean residual (or the trend's change across the variable's 10-90 % range) is
at least ``min_effect`` (2 %) of the mean measured force magnitude |F| of those ticks. With a
few hundred thousand ticks a 0.5 % bias of contact transients is "significant" but is not a
missing effect of the model.
"""
from __future__ import annotations

import math

import numpy as np
from scipy import stats

from pinn_estimator.classical import denormalise_theta, normalised_bounds
from soil_msgs_py.params import KNOWN_PARAMS
from soil_msgs_py.soil_labels import GAMMA_GROUP_PREFIX, UNKNOWN_SOIL
from soil_msgs_py.strict_json import finite_or_none as _f

from .frame import Frame, density_label
from .soil_tests import group_label

# (key, label, unit) of the per-tick variables analysed.
CONTINUOUS: tuple[tuple[str, str, str], ...] = (
    ("d", "cut depth d", "m"),
    ("v_x", "forward speed v_x", "m/s"),
    ("v_z", "blade vertical velocity v_z", "m/s"),
    ("q", "surcharge Q", "N"),
    ("t", "time in episode", "s"),
    ("distance", "distance cut in soil", "m"),
)
CATEGORICAL: tuple[tuple[str, str], ...] = (("soil", "soil (metadata)"), ("i_d", "relative density I_d (metadata)"))
AXES = ("x", "z")
N_BINS = 4
MIN_TICKS = 5  # ticks of an episode in a bin for its mean to count
MIN_EPISODES = 3  # episodes with ticks in a bin for a test
ALPHA = 0.01
MIN_EFFECT = 0.02


def holm(pvalues) -> np.ndarray:
    """Holm-Bonferroni adjusted p-values (NaN stays NaN and is not counted)."""
    p = np.asarray(pvalues, float)
    out = np.full_like(p, np.nan)
    ok = np.isfinite(p)
    m = int(ok.sum())
    if m == 0:
        return out
    idx = np.nonzero(ok)[0]
    order = idx[np.argsort(p[idx], kind="stable")]
    running = 0.0
    for rank, i in enumerate(order):
        running = max(running, min(1.0, (m - rank) * p[i]))
        out[i] = running
    return out


# Per-tick variables a report names that are not binned here (time in soil follows time in the
# episode within a few ticks of the blade's entry): where a discovered form acts.
OTHER_LABELS = {"time_in_soil": "time in soil τ"}


def variable_labels() -> dict[str, str]:
    return {**{k: lab for k, lab, _ in CONTINUOUS}, **dict(CATEGORICAL), **OTHER_LABELS}


def bin_edges(frame: Frame, n_bins: int = N_BINS) -> dict[str, list[float] | None]:
    """Quantile bin edges per continuous variable over the frame's ticks (None: constant)."""
    out: dict[str, list[float] | None] = {}
    for key, _, _ in CONTINUOUS:
        x = frame.column(key)
        lo, hi = float(np.min(x)), float(np.max(x))
        spread = hi - lo
        if not np.isfinite(spread) or spread <= 1e-9 * max(1.0, abs(hi)):
            out[key] = None
            continue
        edges = np.quantile(x, np.linspace(0, 1, n_bins + 1))
        edges = np.where(np.abs(edges) < 1e-3 * spread, 0.0, edges)  # v_z ~ ±1e-5 m/s is 0: readable bins
        edges = np.unique(edges)
        if len(edges) < 2:
            out[key] = None
            continue
        edges[0], edges[-1] = -np.inf, np.inf
        out[key] = [float(e) for e in edges]
    return out


def regime_bins(frame: Frame, edges: dict) -> list[tuple[str, str, np.ndarray, float, float]]:
    """(variable, bin label, tick mask, lo, hi) of every regime bin: continuous then categorical."""
    out = []
    for key, _, unit in CONTINUOUS:
        e = edges.get(key)
        if not e:
            continue
        x = frame.column(key)
        idx = np.digitize(x, e[1:-1])
        for b in range(len(e) - 1):
            lo, hi = e[b], e[b + 1]
            lab = _range_label(lo, hi, unit, x)
            out.append((key, lab, idx == b, lo, hi))
    if frame.has_metadata():
        soils = np.array(frame.soils)[frame.episode]
        cats = sorted(set(soils))
        if len(cats) > 1:
            for s in cats:
                out.append(("soil", str(s), soils == s, math.nan, math.nan))
        dens = np.array(frame.densities)[frame.episode]
        vals = sorted(set(float(v) for v in dens if math.isfinite(v)))
        if len(vals) > 1:
            for v in vals:
                out.append(("i_d", f"{v:g} %", dens == v, v, v))
    return out


def _range_label(lo, hi, unit, x) -> str:
    lo_s = f"{np.min(x):.3g}" if not np.isfinite(lo) else f"{lo:.3g}"
    hi_s = f"{np.max(x):.3g}" if not np.isfinite(hi) else f"{hi:.3g}"
    return f"[{lo_s}, {hi_s}] {unit}"


def episode_means(frame: Frame, values: np.ndarray, mask: np.ndarray, min_ticks: int = MIN_TICKS):
    """(episodes, mean of ``values`` per episode over ``mask`` ticks, tick counts) for episodes with enough ticks."""
    ep = frame.episode[mask]
    v = values[mask]
    good = np.isfinite(v)
    ep, v = ep[good], v[good]
    if len(ep) == 0:
        return np.zeros(0, int), np.zeros(0), np.zeros(0, int)
    uniq, inv, counts = np.unique(ep, return_inverse=True, return_counts=True)
    sums = np.bincount(inv, weights=v)
    keep = counts >= min_ticks
    return uniq[keep], (sums / np.maximum(counts, 1))[keep], counts[keep]


def _ttest(means: np.ndarray) -> float:
    if len(means) < MIN_EPISODES or np.allclose(means, means[0], rtol=0, atol=1e-12):
        return math.nan
    return float(stats.ttest_1samp(means, 0.0).pvalue)


def _ci95(means: np.ndarray) -> tuple[float, float]:
    n = len(means)
    if n < 2:
        return (math.nan, math.nan)
    half = float(stats.t.ppf(0.975, n - 1) * means.std(ddof=1) / math.sqrt(n))
    m = float(means.mean())
    return (m - half, m + half)


def regime_analysis(frame: Frame, resid: np.ndarray, *, edges: dict | None = None, alpha: float = ALPHA,
                    min_effect: float = MIN_EFFECT, n_bins: int = N_BINS, min_ticks: int = MIN_TICKS) -> dict:
    """Residual (N, 2) [N] by regime, bins and trends, episode-level tests, Holm over everything.

    Returns a JSON-ready dict: ``bins`` and ``trends`` (rows with p, p_holm, effect, flagged),
    ``flagged_variables`` (variables with at least one flagged row), ``significant``.
    """
    edges = bin_edges(frame, n_bins) if edges is None else edges
    fmag = np.hypot(frame.forces[:, 0], frame.forces[:, 1])
    rows = []
    for key, label, mask, lo, hi in regime_bins(frame, edges):
        for a, axis in enumerate(AXES):
            eps, means, counts = episode_means(frame, resid[:, a], mask, min_ticks)
            scale = float(np.mean(fmag[mask])) if mask.any() else math.nan
            m = float(means.mean()) if len(means) else math.nan
            rows.append({
                "variable": key, "bin": label, "lo": _f(lo), "hi": _f(hi), "axis": axis,
                "n_episodes": int(len(eps)), "n_ticks": int(mask.sum()), "mean_n": _f(m), "ci95_n": list(map(_f, _ci95(means))),
                "mean_abs_force_n": _f(scale), "effect": _f(abs(m) / scale) if scale and math.isfinite(m) else None,
                "p": _f(_ttest(means)),
            })
    trends = trend_tests(frame, resid, fmag)
    p_all = np.array([r["p"] if r["p"] is not None else np.nan for r in rows + trends], float)
    p_adj = holm(p_all)
    for r, p in zip(rows + trends, p_adj):
        r["p_holm"] = _f(p)
        r["flagged"] = bool(np.isfinite(p) and p < alpha and r["effect"] is not None and r["effect"] >= min_effect)
    flagged = []
    for r in rows + trends:
        if r["flagged"] and r["variable"] not in flagged:
            flagged.append(r["variable"])
    fast = fast_part(frame, resid)
    return {
        "fast_rms_n": fast,
        "alpha": alpha, "min_effect": min_effect, "n_tests": int(np.isfinite(p_all).sum()),
        "edges": {k: v for k, v in edges.items()}, "bins": rows, "trends": trends,
        "flagged_variables": flagged, "significant": bool(flagged),
        "rms_n": {axis: _f(float(np.sqrt(np.nanmean(resid[:, a] ** 2)))) for a, axis in enumerate(AXES)},
    }


def fast_part(frame: Frame, resid: np.ndarray) -> dict:
    """Per axis, the RMS [N] of the residual's fast part: what changes from one analysed tick to the
    next (``frame.stride`` ticks apart), as white noise of that RMS would, sqrt(mean(Δr²) / 2).

    What is left of a residual is structure only beyond this: measurement noise and events
    shorter than a tick pair (a grip lost for a few ms) are the floor no quasi-static term can
    remove. Slow changes add a little to Δr, so this is an upper bound of the noise floor; a
    residual that alternates from tick to tick (a flickering gate) reads above its own RMS.
    """
    r = np.asarray(resid, float)
    same = (np.diff(frame.episode) == 0) & (np.diff(frame.rows) == frame.stride)
    d = np.diff(r, axis=0)[same]
    d = d[np.isfinite(d).all(1)]
    if len(d) == 0:
        return {axis: None for axis in AXES}
    return {axis: _f(math.sqrt(float(np.mean(d[:, a] ** 2)) / 2.0)) for a, axis in enumerate(AXES)}


# A θ-group (or a soil) "fits worse": its episodes' relative misfit is at least this many times the
# other episodes' median, and larger by a one-sided Mann-Whitney test (Holm, ``alpha``). Why a
# ratio of spreads: θ is fitted per group, so an effect that acts in one soil only is absorbed in
# that soil's mean residual (no bin is biased), but the model cannot bend to its form there.
MISFIT_RATIO = 2.0
# A θ-group whose ticks' depths (10th to 90th percentile) span less than this was cut at one depth,
# where φ and c trade off along a ridge (γd²wN_γ + c·d·w·N_c is one number): its θ may slide to the
# fit box's bound with nothing missing (an outside reader's pure-FEE control at one depth had φ on
# its lower bound in 8 of 8 groups, and the verdict blamed the physics).
ONE_DEPTH_SPAN_M = 0.02


# Travel "is" speed × time in soil when the analysed ticks' travel s differs from each episode's
# median v_x times τ by at most this share, RMS over RMS (the 108-episode grids, one target speed
# per episode with a stall's dips: 3.2-3.4 %).
TRAVEL_AS_SPEED_TIME_TOL = 0.05


def travel_is_speed_times_time(frame: Frame, tol: float = TRAVEL_AS_SPEED_TIME_TOL) -> bool:
    """Whether the episodes were cut at one speed each, so that travel is speed × time in soil
    (s ≈ v_x τ, each episode's median v_x): a law of one then reads as a law of the other (an outside
    reader's drag ∝ v_x τ was named w d · s, "pinned down", and the report called compaction's travel
    "the same mechanism"); only a cut whose speed changes tells them apart."""
    v = frame.known[:, KNOWN_PARAMS.index("v_x")]
    s, tau = frame.distance, frame.time_in_soil
    pred = np.full(len(s), np.nan)
    for e in frame.episodes:
        m = frame.episode == e
        pred[m] = np.nanmedian(v[m]) * tau[m]
    ok = np.isfinite(s) & np.isfinite(pred)
    scale = math.sqrt(float(np.mean(s[ok] ** 2))) if ok.any() else 0.0
    return scale > 0 and math.sqrt(float(np.mean((s[ok] - pred[ok]) ** 2))) <= tol * scale


# Travel in soil "is" position along the path when the episodes entered the soil at one place: their
# entry positions spread over at most this share of how far they travel in it (95th percentile). The
# batch grids start every cut at x = 2 m (a spread of ~0.01 m against 3-10 m of travel).
TRAVEL_AS_POSITION_TOL = 0.1


def travel_is_position(frame: Frame, tol: float = TRAVEL_AS_POSITION_TOL) -> float | None:
    """Where along the path [m] every analysed episode entered the soil (the entries' median), if
    they all entered at one place: travel in soil is then position along the path (s = x − x_entry),
    so a law of one reads as a law of the other (an outside tester's soil strengthening along the
    path from 3 m on was named compaction by travel, "pinned down"); only cuts that enter the soil at
    different places tell them apart. None where they did not, or the positions are not known."""
    x = np.asarray(frame.entry_x_m, float)[frame.episodes] if frame.entry_x_m is not None else np.zeros(0)
    x = x[np.isfinite(x)]
    reach = float(np.percentile(frame.distance, 95)) if len(frame) else 0.0
    if len(x) < 2 or not reach > 0:
        return None
    return float(np.median(x)) if float(np.ptp(x)) <= tol * reach else None


# Time in soil "is" the episode's clock when every analysed episode entered the soil at one moment of
# its recording: the moments (t − τ) spread over at most this share of how long the blade was in the
# soil (95th percentile of τ). The batch grids' episodes enter within ~0.1 s of each other.
TIME_AS_CLOCK_TOL = 0.1


def time_in_soil_is_clock(frame: Frame, tol: float = TIME_AS_CLOCK_TOL) -> float | None:
    """The moment [s] after each recording's start at which every analysed episode entered the soil
    (the median of t − τ), if they all did at one moment: time in soil τ is then the recording's clock
    less a constant, so a law of one reads as a law of the other (an outside reader's sensor gain
    drifting with the clock was named "time in soil × the FEE force" and nothing said so); only
    recordings that start at different moments before the cut tell them apart. None otherwise."""
    if not len(frame):
        return None
    reach = float(np.percentile(frame.time_in_soil, 95))
    offsets = [float(np.median((frame.t - frame.time_in_soil)[frame.episode == e])) for e in frame.episodes]
    if len(offsets) < 2 or not reach > 0:
        return None
    return float(np.median(offsets)) if float(np.ptp(offsets)) <= tol * reach else None


def episode_misfit(frame: Frame, resid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(episodes, relative misfit per episode): RMS of the residual magnitude over the mean measured |F| (1)."""
    eps = frame.episodes
    fmag = np.hypot(frame.forces[:, 0], frame.forces[:, 1])
    mag2 = (np.asarray(resid, float) ** 2).sum(1)
    out = np.full(len(eps), np.nan)
    for i, e in enumerate(eps):
        m = (frame.episode == e) & np.isfinite(mag2)
        if m.any():
            out[i] = math.sqrt(float(mag2[m].mean())) / max(float(fmag[m].mean()), 1.0)
    return eps, out


def group_misfit(frame: Frame, resid: np.ndarray, *, alpha: float = ALPHA, ratio: float = MISFIT_RATIO,
                 theta_table=None) -> dict:
    """Where the model fits worse: per θ-group and per soil label, the episodes' relative misfit
    against every other episode's (one-sided Mann-Whitney, Holm over all groups and soils).

    ``theta_table``: ``ThetaFit.table`` rows; a group whose fitted θ sits on the fit's box
    (``pinn_estimator.classical`` bounds) is marked: the model needed a soil outside the
    physical range there, another sign of a missing effect, unless the group was cut at one depth
    ('one_depth': its 'depth_span_m' below ``ONE_DEPTH_SPAN_M``), where φ and c are not
    identifiable apart.
    Per relative density too (every soil at it, "density" rows), where the bags hold more than one.
    Returns {'rows': [...], 'groups': flagged group names, 'soils': flagged soil labels,
    'densities': flagged densities' names, 'ratio', 'alpha'}.
    """
    eps, mis = episode_misfit(frame, resid)
    group_of_ep = frame.group_of[eps]
    units = [("group", frame.group_names[g], group_of_ep == g) for g in np.unique(group_of_ep)]
    if frame.has_metadata():
        soil_of_ep = np.array(frame.soils)[eps]
        labels = sorted(set(soil_of_ep))
        if len(labels) > 1:  # a soil that is one group already is that group's row
            units += [("soil", s, soil_of_ep == s) for s in labels
                      if not any(np.array_equal(soil_of_ep == s, m) for _, _, m in units)]
        # every soil at one relative density: an effect of loose (or dense) soils acts in a group of
        # each soil, and each group against all the others, the other loose groups among them, was
        # flagged in none (an outside reader's drag in I_d 0 % only: 17-22× the others, Holm p 0.02-0.4)
        dens_of_ep = np.array(frame.densities, float)[eps]
        label_of_ep = np.array([density_label(v) if np.isfinite(v) else "" for v in dens_of_ep])
        levels = sorted({float(v) for v in dens_of_ep if np.isfinite(v)})
        names = list(dict.fromkeys(density_label(v) for v in levels))  # by name, as θ-groups are named
        if len(names) > 1:
            units += [("density", n, label_of_ep == n) for n in names
                      if not any(np.array_equal(label_of_ep == n, m) for _, _, m in units)]
    rho = frame.known[:, KNOWN_PARAMS.index("rho")]
    rho_max = {frame.group_names[g]: float(rho[frame.group == g].max()) for g in frame.groups}
    tested = {frame.group_names[g]: box for g, box in (frame.theta_boxes or {}).items()}
    bound = {t["group"]: _theta_at_bound(t, rho_max[t["group"]], tested.get(t["group"])) for t in (theta_table or [])
             if t["group"] in rho_max and t.get("success", True)}
    n_tested = {name: _tested_parameters(rho_max[name], tested.get(name)) for name in rho_max}
    testable = {frame.group_names[g]: group_label(frame, int(g)) is not None for g in frame.groups}
    ranged = {frame.group_names[g]: label_soil(frame, int(g)) is not None for g in frame.groups}
    off_label = _off_label_range(frame, theta_table or [])
    d = frame.known[:, KNOWN_PARAMS.index("d")]
    span = {frame.group_names[g]: float(np.subtract(*np.percentile(d[frame.group == g], [90, 10])))
            for g in frame.groups}
    rows = []
    for kind, name, inside in units:
        a, b = mis[inside & np.isfinite(mis)], mis[~inside & np.isfinite(mis)]
        p = math.nan
        if len(a) >= 1 and len(b) >= MIN_EPISODES and len(a) + len(b) >= 2 * MIN_EPISODES:
            p = float(stats.mannwhitneyu(a, b, alternative="greater").pvalue)
        rel = float(np.median(a) / np.median(b)) if len(a) and len(b) and np.median(b) > 0 else math.nan
        rows.append({"kind": kind, "name": str(name), "n_episodes": int(len(a)), "misfit": _f(np.median(a) if len(a) else None),
                     "misfit_others": _f(np.median(b) if len(b) else None), "ratio": _f(rel), "p": _f(p),
                     "theta_at_bound": bound.get(name, []) if kind == "group" else [],
                     "tested_parameters": n_tested.get(name, 0) if kind == "group" else 0,
                     "testable": testable.get(name, False) if kind == "group" else False,  # by a soil test
                     # its fitted soil checked against a catalogue soil's textbook range (``label_soil``)
                     "range_checked": ranged.get(name, False) if kind == "group" else False,
                     "theta_off_label": off_label.get(name, []) if kind == "group" else [],
                     "depth_span_m": _f(span.get(name)) if kind == "group" else None,
                     "one_depth": kind == "group" and span.get(name, math.inf) < ONE_DEPTH_SPAN_M})
    for r, p in zip(rows, holm([np.nan if r["p"] is None else r["p"] for r in rows])):
        r["p_holm"] = _f(p)
        r["flagged"] = bool(np.isfinite(p) and p < alpha and r["ratio"] is not None and r["ratio"] >= ratio)
    return {"ratio": ratio, "alpha": alpha, "rows": rows,
            "groups": [r["name"] for r in rows if r["kind"] == "group" and r["flagged"]],
            "soils": [r["name"] for r in rows if r["kind"] == "soil" and r["flagged"]],
            "densities": [r["name"] for r in rows if r["kind"] == "density" and r["flagged"]]}


def misfit_unit_name(row: dict) -> str:
    """How the report and the verdict name a row of ``group_misfit``: a θ-group by its name, a soil
    label as "soil Clay", a density as "the soils at I_d=0%"."""
    return {"soil": f"soil {row['name']}", "density": f"the soils at {row['name']}"}.get(row["kind"], row["name"])


def unit_episodes(frame: Frame, row: dict) -> set[int]:
    """The episodes (indices) of one row of ``group_misfit``: its θ-group's, soil label's or density's."""
    if row["kind"] == "soil":
        return {int(e) for e in frame.episodes if frame.soils[e] == row["name"]}
    if row["kind"] == "density":  # the row's level (``group_misfit``: each finite density a row of its own)
        return {int(e) for e in frame.episodes if density_label(frame.densities[e]) == row["name"]}
    return {int(e) for e in frame.episodes if frame.group_names[frame.group_of[e]] == row["name"]}


def flagged_rows(mis: dict | None) -> list[dict]:
    """The flagged rows of ``group_misfit``'s result, in the order reports name them: soils, densities,
    then θ-groups (a report written before the density rows has no 'densities')."""
    mis = mis or {}
    rows = {(r["kind"], r["name"]): r for r in mis.get("rows", [])}
    return [rows[(kind, n)] for kind, names in (("soil", mis.get("soils", [])), ("density", mis.get("densities", [])),
                                                 ("group", mis.get("groups", []))) for n in names]


def flagged_units(mis: dict | None) -> list[str]:
    """The flagged rows of ``group_misfit`` by ``misfit_unit_name`` (``flagged_rows``' order)."""
    return [misfit_unit_name(r) for r in flagged_rows(mis)]


def misfit_discrepancy(reg: dict | None) -> list[dict]:
    """The rows of ``group_misfit`` (in ``reg['misfit']``) that are a discrepancy by themselves,
    whatever the regime tests say: flagged, of a soil label, a density or a θ-group of labelled bags,
    and worse than the other episodes by at least the regime tests' least effect (the row's median
    episode misfit, an RMS over |F|, beyond the others' median in quadrature, ``reg['min_effect']``
    of |F|).

    Why: θ per group takes an effect that acts in some soils only as their bias, so no regime bin
    is biased, but the effect's form is left there (an outside reader's drag while the blade speeds
    up: the dense clay and loam 5.6 % and 5.5 % against 1.1 %, which the report headed "no
    significant discrepancy"). Not a γ-group's (bags without soil labels): two soils of one γ share
    one θ there and fit worse with nothing missing, a caution only; nor the unlabelled episodes'
    soil row ("unknown", beside labelled bags), whose groups are such γ-groups; nor a misfit of
    tenths of a percent, significant only because the others fit so well."""
    min_effect = (reg or {}).get("min_effect", MIN_EFFECT)
    out = []
    for r in ((reg or {}).get("misfit") or {}).get("rows", []):
        if (not r.get("flagged") or (r["kind"] == "group" and GAMMA_GROUP_PREFIX in r["name"])
                or (r["kind"] == "soil" and r["name"] == UNKNOWN_SOIL)):
            continue
        mine, others = r.get("misfit"), r.get("misfit_others")
        if mine is not None and others is not None and mine ** 2 - others ** 2 >= min_effect ** 2:
            out.append(r)
    return out


_TEST_BOUND = "its soil test's"  # how ``_theta_at_bound`` words a bound a soil test set


def on_soil_test_bound(hit: str) -> bool:
    """Whether one of ``_theta_at_bound``'s hits is on a soil test's bound (not the fit box's)."""
    return _TEST_BOUND in hit


# How far [°, Pa] a group's fitted φ and c may lie outside the textbook range of its soil label
# (``soils.CATALOGUE``, loose to dense) before the report says so: a missing effect θ takes in
# moves them far (a drag ∝ d^1.5, 47 % of the FEE force, fitted clays at φ 35° for 17-27° and "no
# significant discrepancy"); the fee world's exact model fits each within a fraction of a degree.
LABEL_RANGE_MARGIN = {"phi": 3.0, "c": 1e3}


def label_soil(frame: Frame, group: int):
    """The catalogue soil whose textbook range θ-group ``group``'s fitted soil is checked against: its
    episodes' one soil label, if a catalogue soil's (None for bags without labels, a group of several,
    or a soil of one's own, whose range is not known here)."""
    from soil_physics.soils import CATALOGUE

    if not frame.has_metadata():
        return None
    labels = set(np.asarray(frame.soils)[frame.group_of == group])
    if len(labels) != 1:
        return None
    by_name = {name.lower(): soil for name, soil in CATALOGUE.items()}
    return by_name.get(str(next(iter(labels))).lower())


def _off_label_range(frame: Frame, theta_table) -> dict[str, list[str]]:
    """θ-group -> its fitted φ or c outside the textbook range of its soil label, in words ({} for
    bags without labels or labels of no catalogue soil, whose range is not known here)."""
    out: dict[str, list[str]] = {}
    for t in theta_table:
        if t["group"] not in frame.group_names or not t.get("success", True):
            continue
        soil = label_soil(frame, frame.group_names.index(t["group"]))
        if soil is None:
            continue
        hits = []
        for key, value, lo, hi, unit, scale in (
                ("phi", t["phi_deg"], math.degrees(soil.loose.phi), math.degrees(soil.dense.phi), "°", 1.0),
                ("c", t["c_pa"], soil.loose.c, soil.dense.c, " kPa", 1e-3)):
            margin = LABEL_RANGE_MARGIN[key]
            if value < min(lo, hi) - margin or value > max(lo, hi) + margin:
                symbol = "φ" if key == "phi" else "c"
                hits.append(f"{symbol} {value * scale:.{1 if key == 'phi' else 2}f}{unit} ({soil.name}: "
                            f"{min(lo, hi) * scale:g}–{max(lo, hi) * scale:g}{unit})")
        if hits:
            out[t["group"]] = hits
    return out


def _fit_box_si(rho_max_rad: float) -> tuple[np.ndarray, np.ndarray] | None:
    """(lower, upper) of φ, c, δ [SI] of the box ``fee_fit`` searches for a group whose steepest blade
    angle is ``rho_max_rad``; None where the blade is so steep that no useful soil fits."""
    box = normalised_bounds(rho_max_rad)
    return None if box is None else tuple(denormalise_theta(np.asarray(b, float)) for b in box)


def _tested_parameters(rho_max_rad: float, tested=None) -> int:
    """How many of φ, c, δ a soil test bounds inside the fit's box for a group (``tested``: its
    ``Frame.theta_boxes`` entry, None for none): each may land on the test's bound by chance."""
    box = _fit_box_si(rho_max_rad)
    if box is None or tested is None:
        return 0
    lo_si, hi_si = box
    return sum(1 for i in range(3) if float(tested[0][i]) > float(lo_si[i]) or float(tested[1][i]) < float(hi_si[i]))


def _theta_at_bound(row: dict, rho_max_rad: float, tested=None) -> list[str]:
    """Which of φ, c, δ of a ``ThetaFit.table`` row lie on the fit's box (0.1 % of its range): the box
    ``fee_fit`` searches for a group whose steepest blade angle is ``rho_max_rad`` (narrowed so that β* exists),
    within a soil test's interval where ``tested`` ((lo, hi) SI, ``Frame.theta_boxes``) holds the group:
    there a bound hit says the forces want a soil the test rules out."""
    box = _fit_box_si(rho_max_rad)
    if box is None:
        return []
    lo_si, hi_si = box
    out = []
    for i, (name, value) in enumerate((("φ", math.radians(row["phi_deg"])), ("c", row["c_pa"]),
                                       ("δ", math.radians(row["delta_deg"])))):
        lo, hi = float(lo_si[i]), float(hi_si[i])
        t_lo, t_hi = (-math.inf, math.inf) if tested is None else (float(tested[0][i]), float(tested[1][i]))
        whose_lo = f"{_TEST_BOUND} lower bound" if t_lo > lo else "its lower bound"
        whose_hi = f"{_TEST_BOUND} upper bound" if t_hi < hi else "its upper bound"
        lo, hi = max(lo, t_lo), min(hi, t_hi)
        tol = 1e-3 * (hi - lo)
        if value <= lo + tol and not (name == "c" and lo <= 1e-6):  # c = 0: a cohesionless soil, not a bound hit
            out.append(f"{name} at {whose_lo}")
        elif value >= hi - tol:
            out.append(f"{name} at {whose_hi}")
    return out


def trend_tests(frame: Frame, resid: np.ndarray, fmag: np.ndarray | None = None) -> list[dict]:
    """Within- and between-episode trend of the residual vs every continuous variable, per axis."""
    fmag = np.hypot(frame.forces[:, 0], frame.forces[:, 1]) if fmag is None else fmag
    scale = float(np.mean(fmag))
    out = []
    eps = frame.episodes
    for key, _, _ in CONTINUOUS:
        x = frame.column(key)
        spread = float(np.ptp(x)) if len(x) else 0.0
        if spread <= 1e-9 * max(1.0, float(np.max(np.abs(x))) if len(x) else 1.0):
            continue
        for a, axis in enumerate(AXES):
            r = resid[:, a]
            zs, effects = [], []
            xm, rm = [], []
            for e in eps:
                sel = (frame.episode == e) & np.isfinite(r)
                xe, re = x[sel], r[sel]
                if len(xe) == 0:
                    continue
                xm.append(xe.mean())
                rm.append(re.mean())
                if len(xe) < 10 or np.ptp(xe) <= 1e-3 * spread or len(np.unique(xe)) < 5 or np.ptp(re) == 0:
                    continue
                rho = stats.spearmanr(xe, re).statistic
                if not np.isfinite(rho):
                    continue
                zs.append(np.arctanh(np.clip(rho, -0.999, 0.999)))
                lo, hi = np.quantile(xe, [0.1, 0.9])
                slope = np.polyfit(xe, re, 1)[0]
                effects.append(slope * (hi - lo))
            if len(zs) >= MIN_EPISODES:
                zs = np.asarray(zs)
                p = _ttest(zs)
                eff = abs(float(np.mean(effects)))
                out.append({"variable": key, "axis": axis, "kind": "within", "n_episodes": len(zs),
                            "stat": _f(float(np.tanh(zs.mean()))), "effect_n": _f(eff), "effect": _f(eff / scale),
                            "p": _f(p)})
            xm, rm = np.asarray(xm), np.asarray(rm)
            if len(xm) >= 5 and np.ptp(xm) > 1e-3 * spread and np.ptp(rm) > 0:
                res = stats.spearmanr(xm, rm)
                lo, hi = np.quantile(xm, [0.1, 0.9])
                eff = abs(float(np.polyfit(xm, rm, 1)[0] * (hi - lo)))
                out.append({"variable": key, "axis": axis, "kind": "between", "n_episodes": int(len(xm)),
                            "stat": _f(float(res.statistic)), "effect_n": _f(eff), "effect": _f(eff / scale),
                            "p": _f(float(res.pvalue))})
    return out


def binned_curve(frame: Frame, values: np.ndarray, key: str, edges: dict, min_ticks: int = MIN_TICKS):
    """For plots: per bin (x centre, mean of episode means, CI low, CI high) of ``values`` vs ``key``."""
    e = edges.get(key)
    if not e:
        return None
    x = frame.column(key)
    idx = np.digitize(x, e[1:-1])
    out = []
    for b in range(len(e) - 1):
        mask = idx == b
        if not mask.any():
            continue
        _, means, _ = episode_means(frame, values, mask, min_ticks)
        if len(means) == 0:
            continue
        lo, hi = _ci95(means)
        out.append((float(np.median(x[mask])), float(means.mean()), lo, hi))
    return np.array(out) if out else None
