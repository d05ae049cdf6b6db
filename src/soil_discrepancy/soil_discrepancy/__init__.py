"""Discrepancy workflow (issue 6): find where the simulation model and measured data disagree,
name the missing effect from the catalogue ``soil_physics.force_terms``, add it to the model and
show the gap shrink on held-out episodes. Never reads ground truth.

    from . import run_discrepancy
    report = run_discrepancy("bags/disc/soil_inertia", "out/disc/soil_inertia")
    report["verdict"], report["model"]["plugin_specs"]

Modules: ``baseline`` (AugmentedFEE, the analysis Frame, θ fits, residuals), ``regimes``
(episode-level tests by regime), ``candidates`` (cross-validated term scores, greedy
selection), ``gap`` (held-out before/after, the hook for other models' predictions),
``report`` (Markdown/JSON/PNG), ``workflow`` (run_discrepancy), ``cli`` (soil_discrepancy).
"""
from .baseline import (
    AugmentedFEE,
    Frame,
    ThetaFit,
    build_frame,
    distance_in_soil,
    fit_fixed,
    fit_joint,
    linear_k,
    plugin_spec,
    residuals,
    term_inputs,
)
from .candidates import TermScore, group_folds, score_terms, select_terms, split_holdout
from .gap import compare_predictions, error_metrics, fee_gap
from .regimes import bin_edges, holm, regime_analysis, trend_tests
from .report import markdown, write_outputs
from .workflow import VERDICTS, load_frame, run_discrepancy

__all__ = [
    "AugmentedFEE", "Frame", "TermScore", "ThetaFit", "VERDICTS", "bin_edges", "build_frame", "compare_predictions",
    "distance_in_soil", "error_metrics", "fee_gap", "fit_fixed", "fit_joint", "group_folds", "holm", "linear_k",
    "load_frame", "markdown", "plugin_spec", "regime_analysis", "residuals", "run_discrepancy", "score_terms",
    "select_terms", "split_holdout", "term_inputs", "trend_tests", "write_outputs",
]
