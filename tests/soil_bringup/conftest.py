"""Fixtures of the soil_bringup tests: one real closed-loop episode to score and print."""
import pytest


@pytest.fixture(scope="module")
def episode():
    """A real 2 s closed-loop episode (120 ticks) from the batch simulator."""
    from soil_sim_node.rollout import run_episodes
    from soil_sim_node.simulator import EpisodeSpec, SimConfig

    return run_episodes(SimConfig(world_mode="default"), [EpisodeSpec("Clay", 20.0, 0.5, 0.2, seed=3, duration_s=2.0)])[0]
