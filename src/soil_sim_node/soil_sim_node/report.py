"""``soil_sim_report``: run the simulator-phenomena checks and print the report.

    soil_sim_report [--duration 10] [--seed 0] [--json PATH]

See ``soil_sim_node.phenomena`` for what is measured and how.
"""
from __future__ import annotations

import argparse
import json
import sys

from soil_msgs_py import cli_numbers
from soil_msgs_py.cli_paths import output_file
from soil_msgs_py.episode import MAX_EPISODE_S

from .phenomena import Settings, format_report, run_all


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="soil_sim_report",
        description="Run small vectorised batches of episodes and report the paper's simulator "
                    "phenomena (depth vs I_d, surcharge growth, fee == FEE, default > fee, oscillations).",
    )
    p.add_argument("--duration", type=float, default=10.0, help="episode length [s] (default 10)")
    p.add_argument("--seed", type=cli_numbers.seed, default=0, help="base seed; episode i uses seed + i (default 0)")
    p.add_argument("--json", type=output_file, default=None, metavar="PATH", help="also save all numbers as JSON here")
    p.add_argument("--quiet", action="store_true", help="no progress messages on stderr")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    tail = 5.0
    if not 2.5 <= args.duration <= MAX_EPISODE_S:  # (NaN too; checked before any episode runs)
        print(f"soil_sim_report: --duration={args.duration} must be in [2.5, {MAX_EPISODE_S:g}] s "
              "(a 1 s detrend window and a tail to average over)", file=sys.stderr)
        return 2
    try:
        settings = Settings(duration_s=args.duration, seed=args.seed, tail_s=min(tail, args.duration / 2))
    except ValueError as exc:
        print(f"soil_sim_report: {exc}", file=sys.stderr)
        return 2
    progress = None if args.quiet else (lambda msg: print(f"[soil_sim_report] {msg}", file=sys.stderr, flush=True))
    report = run_all(settings, progress=progress)
    print(format_report(report))
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(report.to_dict(), indent=2, sort_keys=True) + "\n")
        print(f"numbers saved to {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
