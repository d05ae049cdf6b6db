"""Classical baseline (least-squares FEE fit, after Tan et al. 2005): recovery, real bag, errors.

The synthetic windows are made with the library FEE itself, so a correct fit must recover
the soil exactly when the depth varies (gamma d^2 and c d separable), and must at least
reproduce the force when it does not (the phi/c ambiguity of paper §3.2).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pinn_estimator.classical import (
    C_BOUNDS_PA,
    PHI_BOUNDS_RAD,
    ClassicalFit,
    fit_windows,
)
from soil_physics import fee
from soil_physics.augmented_fee import fee_forces
from soil_msgs_py.params import ADHESION_PA, DEG, GROUND_TRUTH_PARAMS, KNOWN_PARAMS, MACHINE

REPO = Path(__file__).resolve().parents[2]
FEE_BAG = REPO / "bags" / "samples" / "fee_loam_id060_v0.50_d0.200_s7"
T = 60

# (name, phi [deg], c [Pa], delta [deg])
SOILS = [
    ("loam", 30.0, 3000.0, 15.0),
    ("sand", 35.0, 0.0, 15.0),
    ("clay", 22.0, 9000.0, 10.0),
    ("gravel", 42.0, 500.0, 25.0),
]


def make_window(phi_deg, c_pa, delta_deg, depth=(0.10, 0.25), v_x=0.5, v_z=-0.02, q=0.0, t=T):
    """(known (T, 9), forces (T, 2)) of a window whose forces are exactly the FEE's."""
    known = np.zeros((t, len(KNOWN_PARAMS)))
    values = dict(c_a=ADHESION_PA, gamma=18.7e3, rho=MACHINE.blade_angle_rad, alpha=0.0,
                  w=MACHINE.blade_width_m, q=q, v_x=v_x, v_z=v_z)
    for name, value in values.items():
        known[:, KNOWN_PARAMS.index(name)] = value
    known[:, KNOWN_PARAMS.index("d")] = np.linspace(depth[0], depth[1], t)
    theta = {n: known[:, i] for i, n in enumerate(KNOWN_PARAMS)}
    theta.update(phi=phi_deg * DEG, c=c_pa, delta=delta_deg * DEG)
    fx, fz, _ = fee.fee_xz(theta)
    assert np.all(np.isfinite(fx)) and np.all(np.isfinite(fz))
    return known, np.stack((fx, fz), axis=-1)


def _stack(windows):
    return np.stack([w[0] for w in windows]), np.stack([w[1] for w in windows])


def test_recovers_soil_from_varying_depth():
    windows = [make_window(p, c, d) for _, p, c, d in SOILS]
    # a second velocity and a surcharge, so the Eq. 9-10 scaling and Q are exercised too
    windows.append(make_window(28.0, 4000.0, 18.0, v_x=0.8, v_z=0.01, q=1500.0, depth=(0.25, 0.08)))
    truth = [s[1:] for s in SOILS] + [(28.0, 4000.0, 18.0)]
    known, forces = _stack(windows)
    fit = fit_windows(known, forces)
    assert isinstance(fit, ClassicalFit) and len(fit) == len(truth)
    for i, (phi, c, delta) in enumerate(truth):
        err = (fit.phi[i] / DEG - phi, fit.c[i] - c, fit.delta[i] / DEG - delta)
        print(f"window {i}: phi err {err[0]:+.4f} deg, c err {err[1]:+.2f} Pa, delta err {err[2]:+.5f} deg, "
              f"cost {fit.cost[i]:.2e}")
        assert fit.success[i]
        assert abs(err[0]) < 0.5 and abs(err[1]) < 200.0 and abs(err[2]) < 0.5
        assert fit.cost[i] < 1e-4
    # beta and f_fee are the FEE's at the last tick of the fitted soil
    last = known[:, -1, :]
    theta = {n: last[:, i] for i, n in enumerate(KNOWN_PARAMS)}
    delta_corr, _ = fee.velocity_corrected(fit.delta, theta["c_a"], theta["rho"], theta["alpha"], theta["v_x"], theta["v_z"])
    np.testing.assert_allclose(fit.beta, fee.beta_star(fit.phi, delta_corr, theta["rho"], theta["alpha"]))
    assert np.all((fit.beta > 0) & (fit.beta < np.pi))
    np.testing.assert_allclose(fit.f_fee, forces[:, -1, :], rtol=1e-3, atol=5.0)


def test_noisy_synthetic_stays_close():
    """Force noise of a few % of the machine limit moves the estimate only a little."""
    rng = np.random.default_rng(3)
    known, forces = _stack([make_window(30.0, 3000.0, 15.0)] * 3)
    forces = forces + rng.normal(0.0, 1.0, forces.shape) * np.array([200.0, 400.0])
    fit = fit_windows(known, forces)
    assert fit.success.all()
    assert np.all(np.abs(fit.phi / DEG - 30.0) < 3.0)
    assert np.all(np.abs(fit.c - 3000.0) < 1000.0)
    assert np.all(np.abs(fit.delta / DEG - 15.0) < 1.0)


