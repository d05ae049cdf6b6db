"""Reports as strict JSON: NaN and ±inf, which Python's json writes as bare NaN / Infinity that
JSON.parse (Foxglove, a browser, Node) refuses, become null; NumPy scalars and arrays plain numbers
and lists."""
from __future__ import annotations

import json
import math

import numpy as np


def json_safe(x):
    """``x`` with every non-finite float as None and NumPy values as Python ones (recursively)."""
    if isinstance(x, dict):
        return {k: json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [json_safe(v) for v in x]
    if isinstance(x, np.ndarray):
        return json_safe(x.tolist())
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        return float(x) if math.isfinite(x) else None
    return x


def finite_or_none(x) -> float | None:
    """A JSON-ready float: None for None, NaN and ±inf."""
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def dumps(obj, **kwargs) -> str:
    """``json.dumps`` of ``json_safe(obj)`` that refuses anything non-finite left (``allow_nan=False``)."""
    return json.dumps(json_safe(obj), allow_nan=False, **kwargs)
