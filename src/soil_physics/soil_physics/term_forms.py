"""Candidate *forms* of a missing force: a scale (a force in N) times a dimensionless factor or gate.

The catalogue (``force_terms.CATALOGUE``) holds named mechanisms, each one fixed form. When none of
them explains a residual, the discrepancy workflow (``soil_discrepancy.forms``) searches this
library of forms for the few that do. A form is named

    form:<scale>*<factor>        e.g.  form:gd2w_z*sink   ΔF_z = k · (−γ d² w) · [v_z < 0]
    form:-<scale>*<factor>       the same with the opposite sign (so that k >= 0)

and is a force term like any catalogue term: ``force_terms.get_term('form:…')`` gives its
``Term`` (basis, formula, units), so ``AugmentedFEE``, the simulator plugin
(``soil_physics.force_terms:plugin term=form:… k=…``) and the PINN's extra term take it as they
take a catalogue term. Every scale is a force [N] with a direction (x, z or along the FEE force);
every factor is dimensionless (reference values below), so k is dimensionless throughout.

Only what a model built from Θ_k sees is used (``ForceInputs.from_known``): d, Q, v_x, v_z, γ, w,
ρ, the model's θ and FEE force, the blade's travel in soil s and its time in soil τ
(``travel``: both integrated from Θ_k, tick by tick). A form on τ is told from one on s across
speeds (s = ∫ v_x dt). SI units.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

from . import xp as _xp
from .bearing import edge_bearing_n
from soil_msgs_py.params import FORCE_LIMITS_N, GRAVITY_M_S2

PREFIX = "form:"
P_REF_PA = 10e3  # reference pressure of the c-free geometric scale w d · P_REF [Pa]
V_REF_M_S = 1.0  # reference forward speed [m/s]
VZ_REF_M_S = 0.05  # reference vertical speed [m/s] (the blade's lift/sink speeds are a few cm/s)
D_REF_M = 0.1  # reference depth [m]
VZ_GATE_M_S = 0.005  # |v_z| below this is "not moving vertically" (measurement jitter)
FX_LIMIT_N, FZ_LIMIT_N = FORCE_LIMITS_N  # the machine's horizontal / vertical force limits [N]
LIMIT_SHARE = 0.9  # "at a force limit": the model's force above this share of the limit
LAYER_DEPTHS_M = (0.1, 0.15, 0.2)  # tops of the layers the library tries [m] (a cut reaches 0.3 m)
T_REF_S = 10.0  # reference time in soil [s] (an episode of the datasets is 10 s)
F_REF_N = 1e3  # reference force of the constant scales [N]


@dataclass(frozen=True)
class Piece:
    name: str
    words: str  # what it is, in words
    formula: str  # with units
    fn: Callable[[Any, Any], Any]  # (inputs, xp) -> array (scale: a force [N]; factor: dimensionless)
    axis: str = ""  # scales only: 'x', 'z', 'fee' (F_FEE times fn) or 'vec' (fn gives (F_x, F_z))


_pos = _xp.positive_part


def _in(s):
    return (s.d > 0) * 1.0


def _time(s):
    """τ [s]: the inputs' time in soil; a clear error where a model was not given it."""
    if s.time_in_soil is None:
        raise ValueError("this form looks at the time in soil: give the model time_in_soil "
                         "(soil_physics.travel.time_in_soil of the episode)")
    return s.time_in_soil


def _surcharge_part(s, xp):
    """(F_x, F_z) [N] of the FEE's surcharge term Q N_Q: the FEE at Q minus the FEE at Q = 0."""
    from .fee import fee_xz  # the one FEE (NumPy or torch)

    theta = {n: getattr(s, n) for n in ("phi", "c", "delta", "gamma", "rho", "alpha", "w", "d", "q", "v_x", "v_z")}
    theta["c_a"] = s.c_a if s.c_a is not None else 0.0 * s.d
    fx1, fz1, _ = fee_xz(theta)
    fx0, fz0, _ = fee_xz({**theta, "q": 0.0 * s.q})
    keep = _in(s) * (s.q > 0)
    return xp.where(keep > 0, fx1 - fx0, 0.0 * s.d), xp.where(keep > 0, fz1 - fz0, 0.0 * s.d)


