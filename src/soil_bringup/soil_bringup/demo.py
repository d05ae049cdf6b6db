"""`make demo`: the online PINN estimator, live, over the four soils at two relative densities.

Starts ``soil_launch`` (simulator + anti-stall controller + ``pinn_estimator`` + recorder, each
its own process, DDS on loopback only) for a plan of episodes (soils x I_d, default Clay, Loam,
Sand, Gravel at 20 % and 80 %, 10 s each, real time at 60 Hz) and, while it runs, prints one
line per second of simulation time from an in-process monitor node: estimated vs true φ, c,
δ, β and predicted vs measured blade force. When the launch has exited cleanly it scores the
recorded bags (the record of truth: every tick, every estimate) per episode, over valid
estimates only: force MAE x/z [kN, % of measured] (paper §3.2 figures), φ, c, δ, β MAE against
the pseudo-ground truth, and the share of ticks with a valid estimate. It prints a table and
writes ``summary.md``, ``summary.json`` and ``online_estimates.png`` under ``--out``.

    python -m soil_bringup.demo                                # real time, ~2 min
    python -m soil_bringup.demo --pacing lockstep              # as fast as the machine goes
    python -m soil_bringup.demo --soils Clay Sand --densities 40 --duration 5 --rate 2

Exit codes: 0 done; 1 the launch failed or a bag is missing / has no valid estimate; 2 bad
arguments; 130 interrupted. Every wait is bounded; the launch (and its nodes) are stopped on
the way out whatever happens.
"""
from __future__ import annotations

import argparse
import collections
import itertools
import json
import math
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from soil_msgs_py import graph as G
from soil_msgs_py import topics as T
from soil_bag_tools.bag_io import PARTIAL_SUFFIX, find_episode_bags, is_bag, read_episode, read_labelled_topic
from soil_msgs_py.messages import parse_labelled, parse_message
from soil_msgs_py.params import DEG, GROUND_TRUTH_PARAMS, SAMPLE_RATE_HZ, WINDOW_SAMPLES

DEFAULT_SOILS = ("Clay", "Loam", "Sand", "Gravel")
DEFAULT_DENSITIES_PCT = (20.0, 80.0)
DEFAULT_DOMAIN_ID = 42
EXIT_FAILED = 1
EXIT_BAD_ARGS = 2
EXIT_INTERRUPTED = 130

# What the monitor subscribes to besides /sim/status: the simulator must count these
# subscriptions on top of the launch's own 'wait_for' (see _launch_argv).
MONITOR_DATA_TOPICS = (T.GROUND_TRUTH.name, T.BLADE_FORCE.name)
EST = {name: i for i, name in enumerate(T.ESTIMATE_FIELDS)}
TRUTH = {name: i for i, name in enumerate(GROUND_TRUTH_PARAMS)}

# Live-line columns: (symbol, unit, SI -> unit factor, width, decimals).
PARAM_COLUMNS = (("φ", "deg", 1 / DEG, 5, 1), ("c", "kPa", 1e-3, 5, 2),
                 ("δ", "deg", 1 / DEG, 5, 1), ("β", "deg", 1 / DEG, 5, 1))
FORCE_COLUMNS = (("Fx", "kN", 1e-3, 6, 2), ("Fz", "kN", 1e-3, 6, 2))
PREFIX_WIDTH = 17  # "Gravel  80%  9.0s"


# ====================================================================== live lines (pure)

def _pair(est: float | None, true: float | None, width: int, nd: int) -> str:
    e = f"{est:>{width}.{nd}f}" if est is not None and math.isfinite(est) else f"{'--':>{width}}"
    t = f"{true:<{width}.{nd}f}" if true is not None and math.isfinite(true) else f"{'--':<{width}}"
    return f"{e}/{t}"


def _col_width(col) -> int:
    return 2 + 2 * col[3] + 1


def line_prefix(soil: str, i_d_pct: float, t_s: float) -> str:
    return f"{soil[:6]:<6} {i_d_pct:>3.0f}% {t_s:>4.1f}s"


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
    valid = estimate is not None and estimate[EST["valid"]] > 0.5
    if valid:
        for sym, _, k, w, nd in PARAM_COLUMNS:
            name = {"φ": "phi", "c": "c", "δ": "delta", "β": "beta"}[sym]
            true = truth[TRUTH[name]] * k if truth is not None else None
            out += "  " + _pair(estimate[EST[name]] * k, true, w, nd)
    else:
        width = sum(_col_width(c) for c in PARAM_COLUMNS)
        if note:
            text = note
        elif estimate is not None:
            text = f"filling window {int(estimate[EST['window_samples']]):2d}/{WINDOW_SAMPLES}"
        else:
            text = "no estimate"
        out += f"  {text:<{width - 2}}"
    for (sym, _, k, w, nd), (fe, fm) in zip(FORCE_COLUMNS, (("f_x_hat", 0), ("f_z_hat", 1))):
        pred = estimate[EST[fe]] * k if valid else None
        meas = force[fm] * k if force is not None else None
        out += "  " + _pair(pred, meas, w, nd)
    return out.rstrip()


# ====================================================================== live monitor (rclpy)

