"""The planner's admissibility test from two CDF values agrees with the quantile it stands for;
the forecast error law's relative part applies to what a forecast extrapolates."""
from __future__ import annotations

import numpy as np
import pytest

from soil_physics.predictive import extrapolated_part, mixture_cdf, mixture_quantiles, upper_magnitude, within_magnitude


@pytest.mark.parametrize("seed", range(5))
def test_within_magnitude_is_upper_magnitude_below_the_limit(seed):
    rng = np.random.default_rng(seed)
    w = rng.random(64)
    mu = rng.normal(0.0, 8e3, (40, 64)) + rng.normal(0.0, 5e3, (40, 1))
    sd = rng.uniform(50.0, 4e3, (40, 64))
    for q in (0.5, 0.9, 0.95):
        upper = upper_magnitude(w, mu, sd, q)
        for limit in np.quantile(upper, [0.1, 0.5, 0.9]):
            clear = np.abs(upper - limit) > 1e-6 * limit  # (a quantile found by bisection ties at the limit)
            np.testing.assert_array_equal(within_magnitude(w, mu, sd, limit, q)[clear], (upper <= limit)[clear])


def test_mixture_cdf_inverts_the_quantiles():
    rng = np.random.default_rng(7)
    w, mu, sd = rng.random(16), rng.normal(0, 1e3, (3, 16)), rng.uniform(10, 500, (3, 16))
    q = mixture_quantiles(w, mu, sd, (0.05, 0.5, 0.95))
    for i, level in enumerate((0.05, 0.5, 0.95)):
        np.testing.assert_allclose(mixture_cdf(w, mu, sd, q[i]), level, atol=1e-9)


def test_the_extrapolated_part_is_the_change_from_the_evidence_capped_by_the_force_itself():
    force = np.array([10e3, 10e3, -4e3, 6e3, 5e3])
    ref = np.array([10e3, 4e3, 2e3, np.nan, -20e3])  # at the evidence; NaN: no evidence there
    cap = np.array([10e3, 10e3, -4e3, 6e3, 3e3])
    np.testing.assert_allclose(extrapolated_part(force, ref, cap), [0.0, 6e3, 4e3, 6e3, 3e3])
