"""Calibrating the bound a plan keeps within the limits (``soil_planner_calibrate``).

The planner keeps the ``force_quantile`` upper bound of |F| within the machine's limits
(``planner._FusedForceModel``): the fused posterior's forces at the planned depth, anchored to
the force measured now and scaled by each sample's depth ratio, widened by an error law
σ = abs + rel·|ΔF|. That bound is another forecast than the posterior's own intervals, whose law
``pinn_fusion_calibrate`` calibrates (the default world: the law that makes those intervals hold
let this bound be exceeded in 28 % of the calibration pairs going deeper). So its law is
calibrated here, apart, on the estimator's calibration episodes and posteriors: per axis, of the
laws on ``pinn_fusion_calibrate``'s grids, the sharpest whose bound at the planner's default
quantile the measured force exceeds in at most 1 − q of the pairs going deeper (exceeding it there
stalls a machine); where none does, the least exceeded. It is written into the fusion config
(``bound_abs_std_n``, ``bound_rel_std``), which ``soil_launch --planner`` and the cut trials read.
"""
from __future__ import annotations

import argparse
import dataclasses
import sys

import numpy as np

from pinn_estimator import forecast as fc
from pinn_estimator.fusion import FusionConfig, fused_values
from pinn_estimator.fusion_calibration import (CAL_DENSITIES_PCT, CAL_DEPTHS_M, CAL_DURATION_RANGE_S, CAL_SEED,
                                               FLOOR_GRID, FORECAST_GRID, config_path)
from soil_msgs_py.cli_paths import output_file
from soil_msgs_py.episode import WORLD_MODES
from soil_msgs_py.topics import FUSED_FIELDS

from .planner import DEFAULT_FORCE_QUANTILE, fused_upper_force, steady_cut_terms


def anchored_bounds(ds, cfg: FusionConfig, posts, laws, quantile: float | None = None) -> dict:
    """The planner's bound on every pair of ``ds`` going deeper (``planner.fused_upper_force``:
    the ``quantile`` upper bound of |F| from the published moments of the source's posterior under
    ``cfg``, anchored to the source's measured steady force, at the target's steady Θ_k and speed),
    under each law of ``laws`` ((abs_x, abs_z, rel_x, rel_z) each). Returns ``measured`` (pairs, 2)
    |F| [N] and ``bounds`` (laws, pairs, 2) [N]; a pair without a bound under some law (no failure
    wedge) is left out."""
    quantile = DEFAULT_FORCE_QUANTILE if quantile is None else quantile
    parts = fc.steady_parts(ds)
    terms = steady_cut_terms(cfg.terms)[0]
    measured, bounds = [], []
    for a, b in fc.pair_indices(parts):
        src, dst = parts[a], parts[b]
        if not posts[a].updates or dst.known["d"] <= src.known["d"]:
            continue
        est = dict(zip(FUSED_FIELDS, fused_values(posts[a].summary(), cfg)))
        try:
            row = [np.concatenate(fused_upper_force(est, dst.known, [dst.known["d"]], quantile=quantile,
                                                    cut_speed_m_s=dst.known["v_x"], anchor=(tuple(src.force), src.known),
                                                    terms=terms, bound_law=law)) for law in laws]
        except ValueError:
            continue  # no bound (no failure wedge): a plan would refuse this estimate
        measured.append(np.abs(dst.force))
        bounds.append(row)
    return {"measured": np.array(measured, float).reshape(-1, 2),
            "bounds": np.array(bounds, float).reshape(len(measured), len(laws), 2).transpose(1, 0, 2)}


