"""Calibrating the fused posterior's error laws on episodes the evaluation never scores.

Per axis (``fusion_config.FusionConfig``): ``rel_std``, how far the physics model may be from a
stretch's measured force (how hard each stretch teaches), and the forecast law
``forecast_abs_std_n`` + ``forecast_rel_std``·|ΔF|, the model error a forecast adds to the
posterior's spread, ΔF the part of the force it extrapolates from the newest evidence
(``SoilPosterior.forecast``). Calibration episodes: depths 0.05 / 0.09 / 0.125 / 0.175 / 0.25 / 0.3 m
(near and far forecasts, as a planner asks them, from just under its 0.1 m start), densities 20-80 %, other seeds, disjoint
from the evaluation's 0.1 / 0.15 / 0.225 m and 30 / 50 / 70 %. Stage 1, for each law of the
stretches' shape evidence (``SHAPE_GRID``; the simplest as skilful as any, or where the
episodes' θ is the truth, of those as skilful as any, the one and the drift whose parameter
intervals are best calibrated and, of the equally calibrated, the sharpest, ``calibrate``): ``rel_std`` on a log
grid, per axis by how close its median forecasts of that axis at another depth are to the
measured force (mean |error|: of F_x as a share of |F_x|; of F_z, which passes through 0, as a
share of its limit): the smallest value (the evidence that teaches most) within one standard
error of the most accurate (``choose_evidence_law``). An axis the model forecasts worse than
"the force now" is scored as that naive forecast, and then the largest value wins: what the
model cannot forecast should teach least (the default world's F_z, far from the FEE: the
penetration reaction). Where the axes' values differ, each is chosen again with the other held
at its choice (``jointly_chosen_rels``: the trials have one value on both axes). Stage 2,
with the posteriors of stage 1 kept: the forecast law per axis (share and floor on grids)
whose calibration curves are closest to the diagonal (mean |coverage − nominal| over the
central intervals 10-90 %; a law fitted to the 90 % level alone over-covers the 50 % one
whenever errors are not Gaussian; the log also gives each law's coverage over near and far
forecasts, ``reach_strata``), and of the laws within the coverages' sampling error of that one,
the sharpest (narrowest 90 % intervals): sharpness subject to calibration; on the pairs whose
both depths are at least ``MIN_CALIBRATED_DEPTH_M``. Then, with that law kept, its part near the F_x
limit per axis (``forecast_limit_std``, ``choose_limit_shares``): on the pairs whose forecast F_x
lies beyond the planner's margin alone, where the anti-stall controller's lift sets the force,
the smallest share of the limit as calibrated as any (0 where none is better calibrated than
none). The planner's bound law: the anchored upper
bound a plan keeps within the limits is another forecast than the posterior's intervals,
calibrated apart by ``soil_planner_calibrate`` (``soil_planner.bound_calibration``; run it after
this: a whole calibration here leaves the config without one, a ``--forecast-law-only`` keeps it).
``pinn_fusion_calibrate --world fee`` writes the config the estimator and ``pinn_eval`` load
(``models/fusion_<world>.json``) and the calibration curve (PNG).
"""
from __future__ import annotations

import argparse
import dataclasses
import itertools
import math
import sys
from pathlib import Path
from typing import NamedTuple

import numpy as np

from soil_msgs_py.cli_paths import input_text, output_file, save_figure_atomically
from soil_msgs_py.graph import EstimatorPhysics
from soil_msgs_py.episode import MAX_EPISODE_S, WORLD_MODES
from soil_msgs_py.params import FORCE_LIMITS_N, PLANNER_FORCE_MARGIN, SAMPLE_RATE_HZ, WINDOW_SAMPLES
from soil_physics.force_terms import term_texts
from soil_physics.predictive import error_law_text, mixture_cdf, near_limit_text
from soil_msgs_py.interrupts import interruptible

from . import forecast as fc
from .fusion import forecast_error_std
from .fusion_config import PROVENANCE_FIELDS, FusionConfig
from .shipped import DEFAULT_WORLD, config_path  # their home; callers of this module read them from here too

CAL_DENSITIES_PCT = (20.0, 40.0, 60.0, 80.0)
# 0.09 m: a cut just under the planner's start depth (depth_schedule's 0.1 m), where it first asks;
# without it the grid had none between 5 and 12.5 cm, and pairs with a 10 cm cut held 88 / 42 % of
# a law calibrated on 12.5-30 cm (default world, held out; 90 / 46 % with it)
CAL_DEPTHS_M = (0.05, 0.09, 0.125, 0.175, 0.25, 0.3)
CAL_SEED = 9000
# The forecast law is calibrated on the pairs whose both depths are at least this [m]. Shallower,
# the edge's own reaction is a large part of the force, which the posterior's physics lacks: a
# soil fitted at 5 cm forecast the dense soils' force deeper 27-126 % too high, and a law wide
# enough for those pairs held 65 % of the held-out forecasts at its 50 % level (default world;
# 40-60 % on three held-out sets from 7 cm up once they were left out). The published intervals
# are therefore calibrated from the shallowest cut of CAL_DEPTHS_M at least this deep
# (``calibration_bounds``, 0.09 m: the grid has none between 5 and 9 cm; sources of 7 cm going
# deeper held 53 / 24 %, of 9-11.5 cm 91 / 55 %, an outside tester's) to the calibration's
# deepest; the planner's bound, which plans from 5 cm, has its own law, calibrated on every pair
# going deeper (soil_planner_calibrate).
MIN_CALIBRATED_DEPTH_M = 0.07


def calibration_bounds() -> tuple[float, float, float]:
    """(shallowest [m], deepest [m], speed [m/s]) of the calibration cuts the forecast law is scored
    on: CAL_DEPTHS_M has none between 5 cm and its shallowest scored one, whatever
    MIN_CALIBRATED_DEPTH_M, and every calibration episode runs at the forecast's one speed."""
    return (min(d for d in CAL_DEPTHS_M if d >= MIN_CALIBRATED_DEPTH_M), max(CAL_DEPTHS_M), fc.FORECAST_SPEED_M_S)


# A calibration episode's length [s]: its steady part is its second half (forecast.STEADY_FROM),
# which must hold at least one full window of the estimator; at most the simulator's longest episode.
CAL_DURATION_RANGE_S = (2.0 * WINDOW_SAMPLES / SAMPLE_RATE_HZ, MAX_EPISODE_S)
# The episode length [s] the shipped laws are calibrated on. A shorter one calibrates on posteriors
# of a few stretches, wider than the live estimator's after a longer cut: their own spread covers
# the forecasts' errors, so the laws come out sharper than live posteriors need (an outside tester:
# 2 s episodes gave the planner's bound x 20 N + 0|ΔF| for 1000 N + 0.15|ΔF|, and the live planner
# stalled 3x as long in a stiff soil).
CAL_DURATION_S = 10.0


def add_soil_options(p: argparse.ArgumentParser) -> None:
    """``--soil-file`` / ``--soils``: calibrate on soils of one's own (``calibration_soils``)."""
    p.add_argument("--soil-file", metavar="FILE", type=input_text, help="a soils YAML (soil_sim_batch --soil-file's format): calibrate "
                                                      "on its soils (or those --soils names) instead of the catalogue's")
    p.add_argument("--soils", metavar="A,B", type=input_text, help="the calibration soils, comma-separated: the catalogue's or "
                                                  "--soil-file's (default: the catalogue's; with --soil-file, its own)")


def checked_soils(p: argparse.ArgumentParser, args: argparse.Namespace, output_option: str, output: object) -> None:
    """``calibration_soils`` of ``args`` into ``args.calibration_soils``, before any work; exit 2
    (``p.error``) naming the option for soils that cannot be used, or given without ``output_option``
    (``output`` None: the shipped config, calibrated on the catalogue's soils, would be replaced)."""
    try:
        args.calibration_soils = calibration_soils(args)
    except ValueError as err:
        p.error(str(err))
    if (args.soil_file or args.soils) and output is None:
        p.error(f"--soil-file/--soils: give {output_option} (the shipped config is calibrated on the catalogue's soils)")


def add_plugin_option(p: argparse.ArgumentParser, output_option: str) -> None:
    """``--plugin``: a force plugin switched on in the calibration episodes (``checked_plugins``)."""
    p.add_argument("--plugin", action="append", default=[], metavar="SPEC", type=input_text,
                   help="switch on a force plugin in the calibration episodes, as soil_sim_batch --plugin (repeatable; "
                        "e.g. 'soil_physics.force_terms:plugin term=NAME k=K' for a term soil_discrepancy found in "
                        f"your own bags, which the simulated world lacks); needs {output_option}")