@dataclass
class LiveEpisode:
    """What the monitor saw of one episode (wall times: time.monotonic())."""

    index: int
    name: str
    soil: str
    relative_density_pct: float
    first_stamp_ns: int
    planned_ticks: int
    wall_start: float
    wall_end: float | None = None
    reason: str = ""
    ticks: int = 0
    estimates: int = 0
    valid: int = 0
    latencies_s: list = field(default_factory=list)
    next_line_s: float = 0.0
    last_estimate_wall: float | None = None
    first_valid_wall: float | None = None
    last_valid_wall: float | None = None

    @property
    def estimating_s(self) -> float:
        """Wall time from the first to the last valid estimate seen (one tick added)."""
        if self.first_valid_wall is None:
            return 0.0
        return self.last_valid_wall - self.first_valid_wall + 1.0 / SAMPLE_RATE_HZ


class LiveMonitor:
    """An rclpy participant in its own context, spun by a background thread, printing one
    line per simulated second. Best-effort data subscriptions: it can fall behind or miss a
    sample, never slow the graph; the bags, not this, are scored. Import and construct only
    after ROS_AUTOMATIC_DISCOVERY_RANGE is set."""

    DATA_QUEUE = 200
    HISTORY = 1200  # ticks of truth/force kept to match an estimate's stamp
    PENDING_NS = 100_000_000  # a line waits at most this much newer data for its tick's truth/force

    def __init__(self, domain_id: int, planned_episodes: int, out=None):
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
        from rclpy.signals import SignalHandlerOptions
        from std_msgs.msg import String

        from soil_msgs_py.ros_adapter import message_class, topic_qos

        self.out = out or sys.stdout
        self.planned = planned_episodes
        self.episodes: list[LiveEpisode] = []
        self.current: LiveEpisode | None = None
        self.truth: collections.OrderedDict[int, np.ndarray] = collections.OrderedDict()
        self.force: collections.OrderedDict[int, tuple[np.ndarray, float]] = collections.OrderedDict()
        self.problems: collections.Counter = collections.Counter()
        self.pending: tuple[LiveEpisode, int, np.ndarray] | None = None  # a line waiting for its tick's data
        self._rclpy = rclpy
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain_id, signal_handler_options=SignalHandlerOptions.NO)
        try:
            self.node = Node("demo_monitor", context=self.context)
            data_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=self.DATA_QUEUE,
                                  reliability=ReliabilityPolicy.BEST_EFFORT, durability=DurabilityPolicy.VOLATILE)
            # Creation order is the order the executor serves ready subscriptions: status first
            # (episode boundaries), the estimate last (its tick's truth and force are then in).
            self.node.create_subscription(String, G.SIM_STATUS_TOPIC, self._on_status, topic_qos(G.SIM_STATUS_TOPIC))
            self.node.create_subscription(message_class(T.GROUND_TRUTH.msgtype), T.GROUND_TRUTH.name, self._on_truth, data_qos)
            self.node.create_subscription(message_class(T.BLADE_FORCE.msgtype), T.BLADE_FORCE.name, self._on_force, data_qos)
            self.node.create_subscription(message_class(T.ESTIMATE.msgtype), T.ESTIMATE.name, self._on_estimate, data_qos)
            self.executor = SingleThreadedExecutor(context=self.context)
            self.executor.add_node(self.node)
        except BaseException:
            rclpy.try_shutdown(context=self.context)
            raise
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, name="demo_monitor", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ plumbing
    def _spin(self) -> None:
        while not self._stop.is_set() and self.context.ok():
            try:
                self.executor.spin_once(timeout_sec=0.05)
            except Exception as err:  # noqa: BLE001 - a display must never take the run down
                self.problems[f"monitor error: {err!r}"] += 1

    def print(self, text: str = "") -> None:
        try:
            self.out.write(text + "\n")
            self.out.flush()
        except (OSError, ValueError):
            pass

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)
        self._flush()
        try:
            self.executor.shutdown(timeout_sec=1.0)
            self.node.destroy_node()
        finally:
            self._rclpy.try_shutdown(context=self.context)

    @staticmethod
    def _remember(store: collections.OrderedDict, key: int, value, limit: int) -> None:
        store[key] = value
        while len(store) > limit:
            store.popitem(last=False)

    def _nearest_truth(self, stamp: int) -> np.ndarray | None:
        if stamp in self.truth:
            return self.truth[stamp]
        older = [s for s in reversed(self.truth) if s <= stamp]
        return self.truth[older[0]] if older else None

    def _flush(self, newest_stamp: int | None = None) -> None:
        """Print the pending line once its tick's truth and force are in, when data this much
        newer shows they will not come (best effort: a sample can be lost), or when forced
        (``newest_stamp`` None)."""
        if self.pending is None:
            return
        ep, stamp, values = self.pending
        force = self.force.get(stamp)
        ready = force is not None and stamp in self.truth
        if not ready and newest_stamp is not None and newest_stamp - stamp < self.PENDING_NS:
            return
        self.pending = None
        self.print(estimate_line(ep.soil, ep.relative_density_pct, (stamp - ep.first_stamp_ns) * 1e-9, values,
                                 self._nearest_truth(stamp), force[0] if force else None))

    # ------------------------------------------------------------------ callbacks
    def _on_status(self, msg) -> None:
        try:
            event = G.EpisodeEvent.from_json(msg.data)
        except ValueError as err:
            self.problems[f"bad /sim/status: {err}"] += 1
            return
        now = time.monotonic()
        self._flush()
        if event.event == G.EVENT_EPISODE_START:
            ep = LiveEpisode(len(self.episodes), event.name, event.meta.soil, float(event.meta.relative_density_pct),
                             event.first_stamp_ns, event.planned_ticks, now)
            self.episodes.append(ep)
            self.current = ep
            self.print()
            self.print(f"=== episode {ep.index + 1}/{self.planned}: {ep.soil}, I_d {ep.relative_density_pct:.0f} % "
                       f"({event.name}, {event.planned_ticks} ticks = {event.planned_ticks / SAMPLE_RATE_HZ:.1f} s)")
            for line in header_lines():
                self.print(line)
        else:
            ep = self.current if self.current is not None and self.current.name == event.name else None
            if ep is None:
                self.print(f"--- end of {event.name} ({event.reason}) [its start was not seen]")
                return
            ep.wall_end, ep.reason, ep.ticks = now, event.reason, event.ticks
            lat = np.array(ep.latencies_s) * 1e3
            latency = (f"; estimate latency p50 {np.percentile(lat, 50):.1f} ms, p99 {np.percentile(lat, 99):.1f} ms"
                       if len(lat) else "")
            self.print(f"--- end ({event.reason}): {event.ticks} ticks in {now - ep.wall_start:.1f} s wall; "
                       f"{ep.valid} valid estimates seen live{latency}")
            self.current = None

    def _on_truth(self, msg) -> None:
        try:
            stamp, values = parse_labelled(msg, GROUND_TRUTH_PARAMS, T.GROUND_TRUTH.name)
        except ValueError as err:
            self.problems[str(err)] += 1
            return
        self._remember(self.truth, stamp, values, self.HISTORY)
        self._flush(stamp)
        ep = self.current
        if ep is None:
            return
        # No estimate at all for over a second of wall time (estimator silent): say so, once a second.
        t = (stamp - ep.first_stamp_ns) * 1e-9
        last = ep.last_estimate_wall if ep.last_estimate_wall is not None else ep.wall_start
        if t >= ep.next_line_s + 1.0 and time.monotonic() - last > 1.0:
            force = self.force.get(stamp)
            self.print(estimate_line(ep.soil, ep.relative_density_pct, t, None, values,
                                     force[0] if force else None, note="no estimate received"))
            ep.next_line_s = math.floor(t) + 1.0

    def _on_force(self, msg) -> None:
        stamp, values = parse_message(T.BLADE_FORCE.name, msg)
        self._remember(self.force, stamp, (values, time.monotonic()), self.HISTORY)
        self._flush(stamp)

    def _on_estimate(self, msg) -> None:
        now = time.monotonic()
        try:
            stamp, values = parse_labelled(msg, T.ESTIMATE_FIELDS, T.ESTIMATE.name)
        except ValueError as err:
            self.problems[str(err)] += 1
            return
        ep = self.current
        if ep is None or stamp < ep.first_stamp_ns:
            return
        ep.estimates += 1
        ep.last_estimate_wall = now
        valid = values[EST["valid"]] > 0.5
        force = self.force.get(stamp)
        if valid:
            ep.valid += 1
            ep.first_valid_wall = ep.first_valid_wall or now
            ep.last_valid_wall = now
            if force is not None:
                ep.latencies_s.append(now - force[1])
        t = (stamp - ep.first_stamp_ns) * 1e-9
        if t + 1e-6 >= ep.next_line_s:
            self._flush()
            self.pending = (ep, stamp, values)
            self._flush(stamp)
            ep.next_line_s = math.floor(t + 1e-6) + 1.0


