"""ForceInputs: one vocabulary for the simulator's effects, plugins and the catalogue terms,
built from a model's Θ_k, θ, travel in soil and FEE force by one constructor."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from soil_msgs_py.params import KNOWN_PARAMS
from soil_physics import force_terms as X
from soil_physics.force_inputs import ForceInputs

RNG = np.random.default_rng(0)
KNOWN = np.column_stack([
    np.full(5, 2e3),  # c_a
    np.full(5, 17e3),  # gamma
    np.full(5, 1.4),  # rho
    np.zeros(5),  # alpha
    np.full(5, 3.164),  # w
    np.array([0.2, 0.1, 0.0, 0.15, -0.02]),  # d
    RNG.uniform(0, 5e3, 5),  # q
    RNG.uniform(0, 1, 5),  # v_x
    RNG.uniform(-0.1, 0.1, 5),  # v_z
])
MODEL = dict(phi=np.full(5, 0.5), c=np.full(5, 3e3), delta=np.full(5, 0.3), distance_in_soil=np.linspace(0, 2, 5),
             f_fee_x=RNG.uniform(0, 2e4, 5), f_fee_z=RNG.uniform(-5e3, 5e3, 5))


def test_from_known_reads_every_known_column_by_name():
    assert len(KNOWN_PARAMS) == KNOWN.shape[1]
    inputs = ForceInputs.from_known(KNOWN, **MODEL)
    for i, name in enumerate(KNOWN_PARAMS):
        np.testing.assert_array_equal(getattr(inputs, name), KNOWN[:, i])
    for name, value in MODEL.items():
        assert getattr(inputs, name) is value
    assert inputs.t is None and inputs.x_b is None and inputs.relative_density_pct is None, "simulator-only"
    mapped = ForceInputs.from_known({n: KNOWN[:, i] for i, n in enumerate(KNOWN_PARAMS)}, **MODEL)
    for name in KNOWN_PARAMS:
        np.testing.assert_array_equal(getattr(mapped, name), getattr(inputs, name))
    d_prime = KNOWN[:, KNOWN_PARAMS.index("d")] + 0.01
    assert ForceInputs.from_known(KNOWN, **MODEL, d=d_prime).d is d_prime


@pytest.mark.parametrize("name", sorted(X.CATALOGUE))
def test_torch_inputs_give_the_numpy_terms(name):
    bx, bz = X.CATALOGUE[name].basis(ForceInputs.from_known(KNOWN, **MODEL))
    as_t = {k: torch.tensor(v, dtype=torch.float64) for k, v in MODEL.items()}
    tx, tz = X.CATALOGUE[name].basis(ForceInputs.from_known(torch.tensor(KNOWN), **as_t))
    np.testing.assert_allclose(tx.numpy(), bx, rtol=1e-12)
    np.testing.assert_allclose(tz.numpy(), bz, rtol=1e-12)


def test_coerced_turns_scalars_into_tensors_and_keeps_absent_fields():
    inputs = ForceInputs.from_known(torch.tensor(KNOWN, dtype=torch.float32), **{**MODEL, "c": 3e3})
    xp, out = inputs.coerced()
    assert xp is torch
    assert isinstance(out.c, torch.Tensor) and out.c.dtype == torch.float32
    assert isinstance(out.blade_thickness, torch.Tensor)
    assert out.t is None and out.dt is None
