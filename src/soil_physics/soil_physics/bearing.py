"""Bearing capacity of the cutting edge: the one N_q, N_c (and N_γ) and the one edge width.

The FEE's blade has no thickness; a real edge of effective width t_e bears on the floor it
cuts. Both the simulator's penetration constraint and the catalogue's ``tip_penetration``
term use these factors and this width.
"""
from __future__ import annotations

import math

import numpy as np

from . import xp as _xp

EDGE_WIDTH_M = 0.02  # effective width t_e of the cutting edge [m]
# N_c = (N_q − 1) cot φ is 0/0 at φ = 0; above this φ [rad] it is finite and tends to π + 2.
PHI_MIN_RAD = 1e-6


def bearing_factors(phi):
    """(N_q, N_c, N_γ) of a strip footing at friction angle ``phi`` [rad] (NumPy or torch).

    N_q = e^{π tan φ} tan²(45° + φ/2) (Prandtl-Reissner), N_c = (N_q − 1) cot φ (→ π + 2 as
    φ → 0: φ is held at ``PHI_MIN_RAD`` or above), N_γ = 2 (N_q + 1) tan φ (Vesic 1973).
    """
    xp, phi = _xp.coerce(phi)
    phi = _xp.clip_min(xp, phi, PHI_MIN_RAD)
    # tan φ once per factor, not shared: the PINN's gradients through tip_penetration stay
    # bit for bit those of the original formula (autograd sums a shared node in another order)
    n_q = xp.exp(math.pi * xp.tan(phi)) * xp.tan(math.pi / 4 + phi / 2) ** 2
    n_c = (n_q - 1.0) / xp.tan(phi)
    n_gamma = 2.0 * (n_q + 1.0) * xp.tan(phi)
    return n_q, n_c, n_gamma


def penetration_capacity(state, edge_width_m: float | None = None):
    """Largest vertical resistance [N] intact soil offers the cutting edge (Vortex "penetration forces").

    Bearing capacity of a strip of width t_e (``edge_width_m``, default the state's
    ``blade_thickness``) at depth d (Terzaghi 1943 form with Vesic's N_γ):
    q_b = c N_c + γ d N_q + ½ γ t_e N_γ; capacity = q_b w t_e, 0 out of the soil. The
    simulator applies it as a one-sided rigid-plastic constraint: an edge that the lift and
    its weight would move down into the soil is held by up to this force (so dense soils
    resist penetration, paper §2.1.2 footnote 2); an edge the lift holds up or raises feels
    nothing. The held edge includes one *at rest* on the floor it cuts while the lift is
    commanded below it: the floor then carries the lift's whole downward push, a constraint
    force set by the controller, not by the soil, which only bounds it. In the default world
    this is most of the measured F_z (steady at 0.1 m with I_d = 80 %: −2.6 to −9.6 kN in
    clay, gravel and loam, to −1.4 kN in sand, where the edge stopped up to 5 mm short of
    its command while entering; about 0 in looser soils). (A force
    proportional to the sinking speed would be a stiff damper that explicit integration
    cannot carry.)
    ``state``: a ``ForceInputs`` (NumPy).
    """
    t_e = state.blade_thickness if edge_width_m is None else edge_width_m
    q_b = edge_pressure_pa(state.phi, state.c, state.gamma, state.d, np, strip_width_m=t_e)
    return q_b * state.w * t_e * (state.d > 0)


def edge_pressure_pa(phi, c, gamma, d, xp, strip_width_m=None):
    """Bearing pressure of the edge [Pa] at depth d (counted from 0 above the surface):
    q_b = c N_c + γ d N_q, plus ½ γ b N_γ of a strip of width b = ``strip_width_m`` where given
    (Terzaghi's form with Vesic's N_γ). NumPy or torch (``xp``). The one formula: the simulator's
    constraint (with N_γ) and the catalogue's and the form library's edge bearing (without)."""
    n_q, n_c, n_gamma = bearing_factors(phi)
    q_b = c * n_c + gamma * _xp.positive_part(xp, d) * n_q
    if strip_width_m is not None:
        q_b = q_b + 0.5 * gamma * strip_width_m * n_gamma
    return q_b


def edge_bearing_n(s, xp):
    """w t_e (c N_c + γ d N_q) [N] of a ``ForceInputs`` ``s``, 0 out of the soil: the edge bearing
    as the catalogue's ``tip_penetration`` and the form library's ``bear_*`` scales have it."""
    return s.w * s.blade_thickness * edge_pressure_pa(s.phi, s.c, s.gamma, s.d, xp) * ((s.d > 0) * 1.0)
