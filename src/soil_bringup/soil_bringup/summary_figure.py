"""The demo's figure: per episode φ̂ vs φ, ĉ vs c and F̂ vs F against time (``online_estimates.png``)."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from soil_msgs_py.cli_paths import save_figure_atomically
from soil_msgs_py.params import DEG

from .estimate_columns import ESTIMATE_COLUMN, TRUTH_COLUMN
from .scoring import EpisodeScore


def plot(scores: list[EpisodeScore], path: Path) -> Path:
    """Per episode three small panels: φ̂ vs φ, ĉ vs c, F̂ vs F (x and z) against time."""
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
    fig.suptitle("Online PINN estimates (valid only, dots) vs pseudo-ground truth / measured force", fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    save_figure_atomically(fig, path, dpi=80)
    plt.close(fig)
    return path
