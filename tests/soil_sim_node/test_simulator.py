"""Simulator (soil_sim_node) phenomena of Wagner et al. §2.1.2 / §3.1-3.2, and its contracts.

The phenomena are measured by ``soil_sim_node.phenomena`` (the same code the
``soil_sim_report`` console script prints); the margins below were set after looking at the
measured numbers (quoted next to each assertion, seed 0, 10 s episodes), not by tuning the
simulator.

Tests marked ``xfail(strict=True)`` are KNOWN SIMULATOR / MODEL PROBLEMS, kept as failing
tests on purpose (each reason says what is wrong, with numbers). When the simulator is
fixed they XPASS, which fails the suite: then remove the marker.

Runtime: ~25 s on 2 cores (the closed-loop grids are batched: 24 episodes per world).
"""
from __future__ import annotations

import json
import math
import sys

import numpy as np
import pytest

from soil_msgs_py.params import (
    DEG,
    GROUND_TRUTH_PARAMS,
    MACHINE,
    MAX_TARGET_SPEED_M_S,
    SAMPLE_RATE_HZ,
    SOIL_TOOL_FRICTION_DEFAULT_RAD,
    SOIL_TOOL_FRICTION_FEE_RAD,
)
from soil_physics.blade_inertia import inertia_force_rows
from soil_physics.soils import COHESIVE_SOILS
from soil_sim_node import phenomena as ph
from soil_sim_node.effects import Effects, PluginError
from soil_sim_node.plugins_example import side_wall_force
from soil_sim_node.rollout import run_episodes
from soil_sim_node.simulator import EpisodeSpec, SimConfig, SoilSimulator

SETTINGS = ph.Settings(duration_s=10.0, seed=0)
LIMIT = MACHINE.horizontal_force_limit_n
EPISODE_ARRAYS = ("stamps_ns", "observations", "forces", "known", "truth", "extras")


def truth(ep, name):
    return ep.truth[:, GROUND_TRUTH_PARAMS.index(name)]


def assert_episodes_identical(a, b):
    for name in EPISODE_ARRAYS:
        assert np.array_equal(getattr(a, name), getattr(b, name)), f"{name} differs"


# --------------------------------------------------------------------------- shared runs
@pytest.fixture(scope="module")
def grids():
    """Closed loop, d̄_z = 0.25 m, v̄_x = 0.5 m/s, 4 soils x I_d {0..100}: one batch per world."""
    return {world: ph.run_grid(world, SETTINGS) for world in ph.WORLDS}


@pytest.fixture(scope="module")
def depth_rows(grids):
    return ph.depth_vs_density(SETTINGS, grids)


@pytest.fixture(scope="module")
def surcharge_rows(grids):
    return ph.surcharge_growth(SETTINGS, grids)


@pytest.fixture(scope="module")
def surcharge_depth_rows():
    return ph.surcharge_vs_depth(SETTINGS)


@pytest.fixture(scope="module")
def fee_rows(grids):
    return ph.fee_force_match(SETTINGS, grids)


@pytest.fixture(scope="module")
def open_loop_rows():
    return ph.open_loop_comparison(SETTINGS)


@pytest.fixture(scope="module")
def oscillation_rows(grids):
    return ph.force_oscillations(SETTINGS, grids)


@pytest.fixture(scope="module")
def fee_commands():
    """A fee-world closed-loop episode whose commands the open-loop plugin tests replay."""
    spec = EpisodeSpec("Loam", 40.0, 0.5, 0.1, 7, 5.0)
    return spec, run_episodes(SimConfig(world_mode="fee"), [spec])[0]


def replay_tail_force(config, spec, episode, tail_s=2.0):
    """Mean (F_x, F_z) over the last tail_s of an open-loop replay of the episode's commands."""
    out = ph.replay_commands(config, spec, episode)
    n = int(tail_s * SAMPLE_RATE_HZ)
    return out["forces"][-n:].mean(axis=0), out


# --------------------------------------------------------------------------- a. depth vs I_d
@pytest.mark.parametrize("world", ph.WORLDS)
@pytest.mark.parametrize("soil", COHESIVE_SOILS)
def test_a_dense_cohesive_soils_hit_the_limit_and_the_blade_rises(depth_rows, world, soil):
    rows = {r.relative_density_pct: r for r in depth_rows if r.world == world and r.soil == soil}
    ids, depth = ph.depth_trend(depth_rows, world, soil)
    # Measured: Clay 0.252 -> 0.147 (fee) / 0.153 (default) m, Loam 0.252 -> 0.171 / 0.175 m.
    assert depth[-1] < depth[0] - 0.05
    assert np.all(np.diff(depth) <= 0.01), f"depth not falling with I_d: {dict(zip(ids, depth.round(3)))}"
    loose, dense = rows[0.0], rows[100.0]
    # Loose: at the target, never at the 20 kN limit (measured 0.252-0.253 m, fraction 0.00).
    assert abs(loose.mean_depth_tail_m - SETTINGS.deep_depth_m) < 0.01
    assert loose.frac_at_limit == 0.0
    assert loose.mean_offset_tail_m < 1e-3
    # Dense (I_d >= 80): at the limit much of the time (measured 0.56-0.95), the controller
    # keeps the offset up (max 0.069-0.119 m vs 0.027-0.029 m loose), speed ~ v̄ (1 - c_vx).
    for i_d in (80.0, 100.0):
        assert rows[i_d].frac_at_limit > 0.4
        assert rows[i_d].max_offset_m > loose.max_offset_m + 0.03
        assert rows[i_d].mean_offset_tail_m > 0.03
        assert rows[i_d].mean_vx_tail_m_s < 0.45
    assert dense.mean_fx_tail_n > 0.9 * LIMIT


