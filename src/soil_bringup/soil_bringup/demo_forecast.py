"""The planner's question on the main job's own run: from the soil learnt while cutting each live
episode at one depth, what force will the blade meet at another depth in the same soil?

The live episodes cut at one depth. The simulator (in this process, lockstep, no ROS) cuts the
same soil, density, speed and seed at ``OTHER_DEPTHS_M``; ``pinn_estimator.forecast`` scores the
forecasts from each live episode to each of those against the force measured there: the fused
posterior the estimator held at the episode's end (rebuilt from the episode's bag, which gives the
live values), the PINN's live estimates averaged over the episode's steady half, and the two
references (the FEE with the true parameters, and "the force now"). Truth is read for scoring only.
"""
from __future__ import annotations

import math

import numpy as np

OTHER_DEPTHS_M = (0.1, 0.25)  # the demo cuts at 0.2 m: one forecast shallower, one deeper
ESTIMATORS = ("fused", "pinn")


def reference_specs(metas, depths_m=OTHER_DEPTHS_M) -> list:
    """One EpisodeSpec per live episode's metadata and other depth (the same soil, density, speed,
    seed and length; a one-soil path only)."""
    from soil_sim_node.simulator import EpisodeSpec

    return [EpisodeSpec(m.soil, m.relative_density_pct, m.target_speed_m_s, d, seed=m.seed, duration_s=m.duration_s)
            for m in metas for d in depths_m if abs(d - m.target_depth_m) > 1e-9]


def steady_pinn_estimate(score) -> dict[str, float]:
    """The PINN's φ, c, δ [SI] averaged over the valid live estimates of ``score`` (a
    ``scoring.EpisodeScore``) stamped in the episode's steady part (``forecast.steady_parts``'
    rows: the second half, blade in soil). NaN where none."""
    from pinn_estimator import forecast as fc
    from soil_msgs_py.params import KNOWN_PARAMS

    from .estimate_columns import ESTIMATE_COLUMN

    ticks = len(score.episode)
    steady = (score.rows >= int(fc.STEADY_FROM * ticks)) & (score.episode.known[score.rows, KNOWN_PARAMS.index("d")] > 0)
    return {p: float(np.mean(score.estimates[steady, ESTIMATE_COLUMN[p]])) if steady.any() else math.nan
            for p in ("phi", "c", "delta")}


def forecast_from_live(scores, world: str | None = None, depths_m=OTHER_DEPTHS_M, fusion=None) -> dict:
    """The forecast report (``pinn_estimator.forecast.summarise`` per estimator and axis: error,
    bias deeper / shallower, interval coverage) from the live episodes of ``scores`` to the
    simulator's episodes at ``depths_m``. ``world``: the live run's (default: its episodes'
    metadata); ``fusion``: the posterior's config (default: the estimator node's own,
    ``load_fusion_config('')``). ValueError if no pair can be formed."""
    from pinn_estimator import forecast as fc
    from pinn_estimator.dataset import Dataset
    from pinn_estimator.evaluate import fused_posteriors
    from pinn_estimator.fusion_calibration import load_fusion_config
    from soil_sim_node.rollout import run_episodes
    from soil_sim_node.simulator import SimConfig

    live = [s.episode for s in scores]
    worlds = {ep.meta.world_mode for ep in live}
    world = world or (worlds.pop() if len(worlds) == 1 else None)
    if world is None:
        raise ValueError(f"the live episodes' worlds differ ({sorted(worlds)}): name the world to simulate")
    specs = reference_specs([ep.meta for ep in live], depths_m)
    if not specs:
        raise ValueError(f"no other depth to forecast: the live episodes cut at {sorted({ep.meta.target_depth_m for ep in live})} m")
    by_duration: dict[float, list] = {}
    for spec in specs:  # the simulator batches episodes of one length
        by_duration.setdefault(spec.duration_s, []).append(spec)
    others = [ep for group in by_duration.values() for ep in run_episodes(SimConfig(world_mode=world), group)]
    ds = Dataset.from_episodes(live + others, root="(the demo's live episodes and the simulator at other depths)")
    cfg = fusion if fusion is not None else load_fusion_config("")
    parts = fc.steady_parts(ds)
    n_live = len(live)
    posteriors = {"fused": fused_posteriors(Dataset.from_episodes(live), cfg) + [None] * len(others)}
    nan = {p: math.nan for p in ("phi", "c", "delta")}
    thetas = {"pinn": [steady_pinn_estimate(s) for s in scores] + [nan] * len(others)}
    pairs = fc.forecast_pairs(parts, thetas, posteriors, sources=range(n_live))
    if not pairs:
        raise ValueError("no live episode has a steady part to forecast from, or no other depth differs enough")
    terms = {"fused": [[n, float(k)] for n, k in cfg.terms]} if cfg.terms else {}
    return {"world": world, "depths_m": [float(d) for d in depths_m], "live_episodes": n_live,
            "simulated_episodes": len(others), "pairs": len(pairs), "physics": terms,
            "forecast": fc.summarise(pairs, ESTIMATORS)}


def markdown_lines(report: dict) -> list[str]:
    """The report as Markdown: one row per estimator."""
    from pinn_estimator.forecast import label_of

    depths = " and ".join(f"{d:g}" for d in report["depths_m"])
    lines = [f"The planner's question: from each live episode, the force at another depth of the same soil "
             f"({report['pairs']} forecasts to the simulator's episodes at {depths} m, same soil, density, speed and "
             f"seed; the steady half of each). Mean |error| and signed bias, % of the measured force.", "",
             "| estimator | F_x error | F_x bias deeper | F_x bias shallower | F_z error | 90 % / 50 % intervals hold F_x |",
             "|---|---|---|---|---|---|"]
    for name, axes in report["forecast"].items():
        x, z = axes["x"]["all"], axes["z"]["all"]
        cover = f"{x['coverage_90']:.0%} / {x['coverage_50']:.0%}" if "coverage_90" in x else "–"
        lines.append(f"| {label_of(report, name)} | {x['mean_abs_pct']:.1f} % | {axes['x']['deeper']['bias_pct']:+.1f} % | "
                     f"{axes['x']['shallower']['bias_pct']:+.1f} % | {z['mean_abs_pct']:.1f} % | {cover} |")
    return lines