def checked_plugins(p: argparse.ArgumentParser, args: argparse.Namespace, output_option: str, output: object) -> None:
    """``--plugin`` specs loaded (their module, function and parameters) before any work; exit 2
    (``p.error``) naming the option for one that does not load, or given without ``output_option``
    (``output`` None: the shipped config, calibrated on the world as it is, would be replaced)."""
    from soil_sim_node.effects import PluginError, load_plugins

    if args.plugin and output is None:
        p.error(f"--plugin: give {output_option} (the shipped config is calibrated on the world as it is)")
    try:
        load_plugins(args.plugin)
    except PluginError as err:
        p.error(f"--plugin: {err}")


def kept_plugins(p: argparse.ArgumentParser, args: argparse.Namespace, cfg: FusionConfig, path) -> None:
    """For calibrating more of the config ``cfg`` (read from ``path``) on new episodes: the plugins
    its laws were calibrated with (``FusionConfig.calibration_plugins``) are switched on again
    (said); a ``--plugin`` given must be them, whatever the spacing, order or number format (exit 2:
    the config is the laws of another world). A config that does not record them (one written
    before it was) takes the ``--plugin`` given, said."""
    recorded = cfg.calibration_plugins
    if recorded is None:
        print(f"{p.prog}: {path} does not record the plugins its laws were calibrated with: the episodes have "
              + (f"those given,{plugin_words(args.plugin)}" if args.plugin else "none (give --plugin if its had any)"),
              file=sys.stderr, flush=True)
        return
    if args.plugin and plugin_key(args.plugin) != plugin_key(recorded):
        p.error(f"--plugin: {path} was calibrated on episodes with {list(recorded) or 'no plugin'}, not {args.plugin}: its "
                "posterior is that world's (run the whole calibration with --plugin into another --out)")
    if recorded and not args.plugin:
        print(f"{p.prog}: {path} was calibrated on episodes with{plugin_words(recorded)}: switched on again",
              file=sys.stderr, flush=True)
    args.plugin = list(recorded)


def soil_records(names, custom: dict) -> tuple[dict, ...]:
    """The calibration soils (``calibration_soils``' names, None for the catalogue's, and the custom
    soils by name) as a config records them (``FusionConfig.calibration_soils``)."""
    from soil_physics.soils import CATALOGUE, get_soil, soil_to_dict

    return tuple(soil_to_dict(get_soil(name, custom)) for name in (sorted(CATALOGUE) if names is None else names))


def soils_differ(recorded, given) -> str:
    """How the ``given`` calibration soils differ from the ``recorded`` ones, in words ('' if they are
    the same soils in the same order: the episodes' seeds follow it). A soil's ``source``, free text,
    is not compared (a note added to a soils YAML made the same soil another, an outside reviewer's)."""
    def key(r):
        return r["name"].lower(), tuple(r["phi_deg"]), tuple(r["cohesion_pa"]), tuple(r["unit_weight_n_m3"])

    mine, theirs = [key(r) for r in recorded], [key(r) for r in given]
    if mine == theirs:
        return ""
    if sorted(mine) == sorted(theirs):
        return (f"these are the same soils in another order ({[r['name'] for r in given]}), which the episodes' seeds "
                "follow: give them in the recorded order")
    changed = [r["name"] for r, k in zip(given, theirs) if k[0] in {m[0] for m in mine} and k not in mine]
    return (f"these are {[r['name'] for r in given]}"
            + (f", with other properties for {changed}" if changed else ""))


def recorded_soils(cfg: FusionConfig) -> tuple[list[str] | None, dict]:
    """(names, custom soils by name) of the soils ``cfg`` records it was calibrated on, as
    ``calibration_soils`` gives them to the episodes; (None, {}) for the catalogue's or none recorded."""
    from soil_physics.soils import soil_from_dict

    recorded = cfg.calibration_soils
    if recorded is None or not soils_differ(soil_records(None, {}), recorded):  # (a source note aside)
        return None, {}
    return [r["name"] for r in recorded], {r["name"]: soil_from_dict(r) for r in recorded}


def kept_soils(p: argparse.ArgumentParser, args: argparse.Namespace, cfg: FusionConfig, path) -> None:
    """For calibrating more of ``cfg`` (read from ``path``) on new episodes: the soils its laws were
    calibrated on (``FusionConfig.calibration_soils``) are simulated again (said, where not the
    catalogue's); --soil-file/--soils given must give them (exit 2: the config is of other soils).
    A config that does not record them (one written before it was) takes the soils given, said
    where they are the catalogue's by default and the config is not the shipped one (whose
    calibration is the catalogue's: pinn_fusion_calibrate refuses other soils for it)."""
    recorded = cfg.calibration_soils
    given = bool(args.soil_file or args.soils)
    if recorded is None:
        if not given and own_output(path) is not None:
            print(f"{p.prog}: {path} does not record the soils its laws were calibrated on: the episodes have the "
                  "catalogue's (give --soil-file/--soils if its were others)", file=sys.stderr, flush=True)
        return
    names = [r["name"] for r in recorded]
    if given:
        if why := soils_differ(recorded, soil_records(*args.calibration_soils)):
            p.error(f"--soil-file/--soils: {path} was calibrated on the soils {names}; {why}: its posterior is of "
                    "those soils (run the whole calibration with these into another --out)")
        return
    if (kept := recorded_soils(cfg))[0] is not None:
        print(f"{p.prog}: {path} was calibrated on the soils {names} (not the catalogue's): simulated again",
              file=sys.stderr, flush=True)
        args.calibration_soils = kept


def plugin_key(specs) -> list:
    """Plugin specs as what they switch on, (target, sorted parameters) each, sorted: two lists of
    specs that differ in spacing, order or the writing of a number are the same plugins."""
    from soil_sim_node.effects import load_plugins

    return sorted((p.target, sorted(p.params.items())) for p in load_plugins(specs))


def term_note(prog: str, world: str, terms, plugins) -> None:
    """Said (stderr) where the posterior has terms and the calibration episodes no plugin: a term for
    an effect the world lacks needs its force there too. Not for the terms of the world's shipped
    config (the default world's surcharge relief was found in that world's own data: switched on
    again, the calibration episodes would have the effect twice)."""
    shipped = {name for name, _ in load_calibrated(world).terms}
    own = [(n, k) for n, k in terms if n not in shipped]
    if own and not plugins:
        print(f"{prog}: note: the calibration episodes are the {world} world's as simulated. A term for an effect that "
              "world lacks (one soil_discrepancy found in your own bags) needs it switched on there too,"
              f"{plugin_words(f'soil_physics.force_terms:plugin term={n} k={k!r}' for n, k in own)}: else the laws "
              "are calibrated for a force the episodes do not have (their intervals come out too wide)",
              file=sys.stderr, flush=True)


def checked_world_options(p: argparse.ArgumentParser, args: argparse.Namespace, output_option: str, output) -> None:
    """The options that calibrate on another world than the shipped one (``--force-noise``,
    ``--plugin``, own soils) refused without ``output_option`` naming a file of one's own
    (``own_output``), and the plugins and soils checked, before any work (exit 2)."""
    own = own_output(output)
    if args.force_noise and own is None:
        p.error(f"--force-noise: give {output_option} (the shipped config is calibrated on the world as it is)")
    checked_plugins(p, args, output_option, own)
    checked_soils(p, args, output_option, own)


def own_output(path):
    """``path`` (a tool's --out or --config), or None where it names a shipped config (or is None):
    what the calibration's own-world options refuse to replace is the shipped file, however it is
    named (the shipped path given as --out had let --plugin and --force-noise replace it; a reviewer's)."""
    if path is None or any(Path(path).resolve() == config_path(w).resolve() for w in WORLD_MODES):
        return None
    return path


def plugin_words(plugins) -> str:
    """The plugin options of a calibration command line ("" without any)."""
    return "".join(f" --plugin '{spec}'" for spec in plugins)


def calibration_episodes(p: argparse.ArgumentParser, args: argparse.Namespace):
    """The calibration episodes (``evaluate.forecast_dataset``) of ``args``' world, duration, sensor
    noise, plugins (``checked_plugins``) and ``checked_soils``; exit 2 naming the plugin where one
    fails on the episodes' first call, or the soils where one has no failure wedge in the world."""
    from soil_sim_node.effects import PluginError

    from .evaluate import forecast_dataset

    soils, custom = args.calibration_soils
    try:
        return forecast_dataset(args.world, seed=CAL_SEED, duration_s=args.duration, densities_pct=CAL_DENSITIES_PCT,
                                depths_m=CAL_DEPTHS_M, force_noise=args.force_noise, soils=soils, custom_soils=custom,
                                plugins=tuple(args.plugin))
    except PluginError as err:  # (a parameter its function takes but refuses, e.g. k=nan)
        p.error(f"--plugin: {err}")
    except ValueError as err:
        p.error(f"{'--soils' if args.soils else '--soil-file' if args.soil_file else '--world'}: {err}")


