"""Compiled form of the simulator (Numba): the same equations as the NumPy reference, per episode.

The readable reference of the physics is ``simulator.SoilSimulator`` running on NumPy
(``SimConfig(engine="reference")``) with ``soil_physics.fee``, ``bearing`` and ``contact``
and ``anti_stall_controller.controller``. This module is a second form of exactly those
equations, operation for operation in the same order, on the scalars of ONE episode, compiled
by Numba (``cache=True``: compiled once per machine into ``__pycache__``). Why a second form:
the reference spends ~14 ms of interpreter and dispatch overhead per 60 Hz tick on arrays of
one element; here a tick costs microseconds. Keep the two in step: ``tests/soil_sim_node/
test_kernel.py`` checks them against each other over random states and whole episodes of both
worlds with every effect switched on and off (outputs equal to 1e-9 relative), and the FEE
oracle tests check the reference.

Everything here is compiled into one module on purpose: Numba's cache only notices edits to
the file that holds a function, so a kernel split across modules could run stale code.

Random numbers: each episode's ``numpy.random.Generator`` is passed in and drawn in the
reference's order (per tick: ``substeps x 3`` uniforms, then two standard normals for the
noise); Numba draws the same stream from the same bit generator and advances its state.

Layouts (float64 arrays): ``state`` per episode (``S_*`` indices), ``episode`` constants per
episode (``E_*``, then ``E_N_PATCHES`` soil patches of ``N_PATCH`` columns each, ``K_*``
within a patch; an episode without patches has one), ``params`` shared by the batch (``P_*``),
built by ``SoilSimulator``.
"""
from __future__ import annotations

import math

import numba
import numpy as np

from soil_physics.bearing import PHI_MIN_RAD
from soil_physics.fee import BETA_MARGIN_RAD, SIN_ETA_FLOOR

# --- per-episode state (S_PATCH: the patch the soil half uses; S_DIST_ENTRY: S_DIST when the
# edge entered it; S_PILE_GAMMA: the surcharge pile's mean unit weight [N/m^3])
(S_X_C, S_VX_C, S_Z_C, S_VZ_C, S_Z_REL, S_VZ_REL, S_U_E, S_GRIP, S_GRIP_TAU, S_PILE, S_DIST,
 S_PATCH, S_DIST_ENTRY, S_PILE_GAMMA) = range(14)
N_STATE = 14

# --- per-episode constants (the world's, not the soil's), then the soil patches
E_DELTA, E_C_A, E_N_PATCHES = range(3)
N_EPISODE = 3
# --- one soil patch: where it starts (edge x [m]), its I_d [%], catalogue ends, nominal phi, c, gamma
(K_X_START, K_I_D, K_PHI_LOOSE, K_C_LOOSE, K_GAMMA_LOOSE, K_PHI_DENSE, K_C_DENSE, K_GAMMA_DENSE,
 K_PHI0, K_C0, K_GAMMA0) = range(11)
N_PATCH = 11

# --- shared parameters (dynamics, machine, effects; switches as 0.0 / 1.0)
(P_DT, P_SUBSTEPS, P_MOTOR_GAIN, P_JOINT_K, P_JOINT_C, P_CHASSIS_OMEGA, P_SOIL_K, P_SOIL_C,
 P_BLADE_OFFSET, P_CELL_M, P_X_MIN, P_N_CELLS, P_EDGE_W, P_FEE_GAIN, P_RHO, P_ALPHA, P_W,
 P_M_BLADE, P_M_CHASSIS, P_LIMIT_X, P_LIMIT_Z, P_MIN_REL, P_MAX_REL, P_MAX_SPEED, P_GRAVITY,
 P_SURCHARGE, P_PENETRATION, P_CONTACT_DAMPING, P_BASE_FRICTION, P_FORCE_SCALING, P_PARTICLES,
 P_COMPACTION, P_NOISE,
 P_SHED_TIME, P_PILE_CAPACITY, P_SURCHARGE_FEE_FACTOR, P_FORCE_SCALE, P_AREA_LIMIT, P_CHUNK,
 P_LOSS_MAX, P_LOSS_TIME_LO, P_LOSS_TIME_HI, P_FULL_DEPTH, P_COMPACTION_GAIN, P_COMPACTION_LENGTH,
 P_NOISE_X, P_NOISE_Z, P_DAMPING_PA_S_M, P_FRICTION_V_REF) = range(49)
