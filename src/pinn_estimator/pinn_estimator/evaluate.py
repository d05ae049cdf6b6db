"""`pinn_eval`: the paper §3.2 report on a checkpoint's test split, with the baselines beside it.

On the same test windows (episodes the model never saw in training or validation):
* the PINN: F̂ = F_FEE + F_r, its FEE part alone, and Θ̂_u;
* a physics-free network of the same size predicting F directly (``--physics-free``);
* the classical estimator (after Tan et al. 2005): a least-squares fit of φ, c, δ (β = β*) of
  the FEE to each window's measured forces, with the same known parameters.
Reports mean |F - F̂| [N] / % of measured / % of machine limits (x, z, magnitude); parameter
errors against the pseudo-ground truth; per soil x I_d mean ± std of φ̂, ĉ, δ̂, β̂ (Figs. 5-6
analogs); the failure force at d = 0.1 m, Q = 0 from mean estimated vs true parameters; the
issue's targets, met or not; and the planner's question (``forecast``): from the estimates
made at one depth, the force at another depth of the same soil, on held-out episodes the
simulator runs at densities and depths off the training grid, or on the user's own bags
(``--forecast-data``). JSON + Markdown + PNG.
Ground truth is used only to score.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
from scipy.stats import spearmanr

from soil_physics import fee
from soil_msgs_py.process_pool import WorkerDied
from soil_msgs_py import cli_numbers, strict_json
from soil_msgs_py import markdown_table as md
from soil_msgs_py.cli_paths import (file_stem, input_text, output_dir, refuse_directories, save_figure_atomically,
                                   write_text_atomically)
from soil_msgs_py.episode import WORLD_MODES, world_modes
from soil_msgs_py.soil_labels import GAMMA_GROUP_RTOL, unlabelled_count
from soil_msgs_py.params import DEG, GROUND_TRUTH_PARAMS, KNOWN_PARAMS, OBSERVATION_FIELDS, SAMPLE_RATE_HZ, WINDOW_SAMPLES
from soil_physics.soils import COHESIVE_SOILS, ID_LIMIT_PCT
from soil_msgs_py.interrupts import interruptible

from .checkpoint import load_model, trained_worlds, world_mismatch, world_mismatch_lines
from . import forecast as fc
from .dataset import MAX_WINDOW_STRIDE, Dataset, add_skip_bad_bags_option, describe, load_dataset
from .fusion import SoilPosterior, fuse_episode
from .fusion_config import FusionConfig
from .inference import WindowTensors, force_errors, predict
from .shipped import DEFAULT_WORLD

PARAMS = ("phi", "c", "delta", "beta")
UNITS = {"phi": ("deg", 1 / DEG), "c": ("kPa", 1e-3), "delta": ("deg", 1 / DEG), "beta": ("deg", 1 / DEG)}
TRUTH_COL = {p: GROUND_TRUTH_PARAMS.index(p) for p in PARAMS}
FAILURE_DEPTH_M = 0.1  # §3.2: hypothetical failure force at d = 0.1 m, Q = 0
FAILURE_SPEED_M_S = 0.5  # forward, blade level: full soil-tool friction (Eq. 10 scale ~ 1)
TEST_STRIDE = 10  # samples between the test split's windows (1/6 s)


def _windows(ends: np.ndarray, arr: np.ndarray) -> np.ndarray:
    """(W, T, k) windows of per-row ``arr`` ending at global rows ``ends``."""
    return arr[ends[:, None] + np.arange(-(WINDOW_SAMPLES - 1), 1)]


def parameter_errors(est: dict[str, np.ndarray], truth: np.ndarray, mask: np.ndarray) -> dict[str, float]:
    """Mean absolute error of each estimated parameter, in report units (deg, kPa)."""
    out = {}
    for p in PARAMS:
        if p not in est:
            continue
        unit, k = UNITS[p]
        err = np.abs(est[p][mask] - truth[mask, TRUTH_COL[p]]) * k
        out[f"{p}_mae_{unit}"] = float(np.nanmean(err)) if np.isfinite(err).any() else float("nan")
    return out


def failure_force(phi, c, delta, beta, known_mean: dict) -> float:
    """|F| [N] of the FEE at d = 0.1 m, Q = 0, v = 0.5 m/s forward, for one parameter set."""
    theta = dict(known_mean, phi=phi, c=c, delta=delta, d=FAILURE_DEPTH_M, q=0.0, v_x=FAILURE_SPEED_M_S, v_z=0.0)
    _, _, force = fee.fee_xz(theta, beta=beta)
    return float(force)


def window_soils(ds, ends: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """(soil name, I_d [%]) of the windows ending at rows ``ends``, and how many of their episodes
    change soil along the path: the soil under the edge at the window's end (an episode's patches),
    else its metadata's. Why: an episode of Sand 20 % then Silty Clay 80 % was tabled as "Sand 20"
    with the clay's windows in it, its "truth" the mean of both soils (a sand of c 4.3 kPa)."""
    from soil_msgs_py.patches import patch_under

    episode = ds.episode_of_rows(ends)
    soil = np.array([ds.metas[e].soil for e in episode], dtype=object)
    i_d = np.array([float(ds.metas[e].relative_density_pct) for e in episode])
    changing = 0
    for e in np.unique(episode):
        patches = ds.metas[e].soil_patches()
        if len({(p.soil, p.relative_density_pct) for p in patches}) > 1:
            mine = episode == e
            under = patch_under(patches, ds.observations[ends[mine], OBSERVATION_FIELDS.index("p_x_b")])
            soil[mine] = [patches[j].soil for j in under]
            i_d[mine] = [patches[j].relative_density_pct for j in under]
            changing += len({(patches[j].soil, patches[j].relative_density_pct) for j in under}) > 1  # (where its windows are)
    return soil, i_d, changing