def momentum_flux_n(s, xp):
    """(γ/g) w d v_x² [N]: the momentum the blade gives the soil it cuts per second, d and v_x
    counted where positive (a blade backing up throws no soil forward). The catalogue's
    ``soil_inertia`` and the form library's ``mom_x`` scale."""
    return s.gamma / GRAVITY_M_S2 * s.w * _pos(xp, s.d) * _pos(xp, s.v_x) ** 2


# Scales: (name, words, formula, fn, axis). z scales point down (blade pressing on the floor) where
# that is their physics; the sign of k decides the rest through the '-' prefix.
SCALES: dict[str, Piece] = {p.name: p for p in (
    Piece("fee", "the model's FEE force", "F_FEE (both axes)", lambda s, xp: 1.0, "fee"),
    Piece("feex", "the model's FEE force, x", "F_FEE,x", lambda s, xp: s.f_fee_x, "x"),
    Piece("feez", "the model's FEE force, z", "F_FEE,z", lambda s, xp: s.f_fee_z, "z"),
    Piece("gd2w_x", "soil weight scale γ d² w, x", "γ d² w", lambda s, xp: s.gamma * _pos(xp, s.d) ** 2 * s.w, "x"),
    Piece("gd2w_z", "soil weight scale γ d² w, pressing down", "−γ d² w",
          lambda s, xp: -s.gamma * _pos(xp, s.d) ** 2 * s.w, "z"),
    Piece("wd_x", "c-free area scale w d P_ref, x", f"w d · {P_REF_PA:g} Pa",
          lambda s, xp: s.w * _pos(xp, s.d) * P_REF_PA, "x"),
    Piece("wd_z", "c-free area scale w d P_ref, pressing down", f"−w d · {P_REF_PA:g} Pa",
          lambda s, xp: -s.w * _pos(xp, s.d) * P_REF_PA, "z"),
    # the soil's cohesion over the cut face: an adhesion, a cohesion that depends on rate or
    # remoulding (the FEE's own cohesion terms are c d w N_c-like; θ's c takes the rest of it)
    Piece("cwd_x", "cohesion area scale c w d, x", "c w d", lambda s, xp: s.c * s.w * _pos(xp, s.d), "x"),
    Piece("cwd_z", "cohesion area scale c w d, pressing down", "−c w d", lambda s, xp: -s.c * s.w * _pos(xp, s.d), "z"),
    Piece("mom_x", "momentum flux of the cut soil (γ/g) w d v_x², x", "(γ/g) w d v_x²",
          momentum_flux_n, "x"),
    Piece("q_x", "surcharge weight Q, x", "Q", lambda s, xp: s.q * _in(s), "x"),
    Piece("q_z", "surcharge weight Q, pressing down", "−Q", lambda s, xp: -s.q * _in(s), "z"),
    Piece("qnq", "the FEE's surcharge part Q N_Q (along the FEE force)", "(F_FEE(Q) − F_FEE(Q = 0))",
          _surcharge_part, "vec"),
    Piece("bear_z", "bearing capacity of the cutting edge, pressing down",
          "−w t_e (c N_c + γ d N_q)", lambda s, xp: -edge_bearing_n(s, xp), "z"),
    Piece("bear_x", "bearing capacity of the cutting edge, x (friction on it)",
          "w t_e (c N_c + γ d N_q)", lambda s, xp: edge_bearing_n(s, xp), "x"),
    Piece("down_x", "the model's downward push max(−F_FEE,z, 0), x (friction on it)",
          "max(−F_FEE,z, 0)", lambda s, xp: _pos(xp, -s.f_fee_z) * _in(s), "x"),
    # a force that does not scale with the soil or the cut (the sparse regression's constant
    # term): a side plate rubbing, a drag of the machine's own, a sensor offset while cutting;
    # times tanh(v_x/v0) it is Coulomb friction, times exp(−v_x/v0) the static friction a moving
    # part loses (Stribeck)
    Piece("one_x", "a constant force, x", f"{F_REF_N:g} N", lambda s, xp: F_REF_N * _in(s), "x"),
    Piece("one_z", "a constant force, pressing down", f"−{F_REF_N:g} N", lambda s, xp: -F_REF_N * _in(s), "z"),
)}