@pytest.mark.xfail(strict=True, reason=(
    "MODEL GAP (soil catalogue + FEE vs paper §3.2): the paper's mean depth of cut 'drops to nearly zero at "
    "I_d = 80, particularly for the non-cohesive soil', the forces exceeding the tractive limit for I_d > 60. "
    "Here dense Sand/Gravel never reach the 20 kN limit at d̄ = 0.25 m (fee F_x 11.9-17.2 kN, default 13.6-16.4 kN) "
    "and keep the full depth (0.245-0.253 m); Clay/Loam only fall to 0.15-0.18 m at I_d = 100."))
@pytest.mark.parametrize("world", ph.WORLDS)
def test_a_dense_noncohesive_soils_lose_depth_like_the_paper(depth_rows, world):
    dense = [r for r in depth_rows if r.world == world and r.soil not in COHESIVE_SOILS and r.relative_density_pct >= 80]
    assert all(r.mean_depth_tail_m < 0.5 * r.target_depth_m for r in dense)


# --------------------------------------------------------------------------- b. surcharge
def test_b_surcharge_grows_in_default_and_is_exactly_zero_in_fee(grids, surcharge_rows):
    default = [r for r in surcharge_rows if r.world == "default"]
    assert len(default) == len(SETTINGS.soils) * len(SETTINGS.densities)
    for r in default:
        # The pile fills with the cut and sheds over the blade, so Q follows the cut depth
        # and may dip; it must still grow through the episode (paper Fig. 3).
        assert r.spearman_time >= 0.5, r
        assert r.q_last_third_n > 1.15 * r.q_first_third_n, r
        assert r.q_first_third_n > 1000.0 and r.q_final_n > 5000.0, r
    for ep in grids["default"].values():
        q = truth(ep, "q")
        assert q[0] == 0.0 and q[-1] > 0.0
        assert np.array_equal(q, ep.column("q"))  # Θ_k's Q is the published truth Q
    for ep in grids["fee"].values():
        assert np.all(truth(ep, "q") == 0.0) and np.all(ep.column("q") == 0.0)
    assert all(r.q_max_abs_n == 0.0 for r in surcharge_rows if r.world == "fee")


@pytest.mark.xfail(strict=True, reason=(
    "SIMULATOR (effects.Effects surcharge): paper Fig. 3 shows the surcharge growing through the 10 s episode; "
    "here the pile fills at w d v_x (0.4 m^3/s at d = 0.25 m) and hits surcharge_capacity_m3 = 0.45 m^3 "
    "(Q = 8.4 kN for Loam 60) within 1.7 s at d̄ = 0.25-0.3 m, 2.5 s at 0.15 m, 4.0 s at 0.10 m; only d̄ = 0.05 m "
    "still grows in the last third. Q is flat for most of every episode in the paper's depth range."))
def test_b_surcharge_still_grows_late_in_the_episode(surcharge_depth_rows):
    for r in surcharge_depth_rows:
        assert r.q_last_third_n > 1.02 * r.q_middle_third_n, (r.target_depth_m, r.t_plateau_s)


# --------------------------------------------------------------------------- c. fee == FEE
def test_c_fee_world_force_is_the_fee_of_the_ground_truth(fee_rows):
    assert len(fee_rows) == 24
    for r in fee_rows:
        # Measured (inertia removed): mean error x 1.5-2.4 %, z 0.8-1.2 % of mean |F|; median tick
        # 0.1-29 N; 85-93 % of ticks within 1 %. The rest are transients (start, the chassis
        # dropping into its own cut, controller steps): joint dynamics.
        assert r.mae_x_no_inertia_pct < 4.0, r
        assert r.mae_z_no_inertia_pct < 3.0, r
        assert r.median_abs_x_no_inertia_n < 60.0 and r.median_abs_z_no_inertia_n < 30.0, r
        assert r.frac_ticks_within_1pct > 0.8, r
        # The blade inertia explains most of the raw z residual (668-749 N -> 54-237 N).
        assert r.mae_z_no_inertia_n < 0.5 * r.mae_z_n, r


