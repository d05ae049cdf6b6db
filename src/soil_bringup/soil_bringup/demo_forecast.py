"""The planner's question on the main job's own run: from the soil learnt while cutting each live
episode at one depth, what force will the blade meet at another depth in the same soil?

The live episodes cut at one depth. The simulator (in this process, lockstep, no ROS) cuts the
same soil, density, speed and seed at ``OTHER_DEPTHS_M``; ``pinn_estimator.forecast`` scores the
forecasts from each live episode to each of those against the force measured there: the fused
posterior the estimator held at the episode's end (rebuilt from the episode's bag with the
estimator's config and its checkpoint's physics, ``config_for_model``, which gives the live
values), the PINN's live estimates averaged over the episode's steady part (through its own
physics), and the two references (the FEE with the true parameters, and "the force now"). Truth
is read for scoring only.
"""
from __future__ import annotations

import math

import numpy as np

from soil_msgs_py.params import DEFAULT_TARGET_DEPTH_M, LIFT_REACH_M, MIN_PLANNED_DEPTH_M

# From a live cut at d, the forecasts go to d / 2 and 1.25 d (the default 0.2 m cut: 0.1 and 0.25 m):
# one shallower, one deeper, within the forecast's calibrated reach (pairs at most ~2.5x apart; the
# intervals are not to be trusted from cuts shallower than ~7 cm or far deeper than the evidence).
OTHER_DEPTH_FACTORS = (0.5, 1.25)
ESTIMATORS = ("fused", "pinn")


def other_depths(live_depth_m: float) -> tuple[float, ...]:
    """The depths [m] the demo forecasts to from live cuts at ``live_depth_m``: ``OTHER_DEPTH_FACTORS``
    of the depth cut to the millimetre, within [MIN_PLANNED_DEPTH_M, LIFT_REACH_M], the depth cut
    itself left out. Within the lift's reach on level ground the simulator cuts at the depth asked
    there; a deeper target is cut at about the reach (its first metres), so the factors start from it."""
    cut = min(live_depth_m, LIFT_REACH_M)
    depths = sorted({round(min(max(f * cut, MIN_PLANNED_DEPTH_M), LIFT_REACH_M), 3) for f in OTHER_DEPTH_FACTORS})
    return tuple(d for d in depths if abs(d - cut) > 5e-4)


OTHER_DEPTHS_M = other_depths(DEFAULT_TARGET_DEPTH_M)


def depths_text(depths_m=OTHER_DEPTHS_M) -> str:
    """'0.1 and 0.25': the other depths as the console, the help and the summary say them [m]."""
    return " and ".join(f"{d:g}" for d in depths_m)


def reference_specs(metas, depths_m=OTHER_DEPTHS_M) -> list:
    """One EpisodeSpec per live episode's metadata and other depth (the same soil, density, speed,
    seed and length; a one-soil path only)."""
    from soil_sim_node.simulator import EpisodeSpec

    return [EpisodeSpec(m.soil, m.relative_density_pct, m.target_speed_m_s, d, seed=m.seed, duration_s=m.duration_s)
            for m in metas for d in depths_m if abs(d - m.target_depth_m) > 1e-9]


def steady_pinn_estimates(live_ds, scores) -> list[dict[str, float]]:
    """Per live episode, the PINN's φ, c, δ [SI] averaged over its valid live estimates (those of
    ``scores``, ``scoring.EpisodeScore``, in the order of ``live_ds``) stamped in its steady part
    (``forecast.steady_estimates``); NaN where none."""
    from pinn_estimator import forecast as fc

    from .estimate_columns import ESTIMATE_COLUMN

    ends = np.concatenate([live_ds.offsets[e] + s.rows for e, s in enumerate(scores)]).astype(np.int64)
    values = np.concatenate([s.estimates for s in scores])
    return fc.steady_estimates(live_ds, ends, {p: values[:, ESTIMATE_COLUMN[p]] for p in ("phi", "c", "delta")})