def _group_table(ds, ends, truth, estimates: dict[str, dict[str, np.ndarray]]):
    """Per soil x I_d (``window_soils``): truth and each estimator's mean ± std, and failure forces."""
    soil, i_d, _ = window_soils(ds, ends)
    rows = []
    for s in sorted(set(soil)):
        for level in sorted(set(i_d[soil == s])):
            m = (soil == s) & (i_d == level)
            known_mean = {name: float(ds.known[ends[m], j].mean()) for j, name in enumerate(KNOWN_PARAMS)}
            t = {p: float(np.nanmean(truth[m, TRUTH_COL[p]])) for p in PARAMS}
            row = {"soil": s, "relative_density_pct": level, "windows": int(m.sum()), "truth": t,
                   "mean_depth_m": float(known_mean["d"]),
                   "failure_force_n": {"truth": failure_force(t["phi"], t["c"], truth[m, TRUTH_COL["delta"]].mean(), None, known_mean)}}
            for name, est in estimates.items():
                row[name] = {p: {"mean": float(np.nanmean(est[p][m])), "std": float(np.nanstd(est[p][m]))} for p in PARAMS if p in est}
                beta = row[name]["beta"]["mean"] if name == "pinn" else None  # the classical fit uses β* by construction
                row["failure_force_n"][name] = failure_force(*(row[name][p]["mean"] for p in ("phi", "c", "delta")), beta, known_mean)
            rows.append(row)
    return rows


def _trends(rows, estimator="pinn") -> dict:
    """Slope of φ̂ and ĉ against I_d per cohesive soil (paper Fig. 6: both rise with I_d): those
    with a true cohesion in their bags' ground truth (a soil of the user's YAML too), or named as
    the catalogue's cohesive soils where the bags hold no truth."""
    out = {}
    true_c: dict[str, list[float]] = {}
    for r in rows:
        c = float((r.get("truth") or {}).get("c", np.nan))
        true_c.setdefault(r["soil"], []).extend([c] if np.isfinite(c) else [])
    cohesive = {s for s, cs in true_c.items() if (max(cs) > 0 if cs else s in COHESIVE_SOILS)}
    for s in sorted(cohesive):
        mine = [r for r in rows if r["soil"] == s and estimator in r]
        if len(mine) < 2:
            continue
        x = np.array([r["relative_density_pct"] for r in mine])
        res = {}
        for p, unit, k in (("phi", "deg", 1 / DEG), ("c", "kPa", 1e-3)):
            y = np.array([r[estimator][p]["mean"] for r in mine]) * k
            slope = float(np.polyfit(x, y, 1)[0]) * 100
            rank = float(spearmanr(x, y).statistic)
            res[p] = {f"slope_{unit}_per_100pct": slope, "spearman": rank, "rises": bool(slope > 0 and rank > 0.5)}
        out[s] = res
    return out


def forecast_dataset(world: str, seed: int = 7000, duration_s: float = 10.0, densities_pct=fc.FORECAST_DENSITIES_PCT,
                     depths_m=fc.FORECAST_DEPTHS_M, force_noise: bool = False, soils=None,
                     custom_soils: dict | None = None, plugins=()) -> Dataset:
    """Held-out episodes for the forecast: every soil (``soils``: names, default the catalogue's; a
    soil of ``custom_soils`` too, a soils YAML's) at ``densities_pct`` x ``depths_m`` at
    ``fc.FORECAST_SPEED_M_S`` (by default all off the training grid), simulated here.
    ``force_noise``: the world's effects with the measured force's noise on (the default world's
    sensor noise in the fee world, where the FEE is exact and the truth known: calibration against
    truth with a noisy sensor, as a machine's is). ``plugins``: force plugins switched on in the
    simulator (``soil_sim_batch --plugin``'s specs): an effect the world lacks, e.g. one found in a
    machine's bags, for calibrating a posterior whose physics has its term."""
    import itertools

    from soil_physics.soils import CATALOGUE
    from soil_sim_node.effects import effects_for_mode
    from soil_sim_node.rollout import run_episodes
    from soil_sim_node.simulator import EpisodeSpec, SimConfig

    combos = itertools.product(sorted(CATALOGUE) if soils is None else list(soils), densities_pct, depths_m)
    specs = [EpisodeSpec(soil, i_d, fc.FORECAST_SPEED_M_S, d, seed=seed + k, duration_s=duration_s)
             for k, (soil, i_d, d) in enumerate(combos)]
    label = f"{world} world" + (", noisy force" if force_noise else "") + "".join(f", plugin {p}" for p in plugins)
    config = SimConfig(world_mode=world, effects=effects_for_mode(world, force_noise), plugins=tuple(plugins))
    return Dataset.from_episodes(run_episodes(config, specs, custom_soils=custom_soils),
                                 root=f"(simulated, {label})")


FORECAST_STRIDE = SAMPLE_RATE_HZ // 2  # samples between the steady windows a forecast averages (0.5 s)


def fused_posteriors(ds: Dataset, cfg: FusionConfig) -> list[SoilPosterior]:
    """Per episode of ``ds``, the fused posterior after all its samples (what the online
    estimator holds at the episode's end; blade travel in soil for models with distance terms)."""
    distance = ds.distance_in_soil()
    out = []
    for e in range(len(ds)):
        rows = ds.episode_rows(e)
        out.append(fuse_episode(SoilPosterior(cfg), ds.forces[rows], ds.known[rows], distance[rows],
                                ds.observations[rows], ds.gap_before[rows]))
    return out


