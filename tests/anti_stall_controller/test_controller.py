"""Anti-stall controller core (paper §2.1.3, Eq. 11-12): behaviour, batching, validation."""
from __future__ import annotations

import math

import numpy as np
import pytest

from anti_stall_controller.controller import AntiStallController, AntiStallGains, ControlCommand
from soil_msgs_py.params import COMMAND_FIELDS, MACHINE, SAMPLE_RATE_HZ

DT = 1.0 / SAMPLE_RATE_HZ


def run(ctrl, v_x_c, p_z_c=0.0, steps=1):
    """Step ``steps`` times with constant measurements; return (offsets, commands)."""
    offsets, cmds = [], []
    for _ in range(steps):
        cmds.append(ctrl.step(v_x_c, p_z_c))
        offsets.append(ctrl.depth_offset_m)
    return np.array(offsets), cmds


def test_defaults_and_command_layout():
    g = AntiStallGains()
    assert (g.k_v_m_s, g.c_vx, g.delta_d_max_m) == (0.5, 0.2, 0.05)
    assert g.dt_s == pytest.approx(1.0 / 60.0)
    assert ControlCommand._fields == COMMAND_FIELDS
    c = AntiStallController(g, 0.5, 0.1)
    assert c.batch_size == 1
    cmd = c.step(0.5, 0.0)
    for arr in cmd:
        assert isinstance(arr, np.ndarray) and arr.shape == (1,) and arr.dtype == np.float64


def test_steady_tracking_lowers_blade_to_target_depth():
    speed, depth = 0.6, 0.15
    c = AntiStallController(AntiStallGains(), speed, depth)
    offsets, cmds = run(c, v_x_c=speed, steps=10)  # zero velocity error
    assert np.all(offsets == 0.0)
    assert cmds[-1].u_za[0] == -depth
    assert cmds[-1].u_zr[0] == -depth  # chassis on the original surface, p_z^c = 0
    assert cmds[-1].u_x[0] == speed

    # Starting from a raised blade, zero error (below threshold) integrates it back down
    # at K_v c_vx = 0.1 m/s and settles exactly on the target depth.
    c.reset(depth_offset_m=0.1)
    offsets, cmds = run(c, v_x_c=speed, steps=2 * SAMPLE_RATE_HZ)
    assert np.all(np.diff(offsets[:, 0]) <= 0.0)
    assert offsets[-1, 0] == 0.0
    assert cmds[-1].u_za[0] == -depth


def test_sustained_error_raises_blade_and_saturates_above_surface():
    speed, depth = 0.5, 0.2
    g = AntiStallGains()
    c = AntiStallController(g, speed, depth)
    # Stalled machine: e_vx = v̄ > e_vmin; offset rate K_v (1 - c_vx) = 0.4 m/s.
    offsets, cmds = run(c, v_x_c=0.0, steps=2 * SAMPLE_RATE_HZ)
    o = offsets[:, 0]
    top = depth + g.delta_d_max_m
    assert np.all(np.diff(o) >= 0.0)
    n_rise = int(np.argmax(o >= top))
    assert n_rise > 0 and np.all(np.diff(o[: n_rise + 1]) > 0.0)  # strictly rising until the clip
    assert o[0] == pytest.approx(g.k_v_m_s * (1 - g.c_vx) * DT)
    assert o[-1] == top
    assert cmds[-1].u_za[0] == pytest.approx(g.delta_d_max_m, abs=1e-15)  # Δd̄_max above surface
    assert c.depth_offset_m[0] == top


def test_below_threshold_integrates_back_down():
    speed, depth = 0.8, 0.1
    g = AntiStallGains()
    c = AntiStallController(g, speed, depth)
    run(c, v_x_c=0.0, steps=SAMPLE_RATE_HZ)
    assert c.depth_offset_m[0] == depth + g.delta_d_max_m

    # Velocity error below the threshold e_vmin = c_vx v̄: offset decreases monotonically.
    v_fast = speed * (1 - 0.5 * g.c_vx)  # e_vx = 0.5 e_vmin
    offsets, _ = run(c, v_x_c=v_fast, steps=5 * SAMPLE_RATE_HZ)
    o = offsets[:, 0]
    assert np.all(np.diff(o) <= 0.0)
    assert o[0] == pytest.approx(depth + g.delta_d_max_m - g.k_v_m_s * 0.5 * g.c_vx * DT)
    assert o[-1] == 0.0

    # Exactly at the threshold the offset does not move (up to rounding).
    c.reset(depth_offset_m=0.05)
    offsets, _ = run(c, v_x_c=speed * (1 - g.c_vx), steps=SAMPLE_RATE_HZ)
    assert offsets[-1, 0] == pytest.approx(0.05, abs=1e-12)


