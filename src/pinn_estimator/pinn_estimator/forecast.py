"""The planner's question as an evaluation: from estimates made while cutting at one depth,
what force will the blade meet at another depth in the same soil?

For every pair of episodes (A, B) of one soil and relative density cut at different depths:
each estimator's soil parameters θ̂_A = (φ, c, δ), averaged over A's steady part, go through
the FEE (β = β* of θ̂_A, Eq. 7; velocity-corrected, Eq. 9-10) at B's conditions (Θ_k
averaged over B's steady part: d, v, Q, γ, ...), and the forecast is compared with the force
measured over B's steady part. Reported per estimator and axis: mean |error| as % of the
measured force, and the signed bias (forecast − measured, %), over all pairs and split into
shallower→deeper and deeper→shallower. Two references frame the numbers: the FEE with B's
true parameters (0 where the FEE is the world, the model gap elsewhere) and "naive: the
force measured at A" (what knowing nothing about the soil gives).

Works on any ``Dataset``: bags of a real machine cutting one soil at several depths too.
No ROS, no torch here; the estimates are computed by the caller (``evaluate``).
"""
from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass, replace

import numpy as np

from soil_msgs_py import markdown_table as md
from soil_msgs_py.episode import world_modes
from soil_msgs_py.soil_labels import UNKNOWN_SOIL, gamma_group_names, soil_label, unlabelled_count
from soil_msgs_py.params import (DEG, FORCE_LIMITS_N, GROUND_TRUTH_PARAMS, KNOWN_PARAMS, MIN_CUT_DEPTH_M,
                                 OBSERVATION_FIELDS, PLANNER_FORCE_MARGIN, SAMPLE_RATE_HZ)
from soil_physics import fee, force_terms
from soil_physics.augmented_fee import AugmentedFEE
from soil_physics.predictive import mean_standard_error

# Off the training grid (densities 0..100 step 20; depths 0.05, 0.175, 0.3 m; speeds
# 0.3..1.0): the held-out episodes the forecast is judged on.
FORECAST_DENSITIES_PCT = (30.0, 50.0, 70.0)
FORECAST_DEPTHS_M = (0.1, 0.15, 0.225)
FORECAST_SPEED_M_S = 0.6
STEADY_FROM = 0.5  # an episode's steady part: its second half (the controller has settled)
MIN_DEPTH_RATIO = 1.2  # pairs whose steady depths differ by less than this are not "another depth"
# A steady part's rows hold the depth to within this vertical speed [m/s] (``steady_mask``): its
# means of Θ_k and force are compared through the FEE at the mean Θ_k, which is the mean force only
# where Θ_k hardly moves. Tighter than the controller's and the planner's steady cut
# (``params.STEADY_CUT_MAX_ABS_V_Z_M_S``, 0.02 m/s: 1.9° of Eq. 9-10's friction at 0.6 m/s, 6° at
# 0.2 m/s): fee world, the true parameters' FEE at the steady means against their measured force,
# mean |error| of F_x / F_z over 36 held-out cuts at 0.6 m/s and 16 at 0.2 m/s: all rows of the
# second half 0.12 / 0.8 % and 2.7 / 26 %; |v_z| ≤ 0.02 m/s 0.01 / 2.2 % and 0.6 / 3.3 %;
# ≤ 0.005 m/s 0.01 / 0.5 % and 0.2 / 1.3 %.
STEADY_MAX_ABS_V_Z_M_S = 0.005
# An episode whose second half holds less steady cut (``steady_mask``) than this [s] is no steady
# cut: no pair is made from or to it (e.g. the anti-stall controller cycling at a force limit all
# along). Where a cycle does hold its depth that long (the held-out cuts of dense clay and loam at
# 0.225 m: 23 and 69 rows of 300), those rows' means agree with the FEE at the true parameters in
# the fee world to 0.4 and 0.1 % (all rows of the second half: 0.8 and 0.7 %).
MIN_STEADY_S = 0.25
REFERENCES = ("true_fee", "naive_same_force")
_X_EDGE = OBSERVATION_FIELDS.index("p_x_b")  # the blade edge's x [m] in a Dataset's observations
_D, _VZ = KNOWN_PARAMS.index("d"), KNOWN_PARAMS.index("v_z")


@dataclass(frozen=True)
class Steady:
    """One episode's steady part: mean Θ_k, measured force and (for scoring) true θ."""

    soil: str
    relative_density_pct: float
    known: dict[str, float]
    force: np.ndarray  # (2,) [N]
    truth: dict[str, float]
    distance_m: float = 0.0  # mean blade travel in soil over the steady rows (for terms that grow with it)
    time_s: float = 0.0  # mean time in soil over the steady rows [s] (likewise)
    world: str = ""  # the episode's world: a pair is one world's (bags of several worlds may share a folder)
    force_se: np.ndarray | None = None  # (2,) standard error of ``force`` [N] (``mean_standard_error``)
    target_speed_m_s: float = math.nan  # the episode's target speed (its metadata's) [m/s]

    def known_row(self) -> np.ndarray:
        """The steady Θ_k as a row in KNOWN_PARAMS order (what a posterior forecasts at)."""
        return np.array([self.known[n] for n in KNOWN_PARAMS])