def test_c_inertia_term_is_exact_for_a_free_blade():
    """Out of the soil (blade commanded up into the air) the measured force is pure inertia."""
    spec = EpisodeSpec("Sand", 50.0, 0.5, 0.1, 3, 1.0)
    n = 60
    cmds = np.column_stack([np.linspace(0.1, 0.3, n), np.linspace(0.1, 0.3, n), np.full(n, 0.5)])
    out = ph.replay_commands(SimConfig(world_mode="fee"), spec, cmds)
    assert np.all(out["truth"][1:, GROUND_TRUTH_PARAMS.index("d")] <= 0.0)
    ix, iz = inertia_force_rows(out["velocities"][:, 1], out["velocities"][:, 0])
    np.testing.assert_allclose(out["forces"][:, 0], ix, atol=1e-6)
    np.testing.assert_allclose(out["forces"][:, 1], iz, atol=1e-6)


# --------------------------------------------------------------------------- d. open loop
def test_d_replay_reproduces_the_recorded_fee_episode(open_loop_rows):
    assert open_loop_rows and all(r.replay_reproduces_fee_episode for r in open_loop_rows)


def test_d_default_forces_exceed_fee_forces_under_the_same_commands(open_loop_rows):
    for r in open_loop_rows:
        # Shallow commands (d̄ = 0.06 m): neither world near the limit (fractions 0.00).
        assert not r.saturated, r
        # Dense default soils hold the edge up to ~1 cm shallower (penetration resistance), which
        # only lowers the default force: the comparison below stays conservative.
        assert abs(r.default_mean_depth_m - r.fee_mean_depth_m) < 0.012, r
        assert r.default_mean_depth_m <= r.fee_mean_depth_m + 0.005, r
        # Measured ratio default/fee of mean |F|: 1.11 (Clay 100) to 5.31 (Sand 0).
        assert r.default_mean_abs_f_n > 1.05 * r.fee_mean_abs_f_n, r
        assert r.default_mean_fx_n > r.fee_mean_fx_n, r


def test_d_default_forces_exceed_fee_forces_dataset_level(grids):
    levels = {(r.world, r.group): r for r in ph.closed_loop_force_levels(SETTINGS, grids)}
    d, f = levels[("default", "all I_d")], levels[("fee", "all I_d")]
    # Measured: |F| 16.0 vs 13.5 kN; |F_z| 2.8 vs 1.2 kN (paper §3.2: "F_z is much larger").
    assert d.mean_abs_f_n > 1.1 * f.mean_abs_f_n
    assert d.mean_abs_fz_n > 1.5 * f.mean_abs_fz_n


def test_d_default_vertical_force_exceeds_fee_in_every_unsaturated_case(open_loop_rows):
    assert all(r.default_mean_abs_fz_n > r.fee_mean_abs_fz_n for r in open_loop_rows)


# --------------------------------------------------------------------------- e. oscillations
def test_e_dense_default_soils_oscillate_like_the_paper(oscillation_rows):
    groups = {g.label: g for g in ph.oscillation_groups(oscillation_rows, SETTINGS)}
    dense, loose = groups["default, I_d >= 80"], groups["default, I_d <= 20"]
    fee_dense, fee_all = groups["fee, I_d >= 80"], groups["fee, all"]
    px, pz = ph.PAPER_OSCILLATION_N
    # Measured p95-p5 (detrended, tail): dense default 9.6 kN x / 12.0 kN z (paper ~5 / ~10 kN).
    assert 0.5 * px <= dense.p95_p5_fx_n <= 3.0 * px
    assert 0.5 * pz <= dense.p95_p5_fz_n <= 3.0 * pz
    # Loose default 5.9 / 2.1 kN; fee 1.1 / 0.6 kN (dense) and 0.7 / 0.6 kN (all).
    assert dense.p95_p5_fx_n > 1.3 * loose.p95_p5_fx_n and dense.p95_p5_fz_n > 3.0 * loose.p95_p5_fz_n
    for g in (fee_dense, fee_all):
        assert g.p95_p5_fx_n < 0.25 * dense.p95_p5_fx_n and g.p95_p5_fz_n < 0.25 * dense.p95_p5_fz_n
        assert g.std_fx_n < 0.5 * dense.std_fx_n and g.std_fz_n < 0.5 * dense.std_fz_n
    # Dense cohesive default episodes individually reach the paper's z amplitude (measured 14.6-22.5 kN).
    for r in oscillation_rows:
        if r.world == "default" and r.soil in COHESIVE_SOILS and r.relative_density_pct >= 80:
            assert r.p95_p5_fz_n > pz, r


