"""Soil tests: the soil's φ, c (and δ) measured apart from the machine hold θ where the forces cannot.

Why: θ is fitted to the measured force per θ-group, so an effect whose profile the FEE's own
terms can take (an adhesion ∝ c w d, a drag ∝ γ w d², a load cell's gain error) is absorbed into
θ: the forces alone then say "no significant discrepancy" and the soil estimates are wrong. No
analysis of the forces can tell such an effect from a different soil. A shear-box or triaxial
test of the same soil can: with it, θ may move only within the test's interval (value ±
``WIDTH_SIGMA`` standard deviations, the test's own uncertainty), the rest of the force is left
to the residual, and the form search no longer takes the held parameters' directions off it.

File (YAML), one entry per soil label of the bags' metadata, optionally per relative density::

    soil_tests:
      - soil: Clay                 # the bags' soil label (case-insensitive)
        relative_density_pct: 80   # optional: without it the entry holds every density of that soil
        phi_deg: 25.0              # friction angle and its standard deviation [°]
        phi_std_deg: 1.0
        c_kpa: 8.4                 # cohesion and its standard deviation [kPa]
        c_std_kpa: 0.8
        delta_deg: 20.0            # optional: soil-tool friction (interface shear test) [°]
        delta_std_deg: 1.0

Each parameter is optional; one not given stays free. SI inside.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from soil_msgs_py.params import DEG
from soil_msgs_py.soil_labels import UNKNOWN_SOIL
from soil_msgs_py.values import finite_number, short_repr, yaml_exponent

from .frame import Frame, density_label
from soil_msgs_py.yaml_file import read_yaml

WIDTH_SIGMA = 2.0  # θ may move ± this many of a test's standard deviations (its ~95 % interval)
# the share of tested parameters whose truth lies outside ± WIDTH_SIGMA std (a Gaussian test error)
OUTSIDE_BY_CHANCE = math.erfc(WIDTH_SIGMA / math.sqrt(2.0))
# parameter: (value key, std key, SI per unit of the file); the order is θ's (φ, c, δ)
_FIELDS = (("phi", "phi_deg", "phi_std_deg", DEG), ("c", "c_kpa", "c_std_kpa", 1e3),
           ("delta", "delta_deg", "delta_std_deg", DEG))
_KEYS = {"soil", "relative_density_pct"} | {k for _, v, s, _ in _FIELDS for k in (v, s)}
# A tested cohesion above this [kPa] is refused as a unit slip (Pa given as kPa): stiff clays reach a
# few hundred kPa (this project's soils and tests at most 50 kPa, the fused posterior's prior 60 kPa);
# 1 MPa is a weak rock's.
MAX_COHESION_KPA = 1000.0
# θ as reports and errors give it: (name, unit, per SI unit), in θ's order (φ, c, δ)
DISPLAY_UNITS = (("phi", "°", math.degrees(1.0)), ("c", "Pa", 1.0), ("delta", "°", math.degrees(1.0)))


@dataclass(frozen=True)
class SoilTest:
    """One soil's test results (SI): value and standard deviation per parameter, NaN where not tested."""

    soil: str
    relative_density_pct: float | None  # None: every density of the soil
    value: tuple[float, float, float]  # φ [rad], c [Pa], δ [rad]
    std: tuple[float, float, float]

    def box(self) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi) SI per parameter: value ± WIDTH_SIGMA std (c at least 0); ±inf where not tested."""
        v, s = np.array(self.value), np.array(self.std)
        held = np.isfinite(v)
        lo = np.where(held, v - WIDTH_SIGMA * s, -np.inf)
        hi = np.where(held, v + WIDTH_SIGMA * s, np.inf)
        lo[1] = max(lo[1], 0.0) if held[1] else lo[1]
        return lo, hi

    def matches(self, soil: str, relative_density_pct: float) -> bool:
        if soil.casefold() != self.soil.casefold():
            return False
        return self.relative_density_pct is None or (
            math.isfinite(relative_density_pct) and abs(relative_density_pct - self.relative_density_pct) < 1e-6)


def _number(where: str, key: str, value, *, positive: bool = False, lo: float | None = None, hi: float | None = None) -> float:
    value = yaml_exponent(value)  # (PyYAML reads 1e0 as a string)
    if not finite_number(value):
        raise ValueError(f"{where}.{key}={short_repr(value)} is not a finite number")
    x = float(value)
    if positive and not x > 0.0:
        raise ValueError(f"{where}.{key}={short_repr(value)} must be > 0 (a test's standard deviation)")
    if (lo is not None and x < lo) or (hi is not None and x > hi):
        raise ValueError(f"{where}.{key}={short_repr(value)} outside [{-math.inf if lo is None else lo:g}, "
                         f"{math.inf if hi is None else hi:g}]")
    return x


def parse_soil_tests(data, source: str = "soil tests") -> tuple[SoilTest, ...]:
    """``SoilTest`` entries from the YAML's content; ValueError naming the entry, key and value."""
    rows = data.get("soil_tests") if isinstance(data, dict) else None
    if not isinstance(rows, list) or not rows:
        raise ValueError(f"{source}: expected a mapping with a non-empty list 'soil_tests'")
    out, seen = [], set()
    for i, row in enumerate(rows):
        where = f"{source}: soil_tests[{i}]"
        if not isinstance(row, dict):
            raise ValueError(f"{where} is {short_repr(row)}, not a mapping")
        unknown = sorted(set(map(str, row)) - _KEYS)
        if unknown:
            raise ValueError(f"{where}: unknown key(s) {unknown}; known: {sorted(_KEYS)}")
        soil = row.get("soil")
        if not isinstance(soil, str) or not soil.strip():
            raise ValueError(f"{where}.soil={short_repr(soil)} is not a soil label")
        i_d = row.get("relative_density_pct")
        i_d = None if i_d is None else _number(where, "relative_density_pct", i_d, lo=0.0, hi=100.0)
        value, std = [math.nan] * 3, [math.nan] * 3
        for j, (name, vkey, skey, unit) in enumerate(_FIELDS):
            if (vkey in row) != (skey in row):
                raise ValueError(f"{where}: '{vkey}' and '{skey}' go together (a test result and its standard deviation)")
            if vkey in row:
                for key, what in ((vkey, "cohesion"), (skey, "standard deviation")) if name == "c" else ():
                    if finite_number(row[key]) and float(row[key]) > MAX_COHESION_KPA:  # beyond any soil: a unit slip
                        raise ValueError(f"{where}.{key}={short_repr(row[key])} kPa is beyond any soil (more than "
                                         f"{MAX_COHESION_KPA:g} kPa, a weak rock's): a {what} in Pa? "
                                         f"{float(row[key]):g} Pa is {float(row[key]) / 1e3:g} kPa")
                value[j] = _number(where, vkey, row[vkey], lo=0.0, hi=90.0 if unit == DEG else None) * unit
                std[j] = _number(where, skey, row[skey], positive=True) * unit
        if not any(math.isfinite(v) for v in value):
            raise ValueError(f"{where} ({soil}) gives no parameter: phi_deg, c_kpa or delta_deg")
        key = (soil.strip().casefold(), i_d)
        if key in seen:
            raise ValueError(f"{where}: a second entry for {soil}" + ("" if i_d is None else f" at I_d {i_d:g} %"))
        seen.add(key)
        out.append(SoilTest(soil.strip(), i_d, tuple(value), tuple(std)))
    return tuple(out)