def steady_mask(known: np.ndarray) -> np.ndarray:
    """Which rows of Θ_k (..., K) are a steady cut: the blade cutting (at least
    ``params.MIN_CUT_DEPTH_M`` deep: a blade skimming a soil it cannot enter is no cut, and two such
    episodes a tenth of a millimetre apart were a pair "at another depth") and holding its depth
    (|v_z| ≤ ``STEADY_MAX_ABS_V_Z_M_S``).

    Why not every row of the second half: it can hold a transient (the chassis settling into its
    own cut, when a slow blade plunges a few cm and the lift takes it back; the anti-stall lift),
    and a mean across one is no steady cut: its mean v_z bends the friction of Eq. 9-10 and the
    mean force is not the FEE's at the mean depth (in the fee world, where the FEE is exact, the
    true parameters' FEE missed such means of slow cuts by 3 % in F_x and 26 % in F_z; the figures
    at ``STEADY_MAX_ABS_V_Z_M_S``)."""
    known = np.asarray(known)
    return (known[..., _D] >= MIN_CUT_DEPTH_M) & (np.abs(known[..., _VZ]) <= STEADY_MAX_ABS_V_Z_M_S)


def steady_rows(known: np.ndarray, steady_from: float = STEADY_FROM) -> np.ndarray | None:
    """Row indices (into one episode's Θ_k, (n, K)) of its steady part: the ``steady_mask`` rows of
    its second half; None when they make less than ``MIN_STEADY_S`` of cutting."""
    rows = np.arange(len(known))[int(steady_from * len(known)):]
    steady = rows[steady_mask(known[rows])]
    return steady if len(steady) and len(steady) >= MIN_STEADY_S * SAMPLE_RATE_HZ else None


def steady_parts(ds, steady_from: float = STEADY_FROM) -> list[Steady]:
    """Per episode of ``ds`` the means over its steady part (``steady_rows``); None for an
    episode without one, or whose soil changes where its edge went (``episode_one_soil``; its
    metadata's label is only the patch it starts in: it is no one soil to forecast from or to).

    An episode without a soil label (a machine's bag) is labelled by its steady unit weight γ
    (``soil_labels.gamma_group_names`` over the unlabelled episodes): pairs are of one soil, and one
    soil at one density has one γ, where "unknown" would pair every unlabelled soil with every other."""
    out = []
    starts: dict[int, np.ndarray] = {}  # episode -> its true (φ, c) at its first row
    travel, in_soil_s = ds.distance_in_soil(), ds.time_in_soil()
    for e in range(len(ds)):
        rows = steady_rows(ds.known[ds.offsets[e]:ds.offsets[e + 1]], steady_from)
        meta = ds.metas[e]
        if rows is None or not episode_one_soil(ds, e):
            out.append(None)
            continue
        start_truth = ds.truth[ds.offsets[e], :2]  # (φ, c) as the episode began: its soil's, at its I_d
        rows = rows + ds.offsets[e]
        known = {n: float(ds.known[rows, j].mean()) for j, n in enumerate(KNOWN_PARAMS)}
        truth = {n: float(ds.truth[rows, j].mean()) for j, n in enumerate(GROUND_TRUTH_PARAMS)}
        out.append(Steady(meta.soil, float(meta.relative_density_pct), known, ds.forces[rows].mean(axis=0), truth,
                          float(travel[rows].mean()), float(in_soil_s[rows].mean()), meta.world_mode,
                          mean_standard_error(ds.forces[rows]), float(meta.target_speed_m_s)))
        starts[e] = start_truth
    _split_labels_of_two_soils(out, starts)
    unlabelled = [e for e, part in enumerate(out) if part is not None and soil_label(part) == UNKNOWN_SOIL]
    for e, name in zip(unlabelled, gamma_group_names([out[e].known["gamma"] for e in unlabelled])):
        out[e] = replace(out[e], soil=name)
    return out


def _split_labels_of_two_soils(parts: list[Steady | None], starts: dict[int, np.ndarray]) -> None:
    """Where one label at one density names soils whose true (φ, c) differ as their episodes began
    (a soil of the user's soil file named like a catalogue soil, bags of two sites), each soil gets
    its own label, "Sand (φ 11.0°, c 32.00 kPa)": pairs are of one soil. One soil at one density
    starts with one (φ, c), whatever the depth, speed or seed. Bags without a ground truth or a
    label (paired by their unit weight, as a machine's are) are left as they are."""
    groups = defaultdict(list)
    for e, start in starts.items():
        if parts[e] is not None and np.isfinite(start).all() and soil_label(parts[e]) != UNKNOWN_SOIL:
            groups[(parts[e].world, parts[e].soil, parts[e].relative_density_pct)].append(e)
    for (_, soil, _), members in groups.items():
        keys = {e: (round(float(starts[e][0]) / DEG, 1), round(float(starts[e][1]) / 1e3, 2)) for e in members}
        if len(set(keys.values())) > 1:
            for e, (phi_deg, c_kpa) in keys.items():
                parts[e] = replace(parts[e], soil=f"{soil} (φ {phi_deg:.1f}°, c {c_kpa:.2f} kPa)")


def _patch_key(patch: dict) -> tuple:
    return patch.get("soil"), float(patch.get("relative_density_pct", math.nan))


