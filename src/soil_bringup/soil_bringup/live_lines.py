"""The demo's live console lines: one per simulated second, estimate vs truth (pure text).

Kept apart from the rclpy monitor so the layout (<= 120 columns, deg / kPa / kN) can be
checked without a ROS graph.
"""
from __future__ import annotations

import math

import numpy as np

from soil_msgs_py.params import DEG, WINDOW_SAMPLES

from .estimate_columns import ESTIMATE_COLUMN, TRUTH_COLUMN, is_valid

# Live-line columns: (symbol, unit, SI -> unit factor, width, decimals).
PARAM_COLUMNS = (("φ", "deg", 1 / DEG, 5, 1), ("c", "kPa", 1e-3, 5, 2),
                 ("δ", "deg", 1 / DEG, 5, 1), ("β", "deg", 1 / DEG, 5, 1))
FORCE_COLUMNS = (("Fx", "kN", 1e-3, 6, 2), ("Fz", "kN", 1e-3, 6, 2))
PARAM_NAMES = {"φ": "phi", "c": "c", "δ": "delta", "β": "beta"}
PREFIX_WIDTH = 17  # "Gravel  80%  9.0s"


def _pair(est: float | None, true: float | None, width: int, nd: int) -> str:
    e = f"{est:>{width}.{nd}f}" if est is not None and math.isfinite(est) else f"{'--':>{width}}"
    t = f"{true:<{width}.{nd}f}" if true is not None and math.isfinite(true) else f"{'--':<{width}}"
    return f"{e}/{t}"


def _col_width(col) -> int:
    return 2 + 2 * col[3] + 1


def line_prefix(soil: str, i_d_pct: float, t_s: float) -> str:
    """Soil (a longer name cut with an ellipsis: "GravellySand" cut to six read "Gravel", another
    soil), I_d and time, in PREFIX_WIDTH characters."""
    name = soil if len(soil) <= 6 else soil[:5] + "…"
    return f"{name:<6} {i_d_pct:>3.0f}% {t_s:>4.1f}s"


def header_lines() -> list[str]:
    """The two header lines printed at each episode start (units, then est/true)."""
    top = " " * PREFIX_WIDTH + "".join(f"{c[0] + ' [' + c[1] + ']':^{_col_width(c)}}" for c in PARAM_COLUMNS + FORCE_COLUMNS)
    bottom = f"{'soil':<6} {'I_d':>4} {'t':>5}" + "".join(
        f"{'est / true' if c in PARAM_COLUMNS else 'pred / meas':^{_col_width(c)}}" for c in PARAM_COLUMNS + FORCE_COLUMNS)
    return [top.rstrip(), bottom.rstrip()]


def estimate_line(soil: str, i_d_pct: float, t_s: float, estimate: np.ndarray | None,
                  truth: np.ndarray | None, force: np.ndarray | None, note: str = "") -> str:
    """One live line: valid estimate vs truth, or (``estimate`` None / invalid) the window fill.

    ``estimate``: ESTIMATE_FIELDS values (SI); ``truth``: GROUND_TRUTH_PARAMS (SI); ``force``:
    measured (f_x, f_z) [N]. Printed in deg / kPa / kN."""
    out = line_prefix(soil, i_d_pct, t_s)
    valid = estimate is not None and is_valid(estimate)
    if valid:
        for sym, _, k, w, nd in PARAM_COLUMNS:
            name = PARAM_NAMES[sym]
            true = truth[TRUTH_COLUMN[name]] * k if truth is not None else None
            out += "  " + _pair(estimate[ESTIMATE_COLUMN[name]] * k, true, w, nd)
    else:
        width = sum(_col_width(c) for c in PARAM_COLUMNS)
        if note:
            text = note
        elif estimate is not None:
            text = f"filling window {int(estimate[ESTIMATE_COLUMN['window_samples']]):2d}/{WINDOW_SAMPLES}"
        else:
            text = "no estimate"
        out += f"  {text:<{width - 2}}"
    for (sym, _, k, w, nd), (fe, fm) in zip(FORCE_COLUMNS, (("f_x_hat", 0), ("f_z_hat", 1))):
        pred = estimate[ESTIMATE_COLUMN[fe]] * k if valid else None
        meas = force[fm] * k if force is not None else None
        out += "  " + _pair(pred, meas, w, nd)
    return out.rstrip()