def forecast(model, ds: Dataset, *, stride: int = FORECAST_STRIDE, classical: bool = True, workers: int = 2,
             progress: bool = False, fusion: FusionConfig | None = None, posteriors: list | None = None) -> dict:
    """``forecast.evaluate_forecast`` of ``ds`` with the PINN's and (``classical``) the least-squares
    fit's θ̂, and the fused posterior (``fusion``: its config, None: the default world's calibration;
    the model's catalogue terms are added; ``posteriors``: the episodes' ``fused_posteriors`` under
    that config when already made). The PINN's θ̂ forecasts through its own physics (the FEE plus
    the terms it was trained with); the least-squares fit's through the FEE."""
    ends = fc.steady_window_ends(ds, stride)
    if len(ends) == 0:  # (the PINN's output of no window has no θ: a KeyError, an outside tester's)
        raise ValueError(f"no episode of the {len(ds)} holds a steady second of cutting in its second half (a window "
                         "of 60 ticks in a row without a gap): nothing to forecast from")
    out = predict(model, WindowTensors(ds), ends)
    estimates = {"pinn": dict(zip(("phi", "c", "delta"), out["theta"][:, :3].T))}
    if classical:
        from .classical import fit_windows

        fit = fit_windows(_windows(ends, ds.known), _windows(ends, ds.forces), workers=workers, progress=progress)
        estimates["classical"] = {"phi": fit.phi, "c": fit.c, "delta": fit.delta}
    from .fusion_calibration import config_for_model

    fused = config_for_model(fusion, model)
    # the fused posterior forecasts through its own physics; its terms are passed only to be named
    posts = fused_posteriors(ds, fused) if posteriors is None else posteriors
    return fc.evaluate_forecast(ds, ends, estimates, {"fused": posts},
                                terms={"pinn": model.cfg.extra_terms, "fused": fused.terms})


def load_forecast_bags(root, *, workers: int = 1, progress: bool = False, skip_bad_bags: bool = False) -> Dataset:
    """The bags at ``root`` to judge the forecast at another depth on (e.g. a machine's own cuts of
    one soil at several depths); ValueError naming what is wrong if they hold no forecast pair or
    several worlds (the fused posterior's calibration is a world's)."""
    ds = load_dataset(root, workers=workers, progress=progress, skip_bad_bags=skip_bad_bags)
    worlds = world_modes(ds.metas)
    if len(worlds) > 1:
        raise ValueError(f"--forecast-data {root}: bags of several worlds {worlds}; the fused posterior is calibrated "
                         "per world: give one world's bags")
    parts = fc.steady_parts(ds)
    if next(fc.pair_indices(parts), None) is None:
        unsteady = sum(part is None and fc.episode_one_soil(ds, e) for e, part in enumerate(parts))
        changing = sum(not fc.episode_one_soil(ds, e) for e in range(len(ds)))
        depths = sorted(f"{part.known['d']:.3f}" for part in parts if part is not None)
        shown = ", ".join(depths[:8]) + (", ..." if len(depths) > 8 else "")
        split = sorted({part.soil for part in parts if part is not None and " (φ " in part.soil})
        raise ValueError(f"--forecast-data {root}: no two of its {len(ds)} episodes are one soil at one relative density "
                         f"(bags without a soil label: of one measured unit weight γ, within "
                         f"{100 * GAMMA_GROUP_RTOL:g} %) (and one soil along the path) cut at steady depths at least {fc.MIN_DEPTH_RATIO:g}x apart: "
                         f"nothing to forecast ({unsteady} of them hold no steady cut: less than {fc.MIN_STEADY_S:g} s of "
                         f"their second half in the soil with |v_z| <= {1e3 * fc.STEADY_MAX_ABS_V_Z_M_S:g} mm/s"
                         + (f"; {changing} change soil along the path (patches in their metadata): no one soil to "
                            "forecast from or to" if changing else "")
                         + (f"; the steady depths [m]: {shown}" if depths else "")
                         + (f"; labels naming two soils, told apart by their ground truth: {', '.join(split)}" if split else "")
                         + ")")
    return ds