def one_soil(meta, x_edge_m=None) -> bool:
    """Whether an episode's path is one soil at one density where its edge went: no patches, or all
    alike, or, given ``x_edge_m`` (the edge's x over the episode [m]), the patches it crossed all
    alike to the metadata's label (``soil``, ``relative_density_pct``). A path that goes on past where
    the cut ended is one soil (an episode of a long planned path had been left out as a soil change);
    a cut in patches other than its label's is not the soil its label says. (The simulator labels an
    episode after the patch its edge starts in since 2026-12-06; a bag written before is labelled
    after its first patch even where the edge started beyond it, and such a bag stays out.)"""
    patches = list(meta.patches)
    if len({_patch_key(p) for p in patches}) <= 1:
        return True
    x = np.asarray([] if x_edge_m is None else x_edge_m, float)
    x = x[np.isfinite(x)]
    if len(x) == 0:
        return False
    lo, hi = float(x.min()), float(x.max())
    starts = [-math.inf] + [float(p["x_start_m"]) for p in patches[1:]] + [math.inf]  # patch j: [starts[j], starts[j+1])
    crossed = [j for j in range(len(patches)) if starts[j] <= hi and starts[j + 1] > lo]
    label = (meta.soil, float(meta.relative_density_pct))
    return bool(crossed) and all(_patch_key(patches[j]) == label for j in crossed)


def episode_one_soil(ds, e: int) -> bool:
    """``one_soil`` of episode ``e`` of a Dataset, over the x its edge went (its observations' p_x_b)."""
    return one_soil(ds.metas[e], ds.observations[ds.episode_rows(e), _X_EDGE])


def _in_steady_part(ds, ends: np.ndarray, steady_from: float) -> np.ndarray:
    episode = ds.episode_of_rows(ends)
    start = ds.offsets[episode] + steady_from * (ds.offsets[episode + 1] - ds.offsets[episode])
    return (ends >= start) & steady_mask(ds.known[ends])


def steady_window_ends(ds, stride: int, steady_from: float = STEADY_FROM) -> np.ndarray:
    """End rows of the windows (one every ``stride`` samples) that end in an episode's steady part:
    the only ones a forecast uses, so the only ones worth estimating on."""
    ends = ds.window_ends(range(len(ds)), stride)
    return ends[_in_steady_part(ds, ends, steady_from)]


def steady_estimates(ds, ends: np.ndarray, estimates: dict[str, np.ndarray], steady_from: float = STEADY_FROM):
    """Per episode, the mean of each estimate (arrays aligned with window ``ends``) over the
    windows that end in its steady part (NaN where none)."""
    episode = ds.episode_of_rows(ends)
    steady = _in_steady_part(ds, ends, steady_from)
    out = []
    for e in range(len(ds)):
        m = steady & (episode == e)
        out.append({p: float(np.nanmean(v[m])) if m.any() else float("nan") for p, v in estimates.items()})
    return out


def fee_force_at(theta: dict[str, float], at: dict[str, float], terms=(), distance_m: float = 0.0,
                 time_s: float = 0.0) -> np.ndarray:
    """(F_x, F_z) [N] of the FEE with soil θ = (φ, c, δ) at the conditions ``at`` (Θ_k means), β = β*.

    ``terms``: (name, k) force terms beside the FEE (an augmented model's own physics, e.g. a PINN
    trained with them), at blade travel ``distance_m`` [m] and time ``time_s`` [s] in soil (the
    target episode's steady means: exact for terms linear in them, such as compaction hardening).
    """
    if terms:
        known = np.array([at[n] for n in KNOWN_PARAMS])
        fx, fz = AugmentedFEE(terms).force((theta["phi"], theta["c"], theta["delta"]), known, distance_m,
                                           time_in_soil=time_s)
        return np.array([float(fx), float(fz)])
    params = dict(at, phi=theta["phi"], c=theta["c"], delta=theta["delta"])
    fx, fz, _ = fee.fee_xz({k: np.asarray(v, dtype=float) for k, v in params.items()})
    return np.array([float(fx), float(fz)])


INTERVALS = ((0.05, 0.95), (0.25, 0.75))  # the 90 % and 50 % central intervals scored for coverage


