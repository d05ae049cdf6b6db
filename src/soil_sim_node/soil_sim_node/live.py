"""ROS-free parts of the live simulator node: episode plans, the command gate, timing stats.

Kept out of ``node.py`` so they are testable without DDS and the node stays an adapter.
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np

from soil_msgs_py import graph as G
from soil_msgs_py import messages as M
from soil_msgs_py.params import MACHINE

from .simulator import MAX_TARGET_SPEED_M_S, EpisodeSpec

# Command fields in the order the simulator core takes them, with the range each is
# clamped to (u_za is recorded only; the lift joint cannot reach beyond its stroke).
COMMAND_LIMITS: dict[str, tuple[float, float]] = {
    "u_zr": (MACHINE.blade_min_rel_m, MACHINE.blade_max_rel_m),
    "u_za": (-MACHINE.blade_height_m - 10.0, 10.0),
    "u_x": (-MAX_TARGET_SPEED_M_S, MAX_TARGET_SPEED_M_S),
}
COMMAND_TOPIC_FIELDS: dict[str, tuple[str, ...]] = {
    topic: tuple(name for _, name in M.FIELDS[topic].columns) for topic in G.COMMAND_TOPICS
}  # {"/chassis/cmd_vel": ("u_x",), "/blade/cmd": ("u_zr", "u_za")}
# Before the controller has said anything: blade on the chassis reference, machine at rest.
INITIAL_COMMAND = {"u_zr": 0.0, "u_za": 0.0, "u_x": 0.0}


def episode_plan(base: EpisodeSpec, soils: list[str], densities_pct: list[float], repeats: int) -> list[EpisodeSpec]:
    """soils x densities x repeats, seeds base.seed, base.seed+1, ... (empty lists: the base's)."""
    soils = soils or [str(base.soil)]
    densities_pct = densities_pct or [base.relative_density_pct]
    combos = itertools.product(soils, densities_pct, range(max(0, repeats)))
    return [
        EpisodeSpec(soil, float(i_d), base.target_speed_m_s, base.target_depth_m,
                    seed=base.seed + k, duration_s=base.duration_s)
        for k, (soil, i_d, _) in enumerate(combos)
    ]


class CommandGate:
    """Collects the commands that answer the tick now published and sanitises them.

    Why: the simulator core refuses non-finite commands (it raises) and a robot stack's
    simulator must keep running whatever a client publishes. A command is accepted only
    if it is stamped with the tick it answers; stale, repeated and future stamps are
    ignored. Non-finite fields hold the last applied value; out-of-range fields are
    clamped to COMMAND_LIMITS. Every decision returns a warning naming field and value.
    """

    def __init__(self) -> None:
        self.last = dict(INITIAL_COMMAND)
        self.pending: dict[str, float] = {}
        self.arrived: set[str] = set()
        self.stamp_ns: int | None = None
        self.rejected = 0
        self.sanitised = 0

    def expect(self, stamp_ns: int) -> None:
        """A new tick was published: from now on only commands stamped ``stamp_ns`` count."""
        self.stamp_ns = stamp_ns
        self.pending = {}
        self.arrived = set()

    def idle(self) -> None:
        """No episode running: every command is ignored until the next ``expect``."""
        self.stamp_ns = None
        self.pending = {}
        self.arrived = set()

    def offer(self, topic: str, stamp_ns: int, values) -> list[tuple[str, str]]:
        """Offer one command message; returns (kind, warning) pairs (empty when taken as is).

        ``kind`` ("<topic>:<field or stamp>:<problem>") lets the node rate-limit by kind."""
        names = COMMAND_TOPIC_FIELDS[topic]
        if self.stamp_ns is None:
            self.rejected += 1
            return [(f"{topic}:stamp:idle",
                     f"{topic}: command stamped {stamp_ns} ns arrived while no episode is running; ignored")]
        if stamp_ns != self.stamp_ns:
            self.rejected += 1
            kind = "stale" if stamp_ns < self.stamp_ns else "future"
            return [(f"{topic}:stamp:{kind}", f"{topic}: {kind} stamp {stamp_ns} ns (expected {self.stamp_ns} ns, "
                                               f"the tick being answered); ignored")]
        if topic in self.arrived:
            self.rejected += 1
            return [(f"{topic}:stamp:repeated", f"{topic}: second command for stamp {stamp_ns} ns; ignored")]
        warnings = []
        for name, raw in zip(names, values):
            value = float(raw)
            lo, hi = COMMAND_LIMITS[name]
            if not math.isfinite(value):
                warnings.append((f"{topic}:{name}:non_finite",
                                 f"{topic}: field {name}={value} is not finite; holding {self.last[name]}"))
                value = self.last[name]
            elif not lo <= value <= hi:
                clamped = min(max(value, lo), hi)
                warnings.append((f"{topic}:{name}:out_of_range",
                                 f"{topic}: field {name}={value} outside [{lo}, {hi}]; clamped to {clamped}"))
                value = clamped
            self.pending[name] = value
        self.sanitised += bool(warnings)
        self.arrived.add(topic)
        return warnings

    @property
    def complete(self) -> bool:
        return len(self.arrived) == len(COMMAND_TOPIC_FIELDS)

    def take(self) -> tuple[float, float, float]:
        """(u_zr, u_za, u_x) to apply now: what arrived for this tick, else the last applied."""
        self.last.update(self.pending)
        return self.last["u_zr"], self.last["u_za"], self.last["u_x"]


def _percentiles_ms(values_s: list[float]) -> dict[str, float]:
    if not values_s:
        return {"n": 0}
    a = np.asarray(values_s) * 1e3
    return {"n": int(a.size), "p50_ms": round(float(np.percentile(a, 50)), 4),
            "p99_ms": round(float(np.percentile(a, 99)), 4), "max_ms": round(float(a.max()), 4)}


@dataclass
class TickTiming:
    """Wall-clock figures of one episode: publish periods, loop latency, late commands."""

    nominal_period_s: float
    publish_times: list[float] = field(default_factory=list)
    loop_latencies: list[float] = field(default_factory=list)
    late_commands: int = 0

    def published(self, t: float) -> None:
        self.publish_times.append(t)

    def answered(self, t: float) -> None:
        """Both commands for the last published tick arrived at wall time ``t``."""
        if self.publish_times:
            self.loop_latencies.append(t - self.publish_times[-1])

    def summary(self) -> dict:
        periods = np.diff(self.publish_times).tolist() if len(self.publish_times) > 1 else []
        out = {"nominal_period_ms": round(self.nominal_period_s * 1e3, 4), "period": _percentiles_ms(periods)}
        if self.nominal_period_s > 0:  # lockstep has no nominal period, hence no jitter
            out["jitter"] = _percentiles_ms([abs(p - self.nominal_period_s) for p in periods])
        out.update(loop_latency=_percentiles_ms(self.loop_latencies), late_commands=self.late_commands)
        return out
