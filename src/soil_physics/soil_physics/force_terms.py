"""Named candidate effects the FEE lacks: one catalogue for the simulator, the model and the PINN.

The discrepancy workflow (``soil_discrepancy``) looks for the physics a model of earthmoving is missing.
Each candidate here is a documented force term, linear in one coefficient k:

    ΔF = k · B(inputs)        B = (B_x, B_z) [N per unit of k], force of the blade ON the soil,
                                x forward, z up (the sign convention of /blade/force)

so it can be fitted to force residuals by least squares (with an uncertainty), added to the
FEE model with its fitted k (``apply``), switched on in the simulator as an effect plugin
(``plugin``: ``soil_physics.force_terms:plugin term=<name> k=<value>``) and given to the
PINN as an extra physics term. ``basis`` works on NumPy arrays and torch tensors alike (like
``fee``), so this is the one implementation of each term.

Every term looks at a ``ForceInputs`` (``force_inputs``), the simulator's vocabulary too. All
a term uses is available from a measured episode without ground truth
(``ForceInputs.from_known``): Θ_k (d, Q, v, γ, w, ρ, α), the soil parameters φ, c, δ of the
model being corrected (fitted per episode, or the PINN's estimates), the model's own FEE
force, and the blade's travel and time in soil integrated from v_x and d (``travel``).
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from . import term_forms
from . import xp as _xp
from .bearing import EDGE_WIDTH_M, edge_bearing_n
from .fee import beta_star, force_xz
from .force_inputs import ForceInputs
from soil_msgs_py.params import TABLE1
from soil_msgs_py.values import short_repr


@dataclass(frozen=True)
class Term:
    """One candidate effect: ΔF = k · B(inputs)."""

    name: str
    title: str
    formula: str  # human-readable, with units
    k_unit: str  # unit of the coefficient k
    k_nominal: float  # a physically typical k (scale for reports and tests)
    physics: str  # why the FEE misses it
    basis_fn: Callable[[ForceInputs, Any], tuple[Any, Any]]
    k_max: float = math.inf  # the largest k the mechanism can have (``implausible_k``)
    k_max_why: str = ""  # that bound in words, for a report
    # the measured variable ('v_x', 'd', ...: ``term_forms.factor_variable``) whose factor the form claims
    # beyond what the FEE's θ can take: data holding it at too few levels cannot tell that factor from
    # another (the discrepancy workflow); a library form's is its factor's
    factor_variable: str | None = None
    # the force's axes the term acts on ("x", "z" or "xz"; the others' part is identically zero): a
    # report says of a term of x alone that it has no z part to blame
    axes: str = "xz"

    def basis(self, inputs: ForceInputs) -> tuple[Any, Any]:
        """(B_x, B_z) [N per unit k], NumPy or torch like the inputs (scalars broadcast)."""
        xp, inputs = inputs.coerced()
        return self.basis_fn(inputs, xp)


_pos = _xp.positive_part


def _zeros(xp, like):
    return 0.0 * like


def _inertia(s: ForceInputs, xp):
    return term_forms.momentum_flux_n(s, xp), _zeros(xp, s.d)


def side_wall_force(phi, c, gamma, delta, rho, alpha, d, k0=None, walls: float = 2.0):
    """(f_x, f_z) [N] of the side-wall shear of a finite-width blade's wedge (McKyes 1985).

    A_side = d²(cot ρ + cot β*)/2 per wall, τ = c + K0 γ (d/3) tan φ (K0 = 1 − sin φ, Jaky, if
    ``k0`` is None), transmitted to the blade like the FEE's failure-plane cohesion,
    F = walls · A_side τ cos φ / sin η, along the FEE force direction (90° − ρ − δ + α from x).
    Zero out of the soil. NumPy or torch; the one implementation (the catalogue term and the
    example plugin ``soil_sim_node.plugins_example`` use it).
    """
    xp, phi, c, gamma, delta, rho, alpha, d = _xp.coerce(phi, c, gamma, delta, rho, alpha, d)
    depth = _pos(xp, d)
    beta = beta_star(phi, delta, rho, alpha)
    ok = xp.isfinite(beta) & (d > 0)
    beta = xp.where(ok, beta, 0.5 + 0.0 * beta)
    area = depth**2 * (1.0 / xp.tan(rho) + 1.0 / xp.tan(beta)) / 2.0
    k = 1.0 - xp.sin(phi) if k0 is None else k0
    tau = c + k * gamma * depth / 3.0 * xp.tan(phi)
    eta = delta + rho + phi + beta
    force = xp.where(ok, walls * area * tau * xp.cos(phi) / xp.sin(eta), 0.0 * depth)
    return force_xz(force, rho, delta, alpha)


def _side_walls(s: ForceInputs, xp):  # noqa: ARG001 - side_wall_force picks its own namespace
    return side_wall_force(s.phi, s.c, s.gamma, s.delta, s.rho, s.alpha, s.d)


def _tip_bearing(s: ForceInputs, xp):
    return _zeros(xp, s.d), -edge_bearing_n(s, xp)  # the edge presses down on the floor


def _surcharge_drag(s: ForceInputs, xp):
    return s.q * (s.d > 0), _zeros(xp, s.d)


def _rate_strength(s: ForceInputs, xp):
    return s.w * _pos(xp, s.d) * _pos(xp, s.v_x), _zeros(xp, s.d)


def _compaction(s: ForceInputs, xp):
    return s.distance_in_soil * s.f_fee_x, s.distance_in_soil * s.f_fee_z


def _base_friction(s: ForceInputs, xp):
    return _pos(xp, -s.f_fee_z) * (s.d > 0), _zeros(xp, s.d)


# A Coulomb friction of soil on soil or on steel is at most tan φ (δ <= φ), and Table 1's soils reach
# φ 45°: a friction-type term (base friction, a pile pushed along the ground) with a larger k is not that
# mechanism but a stand-in taking another effect's force (two effects hidden at once: a base
# friction of k 2.29 was named beside them).
FRICTION_K_MAX = math.tan(TABLE1["phi"].norm[1])
_FRICTION_WHY = f"a friction coefficient above tan {math.degrees(TABLE1['phi'].norm[1]):.0f}° = {FRICTION_K_MAX:.2f}, Table 1's steepest φ"

CATALOGUE: dict[str, Term] = {
    t.name: t
    for t in (
        Term("soil_inertia", "inertial acceleration of the cut soil",
             "F_x = k (γ/g) w d v_x²  [N]", "1", 1.0,
             "the FEE is quasi-static: the soil entering the wedge is accelerated to blade speed, "
             "a momentum flux that grows with v_x²", _inertia, factor_variable="v_x", axes="x"),
        Term("side_wall_shear", "side-wall shear of a finite-width blade",
             "F = k · 2 A_side τ cos φ / sin η along the FEE force, A_side = d²(cot ρ + cot β*)/2, "
             "τ = c + (1 − sin φ) γ d/3 tan φ  [N]", "1", 1.0,
             "the FEE is plane strain; a blade of finite width also shears the two side faces of the "
             "wedge (McKyes 1985)", _side_walls),
        Term("tip_penetration", "blade-tip penetration (bearing) resistance",
             "F_z = −k w t_e (c N_c + γ d N_q), N_q = e^{π tan φ} tan²(45° + φ/2), N_c = (N_q − 1) cot φ, "
             f"t_e = {EDGE_WIDTH_M:g} m  [N]", "1", 1.0,
             "the FEE's blade has no thickness; a real edge bears on the floor it cuts", _tip_bearing, axes="z"),
        Term("surcharge_drag", "surcharge contribution beyond the FEE's Q N_Q",
             "F_x = k Q  [N]", "1", 0.3,
             "the pile in front of the blade is pushed along the ground, not only lifted with the wedge",
             _surcharge_drag, FRICTION_K_MAX, _FRICTION_WHY, axes="x"),
        Term("rate_strength", "rate-dependent (viscous) strength",
             "F_x = k w d v_x  [N]", "Pa·s/m", 5e3,
             "soil shear strength rises with the shear rate; the FEE's strength is rate-free",
             _rate_strength, factor_variable="v_x", axes="x"),
        Term("compaction_hardening", "compaction hardening with distance travelled",
             "F = k s F_FEE, s = blade travel in soil since the start  [N]", "1/m", 0.05,
             "the soil ahead is compacted by the pass, so its strength grows with distance cut",
             _compaction),
        Term("base_friction", "friction under the blade base",
             "F_x = k max(−F_z^FEE, 0)  [N]", "1", 0.3,
             "the downward push of the blade is carried by the cut floor under its base, which "
             "slides with Coulomb friction μ = k", _base_friction, FRICTION_K_MAX, _FRICTION_WHY, axes="x"),
    )
}


def get_term(name: str) -> Term:
    """A catalogue term by name, or a library form 'form:<scale>*<factor>' (``term_forms``)."""
    if isinstance(name, str) and name.startswith(term_forms.PREFIX):
        return _form_term(name)
    try:
        return CATALOGUE[name]
    except KeyError:
        raise ValueError(f"effect term={name!r} is not one of {sorted(CATALOGUE)} "
                         f"nor a form '{term_forms.PREFIX}<scale>*<factor>'") from None


@functools.lru_cache(maxsize=1024)
def _form_term(name: str) -> Term:
    info = term_forms.describe(name)  # ValueError naming the bad scale/factor
    return Term(name, info["title"], info["formula"], "1", 1.0,
                "a form found by sparse regression over the library of candidate forms (soil_discrepancy.forms)",
                functools.partial(_form_basis, name), factor_variable=term_forms.factor_variable(info["factor"]),
                axes=info["axis"] if info["axis"] in ("x", "z") else "xz")


def _form_basis(name: str, s: ForceInputs, xp):
    return term_forms.basis(name, s, xp)


DISTANCE_TERMS = frozenset({"compaction_hardening"})  # catalogue terms that look at the travel in soil


def uses_distance(name: str) -> bool:
    """True if term ``name`` (catalogue or form) looks at the blade's travel in soil (``distance_in_soil``)."""
    get_term(name)
    if name.startswith(term_forms.PREFIX):
        return term_forms.uses_distance(name)
    return name in DISTANCE_TERMS