def forecast_pairs(parts: list[Steady | None], thetas: dict[str, list[dict]], posteriors: dict[str, list] | None = None,
                   terms: dict[str, tuple] | None = None, sources=None) -> list[dict]:
    """Every ordered pair (A → B) of one soil and density at another depth: each estimator's
    forecast of B's force from A's θ̂ through the FEE plus ``terms[name]`` if given (or, for
    ``posteriors``, the median of A's fused posterior predictive at B's conditions, with its 90 %
    and 50 % intervals), the references', and B's measured force. ``sources``: the episodes A may
    be (default: all; the others are only forecast to)."""
    posteriors = posteriors or {}
    terms = {name: force_terms.parse_terms(t) for name, t in (terms or {}).items()}
    quantiles = tuple(sorted({q for pair in INTERVALS for q in pair} | {0.5}))
    pairs = []
    for a, b in pair_indices(parts, sources):
        forecast = {name: fee_force_at(theta[a], parts[b].known, terms.get(name, ()), parts[b].distance_m, parts[b].time_s)
                    for name, theta in thetas.items()}
        intervals = {}
        for name, posts in posteriors.items():
            out = posts[a].forecast(parts[b].known_row(), quantiles=quantiles, distance_m=parts[b].distance_m,
                                    time_s=parts[b].time_s)
            forecast[name] = out["quantiles"][0.5]
            intervals[name] = {(lo, hi): (out["quantiles"][lo], out["quantiles"][hi]) for lo, hi in INTERVALS}
        forecast["true_fee"] = fee_force_at(parts[b].truth, parts[b].known)
        forecast["naive_same_force"] = parts[a].force
        pairs.append({"soil": parts[a].soil, "relative_density_pct": parts[a].relative_density_pct,
                      "from_depth_m": parts[a].known["d"], "to_depth_m": parts[b].known["d"],
                      "from_speed_m_s": parts[a].known["v_x"], "to_speed_m_s": parts[b].known["v_x"],
                      "target_speeds_m_s": (parts[a].target_speed_m_s, parts[b].target_speed_m_s),
                      "measured": parts[b].force, "forecast": forecast, "intervals": intervals})
    return pairs


# Speeds further apart than this [m/s] are other speeds (``calibration_strata``).
ANOTHER_SPEED_M_S = 0.1
# Measured steady depths may lie this far [m] outside the calibration's target depths and be its.
DEPTH_SLACK_M = 0.005
STRATA = ("calibrated", "other_depths", "across_speeds", "other_speed")


def calibration_strata(pairs: list[dict], names, reach=None) -> dict:
    """Per posterior in ``names``, F_x (``_errors``) over the pairs where its forecast law was
    calibrated and over those outside it. ``reach``: (shallowest [m], deepest [m], speed [m/s]) of
    the calibration (default ``fusion_calibration.calibration_bounds``). Calibrated: both steady
    depths within its depths (DEPTH_SLACK_M's slack) and both episodes' target speeds its speed; else, in turn,
    either depth outside them, steady speeds more than ANOTHER_SPEED_M_S apart, or one speed that
    is not the calibration's. An outside tester's: a headline of 85 / 48 % hid 93 / 52 % at one
    speed and 79 / 45 % across speeds, and sources of 7 cm going deeper held 53 / 24 %, with no
    word of either."""
    if reach is None:
        from .fusion_calibration import calibration_bounds  # (it builds on this module)

        reach = calibration_bounds()
    shallowest, deepest, speed = reach

    def stratum(p: dict) -> str:
        if not all(shallowest - DEPTH_SLACK_M <= p[k] <= deepest + DEPTH_SLACK_M for k in ("from_depth_m", "to_depth_m")):
            return "other_depths"
        if abs(p["to_speed_m_s"] - p["from_speed_m_s"]) > ANOTHER_SPEED_M_S:
            return "across_speeds"
        return "calibrated" if all(abs(v - speed) <= 1e-6 for v in p["target_speeds_m_s"]) else "other_speed"

    groups = {name: [] for name in STRATA}
    for p in pairs:
        groups[stratum(p)].append(p)
    out = {}
    for name in names:
        out[name] = {}
        for group, members in groups.items():
            deeper = [p for p in members if p["to_depth_m"] > p["from_depth_m"]]
            out[name][group] = {**_errors(members, name, 0), "deeper_bias_pct": _errors(deeper, name, 0)["bias_pct"]}
    return {"reach": list(reach), "another_speed_m_s": ANOTHER_SPEED_M_S, "posteriors": out}


def beyond_planner_margin(force_x_n: float, margin: float = PLANNER_FORCE_MARGIN) -> bool:
    """Whether a forecast F_x [N] lies at or beyond ``margin`` of the F_x limit (False where it is
    not finite): the split of ``margin_strata`` and of the forecast law's part near the limit."""
    return bool(np.isfinite(force_x_n) and abs(force_x_n) >= margin * FORCE_LIMITS_N[0])


def margin_strata(pairs: list[dict], names, margin: float = PLANNER_FORCE_MARGIN) -> dict:
    """Per posterior in ``names``, F_x and F_z (``_errors``) over the pairs whose forecast F_x (its
    median) is within ``margin`` of the F_x limit, about the cuts a planner plans (it keeps the 95 %
    bound of both axes within it, so a few fewer), and over the rest. Why: at the limit the anti-stall
    controller lifts the blade, and in the default world F_z is then the lift's push on the floor,
    which no soil model forecasts; one figure over every pair hid where the F_z intervals hold (held
    out, 2026-12-07: 87 / 56 % of the 61 pairs within the planner's margin, 64 / 9 % of the 11
    beyond it)."""
    limit = margin * FORCE_LIMITS_N[0]
    out = {}
    for name in names:
        groups = {"within": [], "beyond": []}
        for p in pairs:
            f = p["forecast"][name][0]
            if np.isfinite(f):
                groups["beyond" if beyond_planner_margin(f, margin) else "within"].append(p)
        out[name] = {g: {axis_name: _errors(members, name, axis) for axis, axis_name in enumerate(("x", "z"))}
                     for g, members in groups.items()}
    return {"margin": margin, "limit_n": float(limit), "posteriors": out}


