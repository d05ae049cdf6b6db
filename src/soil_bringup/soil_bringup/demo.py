"""`make demo`: the online PINN estimator, live, over the four soils at two relative densities.

Starts the graph through ``soil_bringup.launch`` (the ``soil_launch`` machinery: simulator +
anti-stall controller + ``pinn_estimator`` + recorder, each its own process, DDS on loopback
only, stopped in data-flow order) for a plan of episodes (soils x I_d, default Clay, Loam,
Sand, Gravel at 20 % and 80 %, 10 s each, real time at 60 Hz) and, while it runs, prints one
line per second of simulation time from an in-process monitor node (``monitor``): estimated vs
true φ, c, δ, β and predicted vs measured blade force. When the launch has ended cleanly it
scores the recorded bags (``scoring``: the record of truth, every tick, every estimate) per
episode, over valid estimates only: force MAE x/z [kN, % of measured] (paper §3.2 figures),
φ, c, δ, β MAE against the pseudo-ground truth, and the share of ticks with a valid estimate;
and it answers the planner's question from them (``demo_forecast``: from the soil learnt in each
episode, the force at other depths, against the simulator cutting the same soil there).
It prints a table and writes ``summary.md``, ``summary.json`` (``summary``) and
``online_estimates.png`` (``summary_figure``) under ``--out``. This module is the command line
and the order of things only.

    python -m soil_bringup.demo                                # real time, ~2 min
    python -m soil_bringup.demo --pacing lockstep              # as fast as the machine goes
    python -m soil_bringup.demo --soils Clay Sand --densities 40 --duration 5 --rate 2
    python -m soil_bringup.demo --depth 0.15 --speed 0.4      # every episode's target cut
    python -m soil_bringup.demo --soil-file my_soils.yaml --soils Silt Clay   # soils of one's own

A real-time run whose controller could not keep up (more than ``LATE_SHARE`` of its ticks'
commands late) says so beside its table.

Exit codes: 0 done; 1 the launch failed or a bag is missing / has no valid estimate; 2 bad
arguments; 130 interrupted. Every wait is bounded; the launch (and its nodes) are stopped on
the way out whatever happens.
"""
from __future__ import annotations

import argparse
import itertools
import math
import os
import shutil
import signal
import sys
import time
from pathlib import Path

from pinn_estimator.shipped import DEFAULT_WORLD, shipped_checkpoint
from soil_bag_tools.bag_io import PARTIAL_SUFFIX, is_bag
from soil_msgs_py import strict_json
from soil_msgs_py import graph as G
from soil_msgs_py.cli_paths import input_text, output_dir
from soil_msgs_py.episode import MAX_EPISODE_S, WORLD_MODES
from soil_physics.soils import CATALOGUE
from soil_msgs_py.interrupts import EXIT_INTERRUPTED, EXIT_TERMINATED
from soil_msgs_py.params import (DEFAULT_TARGET_DEPTH_M, DEFAULT_TARGET_SPEED_M_S, LIFT_REACH_M, MIN_CUT_DEPTH_M,
                                  MIN_PLANNED_DEPTH_M, SAMPLE_RATE_HZ, WINDOW_SAMPLES, beyond_lift_reach)

from . import launch as L
from .demo_forecast import OTHER_DEPTH_FACTORS, depths_text, forecast_from_live, other_depths
from .demo_forecast import markdown_lines as forecast_lines
from .monitor import MONITOR_DATA_TOPICS, LiveMonitor
from .scoring import missing_episodes, overall, score_bag_dir
from .summary import FIGURE_NAME, JSON_NAME, MARKDOWN_NAME, markdown, table_text, throughput_text
from .summary_figure import plot