def test_penetration_is_a_stable_constraint_that_dense_soil_resists():
    """Penetration is a one-sided rigid-plastic constraint (soil_physics.bearing.penetration_capacity): dense
    gravel holds a deep-commanded edge above its target while the lift joint pushes down, the
    reaction never exceeds what the joint and the blade's weight can push, and the edge does not
    chatter (the old speed-gated damper alternated v_z sign every substep)."""
    only_pen = SimConfig(world_mode="default", effects=Effects.fee().with_switches(penetration=True))
    none = SimConfig(world_mode="default", effects=Effects.fee())
    deep = EpisodeSpec("Gravel", 100.0, 0.5, 0.3, 11, 6.0)
    with_pen, without = (run_episodes(cfg, [deep])[0] for cfg in (only_pen, none))
    assert with_pen.column("d")[-180:].mean() < 0.3 - 0.03 < without.column("d")[-180:].mean()
    assert with_pen.column("f_z_b")[-180:].mean() < -10e3  # the joint pushes hard on the soil
    assert with_pen.column("f_z_b").min() >= -30e3 - 400.0 * 9.81 - 1e-6  # 30 kN joint + blade weight (tared)
    vz = with_pen.column("v_z_b")[-180:]
    assert np.mean(np.diff(np.sign(vz)) != 0) < 0.2, vz  # no tick-to-tick sign chatter
    assert np.abs(vz).max() < 0.05


# --------------------------------------------------------------------------- determinism, batching
DET_SPECS = [EpisodeSpec("Loam", 70.0, 0.6, 0.2, 5, 3.0), EpisodeSpec("Gravel", 30.0, 0.4, 0.1, 6, 3.0)]


def test_same_seed_is_bit_identical_and_different_seeds_differ_in_default():
    cfg = SimConfig(world_mode="default")
    a, b = run_episodes(cfg, DET_SPECS), run_episodes(cfg, DET_SPECS)
    for x, y in zip(a, b):
        assert_episodes_identical(x, y)
        assert x.meta == y.meta
    other = [EpisodeSpec(s.soil, s.relative_density_pct, s.target_speed_m_s, s.target_depth_m, s.seed + 100, s.duration_s)
             for s in DET_SPECS]
    for x, y in zip(a, run_episodes(cfg, other)):
        assert not np.array_equal(x.forces, y.forces)  # noise and particle events are seeded


def test_a_batch_row_equals_the_episode_run_alone():
    specs = [
        EpisodeSpec("Clay", 90.0, 0.3, 0.28, 21, 3.0),
        EpisodeSpec("Sand", 10.0, 1.0, 0.05, 22, 3.0),
        EpisodeSpec("Loam", 55.0, 0.7, 0.15, 23, 3.0),
        EpisodeSpec("Gravel", 100.0, 0.5, 0.3, 24, 3.0),
    ]
    cfg = SimConfig(world_mode="default")
    batch = run_episodes(cfg, specs)
    for spec, row in zip(specs, batch):
        assert_episodes_identical(row, run_episodes(cfg, [spec])[0])


# --------------------------------------------------------------------------- bad input
@pytest.mark.parametrize("field_, value, kwargs", [
    ("soil", "Mud", dict(soil="Mud")),
    ("relative_density_pct", "101", dict(relative_density_pct=101.0)),
    ("relative_density_pct", "-5", dict(relative_density_pct=-5.0)),
    ("target_depth_m", "-0.1", dict(target_depth_m=-0.1)),
    ("target_speed_m_s", "0", dict(target_speed_m_s=0.0)),
])
def test_bad_episode_specs_name_field_and_value(field_, value, kwargs):
    base = dict(soil="Clay", relative_density_pct=50.0, target_speed_m_s=0.5, target_depth_m=0.1, seed=0, duration_s=1.0)
    spec = EpisodeSpec(**{**base, **kwargs})
    with pytest.raises(ValueError) as err:
        SoilSimulator(SimConfig(), [spec])
    assert field_ in str(err.value) and value in str(err.value), str(err.value)
    with pytest.raises(ValueError, match=field_):
        run_episodes(SimConfig(world_mode="fee"), [spec])


@pytest.mark.parametrize("field_, value, needle", [
    ("relative_density_pct", True, "relative_density_pct=True must be a number in [0, 100] %"),
    ("target_speed_m_s", 10**400, "target_speed_m_s=1000000000000000000"),
    ("seed", True, "seed=True must be an integer"),
])
def test_a_bool_or_an_integer_too_large_for_a_float_is_refused_naming_it(field_, value, needle):
    """True had been simulated as 1 % or 1 m/s; 10**400 ended in an OverflowError traceback."""
    base = dict(soil="Clay", relative_density_pct=50.0, target_speed_m_s=0.5, target_depth_m=0.1, seed=0, duration_s=1.0)
    with pytest.raises(ValueError) as err:
        EpisodeSpec(**{**base, field_: value}).resolve()
    assert needle in str(err.value), str(err.value)


