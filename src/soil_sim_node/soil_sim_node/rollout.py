"""Closed-loop episodes without ROS: simulator core + anti-stall controller core -> Episodes.

The one place (with the ROS launch) that composes the two cores. Row k of an Episode is the
state the simulator reported at tick k, the force measured over the tick that ended there,
and the command u_k the controller answered it with (paper §2.1.2: o_t = [p_t, v_t, u_t]).
"""
from __future__ import annotations

import numpy as np

from anti_stall_controller.controller import AntiStallController, AntiStallGains
from soil_msgs_py.episode import Episode, EpisodeMeta
from soil_msgs_py.params import SAMPLE_RATE_HZ

from .effects import plugin_name
from .simulator import EpisodeSpec, SimConfig, SoilSimulator


def episode_meta(config: SimConfig, spec: EpisodeSpec, soil_name: str, effects: list[str]) -> EpisodeMeta:
    return EpisodeMeta(
        soil=soil_name,
        relative_density_pct=float(spec.relative_density_pct),
        world_mode=config.world_mode,
        seed=int(spec.seed),
        target_speed_m_s=float(spec.target_speed_m_s),
        target_depth_m=float(spec.target_depth_m),
        duration_s=float(spec.duration_s),
        effects=effects,
        plugins=[plugin_name(p) for p in config.plugins],
    )


def run_episodes(config: SimConfig, specs: list[EpisodeSpec], gains: AntiStallGains | None = None,
                 custom_soils: dict | None = None) -> list[Episode]:
    """Simulate ``specs`` together (vectorised) in closed loop; one Episode per spec."""
    sim = SoilSimulator(config, specs, custom_soils)
    durations = {s.duration_s for s in sim.specs}
    if len(durations) != 1:
        raise ValueError(f"duration_s differs across the batch ({sorted(durations)}); batch equal durations")
    n_ticks = int(round(specs[0].duration_s * SAMPLE_RATE_HZ))
    b = sim.batch
    controller = AntiStallController(
        gains or AntiStallGains(),
        target_speed_m_s=np.array([s.target_speed_m_s for s in sim.specs]),
        target_depth_m=np.array([s.target_depth_m for s in sim.specs]),
    )
    stamps = np.zeros(n_ticks, dtype=np.int64)
    obs = np.zeros((n_ticks, b, 9))
    forces = np.zeros((n_ticks, b, 2))
    known = np.zeros((n_ticks, b, 9))
    truth = np.zeros((n_ticks, b, 13))
    extras = np.zeros((n_ticks, b, 2))
    out = sim.reset()
    for k in range(n_ticks):
        cmd = controller.step(out.velocities[:, 1], out.positions[:, 2])
        stamps[k] = out.stamp_ns
        obs[k, :, 0:3] = out.positions
        obs[k, :, 3:6] = out.velocities
        obs[k, :, 6] = cmd.u_zr  # already clipped to the lift-joint reach by the controller
        obs[k, :, 7] = cmd.u_za
        obs[k, :, 8] = cmd.u_x
        forces[k], known[k], truth[k], extras[k] = out.forces, out.known, out.truth, out.extras
        out = sim.step(cmd.u_zr, cmd.u_za, cmd.u_x)
    effects = sim.effects.enabled()
    return [
        Episode(
            meta=episode_meta(config, spec, soil.name, effects),
            stamps_ns=stamps.copy(),
            observations=obs[:, i].copy(),
            forces=forces[:, i].copy(),
            known=known[:, i].copy(),
            truth=truth[:, i].copy(),
            extras=extras[:, i].copy(),
        )
        for i, (spec, soil) in enumerate(zip(sim.specs, sim.soils))
    ]
