"""One bearing capacity of the cutting edge (soil_physics.bearing) for the simulator's
penetration constraint and the catalogue's tip_penetration term."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from soil_msgs_py.params import DEG
from soil_physics import force_terms as X
from soil_physics.bearing import EDGE_WIDTH_M, bearing_factors, penetration_capacity
from soil_physics.force_inputs import ForceInputs


def test_bearing_factors_match_the_textbook_values_and_the_frictionless_limit():
    n_q, n_c, n_gamma = bearing_factors(np.array([30 * DEG]))
    # Vesic (1973) table at φ = 30°: N_q = 18.40, N_c = 30.14, N_γ = 22.40
    assert n_q[0] == pytest.approx(18.40, abs=0.01)
    assert n_c[0] == pytest.approx(30.14, abs=0.01)
    assert n_gamma[0] == pytest.approx(22.40, abs=0.01)
    n_q0, n_c0, n_gamma0 = bearing_factors(np.array([0.0, 1e-9]))
    np.testing.assert_allclose(n_c0, math.pi + 2.0, rtol=1e-5)  # Prandtl's undrained strip, no 0/0
    np.testing.assert_allclose(n_q0, 1.0, rtol=1e-5)
    np.testing.assert_allclose(n_gamma0, 0.0, atol=1e-5)


def test_bearing_factors_are_the_same_in_torch():
    phi = np.array([0.0, 10 * DEG, 35 * DEG])
    expected = bearing_factors(phi)
    got = bearing_factors(torch.tensor(phi, dtype=torch.float64))
    for e, g in zip(expected, got):
        np.testing.assert_allclose(g.numpy(), e, rtol=1e-12)


def _state(**over):
    base = dict(d=np.array([0.2, 0.0, -0.1]), q=0.0, v_x=0.5, v_z=0.0, gamma=18e3, w=3.164, rho=80 * DEG,
                alpha=0.0, phi=np.full(3, 27 * DEG), c=np.full(3, 10e3), delta=15 * DEG, distance_in_soil=0.0,
                f_fee_x=0.0, f_fee_z=0.0)
    return ForceInputs(**{**base, **over})


def test_penetration_capacity_and_the_tip_term_share_factors_and_edge_width():
    """capacity = tip bearing (c N_c + γ d N_q) w t_e + the edge's own weight term ½ γ t_e N_γ w t_e."""
    state = _state()
    assert state.blade_thickness == EDGE_WIDTH_M
    capacity = penetration_capacity(state)
    _, tip_z = X.CATALOGUE["tip_penetration"].basis(state)
    _, _, n_gamma = bearing_factors(state.phi)
    own_weight = 0.5 * state.gamma * EDGE_WIDTH_M * n_gamma * state.w * EDGE_WIDTH_M
    np.testing.assert_allclose(capacity[0], -tip_z[0] + own_weight[0], rtol=1e-12)
    assert capacity[1] == 0.0 and capacity[2] == 0.0 and tip_z[1] == 0.0, "no soil, no bearing"
    wider = _state(blade_thickness=2 * EDGE_WIDTH_M)
    _, tip_wide = X.CATALOGUE["tip_penetration"].basis(wider)
    assert tip_wide[0] == pytest.approx(2 * tip_z[0]), "the term bears on the state's edge width"
    assert penetration_capacity(state, 2 * EDGE_WIDTH_M)[0] == pytest.approx(penetration_capacity(wider)[0])
