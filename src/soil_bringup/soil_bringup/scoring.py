"""Scoring the recorded episode bags: the record of truth (every tick, every estimate).

Per episode, over valid estimates only, each matched to the tick it is stamped with: force
MAE x/z [N, % of the mean measured |F|] (paper §3.2), φ, c, δ, β MAE against the
pseudo-ground truth, and the share of ticks with a valid estimate. The error measures are the
estimator's own (``pinn_estimator.inference.force_errors``, ``pinn_estimator.evaluate``).
"""
from __future__ import annotations

import collections
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.stats import norm

from soil_bag_tools.bag_io import PARTIAL_SUFFIX, find_episode_bags, read_episode, read_labelled_topic
from soil_msgs_py import topics as T
from soil_msgs_py.params import SAMPLE_RATE_HZ, WINDOW_SAMPLES

from .estimate_columns import ESTIMATE_COLUMN


@dataclass
class EpisodeScore:
    """One recorded episode and its valid estimates matched to ticks."""

    bag: Path
    episode: object  # soil_msgs_py.episode.Episode
    rows: np.ndarray  # tick index of each valid estimate (unique, ascending)
    estimates: np.ndarray  # (n, len(ESTIMATE_FIELDS)) values of those estimates (SI)
    summary: dict


def score_episode(bag_dir: str | os.PathLike) -> EpisodeScore:
    """Read one episode bag and score its valid ``/soil/estimate`` messages against its ticks.

    ValueError (naming the bag) if the bag has no estimates or none is valid."""
    from pinn_estimator.evaluate import PARAMS, TRUTH_COL, UNITS

    bag = Path(bag_dir)
    ep = read_episode(bag)
    try:
        stamps, values = read_labelled_topic(bag, T.ESTIMATE.name, T.ESTIMATE_FIELDS)
    except ValueError as err:
        raise ValueError(f"{err} (was the estimator running and recorded?)") from None
    if len(stamps) == 0:
        raise ValueError(f"bag {bag} has no {T.ESTIMATE.name} message (the estimator published nothing)")
    ticks = len(ep)
    pos = np.searchsorted(ep.stamps_ns, stamps).clip(0, ticks - 1)
    on_tick = ep.stamps_ns[pos] == stamps
    valid = values[:, ESTIMATE_COLUMN["valid"]] > 0.5
    keep = np.flatnonzero(valid & on_tick)
    rows, first = np.unique(pos[keep], return_index=True)  # one estimate per tick (the first)
    est = values[keep[first]]
    if len(rows) == 0:
        raise ValueError(f"bag {bag} has {len(stamps)} {T.ESTIMATE.name} messages but no valid estimate "
                         f"on a tick of the episode (max window fill "
                         f"{int(values[:, ESTIMATE_COLUMN['window_samples']].max())}/{WINDOW_SAMPLES})")
    possible = max(ticks - (WINDOW_SAMPLES - 1), 0)  # ticks that end a full window
    summary = {
        "name": bag.name, "bag": str(bag), "soil": ep.meta.soil,
        "relative_density_pct": float(ep.meta.relative_density_pct), "world_mode": ep.meta.world_mode,
        "seed": int(ep.meta.seed), "ticks": ticks, "duration_s": ticks / SAMPLE_RATE_HZ,
        "estimates": int(len(stamps)), "valid_estimates": int(len(rows)),
        "valid_off_tick": int((valid & ~on_tick).sum()), "duplicate_valid": int(len(keep) - len(rows)),
        "pct_ticks_valid": 100.0 * len(rows) / ticks,
        "pct_full_window_ticks_valid": 100.0 * len(rows) / possible if possible else 0.0,
        "first_valid_s": float((ep.stamps_ns[rows[0]] - ep.stamps_ns[0]) * 1e-9),
    }
    summary.update(_errors(ep.forces[rows], est, ep.truth[rows]))
    summary["truth_mean"] = {f"{p}_{UNITS[p][0]}": float(ep.truth[rows, TRUTH_COL[p]].mean() * UNITS[p][1]) for p in PARAMS}
    summary["estimate_mean"] = {f"{p}_{UNITS[p][0]}": float(est[:, ESTIMATE_COLUMN[p]].mean() * UNITS[p][1])
                                for p in PARAMS}
    summary["fused_end"] = fused_at_end(ep, stamps[on_tick], values[on_tick])
    return EpisodeScore(bag, ep, rows, est, summary)


Z90 = float(norm.ppf(0.95))  # mean ± Z90·std is a Gaussian's central 90 % interval