def calibration_soils(args: argparse.Namespace) -> tuple[list[str] | None, dict]:
    """(the calibration soils' names or None for the catalogue's, the custom soils by name) from
    ``add_soil_options``; ValueError naming the option and value."""
    from soil_physics.soils import get_soil, load_soil_file

    try:
        custom = load_soil_file(args.soil_file).soils if args.soil_file else {}
    except (OSError, ValueError) as err:
        raise ValueError(f"--soil-file: {err}") from None
    if args.soils is None:
        return (sorted(custom) or None), custom
    names = [n.strip() for n in args.soils.split(",")]
    if not all(names):
        raise ValueError(f"--soils {args.soils!r}: an empty name")
    if len({n.lower() for n in names}) != len(names):  # (a soil is looked up whatever the case: Clay,clay is one)
        raise ValueError(f"--soils {args.soils!r} names a soil twice")
    for name in names:
        get_soil(name, custom)  # ValueError naming an unknown soil
    return names, custom


def short_duration_warning(duration_s: float) -> str | None:
    """What a calibration on episodes shorter than CAL_DURATION_S costs, or None."""
    if duration_s >= CAL_DURATION_S:
        return None
    return (f"--duration {duration_s:g} s is shorter than the {CAL_DURATION_S:g} s the shipped laws are calibrated on: "
            "the posteriors after so short a cut are wider than the live estimator's, so the laws come out "
            "sharper than live forecasts need (a quick check, not a config to ship)")


def check_duration_option(p, duration_s: float) -> None:
    """A calibration command's --duration: refused (``p.error``, exit 2) outside CAL_DURATION_RANGE_S,
    warned about when shorter than the shipped laws' episodes (``short_duration_warning``)."""
    lo, hi = CAL_DURATION_RANGE_S
    if not lo <= duration_s <= hi:  # NaN too
        p.error(f"--duration={duration_s} s must be in [{lo:g}, {hi:g}] s (its second half holds the steady cut)")
    if warning := short_duration_warning(duration_s):
        print(f"{p.prog}: warning: {warning}", file=sys.stderr, flush=True)
REL_GRID = (0.005, 0.02, 0.05, 0.1, 0.2)
# Shape evidence (``FusionConfig.shape_evidence``): off, or the error law (floor [N], share) of how
# a stretch's sub-means depart from each other, from loose to sharp.
SHAPE_GRID = (None, (50.0, 0.05), (10.0, 0.01), (2.0, 0.002), (0.5, 0.0005))
# The soil's drift along the path (``FusionConfig.drift_per_sqrt_m``), chosen where the world's
# parameters are the truth (the fee world) by how often the posterior's intervals hold them
# (``calibrate``'s ``truth_grids``). Not among them: the weight of the sub-means' own uncertainty
# (``shape_noise_gain``), which sets how wide the posterior is with shape evidence. In the
# noise-free fee world that uncertainty is mostly the sub-means' timing on the entry ramp
# (``fusion.SAMPLE_TIMING_TICKS``); at 1 the parameters' intervals hold the truth in 98-100 % of
# the calibration episodes at 50 % as at 90 %, and a weight of 0.3, which the parameters'
# coverage chose on steady cuts, made them nominal there (held-out: φ 97 / 61 %, c 97 / 75 %)
# and overconfident under the controller's depth dither (90 % intervals holding the truth in 6 of
# 12 dithered cuts), where the sub-means move fast and that uncertainty is what keeps the
# posterior honest. So it stays 1 (both measured with the timing error then taken per sub-mean).
# Nor evidence laws sharper than the grids' sharp end, where the fee world's stage 1 lands (a 2 N
# floor + 0.05 %, shape 0.02 N + 0.002 %, no drift: chosen by the parameters' coverage when
# offered, held-out φ 94 / 67 %, c 89 / 33 %, forecasts 79 / 60 %): with the timing error one per
# stretch they hold the dithered cuts, but a truth stage that also required dithered cuts and
# soil changes to hold the truth for good (docs/soil_posterior.md says how) still chose a law whose intervals
# held a held-out new soil for good only 7.9 s after the crossing and a dithered source's F_z
# forecast in 75 % of pairs, for parameters' intervals nearer nominal (φ 100 / 64 %, c 100 / 33 %)
# and forecasts' no nearer (97 / 96 %).
DRIFT_GRID = (0.0, 0.0025, 0.005, 0.01, 0.02)
DRIFT_FIELD = "drift_per_sqrt_m"
TRUTH_GRIDS = ((DRIFT_FIELD, DRIFT_GRID),)
FORECAST_GRID = (0.0, 0.01, 0.02, 0.03, 0.05, 0.07, 0.1, 0.15, 0.2, 0.3, 0.5, 0.8, 1.2, 2.0)  # share of the extrapolated force
FLOOR_GRID = (5.0, 20.0, 300.0, 1000.0, 3000.0)  # forecast error floor [N]: F_z of the default world is ~0 in the FEE
NOMINAL = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9)  # central interval levels of the calibration curve


def load_calibrated(world: str) -> FusionConfig:
    """The calibrated config of ``world``; the defaults if none was written."""
    path = config_path(world)
    return FusionConfig.load(path) if path.exists() else FusionConfig()


def checkpoint_world(ckpt: dict | None) -> str:
    """The world whose shipped calibration goes with a checkpoint: the one world its training data
    came from (``dataset.world_modes``), where that world has a calibration; else DEFAULT_WORLD.
    Why: the posterior's error laws are the world's (the fee world's 5 N against the default
    world's 1 kN), and a fee model read through the default world's laws fused a clay 7° off."""
    from .checkpoint import trained_worlds  # (here: the module is read without torch)

    worlds = trained_worlds(ckpt)
    return worlds[0] if len(worlds) == 1 and config_path(str(worlds[0])).exists() else DEFAULT_WORLD


def checkpoint_world_words(ckpt: dict | None) -> str:
    """Why ``checkpoint_world`` is the world it is, for a log: "the checkpoint's world", or the
    fallback said as one (an estimator log read "(the checkpoint's world)" for a checkpoint of both
    worlds' bags, and of a machine's, an outside tester's)."""
    from .checkpoint import trained_worlds

    worlds = trained_worlds(ckpt)
    if len(worlds) == 1 and config_path(str(worlds[0])).exists():
        return "the checkpoint's world"
    trained = (f"its bags mix worlds {worlds}" if len(worlds) > 1 else
               f"its bags are of the {worlds[0]} world, which has no shipped calibration" if worlds else
               "its bags are of no simulator world")
    return f"the {DEFAULT_WORLD} world's, as {trained}"


def load_fusion_config(path: str, world: str = DEFAULT_WORLD) -> FusionConfig:
    """The estimator node's ``fusion_config`` parameter: the config at ``path``, or the shipped
    calibration of ``world`` (``checkpoint_world``) where it is empty; ValueError naming the
    parameter if it cannot be used."""
    try:
        return FusionConfig.load(path) if path else load_calibrated(world)
    except (OSError, ValueError, TypeError) as err:
        raise ValueError(f"parameter fusion_config={path!r} refused: {err}") from None


def world_note(cfg: FusionConfig, path, world: str) -> str:
    """For recalibrating the config ``cfg`` (read from ``path``) on the ``world`` world's episodes:
    ValueError if it records another world (its posterior is that world's), else a note ("" if it
    records this one) that it records none and is taken for this world's."""
    if cfg.world and cfg.world != world:
        raise ValueError(f"{path} was calibrated in the {cfg.world} world, not the {world} world (its 'world'): "
                         "its posterior is that world's")
    return "" if cfg.world else f"{path} does not record the world it was calibrated in; taking it for the {world} world's"


def missing_shipped_terms(cfg: FusionConfig, world: str) -> tuple[tuple[str, float], ...]:
    """The terms of the ``world``'s shipped config that ``cfg``'s posterior lacks. A calibration on
    one's own soils without them (as the README had given the command) made the default world's
    forecast of F_x at another depth 37 % off instead of 8.6 %, an outside tester's, with no word."""
    have = {name for name, _ in cfg.terms}
    return tuple((name, k) for name, k in load_calibrated(world).terms if name not in have)


def shipped_settings_note(cfg: FusionConfig, path, world: str) -> str:
    """For a whole calibration of ``cfg`` written over the shipped config at ``path``: the settings it
    would change there that the calibration does not choose ("" if none, or nothing is there). Run
    without the shipped arguments (scripts/fusion_args.sh), the tool had replaced the shipped fee
    world's cohesionless and stiff rows with the defaults without a word."""
    try:
        shipped = FusionConfig.load(path)
    except (OSError, ValueError):
        return ""
    chosen = {*CALIBRATED_FIELDS, *PROVENANCE_FIELDS, *((f for f, _ in TRUTH_GRIDS) if world == "fee" else ())}
    changed = [f"{f.name} {getattr(cfg, f.name)!r} (shipped: {getattr(shipped, f.name)!r})"
               for f in dataclasses.fields(FusionConfig)
               if f.name not in chosen and getattr(cfg, f.name) != getattr(shipped, f.name)]
    return "; ".join(changed)