# Factors and gates: dimensionless. Gates are 0/1.
FACTORS: dict[str, Piece] = {p.name: p for p in (
    [Piece("1", "always (while in soil)", "1", lambda s, xp: _in(s)),
     Piece("vx", "forward speed", f"v_x / {V_REF_M_S:g} m/s", lambda s, xp: _pos(xp, s.v_x) / V_REF_M_S),
     Piece("vx2", "forward speed squared", f"(v_x / {V_REF_M_S:g} m/s)²", lambda s, xp: (s.v_x / V_REF_M_S) ** 2),
     Piece("d", "depth", f"d / {D_REF_M:g} m", lambda s, xp: _pos(xp, s.d) / D_REF_M),
     Piece("s", "travel in soil", "s / 1 m", lambda s, xp: s.distance_in_soil),
     Piece("sink", "only while the edge sinks", f"[v_z < −{VZ_GATE_M_S:g} m/s]",
           lambda s, xp: (s.v_z < -VZ_GATE_M_S) * 1.0),
     Piece("rise", "only while the edge rises", f"[v_z > {VZ_GATE_M_S:g} m/s]",
           lambda s, xp: (s.v_z > VZ_GATE_M_S) * 1.0),
     Piece("still", "only while the edge holds its depth", f"[|v_z| ≤ {VZ_GATE_M_S:g} m/s]",
           lambda s, xp: (xp.abs(s.v_z) <= VZ_GATE_M_S) * 1.0),
     Piece("sinkv", "sinking speed", f"max(−v_z, 0) / {VZ_REF_M_S:g} m/s", lambda s, xp: _pos(xp, -s.v_z) / VZ_REF_M_S),
     Piece("risev", "lifting speed", f"max(v_z, 0) / {VZ_REF_M_S:g} m/s", lambda s, xp: _pos(xp, s.v_z) / VZ_REF_M_S),
     # signed in v_z: one column for a force against (or with) the edge's vertical motion either way,
     # a viscous damping or a friction saturating above the reference speed, where sinkv and risev
     # would split it into two halves, each with its own k (and θ, which takes the entry's sinking in,
     # makes those two differ)
     Piece("vz", "vertical speed (signed, + rising)", f"v_z / {VZ_REF_M_S:g} m/s", lambda s, xp: s.v_z / VZ_REF_M_S * _in(s)),
     Piece(f"tanhvz{VZ_REF_M_S:g}", f"vertical speed (signed, + rising), saturating above {VZ_REF_M_S:g} m/s",
           f"tanh(v_z / {VZ_REF_M_S:g} m/s)", lambda s, xp: xp.tanh(s.v_z / VZ_REF_M_S) * _in(s)),
     Piece("xlim", "at the horizontal force limit", f"[F_FEE,x > {LIMIT_SHARE:g}·{FX_LIMIT_N:g} N]",
           lambda s, xp: (s.f_fee_x > LIMIT_SHARE * FX_LIMIT_N) * 1.0),
     Piece("zlim", "at the vertical force limit", f"[|F_FEE,z| > {LIMIT_SHARE:g}·{FZ_LIMIT_N:g} N]",
           lambda s, xp: (xp.abs(s.f_fee_z) > LIMIT_SHARE * FZ_LIMIT_N) * 1.0)]
    + [Piece(f"tanhvx{v0:g}", f"forward speed, saturating above {v0:g} m/s", f"tanh(v_x / {v0:g} m/s)",
             (lambda v0: lambda s, xp: xp.tanh(_pos(xp, s.v_x) / v0))(v0)) for v0 in (0.1, 0.3, 1.0)]
    # a strength the moving blade loses, fading with speed (rate weakening, Stribeck-like static
    # friction). At 0.3 m/s a decay the saturating forms cannot take once θ absorbs their constant
    # (over 0.3-1 m/s it falls off faster than tanh(v_x/1 m/s) and slower than tanh(v_x/0.3 m/s)).
    # At 0.1 and 1 m/s it is, over those speeds, −tanh(v_x/v0) plus a constant (correlation 0.9997+):
    # on a scale θ absorbs the two are nearly one column, on Q or a constant force
    # the fading form is a saturating drag *and* a relief, which a held-out test must then confirm
    + [Piece(f"fadevx{v0:g}", f"fading with forward speed (over ~{v0:g} m/s)", f"exp(−v_x / {v0:g} m/s)",
             (lambda v0: lambda s, xp: xp.exp(-_pos(xp, s.v_x) / v0) * _in(s))(v0)) for v0 in (0.1, 0.3, 1.0)]
    + [Piece(f"enter{s0:g}", f"while the blade enters the soil (first ~{s0:g} m)", f"exp(−s / {s0:g} m)",
             (lambda s0: lambda s, xp: xp.exp(-s.distance_in_soil / s0) * _in(s))(s0)) for s0 in (0.5, 2.0)]
    + [Piece(f"sat{s0:g}", f"growing with travel, saturating over {s0:g} m", f"1 − exp(−s / {s0:g} m)",
             (lambda s0: lambda s, xp: (1.0 - xp.exp(-s.distance_in_soil / s0)) * _in(s))(s0)) for s0 in (2.0, 6.0)]
    # time in soil τ: an effect that builds up or fades while the blade is loaded, whatever its speed
    + [Piece("tau", "time in soil", f"τ / {T_REF_S:g} s", lambda s, xp: _time(s) / T_REF_S * _in(s))]
    + [Piece(f"tenter{t0:g}", f"while the blade is new in the soil (first ~{t0:g} s)", f"exp(−τ / {t0:g} s)",
             (lambda t0: lambda s, xp: xp.exp(-_time(s) / t0) * _in(s))(t0)) for t0 in (1.0, 3.0)]
    + [Piece(f"tsat{t0:g}", f"growing with time in soil, saturating over {t0:g} s", f"1 − exp(−τ / {t0:g} s)",
             (lambda t0: lambda s, xp: (1.0 - xp.exp(-_time(s) / t0)) * _in(s))(t0)) for t0 in (3.0, 10.0)]
    # a layer: the share of the cut face deeper than d0 (a hard pan, a wetter or denser stratum);
    # w d P_ref times it is w (d − d0)+ P_ref, the face area in the layer times a pressure
    + [Piece(f"below{d0:g}", f"the share of the cut deeper than {d0:g} m (a layer there)", f"(d − {d0:g} m)+ / d",
             (lambda d0: lambda s, xp: _pos(xp, s.d - d0) / _xp.clip_min(xp, s.d, 1e-6) * _in(s))(d0))
       for d0 in LAYER_DEPTHS_M]
)}