N_PARAMS = 49

# --- what a substep hands to user plugins between its soil and machine halves (``ForceInputs``)
(F_X_B, F_Z_B, F_V_X, F_V_Z, F_D, F_Q, F_PHI, F_C, F_GAMMA, F_FEE_X, F_FEE_Z, F_X, F_Z, F_I_D) = range(14)
N_FORCE_INPUTS = 14

# --- controller (Eq. 11-12): gains and per-episode targets
C_K_V, C_C_VX, C_DELTA_D_MAX, C_DT, C_DITHER_A, C_DITHER_T, C_FORCE_LIFT, C_FORCE_SHARE, C_LIMIT_X, C_LIMIT_Z = range(10)
N_GAINS = 10

_JIT = dict(cache=True, nogil=True, error_model="numpy")


@numba.njit(**_JIT)
def _clip(x, lo, hi):
    """np.clip of a scalar: min(max(x, lo), hi)."""
    return min(max(x, lo), hi)


# ----------------------------------------------------------------- FEE (soil_physics.fee)
@numba.njit(**_JIT)
def _safe_sin_eta(eta):
    s = math.sin(eta)
    if abs(s) < SIN_ETA_FLOOR:
        return (-SIN_ETA_FLOOR if s < 0 else SIN_ETA_FLOOR) + 0.0 * s
    return s


@numba.njit(**_JIT)
def fee_n_gamma(phi, delta, rho, alpha, beta):
    """N_gamma of ``fee.coefficients``."""
    eta = delta + rho + phi + beta
    sin_eta = _safe_sin_eta(eta)
    s_wedge = math.sin(alpha + phi + beta)
    return (1.0 / math.tan(rho) + 1.0 / math.tan(beta)) * s_wedge / (2.0 * sin_eta)


@numba.njit(**_JIT)
def fee_failure_force(phi, c, delta, c_a, gamma, rho, alpha, w, d, q, beta):
    """``fee.failure_force`` (Eq. 2 with the adhesion length fixed) for one sample [N]."""
    eta = delta + rho + phi + beta
    sin_eta = _safe_sin_eta(eta)
    s_wedge = math.sin(alpha + phi + beta)
    n_gamma = (1.0 / math.tan(rho) + 1.0 / math.tan(beta)) * s_wedge / (2.0 * sin_eta)
    n_c = math.cos(phi) / (math.sin(beta) * sin_eta)
    n_q = s_wedge / sin_eta
    n_a = -math.cos(rho + phi + beta) / (math.sin(rho) * sin_eta)
    d_pos = max(d, 0.0)
    force = gamma * (d_pos * d_pos) * w * n_gamma + c * d_pos * w * n_c + c_a * d_pos * w * n_a
    return force + (q * n_q if d > 0 else 0.0 * q)


@numba.njit(**_JIT)
def fee_beta_star(phi, delta, rho, alpha):
    """``fee.beta_star`` (closed form, the smaller valid N_gamma of the two roots) [rad]."""
    a_ = alpha + phi
    b_ = delta + rho + phi
    a = math.cos(rho - a_)
    p = rho + a_
    b = math.cos(b_)
    q = b_
    x = b * math.cos(p) - a * math.cos(q)
    y = b * math.sin(p) - a * math.sin(q)
    m = math.sqrt(x * x + y * y)
    s = _clip(math.sin(p - q) / m, -1.0, 1.0)
    psi = math.atan2(y, x)
    root = math.asin(s)
    upper = math.pi - b_
    best = 0.0
    best_n = math.inf
    for j in range(2):
        theta = root - psi if j == 0 else math.pi - root - psi
        beta = np.remainder(theta / 2.0, math.pi)
        valid = (beta > BETA_MARGIN_RAD) and (beta < upper - BETA_MARGIN_RAD)
        n = fee_n_gamma(phi, delta, rho, alpha, beta)
        n = n if (valid and n > 0) else math.inf
        if j == 0 or n < best_n:
            best, best_n = beta, n
    return best if best_n < math.inf else math.nan


