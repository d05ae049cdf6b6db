"""The measured blade force is the soil's force plus the blade's own inertia.

What a blade force sensor (here: the lift joint's force and the chassis drive) reads also
accelerates the blade: F_measured = F_soil + m_b·a, with the blade moving with the chassis in x
(v_x^c) and at v_z^b in z. A model of the soil (the FEE) explains only F_soil, so evidence about
the soil is the measured force minus m_b·a. Over one 60 Hz tick the mean acceleration is
(v_k − v_{k−1})·f_s whatever happens within the tick, so two consecutive velocity samples give
the tick-mean inertia force exactly. It matters whenever the blade moves vertically: in the
fee world its mean |m_b a_z| is 22 % of the mean |F_z| under a 3 cm, 2 s depth dither, and
about as large as F_z itself in the first second of a cut, while the edge enters the soil.
"""
from __future__ import annotations

import numpy as np

from soil_msgs_py.params import MACHINE, OBSERVATION_FIELDS, SAMPLE_RATE_HZ

# The observation fields of the blade's velocity (x, z) [m/s]: it moves with the chassis in x.
BLADE_VELOCITY_FIELDS: tuple[str, str] = ("v_x_c", "v_z_b")
_COLUMNS = [OBSERVATION_FIELDS.index(n) for n in BLADE_VELOCITY_FIELDS]


def blade_velocity(observations: np.ndarray) -> np.ndarray:
    """(..., 2) blade velocity (x, z) [m/s] of observation rows (..., len(OBSERVATION_FIELDS))."""
    return np.asarray(observations, float)[..., _COLUMNS]


# The observation fields of the blade's cutting-edge position (x, z) [m].
BLADE_POSITION_FIELDS: tuple[str, str] = ("p_x_b", "p_z_b")
_POSITION_COLUMNS = [OBSERVATION_FIELDS.index(n) for n in BLADE_POSITION_FIELDS]


def blade_position(observations: np.ndarray) -> np.ndarray:
    """(..., 2) blade cutting-edge position (x, z) [m] of observation rows (..., len(OBSERVATION_FIELDS))."""
    return np.asarray(observations, float)[..., _POSITION_COLUMNS]


def inertia_force_n(v_now: np.ndarray, v_prev: np.ndarray, blade_mass_kg: float = MACHINE.blade_mass_kg) -> np.ndarray:
    """m_b × the tick-mean acceleration (x, z) [N] between two consecutive samples' blade velocities."""
    return blade_mass_kg * (np.asarray(v_now, float) - np.asarray(v_prev, float)) * SAMPLE_RATE_HZ


def inertia_force_rows(v_x: np.ndarray, v_z_b: np.ndarray, blade_mass_kg: float = MACHINE.blade_mass_kg):
    """(m_b a_x, m_b a_z) [N] per row of one episode's consecutive velocities (row 0: 0)."""
    v = np.stack([np.asarray(v_x, float), np.asarray(v_z_b, float)], axis=1)
    f = np.zeros_like(v)
    f[1:] = inertia_force_n(v[1:], v[:-1], blade_mass_kg)
    return f[:, 0], f[:, 1]


def inertia_rows(observations: np.ndarray, gap_before: np.ndarray | None = None,
                 blade_mass_kg: float = MACHINE.blade_mass_kg) -> np.ndarray:
    """(N, 2) m_b a (x, z) [N] per row of one episode's observations; 0 on row 0 and on a row
    after a gap (``gap_before``, a repaired bag): no acceleration is known across it."""
    v = blade_velocity(observations)
    f = np.stack(inertia_force_rows(v[:, 0], v[:, 1], blade_mass_kg), axis=1)
    if gap_before is not None:
        f[np.asarray(gap_before, bool)] = 0.0
    return f


def soil_force_rows(forces_n: np.ndarray, observations: np.ndarray,
                    blade_mass_kg: float = MACHINE.blade_mass_kg) -> np.ndarray:
    """(N, 2) the soil's force (x, z) [N] of one episode's measured forces: minus m_b a per row."""
    return np.asarray(forces_n, float) - inertia_rows(observations, blade_mass_kg=blade_mass_kg)