def evaluate(checkpoint, data=None, *, physics_free=None, stride: int = TEST_STRIDE, classical: bool = True, workers: int = 2, progress: bool = False,
             skip_bad_bags: bool = False, forecast_world: str | None = "auto", forecast_data=None, forecast_only: bool = False,
             fusion_config: str | None = None, log=print) -> dict:
    """Build the report dict (see module docstring). ``forecast_data``: a bag directory the forecast
    at another depth is judged on instead of the simulated held-out episodes (``forecast_world``);
    ``forecast_only``: that forecast alone, without the test split (whose bags need not be here);
    ``fusion_config``: the fused posterior's config (default: the forecast world's shipped one)."""
    model, ckpt = load_model(checkpoint)
    if model.cfg.kind != "pinn":
        raise ValueError(f"checkpoint {checkpoint} is a {model.cfg.kind!r} model; pinn_eval needs the PINN first (baseline via --physics-free)")
    # read and checked before the test split's evaluation, so a bad directory costs nothing
    forecast_bags = None if forecast_data is None else load_forecast_bags(
        forecast_data, workers=workers, progress=progress, skip_bad_bags=skip_bad_bags)
    unlabelled = 0 if forecast_bags is None else unlabelled_count(forecast_bags.metas)
    if unlabelled:
        log(f"--forecast-data: {unlabelled} of its {len(forecast_bags)} episodes carry no soil label; they are paired "
            "by their measured unit weight γ (two soils of one γ would pair)")
    split = ckpt.get("split") or {}
    learnt = set(split.get("train") or []) | set(split.get("val") or [])
    seen = [n for n in (forecast_bags.names if forecast_bags is not None else []) if n in learnt]
    if seen:
        log(f"warning: --forecast-data: {len(seen)} of its {len(forecast_bags)} episodes have the names of episodes "
            f"{checkpoint} was trained or validated on (e.g. {seen[0]!r}): if they are those bags, its PINN's row is "
            "no held-out score (the fused posterior's and the classical fit's, which it does not feed, still are)")
    trained = trained_worlds(ckpt)
    judged = forecast_bags.metas[0].world_mode if forecast_bags is not None else forecast_world
    mismatch = {}  # said in the log and in the report, which outlives the log
    if text := world_mismatch(checkpoint, ckpt, judged, f"its forecast is judged on {judged}-world "
                              f"{'bags' if forecast_bags is not None else 'episodes'} (with that world's fusion config)"):
        mismatch["world_mismatch"] = text
        log(f"warning: {text}")
    from .fusion_calibration import checkpoint_world, given_fusion

    if fusion_config is not None:  # checked before anything runs; "auto" is the test split's world, the checkpoint's

        early = judged if judged in WORLD_MODES else (trained[0] if judged == "auto" and len(trained) == 1 else None)
        given_fusion(fusion_config, early)
    if forecast_only:
        return forecast_report(model, checkpoint, forecast_bags, forecast_world, classical=classical, workers=workers,
                               progress=progress, fusion_config=fusion_config, log=log,
                               model_world=checkpoint_world(ckpt)) | {"seen_in_training": len(seen)} | mismatch
    if data is None and not Path(ckpt["dataset"]["root"]).is_dir():
        raise ValueError(f"{checkpoint} was trained on the bags at {ckpt['dataset']['root']!r} (as given then, relative "
                         f"to where it was trained), which is not a directory here: give their directory with --data "
                         "(or --forecast-only, which needs no training bags)")
    ds = load_dataset(data or ckpt["dataset"]["root"], workers=workers, progress=progress, skip_bad_bags=skip_bad_bags)
    if ds.fingerprint != ckpt["dataset"]["fingerprint"]:
        log(f"warning: {differ_from_training(ds, ckpt)}; using its test split by episode name")
    test_names = ckpt["split"]["test"]
    if not test_names:
        raise ValueError(f"checkpoint {checkpoint} has an empty test split")
    test_idx = ds.index(test_names, fix="evaluate on the directory the model was trained from, or score its forecast "
                                        "at another depth on these bags with --forecast-only --forecast-data DIR")
    ends = ds.window_ends(test_idx, stride)
    tensors = WindowTensors(ds)
    measured = ds.forces[ends]
    truth = ds.truth[ends]
    # every test episode must carry it: without, its soil scores NaN and the means quietly leave it out
    blind = [ds.names[e] for e in test_idx if not np.isfinite(ds.truth[ds.episode_rows(e)]).any()]
    if blind:
        some = "the " if len(blind) == len(test_idx) else f"{len(blind)} of the {len(test_idx)} "
        raise ValueError(f"{some}test split bags under {ds.root} have no /soil/ground_truth (as from a machine): "
                         f"{', '.join(blind[:5])}{', ...' if len(blind) > 5 else ''}; this report scores the soil "
                         "parameters against it; --forecast-only --forecast-data DIR scores the forces, which need none")
    t0 = time.monotonic()
    out = predict(model, tensors, ends)
    timing = {"pinn_s": time.monotonic() - t0}
    pinn_est = dict(zip(("phi", "c", "delta", "beta"), out["theta"][:, :4].T))
    forces = {"pinn": force_errors(measured, out["force"]), "pinn_fee_part": force_errors(measured, out["force_fee"])}
    estimates = {"pinn": pinn_est}
    if physics_free:
        free, free_ckpt = load_model(physics_free)
        if free.cfg.kind != "physics_free":
            raise ValueError(f"--physics-free {physics_free} is a {free.cfg.kind!r} model")
        if free_ckpt["split"]["test"] != test_names:
            raise ValueError(f"--physics-free {physics_free} was trained on another split; train it with --split-from {checkpoint}")
        t0 = time.monotonic()
        forces["physics_free"] = force_errors(measured, predict(free, tensors, ends)["force"])
        timing["physics_free_s"] = time.monotonic() - t0
    if classical:
        from .classical import fit_windows

        t0 = time.monotonic()
        fit = fit_windows(_windows(ends, ds.known), _windows(ends, ds.forces), workers=workers, progress=progress)
        timing["classical_s"] = time.monotonic() - t0
        estimates["classical"] = {"phi": fit.phi, "c": fit.c, "delta": fit.delta, "beta": fit.beta}
        forces["classical"] = force_errors(measured, np.nan_to_num(fit.f_fee))
        forces["classical"]["fit_success_pct"] = float(100 * fit.success.mean())
    _, i_d, changing_soil = window_soils(ds, ends)
    masks = {"all": np.ones(len(ends), bool), f"id_le_{ID_LIMIT_PCT:.0f}": i_d <= ID_LIMIT_PCT}
    params = {name: {k: parameter_errors(est, truth, m) for k, m in masks.items()} for name, est in estimates.items()}
    rows = _group_table(ds, ends, truth, estimates)
    report = {
        "checkpoint": str(checkpoint),
        "physics_free_checkpoint": str(physics_free) if physics_free else None,
        "dataset": describe(ds),
        "world_modes": sorted({ds.metas[e].world_mode for e in test_idx}),
        "test_episodes": len(test_names),
        "windows": int(len(ends)),
        "window_stride": stride,
        "force": forces,
        "params": params,
        "per_soil_id": rows,
        "changing_soil_episodes": changing_soil,  # test episodes whose soil changes along the path (``window_soils``)
        "trends": {name: _trends(rows, name) for name in estimates},
        "training": {"pinn": ckpt["metrics"]},
        "timing_s": timing,
    }
    if physics_free:
        report["training"]["physics_free"] = free_ckpt["metrics"]
    if forecast_bags is None and forecast_world == "auto":
        forecast_world = report["world_modes"][0] if len(report["world_modes"]) == 1 else None
        if len(report["world_modes"]) > 1:  # the forecast's posterior is calibrated per world
            report["forecast_skipped"] = (f"the test split mixes worlds {report['world_modes']}; the forecast at "
                                          "another depth is judged in one world: give --forecast-world fee|default")
            log(f"warning: {report['forecast_skipped']}")
    if forecast_bags is not None:
        report["forecast_data"] = describe(forecast_bags)
    if forecast_bags is not None or forecast_world:
        t0 = time.monotonic()
        report["forecast"] = forecast_section(model, forecast_bags, forecast_world, classical=classical,
                                              workers=workers, progress=progress, fusion_config=fusion_config, log=log,
                                              model_world=checkpoint_world(ckpt))
        timing["forecast_s"] = time.monotonic() - t0
    report["targets"] = targets(report)
    return report | {"seen_in_training": len(seen)} | mismatch