# ====================================================================== scoring the bags (pure)

@dataclass
class EpisodeScore:
    """One recorded episode and its valid estimates matched to ticks."""

    bag: Path
    episode: object  # soil_msgs_py.episode.Episode
    rows: np.ndarray  # tick index of each valid estimate (unique, ascending)
    estimates: np.ndarray  # (n, len(ESTIMATE_FIELDS)) values of those estimates (SI)
    summary: dict


def score_episode(bag_dir: str | os.PathLike) -> EpisodeScore:
    """Read one episode bag and score its valid ``/soil/estimate`` messages against its ticks.

    ValueError (naming the bag) if the bag has no estimates or none is valid."""
    from pinn_estimator.evaluate import PARAMS, UNITS, TRUTH_COL, parameter_errors
    from pinn_estimator.inference import force_errors

    bag = Path(bag_dir)
    ep = read_episode(bag)
    try:
        stamps, values = read_labelled_topic(bag, T.ESTIMATE.name, T.ESTIMATE_FIELDS)
    except ValueError as err:
        raise ValueError(f"{err} (was the estimator running and recorded?)") from None
    if len(stamps) == 0:
        raise ValueError(f"bag {bag} has no {T.ESTIMATE.name} message (the estimator published nothing)")
    ticks = len(ep)
    pos = np.searchsorted(ep.stamps_ns, stamps).clip(0, ticks - 1)
    on_tick = ep.stamps_ns[pos] == stamps
    valid = values[:, EST["valid"]] > 0.5
    keep = np.flatnonzero(valid & on_tick)
    rows, first = np.unique(pos[keep], return_index=True)  # one estimate per tick (the first)
    est = values[keep[first]]
    if len(rows) == 0:
        raise ValueError(f"bag {bag} has {len(stamps)} {T.ESTIMATE.name} messages but no valid estimate "
                         f"on a tick of the episode (max window fill {int(values[:, EST['window_samples']].max())}"
                         f"/{WINDOW_SAMPLES})")
    possible = max(ticks - (WINDOW_SAMPLES - 1), 0)  # ticks that end a full window
    summary = {
        "name": bag.name, "bag": str(bag), "soil": ep.meta.soil,
        "relative_density_pct": float(ep.meta.relative_density_pct), "world_mode": ep.meta.world_mode,
        "seed": int(ep.meta.seed), "ticks": ticks, "duration_s": ticks / SAMPLE_RATE_HZ,
        "estimates": int(len(stamps)), "valid_estimates": int(len(rows)),
        "valid_off_tick": int((valid & ~on_tick).sum()), "duplicate_valid": int(len(keep) - len(rows)),
        "pct_ticks_valid": 100.0 * len(rows) / ticks,
        "pct_full_window_ticks_valid": 100.0 * len(rows) / possible if possible else 0.0,
        "first_valid_s": float((ep.stamps_ns[rows[0]] - ep.stamps_ns[0]) * 1e-9),
    }
    summary.update(_errors(ep.forces[rows], est, ep.truth[rows], force_errors, parameter_errors))
    summary["truth_mean"] = {f"{p}_{UNITS[p][0]}": float(ep.truth[rows, TRUTH_COL[p]].mean() * UNITS[p][1]) for p in PARAMS}
    summary["estimate_mean"] = {f"{p}_{UNITS[p][0]}": float(est[:, EST[p]].mean() * UNITS[p][1]) for p in PARAMS}
    return EpisodeScore(bag, ep, rows, est, summary)