# factors that are one shape at several characteristic values (a speed, a length, a time, a depth)
SHAPE_FAMILIES = ("tanhvx", "tanhvz", "fadevx", "enter", "sat", "tenter", "tsat", "below")


def factor_shape(factor: str) -> str:
    """A factor's shape without its characteristic value: 'enter0.5' and 'enter2' are both 'enter'."""
    for shape in SHAPE_FAMILIES:
        if factor.startswith(shape) and factor[len(shape):].replace(".", "", 1).isdigit():
            return shape
    return factor


DISTANCE_FACTORS = frozenset(n for n in FACTORS if n == "s" or n.startswith(("enter", "sat")))  # look at travel s
TIME_FACTORS = frozenset(n for n in FACTORS if n == "tau" or n.startswith(("tenter", "tsat")))  # look at time τ


def factor_variable(factor: str) -> str | None:
    """The measured variable a factor's shape is a function of, as the discrepancy workflow's regime
    analysis names it ('d', 'v_x', 'v_z', 'distance', 't' for time), None for a constant or a gate on
    the model's force. Structure left in that variable once the form is in the model says the
    library's shape is near the effect's, not it."""
    shape = factor_shape(factor)
    if factor in DISTANCE_FACTORS:
        return "distance"
    if factor in TIME_FACTORS:
        return "t"
    if factor == "d" or shape == "below":
        return "d"
    if factor in ("vx", "vx2") or shape in ("tanhvx", "fadevx"):
        return "v_x"
    if factor in ("sink", "rise", "still", "sinkv", "risev", "vz") or shape == "tanhvz":
        return "v_z"
    return None