def load_soil_tests(path) -> tuple[SoilTest, ...]:
    """``parse_soil_tests`` of a YAML file; ValueError naming the file and the bad entry."""
    p = Path(path)
    return parse_soil_tests(read_yaml(p, "soil tests"), f"soil tests {p}")


def hold_theta(frame: Frame, tests) -> Frame:
    """The frame with ``theta_boxes`` set for every θ-group whose episodes' soil label (and relative
    density) a test matches: {group: (lo, hi)} SI. A test of one density wins over one of every density.
    ValueError if no group matches (the labels are named): tests that hold nothing are a mistake."""
    boxes = {g: t.box() for g, t in _chosen(frame, tests).items()}
    if not boxes:
        seen = sorted({f"{s} {density_label(d)}" if math.isfinite(d) else s for s, d in zip(frame.soils, frame.densities)})
        raise ValueError(f"no soil test matches a soil of the bags (their labels: {', '.join(seen[:12])}); "
                         "soil tests need bags whose metadata gives a soil label (and a density, for a test of one "
                         "density), grouped by it (not by --group-by gamma or episode)")
    return replace(frame, theta_boxes=boxes)


def _chosen(frame: Frame, tests) -> dict[int, SoilTest]:
    """{θ-group: the test that holds it}: a group of one soil label (and density) a test matches; a
    test of one density wins over one of every density."""
    out = {}
    for g in np.unique(frame.group_of):
        label = group_label(frame, int(g))
        if label is None:
            continue
        soil, i_d = label
        found = [t for t in tests if t.matches(soil, i_d)]
        if found:
            out[int(g)] = min(found, key=lambda t: t.relative_density_pct is None)
    return out


def group_label(frame: Frame, group: int) -> tuple[str, float] | None:
    """The one (soil label, relative density [%]) of θ-group ``group``'s episodes, which a soil test
    can match; None where they have none (bags without a soil label) or several (grouped by γ)."""
    labels = {(frame.soils[e], frame.densities[e]) for e in np.flatnonzero(frame.group_of == group)}
    if len(labels) != 1:
        return None
    (soil, i_d), = labels
    return None if soil == UNKNOWN_SOIL else (soil, i_d)


def unmatched(frame: Frame, tests) -> list[str]:
    """The tests that hold no θ-group of ``frame``, as the user wrote them: a mistyped soil or
    density, a soil only in groups of several soils, a test of every density that one of a
    density beats wherever it matches (said, not dropped in silence)."""
    used = {id(t) for t in _chosen(frame, tests).values()}
    return [t.soil + (f" {density_label(t.relative_density_pct)}" if t.relative_density_pct is not None else "")
            for t in tests if id(t) not in used]


def displayed_box(lo: np.ndarray, hi: np.ndarray) -> list:
    """A test's interval (SI) per parameter in ``DISPLAY_UNITS`` ([lo, hi]); None where it holds nothing."""
    return [[float(a) * u, float(b) * u] if math.isfinite(a) or math.isfinite(b) else None
            for a, b, (_, _, u) in zip(lo, hi, DISPLAY_UNITS)]


def held_parameters(frame: Frame) -> np.ndarray:
    """(N, 3) bool per tick: which of φ, c, δ a soil test holds in its θ-group."""
    held = np.zeros((len(frame), 3), bool)
    for g, (lo, hi) in (frame.theta_boxes or {}).items():
        held[frame.group == g] = np.isfinite(lo) | np.isfinite(hi)
    return held