def test_numpy_numbers_in_range_are_accepted():
    """np.float32(50) had been refused as "relative_density_pct=50.0 outside [0.0, 100.0]"."""
    spec = EpisodeSpec("Clay", np.float32(50), np.float64(0.5), np.float32(0.1), np.int64(3), np.int64(1))
    assert spec.resolve()[0].relative_density_pct == 50.0


def test_a_machine_driven_faster_than_its_spec_keeps_its_cut_in_the_heightfield():
    """The heightfield was sized from the spec's own speed: a teleop (or a controller at another
    speed) at 2 m/s in a 0.3 m/s episode drove past its end, where every cut was written into the
    last cell and lost (an outside reviewer's 1 m/s lost a quarter of the volume per metre)."""
    from anti_stall_controller.controller import AntiStallController

    spec = EpisodeSpec("Sand", 20.0, 0.3, 0.1, seed=1, duration_s=4.0)
    sim = SoilSimulator(SimConfig(world_mode="fee"), [spec])
    ctl = AntiStallController(None, MAX_TARGET_SPEED_M_S, 0.1)
    out, x_b, depth = sim.reset(), [], []
    for _ in range(round(spec.duration_s * SAMPLE_RATE_HZ)):
        cmd = ctl.step(out.velocities[:, 1], out.positions[:, 2], out.forces)
        out = sim.step(cmd.u_zr, cmd.u_za, cmd.u_x)
        x_b.append(out.positions[0, 0]), depth.append(out.known[0, 5])
    assert x_b[-1] > 2.0 + 1.5 * 0.3 * spec.duration_s + 3.0 + 1.0, x_b[-1]  # beyond where the old heightfield ended
    # over the second half of the travel the heightfield is as deep as the edge cut
    half = len(x_b) // 2
    x = sim.x_min + sim.dyn.terrain_cell_m * (np.arange(sim.n_cells) + 0.5)
    cut = -sim.terrain[0][(x > x_b[half]) & (x < x_b[-1] - 0.05)]
    assert len(cut) == pytest.approx((x_b[-1] - 0.05 - x_b[half]) / sim.dyn.terrain_cell_m, abs=2), len(cut)
    assert np.mean(cut) == pytest.approx(np.mean(depth[half:]), rel=0.05), (np.mean(cut), np.mean(depth[half:]))


def test_plugin_module_that_does_not_import_is_named():
    with pytest.raises(PluginError, match=r"no_such_module"):
        SoilSimulator(SimConfig(plugins=("no_such_module:f",)), DET_SPECS[:1])


def test_a_plugin_is_checked_against_its_parameters_when_it_loads():
    """Parameters a plugin's function cannot be called with are refused at load, naming them; a
    callable object, **kwargs, keyword-only parameters and a partial are taken as they are."""
    import functools
    import types

    from soil_sim_node.effects import ForcePlugin

    module = types.ModuleType("plugin_shapes")
    module.kw_only = lambda state, *, f_x: (f_x, 0.0)
    module.any_kw = lambda state, **params: (0.0, 0.0)
    module.obj = type("Drag", (), {"__call__": lambda self, state, k=1.0: (k, 0.0)})()
    module.part = functools.partial(lambda state, a, b=0.0: (a + b, 0.0), a=1.0)
    sys.modules["plugin_shapes"] = module
    try:
        for spec in ("plugin_shapes:kw_only f_x=2", "plugin_shapes:any_kw anything=3", "plugin_shapes:obj k=2",
                     "plugin_shapes:part b=1", "plugin_shapes:part"):
            assert ForcePlugin.load(spec).target == spec.split()[0]
        for spec, needle in (("plugin_shapes:kw_only", r"cannot be called with the parameters \[\]: missing a required"),
                             ("plugin_shapes:obj kk=2", r"cannot be called with the parameters \['kk'\]")):
            with pytest.raises(PluginError, match=needle):
                ForcePlugin.load(spec)
    finally:
        del sys.modules["plugin_shapes"]


def _step_into_soil(sim, ticks=3):
    for _ in range(ticks):
        sim.step(-0.1, -0.1, 0.5)


def test_plugin_returning_nan_is_named():
    sim = SoilSimulator(SimConfig(world_mode="fee", plugins=("tests.sim_plugins:nan_force",)), DET_SPECS[:1])
    with pytest.raises(PluginError, match=r"tests.sim_plugins:nan_force.*f_x=nan"):
        _step_into_soil(sim)


def test_plugin_returning_a_force_no_soil_makes_is_named():
    """1e300 N is finite, and once gave a bag with the blade 1e297 m away and exit 0."""
    sim = SoilSimulator(SimConfig(world_mode="fee", plugins=("tests.sim_plugins:in_soil_constant_drag f_x=1e300",)),
                        DET_SPECS[:1])
    with pytest.raises(PluginError, match=r"in_soil_constant_drag.*f_x=1e\+300 N, beyond"):
        _step_into_soil(sim)