# The measured variables each scale varies with (beyond the soil's own γ, c, φ), in
# ``factor_variable``'s names: the surcharge Q grows with travel and time in soil, the FEE's force
# with all of them. Where a form's factor varies with one of its scale's variables, the two make
# one law of that variable, and a set of rivals keeping one scale (or one factor) pins that law
# down, not the scale (or the factor) apart from it: a speed step's drag was named
# (γ/g) w d v_x² · (v_x / 1 m/s)², "its scale is pinned down", because no w d scale with a v_x⁴-like
# factor is in the library, not because the drag was a momentum flux.
_MOTION = ("d", "v_x", "v_z", "distance", "t")
SCALE_VARIABLES: dict[str, tuple[str, ...]] = {
    "fee": _MOTION, "feex": _MOTION, "feez": _MOTION, "qnq": _MOTION, "down_x": _MOTION,
    "gd2w_x": ("d",), "gd2w_z": ("d",), "wd_x": ("d",), "wd_z": ("d",), "cwd_x": ("d",), "cwd_z": ("d",),
    "bear_z": ("d",), "bear_x": ("d",), "mom_x": ("d", "v_x"),
    "q_x": ("distance", "t"), "q_z": ("distance", "t"), "one_x": (), "one_z": ()}


def separable(scale: str, factor: str) -> bool:
    """True if the factor's shape is a function of none of the variables the scale varies with
    (``SCALE_VARIABLES``): only then can data pin down the one without the other."""
    return factor_variable(factor) not in SCALE_VARIABLES[scale]


def uses_distance(name: str) -> bool:
    """True if the form looks at the blade's travel in soil (a model must be given it)."""
    return parse(name)[2].name in DISTANCE_FACTORS


def uses_time(name: str) -> bool:
    """True if the form looks at the blade's time in soil (a model must be given it)."""
    return parse(name)[2].name in TIME_FACTORS


# The constant scales go with the factors that make a force of the machine's own of them (a
# constant, viscous, Coulomb or Stribeck friction), not with the soil's geometry or the edge's gates: a
# constant times "the share of the cut below 0.1 m" is no mechanism, and with that freedom a
# hidden deep drag was named as a catalogue term plus such a relief, confirmed by the held-out
# force error while the forecast at another depth stayed 53 % off.
CONSTANT_SCALE_FACTORS = ("1", "vx", "tanhvx0.1", "tanhvx0.3", "tanhvx1", "fadevx0.1", "fadevx0.3", "fadevx1")
# The cohesion scale goes with a cohesion's own variations: none (an adhesion), with the shear rate
# (viscous, saturating, lost with speed), with depth, while the edge sinks or rises (suction), lost
# on entry or with time in soil (remoulding). All 30 factors made a case with a named term ~13 %
# slower (each named term faces every form, on two parts) for forms that θ's c absorbs unless soil
# tests hold it.
COHESION_SCALE_FACTORS = ("1", "vx", "d", "sink", "rise", "tanhvx0.3", "fadevx0.3", "enter2", "tenter3")
SCALE_FACTORS = {"one_x": CONSTANT_SCALE_FACTORS, "one_z": CONSTANT_SCALE_FACTORS,
                 "cwd_x": COHESION_SCALE_FACTORS, "cwd_z": COHESION_SCALE_FACTORS}


def form_names(scales=None, factors=None) -> list[str]:
    """Every 'form:<scale>*<factor>' of the library (both signs are the same column; '+' only);
    a scale of ``SCALE_FACTORS`` only with its factors there (``parse`` takes any pair)."""
    return [f"{PREFIX}{a}*{b}" for a in (scales or SCALES) for b in (factors or FACTORS)
            if b in SCALE_FACTORS.get(a, (b,))]


