"""The planner's margin and force quantile: volume against stall over several paths. Prints figures; asserts nothing.

    .venv/bin/python benchmarks/bench_planner_margin.py
    .venv/bin/python benchmarks/bench_planner_margin.py --settings 0.8,0.95 0.9,0.95 --paths main_default
    .venv/bin/python benchmarks/bench_planner_margin.py --force-lift 1.0   # every policy's controller lifts with the force too
    .venv/bin/python benchmarks/bench_planner_margin.py --settings 0.8,0.95 0.85,0.95 --seeds 3   # each path with 3 seeds

The soil-aware planner cuts to the deepest depth whose ``force_quantile`` upper quantile of
force stays within ``margin`` × the 20 kN / 30 kN limits. Both trade volume for stall, and the
trade depends on the path, so one path says little: every path below runs the closed loop of
``soil_cut_report`` (``soil_bringup.cut_trial``: simulator, controller, estimator, planner and
schedule; deterministic) once per setting, against the same path's fixed-depth sweep
(conservative: the deepest depth that never stalls in the path's strongest soil; aggressive:
the best fixed depth of its weakest soil; ceiling: each patch at its own best fixed depth).
Per setting it prints each path's volume per metre over the conservative depth's, its stall
time, how many of the patches it entered the planned depth reached within 20 % of their best
fixed depth within 2 s (the cut report's "settled"; the first patch, where the cut starts, is no
change), and the totals per world. About 2 min for 7 paths × 5 settings on 2 cores
(``--workers``). ``--seeds N`` runs every default-world path with N seeds (its own, then +100,
+200, ...; the fee world has no noise): one seed's closed loop moves by tenths of a second of stall.
"""
from __future__ import annotations

import os

# no DDS here (the loop runs in-process), but nothing this project runs ever leaves loopback
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
os.environ.setdefault("ROS_DOMAIN_ID", "67")

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import time  # noqa: E402
from concurrent.futures import ProcessPoolExecutor  # noqa: E402

from soil_bringup.cut_report import TARGET_SETTLE_S, WITHIN  # noqa: E402

# name: (world, patches 'x:soil:I_d', seed); 45 s cuts at the controller's default speed. The
# default world's five are four soil sequences: the main path's twice, at seeds 3 and 5.
PATHS = {
    "main_default": ("default", ("0:Sand:20", "10:Clay:80", "16:Loam:50"), 3),
    "main_default_s5": ("default", ("0:Sand:20", "10:Clay:80", "16:Loam:50"), 5),
    "gravel_clay_sand_default": ("default", ("0:Gravel:20", "10:Clay:90", "16:Sand:40"), 7),
    "loam_gravel_clay_default": ("default", ("0:Loam:20", "10:Gravel:80", "16:Clay:30"), 11),
    "loam_gravel_sand_default": ("default", ("0:Loam:40", "10:Gravel:70", "16:Sand:30"), 7),
    "main_fee": ("fee", ("0:Sand:20", "10:Clay:80", "16:Loam:50"), 3),
    "gravel_clay_sand_fee": ("fee", ("0:Gravel:20", "10:Clay:90", "16:Sand:40"), 7),
}
DEFAULT_SETTINGS = ("0.8,0.95", "0.85,0.95", "0.9,0.95", "0.9,0.9", "0.95,0.9")
DURATION_S = 45.0


def parse_args(argv=None) -> argparse.Namespace:
    from soil_bringup.cut_report import add_force_lift_option

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--settings", nargs="+", default=list(DEFAULT_SETTINGS), metavar="MARGIN,QUANTILE",
                    help="planner settings to compare, e.g. 0.8,0.95")
    ap.add_argument("--paths", nargs="+", default=list(PATHS), choices=list(PATHS))
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seeds", type=int, default=1, help="seeds per path: its own, then +100, +200, ... (default 1)")
    add_force_lift_option(ap, "the controller's force lift in every policy (soil_cut_report --force-lift); default off")
    args = ap.parse_args(argv)
    settings = []
    for text in args.settings:
        try:
            margin, quantile = (float(v) for v in text.split(","))
        except ValueError:
            ap.error(f"--settings {text!r}: expected MARGIN,QUANTILE, e.g. 0.8,0.95")
        settings.append((margin, quantile))
    args.settings = settings
    if args.seeds < 1:
        ap.error(f"--seeds {args.seeds}: must be at least 1")
    return args


SEED_STEP = 100  # --seeds: the seeds of one path are its own + k * SEED_STEP
SETTLE_WITHIN_S = TARGET_SETTLE_S  # the "within 2 s of entering a new soil patch" (soil_cut_report's)


