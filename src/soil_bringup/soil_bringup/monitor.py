"""The demo's live monitor: an rclpy participant that prints one line per simulated second.

It listens to /sim/status (episode boundaries), the ground truth, the measured blade force and
/soil/estimate, pairs each estimate with its tick's truth and force by stamp (the graph's one
stamp joiner, ``soil_msgs_py.stamp_join``), and prints through ``live_lines``. It also times the estimator on the wall clock (latency, estimates per
second while estimating), which the bags cannot tell. Best effort by design: the bags, not
this, are scored.
"""
from __future__ import annotations

import collections
import math
import sys
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from soil_msgs_py import graph as G
from soil_msgs_py import topics as T
from soil_msgs_py.messages import parse_labelled, parse_message
from soil_msgs_py.params import GROUND_TRUTH_PARAMS, SAMPLE_RATE_HZ
from soil_msgs_py.stamp_join import Joined, StampJoiner

from .estimate_columns import is_valid
from .live_lines import estimate_line, header_lines

# What the monitor subscribes to besides /sim/status: the simulator must count these
# subscriptions on top of the launch's own 'wait_for'.
MONITOR_DATA_TOPICS = (T.GROUND_TRUTH.name, T.BLADE_FORCE.name)


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
    late_commands: int = 0  # ticks whose commands came after their real-time deadline (the simulator's count)
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

    def latency_ms(self, percentile: float) -> float | None:
        """Percentile of the time from a tick's measured force to its valid estimate [ms]."""
        return float(np.percentile(np.array(self.latencies_s) * 1e3, percentile)) if self.latencies_s else None

    def summary(self, valid_estimates: int) -> dict:
        """The wall-clock figures of this episode for the summary (``valid_estimates``: from its bag)."""
        return {"wall_s": (self.wall_end - self.wall_start) if self.wall_end is not None else None,
                "end_reason": self.reason, "estimates_seen": self.estimates, "valid_seen": self.valid,
                "late_commands": self.late_commands,
                "estimating_wall_s": self.estimating_s,
                "valid_per_wall_s": valid_estimates / self.estimating_s if self.estimating_s > 0 else None,
                "latency_ms_p50": self.latency_ms(50), "latency_ms_p99": self.latency_ms(99)}