def given_fusion(path: str, world: str | None, log=None) -> FusionConfig:
    """The fusion config at ``path`` (a tool's ``--fusion-config``) for forecasts in ``world`` (None:
    not known yet); ValueError naming the option if it cannot be read or was calibrated in another
    world; a config that records no world is said to be taken for this one (to ``log``)."""
    try:
        cfg = FusionConfig.load(path)
        note = world_note(cfg, path, world) if world is not None else ""
    except (OSError, ValueError, TypeError) as err:
        raise ValueError(f"--fusion-config: {err}") from None
    if note and log is not None:
        log(f"--fusion-config: {note}")
    return cfg


def estimator_fusion(path: str, ckpt: dict | None) -> tuple[FusionConfig, str | None]:
    """The estimator's soil posterior config and the world it was calibrated for: the config at
    ``path`` (the ``fusion_config`` parameter; its world as it records it, None where it does not), else the shipped
    calibration of the checkpoint's world (``checkpoint_world``). The node and the demo's forecast
    take it from here (the node says its physics to the planner, ``announced_physics``)."""
    world = None if path else checkpoint_world(ckpt)
    cfg = load_fusion_config(path, world or DEFAULT_WORLD)
    return cfg, (cfg.world or None) if path else world


def config_for_model(fusion: FusionConfig | None, model) -> FusionConfig:
    """``fusion`` (None: the shipped calibration of the default world) with the physics of
    ``model`` (an ``EstimatorNet``): its catalogue terms are added to the FEE, as in its own physics
    part, then any term the config itself adds that the model does not have (e.g. one the
    discrepancy workflow named, before the PINN is retrained with it)."""
    fusion = fusion or load_calibrated(DEFAULT_WORLD)
    return dataclasses.replace(fusion, terms=merged_terms(model.cfg.extra_terms, fusion.terms))


def announced_physics(cfg: FusionConfig, source: str) -> EstimatorPhysics:
    """What the estimator says on /soil/estimator/physics of the posterior it runs (``cfg``, after
    ``config_for_model``): its terms beside the FEE and the bound law calibrated with them, which a
    planner must plan with (``soil_planner.estimator_physics``)."""
    return EstimatorPhysics(terms=tuple(term_texts(cfg.terms)), bound_law=tuple(cfg.planner_bound_law() or ()),
                            source=source)


def uncalibrated_physics(fusion: FusionConfig, model) -> str:
    """The sentence saying the checkpoint's physics has terms the posterior's error laws were not
    calibrated with ("" if none): ``config_for_model`` adds them to the FEE, but the laws were
    chosen for the config's own physics. Why say it: a retrained model with surcharge_drag read
    through the shipped default-world laws held the force at another depth in 72 / 22 % of the
    pairs at 90 / 50 % (100 / 59 % without the term), and nothing said so (an outside tester's)."""
    have, own = dict(fusion.terms), getattr(getattr(model, "cfg", None), "extra_terms", ())  # (no model: none)
    added = [(n, k) for n, k in own if n not in have or not math.isclose(have[n], k, rel_tol=1e-9)]
    if not added:
        return ""
    physics = "FEE" + "".join(f" + {n} (k = {k:g})" for n, k in fusion.terms)
    terms = " ".join(f"--term {n}={k:g}" for n, k in merged_terms(own, fusion.terms))
    return (f"the checkpoint's physics adds {', '.join(f'{n} (k = {k:g})' for n, k in added)} to the {physics} the soil "
            f"posterior's error laws were calibrated for: its intervals are not calibrated for this physics "
            f"(pinn_fusion_calibrate --world {fusion.world or DEFAULT_WORLD} {terms} --out FILE calibrates them, with "
            "--plugin 'soil_physics.force_terms:plugin term=NAME k=K' for each term whose effect that world lacks: give "
            "FILE as the estimator's fusion_config, pinn_eval's --fusion-config)")


def merged_terms(first, then) -> tuple[tuple[str, float], ...]:
    """``first``'s (name, k) terms, then those of ``then`` whose name ``first`` lacks (its k wins)."""
    have = {n for n, _ in first}
    return (*first, *(t for t in then if t[0] not in have))


class PairForecast(NamedTuple):
    """One forecast pair (same soil and density, other depth) with the source's posterior through the model."""

    measured: np.ndarray  # (2,) the target episode's steady force [N]
    now: np.ndarray  # (2,) the source episode's: the naive forecast [N]
    posterior: object  # the source episode's fused posterior (``SoilPosterior``)
    predictive: object  # its samples at the target's conditions (``fusion.Predictive``)
    reach_m: float  # how far in depth the forecast reaches, |d_target − d_source| [m]
    shallower_m: float = math.inf  # the shallower of the two episodes' steady depths [m]


def pair_forecasts(ds, posts) -> list[PairForecast]:
    """Every forecast pair of ``ds`` with ``posts``, the episodes' fused posteriors: the model's
    forces are computed once, whatever forecast laws are then tried on them."""
    parts = fc.steady_parts(ds)
    return [PairForecast(parts[b].force, parts[a].force, posts[a],
                         posts[a].predictive(parts[b].known_row(), parts[b].distance_m, parts[b].time_s),
                         abs(parts[b].known["d"] - parts[a].known["d"]), min(parts[b].known["d"], parts[a].known["d"]))
            for a, b in fc.pair_indices(parts)]


def calibrated_reach(pairs: list[PairForecast]) -> list[PairForecast]:
    """The pairs the forecast law is calibrated on: both depths at least ``MIN_CALIBRATED_DEPTH_M``
    (all of them where none is)."""
    kept = [p for p in pairs if p.shallower_m >= MIN_CALIBRATED_DEPTH_M]
    return kept or pairs  # (none from 7 cm: every pair, as before the reach was set)


def pairs_of(ds, cfg: FusionConfig, posts=None, pairs=None) -> list[PairForecast]:
    """``pairs`` if given, else the ``pair_forecasts`` of ``posts`` (None: ``ds`` fused under ``cfg``)."""
    if pairs is not None:
        return pairs
    from .evaluate import fused_posteriors

    return pair_forecasts(ds, fused_posteriors(ds, cfg) if posts is None else posts)


def reach_strata(reach_m) -> list[np.ndarray]:
    """Masks of the pairs that reach less far in depth than the median pair and of the rest (where
    none reaches less far, those at the median and the rest; one mask of all if every pair reaches
    as far). Stage 2 logs each law's coverage in both: a law
    calibrated over all pairs can be too wide near and too narrow far (the default world's
    1000 N law: 88 / 70 % and 73 / 38 % at 90 / 50 %). Judging the laws by the two halves'
    mean miscalibration instead chose 1000 N + 0.01|ΔF| there, no better on held-out pairs, since
    the sharpest of the calibrated laws is still a floor law (a share of |ΔF| is widest far)."""
    reach = np.asarray(reach_m, float)
    if not len(reach):
        return [np.ones(0, bool)]
    near = reach < np.median(reach)
    if not near.any():
        near = reach <= np.median(reach)
    return [np.ones(len(reach), bool)] if near.all() else [near, ~near]


def forecast_table(ds, cfg: FusionConfig, levels=NOMINAL, posts=None, pairs=None) -> list[dict]:
    """Per forecast pair of ``ds``: the measured force and the fused posterior's forecast from
    the first episode under ``cfg``'s forecast law (median and central intervals of ``levels``).
    ``posts``: the episodes' posteriors when already fused; ``pairs``: their ``pair_forecasts``."""
    pairs = pairs_of(ds, cfg, posts, pairs)
    quantiles = tuple(sorted({0.5 - lv / 2 for lv in levels} | {0.5 + lv / 2 for lv in levels} | {0.5}))
    return [{"measured": p.measured, "now": p.now,
             "forecast": p.posterior.forecast_from(p.predictive, quantiles, cfg)["quantiles"]} for p in pairs]


def predictive_cdf(pairs: list[PairForecast], law: FusionConfig) -> np.ndarray:
    """(pairs, 2): each forecast's predictive CDF at the measured force under ``law``'s forecast
    law (the probability integral transform; NaN where the posterior has no forecast). A central
    interval of level ℓ holds the measured force when |2·CDF − 1| <= ℓ: one CDF value per pair
    judges every level, where intervals would need a quantile search each."""
    out = np.full((len(pairs), 2), np.nan)
    for i, p in enumerate(pairs):
        w = p.predictive.weights
        if not len(w):
            continue
        for j in range(2):
            sd = forecast_error_std(p.predictive, law, j)
            out[i, j] = mixture_cdf(w, p.predictive.force_n[j][None], sd[None], np.array([p.measured[j]]))[0]
    return out


