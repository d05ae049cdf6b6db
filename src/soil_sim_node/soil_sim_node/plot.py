"""`soil_plot_episode`: a paper-Fig.-3-style PNG of one episode, read from its bag.

Measured forces x/z (with the FEE force of the pseudo-ground truth for reference, where the bag
has one), cut depth with its target, and surcharge, against time.

    soil_plot_episode bags/samples/default_loam_id060_v0.53_d0.175_s7 -o fig3.png
"""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from soil_physics import fee  # noqa: E402
from soil_bag_tools.bag_io import BagReadError, read_episode, read_labelled_topic  # noqa: E402
from soil_msgs_py.cli_paths import input_path, output_file, refuse_directories, save_figure_atomically  # noqa: E402
from soil_msgs_py.episode import Episode  # noqa: E402
from soil_msgs_py.params import MACHINE  # noqa: E402
from soil_msgs_py.topics import TARGET_DEPTH  # noqa: E402


def truth_fee_force(ep: Episode) -> tuple[np.ndarray, np.ndarray]:
    """FEE force (x, z) of the episode's pseudo-ground-truth Θ, tick by tick [N]."""
    return fee.fee_xz_of_truth(ep.truth)


def planner_targets(bag: Path, ep: Episode) -> tuple[np.ndarray, np.ndarray] | None:
    """(time [s] on ``ep``'s clock, target depth [m]) of the planner's /planner/target_depth in the
    bag, None if it has none: in a closed loop the controller cut to these, not to the episode's
    target, which the figure then drew as if it had."""
    try:
        stamps, values = read_labelled_topic(bag, TARGET_DEPTH.name, TARGET_DEPTH.labels)
    except BagReadError as err:
        if f"has no topic {TARGET_DEPTH.name}" not in str(err):  # there, but unreadable: said, not hidden
            print(f"soil_plot_episode: warning: the planner's targets not drawn: {err}", file=sys.stderr)
        return None
    if not len(stamps):
        return None
    order = np.argsort(stamps, kind="stable")  # log order is not always stamp order
    return (stamps[order] - ep.stamps_ns[0]) / 1e9, values[order, TARGET_DEPTH.labels.index("target_depth_m")]


FOLLOWED_WITHIN_M = 1e-3  # a command this close to a target followed it (the anti-stall offset at 0)


def followed_share(ep: Episode, planner: tuple[np.ndarray, np.ndarray]) -> float:
    """The share of the ticks whose commanded depth −u_za lies within FOLLOWED_WITHIN_M of the
    planner's target in effect, of those within it of the planner's or the episode's (0 where none
    is: an anti-stall offset all along). A planner beside an open loop records targets too, and a
    controller whose planner died part-way fell back to the episode's depth for the rest."""
    times, targets = planner
    at = np.searchsorted(times, ep.time_s, side="right") - 1  # the newest target at or before each tick
    planned = np.where(at >= 0, targets[np.clip(at, 0, None)], np.nan)
    commanded = -ep.column("u_za")
    with np.errstate(invalid="ignore"):
        telling = np.abs(planned - ep.meta.target_depth_m) > FOLLOWED_WITHIN_M  # (where the two agree, no tick tells)
        by_planner = int(np.sum(telling & (np.abs(commanded - planned) <= FOLLOWED_WITHIN_M)))
        by_episode = int(np.sum(telling & (np.abs(commanded - ep.meta.target_depth_m) <= FOLLOWED_WITHIN_M)))
    return by_planner / (by_planner + by_episode) if by_planner + by_episode else 0.0


MOST = 0.5  # the controller followed the planner on more of the telling ticks than not
ALL_ALONG_SHARE = 0.95  # a loop this closed is said as the planner's (a fallback's few ticks aside)


def followed_planner(ep: Episode, planner: tuple[np.ndarray, np.ndarray]) -> bool:
    """Whether the controller cut to the planner's targets (``depth_source`` planner) rather than
    the episode's for most ticks (``followed_share`` above one half): the figure had said the depth
    came from an advisory planner (an outside tester's)."""
    return followed_share(ep, planner) > MOST