def forecast_from_live(scores, world: str | None = None, depths_m=OTHER_DEPTHS_M, checkpoint=None,
                       fusion_config: str = "", custom_soils: dict | None = None) -> dict:
    """The forecast report (``pinn_estimator.forecast.summarise`` per estimator and axis: error,
    bias deeper / shallower, interval coverage) from the live episodes of ``scores`` to the
    simulator's episodes at ``depths_m``. ``world``: the live run's (default: its episodes'
    metadata); ``checkpoint``: the estimator's (default: the shipped one) and ``fusion_config``
    its parameter of that name (default: the shipped calibration of the checkpoint's world), as the live estimator read
    them; ``custom_soils``: the soils of the live run's soils file by name (``load_soil_file``), which its
    episodes may name. ValueError if no pair can be formed."""
    from pinn_estimator import forecast as fc
    from pinn_estimator.checkpoint import DEFAULT_CHECKPOINT, load_model
    from pinn_estimator.dataset import Dataset
    from pinn_estimator.evaluate import fused_posteriors
    from pinn_estimator.fusion_calibration import config_for_model, estimator_fusion
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
    others = [ep for group in by_duration.values() for ep in run_episodes(SimConfig(world_mode=world), group,
                                                                                custom_soils=custom_soils)]
    ds = Dataset.from_episodes(live + others, root="(the demo's live episodes and the simulator at other depths)")
    live_ds = Dataset.from_episodes(live)
    model, ckpt = load_model(str(checkpoint or DEFAULT_CHECKPOINT))
    cfg = config_for_model(estimator_fusion(fusion_config, ckpt)[0], model)  # as the estimator node builds it
    pinn_terms = tuple(model.cfg.extra_terms)
    parts = fc.steady_parts(ds)
    n_live = len(live)
    posteriors = {"fused": fused_posteriors(live_ds, cfg) + [None] * len(others)}
    nan = {p: math.nan for p in ("phi", "c", "delta")}
    thetas = {"pinn": steady_pinn_estimates(live_ds, scores) + [nan] * len(others)}
    pairs = fc.forecast_pairs(parts, thetas, posteriors, terms={"pinn": pinn_terms}, sources=range(n_live))
    if not pairs:
        raise ValueError("no live episode has a steady part to forecast from, or no other depth differs enough")
    physics = {name: [[n, float(k)] for n, k in t] for name, t in (("fused", cfg.terms), ("pinn", pinn_terms)) if t}
    # what was not paired, said under the table as pinn_eval says it (a summary read "10 forecasts" where 12 were
    # possible): episodes (live or simulated) without a steady part, and live-to-other pairs at one depth
    return json_ready({"world": world, "depths_m": [float(d) for d in depths_m], "live_episodes": n_live,
                       "simulated_episodes": len(others), "pairs": len(pairs), "physics": physics,
                       "no_steady_part": sum(p is None for p in parts),
                       "same_depth_pairs": fc.same_depth_pairs(parts, sources=range(n_live)),
                       "forecast": fc.summarise(pairs, ESTIMATORS),
                       # where the posterior's forecast law was calibrated and not (the live cut's speed and
                       # the other depths may lie outside it), as pinn_eval's report says it
                       "calibration_strata": fc.calibration_strata(pairs, ["fused"]),
                       # within the planner's margin and beyond it, where the controller's lift at the limit sets F_z
                       "margin_strata": fc.margin_strata(pairs, ["fused"])})


def json_ready(value):
    """``value`` with every non-finite float as None (strict JSON: a direction with no pair has no bias)."""
    if isinstance(value, dict):
        return {k: json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_ready(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def markdown_lines(report: dict) -> list[str]:
    """The report as Markdown (``pinn_estimator.forecast.markdown``'s table, this run's sentence)."""
    from pinn_estimator.forecast import markdown

    return markdown(report, intro=(
        f"The planner's question: from each live episode, the force at another depth of the same soil "
        f"({report['pairs']} forecasts to the simulator's episodes at {depths_text(report['depths_m'])} m, same soil, density, speed and seed; "
        "the steady part of each: its second half where the blade holds its depth). Mean |error| and signed bias, % of the measured force."))