def _groups(parts: list[Steady | None]) -> list[list[int]]:
    """Episodes with a steady part, by world, soil and density, in sorted order."""
    groups = defaultdict(list)
    for e, part in enumerate(parts):
        if part is not None:
            groups[(part.world, part.soil, part.relative_density_pct)].append(e)
    return [members for _, members in sorted(groups.items())]


def _another_depth(parts: list[Steady | None], a: int, b: int) -> bool:
    da, db = parts[a].known["d"], parts[b].known["d"]
    return max(da, db) >= MIN_DEPTH_RATIO * min(da, db)


def same_depth_pairs(parts: list[Steady | None], sources=None) -> int:
    """Ordered pairs of one world, soil and density not forecast: steady depths less than MIN_DEPTH_RATIO
    apart (from ``sources`` only if given, as ``pair_indices``)."""
    sources = None if sources is None else set(sources)
    return sum(a != b and not _another_depth(parts, a, b) for members in _groups(parts) for a in members
               if sources is None or a in sources for b in members)


def pair_indices(parts: list[Steady | None], sources=None):
    """(a, b) of every ordered pair of episodes of one world, soil and density at another depth (steady
    depths at least MIN_DEPTH_RATIO apart), grouped by world, soil and density in sorted order; a only
    among ``sources`` if given."""
    sources = None if sources is None else set(sources)
    for members in _groups(parts):
        for a in members:
            if sources is not None and a not in sources:
                continue
            for b in members:
                if a != b and _another_depth(parts, a, b):
                    yield a, b


# A pair is scored where its forecast is finite and its measured force above this [N]: an error as a
# share of a force near zero says nothing (a forecast of no failure wedge has no number at all).
MIN_MEASURED_N = 1.0


def _errors(pairs: list[dict], name: str, axis: int) -> dict[str, float]:
    measured = np.array([p["measured"][axis] for p in pairs])
    forecast = np.array([p["forecast"][name][axis] for p in pairs])
    finite = np.isfinite(forecast)
    ok = finite & (np.abs(measured) > MIN_MEASURED_N)
    # the pairs left out and why, said under the report's table (a row read "70 of the 72 pairs scored")
    left_out = {"no_finite_forecast": int((~finite).sum()), "measured_below_min": int((finite & ~ok).sum())}
    rel = 100.0 * (forecast[ok] - measured[ok]) / np.abs(measured[ok])
    if not len(rel):
        return {"pairs": 0, "mean_abs_pct": float("nan"), "bias_pct": float("nan"), "low_pct_of_pairs": float("nan"),
                **left_out}
    out = {"pairs": int(len(rel)), "mean_abs_pct": float(np.abs(rel).mean()), "bias_pct": float(rel.mean()),
           "low_pct_of_pairs": float(100.0 * (rel < 0).mean()), **left_out}
    for lo, hi in INTERVALS:
        if all(name in p["intervals"] for p in pairs):
            inside = [p["intervals"][name][(lo, hi)][0][axis] <= p["measured"][axis] <= p["intervals"][name][(lo, hi)][1][axis]
                      for p in pairs]
            out[f"coverage_{round(100 * (hi - lo))}"] = float(np.mean(inside))
    return out


def summarise(pairs: list[dict], names) -> dict:
    """Per estimator and axis: all pairs, shallower→deeper and deeper→shallower."""
    deeper = [p for p in pairs if p["to_depth_m"] > p["from_depth_m"]]
    shallower = [p for p in pairs if p["to_depth_m"] < p["from_depth_m"]]
    out = {}
    for name in (*names, *REFERENCES):
        out[name] = {
            axis_name: {"all": _errors(pairs, name, axis), "deeper": _errors(deeper, name, axis),
                        "shallower": _errors(shallower, name, axis)}
            for axis, axis_name in enumerate(("x", "z"))
        }
    return out


def per_soil(pairs: list[dict], names) -> dict:
    """Where the forecast fails, soil by soil (all its densities): per estimator, F_x over its pairs
    (error, bias, coverage) and going deeper."""
    out = {}
    for soil in sorted({p["soil"] for p in pairs}):
        mine = [p for p in pairs if p["soil"] == soil]
        deeper = [p for p in mine if p["to_depth_m"] > p["from_depth_m"]]
        out[soil] = {"pairs": len(mine), **{name: {"x": _errors(mine, name, 0), "deeper_x": _errors(deeper, name, 0)}
                                            for name in (*names, *REFERENCES)}}
    return out