def choose_bound_law(ds, cfg: FusionConfig, posts, forecast_grid=FORECAST_GRID, floor_grid=FLOOR_GRID,
                     log=print) -> tuple[FusionConfig, list[dict]]:
    """``cfg`` with the planner's bound law (``FusionConfig.bound_abs_std_n``,
    ``bound_rel_std``) per axis: of the laws (share and floor on the grids) whose anchored bound
    at the planner's default quantile q is exceeded by the measured force in at most 1 − q of
    the calibration pairs going deeper (where exceeding it stalls a machine), the sharpest
    (lowest mean bound); where none is, the least exceeded. On every pair, the shallow ones too: a
    plan is made from 5 cm on. ``posts``: ``cfg``'s posteriors of ``ds``."""
    grid = [(floor, frel) for floor in floor_grid for frel in forecast_grid]
    found = anchored_bounds(ds, cfg, posts, [(f, f, r, r) for f, r in grid])
    measured, bounds = found["measured"], found["bounds"]
    rows, best = [], []
    for (floor, frel), bound in zip(grid, bounds):
        exceeded = (measured > bound).mean(axis=0) if len(measured) else np.full(2, np.nan)
        rows.append({"floor": floor, "rel": frel, "exceeded": exceeded, "mean_bound": bound.mean(axis=0)})
        log(f"  bound law {floor:g} N + {frel:g}|ΔF|: the {DEFAULT_FORCE_QUANTILE:.0%} bound exceeded in F_x "
            f"{exceeded[0]:.0%} / F_z {exceeded[1]:.0%} of {len(measured)} pairs going deeper, mean bound "
            f"{bound[:, 0].mean():.0f} / {bound[:, 1].mean():.0f} N")
    allowed = 1.0 - DEFAULT_FORCE_QUANTILE
    for j in range(2):
        held = [r for r in rows if r["exceeded"][j] <= allowed + 1e-12]
        best.append(min(held, key=lambda r, j=j: r["mean_bound"][j]) if held
                    else min(rows, key=lambda r, j=j: (r["exceeded"][j], r["mean_bound"][j])))
    chosen = dataclasses.replace(cfg, bound_abs_std_n=(best[0]["floor"], best[1]["floor"]),
                                 bound_rel_std=(best[0]["rel"], best[1]["rel"]))
    log(f"bound law: x {best[0]['floor']:g} N + {best[0]['rel']:g}|ΔF| (exceeded in {best[0]['exceeded'][0]:.0%}), "
        f"z {best[1]['floor']:g} N + {best[1]['rel']:g}|ΔF| (exceeded in {best[1]['exceeded'][1]:.0%}) of "
        f"{len(measured)} pairs going deeper")
    return chosen, rows


def main(argv=None) -> int:
    from pinn_estimator.evaluate import forecast_dataset, fused_posteriors  # (the simulator and torch: here only)

    p = argparse.ArgumentParser(prog="soil_planner_calibrate", description=__doc__.split("\n\n")[0])
    p.add_argument("--world", choices=WORLD_MODES, required=True)
    p.add_argument("--config", type=output_file, default=None,
                   help="the fusion config to calibrate the bound law for and write it into (default: the shipped "
                        "models/fusion_<world>.json of pinn_estimator, replaced)")
    p.add_argument("--duration", type=float, default=10.0,
                   help="calibration episode length [s], as pinn_fusion_calibrate's (default 10)")
    args = p.parse_args(argv)
    lo, hi = CAL_DURATION_RANGE_S
    if not lo <= args.duration <= hi:  # NaN too
        p.error(f"--duration={args.duration} s must be in [{lo:g}, {hi:g}] s (its second half holds the steady cut)")
    path = args.config or config_path(args.world)
    try:
        cfg = FusionConfig.load(path)
    except (OSError, ValueError) as err:
        p.error(f"--config: {path}: {err}")
    ds = forecast_dataset(args.world, seed=CAL_SEED, duration_s=args.duration, densities_pct=CAL_DENSITIES_PCT,
                          depths_m=CAL_DEPTHS_M)
    cfg, _ = choose_bound_law(ds, cfg, fused_posteriors(ds, cfg))
    cfg.save(path)
    law = cfg.planner_bound_law()
    print(f"wrote {path}: the planner's bound law x {law[0]:g} N + {law[2]:g}|ΔF|, z {law[1]:g} N + {law[3]:g}|ΔF|")
    return 0


if __name__ == "__main__":
    sys.exit(main())