def forecast_scores(table: list[dict]) -> dict[str, np.ndarray]:
    """Per axis: ``error``, the mean |median forecast − measured| of F_x as % of the measured
    |F_x| (the force a cut is limited by, positive while cutting: a small force forecast badly
    counts as much as a large one), of F_z as % of its 30 kN limit (F_z passes through 0, in the
    default world often); ``sem``, its standard error over the pairs; ``naive``, the same for the
    force measured now. An axis whose forecasts are worse than the naive one is scored as the
    naive one: nothing there tells one evidence law from another."""
    out = {k: np.full(2, np.inf) for k in ("error", "sem", "naive")}  # no forecast at all: the worst score, never a NaN that wins
    for j in range(2):
        scale = [abs(r["measured"][0]) if j == 0 else FORCE_LIMITS_N[1] for r in table]
        model = np.array([abs(r["forecast"][0.5][j] - r["measured"][j]) / sc for r, sc in zip(table, scale)])
        naive = np.array([abs(r["now"][j] - r["measured"][j]) / sc for r, sc in zip(table, scale)])
        ok = np.isfinite(naive)  # a pair the model gives no forecast for (no wedge) scores as the naive one
        if not ok.any():
            continue
        model = np.where(np.isfinite(model), model, naive)[ok]
        out["naive"][j] = 100.0 * float(naive[ok].mean())
        scored = model if model.mean() < naive[ok].mean() else naive[ok]
        out["error"][j] = 100.0 * float(scored.mean())
        out["sem"][j] = 100.0 * float(scored.std(ddof=1) / math.sqrt(len(scored))) if len(scored) > 1 else 0.0
    return out


def choose_evidence_law(scored: list[tuple[float, dict]]) -> tuple[float, float]:
    """``rel_std`` per axis from stage 1's (rel, ``forecast_scores``) rows. An axis the model
    forecasts: the smallest rel (the evidence that teaches most) whose error is within one
    standard error of the most accurate one's; a wider law only where it forecasts measurably
    better (the errors over a few hundred correlated pairs move by tenths of a percent from
    one law to the next without a trend). An axis no law forecasts better than the force now
    (its errors are the naive one's): the largest, so that what cannot be forecast teaches least."""
    rels = []
    for j in range(2):
        best = min(scored, key=lambda e: e[1]["error"][j])[1]
        if not best["error"][j] < best["naive"][j]:
            rels.append(max(rel for rel, _ in scored))
            continue
        tolerance = best["error"][j] + best["sem"][j]  # (pairs share episodes: the true noise is larger)
        rels.append(min(rel for rel, sc in scored if sc["error"][j] <= tolerance and sc["error"][j] < sc["naive"][j]))
    return rels[0], rels[1]


def coverage_curve(ds, cfg: FusionConfig, levels=NOMINAL, posts=None, pairs=None, width: bool = True) -> dict:
    """Share of forecast pairs whose central interval of each level holds the measured force, per
    axis, and (``width``) the widest level's mean width per axis [N]: the forecasts' sharpness."""
    pairs = pairs_of(ds, cfg, posts, pairs)
    curve = curve_of(interval_level(predictive_cdf(pairs, cfg)), levels)
    return curve | interval_widths(pairs, cfg, max(levels)) if width else curve


def curve_of(held: np.ndarray, levels=NOMINAL) -> dict:
    """The calibration curve per axis (``coverages``) of the pairs' ``interval_level``s (pairs, 2), and their number."""
    return {axis: coverages(held[:, j], levels) for j, axis in enumerate("xz")} | {"pairs": len(held)}


def interval_level(cdf: np.ndarray) -> np.ndarray:
    """|2·CDF − 1|: the narrowest central interval level that holds the measured force (NaN: no
    forecast, held by no interval)."""
    with np.errstate(invalid="ignore"):
        return np.abs(2.0 * np.asarray(cdf, float) - 1.0)


def coverages(held: np.ndarray, levels=NOMINAL) -> list[float]:
    """Share of forecasts whose central interval of each level holds the measured force, from
    their ``interval_level``s."""
    return [float(np.mean(held <= lv)) if len(held) else float("nan") for lv in levels]


def miscalibration(coverage: list[float], levels=NOMINAL) -> float:
    """Mean |coverage − nominal| over a calibration curve's levels (0: perfectly calibrated)."""
    return float(np.mean([abs(c - lv) for c, lv in zip(coverage, levels)]))


def interval_widths(pairs: list[PairForecast], cfg: FusionConfig, level: float) -> dict[str, float]:
    """``width_x``, ``width_z``: the forecasts' mean central ``level`` interval width [N] under ``cfg``'s law."""
    lo, hi = 0.5 - level / 2, 0.5 + level / 2
    q = [p.posterior.forecast_from(p.predictive, (lo, hi), cfg)["quantiles"] for p in pairs]
    out = {}
    for j, axis in enumerate("xz"):
        w = np.array([r[hi][j] - r[lo][j] for r in q], float)
        out[f"width_{axis}"] = float(w[np.isfinite(w)].mean()) if np.isfinite(w).any() else math.inf
    return out


def coverage_tolerance(pairs: int, levels=NOMINAL) -> float:
    """Mean binomial standard error of a coverage over ``pairs`` forecasts at the curve's levels:
    laws whose miscalibration differs by less are equally calibrated on this many pairs. (Pairs
    that share a source or target episode are not independent, so the true error is larger: a
    tight tolerance, i.e. calibration first, sharpness second.)"""
    return float(np.mean([math.sqrt(lv * (1.0 - lv) / max(pairs, 1)) for lv in levels]))


CALIBRATED_FIELDS = ("rel_std", "forecast_rel_std", "forecast_abs_std_n", "forecast_limit_std", "shape_evidence", "shape_abs_std_n",
                     "shape_rel_std", "bound_abs_std_n", "bound_rel_std")  # what ``calibrate`` (and, the bound_*,
# soil_planner_calibrate) chooses, never set with --set; in the fee world also those of TRUTH_GRIDS


def with_shape(cfg: FusionConfig, shape) -> FusionConfig:
    """``cfg`` with the shape evidence of a ``SHAPE_GRID`` entry: None (off) or (floor [N], share)."""
    if shape is None:
        return dataclasses.replace(cfg, shape_evidence=False)
    floor, share = shape
    return dataclasses.replace(cfg, shape_evidence=True, shape_abs_std_n=(floor, floor), shape_rel_std=(share, share))


def forecast_skill(sc: dict) -> tuple[float, float]:
    """(skill, its standard error) of ``forecast_scores``: the median forecast's error as a share of
    the naive forecast's, averaged over the axes (an axis no law forecasts counts as 1 for all)."""
    ratio = np.asarray(sc["error"]) / np.asarray(sc["naive"])
    sem = np.asarray(sc["sem"]) / np.asarray(sc["naive"])
    return float(ratio.mean()), float(sem.mean())


def acceptable_shape_laws(rows: list[tuple]) -> list[tuple]:
    """Stage 1's (shape, skill, sem, ...) rows whose skill is within one standard error of the
    best one's, in grid order (off, then loose to sharp): the laws that forecast as well as any.
    Without the truth to judge the parameters by, the first (the simplest) is taken, as for
    ``rel_std``: a law that teaches more only where it forecasts measurably better."""
    best = min(rows, key=lambda r: r[1])
    return [r for r in rows if r[1] <= best[1] + best[2]]


PARAMETER_LEVELS = (0.5, 0.9)  # the central intervals of φ and c the truth stage judges


def parameter_miscalibration(ds, posts) -> tuple[float, dict]:
    """(mean |coverage − nominal| of the posteriors' 50 % and 90 % intervals of φ and c against
    the episodes' true θ at their ends, ``forecast.parameter_coverage``): meaningful only where
    the model is the world (fee)."""
    cover = fc.parameter_coverage(fc.steady_parts(ds), posts)
    mis = [abs(cover[n][f"coverage_{round(100 * lv)}"] - lv) for n in ("phi", "c") for lv in PARAMETER_LEVELS]
    return float(np.mean(mis)), cover


def shape_text(shape) -> str:
    return "off" if shape is None else f"{shape[0]:g} N + {shape[1]:g}|ΔF|"


def cover_text(cover: dict) -> str:
    return (f"50 % / 90 % intervals hold φ {cover['phi']['coverage_50']:.0%} / {cover['phi']['coverage_90']:.0%}, c "
            f"{cover['c']['coverage_50']:.0%} / {cover['c']['coverage_90']:.0%} (cohesive soils) of the episodes' true soils "
            f"(φ's 90 % interval {math.degrees(cover['phi']['width_90']):.2f}° wide)")