def parameter_coverage(parts: list[Steady | None], posteriors: list) -> dict:
    """Fused posterior at each episode's end against its true θ: mean |error|, how often the
    posterior's central 90 % / 50 % intervals (its exact quantiles) hold the truth (meaningful
    where the model is the world) and the 90 % intervals' mean width [SI] (their sharpness).

    c's intervals are scored on cohesive soils only (true c > 0): the cohesionless row puts its
    mass at c = 0 and within a fraction of a pascal of it, so an interval of c from a cohesionless
    posterior holds a true 0 at any level, however sharp, and says nothing about calibration; a
    cohesionless soil's c counts in its error."""
    levels = (0.05, 0.25, 0.75, 0.95)  # symmetric: bound i and bound -1 - i make a central interval
    # a machine's bag has no ground truth (NaN): nothing to score its soil against
    scored = [(part, post) for part, post in zip(parts, posteriors)
              if part is not None and post.updates and all(np.isfinite(part.truth[n]) for n in ("phi", "c", "delta"))]
    if not scored:
        return {}
    summaries = [post.summary() for _, post in scored]
    bounds = [post.quantiles(levels) for _, post in scored]
    out = {}
    for name in ("phi", "c", "delta"):
        err = [s.mean[name] - part.truth[name] for s, (part, _) in zip(summaries, scored)]
        judged = [(q, part) for q, (part, _) in zip(bounds, scored) if name != "c" or part.truth["c"] > 0]
        held = {lv: [q[name][i] <= part.truth[name] <= q[name][-1 - i] for q, part in judged]
                for i, lv in enumerate((90, 50))}
        out[name] = {"episodes": len(scored), "mae": float(np.mean(np.abs(err))) if err else float("nan"),
                     "interval_episodes": len(judged),
                     **{f"coverage_{lv}": float(np.mean(h)) if h else float("nan") for lv, h in held.items()},
                     "width_90": float(np.mean([q[name][-1] - q[name][0] for q, _ in judged])) if judged else float("nan")}
    return out


def evaluate_forecast(ds, ends: np.ndarray, estimates: dict[str, dict[str, np.ndarray]],
                      posteriors: dict[str, list] | None = None, terms: dict[str, tuple] | None = None) -> dict:
    """The forecast report of ``ds``: ``estimates[name]`` holds φ, c, δ [SI] per window ``ends``
    (forecast through the FEE plus ``terms[name]``, the estimator's own physics, if given);
    ``posteriors[name]`` one fused posterior per episode (at its end; it forecasts through its own
    physics, and ``terms[name]`` only names that physics in the report)."""
    parts = steady_parts(ds)
    thetas = {name: steady_estimates(ds, ends, est) for name, est in estimates.items()}
    posteriors = posteriors or {}
    terms = {name: force_terms.parse_terms(t) for name, t in (terms or {}).items()}
    pairs = forecast_pairs(parts, thetas, posteriors, terms)
    names = [*estimates, *posteriors]
    return {
        "episodes": len(ds),
        # episodes without a soil label, paired by their measured unit weight γ instead (``steady_parts``)
        "unlabelled": unlabelled_count(ds.metas),
        "worlds": world_modes(ds.metas),
        "pairs": len(pairs),
        # what was not paired, said under the table: episodes without a steady part (or of a soil that changes
        # along the path: ``steady_parts``), and ordered pairs of one
        # soil and density whose steady depths are less than MIN_DEPTH_RATIO apart (not "another depth")
        "no_steady_part": sum(p is None for p in parts),
        "same_depth_pairs": same_depth_pairs(parts),
        "steady_from": STEADY_FROM,
        "forecast": summarise(pairs, names),
        "per_soil": per_soil(pairs, names),
        "calibration_strata": calibration_strata(pairs, list(posteriors)),
        "margin_strata": margin_strata(pairs, list(posteriors)),
        "physics": {name: [[n, float(k)] for n, k in t] for name, t in terms.items() if t},
        "parameters": {name: parameter_coverage(parts, posts) for name, posts in posteriors.items()},
        # posteriors that end as no soil the model can be (``SoilPosterior.not_a_soil``): δ above φ, or φ / δ held at
        # the end of their range; their θ is an effective soil (said without ground truth too: a machine's bags)
        "no_soil": {name: [ds.names[e] for e, post in enumerate(posts) if post.not_a_soil(post.summary())]
                    for name, posts in posteriors.items()},
    }


LABELS = {"fused": "fused posterior along the path (median, {physics})", "pinn": "PINN estimates ({physics} part, β*)",
          "classical": "classical least-squares fit (Tan 2005)",
          "true_fee": "FEE with the true parameters", "naive_same_force": "naive: the same force as now (measured at the source depth)"}


def label_of(report: dict, name: str) -> str:
    """An estimator's label, naming the terms its physics has beside the FEE (``report['physics']``)."""
    terms = report.get("physics", {}).get(name)
    physics = "FEE" + "".join(f" + {n} (k = {k:g})" for n, k in terms or ())
    return LABELS.get(name, name).replace("{physics}", physics)


def _coverage_text(v: dict, param: str) -> str:
    """How often a parameter's intervals hold the truth; c's are scored on the episodes of cohesive
    soils only, and with none there is nothing to say."""
    if param == "c" and not v["interval_episodes"]:
        return "no episode of a cohesive soil to score its intervals on"
    where = f" of the {v['interval_episodes']} episodes of cohesive soils" if param == "c" else ""
    return f"intervals hold the truth {v['coverage_90']:.0%} / {v['coverage_50']:.0%}{where}"


def _pct(value: float, signed: bool = False) -> str:
    """A percentage cell; "–" where there was nothing to average (no pair in that direction)."""
    if value is None or not np.isfinite(value):
        return "–"
    return f"{value:+.1f} %" if signed else f"{value:.1f} %"


# Below this many pairs the report says how loosely its coverages are known.
FEW_PAIRS = 50