def test_gain_schedule_one_step_by_hand():
    g = AntiStallGains(k_v_m_s=0.5, c_vx=0.2, delta_d_max_m=0.05, dt_s=1.0 / 60.0)
    speed, depth, v_meas = 0.4, 0.1, 0.1
    c = AntiStallController(g, speed, depth)
    c.step(v_meas, 0.0)
    # Hand computation of Eq. 11: e_vx = 0.3, e_vmin = 0.08, K_Δp = K_v / v̄ = 1.25 1/s.
    e_vx = 0.4 - 0.1
    e_vmin = 0.4 * 0.2
    k_dp = 0.5 / 0.4
    assert k_dp == 1.25
    expected = k_dp * (e_vx - e_vmin) / 60.0  # = 0.0045833...
    assert c.depth_offset_m[0] == pytest.approx(expected, rel=1e-12)
    assert c.depth_offset_m[0] == pytest.approx(0.275 / 60.0, rel=1e-12)
    # The paper's per-step gain K_Δp,paper = K_v dt / v̄ gives the same step.
    assert g.paper_step_gain(speed) == pytest.approx(0.5 / 60.0 / 0.4, rel=1e-15)
    assert c.depth_offset_m[0] == pytest.approx(g.paper_step_gain(speed) * (e_vx - e_vmin), rel=1e-12)

    # Same relative error (e_vx / v̄ = 0.5) at different v̄ -> same offset rate, K_v (0.5 - c_vx).
    speeds = np.array([0.3, 0.5, 1.0])
    cb = AntiStallController(g, speeds, 0.2)
    cb.step(0.5 * speeds, 0.0)
    np.testing.assert_allclose(cb.depth_offset_m, 0.5 * (0.5 - 0.2) * DT, rtol=1e-12)