def run_path(job: tuple) -> list[dict]:
    """One path: its fixed-depth sweep once, then the soil-aware loop under every setting."""
    import torch

    from soil_bringup import cut_metrics as CM
    from soil_bringup import cut_report as CR
    from soil_bringup.cut_trial import Policy, SoilAwareSetup, run_cut

    torch.set_num_threads(1)
    name, settings, gains, k = job
    world, patches, seed = PATHS[name]
    seed += k * SEED_STEP
    label = name if k == 0 else f"{name} (seed {seed})"
    spec = CR.parse_args([a for p in patches for a in ("--patch", p)] + ["--seed", str(seed), "--duration", str(DURATION_S)]).spec
    sweep, best, conservative, aggressive = CR.fixed_policies(world, spec, gains)
    fixed = {c.policy.fixed_depth_m: CM.summary(c) for c in sweep}
    rows = []
    for margin, quantile in settings:
        setup = SoilAwareSetup(world, planner={"margin": margin, "force_quantile": quantile})
        cut = run_cut(world, spec, Policy("soil-aware"), setup, gains)
        aware = CM.summary(cut)
        # the patches entered during the cut (the first is where it starts, as the cut report has it)
        patches_judged = [p for p in CM.per_patch(cut, best)[1:] if p["best_fixed_depth_m"] is not None]
        settled = sum(p["settle_s"] is not None and p["settle_s"] <= SETTLE_WITHIN_S for p in patches_judged)
        rows.append({"path": label, "world": world, "margin": margin, "quantile": quantile,
                     "settled": settled, "patches": len(patches_judged),
                     "volume_ratio": aware["volume_per_m_m3"] / fixed[conservative]["volume_per_m_m3"],
                     "ceiling": CR.hindsight_ratio(cut, best, conservative), "stall_s": aware["stall_s"],
                     "conservative_stall_s": fixed[conservative]["stall_s"], "aggressive_stall_s": fixed[aggressive]["stall_s"]})
    return rows


def main(argv=None) -> int:
    from soil_bringup.cut_report import controller_text

    args = parse_args(argv)
    t0 = time.monotonic()
    with ProcessPoolExecutor(args.workers) as pool:
        # the fee world has no noise: another seed repeats the same run
        jobs = [(p, args.settings, args.gains, k) for k in range(args.seeds) for p in args.paths
                if k == 0 or PATHS[p][0] != "fee"]
        rows = [r for rs in pool.map(run_path, jobs) for r in rs]
    lift = f", {controller_text(dataclasses.asdict(args.gains))}" if args.gains.force_lift_m_s > 0 else ""
    print(f"## Planner margin × force quantile over {len(jobs)} cuts: {len(args.paths)} paths × up to {args.seeds} "
          f"seed(s) ({DURATION_S:g} s cuts{lift})\n")
    print("| path | margin | quantile | volume / m vs conservative | ceiling | stall [s] | conservative / aggressive stall [s] "
          f"| patches entered, {WITHIN} of their best depth within {SETTLE_WITHIN_S:g} s |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        ceiling = f"{r['ceiling']:.2f}×" if r["ceiling"] is not None else "–"
        print(f"| {r['path']} | {r['margin']:g} | {r['quantile']:g} | {r['volume_ratio']:.2f}× | {ceiling} | "
              f"{r['stall_s']:.2f} | {r['conservative_stall_s']:.2f} / {r['aggressive_stall_s']:.2f} | "
              f"{r['settled']} of {r['patches']} |")
    for world in ("default", "fee"):
        mine = [r for r in rows if r["world"] == world]
        if not mine:
            continue
        paths = len({r['path'].split(' (seed')[0] for r in mine})  # a further seed's label: "<path> (seed N)"
        print(f"\n{world} world, per setting over its {len({r['path'] for r in mine})} cuts ({paths} path{'s' if paths != 1 else ''}):\n")
        print("| margin | quantile | mean volume / m vs conservative | total stall [s] | cuts without stall "
              f"| patches entered, {WITHIN} of their best depth within {SETTLE_WITHIN_S:g} s |")
        print("|---|---|---|---|---|---|")
        for margin, quantile in args.settings:
            sel = [r for r in mine if (r["margin"], r["quantile"]) == (margin, quantile)]
            print(f"| {margin:g} | {quantile:g} | {sum(r['volume_ratio'] for r in sel) / len(sel):.2f}× | "
                  f"{sum(r['stall_s'] for r in sel):.2f} | {sum(r['stall_s'] == 0 for r in sel)} of {len(sel)} | "
                  f"{sum(r['settled'] for r in sel)} of {sum(r['patches'] for r in sel)} |")
    print(f"\nTotal {time.monotonic() - t0:.0f} s.")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
