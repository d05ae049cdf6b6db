"""The tiny dataset the PINN tests train on: 6 fee-world episodes of 2 s (2 soils x 3 depths
and seeds), one bag each, written with write_episode like soil_sim_batch's. Each seed cuts at its
own depth: the fee world has no noise, so seeds alone would make copies of one episode, which a
split keeps together."""
from __future__ import annotations

from pathlib import Path

from soil_bag_tools.bag_io import write_episode
from soil_sim_node.rollout import run_episodes
from soil_sim_node.simulator import EpisodeSpec, SimConfig


def write_tiny_bags(root: Path) -> Path:
    specs = [EpisodeSpec(soil, 40.0, 0.6, 0.18 + 0.02 * s, seed=s, duration_s=2.0) for soil in ("Loam", "Sand") for s in range(3)]
    for ep in run_episodes(SimConfig(world_mode="fee"), specs):
        write_episode(root / ep.meta.name, ep)
    return root
