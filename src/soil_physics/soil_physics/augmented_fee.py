"""The FEE on Θ_k arrays, alone or with named catalogue terms: F = F_FEE(θ, Θ_k) + Σ_j k_j B_j.

One NumPy evaluation of the model a fit, a simulator plugin and a PINN agree on: θ = (φ, c, δ)
is the soil, Θ_k the known parameters per tick (``KNOWN_PARAMS`` order), β = β* (paper Eq. 7)
with the Eq. 9-10 velocity correction, and each term ΔF = k·B from ``force_terms`` sees the
same inputs as the simulator's effect plugin, so ``AugmentedFEE.plugin_specs()`` switches the
same model on in the simulator. SI throughout (rad, Pa, m, N; force of the blade on the soil).
"""
from __future__ import annotations

from typing import Mapping

import numpy as np

from soil_msgs_py.params import KNOWN_PARAMS, UNKNOWN_PARAMS

from . import fee
from . import force_terms
from .force_inputs import ForceInputs

THETA_PARAMS: tuple[str, ...] = UNKNOWN_PARAMS[:3]  # ("phi", "c", "delta"): the soil θ the FEE takes
PLUGIN_TARGET = f"{force_terms.__name__}:{force_terms.plugin.__name__}"  # the simulator side of a term


def fee_forces(phi, c, delta, known) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """FEE (F_x, F_z) [N] per tick and whether it is defined.

    phi, c, delta broadcast against known[..., 0] (e.g. (K, 1) against (T,)); ``known`` may also
    be a mapping of the KNOWN_PARAMS names, each broadcasting on its own (β* then costs what
    φ, δ, ρ and α need: a planner's samples at many depths compute it once per sample). beta =
    beta* per tick with the Eq. 9-10 velocity correction, as the PINN's FEE layer does. Out of
    the soil (d <= 0) the force is exactly 0 whatever beta* is (the library's FEE would give
    0 * NaN there); ``defined`` is False only where d > 0 and beta* does not exist.
    """
    theta = _known_columns(known)
    theta.update(phi=phi, c=c, delta=delta)
    with np.errstate(all="ignore"):  # invalid beta* candidates are masked inside beta_star
        fx, fz, _ = fee.fee_xz(theta)
    in_soil = theta["d"] > 0
    fx = np.where(in_soil, fx, 0.0)
    fz = np.where(in_soil, fz, 0.0)
    defined = np.isfinite(fx) & np.isfinite(fz)
    return fx, fz, defined


def plugin_spec(name: str, k: float) -> str:
    """``soil_physics.force_terms:plugin term=<name> k=<k>``: the simulator side of a term."""
    force_terms.get_term(name)
    return f"{PLUGIN_TARGET} term={name} k={k:.6g}"