@numba.njit(**_JIT)
def recorded_beta_star(phi, delta, rho, alpha):
    """``fee.recorded_beta_star``: β*, or π − ρ where no failure wedge resists [rad]."""
    beta = fee_beta_star(phi, delta, rho, alpha)
    return beta if math.isfinite(beta) else math.pi - rho


@numba.njit(**_JIT)
def fee_velocity_scale(rho, alpha, v_x, v_z, c1):
    """tanh(-C1 iota_b . v) of ``fee.velocity_corrected`` (Eq. 9-10)."""
    iota_dot_v = -math.cos(rho - alpha) * v_x + math.sin(rho - alpha) * v_z
    return math.tanh(-c1 * iota_dot_v)


# ------------------------------------------------- bearing and contact (soil_physics)
@numba.njit(**_JIT)
def penetration_capacity(phi, c, gamma, d, w, t_e):
    """``bearing.penetration_capacity`` with ``bearing.bearing_factors`` [N]."""
    phi = max(phi, PHI_MIN_RAD)
    n_q = math.exp(math.pi * math.tan(phi)) * math.tan(math.pi / 4 + phi / 2) ** 2
    n_c = (n_q - 1.0) / math.tan(phi)
    n_gamma = 2.0 * (n_q + 1.0) * math.tan(phi)
    depth = max(d, 0.0)
    q_b = c * n_c + gamma * depth * n_q + 0.5 * gamma * t_e * n_gamma
    return q_b * w * t_e * (1.0 if d > 0 else 0.0)


# ------------------------------------------------------------------ the simulator
@numba.njit(**_JIT)
def _cell(x, p):
    i = np.int64(math.floor((x - p[P_X_MIN]) / p[P_CELL_M]))
    return min(max(i, 0), np.int64(p[P_N_CELLS]) - 2)


@numba.njit(**_JIT)
def depth(s, terrain, p):
    """Cut depth d [m]: the surface one cell ahead of the edge minus the edge height."""
    x_b = s[S_X_C] + p[P_BLADE_OFFSET]
    return terrain[_cell(x_b, p) + 1] - (s[S_Z_C] + s[S_Z_REL])


@numba.njit(**_JIT)
def patch_at(e, x):
    """Index of the soil patch at edge x [m] (``SoilSimulator.patch_at``): the last whose start
    is <= x; the first patch also holds before the second's start."""
    j = 0
    for k in range(1, int(e[E_N_PATCHES])):
        if x >= e[N_EPISODE + k * N_PATCH + K_X_START]:
            j = k
    return j


@numba.njit(**_JIT)
def enter_patch(s, e, p):
    """The column offset of the patch under the edge now (``SoilSimulator._enter_patch``);
    when the edge has crossed into another patch, its compaction starts from its own I_d."""
    j = patch_at(e, s[S_X_C] + p[P_BLADE_OFFSET])
    if j != int(s[S_PATCH]):
        s[S_PATCH] = j
        s[S_DIST_ENTRY] = s[S_DIST]
    return N_EPISODE + j * N_PATCH


@numba.njit(**_JIT)
def soil_in_effect(s, e, p, o):
    """(phi, c, gamma) of patch ``o`` (column offset) at the compacted relative density
    (``SoilSimulator.soil_in_effect``)."""
    i_d = e[o + K_I_D]
    if p[P_COMPACTION] != 0.0:
        i_d = i_d + (100.0 - i_d) * p[P_COMPACTION_GAIN] * (
            1.0 - math.exp(-(s[S_DIST] - s[S_DIST_ENTRY]) / p[P_COMPACTION_LENGTH]))
    frac = i_d / 100.0
    phi = e[o + K_PHI_LOOSE] + (e[o + K_PHI_DENSE] - e[o + K_PHI_LOOSE]) * frac
    c = e[o + K_C_LOOSE] + (e[o + K_C_DENSE] - e[o + K_C_LOOSE]) * frac
    gamma = e[o + K_GAMMA_LOOSE] + (e[o + K_GAMMA_DENSE] - e[o + K_GAMMA_LOOSE]) * frac
    return phi, c, gamma


@numba.njit(**_JIT)
def surcharge_n(s, p):
    """Weight of the surcharge pile Q [N]: its volume times its mean unit weight."""
    return s[S_PILE_GAMMA] * s[S_PILE] if p[P_SURCHARGE] != 0.0 else 0.0