def forecast_section(model, bags: Dataset | None, world: str | None, *, classical: bool = True, workers: int = 2,
                     progress: bool = False, fusion_config: str | None = None, log=print,
                     model_world: str = DEFAULT_WORLD) -> dict:
    """The forecast at another depth: on ``bags`` with their world's calibrated posterior (or the
    config at ``fusion_config``), or else on the simulated held-out episodes of ``world``. Bags of
    no simulator world (a machine's, ``world_mode`` "unknown") take the calibration of
    ``model_world``, the checkpoint's (``checkpoint_world``), as the live estimator does: before, they
    took no calibration at all, a posterior through the FEE alone whose intervals held nothing."""
    from .fusion_calibration import given_fusion, load_calibrated, recorded_soils, uncalibrated_physics

    if bags is None and world not in WORLD_MODES:
        raise ValueError(f"the forecast needs bags (--forecast-data) or a world, fee or default (got {world!r})")
    world = bags.metas[0].world_mode if bags is not None else world
    shipped = f"shipped ({world} world)"
    if world not in WORLD_MODES and not fusion_config:
        log(f"--forecast-data: its episodes' world {world!r} is no simulator world: the fused posterior takes the "
            f"{model_world} world's calibration, the checkpoint's, as the live estimator does (--fusion-config: "
            "one of your own)")
        shipped = f"shipped ({model_world} world, the checkpoint's; the bags' world {world!r})"
        world = model_world
    fusion = given_fusion(fusion_config, world, log) if fusion_config else load_calibrated(world)
    if uncalibrated := uncalibrated_physics(fusion, model):
        log(f"warning: {uncalibrated}")
    if bags is None and fusion.calibration_plugins:  # (its laws are those of the world with the plugins' force)
        log(f"--fusion-config: calibrated on episodes with {', '.join(fusion.calibration_plugins)}: the held-out "
            "episodes are simulated with them too")
    soils, custom = recorded_soils(fusion)
    if bags is None and soils is not None:  # (a site's laws: judged on its soils, at densities and depths held out)
        log(f"--fusion-config: calibrated on the soils {soils}: the held-out episodes are of them too")
    out = forecast(model, forecast_dataset(world, plugins=fusion.calibration_plugins or (), soils=soils,
                                           custom_soils=custom) if bags is None else bags,
                   classical=classical, workers=workers, progress=progress, fusion=fusion)
    if uncalibrated:
        out["uncalibrated_physics"] = uncalibrated
    if bags is not None:
        out["data"] = str(bags.root)
    out["fusion_config"] = fusion_config or shipped
    return out


def differ_from_training(ds: Dataset, ckpt: dict) -> str:
    """What a fingerprint other than the checkpoint's means here. The fingerprint hashes the bags'
    bytes (and the reader's cache version): bags written again from the same seeds by a later
    recorder differ in bytes, not necessarily in data, and the shipped models' reports said their
    own training bags "differ". Same episodes by name and the same tick count: said as written
    again, without claiming the data the same."""
    trained = ckpt["dataset"]
    split_names = [n for names in ckpt["split"].values() for n in names]
    same = (len(ds) == trained.get("episodes") and int(ds.offsets[-1]) == trained.get("ticks")
            and set(split_names) <= set(ds.names))
    if same:
        return (f"the bags at {ds.root} are not byte for byte those the model was trained on (fingerprint "
                f"{ds.fingerprint[:12]}, trained on {trained['fingerprint'][:12]}), but hold its {len(ds)} episodes by "
                f"name and {int(ds.offsets[-1])} ticks: written again (by another version of this software, or after "
                "a change to the simulator, which names and counts cannot tell)")
    return f"the bags at {ds.root} differ from those the model was trained on"


def forecast_report(model, checkpoint, bags: Dataset | None, world: str | None, *, classical: bool = True,
                    workers: int = 2, progress: bool = False, fusion_config: str | None = None, log=print,
                    model_world: str = DEFAULT_WORLD) -> dict:
    """The report of ``forecast_section`` alone (no test split)."""
    t0 = time.monotonic()
    section = forecast_section(model, bags, world, classical=classical, workers=workers, progress=progress,
                               fusion_config=fusion_config, log=log, model_world=model_world)
    return {"checkpoint": str(checkpoint), "forecast_only": True, "world_modes": section["worlds"],
            **({"forecast_data": describe(bags)} if bags is not None else {}),
            "forecast": section, "targets": [], "timing_s": {"forecast_s": time.monotonic() - t0}}


