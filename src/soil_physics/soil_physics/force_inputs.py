"""``ForceInputs``: what every force term the FEE lacks may look at — one vocabulary.

The simulator's effects and user plugins see it once per physics substep (its soil in effect
now, its own FEE force, its ground-truth travel in soil); the catalogue of candidate effects
(``force_terms``) sees it per sample in the FEE model, the discrepancy workflow and the PINN
(the model's θ and FEE force, Θ_k, the estimator's travel in soil). Fields are arrays of one
shape (NumPy or torch; scalars broadcast), SI units. The fields after ``f_fee_z`` are
optional: the simulator fills them, a model built from Θ_k has t, dt, x_b, z_b and
relative_density_pct as None, and time_in_soil only where one of its terms looks at it.
Force convention: the force the blade exerts ON the soil [N], x forward, z up (paper Eq. 8).
"""
from __future__ import annotations

from dataclasses import dataclass, fields, replace
from typing import Any, Mapping

import numpy as np

from soil_msgs_py.params import KNOWN_PARAMS

from . import xp as _xp
from .bearing import EDGE_WIDTH_M


@dataclass(frozen=True)
class ForceInputs:
    """Per-sample (or per-substep, per-episode) quantities a force term may use (SI)."""

    d: Any  # depth of cut, surface minus edge [m] (<= 0: blade out of the soil)
    q: Any  # surcharge weight on the blade [N]
    v_x: Any  # blade velocity x [m/s]
    v_z: Any  # blade velocity z [m/s]
    gamma: Any  # unit weight [N/m^3]
    w: Any  # blade width [m]
    rho: Any  # blade angle [rad]
    alpha: Any  # surface inclination [rad]
    phi: Any  # soil friction angle [rad] (the simulator's in effect now; a model's θ)
    c: Any  # cohesion [Pa] (the simulator's in effect now; a model's θ)
    delta: Any  # soil-tool friction angle [rad] (nominal; a model's θ)
    distance_in_soil: Any  # blade travel with d > 0 since the episode started [m] (``travel``)
    f_fee_x: Any  # the FEE soil force, x [N]
    f_fee_z: Any  # the FEE soil force, z [N]
    c_a: Any = None  # adhesion [Pa] (Θ_k)
    blade_thickness: Any = EDGE_WIDTH_M  # effective cutting-edge width t_e [m]
    # simulation time [s] (simulator only) of the tick, the same for each of its substeps (a plugin that
    # needs the substep's adds up dt); it starts again at 0 with each episode, which is how a plugin
    # that keeps state between calls tells a new one
    t: Any = None
    dt: Any = None  # physics substep [s] (simulator only)
    x_b: Any = None  # blade edge x [m] (simulator only)
    z_b: Any = None  # blade edge z [m] (simulator only)
    relative_density_pct: Any = None  # nominal I_d [%] of the soil (patch) under the edge (simulator only)
    # time with d > 0 since the episode started [s] (``travel.time_in_soil``): the simulator's
    # per substep; a model's from Θ_k when one of its terms looks at it (None: not given)
    time_in_soil: Any = None

    @classmethod
    def from_known(cls, known, *, phi, c, delta, distance_in_soil, f_fee_x, f_fee_z, d=None,
                   time_in_soil=None) -> "ForceInputs":
        """The inputs of a model from measured quantities: Θ_k, its θ = (φ, c, δ) and its FEE force.

        ``known``: Θ_k as (..., 9) columns in ``KNOWN_PARAMS`` order (NumPy or torch) or a
        mapping of those names; ``phi`` [rad], ``c`` [Pa], ``delta`` [rad]: the model's soil;
        ``distance_in_soil`` [m]: ``travel.distance_in_soil``; ``f_fee_x``, ``f_fee_z`` [N]:
        the model's FEE force; ``d`` [m]: a depth of cut to use instead of Θ_k's (the PINN's
        d' = d + Δd); ``time_in_soil`` [s]: ``travel.time_in_soil`` (only terms on time need it).
        """
        if isinstance(known, Mapping):
            col = {n: known[n] for n in KNOWN_PARAMS}
        else:
            col = {n: known[..., i] for i, n in enumerate(KNOWN_PARAMS)}
        if d is not None:
            col["d"] = d
        return cls(**col, phi=phi, c=c, delta=delta, distance_in_soil=distance_in_soil, f_fee_x=f_fee_x, f_fee_z=f_fee_z,
                   time_in_soil=time_in_soil)

    def coerced(self) -> tuple[Any, "ForceInputs"]:
        """(xp, inputs with every given field an array of xp): with torch, scalars and NumPy
        arrays become tensors of the first tensor's dtype and device (absent fields stay None)."""
        values = {n: getattr(self, n) for n in _FIELD_NAMES}
        if not _xp.is_torch(_xp.namespace(*values.values())):
            return np, self  # NumPy takes scalars and arrays as they are: nothing to convert
        given = [n for n, v in values.items() if v is not None]
        xp, *converted = _xp.coerce(*(values[n] for n in given))
        return xp, replace(self, **dict(zip(given, converted)))


_FIELD_NAMES = tuple(f.name for f in fields(ForceInputs))
