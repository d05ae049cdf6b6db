"""The planner's admissibility test from two CDF values agrees with the quantile it stands for;
the forecast error law's relative part applies to what a forecast extrapolates."""
from __future__ import annotations

import numpy as np
import pytest

from soil_physics.predictive import (SE_BLOCK_ROWS, extrapolated_part, mean_standard_error, mixture_cdf, mixture_quantiles,
                                     upper_magnitude, within_magnitude)


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


def test_the_upper_magnitude_is_exceeded_with_one_minus_its_quantile_whatever_the_forces_sign():
    """A force straddling zero: the bound of |F| at q = 0.95 had been exceeded with 10 % (5 % on
    each side, an outside reviewer's); a force of one sign is bounded as by its one-sided quantile."""
    from scipy.special import ndtr

    w, sd = np.ones(1), np.array([[1000.0]])
    bound = upper_magnitude(w, np.array([[0.0]]), sd, 0.95)[0]
    assert 2 * (1 - ndtr(bound / 1000.0)) == pytest.approx(0.05, abs=1e-9)  # 1.96 sigma, not 1.645
    assert not within_magnitude(w, np.array([[0.0]]), sd, 1.7 * 1000.0, 0.95)[0]
    one_sign = upper_magnitude(w, np.array([[-10e3]]), sd, 0.95)[0]
    assert one_sign == pytest.approx(10e3 + 1.6449 * 1000.0, abs=1.0)
    assert upper_magnitude(np.ones(2), np.array([0.0, 0.0]), np.array([1.0, 1.0]), 0.5) == pytest.approx(0.6745, abs=1e-4)


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


def test_a_steady_means_standard_error_is_taken_by_batch_means():
    """The force a forecast is anchored to is a mean over a noisy steady part: its standard error by
    batch means (blocks of a stretch) is σ/√n for white noise and larger where the errors persist
    over several ticks (particle events, drift), which the rows' spread over √n would understate."""
    rng = np.random.default_rng(3)
    white = rng.normal(0.0, 300.0, size=(3000, 2))
    se = mean_standard_error(white)
    assert se == pytest.approx(300.0 / np.sqrt(3000), rel=0.3)
    slow = np.repeat(rng.normal(0.0, 300.0, size=(300, 2)), 10, axis=0)  # each error lasts 10 ticks
    assert (mean_standard_error(slow) > 2.0 * slow.std(axis=0) / np.sqrt(len(slow))).all()
    short = white[:90]  # 3 batches: too few to trust their spread, one independent value per batch
    assert mean_standard_error(short) == pytest.approx(short.std(axis=0, ddof=1) / np.sqrt(90 / SE_BLOCK_ROWS))
    assert mean_standard_error(white[:20]) == pytest.approx(white[:20].std(axis=0, ddof=1))  # less than a batch
    steady = np.tile([[1.0, 2.0]], (600, 1)) + np.tile(np.r_[np.zeros(29), 1.0][:, None], (20, 2))  # equal batches
    assert (mean_standard_error(steady) >= steady.std(axis=0, ddof=1) / np.sqrt(600) - 1e-12).all()
    assert (mean_standard_error(white[:1]) == 0.0).all()