class Candidate(NamedTuple):
    """An evidence law judged where the truth is known (``calibrate``'s truth stage)."""

    skill: float  # median forecasts' error over the naive forecast's (``forecast_skill``)
    sem: float  # its standard error
    miscalibration: float  # of the parameters' intervals (``parameter_miscalibration``)
    config: FusionConfig
    posteriors: list
    width: float  # φ's 90 % interval, mean over the episodes [rad]: the law's sharpness
    cover: dict  # ``forecast.parameter_coverage`` of the posteriors


def judge(ds, sc: dict, trial: FusionConfig, posts: list) -> Candidate:
    """The law ``trial`` with its posteriors of ``ds`` and ``forecast_scores`` ``sc`` as a ``Candidate``."""
    mis, cover = parameter_miscalibration(ds, posts)
    width = cover["phi"]["width_90"]
    return Candidate(*forecast_skill(sc), mis, trial, posts, width if math.isfinite(width) else math.inf, cover)


def most_calibrated(candidates: list[Candidate]) -> Candidate:
    """Of the candidates: those as skilful as any (skill within one standard error of the best),
    of them those whose parameters' intervals are as close to nominal as the closest within the
    coverages' sampling error, and of those the sharpest (narrowest 90 % intervals of φ):
    calibration of the parameters first among the laws that forecast equally well, then
    sharpness, as for the forecast law (stage 2). Why not the most skilful last: with the
    cohesionless row at c = 0 every law's intervals held the fee world's truth in 99-100 % of the
    episodes, and a skill a tenth of its standard error better took a posterior twice as wide as
    it had to be (forecasts' 50 % intervals holding 99 %)."""
    best = min(candidates, key=lambda c: c.skill)
    acceptable = [c for c in candidates if c.skill <= best.skill + best.sem]
    tolerance = coverage_tolerance(sum(p.updates > 0 for p in acceptable[0].posteriors), PARAMETER_LEVELS)
    least = min(c.miscalibration for c in acceptable)
    return min((c for c in acceptable if c.miscalibration <= least + tolerance), key=lambda c: (c.width, c.skill))


def jointly_chosen_rels(ds, shaped: FusionConfig, rels: tuple[float, float], rel_grid=REL_GRID, log=print
                        ) -> tuple[float, float]:
    """``rel_std`` per axis again where stage 1's choice differs between the axes: x on trials that
    hold z at its choice, then z holding x at that (``choose_evidence_law``), one pass. Why: stage 1
    scores trials with one value on both axes, while both axes' evidence makes the one posterior
    both forecasts come from. In the default world z forecasts no better than the force now and
    takes the largest value (0.2); x's 0.005 had been judged with z at 0.005 too, whose z evidence
    taught the posterior so hard that x's forecasts at another depth were 65 % off on the
    calibration pairs, and x went to 0.02 (a pair no trial had fused). With z at 0.2, x's 0.005 is
    14.7 ± 0.7 % off and 0.02 14.3 %: 0.005 again, the shipped law."""
    if rels[0] == rels[1]:
        return rels
    from .evaluate import fused_posteriors

    out = list(rels)
    scores: dict[tuple[float, float], dict] = {}  # (z's pass meets the pair x's chose: fused once)
    for j, axis in enumerate("xz"):
        scored = []
        for rel in rel_grid:
            pair = (rel, out[1]) if j == 0 else (out[0], rel)  # (z with x at its choice of this pass)
            if pair not in scores:
                trial = dataclasses.replace(shaped, rel_std=pair)
                scores[pair] = forecast_scores(forecast_table(ds, trial, levels=(), posts=fused_posteriors(ds, trial)))
            sc = scores[pair]
            scored.append((rel, sc))
            log(f"  rel_std {pair[0]:g} / {pair[1]:g}: median forecasts at another depth off by {sc['error'][0]:.2f} ± "
                f"{sc['sem'][0]:.2f} % of |F_x| (x) / {sc['error'][1]:.2f} ± {sc['sem'][1]:.2f} % of the "
                f"{FORCE_LIMITS_N[1] / 1e3:g} kN limit (z)")
        out[j] = choose_evidence_law(scored)[j]
        log(f"  {axis} with the other axis at its choice: rel_std {out[j]:g}")
    return out[0], out[1]


def calibrate(ds, base: FusionConfig, rel_grid=REL_GRID, forecast_grid=FORECAST_GRID, floor_grid=FLOOR_GRID,
              shape_grid=SHAPE_GRID, truth_grids=(), truth: bool = False, log=print) -> tuple[FusionConfig, list[dict]]:
    """Stage 1: the evidence law. Each shape law of ``shape_grid`` with each ``rel_std`` of
    ``rel_grid`` is fused and scored by its median forecasts at another depth. Without the truth:
    ``rel_std`` per axis by accuracy (``choose_evidence_law``), then the simplest shape law as
    skilful as any (``acceptable_shape_laws``). With it (``truth``: the episodes' θ is the soil,
    i.e. the FEE is the world): of the laws as skilful as any, the one whose intervals of φ and c
    hold the true soils closest to their nominal 50 % and 90 % (``most_calibrated``), and then
    the values of the (field, grid) pairs of ``truth_grids``, every combination, the same way
    (``TRUTH_GRIDS``: the soil's drift; fields that all set how wide the posterior is are chosen
    together, so that one is not chosen for another's value). Why: forecasts at
    another depth tell the laws near the sharp end apart by less than their noise, while how wide
    the posterior is (its evidence law, and the drift that re-widens it before every stretch) is
    what the parameters' intervals measure. Stage 2: the forecast law, share and floor, per axis
    by the calibration curve. Returns the config and every stage-2 candidate's curve."""
    from .evaluate import fused_posteriors

    def logged(judged: Candidate, line: str) -> Candidate:
        log(f"{line}: skill {judged.skill:.3f} ± {judged.sem:.3f}; {cover_text(judged.cover)}")
        return judged

    shapes, candidates = [], []
    for shape in shape_grid:
        scored = []
        for rel in rel_grid:
            trial = dataclasses.replace(with_shape(base, shape), rel_std=(rel, rel))
            posts = fused_posteriors(ds, trial)
            sc = forecast_scores(forecast_table(ds, trial, levels=(), posts=posts))
            scored.append((rel, sc))
            (ex, ez), (sx, sz) = sc["error"], sc["sem"]
            line = (f"shape {shape_text(shape)}, rel_std {rel:g}: median forecasts at another depth off by {ex:.2f} ± "
                    f"{sx:.2f} % of |F_x| (x) / {ez:.2f} ± {sz:.2f} % of the {FORCE_LIMITS_N[1] / 1e3:g} kN limit (z)")
            if truth:
                candidates.append(judge(ds, sc, trial, posts))
                line += f"; {cover_text(candidates[-1].cover)}"
            log(line)
        rels = choose_evidence_law(scored)
        chosen = {k: np.array([dict(scored)[rels[j]][k][j] for j in range(2)]) for k in ("error", "sem", "naive")}
        skill, sem = forecast_skill(chosen)
        log(f"  rel_std {rels[0]:g} / {rels[1]:g}: skill {skill:.3f} ± {sem:.3f} of the naive forecast's error")
        shapes.append((shape, skill, sem, rels))
    if truth:
        chosen = most_calibrated(candidates)
        if truth_grids:  # every combination, and stage 1's own values among them (already judged)
            names = [n for n, _ in truth_grids]
            here = tuple(getattr(chosen.config, n) for n in names)
            combos = list(itertools.product(*(grid for _, grid in truth_grids)))
            trials = []
            for values in combos if here in combos else [here, *combos]:
                text = ", ".join(f"{n} {v:g}" for n, v in zip(names, values))
                if values == here:
                    trials.append(logged(chosen, text))
                    continue
                trial = dataclasses.replace(chosen.config, **dict(zip(names, values)))
                posts = fused_posteriors(ds, trial)
                trials.append(logged(judge(ds, forecast_scores(forecast_table(ds, trial, levels=(), posts=posts)), trial, posts), text))
            chosen = most_calibrated(trials)
            log("  " + ", ".join(f"{n} {getattr(chosen.config, n):g}" for n in names))
        cfg, posts = chosen.config, chosen.posteriors
    else:
        simplest = acceptable_shape_laws(shapes)[0]
        shaped = with_shape(base, simplest[0])
        cfg = dataclasses.replace(shaped, rel_std=jointly_chosen_rels(ds, shaped, simplest[3], rel_grid, log))
        posts = fused_posteriors(ds, cfg)  # the forecast law changes no posterior: fuse once
    return choose_forecast_law(ds, cfg, posts, forecast_grid, floor_grid, log)