@numba.njit(**_JIT)
def substep(s, e, terrain, p, probes, u_zr, u_x, u0, u1, u2):
    """One physics step of ``SoilSimulator._substep``; updates ``s`` and ``terrain`` in place
    and returns the measured (f_x, f_z) of the step [N]."""
    f = np.empty(N_FORCE_INPUTS)
    substep_soil(s, e, terrain, p, u0, u1, u2, f)
    return substep_machine(s, e, terrain, p, probes, u_zr, u_x, f)


@numba.njit(**_JIT)
def substep_soil(s, e, terrain, p, u0, u1, u2, f):
    """First half of a substep: the soil's force on the blade up to where user plugins add
    theirs (FEE, contact, particles, contact damping). Fills ``f`` (``F_*`` layout)."""
    dt = p[P_DT]
    rho, alpha, w = p[P_RHO], p[P_ALPHA], p[P_W]
    delta, c_a = e[E_DELTA], e[E_C_A]
    vz_b = s[S_VZ_C] + s[S_VZ_REL]
    vx = s[S_VX_C]
    d = depth(s, terrain, p)
    in_soil = d > 0
    o = enter_patch(s, e, p)
    phi, c, gamma = soil_in_effect(s, e, p, o)
    q = surcharge_n(s, p)

    # FEE failure force (Eq. 2-10) and its direction (Eq. 8)
    scale = fee_velocity_scale(rho, alpha, vx, vz_b, p[P_FEE_GAIN])
    delta_p, c_a_p = scale * delta, scale * c_a
    beta = fee_beta_star(phi, delta_p, rho, alpha)
    q_fee = q * p[P_SURCHARGE_FEE_FACTOR]
    f_fail = fee_failure_force(phi, c, delta_p, c_a_p, gamma, rho, alpha, w, d, q_fee, beta)
    f_fail = max(f_fail, 0.0) if math.isfinite(f_fail) else 0.0
    if p[P_FORCE_SCALING] != 0.0:
        area = w * max(d, 0.0) / math.sin(rho)
        f_fail = min(f_fail * p[P_FORCE_SCALE], p[P_AREA_LIMIT] * area)
    angle = 0.5 * math.pi - rho - delta_p + alpha
    ex, ez = math.cos(angle), math.sin(angle)

    # elastic-perfectly-plastic contact
    v_n = vx * ex + vz_b * ez
    u_e = _clip(s[S_U_E] + v_n * dt, 0.0, f_fail / p[P_SOIL_K])
    u_e = u_e if in_soil else 0.0
    s[S_U_E] = u_e
    f_mag = _clip(p[P_SOIL_K] * u_e + p[P_SOIL_C] * v_n, 0.0, f_fail)

    if p[P_PARTICLES] != 0.0:
        rate = max(vx, 0.0) / p[P_CHUNK] * (1.0 if in_soil else 0.0)
        event = u0 < rate * dt
        loss = p[P_LOSS_MAX] * u1 * _clip(d / p[P_FULL_DEPTH], 0.0, 1.0)
        lo, hi = p[P_LOSS_TIME_LO], p[P_LOSS_TIME_HI]
        grip, grip_tau = s[S_GRIP], s[S_GRIP_TAU]
        if event:
            grip = min(grip, 1.0 - loss)
            grip_tau = lo + (hi - lo) * u2
        grip = grip + (1.0 - grip) * min(dt / grip_tau, 1.0)
        s[S_GRIP], s[S_GRIP_TAU] = grip, grip_tau
        f_mag = f_mag * grip
    fx, fz = f_mag * ex, f_mag * ez
    f[F_FEE_X], f[F_FEE_Z] = fx, fz

    if p[P_CONTACT_DAMPING] != 0.0:  # contact.contact_damping_force
        area = w * max(d, 0.0) / math.sin(rho)
        n_x, n_z = math.sin(rho - alpha), math.cos(rho - alpha)
        f_n = p[P_DAMPING_PA_S_M] * area * (vx * n_x + vz_b * n_z)
        fx, fz = fx + f_n * n_x, fz + f_n * n_z
    f[F_X_B], f[F_Z_B] = s[S_X_C] + p[P_BLADE_OFFSET], s[S_Z_C] + s[S_Z_REL]
    f[F_V_X], f[F_V_Z], f[F_D], f[F_Q] = vx, vz_b, d, q
    f[F_PHI], f[F_C], f[F_GAMMA], f[F_I_D] = phi, c, gamma, e[o + K_I_D]
    f[F_X], f[F_Z] = fx, fz