def test_plugin_returning_a_matrix_is_named():
    sim = SoilSimulator(SimConfig(world_mode="fee", plugins=("tests.sim_plugins:matrix_force",)), DET_SPECS)
    with pytest.raises(PluginError, match=r"tests.sim_plugins:matrix_force.*f_x of shape \(2, 2\)"):
        _step_into_soil(sim)


def test_plugin_returning_a_wrong_length_vector_is_named():
    sim = SoilSimulator(SimConfig(world_mode="fee", plugins=("tests.sim_plugins:too_long_force",)), DET_SPECS)
    try:
        _step_into_soil(sim)
    except PluginError as exc:
        assert "tests.sim_plugins:too_long_force" in str(exc) and "f_x" in str(exc)
    except ValueError as exc:
        raise AssertionError(f"unnamed error: {type(exc).__name__}: {exc}") from exc
    else:
        raise AssertionError("no error for a wrong-length plugin output")


@pytest.mark.parametrize("name, args", [
    ("u_zr", (math.nan, 0.0, 0.5)),
    ("u_za", (0.0, math.inf, 0.5)),
    ("u_x", (0.0, 0.0, -math.inf)),
])
def test_non_finite_commands_are_refused_by_name(name, args):
    sim = SoilSimulator(SimConfig(), DET_SPECS)
    with pytest.raises(ValueError, match=rf"\b{name}="):
        sim.step(*args)
    with pytest.raises(ValueError, match=rf"\b{name}="):
        cmds = np.tile([0.0, 0.0, 0.5], (5, 1))
        cmds[2, ("u_zr", "u_za", "u_x").index(name)] = args[("u_zr", "u_za", "u_x").index(name)]
        ph.replay_commands(SimConfig(), DET_SPECS[0], cmds)


# --------------------------------------------------------------------------- plugins that work
def test_constant_plugin_adds_its_force_in_fee_open_loop(fee_commands):
    spec, ep = fee_commands
    base, out = replay_tail_force(SimConfig(world_mode="fee"), spec, ep)
    plus, _ = replay_tail_force(SimConfig(world_mode="fee", plugins=("tests.sim_plugins:constant_force",)), spec, ep)
    np.testing.assert_allclose(plus - base, [1000.0, 0.0], atol=30.0)
    with_params = SimConfig(world_mode="fee", plugins=(
        {"target": "tests.sim_plugins:constant_force", "params": {"f_x": 1500.0, "f_z": -500.0}},))
    plus2, _ = replay_tail_force(with_params, spec, ep)
    np.testing.assert_allclose(plus2 - base, [1500.0, -500.0], atol=40.0)
    # plugins are recorded in the episode metadata
    meta = run_episodes(with_params, [EpisodeSpec("Loam", 40.0, 0.5, 0.1, 7, 0.1)])[0].meta
    assert meta.plugins == ["tests.sim_plugins:constant_force"]


def test_example_side_wall_shear_plugin_increases_fx_by_its_formula():
    spec = EpisodeSpec("Clay", 80.0, 0.5, 0.15, 9, 5.0)
    ep = run_episodes(SimConfig(world_mode="fee"), [spec])[0]
    target = "soil_sim_node.plugins_example:side_wall_shear"
    base, out = replay_tail_force(SimConfig(world_mode="fee"), spec, ep)
    plus, out_p = replay_tail_force(SimConfig(world_mode="fee", plugins=(target,)), spec, ep)
    n = 120
    th = {k: out_p["truth"][-n:, j] for j, k in enumerate(GROUND_TRUTH_PARAMS)}
    fx_exp, fz_exp = side_wall_force(th["phi"], th["c"], th["gamma"], th["delta"], th["rho"], th["alpha"], th["d"])
    assert fx_exp.mean() > 500.0  # dense clay, d ~ 0.15 m: ~0.9 kN
    assert plus[0] - base[0] == pytest.approx(fx_exp.mean(), rel=0.05)
    assert plus[1] - base[1] == pytest.approx(fz_exp.mean(), abs=30.0)
    # params reach the plugin: no walls, no force
    off, _ = replay_tail_force(SimConfig(world_mode="fee", plugins=(
        {"target": target, "params": {"walls": 0.0}},)), spec, ep)
    np.testing.assert_array_equal(off, base)


# --------------------------------------------------------------------------- effects
EFFECT_SPECS = [EpisodeSpec("Clay", 100.0, 0.5, 0.25, 3, 4.0), EpisodeSpec("Sand", 50.0, 0.8, 0.1, 4, 4.0)]


@pytest.fixture(scope="module")
def default_runs():
    return run_episodes(SimConfig(world_mode="default"), EFFECT_SPECS)