class LiveMonitor:
    """An rclpy participant in its own context, spun by a background thread, printing one
    line per simulated second. Its data subscriptions are the recorder's (reliable, 2000 deep):
    a lockstep graph runs far above 60 Hz and a best-effort reader this far behind lost the
    samples a second's line needs; a reliable reader never slows the graph either (the nodes'
    KEEP_LAST writers do not wait for it). Import and construct only after
    ROS_AUTOMATIC_DISCOVERY_RANGE is set."""

    HISTORY = 1200  # ticks waiting for their estimate (the estimator may lag the simulator, lockstep)
    ESTIMATOR_WAIT_S = 30.0  # longest wait for the estimator's writer before following episodes
    END_WAIT_S = 3.0  # after an episode_end, wait this long at most for the estimator's last estimates

    def __init__(self, domain_id: int, planned_episodes: int, out=None):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from rclpy.signals import SignalHandlerOptions

        from soil_msgs_py.graph import RECORDER_QOS
        from soil_msgs_py.ros_adapter import init_context, message_class, qos_profile, status_after_inputs

        self.out = out or sys.stdout
        self.planned = planned_episodes
        self.episodes: list[LiveEpisode] = []
        self.current: LiveEpisode | None = None
        # One set per tick: truth, (force, wall time), (estimate, wall time). A tick leaves once
        # complete, or incomplete as soon as a newer tick is (a lost sample, or no estimate
        # for it); an estimate for a tick that has left is refused. The first of a repeat
        # counts, as in the scoring.
        self.ticks = StampJoiner((T.GROUND_TRUTH.name, T.BLADE_FORCE.name, T.ESTIMATE.name),
                                 max_pending=self.HISTORY, reorder_ns=0, duplicates="keep_first")
        self.last_truth: np.ndarray | None = None  # of the newest tick that left with one
        self.last_force: tuple[int, np.ndarray] | None = None  # (stamp, values) as received
        self.problems: collections.Counter = collections.Counter()
        self.pending_end: tuple[G.EpisodeEvent, float] | None = None  # an episode_end and when it came
        self.last_estimate_ns = -1  # newest estimate stamp of the current episode
        self._rclpy = rclpy
        self.context = init_context(domain_id, signal_handler_options=SignalHandlerOptions.NO)
        try:
            self.node = Node("demo_monitor", context=self.context)
            data_qos = qos_profile(RECORDER_QOS)
            self.node.create_subscription(message_class(T.GROUND_TRUTH.msgtype), T.GROUND_TRUTH.name, self._on_truth, data_qos)
            self.node.create_subscription(message_class(T.BLADE_FORCE.msgtype), T.BLADE_FORCE.name, self._on_force, data_qos)
            estimate_sub = self.node.create_subscription(
                message_class(T.ESTIMATE.msgtype), T.ESTIMATE.name, self._on_estimate, data_qos)
            # /sim/status once the estimator's writer has matched (at most ESTIMATOR_WAIT_S: without
            # an estimator the run goes on, its lines saying so): matched late under load, the
            # monitor saw no estimate before 1.2 s.
            self.status = status_after_inputs(self.node, {T.ESTIMATE.name: estimate_sub}, self._on_status,
                                            self.ESTIMATOR_WAIT_S)
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
                self._maybe_end()
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
        self._maybe_end(force=True)
        self._finish_ticks()
        try:
            self.executor.shutdown(timeout_sec=1.0)
            self.node.destroy_node()
        finally:
            self._rclpy.try_shutdown(context=self.context)

    def _offer(self, topic: str, stamp: int, payload) -> None:
        for tick in self.ticks.offer(topic, stamp, payload).out:
            self._on_tick(tick)

    def _finish_ticks(self) -> None:
        """Let every waiting tick leave (an episode ended: late estimates are not counted)."""
        for tick in self.ticks.drain():
            self._on_tick(tick)

    def _on_tick(self, tick: Joined) -> None:
        """One tick's truth, force and estimate, as complete as they came: the estimator's
        latency, and the live line if this tick starts a new simulated second."""
        truth = tick.parts.get(T.GROUND_TRUTH.name)
        if truth is not None:
            self.last_truth = truth
        force = tick.parts.get(T.BLADE_FORCE.name)
        estimate = tick.parts.get(T.ESTIMATE.name)
        ep = self.current
        if estimate is None or ep is None or tick.stamp_ns < ep.first_stamp_ns:
            return
        values, received = estimate
        if force is not None and is_valid(values) and force[1] <= received:
            ep.latencies_s.append(received - force[1])
        t = (tick.stamp_ns - ep.first_stamp_ns) * 1e-9
        if t + 1e-6 >= ep.next_line_s:
            # Without its own truth (a lost sample) the newest earlier one stands in.
            self.print(estimate_line(ep.soil, ep.relative_density_pct, t, values, self.last_truth,
                                     force[0] if force is not None else None))
            ep.next_line_s = math.floor(t + 1e-6) + 1.0

    # ------------------------------------------------------------------ callbacks
    def _on_status(self, msg) -> None:
        try:
            event = G.EpisodeEvent.from_json(msg.data)
        except ValueError as err:
            self.problems[f"bad /sim/status: {err}"] += 1
            return
        now = time.monotonic()
        if event.event == G.EVENT_EPISODE_START:
            self._maybe_end(force=True)
            self.last_estimate_ns = -1
            ep = LiveEpisode(len(self.episodes), event.name, event.meta.soil, float(event.meta.relative_density_pct),
                             event.first_stamp_ns, event.planned_ticks, now)
            self.episodes.append(ep)
            self.current = ep
            if event.first_stamp_ns <= self.ticks.last_ns:  # a new simulator: its clock started over
                self.ticks.reset(event.first_stamp_ns)
            self.print()
            self.print(f"=== episode {ep.index + 1}/{self.planned}: {ep.soil}, I_d {ep.relative_density_pct:.0f} % "
                       f"({event.name}, {event.planned_ticks} ticks = {event.planned_ticks / SAMPLE_RATE_HZ:.1f} s)")
            for line in header_lines():
                self.print(line)
        else:
            # The estimator may lag the simulator (a lockstep one runs far above 60 Hz): the
            # episode's lines end once its last estimate is in, or END_WAIT_S later.
            self._maybe_end(force=True)
            self.pending_end = (event, now)
            self._maybe_end()

    def _maybe_end(self, force: bool = False) -> None:
        """End the episode whose episode_end came, once its last tick's estimate arrived, after
        END_WAIT_S, or now (``force``)."""
        if self.pending_end is None:
            return
        event, now = self.pending_end
        if not (force or self.last_estimate_ns >= event.last_stamp_ns or time.monotonic() - now >= self.END_WAIT_S):
            return
        self.pending_end = None
        self._finish_ticks()
        ep = self.current if self.current is not None and self.current.name == event.name else None
        if ep is None:
            self.print(f"--- end of {event.name} ({event.reason}) [its start was not seen]")
        else:
            ep.wall_end, ep.reason, ep.ticks = now, event.reason, event.ticks
            late = (event.stats or {}).get("late_commands", 0)
            ep.late_commands = late if isinstance(late, int) and not isinstance(late, bool) else 0
            latency = (f"; estimate latency p50 {ep.latency_ms(50):.1f} ms, p99 {ep.latency_ms(99):.1f} ms"
                       if ep.latencies_s else "")
            self.print(f"--- end ({event.reason}): {event.ticks} ticks in {now - ep.wall_start:.1f} s wall; "
                       f"{ep.valid} valid estimates seen live{latency}")
            self.current = None

    def _on_truth(self, msg) -> None:
        try:
            stamp, values = parse_labelled(msg, GROUND_TRUTH_PARAMS, T.GROUND_TRUTH.name)
        except ValueError as err:
            self.problems[str(err)] += 1
            return
        self._offer(T.GROUND_TRUTH.name, stamp, values)
        ep = self.current
        if ep is None:
            return
        # No estimate at all for over a second of wall time (estimator silent): say so, once a second.
        t = (stamp - ep.first_stamp_ns) * 1e-9
        last = ep.last_estimate_wall if ep.last_estimate_wall is not None else ep.wall_start
        if t >= ep.next_line_s + 1.0 and time.monotonic() - last > 1.0:
            force = self.last_force[1] if self.last_force is not None and self.last_force[0] == stamp else None
            self.print(estimate_line(ep.soil, ep.relative_density_pct, t, None, values, force,
                                     note="no estimate received"))
            ep.next_line_s = math.floor(t) + 1.0

    def _on_force(self, msg) -> None:
        try:
            stamp, values = parse_message(T.BLADE_FORCE.name, msg)
        except ValueError as err:
            self.problems[str(err)] += 1
            return
        self.last_force = (stamp, values)
        self._offer(T.BLADE_FORCE.name, stamp, (values, time.monotonic()))

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
        self.last_estimate_ns = max(self.last_estimate_ns, stamp)
        ep.estimates += 1
        ep.last_estimate_wall = now
        if is_valid(values):
            ep.valid += 1
            ep.first_valid_wall = ep.first_valid_wall or now
            ep.last_valid_wall = now
        self._offer(T.ESTIMATE.name, stamp, (values, now))
