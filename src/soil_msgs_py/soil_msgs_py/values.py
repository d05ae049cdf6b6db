"""One value from a user or a message: is it a finite number, how to show it in an error, and the
few spellings a file format gives a number (no ROS, no NumPy).

Every check that names a bad value says it with ``short_repr`` (a 400-digit number stays
readable), judges it with ``finite_number`` (no OverflowError for a JSON integer too large for a
float), and reads YAML's exponents with ``yaml_exponent``.
"""
from __future__ import annotations

import math
import numbers
import re


# No value a graph node publishes or a bag holds comes near this in SI (forces ~1e5 N, cohesion
# ~1e5 Pa, unit weight ~2e4 N/m³, positions ~1e3 m): one beyond it is a fault's or an intruder's.
PLAUSIBLE_ABS_LIMIT = 1e9


def plain_zero(value):
    """``value`` with a float −0.0 as 0.0 (anything else as it is, checked where it is used): a
    user's "-0" had named a bag ``id-00`` beside the ``id000`` of the same grid point, and a
    report "Sand -0 %"."""
    return 0.0 if isinstance(value, float) and value == 0.0 else value


def short_repr(value, most: int = 40) -> str:
    """``repr(value)`` cut to ``most`` characters: a 400-digit number from a JSON message stays
    readable in the error that names it."""
    text = repr(value)
    return text if len(text) <= most else f"{text[:most]}... ({len(text)} characters)"


_EXPONENT_FLOAT = re.compile(r"^[-+]?(\d+\.?\d*|\.\d+)[eE][-+]?\d+$")


def yaml_exponent(value):
    """A YAML text such as ``16e3`` or ``1e0`` as the number it means (YAML 1.1, which PyYAML reads,
    takes an exponent without a dot for a string); any other value unchanged."""
    return float(value) if isinstance(value, str) and _EXPONENT_FLOAT.match(value) else value


def finite_number(value) -> bool:
    """A real number (not a bool) that is finite; False, not OverflowError, for an integer too
    large for a float (JSON has no bound on integers)."""
    if not isinstance(value, numbers.Real) or isinstance(value, bool):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:  # an integer too large for a float (hundreds of digits in a JSON command)
        return False


def number_in(name: str, value, lo: float, hi: float, *, lo_open: bool = False, hi_open: bool = False,
              what: str = "a number", unit: str = "", note: str = "") -> float:
    """``value`` as a float if it is a finite real number (not a bool) within [lo, hi] (an end
    excluded where ``lo_open`` / ``hi_open``); else ValueError "<name>=<value> must be <what> in
    (lo, hi]<unit><note>", naming the parameter as the user wrote it."""
    inside = finite_number(value) and (lo < value if lo_open else lo <= value) and (value < hi if hi_open else value <= hi)
    if not inside:
        ends = f"{'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"
        raise ValueError(f"{name}={short_repr(value)} must be {what} in {ends}{unit}{note}")
    return float(value)