DEFAULT_SOILS = tuple(CATALOGUE)
DEFAULT_DENSITIES_PCT = (20.0, 80.0)
DEFAULT_DOMAIN_ID = 42
# In lockstep the simulator runs ~6x real time and the estimator trails it by up to ~1 s of wall
# time (estimate latency p99 0.2-1.1 s, 2026-12-04): each episode starts this long after the one
# before, so the live lines show an episode's last estimates before the next one's begin [s].
LOCKSTEP_SETTLE_S = 1.5
EXIT_FAILED = 1
# A real-time run whose ticks' commands came late in more than this share said so (a graph that did
# not keep up with its --rate: 119 of 120 late at --rate 1000, an outside tester's, with a normal table)
LATE_SHARE = 0.1
LAUNCH_FAILURES = {L.EXIT_NODE_DIED: "a node died or failed: see the log", L.EXIT_TIMEOUT: "timeout",
                   G.EXIT_EPISODE_FAILED: "an episode ended in error"}


DEFAULT_BAGS = Path("bags/demo_online")
OWNER_MARK = ".soil_demo_bags"  # a file the demo writes into its --bags directory: only such a directory it clears
OWNER_MARK_TEXT = ("The episode bags in this directory are soil_demo's: each demo run deletes them before it records its own.\n"
                   "Record bags you want to keep elsewhere.\n")


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="soil_demo", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--soils", nargs="+", default=list(DEFAULT_SOILS), metavar="SOIL",
                   help="soils in the order run: the catalogue's or --soil-file's (default: %(default)s)")
    p.add_argument("--soil-file", type=Path, metavar="FILE",
                   help="YAML of custom soils (soil_sim_batch --soil-file's format): its soils may be named in "
                        "--soils; the simulator, the scoring and the forecast at other depths all use them")
    p.add_argument("--densities", nargs="+", type=float, default=list(DEFAULT_DENSITIES_PCT), metavar="PCT",
                   help="relative densities I_d [%%] per soil (default: 20 80)")
    p.add_argument("--duration", type=float, default=10.0, help="episode length [s] of simulation time (default 10)")
    p.add_argument("--depth", type=float, default=DEFAULT_TARGET_DEPTH_M,
                   help=f"target cut depth d̄_z [m] of every episode (default {DEFAULT_TARGET_DEPTH_M:g}, at least "
                        f"{MIN_CUT_DEPTH_M:g}); the forecast then goes to {' and '.join(f'{f:g}' for f in OTHER_DEPTH_FACTORS)} "
                        f"times it, within {MIN_PLANNED_DEPTH_M:g}-{LIFT_REACH_M:g} m")
    p.add_argument("--speed", type=float, default=DEFAULT_TARGET_SPEED_M_S,
                   help=f"target forward speed v̄_x [m/s] (default {DEFAULT_TARGET_SPEED_M_S:g})")
    p.add_argument("--pacing", choices=("realtime", "lockstep"), default="realtime",
                   help="realtime: 60 Hz ticks on the wall clock x --rate (the honest online demo, default); "
                        "lockstep: each tick waits for the controller, as fast as the machine goes")
    p.add_argument("--rate", type=float, default=None, help="real-time factor for --pacing realtime (default 1)")
    p.add_argument("--world-mode", choices=WORLD_MODES, default=None,
                   help="simulator world (default: the simulator's, 'default')")
    p.add_argument("--checkpoint", type=Path,
                   help="PINN checkpoint for the estimator (default: the world's shipped one, pinn_<world>.pt)")
    p.add_argument("--fusion-config", metavar="FILE", type=input_text,
                   help="the estimator's fused-posterior config, for the live run and the forecast at other depths "
                        "(default: the shipped calibration of the checkpoint's world; pinn_fusion_calibrate --out makes one)")
    p.add_argument("--out", type=output_dir, default="out/demo", help="summary, PNG and launch log (default out/demo)")
    p.add_argument("--bags", type=Path, default=DEFAULT_BAGS,
                   help="episode bags; cleared at start, if the demo made the directory (its .soil_demo_bags file; "
                        "default bags/demo_online)")
    L.add_domain_id_option(p, DEFAULT_DOMAIN_ID)
    p.add_argument("--no-forecast", action="store_true",
                   help="skip the forecast at other depths (the simulator cutting each episode's soil at "
                        f"{depths_text()} m after the run, for the default --depth)")
    p.add_argument("--timeout", type=float, default=0.0,
                   help="give the launch at most this many seconds (default: from the plan)")
    args = p.parse_args(argv)
    from soil_physics.soils import get_soil, load_soil_file, soil_file_notes

    args.custom_soils = {}
    if args.soil_file is not None:
        try:
            args.custom_soils = load_soil_file(args.soil_file.expanduser()).soils
        except (OSError, ValueError) as err:
            p.error(f"--soil-file: {err}")
        args.soil_file = args.soil_file.expanduser().resolve()  # the simulator node reads it from its own cwd
        for note in soil_file_notes(args.custom_soils):
            print(f"demo: --soil-file {args.soil_file}: {note}", file=sys.stderr)
    try:
        args.soils = [get_soil(s, args.custom_soils).name
                      for s in itertools.chain.from_iterable(x.split(",") for x in args.soils) if s]
    except ValueError as err:
        p.error(f"--soils: {err}")
    if not args.soils:
        p.error("--soils: no soil given")
    if not all(0.0 <= d <= 100.0 for d in args.densities):
        p.error(f"--densities {args.densities}: each must be in [0, 100] %")
    if not (0 < args.duration <= MAX_EPISODE_S):  # the simulator's own limit, checked before the graph starts
        p.error(f"--duration {args.duration} must be in (0, {MAX_EPISODE_S:g}] s")
    if args.duration * SAMPLE_RATE_HZ < WINDOW_SAMPLES + 1:
        p.error(f"--duration {args.duration} s is shorter than one estimator window "
                f"({WINDOW_SAMPLES} samples = {WINDOW_SAMPLES / SAMPLE_RATE_HZ:g} s): no estimate could be made")
    _check_episodes(p, args)
    L.check_graph_options(p, args)  # (soil_launch's: the graph would refuse them once up)
    args.rate = 1.0 if args.rate is None else args.rate
    if args.checkpoint is not None:
        if not args.checkpoint.is_file():
            p.error(f"--checkpoint {args.checkpoint}: no such file")
        args.checkpoint = args.checkpoint.resolve()
        # a model the online estimator cannot run (physics-free, another window) is refused here, not
        # after the graph started (the estimator's refusal then failed the launch seconds later)
        from pinn_estimator.checkpoint import load_model
        from pinn_estimator.online import check_compatible

        try:
            check_compatible(load_model(args.checkpoint)[0])
        except (OSError, ValueError, RuntimeError, KeyError) as err:
            p.error(f"--checkpoint {args.checkpoint}: {err}")
    else:  # the world's shipped model, named: the live estimates and the forecast beside them use one model
        args.checkpoint = shipped_checkpoint(args.world_mode or DEFAULT_WORLD)
    if args.fusion_config:  # unreadable, or another world's: refused before the graph starts (as soil_cut_report)
        from pinn_estimator.fusion_calibration import given_fusion

        try:
            given_fusion(args.fusion_config, args.world_mode or DEFAULT_WORLD,
                         lambda note: print(f"demo: note: {note}", file=sys.stderr))
        except ValueError as err:
            p.error(str(err))
        args.fusion_config = str(Path(args.fusion_config).expanduser().resolve())  # (the estimator's cwd is its own)
    if args.bags.resolve() in (Path.cwd().resolve(), Path.home().resolve(), Path("/")):
        p.error(f"--bags {args.bags}: refusing to clear that directory")
    return args


