"""Can fitted θ tell two soils of the same unit weight γ apart, without a soil label? Prints figures.

    .venv/bin/python scripts/theta_grouping_evidence.py bags/disc_full/control bags/disc_full/soil_inertia ...

Without a soil label, ``soil_discrepancy --group-by gamma`` lets the episodes of one measured γ
share θ. Clustering further by fitted θ would need a force-based test: do two episodes fit
one θ (φ, c, δ) as well as each fits its own? Per γ-group of a labelled dataset, this script
fits θ to every pair of episodes jointly and to each alone (the FEE, ``fee_fit.fit_fixed``,
force normalised by the 20/30 kN limits) and prints the ratio RMS(one θ for the pair) /
RMS(a θ each), for pairs of the same soil and pairs of two soils. The labels are used only to
sort the pairs. A clustering by θ works where the two distributions separate in every
case; a missing effect that depends on speed or depth (soil inertia) raises the ratio of
same-soil pairs as much as a second soil does, so a θ-clustering would split a soil along
the effect the workflow is meant to find.
"""
from __future__ import annotations

import argparse
import dataclasses
import itertools
import math
from collections import defaultdict

import numpy as np

from pinn_estimator.dataset import load_dataset
from soil_discrepancy.candidates import episode_sse
from soil_discrepancy.fee_fit import fit_fixed, residuals
from soil_discrepancy.frame import build_frame
from soil_physics.augmented_fee import AugmentedFEE

FEE = AugmentedFEE(())


def _sse(frame, episodes) -> float:
    """Σ normalised squared residual of one θ fitted to ``episodes`` together (a tick where the
    FEE is undefined counts as the fitter's penalty, as in the fit itself)."""
    part = frame.select(episodes=episodes)
    part = dataclasses.replace(part, group_of=np.zeros(len(part.names), int), group_names=["pair"])
    r, _ = residuals(part, FEE, fit_fixed(part, FEE))
    return sum(sse for sse, _ in episode_sse(part, r).values())


def pair_ratios(bag_dir, stride: int) -> dict[str, list[float]]:
    """{'same soil' | 'two soils': [RMS ratio per pair]} over the dataset's γ-groups."""
    ds = load_dataset(bag_dir)
    per_episode = build_frame(ds, stride=stride, group_by="episode")
    by_gamma = build_frame(ds, stride=stride, group_by="gamma")
    labelled = build_frame(ds, stride=stride, group_by="auto")
    if not labelled.has_metadata():
        raise SystemExit(f"{bag_dir}: the bags have no soil label; this check needs one to sort the pairs")
    alone = {int(e): _sse(per_episode, [e]) for e in per_episode.episodes}
    members = defaultdict(list)
    for e in per_episode.episodes:
        members[int(by_gamma.group_of[e])].append(int(e))
    out = {"same soil": [], "two soils": []}
    for eps in members.values():
        for a, b in itertools.combinations(eps, 2):
            joint = _sse(per_episode, [a, b])
            apart = alone[a] + alone[b]
            kind = "same soil" if labelled.group_of[a] == labelled.group_of[b] else "two soils"
            out[kind].append(math.sqrt(joint / max(apart, 1e-30)))
    return out


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("bag_dirs", nargs="+", help="labelled dataset directories (soil_sim_batch output)")
    p.add_argument("--stride", type=int, default=4, help="every n-th analysed tick (default 4)")
    args = p.parse_args(argv)
    print("RMS(one θ for two episodes of one γ) / RMS(a θ each): quantiles 10/50/90 %")
    print(f"{'dataset':<28} {'pairs':<10} {'n':>5} {'q10':>6} {'q50':>6} {'q90':>6}")
    for bag_dir in args.bag_dirs:
        for kind, ratios in pair_ratios(bag_dir, args.stride).items():
            if ratios:
                q = np.percentile(ratios, [10, 50, 90])
                print(f"{str(bag_dir).rstrip('/').split('/')[-1]:<28} {kind:<10} {len(ratios):>5} "
                      f"{q[0]:>6.2f} {q[1]:>6.2f} {q[2]:>6.2f}")


if __name__ == "__main__":
    main()