def targets(report: dict) -> list[dict]:
    """The issue's targets for this dataset, each with the value reached and whether it is met."""
    out = []

    def add(name, value, limit, op="<=", met=None):
        if met is None and np.isfinite(value):
            met = value <= limit if op == "<=" else value >= limit
        # None: not evaluated on this dataset (e.g. no episode at I_d <= 60 %), no failure
        out.append({"target": name, "value": value, "limit": limit, "op": op, "met": None if met is None else bool(met)})

    f = report["force"]
    fee_world = report["world_modes"] == ["fee"]
    add("PINN force error, % of measured |F|", f["pinn"]["mae_mag_pct_measured"], 5.0 if fee_world else 10.0)
    p = report["params"]["pinn"][f"id_le_{ID_LIMIT_PCT:.0f}"]
    if fee_world:
        add("PINN φ MAE (I_d <= 60 %) [deg]", p["phi_mae_deg"], 2.0)
        add("PINN δ MAE (I_d <= 60 %) [deg]", p["delta_mae_deg"], 1.0)
        add("PINN c MAE (I_d <= 60 %) [kPa]", p["c_mae_kPa"], 1.0)
    else:
        for soil, t in report["trends"]["pinn"].items():
            for q in ("phi", "c"):
                # the trend's own test (``_trends``: ρ above 0.5 and a rising slope), so the table and
                # the JSON's "rises" agree (with three densities ρ = 0.5 is one of three orders wrong)
                add(f"{soil}: {q}̂ rises with I_d (Spearman ρ, and a rising slope)", t[q]["spearman"], 0.5, ">",
                    met=t[q]["rises"])
    if "classical" in report["params"]:
        c = report["params"]["classical"][f"id_le_{ID_LIMIT_PCT:.0f}"]
        for key in ("phi_mae_deg", "c_mae_kPa", "delta_mae_deg"):
            add(f"PINN {key} / classical fit's (I_d <= 60 %)", p[key] / max(c[key], 1e-12), 1.0)
    if "physics_free" in f:
        add("PINN force error / physics-free network's", f["pinn"]["mae_mag_n"] / f["physics_free"]["mae_mag_n"], 1.2)
    train_s = sum(t.get("train_seconds", 0.0) for t in report["training"].values())
    add("training time, all networks [min]", train_s / 60, 15.0)
    return out


# ---------------------------------------------------------------------------------- output
def markdown_targets(rows: list[dict]) -> list[str]:
    """The targets table: met yes / **no**, or n/a where this dataset cannot evaluate it."""
    return [*md.header(["target", "value", "limit", "met"]),
            *(md.row([t["target"], _fmt(t["value"], 2), f"{t['op']} {t['limit']}",
                      "n/a" if t["met"] is None else "yes" if t["met"] else "**no**"]) for t in rows)]


def _fmt(x, nd=1):
    return "n/a" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{x:.{nd}f}"


def _skipped_lines(described: dict | None) -> list[str]:
    """Markdown lines naming the bags ``--skip-bad-bags`` left out of a dataset (none: [])."""
    skipped = (described or {}).get("skipped_bags") or []
    if not skipped:
        return []
    return ["", f"**{len(skipped)} bag(s) under `{described['root']}` could not be read and were left out** "
                f"(`--skip-bad-bags`): " + ", ".join(f"`{b}`" for b in skipped)]


def _mismatch_lines(report: dict) -> list[str]:
    """Markdown lines saying the checkpoint's world is not the forecast's (none: [])."""
    return world_mismatch_lines(report.get("world_mismatch", ""))


def _seen_lines(report: dict) -> list[str]:
    """Markdown lines saying the forecast bags share names with the checkpoint's training or validation
    episodes (none: []); said in the report of a whole evaluation too, not only in its log (an
    outside tester's)."""
    if not report.get("seen_in_training"):
        return []
    return ["", f"**{report['seen_in_training']} of the forecast's episodes have the names of episodes the checkpoint "
                "was trained or validated on**: if they are those bags, the PINN's forecast row is no held-out score."]