def _check_episodes(p: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Every planned episode through the simulator's own checks (ranges, a soil the blade can cut at
    that depth in that world), before the graph starts: the node would refuse it seconds later."""
    from soil_sim_node.simulator import EpisodeSpec, SimConfig, resolve_checked

    if math.isfinite(args.depth) and 0.0 <= args.depth < MIN_CUT_DEPTH_M:
        p.error(f"--depth {args.depth:g}: the blade cuts from {MIN_CUT_DEPTH_M:g} m (shallower it skims the surface: "
                "no evidence about the soil)")
    config = SimConfig(world_mode=args.world_mode or DEFAULT_WORLD)
    for soil, density in itertools.product(args.soils, args.densities):
        try:
            resolve_checked(config, EpisodeSpec(soil, density, args.speed, args.depth, seed=0, duration_s=args.duration),
                            args.custom_soils)
        except ValueError as err:
            option = "--depth" if "target_depth_m" in str(err) else "--speed" if "target_speed_m_s" in str(err) else \
                f"--soils {soil} --densities {density:g}"
            p.error(f"{option}: {err}")
    if note := beyond_lift_reach("--depth", args.depth):
        print(f"demo: {note}", file=sys.stderr)


def planned_seconds(args: argparse.Namespace, episodes: int) -> float:
    """A generous bound on the launch's run time (the launch's own --timeout)."""
    per_episode = args.duration / args.rate if args.pacing == "realtime" else args.duration
    return 60.0 + episodes * (per_episode + 12.0)


def prepare_bag_dir(root: Path, *, adopt_unmarked: bool = False) -> bool:
    """Empty ``root`` of a previous demo's bags; True if something was removed.

    Never deletes data that is not ours: it clears only a directory the demo marked as its own
    (``OWNER_MARK``, written where it made the directory or found it empty), and there only
    episode bags (a link to one: the link) and recorder journals. A directory holding anything
    else, or bags another tool recorded (``soil_launch --record``, ``soil_sim_batch``: a directory
    without the mark), is refused (ValueError) and left as it is. ``adopt_unmarked``: the default
    directory, which the README has always said each run clears, is cleared without the mark too
    (a demo of before the mark left none there)."""
    if not root.exists():
        root.mkdir(parents=True)
        (root / OWNER_MARK).write_text(OWNER_MARK_TEXT, encoding="utf-8")
        return False
    if not root.is_dir():
        raise ValueError(f"--bags {root} exists and is not a directory")
    entries = sorted(e for e in root.iterdir() if e.name != OWNER_MARK)
    foreign = [e for e in entries if not (e.is_dir() and (is_bag(e) or e.name.endswith(PARTIAL_SUFFIX)))]
    if foreign:
        what = "entry that is not an episode bag" if len(foreign) == 1 else "entries that are not episode bags"
        raise ValueError(f"--bags {root} holds {len(foreign)} {what} (e.g. {foreign[0].name}); "
                         "not clearing it - choose another --bags")
    if entries and not adopt_unmarked and not (root / OWNER_MARK).is_file():
        what = "episode bag" if len(entries) == 1 else "episode bags"
        raise ValueError(f"--bags {root} holds {len(entries)} {what} the demo did not record (e.g. {entries[0].name}; "
                         f"no {OWNER_MARK} file beside them, which the demo writes into its own directory, since "
                         "2026-12-08); not clearing it - choose another --bags, or delete them yourself if they are "
                         "an older demo's")
    for e in entries:
        e.unlink() if e.is_symlink() else shutil.rmtree(e)
    (root / OWNER_MARK).write_text(OWNER_MARK_TEXT, encoding="utf-8")
    return bool(entries)


def launch_arguments(args: argparse.Namespace, launch_timeout_s: float) -> argparse.Namespace:
    """The ``soil_launch`` arguments of this plan (what ``soil_launch`` would be given on its command line)."""
    def floats(xs):
        return "[" + ",".join(repr(float(x)) for x in xs) + "]"

    # (the estimator is what the demo shows: required, so its death stops the run at once)
    argv = ["--estimator", "--require", "estimator", "--record", str(args.bags), "--pacing", args.pacing,
            "--domain-id", str(args.domain_id), "--timeout", f"{launch_timeout_s:.0f}",
            "--sim-param", f"sequence_soils:=[{','.join(args.soils)}]",
            "--sim-param", f"sequence_relative_densities_pct:={floats(args.densities)}",
            "--sim-param", f"duration_s:={float(args.duration)!r}", "--sim-param", "episodes:=1",
            "--sim-param", f"target_depth_m:={float(args.depth)!r}",
            "--sim-param", f"target_speed_m_s:={float(args.speed)!r}"]
    if args.pacing == "realtime":
        argv += ["--rate", repr(float(args.rate))]
    else:
        argv += ["--sim-param", f"settle_s:={LOCKSTEP_SETTLE_S!r}"]
    if args.world_mode:
        argv += ["--sim-param", f"world_mode:={args.world_mode}"]
    if args.soil_file is not None:
        argv += ["--sim-param", f"soil_file:={args.soil_file}"]
    if args.checkpoint is not None:
        argv += ["--estimator-param", f"checkpoint:={args.checkpoint}"]
    if args.fusion_config:
        argv += ["--estimator-param", f"fusion_config:={args.fusion_config}"]
    # The simulator holds each episode until its 'wait_for' endpoints have matched (counts,
    # '>='). The monitor's subscriptions would count towards the recorder's and estimator's:
    # add them, so every node and the monitor have matched before tick 0.
    for topic in (G.SIM_STATUS_TOPIC, *MONITOR_DATA_TOPICS):
        argv += ["--wait-for", f"{topic}:1"]
    return L.parse_args(argv)


def _tail(path: Path, lines: int = 30) -> str:
    try:
        return "\n".join(path.read_text(errors="replace").splitlines()[-lines:])
    except OSError as err:
        return f"(cannot read {path}: {err})"


def _interrupt(signum, frame):  # noqa: ARG001
    raise KeyboardInterrupt


def _say_stopping() -> None:
    print("\ndemo: interrupted; stopping the launch and its nodes ...", flush=True)


def run(args: argparse.Namespace) -> int:
    t_start = time.monotonic()
    pairs = list(itertools.product(args.soils, args.densities))
    args.out.mkdir(parents=True, exist_ok=True)
    log_path = args.out / "launch.log"
    # A previous run killed outright could not stop its nodes (they stop with it where launcher_death can
    # arrange it, not everywhere); on our domain they would join this run.
    left_behind = L.stop_logged_nodes(log_path)
    if left_behind:
        print(f"demo: killed nodes a previous run left behind: {', '.join(left_behind)}", flush=True)
    try:
        cleared = prepare_bag_dir(args.bags, adopt_unmarked=args.bags.resolve() == DEFAULT_BAGS.resolve())
    except (ValueError, OSError) as err:
        print(f"demo: {err}", file=sys.stderr)
        return L.EXIT_BAD_ARGS
    print(f"demo: {len(pairs)} episode(s): {', '.join(args.soils)} x I_d {', '.join(f'{d:g}' for d in args.densities)} %, "
          f"{args.duration:g} s each at {args.depth:g} m and {args.speed:g} m/s, pacing {args.pacing}" + (f" x{args.rate:g}" if args.pacing == "realtime" else "")
          + f", ROS_DOMAIN_ID {args.domain_id} (loopback only)")
    print(f"demo: bags -> {args.bags}/" + (" (cleared the previous demo's bags)" if cleared else "")
          + f"; node output -> {log_path}")

    # DDS on loopback for this process (the monitor) as for every node, before rclpy is imported.
    os.environ.pop("ROS_LOCALHOST_ONLY", None)
    os.environ.update(L.loopback_env(args.domain_id))

    launch_timeout = args.timeout or planned_seconds(args, len(pairs))
    old_term = signal.signal(signal.SIGTERM, _interrupt)
    monitor = None
    rc: int | None = None
    t_launch = time.monotonic()
    try:
        with log_path.open("w") as log:
            try:
                launch = L.launch_for(launch_arguments(args, launch_timeout), out=log, on_interrupt=_say_stopping)
            except (FileNotFoundError, ValueError) as err:
                print(f"demo: cannot build the launch: {err}", file=sys.stderr)
                return EXIT_FAILED
            try:
                monitor = LiveMonitor(args.domain_id, len(pairs))
            except Exception as err:  # noqa: BLE001 - no live lines, but the run and its scoring still work
                print(f"demo: live monitor unavailable ({err!r}); running without live lines", flush=True)
            t_launch = time.monotonic()
            try:
                rc = launch.run()  # owns Ctrl-C / SIGTERM until its nodes are stopped
            except OSError as err:
                print(f"demo: soil_launch could not start a node: {err}", file=sys.stderr)
            if launch.interrupted:  # Ctrl-C or SIGTERM, said as soil_launch says it (130 / 143)
                rc = EXIT_TERMINATED if launch.signal == signal.SIGTERM else EXIT_INTERRUPTED
    except KeyboardInterrupt:  # before the launch took over the signals: no node runs yet
        _say_stopping()
        rc = EXIT_INTERRUPTED
    finally:
        # A second Ctrl-C must not abandon the monitor's shutdown half-way (it is bounded by itself).
        old_int = signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        try:
            if monitor is not None:
                monitor.close()
        finally:
            signal.signal(signal.SIGINT, old_int)
            signal.signal(signal.SIGTERM, old_term)
    launch_s = time.monotonic() - t_launch
    if rc in (EXIT_INTERRUPTED, EXIT_TERMINATED):
        print(f"demo: interrupted after {launch_s:.0f} s; partial bags in {args.bags}/, node output in {log_path}")
        return rc
    if rc != 0:
        why = LAUNCH_FAILURES.get(rc, "see the log") if rc is not None else "it did not finish"
        print(f"demo: FAILED - soil_launch exit code {rc} ({why}) after {launch_s:.0f} s. "
              f"Node output: {log_path}; its last lines:", file=sys.stderr)
        print(_tail(log_path), file=sys.stderr)
        return EXIT_FAILED
    if monitor is not None:
        for problem, n in monitor.problems.most_common(5):
            print(f"demo: monitor: {problem} (x{n})")
    return report(args, pairs, monitor, t_start, launch_s, log_path)


def report(args, pairs, monitor, t_start: float, launch_s: float, log_path: Path) -> int:
    """Score the bags, print the table and where everything is; non-zero if an episode is missing."""
    print(f"\ndemo: launch finished in {launch_s:.1f} s; scoring the bags in {args.bags}/ ...", flush=True)
    scored = score_bag_dir(args.bags)
    scores, errors = scored.scores, list(scored.problems)
    missing = missing_episodes(scores, pairs)
    if missing:
        errors.append(f"no usable bag for {len(missing)} of {len(pairs)} planned episode(s): {', '.join(missing)} "
                      f"(found {len(scored.bags)} bag(s) in {args.bags}/; node output in {log_path})")
    if not scores:
        for e in errors:
            print(f"demo: ERROR: {e}", file=sys.stderr)
        print(f"demo: FAILED - nothing to score. Node output: {log_path}; its last lines:", file=sys.stderr)
        print(_tail(log_path), file=sys.stderr)
        return EXIT_FAILED

    rows = [s.summary for s in scores]
    total = overall(scores)
    # Throughput from the monitor's wall clock: the span from each episode's first to its last
    # valid estimate (what the estimator sustains online; 60/s = every tick at 60 Hz).
    live = {ep.name: ep for ep in (monitor.episodes if monitor is not None else [])}
    estimating, warnings = [], []
    for r in rows:
        ep = live.get(r["name"])
        if ep is None:
            continue
        r["live"] = ep.summary(r["valid_estimates"])
        if ep.estimating_s > 0:
            estimating.append((r["valid_estimates"], ep.estimating_s))
        if ep.reason and ep.reason != "completed":
            errors.append(f"episode {r['name']} ended with reason {ep.reason!r} (see {log_path})")
        if ep.ticks and ep.late_commands > LATE_SHARE * ep.ticks:
            warnings.append(f"episode {r['name']}: the commands of {ep.late_commands} of its {ep.ticks} ticks came after "
                            f"their real-time deadline: the graph did not keep up with --rate {args.rate:g}, and its "
                            "figures are the cut of a controller that lagged (a lower --rate, or --pacing lockstep)")
    per_wall = sum(n for n, _ in estimating) / sum(w for _, w in estimating) if estimating else None
    sim_s = total["ticks"] / SAMPLE_RATE_HZ
    wall_s = time.monotonic() - t_start
    run_info = {
        "soils": args.soils, "densities_pct": [float(d) for d in args.densities], "duration_s": args.duration,
        "target_depth_m": args.depth, "target_speed_m_s": args.speed,
        "pacing": args.pacing, "rate": args.rate if args.pacing == "realtime" else None,
        "world_mode": args.world_mode, "checkpoint": str(args.checkpoint), "fusion_config": args.fusion_config or None,
        "soil_file": str(args.soil_file) if args.soil_file else None,
        "domain_id": args.domain_id, "bags": str(args.bags), "launch_log": str(log_path),
        "launch_s": launch_s, "wall_s": wall_s, "simulated_s": sim_s,
        "valid_estimates": total["valid_estimates"],
        "estimates_per_wall_s_estimating": per_wall,
        "estimates_per_launch_s": total["valid_estimates"] / launch_s if launch_s > 0 else None,
        "estimates_per_sim_s": total["valid_estimates"] / sim_s if sim_s else 0.0,
        "valid_fraction": total["valid_estimates"] / total["ticks"] if total["ticks"] else 0.0,
        "errors": errors, "warnings": warnings,
    }
    result = {"run": run_info, "episodes": rows, "overall": total}
    if not args.no_forecast:
        depths = other_depths(args.depth)
        print("demo: the planner's question: the simulator cuts each episode's soil at "
              f"{depths_text(depths)} m ...", flush=True)
        try:
            result["forecast"] = forecast_from_live(scores, args.world_mode, depths, checkpoint=args.checkpoint,
                                                    fusion_config=args.fusion_config or "", custom_soils=args.custom_soils)
        except Exception as err:  # noqa: BLE001 - the run's own summary is written whatever this does
            result["forecast"] = {"skipped": f"{type(err).__name__}: {err}"}
    paths = {"json": args.out / JSON_NAME, "markdown": args.out / MARKDOWN_NAME, "png": args.out / FIGURE_NAME}
    plot(scores, paths["png"])
    run_info["wall_s"] = wall_s = time.monotonic() - t_start
    paths["markdown"].write_text(markdown(result))
    # strict JSON: a figure with nothing to score (NaN) is null, which JSON.parse reads
    paths["json"].write_text(strict_json.dumps(result, indent=1, default=float) + "\n")

    print()
    print(table_text(rows, total))
    print("MAE over valid estimates; (%) of the mean measured |F|. φ/c/δ/β against the pseudo-ground truth.")
    if "forecast" in result:
        print("\n" + ("\n".join(forecast_lines(result["forecast"])) if "skipped" not in result["forecast"]
                      else f"forecast at other depths skipped: {result['forecast']['skipped']}"))
    print(f"\ndemo: wall time {wall_s:.1f} s (launch {launch_s:.1f} s for {sim_s:.0f} s of simulation time)")
    print(f"demo: {throughput_text(run_info)}")
    print(f"demo: {100 * run_info['valid_fraction']:.1f} % of ticks have a valid estimate "
          f"({total['pct_full_window_ticks_valid']:.1f} % of those ending a full {WINDOW_SAMPLES}-sample window)")
    print(f"demo: bags    {args.bags}/ ({len(scored.bags)} episode bag(s), with /soil/estimate)")
    print(f"demo: table   {paths['markdown']}  (+ {paths['json'].name})")
    print(f"demo: figure  {paths['png']}")
    print(f"demo: log     {log_path}")
    for w in warnings:
        print(f"demo: warning: {w}", file=sys.stderr)
    if errors:
        for e in errors:
            print(f"demo: ERROR: {e}", file=sys.stderr)
        return EXIT_FAILED
    return 0


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        sys.stdout.reconfigure(errors="replace")
    except (AttributeError, ValueError):
        pass
    try:
        return run(args)
    except KeyboardInterrupt:
        print("\ndemo: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == "__main__":
    raise SystemExit(main())