@numba.njit(**_JIT)
def substep_machine(s, e, terrain, p, probes, u_zr, u_x, f):
    """Second half of a substep: from the soil's force ``f`` (plus any plugins' in f[F_X],
    f[F_Z]) the lift joint, penetration, base friction, integration and the cut; returns the
    measured (f_x, f_z) of the step [N]."""
    dt = p[P_DT]
    w, delta = p[P_W], e[E_DELTA]
    vx, vz_b, d = f[F_V_X], f[F_V_Z], f[F_D]
    phi, c, gamma = f[F_PHI], f[F_C], f[F_GAMMA]
    f_fee_z, fx, fz = f[F_FEE_Z], f[F_X], f[F_Z]

    # blade vertical: lift joint, then the penetration constraint
    f_joint = _clip(p[P_JOINT_K] * (u_zr - s[S_Z_REL]) - p[P_JOINT_C] * s[S_VZ_REL], -p[P_LIMIT_Z], p[P_LIMIT_Z])
    m_b = p[P_M_BLADE]
    weight = m_b * p[P_GRAVITY]
    h = 0.0
    for o in probes:
        h = h + terrain[_cell(s[S_X_C] + o, p)]
    h = h / probes.shape[0]
    w_c = p[P_CHASSIS_OMEGA]
    a_zc = w_c * w_c * (h - s[S_Z_C]) - 2.0 * w_c * s[S_VZ_C]
    friction = math.tan(delta) if p[P_BASE_FRICTION] != 0.0 else 0.0
    v_ref = p[P_FRICTION_V_REF]
    if p[P_PENETRATION] != 0.0:
        sinking = vz_b + (f_joint - weight - fz) / m_b * dt
        need = max(-sinking, 0.0) * m_b / dt
        reaction = min(need, penetration_capacity(phi, c, gamma, d, w, p[P_EDGE_W]))
        fz = fz - reaction
        if p[P_BASE_FRICTION] != 0.0:  # contact.base_friction_force on the reaction
            normal = max(reaction + max(-f_fee_z, 0.0), 0.0)
            fx = fx + friction * normal * (1.0 if d > 0 else 0.0) * math.tanh(vx / v_ref)
    elif p[P_BASE_FRICTION] != 0.0:
        normal = max(-f_fee_z, 0.0)
        fx = fx + friction * normal * (1.0 if d > 0 else 0.0) * math.tanh(vx / v_ref)
    a_zb = (f_joint - weight - fz) / m_b

    # chassis + blade in x (semi-implicit Euler)
    f_motor = _clip(p[P_MOTOR_GAIN] * (u_x - vx), -p[P_LIMIT_X], p[P_LIMIT_X])
    a_x = (f_motor - fx) / (p[P_M_CHASSIS] + m_b)
    s[S_VX_C] = s[S_VX_C] + a_x * dt
    s[S_X_C] = s[S_X_C] + s[S_VX_C] * dt
    s[S_VZ_C] = s[S_VZ_C] + a_zc * dt
    s[S_Z_C] = s[S_Z_C] + s[S_VZ_C] * dt
    s[S_VZ_REL] = s[S_VZ_REL] + (a_zb - a_zc) * dt
    s[S_Z_REL] = s[S_Z_REL] + s[S_VZ_REL] * dt

    # the edge cuts the heightfield; pile and travel in soil (``travel.soil_advance``)
    i = _cell(s[S_X_C] + p[P_BLADE_OFFSET], p)
    terrain[i] = min(terrain[i], s[S_Z_C] + s[S_Z_REL])
    advance = max(s[S_VX_C], 0.0) * dt * (1.0 if d > 0 else 0.0)
    s[S_DIST] = s[S_DIST] + advance
    if p[P_SURCHARGE] != 0.0:
        cap = p[P_PILE_CAPACITY]
        inflow = w * max(d, 0.0) * advance * (1.0 - s[S_PILE] / cap)
        kept = s[S_PILE] + inflow - s[S_PILE] * dt / p[P_SHED_TIME]
        if inflow > 0.0 and kept > 0.0:  # the cut soil mixes into the pile (``SoilSimulator._substep``)
            gamma_cut = e[N_EPISODE + int(s[S_PATCH]) * N_PATCH + K_GAMMA0]
            s[S_PILE_GAMMA] = s[S_PILE_GAMMA] + (gamma_cut - s[S_PILE_GAMMA]) * (inflow / kept)
        s[S_PILE] = _clip(kept, 0.0, cap)
    return m_b * a_x + fx, f_joint - weight