def markdown(report: dict) -> str:
    if report.get("forecast_only"):
        return "\n".join([
            f"# PINN evaluation: the force at another depth, "
            f"{', '.join(report['world_modes']) + ' world' if report['world_modes'] else 'bags of no simulator world'}", "",
            f"Checkpoint `{Path(report['checkpoint']).name}`; the forecast alone (no test split). Generated by `pinn_eval`.",
            *_seen_lines(report), *_skipped_lines(report.get("forecast_data")), *_mismatch_lines(report),
            "", *fc.markdown(report["forecast"]), "",
            "- evaluation time: " + ", ".join(f"{k} {v:.1f} s" for k, v in report["timing_s"].items())]) + "\n"
    lines = [
        f"# PINN evaluation: {', '.join(report['world_modes'])} world",
        "",
        f"Checkpoint `{Path(report['checkpoint']).name}`; dataset fingerprint `{report['dataset']['fingerprint'][:16]}` "
        f"({report['dataset']['episodes']} episodes); test split: {report['test_episodes']} episodes, "
        f"{report['windows']} windows (one every {report['window_stride']} samples). Generated by `pinn_eval`.",
        *_skipped_lines(report.get("dataset")), *_skipped_lines(report.get("forecast_data")), *_mismatch_lines(report),
        *_seen_lines(report),
        *(["", f"**The forecast at another depth is not judged**: {report['forecast_skipped']}."]
          if report.get("forecast_skipped") else []),
        "",
        "## Force error on the test split (mean |F - F̂|)",
        "",
        *md.header(["estimator", "x [N]", "z [N]", "magnitude [N]", "% of measured (x / z / mag)",
                    "% of machine limits (x / z / mag)"]),
    ]
    for name, f in report["force"].items():
        lines.append(md.row([
            name, f"{f['mae_x_n']:.0f}", f"{f['mae_z_n']:.0f}", f"{f['mae_mag_n']:.0f}",
            f"{f['mae_x_pct_measured']:.1f} / {f['mae_z_pct_measured']:.1f} / {f['mae_mag_pct_measured']:.1f}",
            f"{f['mae_x_pct_limit']:.1f} / {f['mae_z_pct_limit']:.1f} / {f['mae_mag_pct_limit']:.1f}"]))
    lines += ["", "`pinn_fee_part` is F_FEE alone (F̂ without the residual F_r); `classical` is the FEE of the fitted parameters.", ""]
    lines += ["## Parameter error against the pseudo-ground truth (mean absolute)", "",
              *md.header(["estimator", "windows", "φ [deg]", "c [kPa]", "δ [deg]", "β [deg]"])]
    for name, per in report["params"].items():
        for subset, e in per.items():
            lines.append(md.row([name, subset, _fmt(e.get('phi_mae_deg')), _fmt(e.get('c_mae_kPa'), 2),
                                 _fmt(e.get('delta_mae_deg')), _fmt(e.get('beta_mae_deg'))]))
    lines += ["", "## Per soil and relative density (mean ± std over test windows; truth in brackets)", "",
              *([f"{report['changing_soil_episodes']} test episode(s) change soil along the path: each window is "
                 "counted in the soil and density under the blade's edge at its end (the patch of the episode's path).", ""]
                if report.get("changing_soil_episodes") else []),
              *md.header(["soil", "I_d [%]", "mean d [m]", "φ̂ [deg]", "ĉ [kPa]", "δ̂ [deg]", "β̂ [deg]",
                          "classical φ / c / δ", "|F| at d = 0.1 m [kN]: truth / PINN / classical"])]
    for r in report["per_soil_id"]:
        p, t = r["pinn"], r["truth"]
        cells = []
        for q in PARAMS:
            k = UNITS[q][1]
            cells.append(f"{p[q]['mean'] * k:.{2 if q == 'c' else 1}f} ± {p[q]['std'] * k:.{2 if q == 'c' else 1}f} ({t[q] * k:.{2 if q == 'c' else 1}f})")
        cl = r.get("classical")
        cls = f"{cl['phi']['mean'] / DEG:.1f} / {cl['c']['mean'] / 1e3:.2f} / {cl['delta']['mean'] / DEG:.1f}" if cl else "n/a"
        ff = r["failure_force_n"]
        ffs = " / ".join(_fmt(ff.get(k, float("nan")) / 1e3, 1) for k in ("truth", "pinn", "classical"))
        lines.append(md.row([r['soil'], f"{r['relative_density_pct']:.0f}", f"{r['mean_depth_m']:.3f}", *cells, cls, ffs]))
    if report["trends"].get("pinn"):
        lines += ["", "## Trend with relative density, cohesive soils (paper Fig. 6)", "",
                  *md.header(["soil", "φ̂ slope [deg / 100 % I_d]", "φ̂ Spearman", "ĉ slope [kPa / 100 % I_d]", "ĉ Spearman"])]
        for s, t in report["trends"]["pinn"].items():
            lines.append(md.row([s, f"{t['phi']['slope_deg_per_100pct']:.2f}", f"{t['phi']['spearman']:.2f}",
                                 f"{t['c']['slope_kPa_per_100pct']:.2f}", f"{t['c']['spearman']:.2f}"]))
    if report.get("forecast"):
        lines += ["", "## Forecast: the force at another depth (the planner's question)", ""]
        lines += fc.markdown(report["forecast"])
    lines += ["", "## Targets", "", *markdown_targets(report["targets"])]
    tr = report["training"]
    lines += ["", "## Training", ""]
    for name, m in tr.items():
        lines.append(f"- {name}: {m.get('parameters')} parameters, best epoch {m.get('best_epoch')} of {m.get('epochs_run')} "
                     f"({m.get('stop_reason')}), {m.get('train_seconds', 0) / 60:.1f} min")
    lines.append("- evaluation time: " + ", ".join(f"{k} {v:.1f} s" for k, v in report["timing_s"].items()))
    return "\n".join(lines) + "\n"