def _errors(measured: np.ndarray, est: np.ndarray, truth: np.ndarray, force_errors, parameter_errors) -> dict:
    predicted = est[:, [EST["f_x_hat"], EST["f_z_hat"]]]
    forces = force_errors(measured, predicted)
    params = parameter_errors({p: est[:, EST[p]] for p in ("phi", "c", "delta", "beta")}, truth,
                              np.ones(len(est), dtype=bool))
    return {"force": forces, "params": params}


def summarise(bag_dir: str | os.PathLike) -> dict:
    """Per-episode figures of one recorded bag (JSON-ready; see ``score_episode``)."""
    return score_episode(bag_dir).summary


def overall(scores: list[EpisodeScore]) -> dict:
    """The same figures over the valid estimates of every episode together."""
    from pinn_estimator.evaluate import parameter_errors
    from pinn_estimator.inference import force_errors

    ticks = sum(len(s.episode) for s in scores)
    valid = sum(len(s.rows) for s in scores)
    possible = sum(max(len(s.episode) - (WINDOW_SAMPLES - 1), 0) for s in scores)
    out = {"name": "overall", "episodes": len(scores), "ticks": ticks, "valid_estimates": valid,
           "estimates": sum(s.summary["estimates"] for s in scores),
           "pct_ticks_valid": 100.0 * valid / ticks if ticks else 0.0,
           "pct_full_window_ticks_valid": 100.0 * valid / possible if possible else 0.0}
    if scores:
        out.update(_errors(np.concatenate([s.episode.forces[s.rows] for s in scores]),
                           np.concatenate([s.estimates for s in scores]),
                           np.concatenate([s.episode.truth[s.rows] for s in scores]), force_errors, parameter_errors))
    return out


# ====================================================================== table, files, figure

TABLE_COLUMNS = (  # (header, width, getter)
    ("episode", 13, lambda r: r["soil"] if "soil" in r else r["name"]),
    ("I_d %", 5, lambda r: f"{r['relative_density_pct']:.0f}" if "relative_density_pct" in r else ""),
    ("valid", 5, lambda r: f"{r['valid_estimates']}"),
    ("ticks %", 7, lambda r: f"{r['pct_ticks_valid']:.1f}"),
    ("Fx MAE kN (%)", 13, lambda r: f"{r['force']['mae_x_n'] / 1e3:.2f} ({r['force']['mae_x_pct_measured']:.0f})"),
    ("Fz MAE kN (%)", 13, lambda r: f"{r['force']['mae_z_n'] / 1e3:.2f} ({r['force']['mae_z_pct_measured']:.0f})"),
    ("φ deg", 6, lambda r: f"{r['params']['phi_mae_deg']:.1f}"),
    ("c kPa", 6, lambda r: f"{r['params']['c_mae_kPa']:.2f}"),
    ("δ deg", 6, lambda r: f"{r['params']['delta_mae_deg']:.1f}"),
    ("β deg", 6, lambda r: f"{r['params']['beta_mae_deg']:.1f}"),
)


def table_text(rows: list[dict], total: dict) -> str:
    """Console table: one row per episode, a rule, the overall row (MAE over valid estimates)."""
    def line(cells):
        return "  ".join(f"{c:<{w}}" if i == 0 else f"{c:>{w}}" for i, (c, (_, w, _)) in enumerate(zip(cells, TABLE_COLUMNS)))
    head = line([h for h, _, _ in TABLE_COLUMNS])
    body = [line([get(r) for _, _, get in TABLE_COLUMNS]) for r in rows]
    return "\n".join([head, "-" * len(head), *body, "-" * len(head), line([get(total) for _, _, get in TABLE_COLUMNS])])