@pytest.mark.parametrize("name", Effects.names())
def test_each_default_effect_is_switchable_and_matters(default_runs, name):
    cfg = SimConfig(world_mode="default", effects=Effects().with_switches(**{name: False}))
    off = run_episodes(cfg, EFFECT_SPECS)
    for ep in off:
        assert name not in ep.meta.effects
    if name == "surcharge":
        assert all(np.all(truth(ep, "q") == 0.0) for ep in off)
    assert any(not np.array_equal(a.forces, b.forces) for a, b in zip(default_runs, off)), f"{name} has no effect"


def test_unknown_effect_switch_is_refused():
    with pytest.raises(ValueError, match="wobble"):
        Effects().with_switches(wobble=False)


def test_default_world_with_all_effects_off_is_the_fee_world_except_delta():
    specs = [EpisodeSpec("Loam", 60.0, 0.5, 0.2, 31, 4.0), EpisodeSpec("Sand", 20.0, 0.8, 0.12, 32, 4.0)]
    reseeded = [EpisodeSpec(s.soil, s.relative_density_pct, s.target_speed_m_s, s.target_depth_m, s.seed + 7, s.duration_s)
                for s in specs]
    off = SimConfig(world_mode="default", effects=Effects.fee())
    a, b = run_episodes(off, specs), run_episodes(off, reseeded)
    fee_world = run_episodes(SimConfig(world_mode="fee"), specs)
    for x, y, f in zip(a, b, fee_world):
        # no surcharge, no noise, no particles: deterministic whatever the seed
        assert np.all(truth(x, "q") == 0.0)
        for name in ("observations", "forces", "known", "truth", "extras"):
            assert np.array_equal(getattr(x, name), getattr(y, name)), name
        # the only difference to the fee world is delta (10 deg vs 15 deg, §3.1) ...
        assert np.all(truth(x, "delta") == SOIL_TOOL_FRICTION_DEFAULT_RAD)
        assert np.all(truth(f, "delta") == SOIL_TOOL_FRICTION_FEE_RAD)
        assert SOIL_TOOL_FRICTION_FEE_RAD - SOIL_TOOL_FRICTION_DEFAULT_RAD == pytest.approx(5 * DEG)
        assert not np.array_equal(x.forces, f.forces)
        # ... and it obeys the same FEE physics: F - m_b dv/dt == FEE(truth) on typical ticks
        fx_fee, fz_fee = ph.fee_of_truth(x.truth)
        ix, iz = inertia_force_rows(x.column("v_x_c"), x.column("v_z_b"))
        mag = np.hypot(x.forces[1:, 0], x.forces[1:, 1]).mean()
        ex = np.abs(x.forces[1:, 0] - ix[1:] - fx_fee[1:])
        ez = np.abs(x.forces[1:, 1] - iz[1:] - fz_fee[1:])
        assert ex.mean() < 0.04 * mag and ez.mean() < 0.03 * mag
        assert np.median(ex) < 60.0 and np.median(ez) < 30.0
        # delta = 10 deg with rho = 80 deg: the FEE force is horizontal (F_z^FEE ~ 0)
        assert np.abs(fz_fee[60:]).max() < 0.02 * np.abs(fx_fee[60:]).max()


# --------------------------------------------------------------------------- report
def test_format_report_and_json(grids, depth_rows, surcharge_rows, surcharge_depth_rows, fee_rows, open_loop_rows,
                                 oscillation_rows):
    report = ph.PhenomenaReport(
        SETTINGS, depth=depth_rows, surcharge=surcharge_rows, surcharge_depths=surcharge_depth_rows,
        fee_match=fee_rows, open_loop=open_loop_rows, force_levels=ph.closed_loop_force_levels(SETTINGS, grids),
        oscillations=oscillation_rows, oscillation_summary=ph.oscillation_groups(oscillation_rows, SETTINGS))
    text = ph.format_report(report)
    for heading in ("a. Cut depth", "b. Surcharge", "b'. Surcharge", "c. fee world", "d. Open loop", "d''. Closed loop",
                    "e. Force oscillations", "Summary"):
        assert heading in text
    verdicts = {claim.split(":")[0]: ok for claim, ok, _ in ph.summarize(report)}
    assert verdicts["a"] and verdicts["b"] and verdicts["c"] and verdicts["d"] and verdicts["d''"] and verdicts["e"]
    data = json.loads(json.dumps(report.to_dict(), allow_nan=False))
    assert len(data["depth"]) == 48 and len(data["open_loop"]) == len(open_loop_rows)


def test_report_cli(tmp_path, capsys):
    from soil_sim_node.report import main

    assert main(["--duration", "1", "--quiet"]) == 2
    assert "--duration" in capsys.readouterr().err
    path = tmp_path / "numbers.json"
    assert main(["--duration", "3", "--seed", "5", "--quiet", "--json", str(path)]) == 0
    out = capsys.readouterr().out
    assert "a. Cut depth" in out and "Summary" in out
    data = json.loads(path.read_text())
    assert data["settings"]["seed"] == 5 and data["settings"]["duration_s"] == 3.0
    assert {"depth", "surcharge", "fee_match", "open_loop", "oscillations", "summary"} <= set(data)


