"""The demo's figure: per episode φ̂ vs φ, ĉ vs c and F̂ vs F against time (``online_estimates.png``).

Beside the PINN's estimate of each window (dots), φ and c of the soil fused along the path, as
``/soil/estimate`` carries it (its mean, and mean ± 1.645 std, the published 90 % interval): what a
planner reads, and the window's scatter alone had shown a user no estimate with its uncertainty."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from soil_msgs_py.cli_paths import save_figure_atomically
from soil_msgs_py.params import DEG

from .estimate_columns import ESTIMATE_COLUMN, TRUTH_COLUMN
from .scoring import Z90, EpisodeScore


def plot(scores: list[EpisodeScore], path: Path) -> Path:
    """``draw(scores)`` saved to ``path``."""
    import matplotlib.pyplot as plt

    fig = draw(scores)
    path.parent.mkdir(parents=True, exist_ok=True)
    save_figure_atomically(fig, path, dpi=80)
    plt.close(fig)
    return path


def _fused_band(ax, t: np.ndarray, estimates: np.ndarray, name: str, scale: float, color: str,
                lowest: float = -np.inf) -> None:
    """The fused mean of ``name`` and its 90 % band (mean ± Z90·std, not below ``lowest``: c ≥ 0,
    where the topic's mean and std are a Gaussian's summary of a posterior bounded at 0) where the
    posterior is valid; gaps where it is not (no stretch learnt yet) stay gaps."""
    valid = estimates[:, ESTIMATE_COLUMN["fused_valid"]] == 1.0
    if not valid.any():
        return
    mean = np.where(valid, estimates[:, ESTIMATE_COLUMN[f"{name}_fused"]], np.nan) * scale
    std = np.where(valid, estimates[:, ESTIMATE_COLUMN[f"{name}_std"]], np.nan) * scale
    ax.fill_between(t, np.maximum(mean - Z90 * std, lowest), mean + Z90 * std, color=color, alpha=0.25, lw=0,
                    label="fused, 90 %")
    ax.plot(t, mean, color=color, lw=1.0, label="fused mean")


def draw(scores: list[EpisodeScore]):
    """Per episode three small panels: φ̂ vs φ, ĉ vs c (each with the fused soil), F̂ vs F (x and z)
    against time. Returns the matplotlib figure."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(scores)
    ncols = min(4, n)
    groups = math.ceil(n / ncols)
    fig, axes = plt.subplots(3 * groups, ncols, figsize=(3.6 * ncols + 0.4, 2.0 * 3 * groups + 0.8),
                             squeeze=False, sharex="col")
    force_columns = [ESTIMATE_COLUMN["f_x_hat"], ESTIMATE_COLUMN["f_z_hat"]]
    for k, s in enumerate(scores):
        g, col = divmod(k, ncols)
        ax_phi, ax_c, ax_f = (axes[3 * g + i, col] for i in range(3))
        ep = s.episode
        t_all = ep.time_s
        t = t_all[s.rows]
        ax_phi.plot(t_all, ep.truth[:, TRUTH_COLUMN["phi"]] / DEG, "k--", lw=1.0, label="truth")
        ax_phi.plot(t, s.estimates[:, ESTIMATE_COLUMN["phi"]] / DEG, ".", ms=1.5, color="C0", label="estimate")
        ax_phi.set_title(f"{ep.meta.soil}, I_d {ep.meta.relative_density_pct:.0f} %", fontsize=9)
        ax_c.plot(t_all, ep.truth[:, TRUTH_COLUMN["c"]] * 1e-3, "k--", lw=1.0, label="truth")
        ax_c.plot(t, s.estimates[:, ESTIMATE_COLUMN["c"]] * 1e-3, ".", ms=1.5, color="C2", label="estimate")
        _fused_band(ax_phi, t, s.estimates, "phi", 1.0 / DEG, "C1")
        _fused_band(ax_c, t, s.estimates, "c", 1e-3, "C1", lowest=0.0)
        for j, (axis, color) in enumerate((("x", "C0"), ("z", "C3"))):
            ax_f.plot(t_all, ep.forces[:, j] * 1e-3, color=color, lw=0.6, alpha=0.45, label=f"$F_{axis}$ measured")
            ax_f.plot(t, s.estimates[:, force_columns[j]] * 1e-3, ".", ms=1.2, color=color, label=rf"$\hat F_{axis}$")
        # Scale to the estimated stretch: the start-up transient (blade entering) would flatten it.
        shown = np.concatenate([ep.forces[s.rows[0]:].ravel(), s.estimates[:, force_columns].ravel()]) * 1e-3
        lo, hi = float(shown.min()), float(shown.max())
        pad = 0.15 * max(hi - lo, 1.0)
        ax_f.set_ylim(lo - pad, hi + pad)
        ax_f.set_xlabel("t [s]", fontsize=8)
        if col == 0:
            ax_phi.set_ylabel("φ [deg]", fontsize=8)
            ax_c.set_ylabel("c [kPa]", fontsize=8)
            ax_f.set_ylabel("F [kN]", fontsize=8)
        for ax in (ax_phi, ax_c, ax_f):
            ax.tick_params(labelsize=7)
            ax.grid(alpha=0.3)
            ax.xaxis.set_tick_params(labelbottom=True)
        if k == 0:
            ax_phi.legend(fontsize=6, loc="best", markerscale=4)
            ax_f.legend(fontsize=6, loc="best", ncol=2, markerscale=4)
    for k in range(n, groups * ncols):  # unused cells of the last group
        g, col = divmod(k, ncols)
        for i in range(3):
            axes[3 * g + i, col].set_visible(False)
    fig.suptitle("Online estimates: the PINN's window (valid only, dots), the soil fused along the path (line, "
                 "90 % band) vs pseudo-ground truth / measured force", fontsize=10)
    fig.tight_layout()
    return fig