def plot_episode(ep: Episode, out: Path, planner: tuple[np.ndarray, np.ndarray] | None = None) -> Path:
    """Write the Fig.-3-style figure of ``ep`` to ``out`` (PNG, or the format of its suffix);
    ``planner``: the planner's targets (``planner_targets``), drawn in place of the episode's one
    where the controller followed them (``followed_planner``), else beside it as advice."""
    t = ep.time_s
    m = ep.meta
    share = followed_share(ep, planner) if planner is not None else 0.0
    followed = share > MOST  # (``followed_planner``, the share kept for the title)
    fig, axes = plt.subplots(3, 1, figsize=(9, 8), sharex=True, constrained_layout=True)
    ax = axes[0]
    ax.plot(t, ep.column("f_x_b") / 1e3, lw=0.9, label="$f_x^b$ measured")
    ax.plot(t, ep.column("f_z_b") / 1e3, lw=0.9, label="$f_z^b$ measured")
    if ep.has_ground_truth:  # a machine's bag has no Θ to draw the FEE of
        fx_fee, fz_fee = truth_fee_force(ep)
        ax.plot(t, fx_fee / 1e3, "k--", lw=0.8, label="FEE($\\Theta$) x")
        ax.plot(t, fz_fee / 1e3, "k:", lw=0.8, label="FEE($\\Theta$) z")
    for lim in (MACHINE.horizontal_force_limit_n, -MACHINE.horizontal_force_limit_n):
        ax.axhline(lim / 1e3, color="grey", lw=0.5)
    ax.set_ylabel("force [kN]")
    ax.legend(ncol=4, fontsize=8, loc="lower right")
    patches = m.soil_patches()
    named = [f"{p.soil} {p.relative_density_pct:.0f} %" + (f" (x ≥ {p.x_start_m:g} m)" if i else "")
             for i, p in enumerate(patches)]
    # three patches a line: a long path's title ran off both edges of the figure
    soil = ("\n".join(" → ".join(named[i:i + 3]) + (" →" if i + 3 < len(named) else "")
                      for i in range(0, len(named), 3)) + "\n") if patches else \
        f"{m.soil}, $I_d$ = {m.relative_density_pct:.0f} %, "
    ax.set_title(
        f"{soil}{m.world_mode} world, "
        f"$\\bar v_x$ = {m.target_speed_m_s:.2f} m/s, "
        + ("$\\bar d_z$ from the planner" + (f" ({share:.0%} of the ticks, else {m.target_depth_m:.3f} m)"
                                               if share < ALL_ALONG_SHARE else "")
           if followed else f"$\\bar d_z$ = {m.target_depth_m:.3f} m")
        + f", seed {m.seed}"
    )
    x_b = ep.column("p_x_b")
    for patch in patches[1:]:  # where the edge entered each further patch
        crossed = np.flatnonzero(x_b >= patch.x_start_m)
        for axis in axes if crossed.size else ():
            axis.axvline(t[crossed[0]], color="tab:purple", lw=0.8, ls="-.")
    ax = axes[1]
    ax.plot(t, ep.column("d"), label="cut depth $d$")
    if followed:  # the loop closed: the controller's target was the planner's, step by step
        ax.step(*planner, where="post", color="k", ls="--", lw=0.8, label="planner's target $\\bar d_z$")
        if share < ALL_ALONG_SHARE:  # part-way (a planner that died): the depth it fell back to
            ax.axhline(m.target_depth_m, color="grey", ls="--", lw=0.6, label="fallback $\\bar d_z$")
    else:
        ax.axhline(m.target_depth_m, color="k", ls="--", lw=0.8, label="target $\\bar d_z$")
        if planner is not None:  # an advisory planner's: what it would have cut to
            ax.step(*planner, where="post", color="grey", ls=":", lw=0.8, label="planner's target (not followed)")
    ax.plot(t, -ep.column("u_za"), lw=0.8, label="commanded depth $-u_{z_a}$")
    ax.set_ylabel("depth [m]")
    ax.legend(fontsize=8, loc="lower right")
    ax = axes[2]
    ax.plot(t, ep.column("q") / 1e3, color="tab:brown")
    ax.set_ylabel("surcharge Q [kN]")
    ax.set_xlabel("time [s]")
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    save_figure_atomically(fig, out, dpi=110)
    plt.close(fig)
    return out


def figure_file(text: str) -> Path:
    """``-o``: a file matplotlib writes by its suffix (none: .png, the name savefig would write),
    checked before the bag is read, not by savefig after it."""
    path = output_file(text)
    if not path.suffix:
        path = output_file(str(path.with_name(path.name.rstrip(".") + ".png")))
    formats = Figure().canvas.get_supported_filetypes()
    if path.suffix[1:].lower() not in formats:
        raise argparse.ArgumentTypeError(
            f"{text!r}: matplotlib cannot write {path.suffix!r} files; it writes {', '.join(sorted(formats))}")
    return path


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="soil_plot_episode", description=__doc__.split("\n\n")[0])
    p.add_argument("bag", type=input_path, help="episode bag directory")
    p.add_argument("-o", "--out", type=figure_file,
                   help="figure path, its format by its suffix (default: <bag>.png beside the bag)")
    args = p.parse_args(argv)
    bag = Path(os.path.abspath(args.bag))  # "." or ".." have a usable name only once absolute
    # not bag.with_suffix: "..._v0.50_d0.100_s0" and "..._v0.50_d0.200_s1" both became "..._v0.50_d0.png"
    out = args.out or bag.parent / (bag.name + ".png")
    try:
        refuse_directories([out], "give -o")
        ep = read_episode(args.bag)
    except (ValueError, FileNotFoundError) as exc:
        print(f"soil_plot_episode: error: {exc}", file=sys.stderr)
        return 2
    for problem in ep.problems():  # drawn all the same: a line across a gap or a NaN's hole is easy to miss
        print(f"soil_plot_episode: warning: {args.bag}: {problem}", file=sys.stderr)
    out = plot_episode(ep, out, planner_targets(args.bag, ep))
    print(out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