def _unpaired_text(report: dict) -> str:
    """What the pairing left out, and how loosely few pairs pin a coverage down ('' if neither)."""
    out = []
    if report.get("no_steady_part"):
        out.append(f"{report['no_steady_part']} episode(s) without a steady cut of one soil in their second half")
    if report.get("same_depth_pairs"):
        out.append(f"{report['same_depth_pairs']} ordered pair(s) of one soil and density whose steady depths are less "
                   f"than {MIN_DEPTH_RATIO:g}× apart (not another depth)")
    text = f" Not paired: {'; '.join(out)}." if out else ""
    n = report.get("pairs", 0)
    if 0 < n < FEW_PAIRS:  # a coverage of p over n pairs has a standard error √(p(1 − p)/n): ±12 points at 50 % for 16
        # (pairs share their source and their target: the true uncertainty is larger, hence "at least")
        text += (f" With {n} pairs a coverage is known to at least ±{100 * math.sqrt(0.25 / n):.0f} points at 50 % "
                 f"(±{100 * math.sqrt(0.09 / n):.0f} at 90 %).")
    return text


def _left_out_text(report: dict, shown) -> str:
    """Under the table: of each row scored on fewer pairs than it has, how many each axis left out and
    why (``_errors``: no finite forecast, a measured force under MIN_MEASURED_N); '' if none."""
    reasons = (("no_finite_forecast", "no finite forecast (no failure wedge)"),
               ("measured_below_min", f"a measured force under {MIN_MEASURED_N:g} N"))
    rows = []
    for name in shown:
        axes = []
        for axis in ("x", "z"):
            cell = report["forecast"][name][axis]["all"]
            if (n := report["pairs"] - cell.get("pairs", report["pairs"])) > 0:
                why = [f"{cell[key]} with {text}" for key, text in reasons if cell.get(key)]
                axes.append(f"F_{axis}: {', '.join(why) or n}")  # (a report of before the reasons: the count)
        if axes:
            rows.append(f"{label_of(report, name)}: {'; '.join(axes)}")
    return f"Pairs left out of a row's score: {'. '.join(rows)}." if rows else ""


def _strata_text(report: dict, name: str) -> str:
    """Where the posterior's forecast law was calibrated and where not (``calibration_strata``), in one
    paragraph ('' for a report of before the strata, or where every pair lies within it)."""
    strata = report.get("calibration_strata")
    if not strata or name not in strata["posteriors"]:
        return ""
    cells = strata["posteriors"][name]
    if not any(cells[g]["pairs"] for g in STRATA[1:]):
        return ""
    shallowest, deepest, speed = strata["reach"]

    def said(v: dict) -> str:
        if not v["pairs"]:
            return "no pair"
        cover = f", 90 % / 50 % intervals hold {v['coverage_90']:.0%} / {v['coverage_50']:.0%}" if "coverage_90" in v else ""
        return (f"{v['pairs']} pair{'s' if v['pairs'] != 1 else ''}, {_pct(v['mean_abs_pct'])} off, bias deeper "
                f"{_pct(v['deeper_bias_pct'], True)}{cover}")

    return (f"Its F_x where its forecast law was calibrated (both depths {shallowest:g}–{deepest:g} m, the cuts the "
            f"calibration scores, both cut at its {speed:g} m/s): {said(cells['calibrated'])}; a depth outside them: "
            f"{said(cells['other_depths'])}; across speeds (steady speeds more than {strata['another_speed_m_s']:g} m/s "
            f"apart): {said(cells['across_speeds'])}; at one other speed: {said(cells['other_speed'])}. Outside the "
            "calibration the intervals are not calibrated: the posterior's physics lacks the edge's own reaction, a "
            "large part of a shallow cut's force, and (in the default world) the blade's contact damping, a drag that "
            "grows with speed.")


def _margin_text(report: dict, name: str) -> str:
    """How the posterior's intervals hold within the planner's margin and beyond it (``margin_strata``),
    in one sentence ('' for a report of before the strata, or where no pair lies beyond it)."""
    strata = report.get("margin_strata")
    if not strata or name not in strata["posteriors"] or not strata["posteriors"][name]["beyond"]["x"]["pairs"]:
        return ""
    cells = strata["posteriors"][name]

    def held(v: dict) -> str:
        return f"{v['coverage_90']:.0%} / {v['coverage_50']:.0%}" if "coverage_90" in v else "no intervals"

    def said(v: dict) -> str:
        n = v["x"]["pairs"]
        return f"{n} pair{'s' if n != 1 else ''}, F_x held in {held(v['x'])}, F_z in {held(v['z'])}"

    return (f"Its 90 % / 50 % intervals where the forecast F_x (median) is within the planner's margin "
            f"({strata['margin']:g} of the limit, below {strata['limit_n'] / 1e3:g} kN: about the cuts a planner plans, "
            f"which keeps the 95 % bound within it): {said(cells['within'])}; "
            f"beyond it: {said(cells['beyond'])}. At the limit the anti-stall controller lifts the blade, and its push "
            "(in the default world the floor carries it) is in no soil model's F_z: where the calibration pairs beyond "
            "the margin say so, the forecast law widens toward the limit (its part near it, forecast_limit_std).")