def markdown(report: dict) -> str:
    run, rows, total = report["run"], report["episodes"], report["overall"]
    lines = [
        "# Online estimation demo", "",
        f"{len(rows)} episode(s) of {run['duration_s']:g} s, pacing {run['pacing']}"
        + (f" x{run['rate']:g}" if run["pacing"] == "realtime" else "")
        + f", {run['world_mode'] or 'default'} world; checkpoint `{run['checkpoint']}`. "
        f"Run wall time {run['wall_s']:.1f} s (launch {run['launch_s']:.1f} s). Bags: `{run['bags']}`.", "",
        "Errors are mean absolute errors over the valid estimates of each episode (each matched to the tick it is "
        "stamped with); forces as in paper §3.2 (% of the mean measured |F|), parameters against the "
        "pseudo-ground truth. The paper's parameter targets apply for I_d <= 60 % (soil failure assumption).", "",
        "| episode | I_d [%] | valid estimates | ticks with one [%] | Fx MAE [kN] (% meas.) | Fz MAE [kN] (% meas.) "
        "| φ MAE [deg] | c MAE [kPa] | δ MAE [deg] | β MAE [deg] |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows + [total]:
        cells = [get(r) for _, _, get in TABLE_COLUMNS]
        if r is total:
            cells[0] = "**overall**"
        lines.append("| " + " | ".join(cells) + " |")
    lines += ["", "Mean estimate (truth) over the valid estimates:", "",
              "| episode | I_d [%] | φ [deg] | c [kPa] | δ [deg] | β [deg] |", "|---|---|---|---|---|---|"]
    for r in rows:
        e, t = r["estimate_mean"], r["truth_mean"]
        lines.append(f"| {r['soil']} | {r['relative_density_pct']:.0f} | " + " | ".join(
            f"{e[k]:.{2 if k.startswith('c_') else 1}f} ({t[k]:.{2 if k.startswith('c_') else 1}f})" for k in e) + " |")
    lines += ["", f"Throughput: {throughput_text(run)}; {total['pct_ticks_valid']:.1f} % of ticks have a valid estimate "
              f"({total['pct_full_window_ticks_valid']:.1f} % of the ticks that end a full {WINDOW_SAMPLES}-sample window).",
              "", "![online estimates](online_estimates.png)", ""]
    return "\n".join(lines)


def throughput_text(run: dict) -> str:
    live = run.get("estimates_per_wall_s_estimating")
    per_launch = run.get("estimates_per_launch_s")
    return (f"{run['valid_estimates']} valid estimates: {run['estimates_per_sim_s']:.1f} per simulated second"
            + (f", {live:.1f}/s of wall time while estimating" if live else "")
            + (f", {per_launch:.1f}/s over the whole launch (with start-up and episode hand-overs)" if per_launch else ""))


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
    for k, s in enumerate(scores):
        g, col = divmod(k, ncols)
        ax_phi, ax_c, ax_f = (axes[3 * g + i, col] for i in range(3))
        ep = s.episode
        t_all = ep.time_s
        t = t_all[s.rows]
        ax_phi.plot(t_all, ep.truth[:, TRUTH["phi"]] / DEG, "k--", lw=1.0, label="truth")
        ax_phi.plot(t, s.estimates[:, EST["phi"]] / DEG, ".", ms=1.5, color="C0", label="estimate")
        ax_phi.set_title(f"{ep.meta.soil}, I_d {ep.meta.relative_density_pct:.0f} %", fontsize=9)
        ax_c.plot(t_all, ep.truth[:, TRUTH["c"]] * 1e-3, "k--", lw=1.0, label="truth")
        ax_c.plot(t, s.estimates[:, EST["c"]] * 1e-3, ".", ms=1.5, color="C2", label="estimate")
        for j, (axis, color) in enumerate((("x", "C0"), ("z", "C3"))):
            ax_f.plot(t_all, ep.forces[:, j] * 1e-3, color=color, lw=0.6, alpha=0.45, label=f"$F_{axis}$ measured")
            ax_f.plot(t, s.estimates[:, EST[f"f_{axis}_hat"]] * 1e-3, ".", ms=1.2, color=color, label=rf"$\hat F_{axis}$")
        # Scale to the estimated stretch: the start-up transient (blade entering) would flatten it.
        shown = np.concatenate([ep.forces[s.rows[0]:].ravel(), s.estimates[:, [EST["f_x_hat"], EST["f_z_hat"]]].ravel()]) * 1e-3
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
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


# ====================================================================== running the launch

def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m soil_bringup.demo", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--soils", nargs="+", default=list(DEFAULT_SOILS), metavar="SOIL",
                   help="soils in the order run (default: %(default)s)")
    p.add_argument("--densities", nargs="+", type=float, default=list(DEFAULT_DENSITIES_PCT), metavar="PCT",
                   help="relative densities I_d [%%] per soil (default: 20 80)")
    p.add_argument("--duration", type=float, default=10.0, help="episode length [s] of simulation time (default 10)")
    p.add_argument("--pacing", choices=("realtime", "lockstep"), default="realtime",
                   help="realtime: 60 Hz ticks on the wall clock x --rate (the honest online demo, default); "
                        "lockstep: each tick waits for the controller, as fast as the machine goes")
    p.add_argument("--rate", type=float, default=1.0, help="real-time factor for --pacing realtime (default 1)")
    p.add_argument("--world-mode", choices=("default", "fee"), default=None,
                   help="simulator world (default: the simulator's, 'default')")
    p.add_argument("--checkpoint", type=Path, help="PINN checkpoint for the estimator (default: the shipped one)")
    p.add_argument("--out", type=Path, default=Path("out/demo"), help="summary, PNG and launch log (default out/demo)")
    p.add_argument("--bags", type=Path, default=Path("bags/demo_online"),
                   help="episode bags; cleared at start (default bags/demo_online)")
    env_id = os.environ.get("ROS_DOMAIN_ID", "").strip()
    p.add_argument("--domain-id", type=int, default=int(env_id) if env_id.isdigit() else DEFAULT_DOMAIN_ID,
                   help=f"ROS_DOMAIN_ID (default: $ROS_DOMAIN_ID, else {DEFAULT_DOMAIN_ID})")
    p.add_argument("--timeout", type=float, default=0.0,
                   help="give the launch at most this many seconds (default: from the plan)")
    args = p.parse_args(argv)
    from soil_physics.soils import get_soil

    try:
        args.soils = [get_soil(s).name for s in itertools.chain.from_iterable(x.split(",") for x in args.soils) if s]
    except ValueError as err:
        p.error(str(err))
    if not args.soils:
        p.error("--soils: no soil given")
    if not all(0.0 <= d <= 100.0 for d in args.densities):
        p.error(f"--densities {args.densities}: each must be in [0, 100] %")
    if not (args.duration > 0 and math.isfinite(args.duration)):
        p.error(f"--duration {args.duration} must be > 0 s")
    if args.duration * SAMPLE_RATE_HZ < WINDOW_SAMPLES + 1:
        p.error(f"--duration {args.duration} s is shorter than one estimator window "
                f"({WINDOW_SAMPLES} samples = {WINDOW_SAMPLES / SAMPLE_RATE_HZ:g} s): no estimate could be made")
    if not (args.rate > 0 and math.isfinite(args.rate)):
        p.error(f"--rate {args.rate} must be > 0")
    if not 0 <= args.domain_id <= 232:
        p.error(f"--domain-id {args.domain_id} outside [0, 232]")
    if args.checkpoint is not None:
        if not args.checkpoint.is_file():
            p.error(f"--checkpoint {args.checkpoint}: no such file")
        args.checkpoint = args.checkpoint.resolve()
    if args.bags.resolve() in (Path.cwd().resolve(), Path.home().resolve(), Path("/")):
        p.error(f"--bags {args.bags}: refusing to clear that directory")
    return args