def uses_time(name: str) -> bool:
    """True if term ``name`` looks at the blade's time in soil (``time_in_soil``): some forms do,
    no catalogue term."""
    get_term(name)
    return name.startswith(term_forms.PREFIX) and term_forms.uses_time(name)


def parse_terms(specs) -> tuple[tuple[str, float], ...]:
    """'name=k' strings (or (name, k) pairs) -> ((name, k), ...); ValueError naming the bad one."""
    out = []
    for spec in specs or ():
        if isinstance(spec, str):
            name, sep, value = spec.partition("=")
            if not sep:
                raise ValueError(f"effect term {spec!r} must look like 'name=k', e.g. 'soil_inertia=2.0'")
        else:
            name, value = spec
        if not isinstance(name, str):
            raise ValueError(f"effect term {short_repr(spec)}: its name {short_repr(name)} must be a text, e.g. 'soil_inertia'")
        get_term(name.strip())
        try:
            k = float(value)
        except OverflowError:  # an integer of hundreds of digits (JSON and YAML have no bound)
            k = math.inf
        except (TypeError, ValueError):
            raise ValueError(f"effect term {name}: k={short_repr(value)} is not a number") from None
        if not math.isfinite(k):
            raise ValueError(f"effect term {name}: k={short_repr(value)} must be finite")
        out.append((name.strip(), k))
    return tuple(out)


