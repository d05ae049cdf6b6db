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
stalls a machine); where none does, the forecast law (``choose_bound_law`` says why). It is
written into the fusion config (``bound_abs_std_n``, ``bound_rel_std``), which the estimator
says to the planner (/soil/estimator/physics) and the cut trials read; the planner uses it where
its bound is anchored.
"""
from __future__ import annotations

import argparse
import dataclasses
import sys

import numpy as np

from pinn_estimator import forecast as fc
from pinn_estimator.fusion import fused_values
from pinn_estimator.fusion_config import FusionConfig
from pinn_estimator.fusion_calibration import (CALIBRATED_FIELDS, CAL_DURATION_S, FLOOR_GRID, FORECAST_GRID,
                                               add_plugin_option, add_soil_options, calibration_episodes,
                                               check_duration_option, checked_world_options, config_path,
                                               kept_plugins, kept_soils, term_note, world_note)
from soil_msgs_py.cli_paths import output_file
from soil_msgs_py.episode import WORLD_MODES
from soil_msgs_py.topics import FUSED_FIELDS

from soil_physics.predictive import error_law_text
from soil_msgs_py.interrupts import interruptible

from .planner import DEFAULT_FORCE_QUANTILE, check_quantile, fused_upper_force, steady_cut_terms


ANCHORS = ("measured", "measured_with_se", None)  # what ``anchored_bounds`` may anchor the bound to


def anchored_bounds(ds, cfg: FusionConfig, posts, laws, quantile: float | None = None, anchor: str | None = "measured",
                    deeper_only: bool = True) -> dict:
    """The planner's bound on the pairs of ``ds`` (``planner.fused_upper_force``: the ``quantile``
    upper bound of |F| from the published moments of the source's posterior under ``cfg``, at the
    target's steady Θ_k and speed) under each law of ``laws`` ((abs_x, abs_z, rel_x, rel_z) each,
    or None: the published law), ``anchor``ed as the planner is to the source's measured steady
    force ("measured"), the same with that force's standard error carried ("measured_with_se"), or
    not (None); on the pairs going deeper only (``deeper_only``) or every pair. Returns
    ``measured`` (pairs, 2) |F| [N], ``bounds`` (laws, pairs, 2) [N] and ``reach`` (pairs,), the
    target's depth over the source's; a pair without a bound under some law (no failure wedge: a
    plan would refuse the estimate) is left out."""
    if anchor not in ANCHORS:
        raise ValueError(f"anchor={anchor!r} must be one of {ANCHORS}")
    quantile = DEFAULT_FORCE_QUANTILE if quantile is None else quantile
    parts = fc.steady_parts(ds)
    terms = steady_cut_terms(cfg.terms)[0]
    measured, bounds, reach = [], [], []
    for a, b in fc.pair_indices(parts):
        src, dst = parts[a], parts[b]
        if not posts[a].updates or (deeper_only and dst.known["d"] <= src.known["d"]):
            continue
        est = dict(zip(FUSED_FIELDS, fused_values(posts[a].summary(), cfg)))
        at = {"measured": (tuple(src.force), src.known),
              "measured_with_se": (tuple(src.force), src.known, tuple(src.force_se)), None: None}[anchor]
        try:
            row = [np.concatenate(fused_upper_force(est, dst.known, [dst.known["d"]], quantile=quantile,
                                                    cut_speed_m_s=dst.known["v_x"], anchor=at, terms=terms,
                                                    bound_law=law)) for law in laws]
        except ValueError:
            continue
        measured.append(np.abs(dst.force))
        bounds.append(row)
        reach.append(dst.known["d"] / src.known["d"])
    return {"measured": np.array(measured, float).reshape(-1, 2),
            "bounds": np.array(bounds, float).reshape(len(measured), len(laws), 2).transpose(1, 0, 2),
            "reach": np.array(reach, float)}


def choose_bound_law(ds, cfg: FusionConfig, posts, forecast_grid=FORECAST_GRID, floor_grid=FLOOR_GRID,
                     log=print, quantile: float = DEFAULT_FORCE_QUANTILE) -> tuple[FusionConfig, list[dict]]:
    """``cfg`` with the planner's bound law (``FusionConfig.bound_abs_std_n``,
    ``bound_rel_std``) per axis: of the laws (share and floor on the grids) whose anchored bound
    at the quantile q (the planner's default; a planner set to another quantile uses the same
    law) is exceeded by the measured force in at most 1 − q of the calibration pairs going deeper
    (where exceeding it stalls a machine), the sharpest (lowest mean bound). Where none is, the
    axis keeps ``cfg``'s forecast law: misses that no width on the grid brings to nominal are not
    a matter of width (the default world's z: 17-18 % exceeded from 300 N to 1 kN whatever the
    share, 7 % only at 3 kN + 2|ΔF|, a bound of 22 kN on average, the lift's push on a held edge
    in both the source's anchor and the target's force), and a law that wide made the live
    plan in dense gravel cycle (2 falls of the target, ±3.7 cm, where the forecast law's z
    settles). On every pair going deeper, from the shallow cuts too: a plan is made from 5 cm on.
    ``posts``: ``cfg``'s posteriors of ``ds``. ValueError if no pair goes deeper."""
    grid = [(floor, frel) for floor in floor_grid for frel in forecast_grid]
    found = anchored_bounds(ds, cfg, posts, [(f, f, r, r) for f, r in grid], quantile)
    measured, bounds = found["measured"], found["bounds"]
    if not len(measured):
        raise ValueError("no calibration pair goes deeper with a fused posterior and a failure wedge: nothing to "
                         "calibrate the bound on")
    rows, best = [], []
    for (floor, frel), bound in zip(grid, bounds):
        exceeded = (measured > bound).mean(axis=0)
        rows.append({"floor": floor, "rel": frel, "exceeded": exceeded, "mean_bound": bound.mean(axis=0)})
        log(f"  bound law {floor:g} N + {frel:g}|ΔF|: the {quantile:.0%} bound exceeded in F_x "
            f"{exceeded[0]:.0%} / F_z {exceeded[1]:.0%} of {len(measured)} pairs going deeper, mean bound "
            f"{bound[:, 0].mean():.0f} / {bound[:, 1].mean():.0f} N")
    allowed = 1.0 - quantile
    said = []
    for j, axis in enumerate("xz"):
        held = [r for r in rows if r["exceeded"][j] <= allowed + 1e-12]
        if held:
            r = min(held, key=lambda r, j=j: r["mean_bound"][j])
            best.append((r["floor"], r["rel"]))
            said.append(f"{axis} {r['floor']:g} N + {r['rel']:g}|ΔF| (exceeded in {r['exceeded'][j]:.0%})")
        else:
            best.append((cfg.forecast_abs_std_n[j], cfg.forecast_rel_std[j]))
            least = min(r["exceeded"][j] for r in rows)
            said.append(f"{axis} the forecast law {best[-1][0]:g} N + {best[-1][1]:g}|ΔF| (no law on the grid holds "
                        f"{allowed:.0%}: {least:.0%} at best)")
    chosen = dataclasses.replace(cfg, bound_abs_std_n=(best[0][0], best[1][0]), bound_rel_std=(best[0][1], best[1][1]))
    log(f"bound law: {', '.join(said)} of {len(measured)} pairs going deeper")
    return chosen, rows