def test_a_soil_the_fee_gives_no_failure_wedge_is_refused_with_its_name_not_simulated_as_no_force(tmp_path, capsys):
    """φ = 0 (an undrained clay) or φ + δ + ρ ≥ 180°: the FEE has no failure wedge, and the simulator's
    force there is 0, a soil that resists nothing. Such a soil is refused, named with its φ, at
    its own density or once compaction makes it dense; a small φ is a soil (a large force)."""
    from soil_physics.soils import soil_from_dict
    from soil_sim_node.rollout import run_episodes
    from soil_sim_node.simulator import EpisodeSpec, SimConfig, SoilSimulator, check_failure_wedges

    def soil(name, phi):
        return {name: soil_from_dict({"name": name, "phi_deg": list(phi), "cohesion_pa": [30e3, 30e3],
                                      "unit_weight_n_m3": [17e3, 17e3]})}

    # the fee world's blade (ρ 80°, δ 15°) has a wedge up to φ 85°; the default world's (δ 10°) to 90°
    steep = (("Steep", (89, 89.9), "phi=89.5°"), ("Densens", (30, 89.9), "100 %: phi=89.9°"))
    for world, cases in (("fee", steep), ("default", ())):
        for name, phi, needle in (("Undrained", (0, 0), "phi=0°"),) + cases:
            custom = soil(name, phi)
            spec = EpisodeSpec(name, 50.0, 0.5, 0.2, seed=0, duration_s=1.0)
            with pytest.raises(ValueError, match=f"soil '{name}' at I_d .*{needle}.*no failure wedge"):
                SoilSimulator(SimConfig(world_mode=world), [spec], custom)
            with pytest.raises(ValueError, match="no failure wedge"):  # a patch of it too
                check_failure_wedges(SimConfig(world_mode=world), EpisodeSpec(
                    "Clay", 50.0, 0.5, 0.2, seed=0, patches=["0:Clay:50", f"5:{name}:50"]), custom)
        small = soil("Small", (2, 2))
        with pytest.warns(UserWarning, match=r"soil 'Small' at I_d 50 %: phi=2° is below the soil-tool friction .* while "
                                             r"the blade rises .* the recorded truth's FEE"):
            ep = run_episodes(SimConfig(world_mode=world), [EpisodeSpec("Small", 50.0, 0.5, 0.05, seed=0, duration_s=2.0)],
                              custom_soils=small)[0]
        assert np.abs(ep.forces[60:, 0]).max() > 5e3  # a nearly frictionless cohesive soil resists (hard)
    # the batch refuses it before writing any bag, the good soils' included
    import yaml
    from soil_sim_node import batch

    soil_file = tmp_path / "soils.yaml"
    soil_file.write_text(yaml.safe_dump({"soils": [{"name": "Undrained", "phi_deg": [0, 0], "cohesion_pa": [3e4, 3e4],
                                                    "unit_weight_n_m3": [17e3, 17e3]}]}))
    out = tmp_path / "bags"
    assert batch.main(["--mode", "fee", "--soil-file", str(soil_file), "--soils", "Sand,Undrained", "--seeds", "2",
                       "--relative-densities", "50", "--speeds", "0.5", "--depths", "0.2", "--duration", "1",
                       "--workers", "2", "--quiet", "--out", str(out)]) == 2
    assert "soil 'Undrained' at I_d 50 %" in capsys.readouterr().err and not out.exists()
    import warnings

    # without cohesion too: the world's adhesion c_a keeps the truth's FEE off the simulated 0 (a reviewer's)
    loose = {"Loose": soil_from_dict({"name": "Loose", "phi_deg": [12, 12], "cohesion_pa": [0, 0],
                                      "unit_weight_n_m3": [17e3, 17e3]})}
    with pytest.warns(UserWarning, match=r"soil 'Loose' at I_d 50 %: phi=12° is below the soil-tool friction delta=15°"):
        SoilSimulator(SimConfig(world_mode="fee"), [EpisodeSpec("Loose", 50.0, 0.5, 0.1, seed=0, duration_s=1.0)], loose)
    for name in ("Clay", "Loam", "Sand", "Gravel"):  # every catalogue soil has its wedge, rising too (φ ≥ 17° > δ)
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            SoilSimulator(SimConfig(world_mode="default"), [EpisodeSpec(name, 0.0, 0.5, 0.2, seed=0)])
            SoilSimulator(SimConfig(world_mode="fee"), [EpisodeSpec(name, 0.0, 0.5, 0.2, seed=0)])
            SoilSimulator(SimConfig(world_mode="fee"), [EpisodeSpec(name, 100.0, 0.5, 0.2, seed=0)])