class AugmentedFEE:
    """The FEE model with named catalogue terms: F = F_FEE(θ, Θ_k) + Σ_j k_j B_j(inputs).

    ``terms`` are (name, k) pairs or 'name=k' strings (``force_terms.parse_terms``). The terms'
    inputs are θ, Θ_k, the model's own FEE force and the blade's travel in soil, as in the
    simulator's effect plugin, so ``plugin_specs()`` switches on the same model in the simulator.
    """

    def __init__(self, terms=()):
        self.terms: tuple[tuple[str, float], ...] = force_terms.parse_terms(terms)

    def __repr__(self) -> str:
        return f"AugmentedFEE(terms={self.terms!r})"

    def __eq__(self, other) -> bool:
        return isinstance(other, AugmentedFEE) and self.terms == other.terms

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(n for n, _ in self.terms)

    def with_term(self, name: str, k: float) -> "AugmentedFEE":
        """A new model with ``name`` added (or its k replaced)."""
        kept = [(n, v) for n, v in self.terms if n != name]
        return AugmentedFEE(kept + [(name, float(k))])

    def plugin_specs(self) -> list[str]:
        """Simulator plugin specs that switch the same terms on (``soil_sim_batch --plugin ...``)."""
        return [plugin_spec(n, k) for n, k in self.terms]

    def extra_term_args(self) -> list[str]:
        """``name=k`` strings, e.g. for ``pinn_train --extra-term``."""
        return [f"{n}={k:.6g}" for n, k in self.terms]

    # -- evaluation
    @staticmethod
    def fee(theta, known) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pure FEE (F_x, F_z, defined): see ``fee_forces`` (0 out of the soil)."""
        phi, c, delta = _theta_tuple(theta)
        return fee_forces(phi, c, delta, known)

    @property
    def needs_time(self) -> bool:
        """True if a term looks at the time in soil (``force``'s ``time_in_soil`` is then required)."""
        return any(force_terms.uses_time(n) for n in self.names)

    @staticmethod
    def inputs(theta, known, distance, f_fee_x, f_fee_z, time_in_soil=None) -> ForceInputs:
        """What every catalogue term may look at, per tick (θ, Θ_k, travel in soil [m], F_FEE [N],
        time in soil [s] if given)."""
        phi, c, delta = _theta_tuple(theta)
        return ForceInputs.from_known(
            _known_columns(known), phi=phi, c=c, delta=delta,
            distance_in_soil=np.asarray(distance, dtype=float), f_fee_x=f_fee_x, f_fee_z=f_fee_z,
            time_in_soil=None if time_in_soil is None else np.asarray(time_in_soil, dtype=float),
        )

    def basis(self, name: str, theta, known, distance, time_in_soil=None) -> tuple[np.ndarray, np.ndarray]:
        """(B_x, B_z) [N per unit k] of one catalogue term for this θ (0 where the FEE is undefined)."""
        return self.bases([name], theta, known, distance, time_in_soil)[0]

    def bases(self, names, theta, known, distance, time_in_soil=None) -> list[tuple[np.ndarray, np.ndarray]]:
        """``basis`` of each of ``names`` at one θ: the FEE and the terms' inputs are computed once
        (a search over hundreds of forms spent most of its time recomputing them per form)."""
        fx, fz, ok = self.fee(theta, known)
        inputs = self.inputs(theta, known, distance, fx, fz, time_in_soil)
        out = []
        for name in names:
            with np.errstate(all="ignore"):
                bx, bz = force_terms.get_term(name).basis(inputs)
            bx, bz = np.broadcast_arrays(np.asarray(bx, float), np.asarray(bz, float))
            good = ok & np.isfinite(bx) & np.isfinite(bz)
            out.append((np.where(good, bx, 0.0), np.where(good, bz, 0.0)))
        return out

    def force(self, theta, known, distance, with_defined: bool = False, time_in_soil=None):
        """Model force (F_x, F_z) [N, blade on soil] per tick; NaN where the FEE is undefined.

        theta: mapping with phi, c, delta (rad, Pa, rad) or a (phi, c, delta) tuple, arrays that
        broadcast against the ticks; known: (..., 9) Θ_k in KNOWN_PARAMS order or a mapping of
        those names; distance: blade travel in soil [m] per tick (``travel.distance_in_soil``);
        time_in_soil: [s] per tick (``travel.time_in_soil``), required if ``needs_time``.
        """
        fx, fz, ok = self.fee(theta, known)
        if self.terms:
            with np.errstate(all="ignore"):
                dx, dz = force_terms.apply(self.terms, self.inputs(theta, known, distance, fx, fz, time_in_soil))
            fx, fz = fx + dx, fz + dz
            ok = ok & np.isfinite(fx) & np.isfinite(fz)
        fx = np.where(ok, fx, np.nan)
        fz = np.where(ok, fz, np.nan)
        return (fx, fz, ok) if with_defined else (fx, fz)


def _theta_tuple(theta):
    if isinstance(theta, Mapping):
        return tuple(np.asarray(theta[n], dtype=float) for n in THETA_PARAMS)
    phi, c, delta = theta
    return np.asarray(phi, float), np.asarray(c, float), np.asarray(delta, float)


def _known_columns(known) -> dict[str, np.ndarray]:
    """Θ_k as name -> array: a mapping's values as given (not broadcast against each other), or
    the columns of an (..., 9) array in KNOWN_PARAMS order."""
    if isinstance(known, Mapping):
        return {n: np.asarray(known[n], dtype=float) for n in KNOWN_PARAMS}
    known = np.asarray(known, dtype=float)
    return {n: known[..., i] for i, n in enumerate(KNOWN_PARAMS)}