def planned_seconds(args: argparse.Namespace, episodes: int) -> float:
    """A generous bound on the launch's run time (the launch's own --timeout)."""
    per_episode = args.duration / args.rate if args.pacing == "realtime" else args.duration
    return 60.0 + episodes * (per_episode + 12.0)


def prepare_bag_dir(root: Path) -> bool:
    """Empty ``root`` of a previous demo's bags; True if something was removed.

    Refuses (ValueError) a directory holding anything but episode bags: never deletes data
    that is not ours."""
    if not root.exists():
        root.mkdir(parents=True)
        return False
    if not root.is_dir():
        raise ValueError(f"--bags {root} exists and is not a directory")
    entries = list(root.iterdir())
    foreign = [e for e in entries if not (e.is_dir() and (is_bag(e) or e.name.endswith(PARTIAL_SUFFIX)))]
    if foreign:
        raise ValueError(f"--bags {root} holds {len(foreign)} entr{'y' if len(foreign) == 1 else 'ies'} that "
                         f"are not episode bags (e.g. {foreign[0].name}); not clearing it - choose another --bags")
    for e in entries:
        shutil.rmtree(e)
    return bool(entries)


def _launch_argv(args: argparse.Namespace, launch_timeout: float) -> list[str]:
    from . import launch as L

    def floats(xs):
        return "[" + ",".join(repr(float(x)) for x in xs) + "]"

    argv = ["--estimator", "--record", str(args.bags), "--pacing", args.pacing, "--domain-id", str(args.domain_id),
            "--timeout", f"{launch_timeout:.0f}",
            "--sim-param", f"sequence_soils:=[{','.join(args.soils)}]",
            "--sim-param", f"sequence_relative_densities_pct:={floats(args.densities)}",
            "--sim-param", f"duration_s:={float(args.duration)!r}", "--sim-param", "episodes:=1"]
    if args.pacing == "realtime":
        argv += ["--rate", repr(float(args.rate))]
    if args.world_mode:
        argv += ["--sim-param", f"world_mode:={args.world_mode}"]
    if args.checkpoint is not None:
        argv += ["--estimator-param", f"checkpoint:={args.checkpoint}"]
    # The simulator holds each episode until its 'wait_for' endpoints have matched (counts,
    # '>='). The monitor's subscriptions would count towards the recorder's and estimator's:
    # add them, so every node and the monitor have matched before tick 0.
    for topic in (G.SIM_STATUS_TOPIC, *MONITOR_DATA_TOPICS):
        argv += ["--wait-for", f"{topic}:1"]
    L.build_nodes(L.parse_args(argv))  # ValueError now rather than a launch that exits 2
    return [L.executable("soil_launch"), *argv]


def _tail(path: Path, lines: int = 30) -> str:
    try:
        return "\n".join(path.read_text(errors="replace").splitlines()[-lines:])
    except OSError as err:
        return f"(cannot read {path}: {err})"


def _started_nodes(log_path: Path) -> dict[int, tuple[str, str]]:
    """pid -> (name, command line) of the nodes the launch says it started."""
    try:
        text = log_path.read_text(errors="replace")
    except OSError:
        return {}
    found = re.findall(r"^\[launch\] started (\S+) \(pid (\d+)\): (.*)$", text, re.M)
    return {int(pid): (name, cmd) for name, pid, cmd in found}


def _kill_leftover_nodes(log_path: Path) -> list[str]:
    """SIGKILL the nodes of a launch that had to be killed itself (its nodes run in their own
    sessions and would outlive it). Only a process whose command line is still the logged one
    is touched: a recycled pid is left alone."""
    killed = []
    for pid, (name, cmd) in _started_nodes(log_path).items():
        try:
            cmdline = " ".join(Path(f"/proc/{pid}/cmdline").read_bytes().decode(errors="replace").split("\0")).strip()
        except OSError:
            continue
        if cmdline.endswith(cmd.strip()):
            try:
                os.kill(pid, signal.SIGKILL)
                killed.append(f"{name} ({pid})")
            except ProcessLookupError:
                pass
    return killed