def parse(name: str) -> tuple[float, Piece, Piece]:
    """'form:[-]<scale>*<factor>' -> (sign, scale, factor); ValueError naming what is wrong."""
    if not isinstance(name, str) or not name.startswith(PREFIX):
        raise ValueError(f"form {name!r} must look like '{PREFIX}<scale>*<factor>'")
    body = name[len(PREFIX):]
    sign = -1.0 if body.startswith("-") else 1.0
    if body.startswith("--"):  # ('--' read as one minus had been a second name of the same term, past every repeat check)
        raise ValueError(f"form {name!r} must look like '{PREFIX}[-]<scale>*<factor>': one '-' at most")
    a, sep, b = body.removeprefix("-").partition("*")
    if not sep:
        raise ValueError(f"form {name!r} must look like '{PREFIX}<scale>*<factor>' (no '*')")
    if a not in SCALES:  # the part that is wrong, named first
        raise ValueError(f"form {name!r}: scale {a!r} is not one of {sorted(SCALES)}"
                         + ("" if b in FACTORS else f"; nor is factor {b!r} one of {sorted(FACTORS)}"))
    if b not in FACTORS:
        raise ValueError(f"form {name!r}: factor {b!r} is not one of {sorted(FACTORS)} (scale {a!r} is known)")
    return sign, SCALES[a], FACTORS[b]


def negated(name: str) -> str:
    sign, a, b = parse(name)
    return f"{PREFIX}{'' if sign < 0 else '-'}{a.name}*{b.name}"


def basis(name: str, s, xp) -> tuple[Any, Any]:
    """(B_x, B_z) [N per unit k] of a form on ``ForceInputs`` ``s`` (coerced, namespace ``xp``)."""
    sign, a, b = parse(name)
    if a.axis == "vec":
        vx, vz = a.fn(s, xp)
        f = sign * b.fn(s, xp)
        return f * vx, f * vz
    mag = sign * a.fn(s, xp) * b.fn(s, xp) + 0.0 * s.d
    zero = 0.0 * s.d
    if a.axis == "x":
        return mag, zero
    if a.axis == "z":
        return zero, mag
    return mag * s.f_fee_x, mag * s.f_fee_z


def describe(name: str) -> dict:
    """Title, formula and words of a form (for ``force_terms.Term`` and the report)."""
    sign, a, b = parse(name)
    # A z scale carries its own sign (pressing down, "−γ d² w"): folded into k's, so a relief
    # reads "k · γ d² w", not "−k · −γ d² w".
    scale_negative = a.formula.startswith("−")
    scale_formula = a.formula[1:] if scale_negative else a.formula
    sgn = "−" if (sign < 0) != scale_negative else ""
    axis = {"x": "F_x", "z": "F_z", "fee": "F", "vec": "F"}[a.axis]
    # a factor that is a difference ("1 − exp(−s / 2 m)") is one factor of the product: bracketed
    factor = "" if b.name == "1" else f" · ({b.formula})" if b.formula.startswith("1 − ") else f" · {b.formula}"
    if sign < 0 and a.words.endswith(", pressing down"):  # likewise in words
        words = f"{a.words.removesuffix(', pressing down')}, pushing up, {b.words}"
    else:
        words = f"{'minus ' if sign < 0 else ''}{a.words}, {b.words}"
    return {"title": words, "formula": f"{axis} = {sgn}k · {scale_formula}{factor}  [N]",
            "words": words, "axis": a.axis, "scale": a.name, "factor": b.name, "sign": sign,
            "gate": b.name in ("sink", "rise", "still", "xlim", "zlim")}


def proposed_name(name: str) -> str:
    """A readable default name for a discovered form the user can change."""
    sign, a, b = parse(name)
    return f"{b.words} × {a.words}" + (" (relief)" if sign < 0 else "")


__all__ = ["PREFIX", "SCALES", "FACTORS", "SHAPE_FAMILIES", "factor_shape", "DISTANCE_FACTORS", "TIME_FACTORS", "uses_distance", "uses_time", "form_names", "parse", "negated", "basis", "describe", "proposed_name"]
