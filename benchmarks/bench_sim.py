"""Simulator and dataset benchmarks (issue: foundation). Prints figures; asserts nothing.

    .venv/bin/python benchmarks/bench_sim.py            # all
    .venv/bin/python benchmarks/bench_sim.py --no-dataset

Figures: simulated seconds per wall second for one episode (B = 1) and for a vectorised
batch, in both worlds; wall time to generate and write the 576-episode default-mode dataset
on all cores (target < 180 s, bags included); bytes per episode.
"""
from __future__ import annotations

import argparse
import os
import shutil
import tempfile
import time
from pathlib import Path

from soil_sim_node.batch import DatasetPlan, GRID_DEPTHS, GRID_SPEEDS, DEFAULT_RELATIVE_DENSITIES, generate, grid_specs
from soil_sim_node.effects import effects_for_mode
from soil_sim_node.rollout import run_episodes
from soil_sim_node.simulator import EpisodeSpec, SimConfig


def sim_rate(mode: str, batch: int, duration_s: float = 10.0, repeats: int = 3) -> float:
    specs = [EpisodeSpec(("Clay", "Loam", "Sand", "Gravel")[i % 4], 20.0 * (i % 6), 0.6, 0.2, seed=i, duration_s=duration_s)
             for i in range(batch)]
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        run_episodes(SimConfig(world_mode=mode), specs)
        best = min(best, time.perf_counter() - t0)
    return batch * duration_s / best


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--no-dataset", action="store_true")
    p.add_argument("--workers", type=int, default=0)
    args = p.parse_args()
    print(f"cores: {os.cpu_count()}")
    for mode in ("fee", "default"):
        for batch in (1, 48):
            print(f"sim {mode:7s} B={batch:3d}: {sim_rate(mode, batch):8.1f} simulated s per wall s (one process)")
    if args.no_dataset:
        return
    out = Path(tempfile.mkdtemp(prefix="bench_d_default_"))
    try:
        specs = grid_specs(["Clay", "Loam", "Sand", "Gravel"], DEFAULT_RELATIVE_DENSITIES, GRID_SPEEDS["default"],
                           GRID_DEPTHS, 2, 0, 10.0)
        plan = DatasetPlan("default", out, specs, effects_for_mode("default"))
        s = generate(plan, workers=args.workers, progress=False)
        print(f"dataset default: {s['episodes']} episodes, {s['wall_time_s']:.1f} s wall incl. bags "
              f"(target < 180 s), {s['simulated_s_per_wall_s']:.0f} simulated s per wall s, "
              f"{s['bytes_per_episode'] / 1e3:.0f} kB per episode, {s['bytes_total'] / 1e6:.0f} MB total")
    finally:
        shutil.rmtree(out, ignore_errors=True)


if __name__ == "__main__":
    main()
