"""The Fundamental Equation of Earthmoving (paper §1.1.2, Eq. 2-10) against independent physics.

Nothing here re-uses ``fee``'s formulas. The references are

* classical earth-pressure theory (Rankine and Coulomb passive pressure on a vertical wall),
* a soil-wedge force balance set up from the wedge's vertices in the surface frame and solved
  numerically with ``numpy.linalg.solve`` (this is what pins down the adhesion-length
  correction of Eq. 2 and the sign/direction convention of Eq. 8),
* numerical minimisation (dense grid + ``scipy.optimize.minimize_scalar``) of that wedge
  force for beta* (Eq. 7), and finite differences for every derivative,
* a rotation of the blade's up-vector into the world frame for Eq. 9-10.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.optimize import minimize_scalar

from soil_physics import fee
from soil_msgs_py.params import DEG, TABLE1

RNG_SEED = 20240601


# ----------------------------------------------------------------------------------------
# Independent reference: the soil wedge in the surface frame.
# ----------------------------------------------------------------------------------------
def _rot(alpha):
    """Surface frame -> world frame (the surface is inclined at +alpha)."""
    ca, sa = np.cos(alpha), np.sin(alpha)
    return np.array([[ca, -sa], [sa, ca]])


def wedge(phi, c, delta, c_a, gamma, rho, alpha, w, d, q, beta):
    """Solve the wedge's force balance. Returns (P, R, blade force on the wedge, surface frame).

    Everything is derived from the wedge's three vertices: blade tip at the origin, top of the
    blade face at (-d cot rho, d), top of the failure plane at (d cot beta, d).
    """
    tip = np.zeros(2)
    blade_top = np.array([-d / math.tan(rho), d])
    fail_top = np.array([d / math.tan(beta), d])
    verts = np.array([tip, fail_top, blade_top])
    # Signed shoelace area (counter-clockwise tip -> failure top -> blade top) and centroid,
    # no cot-formula. A non-positive area means there is no wedge (rho + beta >= 180 deg).
    x, y = verts[:, 0], verts[:, 1]
    area = 0.5 * (np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))
    assert area > 0, "not a wedge"
    centroid = verts.mean(axis=0)

    def unit_and_inward_normal(top):
        length = float(np.hypot(*top))
        t = top / length  # pointing up along the face
        n = np.array([-t[1], t[0]])
        if np.dot(n, centroid) < 0:  # into the wedge
            n = -n
        return t, n, length

    t_f, n_f, l_f = unit_and_inward_normal(fail_top)
    t_b, n_b, l_b = unit_and_inward_normal(blade_top)
    g_hat = np.array([-math.sin(alpha), -math.cos(alpha)])  # gravity in the surface frame

    known = (gamma * w * area + q) * g_hat  # weight + surcharge
    known = known - c * w * l_f * t_f  # cohesion opposes the wedge sliding up the failure plane
    known = known - c_a * w * l_b * t_b  # adhesion opposes the wedge sliding up the blade
    r_dir = math.cos(phi) * n_f - math.sin(phi) * t_f  # failure-plane reaction, at phi to n_f
    p_dir = math.cos(delta) * n_b - math.sin(delta) * t_b  # blade reaction, at delta to n_b
    p, r = np.linalg.solve(np.column_stack([p_dir, r_dir]), -known)
    return p, r, p * p_dir


def wedge_n_gamma(phi, delta, rho, alpha, beta):
    """N_gamma from the wedge balance: the blade force per gamma d^2 w with c = c_a = Q = 0."""
    return wedge(phi, 0.0, delta, 0.0, 1.0, rho, alpha, 1.0, 1.0, 0.0, beta)[0]


def wedge_n_gamma_batch(phi, delta, rho, alpha, betas):
    """Vectorised wedge_n_gamma over an array of betas (batched 2x2 solves)."""
    betas = np.asarray(betas, dtype=float)
    bx, bz = -1.0 / math.tan(rho), 1.0
    fx, fz = 1.0 / np.tan(betas), np.ones_like(betas)
    area = 0.5 * (fx * bz - bx * fz)  # signed: < 0 once rho + beta > 180 deg (no wedge)
    lf = np.hypot(fx, fz)
    t_f = np.stack([fx / lf, fz / lf], -1)
    n_f = np.stack([-t_f[:, 1], t_f[:, 0]], -1)  # inward for 0 < beta < pi (checked in wedge())
    lb = math.hypot(bx, bz)
    t_b = np.array([bx / lb, bz / lb])
    n_b = np.array([t_b[1], -t_b[0]])
    g_hat = np.array([-math.sin(alpha), -math.cos(alpha)])
    r_dir = math.cos(phi) * n_f - math.sin(phi) * t_f
    p_dir = math.cos(delta) * n_b - math.sin(delta) * t_b
    a = np.stack([np.broadcast_to(p_dir, r_dir.shape), r_dir], -1)
    rhs = -(area[:, None] * g_hat)
    return np.linalg.solve(a, rhs[..., None])[:, 0, 0]


def random_valid_wedges(rng, n, *, delta_range=(-30.0, 35.0), ca_range=(-5e3, 1e4)):
    """Physically valid, well-conditioned wedges (eta < 175 deg, non-degenerate triangle)."""
    out = []
    while len(out) < n:
        s = dict(
            phi=rng.uniform(0, 45) * DEG,
            c=rng.uniform(0, 1e4),
            delta=rng.uniform(*delta_range) * DEG,
            c_a=rng.uniform(*ca_range),
            gamma=rng.uniform(14e3, 22e3),
            rho=rng.uniform(30, 150) * DEG,
            alpha=rng.uniform(-30, 30) * DEG,
            w=rng.uniform(0.3, 3.164),
            d=rng.uniform(0.01, 0.66),
            q=rng.uniform(0, 1e4),
            beta=rng.uniform(2, 88) * DEG,
        )
        eta = s["delta"] + s["rho"] + s["phi"] + s["beta"]
        if eta < 175 * DEG and eta > 5 * DEG and s["rho"] + s["beta"] < 170 * DEG:
            out.append(s)
    return out


ARGS = ("phi", "c", "delta", "c_a", "gamma", "rho", "alpha", "w", "d", "q", "beta")


def call_ff(s, **over):
    s = {**s, **over}
    return fee.failure_force(*(s[k] for k in ARGS))


# ----------------------------------------------------------------------------------------
# 1. Classical limits and the independent wedge balance.
# ----------------------------------------------------------------------------------------
def test_wedge_reference_is_sane():
    """Guard the reference itself: frame, normals and area against hand values."""
    # Surface frame rotated by alpha: gravity must come out straight down in the world.
    for a in (-0.4, 0.0, 0.3):
        np.testing.assert_allclose(_rot(a) @ np.array([-math.sin(a), -math.cos(a)]), [0.0, -1.0], atol=1e-15)
    # Vertical frictionless wall, beta = 45 deg, phi = 0, cohesionless: the wedge is a right
    # isosceles triangle of area d^2/2 and P = W exactly (R at 45 deg balances both).
    p, r, vec = wedge(0.0, 0.0, 0.0, 0.0, 10.0, math.pi / 2, 0.0, 2.0, 1.0, 0.0, math.pi / 4)
    assert p == pytest.approx(10.0 * 2.0 * 0.5)
    assert r == pytest.approx(10.0 * 2.0 * 0.5 * math.sqrt(2))
    np.testing.assert_allclose(vec, [p, 0.0], atol=1e-12)  # horizontal push into the soil


@pytest.mark.parametrize("phi_deg", [5.0, 17.0, 25.0, 30.0, 38.0, 45.0])
@pytest.mark.parametrize("c", [0.0, 2e3, 1e4])
def test_rankine_passive_vertical_smooth_wall(phi_deg, c):
    phi = phi_deg * DEG
    gamma, d, w = 18e3, 0.25, 3.164
    k_p = math.tan(math.pi / 4 + phi / 2) ** 2
    rankine = 0.5 * gamma * d**2 * w * k_p + 2.0 * c * d * w * math.sqrt(k_p)
    beta_rankine = math.pi / 4 - phi / 2

    b = fee.beta_star(phi, 0.0, math.pi / 2, 0.0)
    assert float(b) == pytest.approx(beta_rankine, abs=1e-9)
    f = fee.failure_force(phi, c, 0.0, 0.0, gamma, math.pi / 2, 0.0, w, d, 0.0, beta_rankine)
    assert float(f) == pytest.approx(rankine, rel=1e-12)
    # Through the full layer (beta defaulting to beta*), force horizontal.
    theta = dict(phi=phi, c=c, delta=0.0, c_a=0.0, gamma=gamma, rho=math.pi / 2, alpha=0.0, w=w, d=d, q=0.0,
                 v_x=0.5, v_z=0.0)
    fx, fz, f2 = fee.fee_xz(theta)
    assert float(f2) == pytest.approx(rankine, rel=1e-10)
    assert float(fx) == pytest.approx(rankine, rel=1e-10)
    assert abs(float(fz)) < 1e-9 * rankine


def coulomb_kp(phi, delta):
    """Coulomb passive coefficient, vertical wall, level backfill, wall friction delta."""
    return math.cos(phi) ** 2 / (
        math.cos(delta) * (1.0 - math.sqrt(math.sin(phi + delta) * math.sin(phi) / math.cos(delta))) ** 2
    )


@pytest.mark.parametrize("phi_deg,delta_deg", [(20, 5), (25, 12), (30, 10), (30, 20), (35, 23.3), (40, 15), (45, 30)])
def test_coulomb_passive_vertical_rough_wall(phi_deg, delta_deg):
    phi, delta = phi_deg * DEG, delta_deg * DEG
    gamma, d, w = 17e3, 0.3, 2.0
    p_p = 0.5 * gamma * d**2 * w * coulomb_kp(phi, delta)
    b = fee.beta_star(phi, delta, math.pi / 2, 0.0)
    f = fee.failure_force(phi, 0.0, delta, 0.0, gamma, math.pi / 2, 0.0, w, d, 0.0, b)
    assert float(f) == pytest.approx(p_p, rel=1e-9)
    fx, fz = fee.force_xz(f, math.pi / 2, delta, 0.0)
    # P_p is inclined at delta to the wall normal; the wedge rides up, so friction on the
    # soil points down: the blade pushes the soil forward and down.
    assert float(fx) == pytest.approx(p_p * math.cos(delta), rel=1e-9)
    assert float(fz) == pytest.approx(-p_p * math.sin(delta), rel=1e-9)
    assert float(fz) < 0


def test_failure_force_matches_independent_wedge_equilibrium():
    rng = np.random.default_rng(RNG_SEED)
    samples = random_valid_wedges(rng, 400)
    for s in samples:
        p, _, _ = wedge(**s)
        f = float(call_ff(s))
        # scale: size of the individual contributions, so a cancelling sum is still judged fairly
        scale = abs(p) + abs(float(call_ff(s, c_a=0.0, c=0.0))) + 1.0
        assert abs(f - p) <= 1e-9 * scale, (s, f, p)


def test_adhesion_term_carries_the_contact_length():
    """Eq. 2 printed c_a w N_a is N/m; the wedge balance needs c_a d w N_a (linear in d)."""
    rng = np.random.default_rng(RNG_SEED + 1)
    for s in random_valid_wedges(rng, 100, delta_range=(0.0, 35.0), ca_range=(100.0, 1e4)):
        adhesion_only = dict(s, c=0.0, gamma=0.0, q=0.0)
        p1 = wedge(**adhesion_only)[0]
        p2 = wedge(**dict(adhesion_only, d=2 * s["d"]))[0]
        assert p2 == pytest.approx(2 * p1, rel=1e-9)  # physics: adhesion force ~ contact length ~ d
        f1 = float(call_ff(adhesion_only))
        f2 = float(call_ff(adhesion_only, d=2 * s["d"]))
        assert f1 == pytest.approx(p1, rel=1e-9)
        assert f2 == pytest.approx(2 * f1, rel=1e-9)
        # The printed length-less term (transcribed from the paper, Eq. 6) is d-independent
        # and therefore cannot match the balance for any d != 1 m.
        phi, delta, rho, beta = s["phi"], s["delta"], s["rho"], s["beta"]
        n_a_paper = -math.cos(rho + phi + beta) / (math.sin(rho) * math.sin(delta + rho + phi + beta))
        printed = s["c_a"] * s["w"] * n_a_paper
        assert abs(printed - p1) > 1e-3 * abs(p1) + 1e-9  # d in (0.01, 0.66): never 1 m
        assert printed == pytest.approx(p1 / s["d"], rel=1e-9)  # differs exactly by the length d


def test_force_direction_matches_wedge_blade_reaction_in_world_frame():
    rng = np.random.default_rng(RNG_SEED + 2)
    for s in random_valid_wedges(rng, 300):
        p, _, vec_surface = wedge(**s)
        vec_world = _rot(s["alpha"]) @ vec_surface
        fx, fz = fee.force_xz(p, s["rho"], s["delta"], s["alpha"])
        np.testing.assert_allclose([float(fx), float(fz)], vec_world, rtol=1e-10, atol=1e-10 * abs(p))
        # and the full layer (no velocity correction, same beta) gives the same vector
        theta = {k: s[k] for k in ARGS if k != "beta"}
        theta.update(v_x=0.0, v_z=0.0)
        gx, gz, _ = fee.fee_xz(theta, beta=s["beta"], correct_velocity=False)
        np.testing.assert_allclose([float(gx), float(gz)], vec_world, rtol=1e-9, atol=1e-9 * abs(p) + 1e-9)


def test_typical_dozer_cut_sign():
    """Advancing blade at rho = 80 deg, level ground: the blade pushes the soil forward (F_x > 0)."""
    theta = dict(phi=30 * DEG, c=2e3, delta=15 * DEG, c_a=200.0, gamma=18e3, rho=80 * DEG, alpha=0.0,
                 w=3.164, d=0.15, q=2e3, v_x=0.5, v_z=0.0)
    fx, fz, f = fee.fee_xz(theta)
    assert float(f) > 0 and float(fx) > 0
    # direction 90 - 80 - 15*tanh(...) deg: slightly below horizontal
    assert float(fz) < 0 and abs(float(fz)) < 0.1 * float(fx)


# ----------------------------------------------------------------------------------------
# 2. beta* (Eq. 7) and dN_gamma/dbeta.
# ----------------------------------------------------------------------------------------
def numerical_beta_star(phi, delta, rho, alpha, n_grid=4001):
    upper = math.pi - (delta + rho + phi)
    grid = np.linspace(upper * 1e-4, upper * (1 - 1e-4), n_grid)
    n = wedge_n_gamma_batch(phi, delta, rho, alpha, grid)
    i = int(np.argmin(n))
    assert 0 < i < n_grid - 1, "no interior minimum"
    res = minimize_scalar(lambda b: wedge_n_gamma(phi, delta, rho, alpha, b), bounds=(grid[i - 1], grid[i + 1]),
                          method="bounded", options=dict(xatol=1e-12))
    return res.x, res.fun


def _beta_samples(rng, n, delta_range=(0.0, 35.0)):
    out = []
    while len(out) < n:
        phi = rng.uniform(17, 45) * DEG
        delta = rng.uniform(*delta_range) * DEG
        rho = rng.uniform(45, 135) * DEG
        alpha = rng.uniform(-30, 30) * DEG
        # need room for a wedge and a stable free surface (alpha + phi > 0; otherwise
        # N_gamma -> -inf as beta -> 0 and no minimum exists)
        if math.pi - (delta + rho + phi) > 10 * DEG and alpha + phi > 5 * DEG:
            out.append((phi, delta, rho, alpha))
    return out


@pytest.mark.parametrize("delta_range", [(0.0, 35.0), (-15.0, 0.0)], ids=["delta>=0", "delta'<0"])
def test_beta_star_is_numerical_argmin(delta_range):
    rng = np.random.default_rng(RNG_SEED + 3)
    for phi, delta, rho, alpha in _beta_samples(rng, 60, delta_range):
        b_num, n_min = numerical_beta_star(phi, delta, rho, alpha)
        b = float(fee.beta_star(phi, delta, rho, alpha))
        assert b == pytest.approx(b_num, abs=2e-5), (phi / DEG, delta / DEG, rho / DEG, alpha / DEG)
        # the minimum value agrees to second order
        assert wedge_n_gamma(phi, delta, rho, alpha, b) == pytest.approx(n_min, rel=1e-9)
        # stationary: dN_gamma/dbeta = 0 there
        assert abs(float(fee.dn_gamma_dbeta(phi, delta, rho, alpha, b))) < 1e-9 * max(1.0, n_min)


def test_beta_star_vectorised_and_torch_agree_with_scalar():
    rng = np.random.default_rng(RNG_SEED + 4)
    pts = np.array(_beta_samples(rng, 50))
    b_vec = fee.beta_star(*pts.T)
    b_scalar = np.array([float(fee.beta_star(*p)) for p in pts])
    np.testing.assert_allclose(b_vec, b_scalar, rtol=0, atol=1e-13)
    b_t = fee.beta_star(*(torch.tensor(col, dtype=torch.float64) for col in pts.T))
    assert b_t.dtype == torch.float64
    np.testing.assert_allclose(b_t.numpy(), b_vec, rtol=0, atol=1e-12)
    b_t32 = fee.beta_star(*(torch.tensor(col, dtype=torch.float32) for col in pts.T))
    assert b_t32.dtype == torch.float32
    np.testing.assert_allclose(b_t32.numpy(), b_vec, atol=1e-4)


def test_dn_gamma_dbeta_matches_finite_differences():
    rng = np.random.default_rng(RNG_SEED + 5)
    for s in random_valid_wedges(rng, 300, delta_range=(-30.0, 35.0)):
        phi, delta, rho, alpha, beta = s["phi"], s["delta"], s["rho"], s["alpha"], s["beta"]
        h = 1e-6
        fd = (wedge_n_gamma(phi, delta, rho, alpha, beta + h) - wedge_n_gamma(phi, delta, rho, alpha, beta - h)) / (2 * h)
        an = float(fee.dn_gamma_dbeta(phi, delta, rho, alpha, beta))
        n = abs(wedge_n_gamma(phi, delta, rho, alpha, beta))
        assert an == pytest.approx(fd, rel=1e-6, abs=1e-6 * (1 + n)), s
    # and against fee's own N_gamma with a vectorised central difference
    beta = np.linspace(5, 80, 200) * DEG
    args = (25 * DEG, 10 * DEG, 80 * DEG, 5 * DEG)
    h = 1e-6
    fd = (fee.coefficients(*args, beta + h).n_gamma - fee.coefficients(*args, beta - h).n_gamma) / (2 * h)
    np.testing.assert_allclose(fee.dn_gamma_dbeta(*args, beta), fd, rtol=1e-6, atol=1e-7)


def test_beta_star_on_simulator_ranges_is_finite_and_documented():
    """Simulator: phi in [17, 45] deg, delta' in [-15, 15] deg, rho = 80 deg, alpha = 0.

    beta* is finite everywhere and is the valid-interval argmin, but it does NOT stay inside
    Table 1's beta limits [11.5, 34.5] deg: it spans ~[18.9, 79.0] deg. Loose soils (low phi)
    and any reversed soil-tool friction (delta' < 0, blade moving up) push beta* above 34.5
    deg. For the advancing blade of the fee world (delta' ~ 10-15 deg) it is inside.
    """
    phi = np.linspace(17, 45, 57) * DEG
    delta = np.linspace(-15, 15, 61) * DEG
    P, D = np.meshgrid(phi, delta)
    b = fee.beta_star(P, D, 80 * DEG, 0.0)
    assert np.all(np.isfinite(b))
    assert np.all(b > 0) and np.all(b < math.pi - (P + D + 80 * DEG))
    lo, hi = TABLE1["beta"].limits
    assert b.min() == pytest.approx(18.884 * DEG, abs=0.01 * DEG)  # phi = 45, delta' = 15
    assert b.max() == pytest.approx(79.012 * DEG, abs=0.01 * DEG)  # phi = 17, delta' = -15
    assert b.max() > hi  # documented: outside Table 1 (see report)
    advancing = D >= 10 * DEG
    assert np.all((b[advancing] >= lo) & (b[advancing] <= hi))
    # Rankine-like corner: delta' = 0, phi = 17 -> beta* = 41.5 deg (> 34.5)
    assert float(fee.beta_star(17 * DEG, 0.0, 80 * DEG, 0.0)) == pytest.approx(41.5 * DEG, abs=1e-6)


# ----------------------------------------------------------------------------------------
# 3. Velocity correction (Eq. 9-10).
# ----------------------------------------------------------------------------------------
def iota_b_world(rho, alpha):
    """Unit vector up along the blade: surface-frame (-cos rho, sin rho) rotated by alpha."""
    return _rot(alpha) @ np.array([-math.cos(rho), math.sin(rho)])


def test_velocity_correction_advancing_blade_keeps_full_friction():
    delta, c_a = 15 * DEG, 200.0
    dp, cap = fee.velocity_corrected(delta, c_a, 80 * DEG, 0.0, 0.3, 0.0)
    assert float(dp) == pytest.approx(delta, rel=0.015)
    assert float(cap) == pytest.approx(c_a, rel=0.015)
    assert 0 < float(dp) <= delta
    # faster -> closer to full
    dp_fast, _ = fee.velocity_corrected(delta, c_a, 80 * DEG, 0.0, 1.0, 0.0)
    assert float(dp) < float(dp_fast) <= delta and float(dp_fast) == pytest.approx(delta, rel=1e-6)


def test_velocity_correction_reverses_when_blade_slides_up():
    delta, c_a = 15 * DEG, 200.0
    dp, cap = fee.velocity_corrected(delta, c_a, 80 * DEG, 0.0, 0.3, 1.0)
    assert float(dp) < 0 and float(cap) < 0
    assert float(dp) == pytest.approx(-delta, rel=1e-6)
    dp0, ca0 = fee.velocity_corrected(delta, c_a, 80 * DEG, 0.0, 0.0, 0.0)
    assert float(dp0) == 0.0 and float(ca0) == 0.0
    # blade moving straight down into the soil: wedge slides up along the blade -> full friction
    dpd, _ = fee.velocity_corrected(delta, c_a, 80 * DEG, 0.0, 0.0, -0.5)
    assert float(dpd) == pytest.approx(delta, rel=1e-6)


def test_velocity_correction_uses_blade_direction_in_world_frame():
    rng = np.random.default_rng(RNG_SEED + 6)
    n = 500
    delta = rng.uniform(-90, 90, n) * DEG
    c_a = rng.uniform(0, 1e4, n)
    rho = rng.uniform(2, 178, n) * DEG
    alpha = rng.uniform(-30, 30, n) * DEG
    v_x = rng.uniform(-2, 2, n)
    v_z = rng.uniform(-2, 2, n)
    dp, cap = fee.velocity_corrected(delta, c_a, rho, alpha, v_x, v_z)
    assert np.all(np.abs(dp) <= np.abs(delta)) and np.all(np.abs(cap) <= np.abs(c_a))
    for i in range(n):
        dot = float(iota_b_world(rho[i], alpha[i]) @ [v_x[i], v_z[i]])
        k = math.tanh(-fee.FEE_VELOCITY_GAIN_S_M * dot)
        assert dp[i] == pytest.approx(k * delta[i], rel=1e-12, abs=1e-15)
        assert cap[i] == pytest.approx(k * c_a[i], rel=1e-12, abs=1e-12)
    # Blade moving parallel to an inclined surface behaves as on level ground.
    for a in (-20 * DEG, 25 * DEG):
        dp_a, _ = fee.velocity_corrected(0.2, 1.0, 80 * DEG, a, 0.3 * math.cos(a), 0.3 * math.sin(a))
        dp_0, _ = fee.velocity_corrected(0.2, 1.0, 80 * DEG, 0.0, 0.3, 0.0)
        assert float(dp_a) == pytest.approx(float(dp_0), rel=1e-12)


def test_velocity_correction_scales_adhesion_not_cohesion():
    base = dict(phi=30 * DEG, c=4e3, delta=15 * DEG, c_a=2e3, gamma=18e3, rho=80 * DEG, alpha=0.0, w=3.164,
                d=0.2, q=1e3)
    for v_x, v_z in [(0.3, 0.0), (0.3, 0.06), (0.0, 0.5), (0.2, 0.05)]:
        theta = dict(base, v_x=v_x, v_z=v_z)
        beta = 25 * DEG
        fx, fz, f = fee.fee_xz(theta, beta=beta)
        k = math.tanh(-fee.FEE_VELOCITY_GAIN_S_M * float(iota_b_world(base["rho"], 0.0) @ [v_x, v_z]))
        expect = wedge(**dict(base, delta=k * base["delta"], c_a=k * base["c_a"], beta=beta))
        assert float(f) == pytest.approx(expect[0], rel=1e-9)
        np.testing.assert_allclose([float(fx), float(fz)], expect[2], rtol=1e-9, atol=1e-6)
        if abs(k) < 0.9:  # scaling c as well would give a different force
            wrong = wedge(**dict(base, delta=k * base["delta"], c_a=k * base["c_a"], c=k * base["c"], beta=beta))
            assert abs(wrong[0] - float(f)) > 1e-3 * abs(float(f))


# ----------------------------------------------------------------------------------------
# 4. Depth of cut.
# ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("d", [0.0, -1e-9, -0.05, -0.1])
def test_no_force_out_of_the_soil(d):
    args = dict(phi=30 * DEG, c=5e3, delta=15 * DEG, c_a=200.0, gamma=18e3, rho=80 * DEG, alpha=0.1, w=3.164,
                d=d, q=5e3, beta=25 * DEG)
    assert float(call_ff(args)) == 0.0
    fx, fz, f = fee.fee_xz({**{k: v for k, v in args.items() if k != "beta"}, "v_x": 0.5, "v_z": 0.0})
    assert float(f) == 0.0 and float(fx) == 0.0 and float(fz) == 0.0
    t = {k: torch.tensor(v, dtype=torch.float64, requires_grad=True) for k, v in args.items()}
    out = call_ff(t)
    out.backward()
    assert out.item() == 0.0
    assert all(torch.isfinite(t[k].grad) for k in t)
    assert t["q"].grad.item() == 0.0 and t["c"].grad.item() == 0.0


def test_force_positive_in_the_soil():
    rng = np.random.default_rng(RNG_SEED + 7)
    n = 2000
    phi = rng.uniform(17, 45, n) * DEG
    delta = rng.uniform(0, 35, n) * DEG
    alpha = rng.uniform(-10, 10, n) * DEG
    beta = fee.beta_star(phi, delta, 80 * DEG, alpha)
    f = fee.failure_force(phi, rng.uniform(0, 1e4, n), delta, rng.uniform(0, 1e4, n), rng.uniform(14e3, 22e3, n),
                          80 * DEG, alpha, 3.164, rng.uniform(1e-3, 0.3, n), rng.uniform(0, 1e4, n), beta)
    assert np.all(np.isfinite(beta)) and np.all(f > 0)
    # monotone in depth
    d = np.linspace(0.0, 0.66, 50)
    f_d = fee.failure_force(0.5, 2e3, 0.2, 200.0, 18e3, 80 * DEG, 0.0, 3.164, d, 1e3, 0.4)
    assert f_d[0] == 0 and np.all(np.diff(f_d) > 0)


# ----------------------------------------------------------------------------------------
# 5. torch: gradients, dtypes, NumPy parity.
# ----------------------------------------------------------------------------------------
FIXED = dict(c_a=200.0, gamma=18e3, rho=80 * DEG, alpha=5 * DEG, w=3.164, q=2e3)


def _grad_inputs():
    return (
        torch.tensor([25, 30, 40, 20, 35], dtype=torch.float64) * DEG,  # phi
        torch.tensor([0.0, 2.0, 5.0, 8.0, 1.0], dtype=torch.float64),  # c [kPa]
        torch.tensor([10, 15, 20, -10, 5], dtype=torch.float64) * DEG,  # delta
        torch.tensor([20, 25, 15, 30, 33], dtype=torch.float64) * DEG,  # beta
        torch.tensor([0.05, 0.1, 0.2, 0.3, 0.15], dtype=torch.float64),  # d
    )


def test_failure_force_gradcheck_float64():
    inputs = tuple(x.clone().requires_grad_(True) for x in _grad_inputs())

    def f(phi, c_kpa, delta, beta, d):
        return fee.failure_force(phi, c_kpa * 1e3, delta, FIXED["c_a"], FIXED["gamma"], FIXED["rho"], FIXED["alpha"],
                                 FIXED["w"], d, FIXED["q"], beta) / 1e3

    assert torch.autograd.gradcheck(f, inputs, eps=1e-6, atol=1e-6, rtol=1e-5)


def test_fee_xz_gradcheck_float64_with_velocity_correction():
    inputs = tuple(x.clone().requires_grad_(True) for x in _grad_inputs())
    v_x = torch.tensor([0.3, 0.5, 0.2, 0.4, 0.1], dtype=torch.float64)
    v_z = torch.tensor([0.0, 0.05, 0.1, -0.1, 0.02], dtype=torch.float64)

    def f(phi, c_kpa, delta, beta, d):
        theta = dict(FIXED, phi=phi, c=c_kpa * 1e3, delta=delta, d=d, v_x=v_x, v_z=v_z)
        fx, fz, force = fee.fee_xz(theta, beta=beta)
        return fx / 1e3, fz / 1e3, force / 1e3

    assert torch.autograd.gradcheck(f, inputs, eps=1e-6, atol=1e-6, rtol=1e-5)


def test_autograd_matches_manual_central_differences():
    """Explicit FD of the NumPy implementation vs torch autograd (not only gradcheck)."""
    base = [float(x[1]) for x in _grad_inputs()]  # phi, c[kPa], delta, beta, d
    names = ["phi", "c", "delta", "beta", "d"]

    def np_force(vals):
        s = dict(FIXED, **dict(zip(names, vals)))
        s["c"] *= 1e3
        return float(call_ff(s))

    t = [torch.tensor(v, dtype=torch.float64, requires_grad=True) for v in base]
    s_t = dict(FIXED, **dict(zip(names, t)))
    s_t["c"] = s_t["c"] * 1e3
    call_ff(s_t).backward()
    for i, name in enumerate(names):
        h = 1e-6 * max(1.0, abs(base[i]))
        up, dn = list(base), list(base)
        up[i] += h
        dn[i] -= h
        fd = (np_force(up) - np_force(dn)) / (2 * h)
        assert t[i].grad.item() == pytest.approx(fd, rel=1e-6, abs=1e-4), name


def _physical_sample(rng, n):
    phi = rng.uniform(17, 45, n) * DEG
    delta = rng.uniform(-15, 35, n) * DEG
    rho = rng.uniform(60, 100, n) * DEG
    beta = rng.uniform(11.5, 34.5, n) * DEG
    keep = delta + rho + phi + beta < 160 * DEG
    cols = dict(phi=phi, c=rng.uniform(0, 1e4, n), delta=delta, c_a=rng.uniform(0, 1e4, n),
                gamma=rng.uniform(14e3, 22e3, n), rho=rho, alpha=rng.uniform(-30, 30, n) * DEG,
                w=rng.uniform(0.5, 3.164, n), d=rng.uniform(0.01, 0.66, n), q=rng.uniform(0, 1e4, n), beta=beta)
    return {k: v[keep] for k, v in cols.items()}


def test_numpy_torch_parity_and_dtypes():
    s = _physical_sample(np.random.default_rng(RNG_SEED + 8), 3000)
    f_np = call_ff(s)
    fx_np, fz_np = fee.force_xz(f_np, s["rho"], s["delta"], s["alpha"])
    dn_np = fee.dn_gamma_dbeta(s["phi"], s["delta"], s["rho"], s["alpha"], s["beta"])
    assert isinstance(f_np, np.ndarray) and f_np.dtype == np.float64
    for dtype, rtol in ((torch.float64, 1e-12), (torch.float32, 1e-4)):
        st = {k: torch.tensor(v, dtype=dtype) for k, v in s.items()}
        f_t = call_ff(st)
        fx_t, fz_t = fee.force_xz(f_t, st["rho"], st["delta"], st["alpha"])
        dn_t = fee.dn_gamma_dbeta(st["phi"], st["delta"], st["rho"], st["alpha"], st["beta"])
        for out in (f_t, fx_t, fz_t, dn_t):
            assert isinstance(out, torch.Tensor) and out.dtype == dtype
        np.testing.assert_allclose(f_t.double().numpy(), f_np, rtol=rtol, atol=rtol * np.abs(f_np).max() * 1e-3)
        np.testing.assert_allclose(fx_t.double().numpy(), fx_np, rtol=rtol, atol=rtol * np.abs(f_np).max() * 1e-3)
        np.testing.assert_allclose(fz_t.double().numpy(), fz_np, rtol=rtol, atol=rtol * np.abs(f_np).max() * 1e-3)
        np.testing.assert_allclose(dn_t.double().numpy(), dn_np, rtol=rtol, atol=rtol)


def test_torch_float32_mixed_with_python_scalars_stays_float32():
    phi = torch.tensor([0.5, 0.6], dtype=torch.float32, requires_grad=True)
    f = fee.failure_force(phi, 1e3, 0.2, 200.0, 18e3, 80 * DEG, 0.0, 3.164, 0.2, 500.0, 0.4)
    assert f.dtype == torch.float32 and f.shape == (2,)
    f.sum().backward()
    assert phi.grad.dtype == torch.float32 and torch.all(torch.isfinite(phi.grad))
    fx, fz, force = fee.fee_xz(dict(FIXED, phi=phi, c=1e3, delta=0.2, d=0.2, v_x=0.5, v_z=0.0), beta=0.4)
    assert fx.dtype == fz.dtype == force.dtype == torch.float32


# ----------------------------------------------------------------------------------------
# 6. No NaN/inf anywhere inside Table 1's limits.
# ----------------------------------------------------------------------------------------
LIMITS = dict(
    phi=(0.0, 90 * DEG), c=(0.0, 1e5), delta=(-90 * DEG, 90 * DEG), c_a=(0.0, 1e4), gamma=(0.0, 3e4),
    rho=(2 * DEG, 178 * DEG), alpha=(-30 * DEG, 30 * DEG), w=(0.0, 3.164), d=(-0.1, 0.66), q=(0.0, 1e5),
    beta=(11.5 * DEG, 34.5 * DEG),
)


def _table1_sweep():
    rng = np.random.default_rng(RNG_SEED + 9)
    n = 20000
    cols = {k: rng.uniform(lo, hi, n) for k, (lo, hi) in LIMITS.items()}
    # every corner of the box (2^11)
    corners = np.array(np.meshgrid(*[[lo, hi] for lo, hi in LIMITS.values()], indexing="ij")).reshape(len(LIMITS), -1)
    for i, k in enumerate(LIMITS):
        cols[k] = np.concatenate([cols[k], corners[i]])
    # exact singularities eta = 180 deg and eta = 360 deg, and rho = 90 deg (cot = 0)
    m = 400
    phi = rng.uniform(0, 90, m) * DEG
    beta = rng.uniform(11.5, 34.5, m) * DEG
    rho = rng.uniform(2, 178, m) * DEG
    for target in (math.pi, 2 * math.pi):
        delta = np.clip(target - phi - beta - rho, -90 * DEG, 90 * DEG)
        extra = dict(phi=phi, beta=beta, rho=rho, delta=delta)
        for k in LIMITS:
            cols[k] = np.concatenate([cols[k], extra.get(k, np.full(m, np.mean(LIMITS[k])))])
    cols["rho"][-50:] = math.pi / 2
    # eta == 0 exactly in floating point (sin(eta) == 0.0): dyadic angles, delta' < 0
    exact = dict(phi=[0.25, 0.5, 0.125], rho=[0.25, 0.25, 0.5], beta=[0.25, 0.25, 0.375],
                 delta=[-0.75, -1.0, -1.0])
    for k in LIMITS:
        cols[k] = np.concatenate([cols[k], exact.get(k, [np.mean(LIMITS[k])] * 3)])
    return cols


def _check_finite_outputs(xp_cols, dtype=None):
    s = xp_cols
    f = call_ff(s)
    fx, fz = fee.force_xz(f, s["rho"], s["delta"], s["alpha"])
    dn = fee.dn_gamma_dbeta(s["phi"], s["delta"], s["rho"], s["alpha"], s["beta"])
    dp, cap = fee.velocity_corrected(s["delta"], s["c_a"], s["rho"], s["alpha"], s["v_x"], s["v_z"])
    theta = {k: v for k, v in s.items() if k != "beta"}
    gx, gz, g = fee.fee_xz(theta, beta=s["beta"])
    outs = dict(f=f, fx=fx, fz=fz, dn=dn, dp=dp, cap=cap, gx=gx, gz=gz, g=g)
    for name, out in outs.items():
        arr = out.detach().double().numpy() if isinstance(out, torch.Tensor) else np.asarray(out)
        bad = ~np.isfinite(arr)
        assert not bad.any(), f"{name} ({dtype}) not finite at {int(bad.sum())} points, e.g. " + str(
            {k: float(np.asarray(v.detach() if isinstance(v, torch.Tensor) else v)[np.argmax(bad)]) for k, v in s.items()})
    return outs


def test_no_nan_or_inf_inside_table1_limits_numpy():
    cols = _table1_sweep()
    n = len(cols["phi"])
    rng = np.random.default_rng(RNG_SEED + 10)
    cols["v_x"] = rng.uniform(-2, 2, n)
    cols["v_z"] = rng.uniform(-2, 2, n)
    with np.errstate(all="raise"):  # also no overflow/invalid warnings along the way
        _check_finite_outputs(cols)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_no_nan_or_inf_inside_table1_limits_torch_with_gradients(dtype):
    cols = _table1_sweep()
    n = len(cols["phi"])
    rng = np.random.default_rng(RNG_SEED + 10)
    cols["v_x"] = rng.uniform(-2, 2, n)
    cols["v_z"] = rng.uniform(-2, 2, n)
    t = {k: torch.tensor(v, dtype=dtype, requires_grad=True) for k, v in cols.items()}
    outs = _check_finite_outputs(t, dtype)
    for name in ("f", "fx", "fz", "dn", "gx", "gz"):
        for v in t.values():
            v.grad = None
        outs[name].sum().backward(retain_graph=True)
        for k, v in t.items():
            if v.grad is None:
                continue
            bad = ~torch.isfinite(v.grad)
            assert not bad.any(), f"d{name}/d{k} ({dtype}) not finite at {int(bad.sum())} points"


def test_beta_star_nan_only_without_valid_minimum():
    """NaN is allowed only where no interior minimum of N_gamma exists."""
    # eta >= 180 deg for every beta > 0: no wedge at all
    assert np.isnan(fee.beta_star(45 * DEG, 60 * DEG, 90 * DEG, 0.0))
    # physical inputs always give a finite beta* inside the valid interval
    rng = np.random.default_rng(RNG_SEED + 11)
    pts = np.array(_beta_samples(rng, 500, (-15.0, 35.0)))
    b = fee.beta_star(*pts.T)
    assert np.all(np.isfinite(b))
    upper = math.pi - (pts[:, 0] + pts[:, 1] + pts[:, 2])
    assert np.all((b > 0) & (b < upper))


def test_beta_star_is_global_minimum_wherever_one_exists_in_table1_limits():
    """Across Table 1's limits (delta' in [-90, 90] deg): wherever N_gamma > 0 on the whole
    valid interval (so a minimum exists), beta* is finite and is the global minimum."""
    rng = np.random.default_rng(RNG_SEED + 12)
    checked = 0
    while checked < 150:
        phi, delta = rng.uniform(0, 90) * DEG, rng.uniform(-90, 90) * DEG
        rho, alpha = rng.uniform(2, 178) * DEG, rng.uniform(-30, 30) * DEG
        upper = math.pi - (phi + delta + rho)
        if upper <= 0:  # eta >= 180 deg for every beta > 0
            assert np.isnan(fee.beta_star(phi, delta, rho, alpha))
            continue
        if upper < 1 * DEG:
            continue
        grid = np.linspace(upper * 1e-5, upper * (1 - 1e-5), 4001)
        n = wedge_n_gamma_batch(phi, delta, rho, alpha, grid)
        if np.any(n <= 0):
            continue  # N_gamma -> -inf somewhere: no minimum, NaN or a local minimum are both fine
        checked += 1
        b = float(fee.beta_star(phi, delta, rho, alpha))
        assert math.isfinite(b) and 0 < b < upper
        assert wedge_n_gamma(phi, delta, rho, alpha, b) <= n.min() * (1 + 1e-9)


def test_recorded_beta_star_is_beta_star_or_the_vanishing_wedge():
    """Where a failure wedge resists, the recorded β is β*; where the reversed friction of a rising
    blade exceeds φ (δ' < −φ) N_γ only falls towards 0 at β = π − ρ over wedges of non-negative
    area, and that is what the simulator records (never NaN)."""
    rho = 80.0 * DEG
    phi = np.array([30.0, 12.8]) * DEG
    delta = np.array([15.0, -14.8]) * DEG
    star = fee.beta_star(phi, delta, rho, 0.0)
    assert np.isfinite(star[0]) and np.isnan(star[1])
    got = fee.recorded_beta_star(phi, delta, rho, 0.0)
    assert got[0] == star[0] and got[1] == pytest.approx(np.pi - rho)
    beta = np.linspace(1e-3, np.pi - rho - 1e-6, 400)  # the wedges of non-negative area
    n = (1 / np.tan(rho) + 1 / np.tan(beta)) * np.sin(phi[1] + beta) / (2 * np.sin(delta[1] + rho + phi[1] + beta))
    assert (np.diff(n) < 0).all() and n[-1] < 1e-4 * n[0], "no minimum inside: it falls to 0 at π − ρ"


def test_the_fees_remainder_is_numpys_to_the_bit():
    """beta_star folds its roots into [0, pi) with a remainder written from fmod (NumPy's own costs
    3-4x as much): it must give NumPy's value to the bit, signed zeros, dtype and scalars too."""
    from soil_physics import xp as _xp

    rng = np.random.default_rng(11)
    x = np.concatenate([rng.uniform(-10, 10, 100_000), rng.uniform(-1e6, 1e6, 1000), np.arange(-8, 9) * math.pi,
                        np.arange(-8, 9) * math.pi / 2, [0.0, -0.0, 1e-300, -1e-300, math.pi - 1e-16, -math.pi + 1e-16,
                                                         np.nan, np.inf, -np.inf]])
    for values in (x, x.astype(np.float32)):
        with np.errstate(invalid="ignore"):
            got, want = _xp.remainder(np, values, math.pi), np.remainder(values, math.pi)
        assert got.dtype == want.dtype
        assert np.array_equal(got.view(f"i{got.itemsize}"), want.view(f"i{want.itemsize}"))
    for scalar in (-2.0 * math.pi, 7.5, np.float32(-1.25)):
        got, want = _xp.remainder(np, scalar, math.pi), np.remainder(scalar, math.pi)
        assert type(got) is type(want) and np.asarray(got).tobytes() == np.asarray(want).tobytes()
