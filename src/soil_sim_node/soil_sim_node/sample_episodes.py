"""`python -m soil_sim_node.sample_episodes`: a small simulator dataset and its plots (not `make demo`).

Generates Loam at I_d = 60 % (the paper's Fig. 3 episode), dense Clay and loose Sand in both
worlds, writes the bags under bags/sim_samples/<mode>/, a Fig.-3-style PNG per episode under
out/sim_samples/ (folders of its own: out/demo/ and bags/demo_online/ belong to `make demo`),
and prints one line per episode (mean cut depth, force mean/std, final surcharge, fee-mode
error against the FEE of the pseudo-ground truth).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from soil_bag_tools.bag_io import read_episode

from .batch import DatasetPlan, generate, grid_specs
from .effects import effects_for_mode
from .plot import plot_episode, truth_fee_force

SAMPLE_EPISODES = (("Loam", 60.0), ("Clay", 100.0), ("Sand", 0.0))


def main(argv=None) -> int:
    argparse.ArgumentParser(prog="python -m soil_sim_node.sample_episodes", description=__doc__.splitlines()[0],
                            epilog=__doc__.split("\n\n", 1)[1]).parse_args(argv)  # only --help: the job takes no options
    root, figs = Path("bags/sim_samples"), Path("out/sim_samples")
    print(f"{'episode':44s} {'depth m':>8s} {'Fx kN':>12s} {'Fz kN':>12s} {'Q kN':>6s} {'|F-FEE| kN':>10s}")
    for mode in ("fee", "default"):
        specs = []
        for k, (soil, i_d) in enumerate(SAMPLE_EPISODES):
            specs += grid_specs([soil], [i_d], [0.5], [0.2], 1, seed_base=7 + k, duration_s=10.0)
        plan = DatasetPlan(mode, root / mode, specs, effects_for_mode(mode), overwrite=True)
        summary = generate(plan, workers=2, progress=False)
        for name in summary["episode_names"]:
            ep = read_episode(root / mode / name)
            plot_episode(ep, figs / f"{name}.png")
            late = slice(len(ep) // 2, None)
            fx_fee, fz_fee = truth_fee_force(ep)
            err = np.hypot(ep.forces[late, 0] - fx_fee[late], ep.forces[late, 1] - fz_fee[late]).mean()
            fx, fz = ep.forces[late, 0] / 1e3, ep.forces[late, 1] / 1e3
            print(f"{name:44s} {ep.column('d')[late].mean():8.3f} {fx.mean():6.1f}±{fx.std():4.1f} "
                  f"{fz.mean():6.1f}±{fz.std():4.1f} {ep.column('q')[-1] / 1e3:6.1f} {err / 1e3:10.2f}")
    print(f"bags in {root}/, figures in {figs}/ (open the bags with Foxglove or `ros2 bag info`)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
