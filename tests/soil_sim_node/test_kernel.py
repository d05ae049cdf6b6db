"""The compiled kernel is the same simulator as the NumPy reference (``soil_sim_node.kernel``).

Tolerance: every output of the compiled engine equals the reference's to 1e-9 of that
column's largest magnitude over the run (measured: ~5e-15 over 10 s closed-loop episodes;
the two differ only where NumPy's vectorised tanh and libm's round the last bit differently).
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from anti_stall_controller.controller import AntiStallController, AntiStallGains
from soil_msgs_py.params import DEG, FORCE_LIMITS_N, GROUND_TRUTH_PARAMS, MACHINE
from soil_physics import fee
from soil_physics.bearing import penetration_capacity
from soil_physics.force_inputs import ForceInputs
from soil_physics.travel import time_in_soil_of_known
from soil_sim_node import kernel
from soil_sim_node import phenomena as ph
from soil_sim_node.effects import Effects
from soil_sim_node.rollout import kernel_gains, run_episodes
from soil_sim_node.simulator import EpisodeSpec, SimConfig, SoilSimulator
from tests import sim_plugins

RTOL = 1e-9
EPISODE_FIELDS = ("observations", "forces", "known", "truth", "extras")
SPECS = [
    EpisodeSpec("Clay", 90.0, 0.4, 0.3, 3, 4.0),  # dense and deep: stalls, the controller backs off
    EpisodeSpec("Sand", 10.0, 1.0, 0.1, 4, 4.0),
    EpisodeSpec("Gravel", 60.0, 0.7, 0.2, 5, 4.0),
]


def assert_close(got: np.ndarray, want: np.ndarray, what: str) -> None:
    """|got - want| <= RTOL * (largest |want| of the column) everywhere."""
    got, want = np.asarray(got, dtype=float), np.asarray(want, dtype=float)
    assert got.shape == want.shape, what
    scale = np.abs(want).reshape(-1, want.shape[-1]).max(axis=0) if want.ndim > 1 else np.abs(want).max()
    err = np.abs(got - want) / np.maximum(scale, 1e-300)
    assert np.all(err <= RTOL), f"{what}: worst relative difference {err.max():.3g}"


def assert_same_episodes(got, want) -> None:
    for a, b in zip(got, want, strict=True):
        assert a.meta == b.meta
        np.testing.assert_array_equal(a.stamps_ns, b.stamps_ns)
        for name in EPISODE_FIELDS:
            assert_close(getattr(a, name), getattr(b, name), f"{a.meta.soil} {name}")


@pytest.mark.parametrize("world", ["fee", "default"])
def test_closed_loop_episodes_match_the_reference(world):
    compiled = run_episodes(SimConfig(world_mode=world), SPECS)
    reference = run_episodes(SimConfig(world_mode=world, engine="reference"), SPECS)
    assert_same_episodes(compiled, reference)
    assert max(abs(ep.forces[:, 0]).max() for ep in compiled) > 5e3  # the episodes do cut


def test_a_soil_weaker_than_the_reversed_blade_friction_records_a_finite_truth(tmp_path):
    """φ below the fee world's δ = 15°: while the entering blade rises, the reversed friction
    (δ' < −φ) leaves no failure wedge, so β* is undefined there. Both engines record the vanishing
    wedge's β = π − ρ instead (before, NaN: the bag writer refused the episode and
    ``soil_sim_batch`` stopped), apply no soil force on those ticks, and agree."""
    from soil_bag_tools.bag_io import read_episode, write_episode
    from soil_physics.soils import SoilProperties, SoilType

    soil = SoilType("WeakMud", SoilProperties(12.0 * DEG, 18e3, 18e3), SoilProperties(14.0 * DEG, 22e3, 20e3), "test")
    spec = [EpisodeSpec("WeakMud", 20.0, 0.5, 0.16, 1, 4.0)]
    compiled = run_episodes(SimConfig(world_mode="fee"), spec, custom_soils={"WeakMud": soil})
    assert_same_episodes(compiled, run_episodes(SimConfig(world_mode="fee", engine="reference"), spec,
                                                custom_soils={"WeakMud": soil}))
    ep = compiled[0]
    beta = ep.truth[:, -1]
    rho = ep.known[0, 2]
    flat = np.isclose(beta, np.pi - rho)
    assert np.isfinite(ep.truth).all() and flat.any(), "the rising entry leaves no wedge on some ticks"
    assert (ep.truth[flat, GROUND_TRUTH_PARAMS.index("v_z")] > 0).all(), "only while the blade rises"
    write_episode(tmp_path / "weak", ep)
    assert np.array_equal(read_episode(tmp_path / "weak").truth, ep.truth)


@pytest.mark.parametrize("name", Effects.names())
def test_each_effect_switched_off_matches_the_reference(name):
    config = SimConfig(world_mode="default", effects=Effects().with_switches(**{name: False}))
    spec = [EpisodeSpec("Loam", 70.0, 0.6, 0.25, 11, 2.0)]
    assert_same_episodes(run_episodes(config, spec),
                         run_episodes(SimConfig(world_mode="default", effects=config.effects, engine="reference"), spec))


@pytest.mark.parametrize("name", Effects.names())
def test_each_effect_alone_matches_the_reference(name):
    effects = Effects.fee().with_switches(**{name: True})
    spec = [EpisodeSpec("Clay", 40.0, 0.5, 0.2, 12, 2.0)]
    assert_same_episodes(run_episodes(SimConfig(world_mode="default", effects=effects), spec),
                         run_episodes(SimConfig(world_mode="default", effects=effects, engine="reference"), spec))


# Soil changing along x: the blade starts at x = 2 m and crosses every boundary below in 3 s
# (the first patch's x_start_m is before the start; patched and plain rows share a batch).
PATCHED_SPECS = [
    EpisodeSpec("Loam", 50.0, 0.9, 0.2, 31, 3.0, patches=("0.0:Sand:20", "2.6:Clay:90", "3.5:Gravel:60")),
    EpisodeSpec("Loam", 50.0, 0.7, 0.25, 32, 3.0, patches=((-5.0, "Clay", 30.0), (2.9, "Loam", 100.0))),
    EpisodeSpec("Sand", 70.0, 0.8, 0.15, 33, 3.0),
]


@pytest.mark.parametrize("world", ["fee", "default"])
def test_episodes_through_soil_patches_match_the_reference(world):
    compiled = run_episodes(SimConfig(world_mode=world), PATCHED_SPECS)
    assert_same_episodes(compiled, run_episodes(SimConfig(world_mode=world, engine="reference"), PATCHED_SPECS))
    for ep, spec in zip(compiled, PATCHED_SPECS):  # every boundary was crossed: one φ per patch
        assert len(np.unique(ep.column("phi"))) == max(1, len(spec.patches))


@pytest.mark.parametrize("specs", [SPECS, PATCHED_SPECS], ids=["one_soil", "patches"])
def test_a_batch_row_is_the_episode_run_alone(specs):
    together = run_episodes(SimConfig(), specs)
    for spec, row in zip(specs, together):
        (alone,) = run_episodes(SimConfig(), [spec])
        for name in ("stamps_ns", *EPISODE_FIELDS):
            np.testing.assert_array_equal(getattr(row, name), getattr(alone, name), err_msg=name)


def test_tick_by_tick_stepping_matches_the_reference_open_loop():
    """The live node's path (``SoilSimulator.step``): replaying an episode's commands."""
    (ep,) = run_episodes(SimConfig(), SPECS[:1])
    got = ph.replay_commands(SimConfig(), SPECS[0], ep)
    want = ph.replay_commands(SimConfig(engine="reference"), SPECS[0], ep)
    for key in ("positions", "velocities", "forces", "known", "truth", "extras", "applied_u_zr"):
        assert_close(got[key], want[key], key)
    assert_close(got["forces"], ep.forces, "replayed forces against the closed loop")


def _random_states(n: int, seed: int) -> tuple[list[EpisodeSpec], dict, np.ndarray, np.ndarray]:
    """n episodes in random states: in and out of the soil, sinking and rising, stalled and
    fast, fresh and compacted, on a random terrain, every other one on a random path of soil
    patches (at or next to a boundary, with a pile of another soil); and random commands."""
    rng = np.random.default_rng(seed)
    soils = ("Clay", "Loam", "Sand", "Gravel")

    def path(i):
        starts = np.sort(rng.uniform(1.5, 4.5, 2))
        return [(0.0, soils[(i + 1) % 4], float(rng.uniform(0, 100)))] + [
            (float(x), soils[(i + k) % 4], float(rng.uniform(0, 100))) for k, x in enumerate(starts, 2)]

    specs = [EpisodeSpec(soils[i % 4], float(rng.uniform(0, 100)), 0.5, 0.2, int(seed * 1000 + i), 2.0,
                         patches=path(i) if i % 2 else ()) for i in range(n)]
    state = {
        "x_c": rng.uniform(0.0, 2.0, n), "vx_c": rng.uniform(-0.3, 1.5, n), "z_c": rng.uniform(-0.1, 0.05, n),
        "vz_c": rng.uniform(-0.2, 0.2, n), "z_rel": rng.uniform(-0.35, 0.1, n), "vz_rel": rng.uniform(-0.5, 0.5, n),
        "u_e": rng.uniform(0.0, 5e-3, n), "grip": rng.uniform(0.1, 1.0, n), "grip_tau": rng.uniform(0.01, 0.08, n),
        "pile_m3": rng.uniform(0.0, 0.45, n), "distance_in_soil": rng.uniform(0.0, 8.0, n),
        "pile_gamma": rng.uniform(15e3, 21e3, n), "dist_entry": rng.uniform(0.0, 1.0, n),
    }
    u = np.stack([rng.uniform(MACHINE.blade_min_rel_m - 0.1, 0.2, n), np.zeros(n), rng.uniform(-0.5, 2.5, n)], axis=1)
    return specs, state, rng.uniform(-0.2, 0.02, (n, 1)), u


@pytest.mark.parametrize("world", ["fee", "default"])
def test_one_tick_from_random_states_matches_the_reference(world):
    specs, state, heights, u = _random_states(300, seed=1 if world == "fee" else 2)
    sims = {engine: SoilSimulator(SimConfig(world_mode=world, engine=engine), specs) for engine in ("compiled", "reference")}
    for sim in sims.values():
        for name, values in state.items():
            setattr(sim, name, values)
        cells = np.arange(sim.n_cells) * sim.dyn.terrain_cell_m + sim.x_min
        sim.terrain[:] = np.minimum(heights + 0.02 * np.sin(3.0 * cells), 0.0)  # an uneven, cut surface
    outs = {engine: [sim.step(*u.T) for _ in range(3)] for engine, sim in sims.items()}
    for k, (got, want) in enumerate(zip(outs["compiled"], outs["reference"])):
        for key in ("positions", "velocities", "forces", "known", "truth", "extras"):
            assert_close(getattr(got, key), getattr(want, key), f"tick {k} {key}")
    for name in state:
        assert_close(getattr(sims["compiled"], name)[:, None], getattr(sims["reference"], name)[:, None], name)
    assert_close(sims["compiled"].terrain, sims["reference"].terrain, "terrain")
    forces = outs["reference"][0].forces
    assert (forces[:, 0] > 1e3).sum() > 30 and (forces[:, 0] < 1.0).sum() > 10  # cutting and idle rows both


def test_scalar_fee_matches_soil_physics_over_random_inputs():
    rng = np.random.default_rng(3)
    n = 2000
    phi, delta = rng.uniform(0.1, 0.8, n), rng.uniform(-0.6, 0.6, n)
    rho, alpha = rng.uniform(0.6, 1.5, n), rng.uniform(-0.3, 0.3, n)
    c, c_a, gamma = rng.uniform(0, 30e3, n), rng.uniform(0, 5e3, n), rng.uniform(12e3, 22e3, n)
    w, d, q = rng.uniform(1, 4, n), rng.uniform(-0.1, 0.6, n), rng.uniform(0, 1e4, n)
    beta = fee.beta_star(phi, delta, rho, alpha)
    got = np.array([kernel.fee_beta_star(*a) for a in zip(phi, delta, rho, alpha)])
    np.testing.assert_array_equal(np.isnan(got), np.isnan(beta))
    ok = np.isfinite(beta)
    assert ok.mean() > 0.7  # the rest: no wedge for these angles (NaN in both)
    assert_close(got[ok], beta[ok], "beta*")
    force = fee.failure_force(phi, c, delta, c_a, gamma, rho, alpha, w, d, q, beta)
    got = np.array([kernel.fee_failure_force(*a) for a in zip(phi, c, delta, c_a, gamma, rho, alpha, w, d, q, beta)])
    assert_close(got[ok], force[ok], "failure force")
    v_x, v_z = rng.uniform(-1, 2, n), rng.uniform(-0.5, 0.5, n)
    delta_p, _ = fee.velocity_corrected(delta, c_a, rho, alpha, v_x, v_z)
    got = np.array([kernel.fee_velocity_scale(*a, fee.FEE_VELOCITY_GAIN_S_M) for a in zip(rho, alpha, v_x, v_z)]) * delta
    np.testing.assert_allclose(got, delta_p, rtol=1e-14, atol=1e-15)
    state = ForceInputs(d=d, q=q, v_x=v_x, v_z=v_z, gamma=gamma, w=w, rho=rho, alpha=alpha, phi=phi, c=c,
                        delta=delta, distance_in_soil=0.0 * d, f_fee_x=0.0 * d, f_fee_z=0.0 * d)
    want = penetration_capacity(state, 0.02)
    got = np.array([kernel.penetration_capacity(*a, 0.02) for a in zip(phi, c, gamma, d, w)])
    assert_close(got, want, "penetration capacity")


PLUGINS = (
    ("tests.sim_plugins:constant_force",),
    ({"target": "soil_sim_node.plugins_example:side_wall_shear", "params": {"walls": 2.0}},),
    ("soil_physics.force_terms:plugin term=soil_inertia k=4", "soil_physics.force_terms:plugin term=compaction_hardening k=0.06"),
    ("soil_physics.force_terms:plugin term=form:wd_x*tsat3 k=2",),
)


@pytest.mark.parametrize("world", ["fee", "default"])
@pytest.mark.parametrize("plugins", PLUGINS, ids=["constant", "side_walls", "two_catalogue_terms", "a_form_on_time"])
def test_user_plugins_between_the_kernel_halves_match_the_reference(world, plugins):
    specs = [EpisodeSpec("Clay", 70.0, 0.5, 0.25, 21, 2.0), EpisodeSpec("Sand", 30.0, 0.9, 0.15, 22, 2.0)]
    compiled = run_episodes(SimConfig(world_mode=world, plugins=plugins), specs)
    assert_same_episodes(compiled, run_episodes(SimConfig(world_mode=world, plugins=plugins, engine="reference"), specs))
    plain = run_episodes(SimConfig(world_mode=world), specs)
    assert not np.allclose(compiled[0].forces, plain[0].forces)  # the plugin does act


@pytest.mark.parametrize("engine", ["compiled", "reference"])
def test_plugins_see_the_soil_patch_under_the_edge(engine):
    """``ForceInputs.relative_density_pct`` is the I_d of the patch under the edge."""
    sim_plugins.SEEN_DENSITY.clear()
    run_episodes(SimConfig(world_mode="fee", engine=engine, plugins=("tests.sim_plugins:record_density",)),
                 [EpisodeSpec("Loam", 50.0, 0.9, 0.2, 31, 1.5, patches=("0.0:Sand:20", "2.4:Clay:90", "2.8:Gravel:60"))])
    x, i_d = (np.concatenate(v) for v in zip(*sim_plugins.SEEN_DENSITY))
    want = np.where(x < 2.4, 20.0, np.where(x < 2.8, 90.0, 60.0))
    np.testing.assert_array_equal(i_d, want)
    assert x.max() > 2.9


@pytest.mark.parametrize("engine", ["compiled", "reference"])
def test_plugins_see_the_time_in_soil_summed_per_substep(engine):
    """``ForceInputs.time_in_soil`` is the time the edge has been in the soil before the substep
    (dt per substep with d > 0), close to what a model integrates from Θ_k per tick."""
    sim_plugins.SEEN_TIME.clear()
    ep, = run_episodes(SimConfig(world_mode="fee", engine=engine, plugins=("tests.sim_plugins:record_time_in_soil",)),
                       [EpisodeSpec("Loam", 50.0, 0.6, 0.15, 32, 2.0)])
    d, seen, dt = (np.concatenate([np.atleast_1d(v[i]) for v in sim_plugins.SEEN_TIME]) for i in range(3))
    assert seen[0] == 0.0 and d[-1] > 0.1
    np.testing.assert_allclose(np.diff(seen), dt[:-1] * (d[:-1] > 0), atol=1e-12)
    from_known = time_in_soil_of_known(ep.known)
    assert abs(from_known[-1] - seen[-1]) < 3.0 / 60  # the model's per-tick sum of Θ_k's d: within a few ticks


DITHER = AntiStallGains(dither_amplitude_m=0.05, dither_period_s=2.0)


FORCE_LIFT = dataclasses.replace(DITHER, force_lift_m_s=1.5, force_lift_share=0.9)


@pytest.mark.parametrize("gains", [DITHER, FORCE_LIFT], ids=["dither", "dither and force lift"])
def test_controller_step_is_the_controller_core_with_the_depth_dither_and_the_force_lift(gains):
    rng = np.random.default_rng(7)
    n = 400
    v, pz = rng.uniform(-0.2, 1.0, n), rng.uniform(-0.4, 0.1, n)
    v[::37], pz[::53] = np.nan, np.inf  # held state
    force = rng.uniform(-40e3, 40e3, (n, 2))
    force[::41, 0], force[::43, 1] = np.nan, -np.inf  # no force term
    core = AntiStallController(gains, 0.6, 0.15)
    row = kernel_gains(gains)
    np.testing.assert_array_equal(row, [gains.k_v_m_s, gains.c_vx, gains.delta_d_max_m, gains.dt_s,
                                        gains.dither_amplitude_m, gains.dither_period_s, gains.force_lift_m_s,
                                        gains.force_lift_share, *FORCE_LIMITS_N])
    ctl, command = np.zeros(3), np.array([0.0, 0.0, 0.0, MACHINE.blade_min_rel_m, MACHINE.blade_max_rel_m])
    for k in range(n):
        want = core.step(v[k], pz[k], force[k])
        kernel.controller_step(row, 0.6, 0.15, ctl, v[k], pz[k], force[k], command)
        assert tuple(command[:3]) == (want.u_zr[0], want.u_za[0], want.u_x[0]), k
        assert ctl[0] == core.depth_offset_m[0], k


def test_the_force_lift_takes_the_blade_out_of_a_stall_sooner_in_both_engines():
    """Dense clay at 0.3 m stalls the machine (20 kN tractive limit); lifting with the force
    beyond the limits as well as with the speed error (Eq. 11) shortens the stall, and both
    engines give the same episodes."""
    spec = [EpisodeSpec("Clay", 80.0, 0.5, 0.3, 3, 6.0)]
    lift = AntiStallGains(force_lift_m_s=2.0, force_lift_share=1.0)
    compiled = run_episodes(SimConfig(world_mode="fee"), spec, gains=lift)
    assert_same_episodes(compiled, run_episodes(SimConfig(world_mode="fee", engine="reference"), spec, gains=lift))
    (plain,) = run_episodes(SimConfig(world_mode="fee"), spec)

    def stall_ticks(ep):  # below Eq. 11's threshold v̄_x (1 − c_vx) once moving
        v = ep.column("v_x_c")
        moving = np.flatnonzero(v >= 0.5 * (1 - lift.c_vx))
        return int((v[moving[0]:] < 0.5 * (1 - lift.c_vx)).sum()) if len(moving) else len(v)

    assert stall_ticks(plain) > 60  # a second (measured 191 ticks; 0 with the lift)
    assert stall_ticks(compiled[0]) < 0.5 * stall_ticks(plain)
    assert np.max(np.abs(compiled[0].forces[:, 0])) <= np.max(np.abs(plain.forces[:, 0])) + 1e-9


@pytest.mark.parametrize("world", ["fee", "default"])
def test_depth_dither_sweeps_the_cut_depth_in_both_engines(world):
    """Dither on: the achieved depth swings by about ±A around the target; off: it holds."""
    spec = [EpisodeSpec("Loam", 20.0, 0.5, 0.2, 3, 4.0)]  # soft soil: no anti-stall offset
    compiled = run_episodes(SimConfig(world_mode=world), spec, gains=DITHER)
    assert_same_episodes(compiled, run_episodes(SimConfig(world_mode=world, engine="reference"), spec, gains=DITHER))
    (off,) = run_episodes(SimConfig(world_mode=world), spec)

    def half_swing(ep):  # over the last 2 s: one dither period
        d = ep.column("d")[120:]
        return (np.percentile(d, 97.5) - np.percentile(d, 2.5)) / 2

    assert abs(half_swing(compiled[0]) - DITHER.dither_amplitude_m) < 0.2 * DITHER.dither_amplitude_m
    assert half_swing(off) < 0.1 * DITHER.dither_amplitude_m


def test_the_engine_is_checked():
    with pytest.raises(ValueError, match=r"engine='numpy'"):
        SoilSimulator(SimConfig(engine="numpy"), SPECS[:1])
