"""Discrepancy workflow: find where the simulation model and measured data disagree,
name the missing effect from the catalogue ``soil_physics.force_terms``, add it to the model and
show the gap shrink on held-out episodes. Never reads ground truth.

    from soil_discrepancy import run_discrepancy
    report = run_discrepancy("bags/disc/soil_inertia", "out/disc/soil_inertia")
    report["verdict"], report["model"]["plugin_specs"]

Modules: ``frame`` (the analysed ticks and their θ-groups), ``fee_fit`` (θ per group, with or
without one term's k, and residuals), ``regimes`` (episode-level tests by regime), ``candidates``
(cross-validated term scores, greedy selection), ``gap`` (held-out before/after, the hook for
other models' predictions), ``soil_tests`` (φ, c, δ measured apart from the machine hold θ where
the forces cannot), ``verdict`` (the verdict and its words), ``report`` (Markdown/JSON/PNG),
``workflow`` (run_discrepancy), ``cli`` (soil_discrepancy). The model itself, the FEE plus named
terms, is physics: ``soil_physics.augmented_fee.AugmentedFEE``.
"""
from soil_physics.augmented_fee import AugmentedFEE, plugin_spec

from .candidates import TermScore, group_folds, score_terms, select_terms, split_holdout
from .fee_fit import ThetaFit, fit_fixed, fit_joint, linear_k, residuals, term_inputs
from .frame import Frame, build_frame
from .gap import compare_predictions, error_metrics, fee_gap
from .regimes import bin_edges, holm, regime_analysis, trend_tests
from .report import markdown, write_outputs
from .soil_tests import SoilTest, hold_theta, load_soil_tests
from .verdict import VERDICTS
from .workflow import load_frame, run_discrepancy

__all__ = [
    "AugmentedFEE", "Frame", "TermScore", "ThetaFit", "VERDICTS", "bin_edges", "build_frame", "compare_predictions",
    "error_metrics", "fee_gap", "fit_fixed", "fit_joint", "group_folds", "holm", "linear_k",
    "load_frame", "markdown", "plugin_spec", "regime_analysis", "residuals", "run_discrepancy", "score_terms",
    "select_terms", "split_holdout", "term_inputs", "trend_tests", "write_outputs",
    "SoilTest", "hold_theta", "load_soil_tests",
]