def stop_launch(proc: subprocess.Popen, log_path: Path) -> None:
    """Ask the launch to stop its nodes (SIGINT: it stops them in data-flow order, escalating
    per node), then escalate; bounded (~80 s worst case). If the launch itself had to be
    killed, its nodes are killed too."""
    for sig, wait in ((signal.SIGINT, 60.0), (signal.SIGTERM, 15.0), (signal.SIGKILL, 5.0)):
        if proc.poll() is not None:
            return
        try:
            proc.send_signal(sig)
        except ProcessLookupError:
            return
        try:
            proc.wait(timeout=wait)
        except subprocess.TimeoutExpired:
            print(f"demo: soil_launch did not stop within {wait:.0f} s of {signal.Signals(sig).name}", flush=True)
            continue
        if sig != signal.SIGKILL:
            return
    killed = _kill_leftover_nodes(log_path)
    if killed:
        print(f"demo: killed nodes left behind by soil_launch: {', '.join(killed)}", flush=True)


def _interrupt(signum, frame):  # noqa: ARG001
    raise KeyboardInterrupt


def run(args: argparse.Namespace) -> int:
    t_start = time.monotonic()
    pairs = list(itertools.product(args.soils, args.densities))
    args.out.mkdir(parents=True, exist_ok=True)
    log_path = args.out / "launch.log"
    try:
        cleared = prepare_bag_dir(args.bags)
    except (ValueError, OSError) as err:
        print(f"demo: {err}", file=sys.stderr)
        return EXIT_BAD_ARGS
    print(f"demo: {len(pairs)} episode(s): {', '.join(args.soils)} x I_d {', '.join(f'{d:g}' for d in args.densities)} %, "
          f"{args.duration:g} s each, pacing {args.pacing}" + (f" x{args.rate:g}" if args.pacing == "realtime" else "")
          + f", ROS_DOMAIN_ID {args.domain_id} (loopback only)")
    print(f"demo: bags -> {args.bags}/" + (" (cleared the previous demo's bags)" if cleared else "")
          + f"; node output -> {log_path}")

    # DDS on loopback for this process (the monitor) and every node, before rclpy is imported.
    from .launch import loopback_env

    env = loopback_env(args.domain_id)
    os.environ.pop("ROS_LOCALHOST_ONLY", None)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ["ROS_DOMAIN_ID"] = str(args.domain_id)

    launch_timeout = args.timeout or planned_seconds(args, len(pairs))
    try:
        argv = _launch_argv(args, launch_timeout)
    except (FileNotFoundError, ValueError) as err:
        print(f"demo: cannot build the launch: {err}", file=sys.stderr)
        return EXIT_FAILED
    old_term = signal.signal(signal.SIGTERM, _interrupt)
    monitor = proc = None
    rc: int | None = None
    t_launch = time.monotonic()
    try:
        try:
            monitor = LiveMonitor(args.domain_id, len(pairs))
        except Exception as err:  # noqa: BLE001 - no live lines, but the run and its scoring still work
            print(f"demo: live monitor unavailable ({err!r}); running without live lines", flush=True)
        with log_path.open("w") as log:
            t_launch = time.monotonic()
            proc = subprocess.Popen(argv, env=env, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                    start_new_session=True)  # Ctrl-C reaches us; we stop it in order
            try:
                rc = proc.wait(timeout=launch_timeout + 90.0)
            except subprocess.TimeoutExpired:
                print(f"demo: soil_launch still running after {launch_timeout + 90:.0f} s; stopping it", flush=True)
    except KeyboardInterrupt:
        print("\ndemo: interrupted; stopping the launch and its nodes ...", flush=True)
        rc = EXIT_INTERRUPTED
    finally:
        # A second Ctrl-C must not abandon the stop half-way (it is bounded by itself).
        old_int = signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        try:
            if proc is not None and proc.poll() is None:
                stop_launch(proc, log_path)
            if monitor is not None:
                monitor.close()
        finally:
            signal.signal(signal.SIGINT, old_int)
            signal.signal(signal.SIGTERM, old_term)
    launch_s = time.monotonic() - t_launch
    if rc == EXIT_INTERRUPTED:
        print(f"demo: interrupted after {launch_s:.0f} s; partial bags in {args.bags}/, node output in {log_path}")
        return EXIT_INTERRUPTED
    if rc != 0:
        why = {1: "a node died", 3: "timeout"}.get(rc, "see the log") if rc is not None else "it did not finish"
        print(f"demo: FAILED - soil_launch exit code {rc} ({why}) after {launch_s:.0f} s. "
              f"Node output: {log_path}; its last lines:", file=sys.stderr)
        print(_tail(log_path), file=sys.stderr)
        return EXIT_FAILED
    if monitor is not None:
        for problem, n in monitor.problems.most_common(5):
            print(f"demo: monitor: {problem} (x{n})")
    return report(args, pairs, monitor, t_start, launch_s, log_path)