@numba.njit(**_JIT)
def substep_soil_batch(states, episodes, terrains, p, uniforms, f):
    """``substep_soil`` for every row of a batch (``uniforms`` (B, 3), ``f`` (B, N_FORCE_INPUTS))."""
    for i in range(states.shape[0]):
        substep_soil(states[i], episodes[i], terrains[i], p, uniforms[i, 0], uniforms[i, 1], uniforms[i, 2], f[i])


@numba.njit(**_JIT)
def substep_machine_batch(states, episodes, terrains, p, probes, u_zr, u_x, f, measured):
    """``substep_machine`` for every row of a batch; the measured force into ``measured`` (B, 2)."""
    for i in range(states.shape[0]):
        measured[i, 0], measured[i, 1] = substep_machine(states[i], episodes[i], terrains[i], p, probes, u_zr[i],
                                                         u_x[i], f[i])


@numba.njit(**_JIT)
def tick(s, e, terrain, p, probes, rng, u_zr, u_x, forces):
    """One 60 Hz tick of ``SoilSimulator.step`` for one episode; commands already clipped.
    Writes the tick's measured force (mean over substeps, plus noise) into ``forces`` (2,)."""
    n = int(p[P_SUBSTEPS])
    uniforms = np.empty((n, 3))
    for k in range(n):
        for j in range(3):
            uniforms[k, j] = rng.random()
    fx_sum, fz_sum = 0.0, 0.0
    for k in range(n):
        fx, fz = substep(s, e, terrain, p, probes, u_zr, u_x, uniforms[k, 0], uniforms[k, 1], uniforms[k, 2])
        fx_sum, fz_sum = fx_sum + fx, fz_sum + fz
    forces[0], forces[1] = fx_sum / n, fz_sum / n
    if p[P_NOISE] != 0.0:
        n0 = rng.standard_normal()
        n1 = rng.standard_normal()
        forces[0], forces[1] = forces[0] + n0 * p[P_NOISE_X], forces[1] + n1 * p[P_NOISE_Z]


@numba.njit(**_JIT)
def push_velocity(s, v_hist, count):
    """``SoilSimulator._push_velocity_history``: newest first in ``v_hist`` (n, 2); returns the count."""
    for j in range(v_hist.shape[0] - 1, 0, -1):
        v_hist[j, 0], v_hist[j, 1] = v_hist[j - 1, 0], v_hist[j - 1, 1]
    v_hist[0, 0], v_hist[0, 1] = s[S_VX_C], s[S_VZ_C] + s[S_VZ_REL]
    return min(count + 1, v_hist.shape[0])


@numba.njit(**_JIT)
def output_row(s, e, terrain, p, v_hist, count, positions, velocities, known, truth, extras):
    """``SoilSimulator._output`` for one episode (columns in the params module's orders)."""
    x_b = s[S_X_C] + p[P_BLADE_OFFSET]
    z_b = s[S_Z_C] + s[S_Z_REL]
    vz_b = s[S_VZ_C] + s[S_VZ_REL]
    d = depth(s, terrain, p)
    q = surcharge_n(s, p)
    o = N_EPISODE + patch_at(e, x_b) * N_PATCH  # the ground truth is the soil under the edge
    v_x, v_z = 0.0, 0.0
    for j in range(count):
        v_x, v_z = v_x + v_hist[j, 0], v_z + v_hist[j, 1]
    v_x, v_z = v_x / count, v_z / count
    rho, alpha, w = p[P_RHO], p[P_ALPHA], p[P_W]
    positions[0], positions[1], positions[2] = x_b, z_b, s[S_Z_C]
    velocities[0], velocities[1], velocities[2] = vz_b, s[S_VX_C], s[S_VZ_C]
    # KNOWN_PARAMS: c_a, gamma, rho, alpha, w, d, q, v_x, v_z
    known[0], known[1], known[2], known[3], known[4] = e[E_C_A], e[o + K_GAMMA0], rho, alpha, w
    known[5], known[6], known[7], known[8] = d, q, v_x, v_z
    # GROUND_TRUTH_PARAMS: phi, c, delta, c_a, gamma, rho, alpha, w, d, q, v_x, v_z, beta
    truth[0], truth[1], truth[2] = e[o + K_PHI0], e[o + K_C0], e[E_DELTA]
    for j in range(9):
        truth[3 + j] = known[j]
    delta_p = fee_velocity_scale(rho, alpha, v_x, v_z, p[P_FEE_GAIN]) * e[E_DELTA]
    truth[12] = recorded_beta_star(e[o + K_PHI0], delta_p, rho, alpha)
    extras[0], extras[1] = s[S_X_C], s[S_VX_C]


