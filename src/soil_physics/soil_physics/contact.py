"""Blade-soil contact forces the FEE lacks (Vortex's contact heuristics), on ``ForceInputs``.

Force convention: the force the blade exerts ON the soil [N], x forward, z up (the FEE's,
paper Eq. 8). The simulator switches them on and off (``soil_sim_node.effects.Effects``);
the bearing-capacity constraint of the edge is ``bearing.penetration_capacity``.
"""
from __future__ import annotations

import numpy as np

CONTACT_DAMPING_PA_S_M = 6e3  # contact damping pressure per unit normal speed [Pa·s/m]
BASE_FRICTION_V_REF_M_S = 0.02  # base friction reaches tanh(1) of its Coulomb value at this speed [m/s]


def submerged_area_m2(w, d, rho):
    """Area of the blade face below the surface [m²]: w d / sin ρ (0 out of the soil)."""
    return w * np.maximum(d, 0.0) / np.sin(rho)


def contact_damping_force(state, damping_pa_s_m: float = CONTACT_DAMPING_PA_S_M):
    """Viscous contact damping on the submerged blade face [N] (Vortex contact damping).

    Pressure c_v · v_n [Pa] on the submerged area w d / sin ρ, along the blade normal,
    opposing the blade's normal velocity v_n (rate-dependent resistance).
    """
    area = submerged_area_m2(state.w, state.d, state.rho)
    n_x, n_z = np.sin(state.rho - state.alpha), np.cos(state.rho - state.alpha)
    v_n = state.v_x * n_x + state.v_z * n_z
    f_n = damping_pa_s_m * area * v_n
    return f_n * n_x, f_n * n_z


def base_friction_force(state, normal_down_n=None, mu: float | None = None, v_ref_m_s: float = BASE_FRICTION_V_REF_M_S):
    """Coulomb friction of the blade base on the cut floor [N] (Vortex contact friction).

    What the blade pushes down onto the floor (``normal_down_n`` [N] >= 0; the simulator
    passes the penetration reaction plus any downward FEE component; default the downward
    FEE component) resists forward sliding with μ = tan δ, smoothed through zero speed by
    tanh(v_x / ``v_ref_m_s``) so a blade at rest feels none.
    """
    mu_v = np.tan(state.delta) if mu is None else mu
    normal = np.maximum(-state.f_fee_z, 0.0) if normal_down_n is None else np.maximum(normal_down_n, 0.0)
    fx = mu_v * normal * (state.d > 0) * np.tanh(state.v_x / v_ref_m_s)
    return fx, np.zeros_like(fx)