def report(args, pairs, monitor, t_start: float, launch_s: float, log_path: Path) -> int:
    """Score the bags, print the table and where everything is; non-zero if an episode is missing."""
    print(f"\ndemo: launch finished in {launch_s:.1f} s; scoring the bags in {args.bags}/ ...", flush=True)
    errors: list[str] = []
    partial = sorted(p.name for p in args.bags.glob(f"*{PARTIAL_SUFFIX}"))
    if partial:
        errors.append(f"unfinished bag(s) (the recorder did not close them): {', '.join(partial)}")
    bags = find_episode_bags(args.bags)
    scores: list[EpisodeScore] = []
    for bag in bags:
        try:
            scores.append(score_episode(bag))
        except (ValueError, FileNotFoundError) as err:
            errors.append(str(err))
    scores.sort(key=lambda s: int(s.episode.stamps_ns[0]))  # run order (simulation time is continuous)
    recorded = collections.Counter((s.episode.meta.soil, float(s.episode.meta.relative_density_pct)) for s in scores)
    missing = [f"{soil} I_d {d:g} %" for soil, d in pairs if not recorded.pop((soil, float(d)), 0)]
    if missing:
        errors.append(f"no usable bag for {len(missing)} of {len(pairs)} planned episode(s): {', '.join(missing)} "
                      f"(found {len(bags)} bag(s) in {args.bags}/; node output in {log_path})")
    if not scores:
        for e in errors:
            print(f"demo: ERROR: {e}", file=sys.stderr)
        print(f"demo: FAILED - nothing to score. Node output: {log_path}; its last lines:", file=sys.stderr)
        print(_tail(log_path), file=sys.stderr)
        return EXIT_FAILED

    rows = [s.summary for s in scores]
    total = overall(scores)
    # Throughput from the monitor's wall clock: the span from each episode's first to its last
    # valid estimate (what the estimator sustains online; 60/s = every tick at 60 Hz).
    live = {ep.name: ep for ep in (monitor.episodes if monitor is not None else [])}
    estimating = []
    for r in rows:
        ep = live.get(r["name"])
        if ep is None:
            continue
        lat = np.array(ep.latencies_s) * 1e3
        r["live"] = {"wall_s": (ep.wall_end - ep.wall_start) if ep.wall_end is not None else None,
                     "end_reason": ep.reason, "estimates_seen": ep.estimates, "valid_seen": ep.valid,
                     "estimating_wall_s": ep.estimating_s,
                     "valid_per_wall_s": r["valid_estimates"] / ep.estimating_s if ep.estimating_s > 0 else None,
                     "latency_ms_p50": float(np.percentile(lat, 50)) if len(lat) else None,
                     "latency_ms_p99": float(np.percentile(lat, 99)) if len(lat) else None}
        if ep.estimating_s > 0:
            estimating.append((r["valid_estimates"], ep.estimating_s))
        if ep.reason and ep.reason != "completed":
            errors.append(f"episode {r['name']} ended with reason {ep.reason!r} (see {log_path})")
    per_wall = sum(n for n, _ in estimating) / sum(w for _, w in estimating) if estimating else None
    sim_s = total["ticks"] / SAMPLE_RATE_HZ
    wall_s = time.monotonic() - t_start
    run_info = {
        "soils": args.soils, "densities_pct": [float(d) for d in args.densities], "duration_s": args.duration,
        "pacing": args.pacing, "rate": args.rate if args.pacing == "realtime" else None,
        "world_mode": args.world_mode, "checkpoint": str(args.checkpoint or "shipped pinn_default.pt"),
        "domain_id": args.domain_id, "bags": str(args.bags), "launch_log": str(log_path),
        "launch_s": launch_s, "wall_s": wall_s, "simulated_s": sim_s,
        "valid_estimates": total["valid_estimates"],
        "estimates_per_wall_s_estimating": per_wall,
        "estimates_per_launch_s": total["valid_estimates"] / launch_s if launch_s > 0 else None,
        "estimates_per_sim_s": total["valid_estimates"] / sim_s if sim_s else 0.0,
        "valid_fraction": total["valid_estimates"] / total["ticks"] if total["ticks"] else 0.0,
        "errors": errors,
    }
    result = {"run": run_info, "episodes": rows, "overall": total}
    paths = {"json": args.out / "summary.json", "markdown": args.out / "summary.md", "png": args.out / "online_estimates.png"}
    plot(scores, paths["png"])
    run_info["wall_s"] = wall_s = time.monotonic() - t_start
    paths["markdown"].write_text(markdown(result))
    paths["json"].write_text(json.dumps(result, indent=1, default=float) + "\n")

    print()
    print(table_text(rows, total))
    print("MAE over valid estimates; (%) of the mean measured |F|. φ/c/δ/β against the pseudo-ground truth.")
    print(f"\ndemo: wall time {wall_s:.1f} s (launch {launch_s:.1f} s for {sim_s:.0f} s of simulation time)")
    print(f"demo: {throughput_text(run_info)}")
    print(f"demo: {100 * run_info['valid_fraction']:.1f} % of ticks have a valid estimate "
          f"({total['pct_full_window_ticks_valid']:.1f} % of those ending a full {WINDOW_SAMPLES}-sample window)")
    print(f"demo: bags    {args.bags}/ ({len(bags)} episode bag(s), with /soil/estimate)")
    print(f"demo: table   {paths['markdown']}  (+ {paths['json'].name})")
    print(f"demo: figure  {paths['png']}")
    print(f"demo: log     {log_path}")
    if errors:
        for e in errors:
            print(f"demo: ERROR: {e}", file=sys.stderr)
        return EXIT_FAILED
    return 0


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        sys.stdout.reconfigure(errors="replace")
    except (AttributeError, ValueError):
        pass
    try:
        return run(args)
    except KeyboardInterrupt:
        print("\ndemo: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == "__main__":
    raise SystemExit(main())