def test_rate_is_sample_rate_independent():
    """Same K_v at 60 Hz and 120 Hz -> same offset after the same elapsed time."""
    outs = []
    for hz in (60, 120):
        c = AntiStallController(AntiStallGains(dt_s=1.0 / hz), 0.5, 0.3)
        run(c, v_x_c=0.25, steps=hz // 2)  # 0.5 s
        outs.append(c.depth_offset_m[0])
    assert outs[0] == pytest.approx(outs[1], rel=1e-9)
    assert outs[0] == pytest.approx(0.5 * (0.5 - 0.2) * 0.5, rel=1e-9)


def test_u_zr_is_relative_to_chassis_and_clipped_to_joint_limits():
    depth = 0.1
    c = AntiStallController(AntiStallGains(), 0.5, depth, batch_size=4)
    p_z_c = np.array([0.0, -0.05, 2.0, -3.0])
    cmd = c.step(0.5, p_z_c)
    np.testing.assert_array_equal(cmd.u_za, -depth)
    assert cmd.u_zr[0] == -depth
    assert cmd.u_zr[1] == pytest.approx(-depth + 0.05)  # chassis on a 5 cm cut floor
    assert cmd.u_zr[2] == MACHINE.blade_min_rel_m  # chassis far above: joint fully down
    assert cmd.u_zr[3] == MACHINE.blade_max_rel_m  # chassis far below: joint fully up
    assert (MACHINE.blade_min_rel_m, MACHINE.blade_max_rel_m) == (-0.3, 1.0)


def test_run_time_target_change():
    g = AntiStallGains()
    c = AntiStallController(g, 0.5, 0.2)
    run(c, v_x_c=0.0, steps=SAMPLE_RATE_HZ)
    assert c.depth_offset_m[0] == 0.25
    # Shallower target: the integrator state is clipped to the new range [0, 0.05 + 0.05].
    c.set_targets(target_depth_m=0.05)
    assert c.depth_offset_m[0] == 0.1
    np.testing.assert_array_equal(c.target_speed_m_s, 0.5)
    cmd = c.step(0.0, 0.0)
    assert cmd.u_za[0] == pytest.approx(0.05)
    # New speed: u_x follows, and the threshold/gain use it on the next step.
    c.set_targets(target_speed_m_s=1.0)
    before = c.depth_offset_m[0]
    cmd = c.step(1.0, 0.0)
    assert cmd.u_x[0] == 1.0
    assert c.depth_offset_m[0] == pytest.approx(before - 0.5 * 0.2 * DT)
    # Rejected change leaves the controller intact.
    with pytest.raises(ValueError, match="target_depth_m"):
        c.set_targets(1.0, -0.1)
    np.testing.assert_array_equal(c.target_depth_m, 0.05)
    np.testing.assert_array_equal(c.target_speed_m_s, 1.0)
    # Gains can change at run time; a smaller Δd̄_max clips the state.
    run(c, v_x_c=0.0, steps=SAMPLE_RATE_HZ)
    c.set_gains(delta_d_max_m=0.01)
    assert c.depth_offset_m[0] == pytest.approx(0.06)
    assert c.gains.delta_d_max_m == 0.01 and c.gains.k_v_m_s == 0.5
    c.set_gains(AntiStallGains(k_v_m_s=0.0))
    before = c.depth_offset_m.copy()
    run(c, v_x_c=0.0, steps=10)  # K_v = 0 freezes the offset
    np.testing.assert_array_equal(c.depth_offset_m, before)


def _random_episode(rng, steps):
    v = rng.uniform(-0.2, 1.2, steps)
    v[rng.random(steps) < 0.05] = np.nan
    p = rng.uniform(-0.4, 0.4, steps)
    p[rng.random(steps) < 0.03] = np.inf
    return v, p


def test_batch_rows_are_bit_identical_to_single_runs():
    rng = np.random.default_rng(1234)
    b, steps = 7, 400
    speeds = rng.uniform(0.3, 1.0, b)
    depths = rng.uniform(0.0, 0.3, b)
    episodes = [_random_episode(rng, steps) for _ in range(b)]
    v = np.stack([e[0] for e in episodes], axis=1)  # (steps, B)
    p = np.stack([e[1] for e in episodes], axis=1)
    g = AntiStallGains(k_v_m_s=0.7, c_vx=0.15, delta_d_max_m=0.04)

    batch = AntiStallController(g, speeds, depths)
    out_b = []
    for k in range(steps):
        if k == 200:
            batch.set_targets(speeds[::-1].copy(), depths * 0.5)
        out_b.append(np.stack(batch.step(v[k], p[k])))
    out_b = np.stack(out_b)  # (steps, 3, B)
    off_b = batch.depth_offset_m

    for i in range(b):
        single = AntiStallController(g, speeds[i], depths[i])
        out_s = []
        for k in range(steps):
            if k == 200:
                single.set_targets(speeds[::-1][i], depths[i] * 0.5)
            out_s.append(np.stack(single.step(v[k, i], p[k, i])))
        out_s = np.stack(out_s)[:, :, 0]
        assert np.all(np.isfinite(out_s))
        assert out_s.tobytes() == out_b[:, :, i].copy().tobytes(), f"row {i} differs"
        assert single.depth_offset_m.tobytes() == off_b[i : i + 1].tobytes()


def test_deterministic():
    def go():
        rng = np.random.default_rng(7)
        c = AntiStallController(AntiStallGains(), rng.uniform(0.3, 1, 5), rng.uniform(0, 0.3, 5))
        return np.stack([np.stack(c.step(rng.uniform(0, 1, 5), rng.uniform(-0.3, 0.3, 5))) for _ in range(100)])

    assert go().tobytes() == go().tobytes()


@pytest.mark.parametrize(
    "kwargs, field, value",
    [
        (dict(k_v_m_s=float("nan")), "k_v_m_s", "nan"),
        (dict(k_v_m_s=-0.1), "k_v_m_s", "-0.1"),
        (dict(c_vx=-0.2), "c_vx", "-0.2"),
        (dict(c_vx=float("inf")), "c_vx", "inf"),
        (dict(delta_d_max_m=-0.01), "delta_d_max_m", "-0.01"),
        (dict(delta_d_max_m=float("nan")), "delta_d_max_m", "nan"),
        (dict(dt_s=0.0), "dt_s", "0.0"),
        (dict(dt_s=float("-inf")), "dt_s", "-inf"),
        (dict(force_lift_m_s=-1.0), "force_lift_m_s", "-1.0"),
        (dict(force_lift_m_s=float("nan")), "force_lift_m_s", "nan"),
        (dict(force_lift_share=0.0), "force_lift_share", "0.0"),
        (dict(force_lift_share=float("inf")), "force_lift_share", "inf"),
        # beyond sense: accepted before, and c_vx >= 1 silently switched Eq. 11 off
        (dict(k_v_m_s=1e308), "k_v_m_s", "1e+308"),
        (dict(c_vx=1.5), "c_vx", "1.5"),
        (dict(c_vx=1.0), "c_vx", "1.0"),
        (dict(delta_d_max_m=100.0), "delta_d_max_m", "100.0"),
        (dict(dither_amplitude_m=1.0), "dither_amplitude_m", "1.0"),
        (dict(force_lift_m_s=1e6), "force_lift_m_s", "1000000.0"),
        # no number: a text was taken as the number it spells
        (dict(c_vx="0.3"), "c_vx", "'0.3'"),
        (dict(k_v_m_s=True), "k_v_m_s", "True"),
    ],
)
def test_bad_gains_name_field_value_and_range(kwargs, field, value):
    with pytest.raises(ValueError) as exc:
        AntiStallGains(**kwargs)
    msg = str(exc.value)
    allowed = {"dt_s": "(0, inf)", "force_lift_share": "(0, inf)", "dither_period_s": "(0, inf)", "c_vx": "[0, 1)",
               "k_v_m_s": "[0, 10]", "force_lift_m_s": "[0, 10]", "delta_d_max_m": "[0, 0.66]",
               "dither_amplitude_m": "[0, 0.1]"}[field]
    assert field in msg and value in msg and allowed in msg, msg
    # set_gains validates the same way and leaves the old gains in place.
    c = AntiStallController(AntiStallGains(), 0.5, 0.1)
    with pytest.raises(ValueError, match=field):
        c.set_gains(**kwargs)
    assert c.gains == AntiStallGains()


@pytest.mark.parametrize(
    "speed, depth, field, value, allowed",
    [
        (0.0005, 0.1, "target_speed_m_s", "0.0005", "[0.001, 2]"),  # slower than the simulator takes (it was taken)
        (0.0, 0.1, "target_speed_m_s", "0.0", "[0.001, 2]"),
        (-0.5, 0.1, "target_speed_m_s", "-0.5", "[0.001, 2]"),
        (float("nan"), 0.1, "target_speed_m_s", "nan", "[0.001, 2]"),
        (float("inf"), 0.1, "target_speed_m_s", "inf", "[0.001, 2]"),
        (1000.0, 0.1, "target_speed_m_s", "1000.0", "[0.001, 2]"),  # beyond the chassis command's reach
        (0.5, -0.01, "target_depth_m", "-0.01", "[0, 0.66]"),
        (0.5, float("nan"), "target_depth_m", "nan", "[0, 0.66]"),
        (0.5, 1000.0, "target_depth_m", "1000.0", "[0, 0.66]"),  # deeper than the blade is high
        (np.array([0.5, -1.0]), 0.1, "target_speed_m_s", "-1.0", "[0.001, 2]"),
        (0.5, np.array([0.1, 0.2, float("inf")]), "target_depth_m", "inf", "[0, 0.66]"),
    ],
)
def test_bad_targets_name_field_value_and_range(speed, depth, field, value, allowed):
    with pytest.raises(ValueError) as exc:
        AntiStallController(AntiStallGains(), speed, depth)
    msg = str(exc.value)
    assert field in msg and value in msg and allowed in msg, msg
    assert ("at index" in msg) == (np.size(speed) > 1 or np.size(depth) > 1), msg  # a scalar has no index
    c = AntiStallController(AntiStallGains(), 0.5, 0.1)
    with pytest.raises(ValueError, match=field):
        c.set_targets(np.atleast_1d(speed)[-1], np.atleast_1d(depth)[-1])


def test_bad_shapes_and_gain_fields():
    with pytest.raises(ValueError, match="target_depth_m"):
        AntiStallController(AntiStallGains(), 0.5, np.array([0.1, 0.2]), batch_size=3)
    with pytest.raises(ValueError, match="target_speed_m_s"):
        AntiStallController(AntiStallGains(), np.ones((2, 2)), 0.1)
    c = AntiStallController(AntiStallGains(), np.array([0.5, 0.6]), 0.1)
    with pytest.raises(ValueError, match="v_x_c"):
        c.step(np.zeros(3), 0.0)
    with pytest.raises(ValueError, match="unknown gain"):
        c.set_gains(k_p=1.0)


def test_nan_measurement_holds_offset_and_commands_stay_finite():
    g = AntiStallGains()
    c = AntiStallController(g, 0.5, 0.2, batch_size=3)
    run(c, v_x_c=0.1, p_z_c=-0.02, steps=10)
    held = c.depth_offset_m
    assert np.all(held > 0)

    v = np.array([np.nan, 0.1, np.inf])
    p = np.array([-0.02, np.nan, -0.02])
    cmd = c.step(v, p)
    after = c.depth_offset_m
    assert after[0] == held[0]  # NaN velocity: offset held
    assert after[1] == held[1]  # NaN chassis height: offset held
    assert after[2] == held[2]  # inf velocity: offset held
    for arr in cmd:
        assert np.all(np.isfinite(arr))
    # u_zr for the NaN-p_z^c row uses the last finite p_z^c (-0.02).
    assert cmd.u_zr[1] == pytest.approx(cmd.u_za[1] + 0.02)

    # The integrator continues normally once measurements are finite again.
    c.step(0.1, -0.02)
    np.testing.assert_allclose(c.depth_offset_m, held + g.k_v_m_s / 0.5 * (0.4 - 0.1) * DT, rtol=1e-12)

    # Before any finite p_z^c, the level surface (0) is used.
    c2 = AntiStallController(g, 0.5, 0.1)
    cmd = c2.step(0.5, math.nan)
    assert cmd.u_zr[0] == -0.1 and c2.depth_offset_m[0] == 0.0


def test_force_lift_raises_the_offset_by_the_force_beyond_the_limits():
    """Item 5: with g > 0 the offset rises by g · max(s − θ, 0) · dt, s the larger share of the
    force limits (20 kN in x, 30 kN in z) of the tick's force, on top of Eq. 11; a force within
    θ or not finite adds nothing; rows of a batch each take their own force."""
    g = AntiStallGains(force_lift_m_s=2.0, force_lift_share=0.9)
    plain = AntiStallController(AntiStallGains(), 0.5, 0.2, batch_size=5)
    lift = AntiStallController(g, 0.5, 0.2, batch_size=5)
    force = np.array([[30e3, 0.0],  # x at 1.5 of its limit
                      [-10e3, 33e3],  # z at 1.1
                      [17e3, 26e3],  # 0.85 and 0.87: within θ
                      [np.nan, 45e3],  # not finite: nothing
                      [25e3, np.inf]])
    v = np.full(5, 0.3)  # slowing down: Eq. 11 raises the offset of both alike
    for _ in range(3):
        plain.step(v, 0.0)
        lift.step(v, 0.0, force)
    extra = lift.depth_offset_m - plain.depth_offset_m
    np.testing.assert_allclose(extra, 3 * DT * 2.0 * np.array([1.5 - 0.9, 1.1 - 0.9, 0.0, 0.0, 0.0]), rtol=1e-12, atol=1e-15)
    # the clip of Eq. 11 holds: at most Δd̄_max above the surface
    for _ in range(600):
        lift.step(v, 0.0, force)
    assert lift.depth_offset_m.max() == pytest.approx(0.2 + g.delta_d_max_m)


def test_without_the_force_lift_the_force_changes_nothing_and_with_it_is_required():
    rng = np.random.default_rng(3)
    a, b = AntiStallController(AntiStallGains(), 0.5, 0.15), AntiStallController(AntiStallGains(), 0.5, 0.15)
    for _ in range(200):
        v, pz = rng.uniform(0.0, 0.6), rng.uniform(-0.3, 0.0)
        assert np.stack(a.step(v, pz)).tobytes() == np.stack(b.step(v, pz, rng.uniform(-50e3, 50e3, 2))).tobytes()
    c = AntiStallController(AntiStallGains(force_lift_m_s=1.0), 0.5, 0.15, batch_size=2)
    with pytest.raises(ValueError, match="force_n .* is needed with force_lift_m_s > 0"):
        c.step(0.5, 0.0)
    with pytest.raises(ValueError, match=r"force_n must have shape \(2,\) or \(B, 2\) = \(2, 2\); got \(3,\)"):
        c.step(0.5, 0.0, np.zeros(3))
    assert c.depth_offset_m.tolist() == [0.0, 0.0]  # a refused tick changes nothing
