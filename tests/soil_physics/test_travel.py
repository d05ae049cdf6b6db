"""Blade travel in soil, one definition (soil_physics.travel)."""
from __future__ import annotations

import numpy as np
import pytest

from soil_msgs_py.params import KNOWN_PARAMS
from soil_physics.travel import TICK_S, distance_in_soil, distance_in_soil_of_known, soil_advance


def test_advance_is_forward_travel_with_the_blade_in_soil():
    np.testing.assert_array_equal(soil_advance([0.6, -0.3, 0.6], [0.1, 0.1, 0.0]), [0.6 * TICK_S, 0.0, 0.0])
    assert soil_advance(0.5, 0.2, dt=0.1) == pytest.approx(0.05)


def test_distance_of_known_rows_is_the_distance_of_their_v_x_and_d_columns():
    known = np.zeros((4, len(KNOWN_PARAMS)))
    known[:, KNOWN_PARAMS.index("v_x")] = [0.6, 0.6, -0.2, 0.3]
    known[:, KNOWN_PARAMS.index("d")] = [0.1, 0.0, 0.1, 0.2]
    np.testing.assert_array_equal(
        distance_in_soil_of_known(known),
        distance_in_soil(known[:, KNOWN_PARAMS.index("v_x")], known[:, KNOWN_PARAMS.index("d")]),
    )
    np.testing.assert_allclose(distance_in_soil_of_known(known, dt=1.0), [0.6, 0.6, 0.6, 0.9])
    assert distance_in_soil_of_known(np.zeros((0, len(KNOWN_PARAMS)))).shape == (0,)
    assert distance_in_soil_of_known(np.zeros(0)).shape == (0,)
    with pytest.raises(ValueError, match="Θ_k rows"):
        distance_in_soil_of_known(np.zeros((3, 2)))