@numba.njit(**_JIT)
def controller_step(gains, speed, target_depth, ctl, v, pz, force, command):
    """``AntiStallController.step`` (Eq. 11-12 with the depth dither and the force lift) for one
    episode, ``force`` the blade force (F_x, F_z) of the tick. ``ctl`` = (offset, last p_z^c,
    steps since reset) is updated in place; ``command`` gets (u_zr, u_za, u_x)."""
    e_vx = speed - v
    e_vmin = speed * gains[C_C_VX]
    k_dp = gains[C_K_V] / speed
    candidate = ctl[0] + (k_dp * (e_vx - e_vmin)) * gains[C_DT]
    if gains[C_FORCE_LIFT] > 0.0 and math.isfinite(force[0]) and math.isfinite(force[1]):
        share = max(abs(force[0]) / gains[C_LIMIT_X], abs(force[1]) / gains[C_LIMIT_Z])
        candidate = candidate + (gains[C_FORCE_LIFT] * max(share - gains[C_FORCE_SHARE], 0.0)) * gains[C_DT]
    candidate = _clip(candidate, 0.0, target_depth + gains[C_DELTA_D_MAX])
    if math.isfinite(v) and math.isfinite(pz):
        ctl[0] = candidate
    if math.isfinite(pz):
        ctl[1] = pz
    dither = gains[C_DITHER_A] * math.sin(2.0 * math.pi * (ctl[2] * gains[C_DT]) / gains[C_DITHER_T])
    u_za = -((target_depth + dither) - ctl[0])
    ctl[2] = ctl[2] + 1.0
    command[0] = _clip(u_za - ctl[1], command[3], command[4])
    command[1] = u_za
    command[2] = speed


@numba.njit(**_JIT)
def run_episode(s, e, terrain, p, probes, rng, gains, speed, target_depth, v_hist_len,
                obs, forces, known, truth, extras):
    """Closed loop of ``rollout.run_episodes`` for one episode from its reset state: row k of
    the outputs is the state after k ticks, the force of the tick that ended there and the
    controller's command for it (obs columns: positions, velocities, u_zr, u_za, u_x)."""
    n_ticks = obs.shape[0]
    v_hist = np.zeros((v_hist_len, 2))
    count = push_velocity(s, v_hist, 0)
    ctl = np.zeros(3)
    command = np.array([0.0, 0.0, 0.0, p[P_MIN_REL], p[P_MAX_REL]])
    tick_forces = np.zeros(2)
    positions, velocities = np.zeros(3), np.zeros(3)
    for k in range(n_ticks):
        output_row(s, e, terrain, p, v_hist, count, positions, velocities, known[k], truth[k], extras[k])
        controller_step(gains, speed, target_depth, ctl, velocities[1], positions[2], tick_forces, command)
        for j in range(3):
            obs[k, j], obs[k, 3 + j], obs[k, 6 + j] = positions[j], velocities[j], command[j]
        forces[k, 0], forces[k, 1] = tick_forces[0], tick_forces[1]
        u_zr = _clip(command[0], p[P_MIN_REL], p[P_MAX_REL])
        u_x = _clip(command[2], -p[P_MAX_SPEED], p[P_MAX_SPEED])
        tick(s, e, terrain, p, probes, rng, u_zr, u_x, tick_forces)
        count = push_velocity(s, v_hist, count)
