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
import importlib

# name -> the module it lives in, imported on first use: the package itself imports nothing heavy,
# so the soil_discrepancy console script (entry_points) handles Ctrl-C from its first instant
_EXPORTS = {
    "AugmentedFEE": "soil_physics.augmented_fee", "plugin_spec": "soil_physics.augmented_fee",
    **dict.fromkeys(("TermScore", "group_folds", "score_terms", "select_terms", "split_holdout"), ".candidates"),
    **dict.fromkeys(("ThetaFit", "fit_fixed", "fit_joint", "linear_k", "residuals", "term_inputs"), ".fee_fit"),
    **dict.fromkeys(("Frame", "build_frame"), ".frame"),
    **dict.fromkeys(("compare_predictions", "error_metrics", "fee_gap"), ".gap"),
    **dict.fromkeys(("bin_edges", "holm", "regime_analysis", "trend_tests"), ".regimes"),
    **dict.fromkeys(("markdown", "write_outputs"), ".report"),
    **dict.fromkeys(("SoilTest", "hold_theta", "load_soil_tests"), ".soil_tests"),
    "VERDICTS": ".verdict",
    **dict.fromkeys(("load_frame", "run_discrepancy"), ".workflow"),
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    try:
        module = _EXPORTS[name]
    except KeyError:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None
    value = getattr(importlib.import_module(module, __name__), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_EXPORTS))
