"""Example user force plugin: side-wall shear of a finite-width blade.

Use it without editing the simulator::

    SimConfig(plugins=["soil_sim_node.plugins_example:side_wall_shear"])
    SimConfig(plugins=[{"target": "soil_sim_node.plugins_example:side_wall_shear",
                        "params": {"k0": 0.5, "walls": 2}}])

Plugin contract (``soil_sim_node.effects``): called once per physics substep as
``fn(state, **params)`` with a ``ForceInputs`` (arrays of shape (B,), SI units); returns
``(f_x, f_z)``, the extra force the blade exerts ON the soil [N], x forward, z up.

Physics
-------
The FEE (paper Eq. 2) is a plane-strain (2-D) wedge: per metre of blade it ignores the two
side faces of the failing soil wedge. A real blade of finite width w also has to shear the
soil along these two vertical side walls (McKyes 1985, "Soil cutting and tillage", ch. 4:
the side "crescent" forces). This plugin adds that resistance with the simplest wedge-side
model:

* Each side wall is the wedge's cross-section, a triangle between the blade (angle rho to
  the surface) and the failure plane (angle beta), of depth d:

      A_side = d^2 (cot(rho) + cot(beta)) / 2                               [m^2]

  (level surface, alpha = 0; beta = beta* of Eq. 7 for the state's phi, delta, rho, alpha).
* The shear strength on it is Mohr-Coulomb with the at-rest lateral stress at the
  triangle's centroid depth d/3:

      tau = c + K0 gamma (d / 3) tan(phi),   K0 = 1 - sin(phi) (Jaky)       [Pa]

* The shear force on both walls, S = walls * A_side * tau [N], resists the wedge sliding
  out along the failure plane, exactly like the cohesion on the failure plane does. Wedge
  equilibrium transmits a failure-plane shear force T to the blade as T cos(phi) / sin(eta),
  eta = delta + rho + phi + beta (the FEE's own cohesion term: c d w N_c =
  c (w d / sin beta) cos(phi) / sin(eta)). So the extra blade force is

      F_side = walls * A_side * tau * cos(phi) / sin(eta)                  [N]

  acting along the FEE force direction (paper Eq. 8), at 90 deg - rho - delta + alpha from x:

      f_x = F_side cos(90 deg - rho - delta + alpha),  f_z = F_side sin(...)   [N]

It is zero when the blade is out of the soil (d <= 0). Size: dense Clay (c = 10 kPa,
phi = 27 deg) at d = 0.25 m gives f_x ~ 2.4 kN, ~7 % on top of the 3.164 m wide blade's FEE
force (37 kN, delta = 15 deg); loose Sand ~0.1 kN.
Uses the nominal delta (no velocity correction) for beta, eta and the direction.
"""
from __future__ import annotations

import math
import numbers

# The formula lives in the catalogue of candidate effects (one implementation, NumPy and torch).
from soil_physics.force_terms import side_wall_force  # noqa: F401 - re-exported


def side_wall_shear(state, k0: float | None = None, walls: float = 2.0):
    """Plugin entry point: side-wall shear of the wedge of a finite-width blade [N].

    Parameters (``params`` in the plugin spec): ``k0`` lateral earth-pressure coefficient
    (default Jaky's 1 - sin phi), ``walls`` number of shearing side walls (default 2).
    """
    for name, value in (("k0", k0), ("walls", walls)):
        if name == "k0" and value is None:
            continue
        if isinstance(value, bool) or not isinstance(value, numbers.Real) or not (math.isfinite(value) and value >= 0):
            raise ValueError(f"{name}={value!r} must be a finite number >= 0")
    return side_wall_force(state.phi, state.c, state.gamma, state.delta, state.rho, state.alpha, state.d, k0, walls)
