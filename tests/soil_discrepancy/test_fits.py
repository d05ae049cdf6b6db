"""The discrepancy fits' numerical choices give the answers of the plain ones they replace.

A joint fit of θ per group with a term's k solves each step exactly (dense) up to a size and
iteratively (sparse) above it: both must find the hidden k and fit the data alike. The one-sided
Wilcoxon of hundreds of forms at once must give each the p it gets alone, to the bit.
"""
from __future__ import annotations

import numpy as np
import pytest

from soil_discrepancy import build_frame, fit_fixed, fit_joint
from soil_discrepancy import fee_fit
from soil_discrepancy.candidates import paired_test, paired_tests
from soil_physics.augmented_fee import AugmentedFEE
from soil_physics.soils import CATALOGUE as SOILS
from soil_sim_node.batch import grid_specs

from .test_discrepancy import simulated


def test_the_joint_fit_finds_the_hidden_k_solving_exactly_or_iteratively(monkeypatch):
    """A hidden rate-dependent strength (rate_strength) on 8 episodes of 2 soils: the dense step
    (these fits are far below its bound) and the sparse one (above it) both find the hidden k and
    fit the data alike. Their θ may differ where φ and c trade off at one depth: not compared."""
    specs = grid_specs(list(SOILS)[:2], [20.0, 80.0], [0.3, 1.0], [0.25], 1, seed_base=0, duration_s=6.0)
    frame = build_frame(simulated(specs, ("soil_physics.force_terms:plugin term=rate_strength k=8000",)), stride=8)
    model = AugmentedFEE()
    base = fit_fixed(frame, model)
    fits, costs = {}, {}
    for bound in (fee_fit._DENSE_SVD_WORK, 0.0):  # the shipped bound, then always sparse
        monkeypatch.setattr(fee_fit, "_DENSE_SVD_WORK", bound)
        fits[bound] = fit = fit_joint(frame, model, "rate_strength", base)
        r, _ = fee_fit.residuals(frame, model.with_term("rate_strength", fit.k), fit)
        costs[bound] = float(((r / fee_fit.FORCE_SCALE_N) ** 2).sum())
    (dense, sparse), (dense_cost, sparse_cost) = fits.values(), costs.values()
    assert dense.k == pytest.approx(8000, rel=0.05) and sparse.k == pytest.approx(8000, rel=0.05)
    assert dense.k == pytest.approx(sparse.k, rel=2e-3)
    assert dense_cost == pytest.approx(sparse_cost, rel=1e-3)
    assert all(dense.success.values()) and all(sparse.success.values())


def test_the_wilcoxon_of_many_rows_at_once_is_each_rows_own_to_the_bit():
    rng = np.random.default_rng(5)
    own = rng.gamma(2.0, 1.0, 32)
    rows = own * rng.lognormal(0.05, 0.3, (200, 32))  # continuous: one call for all of them
    rows[0] = own  # every difference zero
    rows[1, :5] = own[:5]  # some zero
    rows[2, :2] = own[:2] + 0.5  # a tie in |d|
    rows[2, 2:4] = own[2:4] - 0.5
    rows[3, 7] = np.nan
    rows[4, :] = own + 1.0  # all tied
    wide = rng.gamma(2.0, 1.0, (3, 60))  # over 50 episodes: the normal approximation
    for before, after in ((rows, own), (own, rows), (wide, wide[::-1]), (rows[:, :1], own[:1])):
        got = paired_tests(before, after)
        b, a = np.broadcast_arrays(np.atleast_2d(before), np.atleast_2d(after))
        want = np.array([paired_test(x, y) for x, y in zip(b, a)])
        assert got.shape == want.shape
        assert np.array_equal(got.view(np.int64), want.view(np.int64))
    assert paired_tests(rows, own)[0] == 1.0 and paired_tests(rows, own)[3] < 1.0


def test_the_reports_header_says_the_folds_that_ran_and_counts_groups_in_words():
    """Cross-validation runs at most one fold per selection group: with 3 groups and --folds 5 the
    header said "5 folds" (an outside tester's), and "1 groups" for a single held-out group."""
    from soil_discrepancy.report import _folds_used, _groups

    assert _folds_used(5, 3) == "3 folds (5 asked: at most one per selection group)"
    assert _folds_used(5, 8) == "5 folds" and _folds_used(3, 3) == "3 folds"
    assert (_groups(1), _groups(4)) == ("1 group", "4 groups")