def test_fee_bag_reproduces_force():
    from soil_bag_tools.bag_io import read_episode

    ep = read_episode(FEE_BAG)
    starts = np.arange(0, len(ep) - T + 1, 20)
    known = np.stack([ep.known[s : s + T] for s in starts])
    forces = np.stack([ep.forces[s : s + T] for s in starts])
    truth = ep.truth[starts + T - 1]
    fit = fit_windows(known, forces, workers=2)
    assert fit.success.mean() >= 0.9
    f_last = forces[:, -1, :]
    err = np.linalg.norm(fit.f_fee - f_last, axis=1)
    rel = err.mean() / np.linalg.norm(f_last, axis=1).mean()
    g = {n: truth[:, i] for i, n in enumerate(GROUND_TRUTH_PARAMS)}
    print(f"\n{len(starts)} windows, success {fit.success.mean():.2f}, last-tick |F err| {err.mean():.0f} N "
          f"= {100 * rel:.1f} % of mean |F|, median RMS residual {np.median(fit.cost):.4f} of the limit")
    for name, est, tru, unit, scale in (("phi", fit.phi, g["phi"], "deg", 1 / DEG), ("c", fit.c, g["c"], "Pa", 1.0),
                                        ("delta", fit.delta, g["delta"], "deg", 1 / DEG), ("beta", fit.beta, g["beta"], "deg", 1 / DEG)):
        e = (est - tru) * scale
        print(f"  {name:5s} error vs truth [{unit}]: median {np.nanmedian(e):+9.2f}, "
              f"10-90 % [{np.nanpercentile(e, 10):+9.2f}, {np.nanpercentile(e, 90):+9.2f}]")
    assert rel < 0.10
    # delta is identified by the force direction alone, even at constant depth
    assert abs(np.median(fit.delta - g["delta"])) < 1.0 * DEG


def test_constant_depth_is_finite():
    """At constant depth phi and c trade off along a valley; the fit must still be sane."""
    known, forces = _stack([make_window(p, c, d, depth=(0.2, 0.2)) for _, p, c, d in SOILS])
    fit = fit_windows(known, forces)
    assert fit.success.all()
    for arr in (fit.phi, fit.c, fit.delta, fit.beta, fit.cost, fit.f_fee):
        assert np.all(np.isfinite(arr))
    assert np.all((fit.phi >= PHI_BOUNDS_RAD[0]) & (fit.phi <= PHI_BOUNDS_RAD[1]))
    assert np.all((fit.c >= C_BOUNDS_PA[0]) & (fit.c <= C_BOUNDS_PA[1]))
    np.testing.assert_allclose(fit.f_fee, forces[:, -1, :], rtol=1e-3, atol=20.0)


def test_out_of_soil_ticks_and_windows():
    """d <= 0 ticks give zero FEE force (kept as residuals); a window never in soil is not fitted."""
    known, forces = make_window(30.0, 3000.0, 15.0)
    known = known.copy()
    d = KNOWN_PARAMS.index("d")
    known[:10, d] = np.linspace(-0.05, 0.0, 10)  # blade above the surface first
    forces = forces.copy()
    forces[:10] = 0.0
    air_known = known.copy()
    air_known[:, d] = -0.1
    fit = fit_windows(np.stack([known, air_known]), np.stack([forces, np.zeros_like(forces)]))
    assert fit.success[0] and abs(fit.phi[0] / DEG - 30.0) < 0.5
    assert not fit.success[1] and np.isnan(fit.phi[1])
    # fee_forces: exactly 0 out of the soil, even where beta* does not exist
    fx, fz, defined = fee_forces(np.array([30 * DEG]), np.array([0.0]), np.array([75 * DEG]), known[:12])
    assert np.all(fx[:10] == 0.0) and np.all(fz[:10] == 0.0) and np.all(defined[:10])
    assert not defined[11]


@pytest.mark.parametrize("field", ["f_x_b", "f_z_b"])
def test_nan_force_names_field_and_index(field):
    known, forces = _stack([make_window(30.0, 3000.0, 15.0)] * 3)
    forces[2, 7, ["f_x_b", "f_z_b"].index(field)] = np.nan
    with pytest.raises(ValueError) as exc:
        fit_windows(known, forces)
    msg = str(exc.value)
    assert "forces" in msg and repr(field) in msg and "window 2" in msg and "tick 7" in msg


def test_inf_known_names_field_and_index():
    known, forces = _stack([make_window(30.0, 3000.0, 15.0)] * 2)
    known[1, 4, KNOWN_PARAMS.index("q")] = np.inf
    with pytest.raises(ValueError, match=r"known.*'q'.*window 1, tick 4"):
        fit_windows(known, forces)


def test_bad_shapes():
    known, forces = _stack([make_window(30.0, 3000.0, 15.0)] * 2)
    with pytest.raises(ValueError, match="forces has shape"):
        fit_windows(known, forces[..., :1])
    with pytest.raises(ValueError, match="known has shape"):
        fit_windows(known[0], forces)
    with pytest.raises(ValueError, match="known has shape"):
        fit_windows(known[..., :8], forces)
    with pytest.raises(ValueError, match=r"\(W, T\)"):
        fit_windows(known, forces[:, :30])
    known[0, 0, KNOWN_PARAMS.index("rho")] = 190 * DEG
    with pytest.raises(ValueError, match="'rho'"):
        fit_windows(known, forces)


def test_empty_input():
    fit = fit_windows(np.zeros((0, T, 9)), np.zeros((0, T, 2)))
    assert len(fit) == 0 and fit.f_fee.shape == (0, 2)