def markdown(report: dict, intro: str | None = None) -> list[str]:
    """Table lines: per estimator, F_x and F_z error at another depth, bias going deeper and
    shallower. ``intro``: the sentence above the table (default: the held-out episodes')."""
    if intro is None and report.get("data"):
        blind = report.get("unlabelled", 0)
        same = ("same soil and density" if not blind else
                f"same soil and density ({blind} of the episodes carry no soil label: those are paired by their measured "
                "unit weight γ, so two soils of one γ pair too, and the per-soil table groups them by γ)")
        intro = (f"Forecast of the force at another depth, {same}: {report['pairs']} pairs of "
                 f"{report['episodes']} episodes of the bags at {report['data']} "
                 f"({', '.join(report['worlds']) + ' world' if report['worlds'] else 'no simulator world'}; the posterior "
                 f"{report.get('fusion_config', 'shipped')}). "
                 "Mean |error| and signed bias, % of the measured force.")
    elif intro is None:  # (an outside tester read these as a held-out part of their own checkpoint's soils)
        soils = sorted(report.get("per_soil") or {})
        intro = (f"Forecast of the force at another depth, same soil and density: {report['pairs']} pairs of "
                 f"{report['episodes']} held-out episodes the simulator ran for this report ({', '.join(report['worlds'])}"
                 f"{'; the catalogue soils ' + ', '.join(soils) if soils else ''}; densities and depths off the shipped "
                 "models' training grid, whatever the checkpoint was trained on: `--forecast-data DIR` forecasts on "
                 "bags of your own). Mean |error| and signed bias, % of the measured force.")
    lines = [intro + _unpaired_text(report), "",
             *md.header(["estimator", "F_x error", "F_x bias deeper", "F_x bias shallower", "F_z error", "F_z bias deeper",
                         "90 % / 50 % intervals hold F_x", "hold F_z"])]
    # bags without ground truth (a machine's): no true-parameter FEE row or column, said below the table
    no_truth = "parameters" in report and not any(report["parameters"].values())
    shown = [n for n in report["forecast"] if not (no_truth and n == "true_fee")]
    for name in shown:
        axes = report["forecast"][name]
        x, z = axes["x"], axes["z"]
        label = label_of(report, name)
        scored = x["all"].get("pairs", report["pairs"])
        if scored != report["pairs"]:  # why: said under the table (``_left_out_text``)
            label += f" ({scored} of the {report['pairs']} pairs scored)"
        cover = [f"{a['all']['coverage_90']:.0%} / {a['all']['coverage_50']:.0%}" if "coverage_90" in a["all"] else "–"
                 for a in (x, z)]
        lines.append(md.row([label, _pct(x['all']['mean_abs_pct']), _pct(x['deeper']['bias_pct'], True),
                             _pct(x['shallower']['bias_pct'], True), _pct(z['all']['mean_abs_pct']),
                             _pct(z['deeper']['bias_pct'], True), *cover]))
    if left := _left_out_text(report, shown):
        lines += ["", left]
    if report.get("uncalibrated_physics"):
        lines += ["", f"**Not calibrated for this physics**: {report['uncalibrated_physics']}."]
    if "fused" in shown:
        lines += ["", f"The {LABELS['fused'].split(' (')[0]} fits its physics (the FEE and the terms its label names) to "
                      "the measured force: it uses the checkpoint's terms, not its network, and its row is the same for "
                      "every checkpoint of that physics."]
        if strata := _strata_text(report, "fused"):
            lines += ["", strata]
        if margin := _margin_text(report, "fused"):
            lines += ["", margin]
    per_soil = report.get("per_soil") or {}
    if len(per_soil) > 1:
        columns = [n for n in shown if n not in REFERENCES] + [n for n in REFERENCES if n in shown]
        lines += ["", "Per soil (all its densities), F_x at another depth: mean |error| (bias going deeper):", "",
                  *md.header(["soil", "pairs", *(label_of(report, n) for n in columns)])]
        for soil, row in per_soil.items():
            cells = [f"{_pct(row[n]['x']['mean_abs_pct'])} ({_pct(row[n]['deeper_x']['bias_pct'], True)})"
                     for n in columns]
            lines.append(md.row([soil, row['pairs'], *cells]))
    if no_truth:
        lines += ["", "No ground truth in these bags (no /soil/ground_truth, as from a machine): the soil's "
                      "parameters are not scored, only the forces, and there is no FEE with the true parameters."]
    for name, params in report.get("parameters", {}).items():
        if not params:
            continue
        cells = ", ".join(f"{p} error {v['mae'] / (DEG if p != 'c' else 1e3):.2f} {'kPa' if p == 'c' else '°'} "
                          f"({_coverage_text(v, p)})" for p, v in params.items())
        lines += ["", f"{label_of(report, name)}, soil at each episode's end vs the truth: {cells}."]
    for name, episodes in report.get("no_soil", {}).items():
        if episodes:
            named = ", ".join(episodes[:4]) + (", ..." if len(episodes) > 4 else "")
            lines += ["", f"{len(episodes)} of the {report['episodes']} episodes end with the {label_of(report, name)} "
                          f"as no soil the model can be (δ above φ, or φ or δ at the end of the range it is kept in: {named}): the force "
                          "has physics the model lacks, and their θ is an effective soil, whose forces at other depths are "
                          "what the figures above judge."]
    return lines
