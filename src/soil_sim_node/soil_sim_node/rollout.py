"""Closed-loop episodes without ROS: simulator core + anti-stall controller core -> Episodes.

The one place (with the ROS launch) that composes the two cores. Row k of an Episode is the
state the simulator reported at tick k, the force measured over the tick that ended there,
and the command u_k the controller answered it with (paper §2.1.2: o_t = [p_t, v_t, u_t]).
"""
from __future__ import annotations

import numpy as np

from anti_stall_controller.controller import AntiStallController, AntiStallGains
from soil_msgs_py.episode import Episode, EpisodeMeta
from soil_msgs_py.params import (FORCE_LIMITS_N, GROUND_TRUTH_PARAMS, KNOWN_PARAMS, OBSERVATION_FIELDS,
                                 VELOCITY_AVERAGE_SAMPLES, tick_stamp_ns, ticks_in)

from .effects import plugin_name
from . import kernel
from .simulator import EpisodeSpec, SimConfig, SoilSimulator


def episode_meta(config: SimConfig, spec: EpisodeSpec, soil_name: str, effects: list[str]) -> EpisodeMeta:
    """The metadata of ``spec`` as ``SoilSimulator`` resolved it (``sim.specs[i]``: with
    patches, the soil and I_d of the patch the edge starts in and the patches with catalogue names)."""
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
        patches=[patch.as_dict() for patch in spec.patches],
    )


def run_episodes(config: SimConfig, specs: list[EpisodeSpec], gains: AntiStallGains | None = None,
                 custom_soils: dict | None = None, plugin_peaks: dict | None = None) -> list[Episode]:
    """Simulate ``specs`` together (vectorised) in closed loop; one Episode per spec.
    ``plugin_peaks``: filled with {str(plugin spec): the largest |force| [N] it returned in any substep}."""
    sim = SoilSimulator(config, specs, custom_soils)
    durations = {s.duration_s for s in sim.specs}
    if len(durations) != 1:
        raise ValueError(f"duration_s differs across the batch ({sorted(durations)}); batch equal durations")
    n_ticks = ticks_in(specs[0].duration_s)
    gains = gains or AntiStallGains()
    if sim.engine == "compiled" and not sim.plugins:  # plugins are Python: the loop below steps them
        return [_compiled_episode(sim, i, gains, n_ticks) for i in range(sim.batch)]
    b = sim.batch
    controller = AntiStallController(
        gains,
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
        cmd = controller.step(out.velocities[:, 1], out.positions[:, 2], out.forces)
        stamps[k] = out.stamp_ns
        obs[k, :, 0:3] = out.positions
        obs[k, :, 3:6] = out.velocities
        obs[k, :, 6] = cmd.u_zr  # already clipped to the lift-joint reach by the controller
        obs[k, :, 7] = cmd.u_za
        obs[k, :, 8] = cmd.u_x
        forces[k], known[k], truth[k], extras[k] = out.forces, out.known, out.truth, out.extras
        out = sim.step(cmd.u_zr, cmd.u_za, cmd.u_x)
    effects = sim.effects.enabled()
    if plugin_peaks is not None:
        for spec, plugin in zip(config.plugins, sim.plugins):
            plugin_peaks[str(spec)] = max(plugin_peaks.get(str(spec), 0.0), plugin.peak_n)
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


def kernel_gains(g: AntiStallGains) -> np.ndarray:
    """The controller's gains as the compiled kernel's row (``kernel.C_*``), the machine's force limits with them."""
    row = np.zeros(kernel.N_GAINS)
    row[[kernel.C_K_V, kernel.C_C_VX, kernel.C_DELTA_D_MAX, kernel.C_DT, kernel.C_DITHER_A, kernel.C_DITHER_T,
         kernel.C_FORCE_LIFT, kernel.C_FORCE_SHARE, kernel.C_LIMIT_X, kernel.C_LIMIT_Z]] = (
        g.k_v_m_s, g.c_vx, g.delta_d_max_m, g.dt_s, g.dither_amplitude_m, g.dither_period_s,
        g.force_lift_m_s, g.force_lift_share, *FORCE_LIMITS_N)
    return row


def _compiled_episode(sim: SoilSimulator, i: int, gains: AntiStallGains, n_ticks: int) -> Episode:
    """Episode ``i`` of ``sim`` (just reset) in closed loop, whole, in the compiled kernel:
    the same rows as the reference loop above, each episode on its own."""
    spec = sim.specs[i]
    controller = AntiStallController(gains, spec.target_speed_m_s, spec.target_depth_m)  # validates the targets
    gain_row = kernel_gains(controller.gains)
    obs = np.zeros((n_ticks, len(OBSERVATION_FIELDS)))
    forces, extras = np.zeros((n_ticks, 2)), np.zeros((n_ticks, 2))
    known, truth = np.zeros((n_ticks, len(KNOWN_PARAMS))), np.zeros((n_ticks, len(GROUND_TRUTH_PARAMS)))
    kernel.run_episode(*sim.kernel_arguments(i), gain_row, float(controller.target_speed_m_s[0]),
                       float(controller.target_depth_m[0]), VELOCITY_AVERAGE_SAMPLES, obs, forces, known, truth, extras)
    return Episode(
        meta=episode_meta(sim.config, spec, sim.soils[i].name, sim.effects.enabled()),
        stamps_ns=np.array([tick_stamp_ns(k) for k in range(n_ticks)], dtype=np.int64),
        observations=obs, forces=forces, known=known, truth=truth, extras=extras,
    )