def choose_forecast_law(ds, cfg: FusionConfig, posts, forecast_grid=FORECAST_GRID, floor_grid=FLOOR_GRID,
                        log=print, pairs=None) -> tuple[FusionConfig, list[dict]]:
    """Stage 2 (``calibrate``): ``cfg`` with the forecast law per axis, share and floor, by
    the calibration curve of the forecasts at another depth from ``posts`` (``cfg``'s posteriors
    of ``ds``); every law tried with its curve. The law changes no posterior, so this alone
    recalibrates the forecasts of a config whose evidence law is kept (``--forecast-law-only``).
    ``pairs``: ``pair_forecasts(ds, posts)`` when already made."""
    rows = []
    i90, i50 = NOMINAL.index(0.9), NOMINAL.index(0.5)
    every = pairs_of(ds, cfg, posts, pairs)  # the model's forces once; each law only changes the error around them
    pairs = calibrated_reach(every)
    log(f"forecast law: every pair ({len(every)}; none has both depths at least {MIN_CALIBRATED_DEPTH_M:g} m)"
        if pairs is every and every else
        f"forecast law: {len(pairs)} of {len(every)} pairs, both depths at least {MIN_CALIBRATED_DEPTH_M:g} m")
    strata = reach_strata([p.reach_m for p in pairs])
    for floor in floor_grid:
        for frel in forecast_grid:
            law = dataclasses.replace(cfg, forecast_rel_std=(frel, frel), forecast_abs_std_n=(floor, floor),
                                      forecast_limit_std=(0.0, 0.0))  # (its part near the limit: chosen after)
            held = interval_level(predictive_cdf(pairs, law))
            curve = curve_of(held)
            rows.append({"forecast_rel_std": frel, "forecast_abs_std_n": floor, "law": law, "curve": curve,
                         **{f"coverage_{lv}_{a}": curve[a][i] for a in "xz" for lv, i in ((90, i90), (50, i50))},
                         **{f"miscalibration_{a}": miscalibration(curve[a]) for a in "xz"}})
            reach = "; ".join(
                f"reaching {'less far' if k == 0 else 'farther'}: F_x " + " / ".join(f"{c:.0%}" for c in coverages(held[m, 0], (0.9, 0.5)))
                for k, m in enumerate(strata)) if len(strata) > 1 else ""
            log(f"  forecast_rel_std {frel:g}, floor {floor:g} N: 90 % / 50 % intervals hold F_x {curve['x'][i90]:.0%} / "
                f"{curve['x'][i50]:.0%}, F_z {curve['z'][i90]:.0%} / {curve['z'][i50]:.0%} of {curve['pairs']} pairs"
                + (f" ({reach})" if reach else ""))
    # per axis, of the laws calibrated as well as the best within the coverages' sampling error,
    # the sharpest (narrowest mean 90 % interval): sharpness subject to calibration; the widths
    # only of those (a width is a quantile search per pair)
    best = []
    for axis in "xz":
        least = min(r[f"miscalibration_{axis}"] for r in rows)
        calibrated = [r for r in rows if r[f"miscalibration_{axis}"] <= least + coverage_tolerance(len(pairs))]
        for r in calibrated:
            if f"width_{axis}" not in r["curve"]:
                r["curve"] |= interval_widths(pairs, r["law"], max(NOMINAL))
        best.append(min(calibrated, key=lambda r, a=axis: (r["curve"][f"width_{a}"], r[f"miscalibration_{a}"])))
    law = dataclasses.replace(cfg, forecast_rel_std=(best[0]["forecast_rel_std"], best[1]["forecast_rel_std"]),
                              forecast_abs_std_n=(best[0]["forecast_abs_std_n"], best[1]["forecast_abs_std_n"]))
    return choose_limit_shares(pairs, law, log=log), rows


# Shares of each axis's force limit the forecast law's part near the F_x limit may take
# (``forecast_limit_std``): from none to 0.8 of it at the limit (24 kN of F_z).
LIMIT_GRID = (0.0, 0.02, 0.05, 0.1, 0.15, 0.2, 0.3, 0.4, 0.6, 0.8)
# Fewer calibration pairs beyond the planner's margin say too little of how the law holds there:
# the part near the limit stays 0.
MIN_BEYOND_MARGIN_PAIRS = 10


def beyond_margin(pairs: list[PairForecast], law: FusionConfig) -> np.ndarray:
    """Mask of the pairs whose forecast F_x (its median under ``law``) is beyond the planner's margin
    of the F_x limit (``forecast.beyond_planner_margin``, as ``forecast.margin_strata`` splits a report's pairs)."""
    return np.array([bool(fc.beyond_planner_margin(p.posterior.forecast_from(p.predictive, (0.5,), law)["quantiles"][0.5][0]))
                     for p in pairs], bool)


def choose_limit_shares(pairs: list[PairForecast], law: FusionConfig, grid=LIMIT_GRID, log=print) -> FusionConfig:
    """``law`` with the part of its forecast law near the F_x limit per axis (``forecast_limit_std``),
    chosen on the ``pairs`` beyond the planner's margin alone (``beyond_margin``, split under ``law``
    without that part): the smallest share whose calibration curve there is within the coverages'
    sampling error of the best one's. Why apart: a law calibrated over all pairs held the default
    world's F_z in 89 / 60 % of the calibration pairs within the margin and 47 / 24 % beyond it,
    where the lift's push on the floor sets F_z; a share of |ΔF| wide enough there is too wide
    within (and a part near the limit calibrated jointly with it took the share down, worse held
    out). The base law is kept, so a forecast whose samples all lie within the margin is as before
    (one with some samples beyond it widens a little there, its median may move); and an axis whose
    curve over all the pairs would come out less calibrated than without the part, beyond the
    coverages' sampling error, keeps none."""
    law = dataclasses.replace(law, forecast_limit_std=(0.0, 0.0))
    beyond = beyond_margin(pairs, law)
    far = [p for p, b in zip(pairs, beyond) if b]
    if len(far) < MIN_BEYOND_MARGIN_PAIRS:
        log(f"forecast law near the F_x limit: none ({len(far)} pair{'' if len(far) == 1 else 's'} beyond the planner's margin of "
            f"{PLANNER_FORCE_MARGIN:g} x {FORCE_LIMITS_N[0]:g} N, fewer than {MIN_BEYOND_MARGIN_PAIRS})")
        return law
    i90, i50 = NOMINAL.index(0.9), NOMINAL.index(0.5)
    log(f"forecast law near the F_x limit: on the {len(far)} pairs of {len(pairs)} whose forecast F_x is beyond the "
        f"planner's margin ({PLANNER_FORCE_MARGIN:g} x {FORCE_LIMITS_N[0]:g} N)")
    curves = []
    for share in grid:
        curve = curve_of(interval_level(predictive_cdf(far, dataclasses.replace(law, forecast_limit_std=(share, share)))))
        curves.append(curve)
        log(f"  share {share:g} of the limit: 90 % / 50 % intervals hold F_x {curve['x'][i90]:.0%} / {curve['x'][i50]:.0%}, "
            f"F_z {curve['z'][i90]:.0%} / {curve['z'][i50]:.0%}")
    chosen = []
    for axis in "xz":
        mis = [miscalibration(c[axis]) for c in curves]
        # the smallest share (the sharpest: each share widens every interval) as calibrated as the best
        chosen.append(min(share for share, m in zip(grid, mis) if m <= min(mis) + coverage_tolerance(len(far))))
    if any(chosen):  # over all the pairs, not worse than without it
        every = [curve_of(interval_level(predictive_cdf(pairs, cfg))) for cfg in
                 (law, dataclasses.replace(law, forecast_limit_std=tuple(chosen)))]
        for j, axis in enumerate("xz"):
            if chosen[j] and miscalibration(every[1][axis]) > miscalibration(every[0][axis]) + coverage_tolerance(len(pairs)):
                log(f"  {axis}: {chosen[j]:g} would leave the curve over all {len(pairs)} pairs less calibrated "
                    f"({miscalibration(every[1][axis]):.3f} against {miscalibration(every[0][axis]):.3f}): none")
                chosen[j] = 0.0
    log(f"  chosen: x {chosen[0]:g}, z {chosen[1]:g} of the axis's limit")
    return dataclasses.replace(law, forecast_limit_std=tuple(chosen))