def fused_at_end(ep, stamps: np.ndarray, values: np.ndarray) -> dict | None:
    """The soil fused along the episode, as its last estimate carried it, against the truth of
    that tick: mean ± std of φ, c, δ [deg, kPa], the error, and whether the 90 % interval
    (mean ± 1.645 std) holds the truth. None if no estimate carried a fused soil."""
    from pinn_estimator.evaluate import TRUTH_COL, UNITS

    fused = np.flatnonzero(values[:, ESTIMATE_COLUMN["fused_valid"]] == 1.0)
    if not len(fused):
        return None
    last = fused[-1]
    row = int(np.searchsorted(ep.stamps_ns, stamps[last]))
    out = {"at_s": float((stamps[last] - ep.stamps_ns[0]) * 1e-9),
           "stretches": int(values[last, ESTIMATE_COLUMN["fused_stretches"]])}
    for p in ("phi", "c", "delta"):
        unit, scale = UNITS[p]
        mean, std = values[last, ESTIMATE_COLUMN[f"{p}_fused"]], values[last, ESTIMATE_COLUMN[f"{p}_std"]]
        truth = ep.truth[row, TRUTH_COL[p]]
        out[p] = {f"mean_{unit}": float(mean * scale), f"std_{unit}": float(std * scale), f"truth_{unit}": float(truth * scale),
                  f"error_{unit}": float((mean - truth) * scale), "in_90": bool(abs(mean - truth) <= Z90 * std)}
    return out


def _errors(measured: np.ndarray, est: np.ndarray, truth: np.ndarray) -> dict:
    """Force errors [N, %] and parameter errors [deg, kPa] of matched estimates."""
    from pinn_estimator.evaluate import parameter_errors
    from pinn_estimator.inference import force_errors

    predicted = est[:, [ESTIMATE_COLUMN["f_x_hat"], ESTIMATE_COLUMN["f_z_hat"]]]
    forces = force_errors(measured, predicted)
    params = parameter_errors({p: est[:, ESTIMATE_COLUMN[p]] for p in ("phi", "c", "delta", "beta")}, truth,
                              np.ones(len(est), dtype=bool))
    return {"force": forces, "params": params}


def summarise(bag_dir: str | os.PathLike) -> dict:
    """Per-episode figures of one recorded bag (JSON-ready; see ``score_episode``)."""
    return score_episode(bag_dir).summary


def overall(scores: list[EpisodeScore]) -> dict:
    """The same figures over the valid estimates of every episode together."""
    ticks = sum(len(s.episode) for s in scores)
    valid = sum(len(s.rows) for s in scores)
    possible = sum(max(len(s.episode) - (WINDOW_SAMPLES - 1), 0) for s in scores)
    out = {"name": "overall", "episodes": len(scores), "ticks": ticks, "valid_estimates": valid,
           "estimates": sum(s.summary["estimates"] for s in scores),
           "pct_ticks_valid": 100.0 * valid / ticks if ticks else 0.0,
           "pct_full_window_ticks_valid": 100.0 * valid / possible if possible else 0.0}
    if scores:
        out.update(_errors(np.concatenate([s.episode.forces[s.rows] for s in scores]),
                           np.concatenate([s.estimates for s in scores]),
                           np.concatenate([s.episode.truth[s.rows] for s in scores])))
    return out


@dataclass
class BagDirScores:
    """Every episode bag of one directory, scored; what could not be scored, said."""

    bags: list[Path]
    scores: list[EpisodeScore]  # in run order (simulation time is continuous across episodes)
    problems: list[str]  # unfinished bags, bags without (valid) estimates


def score_bag_dir(root: Path) -> BagDirScores:
    """Score each finished episode bag under ``root``; a bag that cannot be scored is a problem, not an error."""
    problems: list[str] = []
    partial = sorted(p.name for p in root.glob(f"*{PARTIAL_SUFFIX}"))
    if partial:
        problems.append(f"unfinished bag(s) (the recorder did not close them): {', '.join(partial)}")
    bags = find_episode_bags(root)
    scores: list[EpisodeScore] = []
    for bag in bags:
        try:
            scores.append(score_episode(bag))
        except (ValueError, FileNotFoundError) as err:
            problems.append(str(err))
    scores.sort(key=lambda s: int(s.episode.stamps_ns[0]))
    return BagDirScores(bags, scores, problems)


def missing_episodes(scores: list[EpisodeScore], planned: list[tuple[str, float]]) -> list[str]:
    """The planned (soil, I_d [%]) episodes no scored bag accounts for, as 'Soil I_d 20 %'."""
    recorded = collections.Counter((s.episode.meta.soil, float(s.episode.meta.relative_density_pct)) for s in scores)
    return [f"{soil} I_d {d:g} %" for soil, d in planned if not recorded.pop((soil, float(d)), 0)]
