"""Reports are strict JSON: what JSON.parse (Foxglove, a browser) reads."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from soil_msgs_py.strict_json import dumps, json_safe


def _strict(text: str):
    def refuse(constant):
        raise ValueError(f"not strict JSON: {constant}")
    return json.loads(text, parse_constant=refuse)


def test_non_finite_numbers_become_null_and_numpy_values_plain_ones():
    obj = {"ratio": math.inf, "nan": float("nan"), "neg": -math.inf, "np": np.float64(2.5), "i": np.int64(3),
           "flag": np.bool_(True), "arr": np.array([1.0, np.inf]), "nested": [{"x": (np.nan, 1)}], "s": "inf"}
    back = _strict(dumps(obj))
    assert back == {"ratio": None, "nan": None, "neg": None, "np": 2.5, "i": 3, "flag": True, "arr": [1.0, None],
                    "nested": [{"x": [None, 1]}], "s": "inf"}
    assert json_safe({"a": 1.0}) == {"a": 1.0}
    with pytest.raises(ValueError):
        _strict(json.dumps({"ratio": math.inf}))  # what the plain writer gave