def calibrated_fields(cfg: FusionConfig) -> list[str]:
    """The laws ``pinn_fusion_calibrate`` chooses that ``cfg`` sets away from their defaults (a file
    ``FusionConfig.save`` writes lists every field, its defaults too)."""
    default = FusionConfig()
    return [f for f in CALIBRATED_FIELDS if not f.startswith("bound_") and getattr(cfg, f) != getattr(default, f)]


@interruptible("soil_planner_calibrate")
def main(argv=None) -> int:
    from pinn_estimator.evaluate import fused_posteriors  # (the simulator and torch: here only)

    p = argparse.ArgumentParser(prog="soil_planner_calibrate", description=__doc__.split("\n\n")[0])
    p.add_argument("--world", choices=WORLD_MODES, required=True)
    p.add_argument("--config", type=output_file, default=None,
                   help="the fusion config to calibrate the bound law for and write it into (default: the shipped "
                        "models/fusion_<world>.json of pinn_estimator, replaced)")
    p.add_argument("--duration", type=float, default=CAL_DURATION_S,
                   help="calibration episode length [s], as pinn_fusion_calibrate's (default %g; shorter is a quick "
                        "check: its law comes out too sharp)" % CAL_DURATION_S)
    p.add_argument("--force-noise", action="store_true",
                   help="calibration episodes with the measured force's noise on, as pinn_fusion_calibrate "
                        "--force-noise made the config's posterior; needs --config")
    add_plugin_option(p, "--config")
    add_soil_options(p)
    p.add_argument("--quantile", type=float, default=DEFAULT_FORCE_QUANTILE,
                   help=f"the planner's force quantile the law is calibrated at, [0.5, 1) (default "
                        f"{DEFAULT_FORCE_QUANTILE:g}, the planner's default)")
    args = p.parse_args(argv)
    try:
        check_quantile(args.quantile)
    except ValueError as err:
        p.error(f"--quantile: {err}")
    checked_world_options(p, args, "--config", args.config)
    check_duration_option(p, args.duration)
    path = args.config or config_path(args.world)
    try:
        cfg = FusionConfig.load(path)
    except (OSError, ValueError) as err:
        p.error(f"--config: {path}: {err}")
    try:
        note = world_note(cfg, path, args.world)
    except ValueError as err:
        p.error(f"--config: {err}, and a bound law from the {args.world} world's episodes would not hold there")
    if note:
        print(f"soil_planner_calibrate: {note}" + ("" if calibrated_fields(cfg) else " (it sets none of the laws "
              "pinn_fusion_calibrate chooses away from its default)"), file=sys.stderr)
    kept_plugins(p, args, cfg, path)  # (the bound is calibrated on the world the posterior's laws are of)
    kept_soils(p, args, cfg, path)  # (and on its soils)
    term_note(p.prog, args.world, cfg.terms, args.plugin)
    if left_out := steady_cut_terms(cfg.terms)[1]:  # (as the planner node and soil_cut_report say it)
        print(f"soil_planner_calibrate: note: the bound is calibrated without {', '.join(left_out)} (on the travel or "
              "time in soil, which a planned steady cut does not have), as the planner plans", file=sys.stderr)
    ds = calibration_episodes(p, args)
    try:
        cfg, _ = choose_bound_law(ds, cfg, fused_posteriors(ds, cfg), quantile=args.quantile)
    except ValueError as err:
        print(f"soil_planner_calibrate: error: {err}", file=sys.stderr)
        return 2
    cfg.save(path)
    print(f"wrote {path}: the planner's bound law {error_law_text(cfg.planner_bound_law())}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