def refuse_repeats(terms, where: str = "") -> None:
    """ValueError naming a term given twice in ``terms`` ((name, k) pairs), after ``where: ``: a
    model sums every entry, so 'soil_inertia=1,soil_inertia=2' would silently mean k = 3."""
    names = [n for n, _ in terms]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise ValueError(f"{where}: " * bool(where) + f"effect term {twice[0]} is given more than once")


def implausible_k(name: str, k: float) -> str:
    """Words for a fitted k beyond what the term's mechanism can have ('' within it, and for a library
    form, which has no such bound): such a term fits the force as a stand-in for another effect."""
    term = get_term(name)
    if not abs(float(k)) > term.k_max:
        return ""
    return f"k = {float(k):.3g} is beyond what {term.title} can be ({term.k_max_why})"


def term_texts(terms) -> list[str]:
    """(name, k) pairs -> 'name=k' strings that ``parse_terms`` reads back exactly (k by repr)."""
    return [f"{name}={float(k)!r}" for name, k in terms]


def apply(terms, inputs: ForceInputs) -> tuple[Any, Any]:
    """Σ k · B over ``terms`` ((name, k) pairs): the force to add to the model's FEE force [N]."""
    fx = fz = 0.0 * inputs.d
    for name, k in terms:
        bx, bz = get_term(name).basis(inputs)
        fx, fz = fx + k * bx, fz + k * bz
    return fx, fz


def plugin(state, term: str, k: float):
    """Simulator effect plugin: the catalogue term ``term`` with coefficient ``k`` [N].

    ``SimConfig(plugins=["soil_physics.force_terms:plugin term=soil_inertia k=2.0"])`` switches
    on in the simulator exactly the term the discrepancy workflow fits and the model adds.
    ``state`` is the simulator's ``ForceInputs`` (its own soil and FEE force).
    """
    (name, k), = parse_terms([(term, k)])
    bx, bz = get_term(name).basis(state)
    return k * np.asarray(bx, dtype=float), k * np.asarray(bz, dtype=float)