def plot_curve(rows: list[dict], final: dict, path: Path, title: str) -> None:
    """Calibration curve: nominal central interval vs the share of forecasts it holds, the sweep
    dotted (each a base law, before its part near the F_x limit), the chosen config solid (x) and dashed (z)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 4))
    ax.plot([0, 1], [0, 1], "k:", lw=1, label="perfect calibration")
    for r in rows:
        ax.plot(NOMINAL, r["curve"]["x"], color="0.8", lw=0.8)
    near = final.get("forecast_limit_std", (0.0, 0.0))
    for j, (axis, style) in enumerate((("x", "-o"), ("z", "--s"))):
        ax.plot(NOMINAL, final["curve"][axis], style, ms=3,
                label=f"F_{axis} (forecast rel {final['forecast_rel_std'][j]:g}{near_limit_text(near[j])})")
    ax.set_xlabel("nominal central interval")
    ax.set_ylabel("share of forecasts holding the measured force")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    save_figure_atomically(fig, path, dpi=110)
    plt.close(fig)


@interruptible("pinn_fusion_calibrate")
def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="pinn_fusion_calibrate", description=__doc__.split("\n\n")[0])
    p.add_argument("--world", choices=WORLD_MODES, required=True)
    p.add_argument("--out", type=output_file, default=None,
                   help="config JSON to write (default: the shipped models/fusion_<world>.json in this package, replaced)")
    p.add_argument("--duration", type=float, default=CAL_DURATION_S,
                   help="calibration episode length [s], in [%g, %g] (default %g; shorter is a quick check: its "
                        "laws come out too sharp)" % (*CAL_DURATION_RANGE_S, CAL_DURATION_S))
    p.add_argument("--term", action="append", default=[], metavar="NAME=K",
                   help="a force term in the posterior's physics beside the FEE (repeatable; a catalogue name or a "
                        "form soil_discrepancy named, e.g. form:-qnq*tanhvx0.1=0.756); saved in the config, so the "
                        "estimator's posterior uses it with any checkpoint (besides the checkpoint's own terms)")
    p.add_argument("--set", dest="fields", action="append", default=[], metavar="FIELD=VALUE",
                   help="a posterior config field the calibration does not choose, set before it (repeatable; VALUE "
                        "as JSON, e.g. cohesionless_prior=0); saved in the config")
    p.add_argument("--forecast-law-only", action="store_true",
                   help="keep the evidence law of the config at --out (if --out names no file yet: the shipped one's) "
                        "and choose only the forecast law (stage 2: about a minute, where the whole calibration takes "
                        "5-8 min)")
    p.add_argument("--force-noise", action="store_true",
                   help="calibrate on episodes with the measured force's noise on (in the fee world: the default "
                        "world's sensor noise, the truth still known); needs --out, since the shipped fee config is "
                        "the noise-free world's")
    add_plugin_option(p, "--out")
    add_soil_options(p)
    args = p.parse_args(argv)
    check_duration_option(p, args.duration)
    from soil_physics.force_terms import parse_terms, refuse_repeats

    from .evaluate import fused_posteriors

    try:
        terms = parse_terms(args.term)
        refuse_repeats(terms)
    except ValueError as err:
        p.error(f"--term: {err}")
    try:
        fields = dict(FusionConfig.parse_field(text) for text in args.fields)
        chosen = sorted(set(fields) & {*CALIBRATED_FIELDS, *((f for f, _ in TRUTH_GRIDS) if args.world == "fee" else ())})
        if chosen:
            raise ValueError(f"{chosen[0]} is chosen by the calibration")
        if "terms" in fields:
            raise ValueError("terms is set by --term")
        if "world" in fields:
            raise ValueError("world is set by --world")
        if "calibration_plugins" in fields:
            raise ValueError("calibration_plugins is set by --plugin")
        if "calibration_soils" in fields:
            raise ValueError("calibration_soils is set by --soil-file/--soils")
        base = FusionConfig(terms=terms).with_fields(fields)
    except ValueError as err:
        p.error(f"--set: {err}")
    checked_world_options(p, args, "--out", args.out)
    out = args.out or config_path(args.world)
    shipped_out = Path(out).resolve() == config_path(args.world).resolve()  # (--out naming it by another path too)
    if args.forecast_law_only:
        if args.term or args.fields:
            p.error("--forecast-law-only keeps the config's posterior: --term and --set change it (run the whole calibration)")
        # a new --out keeps the shipped config's evidence law (it was refused, though the help said so)
        kept = out if out.is_file() else config_path(args.world)
        if args.force_noise and kept != out:  # the shipped evidence law is the noise-free world's
            p.error(f"--forecast-law-only --force-noise: no config at {out} yet; the shipped one's evidence law is "
                    "the world's as it is, not a noisy sensor's: run the whole calibration with --force-noise first")
        if not kept.is_file():
            p.error(f"--forecast-law-only: no config file at {out} or {kept} to keep the evidence law of")
        try:
            base = FusionConfig.load(kept)
        except (OSError, ValueError) as err:
            p.error(f"--forecast-law-only: {kept}: {err}")
        try:
            note = world_note(base, kept, args.world)
        except ValueError as err:
            p.error(f"--forecast-law-only: {err} (run the whole calibration)")
        if note:  # (it is written with the world it is recalibrated in)
            print(f"--forecast-law-only: {note}", file=sys.stderr, flush=True)
        kept_plugins(p, args, base, kept)  # (the evidence law kept is that of the world with its plugins)
        kept_soils(p, args, base, kept)  # (and of its soils)
        if kept != out:
            print(f"--forecast-law-only: keeping the evidence law of {kept}; writing {out}", flush=True)
    term_note(p.prog, args.world, base.terms, args.plugin)
    if not args.forecast_law_only and (lacking := missing_shipped_terms(base, args.world)):
        given = " ".join(f'--term "{name}={k!r}"' for name, k in lacking)
        print(f"{p.prog}: warning: the shipped {args.world}-world config's posterior has "
              f"{', '.join(name for name, _ in lacking)} beside the FEE, this one not: its forecasts at other depths "
              f"will be far worse unless that is what you want to find out; {given} keeps it",
              file=sys.stderr, flush=True)
    if not args.forecast_law_only and shipped_out and (changed := shipped_settings_note(base, out, args.world)):
        print(f"{p.prog}: warning: this run rewrites the shipped {out} with settings other than its own: {changed}. "
              f"The shipped config is made with the arguments of scripts/fusion_args.sh (make models); --out FILE "
              "writes elsewhere", file=sys.stderr, flush=True)
    ds = calibration_episodes(p, args)
    if args.forecast_law_only:
        pairs = pair_forecasts(ds, fused_posteriors(ds, base))
        cfg, rows = choose_forecast_law(ds, base, None, pairs=pairs)
    else:
        # the drift is chosen where the episodes' θ is the truth, i.e. the FEE is the world
        truth = args.world == "fee"
        cfg, rows = calibrate(ds, base, truth_grids=TRUTH_GRIDS if truth else (), truth=truth)
        # new posteriors: the planner's bound law is to be calibrated on them again
        cfg = dataclasses.replace(cfg, bound_abs_std_n=None, bound_rel_std=None)
        pairs = pair_forecasts(ds, fused_posteriors(ds, cfg))  # (the forecast law changes no posterior)
    cfg = dataclasses.replace(cfg, world=args.world, calibration_plugins=tuple(args.plugin),
                              calibration_soils=soil_records(*args.calibration_soils))
    cfg.save(out)
    final = {"forecast_rel_std": cfg.forecast_rel_std,
             "curve": coverage_curve(ds, cfg, pairs=calibrated_reach(pairs), width=False)}
    final["forecast_abs_std_n"], final["forecast_limit_std"] = cfg.forecast_abs_std_n, cfg.forecast_limit_std
    plot_curve(rows, final, out.with_suffix(".png"),
               f"fused forecast at another depth, {args.world} world{' (noisy force)' if args.force_noise else ''}"
               f"{' with plugins' if args.plugin else ''}: calibration episodes")
    i90, i50 = NOMINAL.index(0.9), NOMINAL.index(0.5)
    cx, cz = final["curve"]["x"], final["curve"]["z"]
    shape = (f"shape evidence {shape_text((cfg.shape_abs_std_n[0], cfg.shape_rel_std[0]))}" if cfg.shape_evidence
             else "no shape evidence")
    print(f"wrote {out} ({shape}, rel_std x {cfg.rel_std[0]:g} / z {cfg.rel_std[1]:g}, forecast law x {cfg.forecast_abs_std_n[0]:g} N + "
          f"{cfg.forecast_rel_std[0]:g}|ΔF|{near_limit_text(cfg.forecast_limit_std[0])}, z {cfg.forecast_abs_std_n[1]:g} N + "
          f"{cfg.forecast_rel_std[1]:g}|ΔF|{near_limit_text(cfg.forecast_limit_std[1])}: 90 % / 50 % "
          f"intervals hold F_x {cx[i90]:.0%} / {cx[i50]:.0%}, F_z {cz[i90]:.0%} / {cz[i50]:.0%} of the pairs from "
          f"{MIN_CALIBRATED_DEPTH_M:g} m) and {out.with_suffix('.png')}")
    law = cfg.planner_bound_law()
    again = (f"soil_planner_calibrate --world {args.world}" + ("" if shipped_out else f" --config {out}")
             + (f" --duration {args.duration:g}" if args.duration != CAL_DURATION_S else "") + (" --force-noise" if args.force_noise else "")
             + (f" --soil-file {args.soil_file}" if args.soil_file else "") + (f" --soils {args.soils}" if args.soils else "")
             + plugin_words(args.plugin))
    print(f"the planner's bound law: {'kept, ' + error_law_text(law) if law else 'none'}"
          f" ({again} calibrates it on these posteriors)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