def plot(report: dict, path: Path) -> Path:
    """Figs. 5-6 analog: φ̂, ĉ, δ̂, β̂ and the d = 0.1 m failure force against I_d, per soil."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    soils = sorted({r["soil"] for r in report["per_soil_id"]})
    fig, axes = plt.subplots(5, len(soils), figsize=(3.2 * len(soils), 11), sharex=True, squeeze=False)
    styles = {"pinn": ("C0", "PINN"), "classical": ("C1", "classical fit")}
    for j, s in enumerate(soils):
        rows = [r for r in report["per_soil_id"] if r["soil"] == s]
        x = np.array([r["relative_density_pct"] for r in rows])
        for i, q in enumerate(PARAMS):
            ax = axes[i, j]
            unit, k = UNITS[q]
            ax.plot(x, [r["truth"][q] * k for r in rows], "s-", color="C2", label="ground truth")
            for name, (color, label) in styles.items():
                if name in rows[0]:
                    m = np.array([r[name][q]["mean"] for r in rows]) * k
                    sd = np.array([r[name][q]["std"] for r in rows]) * k
                    ax.errorbar(x + (1.5 if name == "classical" else 0), m, yerr=sd, fmt="o-", color=color, capsize=2, label=label, alpha=0.9)
            ax.set_ylabel(f"{q} [{unit}]")
            if i == 0:
                ax.set_title(s)
        ax = axes[4, j]
        for key, color, label in (("truth", "C2", "ground truth"), ("pinn", "C0", "PINN"), ("classical", "C1", "classical fit")):
            vals = [r["failure_force_n"].get(key) for r in rows]
            if all(v is not None for v in vals):
                ax.plot(x, np.array(vals) / 1e3, "o-", color=color, label=label)
        ax.set_ylabel("|F| at d=0.1 m [kN]")
        ax.set_xlabel("I_d [%]")
    axes[0, 0].legend(fontsize=7)
    fig.suptitle(f"{', '.join(report['world_modes'])} world, test split: estimates vs ground truth (mean ± std)")
    fig.tight_layout()
    save_figure_atomically(fig, path, dpi=80)
    plt.close(fig)
    return path


def default_stem(checkpoint, forecast_only: bool) -> str:
    """The report's file stem without ``--name``: the forecast alone and the whole evaluation are
    two reports, in one ``--out`` side by side (the forecast alone had replaced the whole one)."""
    return f"{Path(checkpoint).stem}_{'forecast' if forecast_only else 'report'}"


def report_paths(out_dir: Path, stem: str, forecast_only: bool) -> dict[str, Path]:
    """The report's files in ``out_dir``: JSON, markdown and the per-soil figure (not with
    ``forecast_only``: no test split, no figure)."""
    paths = {"json": out_dir / f"{stem}.json", "markdown": out_dir / f"{stem}.md"}
    return paths if forecast_only else paths | {"png": out_dir / f"{stem}_params.png"}


def write_report(report: dict, out_dir: Path, stem: str) -> dict[str, Path]:
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = report_paths(out_dir, stem, bool(report.get("forecast_only")))
    # strict JSON: a figure with nothing to score (NaN) is null, which JSON.parse reads
    write_text_atomically(paths["json"], strict_json.dumps(report, indent=1, default=float) + "\n")
    write_text_atomically(paths["markdown"], markdown(report))
    if "png" in paths:
        plot(report, paths["png"])
    return paths


@interruptible("pinn_eval")
def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="pinn_eval", description=__doc__.splitlines()[0])
    p.add_argument("--checkpoint", required=True, type=input_text, help="PINN checkpoint (.pt)")
    p.add_argument("--physics-free", help="physics-free baseline checkpoint trained on the same split")
    p.add_argument("--data", type=input_text, help="bag directory (default: the one the checkpoint was trained on)")
    p.add_argument("--out", type=output_dir, default="out/eval", help="report directory (default: out/eval)")
    p.add_argument("--name", type=file_stem, help="report file stem (default: <checkpoint stem>_report, with "
                   "--forecast-only <checkpoint stem>_forecast: the two never replace each other)")
    p.add_argument("--stride", type=int, help=f"samples between test windows (default: {TEST_STRIDE})")
    p.add_argument("--no-classical", action="store_true", help="skip the classical least-squares baseline")
    p.add_argument("--workers", type=cli_numbers.workers, default=2, help="processes for the classical fit and bag reading (0: one per core)")
    p.add_argument("--forecast-world", default="auto", choices=("auto", *WORLD_MODES, "none"),
                   help="world of the held-out forecast episodes (default: the test split's; none: skip)")
    p.add_argument("--forecast-data", metavar="DIR", type=input_text,
                   help="judge the forecast at another depth on these bags instead (pairs of episodes of one soil and "
                        "relative density at different depths, or without a soil label of one measured unit weight "
                        "gamma, e.g. your machine's cuts; bags the model was trained "
                        "on are not held out), with the calibrated posterior of their world")
    p.add_argument("--forecast-only", action="store_true",
                   help="only the forecast at another depth (of --forecast-data, or of --forecast-world's simulated "
                        "episodes), without the test split: the bags the model was trained on need not be here")
    p.add_argument("--fusion-config", metavar="FILE", type=input_text,
                   help="the fused posterior's config for the forecast (e.g. one pinn_fusion_calibrate --out wrote; "
                        "default: the shipped calibration of the forecast's world)")
    p.add_argument("--quiet", action="store_true")
    add_skip_bad_bags_option(p)
    args = p.parse_args(argv)
    if args.forecast_data and args.forecast_world == "none":
        p.error("--forecast-data asks for the forecast that --forecast-world none skips: give one of them")
    if args.forecast_data and args.forecast_world in WORLD_MODES:
        p.error(f"--forecast-world {args.forecast_world} names the world of the simulated held-out episodes; "
                "--forecast-data's bags say their own world in their metadata: give one of them")
    if args.forecast_only and (args.physics_free or args.data or args.stride is not None):
        p.error("--forecast-only evaluates no test split: --data, --physics-free and --stride do not apply")
    if args.stride is None:
        args.stride = TEST_STRIDE
    if args.forecast_only and not args.forecast_data and args.forecast_world not in WORLD_MODES:
        p.error("--forecast-only needs --forecast-data DIR or --forecast-world fee|default")
    stem = args.name or default_stem(args.checkpoint, args.forecast_only)
    try:
        refuse_directories(report_paths(Path(args.out), stem, args.forecast_only).values(), "give another --out or --name")
        if not 1 <= args.stride <= MAX_WINDOW_STRIDE:
            raise ValueError(f"--stride={args.stride} must be in [1, {MAX_WINDOW_STRIDE}] samples (beyond it one window "
                             "per episode)")
        report = evaluate(args.checkpoint, args.data, physics_free=args.physics_free, stride=args.stride,
                          classical=not args.no_classical, workers=args.workers, progress=not args.quiet,
                          skip_bad_bags=args.skip_bad_bags,
                          forecast_world=None if args.forecast_world == "none" else args.forecast_world,
                          forecast_data=args.forecast_data, forecast_only=args.forecast_only,
                          fusion_config=args.fusion_config)
    except (ValueError, FileNotFoundError) as err:
        print(f"pinn_eval: error: {err}", file=sys.stderr)
        return 2
    except WorkerDied as err:  # a run that broke, not the input
        print(f"pinn_eval: error: {err}", file=sys.stderr)
        return 1
    replaced = [p.name for p in report_paths(Path(args.out), stem, args.forecast_only).values() if p.exists()]
    # a whole report's figure beside the forecast's files of its name is not the forecast's (an outside reviewer's)
    figure = report_paths(Path(args.out), stem, False)["png"]
    stale = args.forecast_only and figure.exists()
    paths = write_report(report, Path(args.out), stem)
    print(markdown(report))
    if replaced:  # a report of before is gone: said, since a user may have meant to keep it (--name, --out)
        print(f"pinn_eval: replaced {', '.join(replaced)} in {args.out} (give --name or --out to keep a report)"
              + (f"; {figure.name} beside them is the earlier whole report's figure" if stale else ""), file=sys.stderr)
    print(json.dumps({k: str(v) for k, v in paths.items()}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
