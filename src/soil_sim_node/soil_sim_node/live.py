"""ROS-free parts of the live simulator node: episode plans and the command gate (pacing and
timing stats: ``pacing.py``).

Kept out of ``node.py`` so they are testable without DDS and the node stays an adapter.
"""
from __future__ import annotations

import itertools
import math

from soil_msgs_py import graph as G
from soil_msgs_py import messages as M
from soil_msgs_py.episode import MAX_SEED
from soil_msgs_py.params import MACHINE
from soil_msgs_py.stamp_join import StampJoiner, Verdict
from soil_msgs_py.writer_identity import FORGET_WRITER_AFTER_TICKS, WriterTracks, tick_number

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


def command_writers() -> dict[str, WriterTracks]:
    """The command writers per topic; kept across episodes (the controller's counter runs on
    and consecutive episodes continue one tick grid), so only the node's very first tick has
    no writer to follow yet."""
    return {topic: WriterTracks(forget_after_ticks=FORGET_WRITER_AFTER_TICKS) for topic in G.COMMAND_TOPICS}


def episode_plan(base: EpisodeSpec, soils: list[str], densities_pct: list[float], repeats: int) -> list[EpisodeSpec]:
    """soils x densities x repeats, seeds base.seed, base.seed+1, ... (empty lists: the base's);
    every episode keeps the base's soil patches."""
    soils = soils or [str(base.soil)]
    densities_pct = densities_pct or [base.relative_density_pct]
    count = len(soils) * len(densities_pct) * max(0, repeats)
    if count and base.seed + count - 1 > MAX_SEED:  # the message names what the user set, not seed + k
        raise ValueError(f"seed={base.seed} with {count} episodes in the plan reaches seed {base.seed + count - 1}, "
                         f"beyond 2**63 - 1: episode k uses seed + k (lower the seed or the number of episodes)")
    combos = itertools.product(soils, densities_pct, range(max(0, repeats)))
    return [
        EpisodeSpec(soil, float(i_d), base.target_speed_m_s, base.target_depth_m,
                    seed=base.seed + k, duration_s=base.duration_s, patches=base.patches)
        for k, (soil, i_d, _) in enumerate(combos)
    ]


class CommandGate:
    """Collects the commands that answer the tick now published and sanitises them.

    Why: the simulator core refuses non-finite commands (it raises) and a robot stack's
    simulator must keep running whatever a client publishes. A command is accepted only
    if it is stamped with the tick it answers (a stamp joiner that expects exactly that
    stamp); stale, repeated and future stamps are ignored. Of commands for that stamp only
    the followed writer's counts (``writer_identity``: the writer that has answered the most
    ticks, told apart by publication sequence numbers), so another publisher's command sent
    first neither steers the simulator nor pushes out the controller's; without sequence
    numbers the first command of a tick counts. A second command of a tick carrying the
    sequence number of the one taken (an intruder's counter that lined up with the
    controller's there) cannot be told from it by counters, only by values: a plausible one
    replaces an implausible one taken first (``messages.plausible_values``), else the first
    stays. So an intruder's garbage never steers, and a plausible copy that arrives first
    still does (nothing tells it apart); a controller that itself sends garbage loses such a
    tick to a plausible copy, the value that can be applied. ``ready``: the tick may be
    stepped now (complete, every command plausible); a complete tick that is not is worth a
    short wait for the controller's own command (the node's timer steps it). Non-finite
    fields hold the last applied value; out-of-range fields are clamped to COMMAND_LIMITS.
    Every decision returns a warning naming field and value.
    """

    def __init__(self, writers: dict[str, WriterTracks] | None = None) -> None:
        self.last = dict(INITIAL_COMMAND)
        self.pending: dict[str, float] = {}
        self.arrived: set[str] = set()
        # per topic, of the command taken for the tick: its sequence number, whether its values are
        # plausible and whether it was sanitised
        self.taken: dict[str, tuple[int | None, bool, bool]] = {}
        self.stamp_ns: int | None = None
        self.complete = False  # both commands for ``stamp_ns`` arrived
        self.joiner = StampJoiner(G.COMMAND_TOPICS, max_pending=1, duplicates="keep_first", max_ahead_ns=0)
        self.writers = writers if writers is not None else command_writers()
        self.rejected = 0
        self.sanitised = 0

    def expect(self, stamp_ns: int) -> None:
        """A new tick was published: from now on only commands stamped ``stamp_ns`` count."""
        self.stamp_ns = stamp_ns
        self.pending, self.arrived, self.complete, self.taken = {}, set(), False, {}
        self.joiner.reset(stamp_ns)

    def idle(self) -> None:
        """No episode running: every command is ignored until the next ``expect``."""
        self.stamp_ns = None
        self.pending, self.arrived, self.complete, self.taken = {}, set(), False, {}
        self.joiner.reset()

    def offer(self, topic: str, stamp_ns: int, values, sequence: int | None = None) -> list[tuple[str, str]]:
        """Offer one command message; returns (kind, warning) pairs (empty when taken as is).

        ``sequence``: its writer's publication sequence number (None or 0: unknown).
        ``kind`` ("<topic>:<field, stamp or writer>:<problem>") lets the node rate-limit by kind."""
        if self.stamp_ns is None:
            self.rejected += 1
            return [(f"{topic}:stamp:idle",
                     f"{topic}: command stamped {stamp_ns} ns arrived while no episode is running; ignored")]
        if stamp_ns == self.stamp_ns:
            writers = self.writers[topic]
            if sequence and topic in self.taken and self.taken[topic][0] == sequence:
                return self._second_claim(topic, stamp_ns, values, sequence)
            if not writers.leads(writers.observe(sequence, tick_number(stamp_ns))):
                self.rejected += 1
                return [(f"{topic}:writer:not_followed",
                         f"{topic}: command for stamp {stamp_ns} ns from a writer other than the one answering "
                         f"every tick (publication sequence number {sequence}); ignored")]
        fields, warnings = self._sanitise(topic, values)
        verdict, out = self.joiner.offer(topic, stamp_ns)
        if verdict is not Verdict.TAKEN:
            self.rejected += 1
            if verdict is Verdict.DUPLICATE or stamp_ns == self.stamp_ns:  # (after both came: stale to the joiner)
                return [(f"{topic}:stamp:repeated", f"{topic}: second command for stamp {stamp_ns} ns; ignored")]
            kind = verdict.value  # "stale" or "future"
            return [(f"{topic}:stamp:{kind}", f"{topic}: {kind} stamp {stamp_ns} ns (expected {self.stamp_ns} ns, "
                                               f"the tick being answered); ignored")]
        self.pending.update(fields)
        self.sanitised += bool(warnings)
        self.arrived.add(topic)
        self.taken[topic] = (sequence or None, M.plausible_values(values), bool(warnings))
        self.complete = bool(out)
        return warnings

    @property
    def plausible(self) -> bool:
        """Whether every command taken for this tick carries plausible values."""
        return all(plausible for _, plausible, _ in self.taken.values())

    @property
    def ready(self) -> bool:
        """The tick may be stepped at once: both commands in, all plausible (class doc)."""
        return self.complete and self.plausible

    def _second_claim(self, topic: str, stamp_ns: int, values, sequence: int) -> list[tuple[str, str]]:
        """A command of this tick carrying the sequence number the command taken for it carried."""
        self.rejected += 1
        _, taken_plausible, taken_sanitised = self.taken[topic]
        if taken_plausible or not M.plausible_values(values):
            return [(f"{topic}:writer:same_sequence",
                     f"{topic}: second command for stamp {stamp_ns} ns with the same publication sequence "
                     f"number {sequence} as the one taken; ignored")]
        fields, warnings = self._sanitise(topic, values)
        self.pending.update(fields)
        self.sanitised += bool(warnings) - taken_sanitised  # the command applied is this one
        self.taken[topic] = (sequence, True, bool(warnings))
        return [(f"{topic}:writer:same_sequence",
                 f"{topic}: two commands for stamp {stamp_ns} ns carry publication sequence number {sequence}; "
                 f"the plausible one replaced the implausible one taken first")] + warnings

    def _sanitise(self, topic: str, values) -> tuple[dict[str, float], list[tuple[str, str]]]:
        """(field -> value to apply, warnings): non-finite held, out of range clamped."""
        fields, warnings = {}, []
        for name, raw in zip(COMMAND_TOPIC_FIELDS[topic], values):
            value = float(raw)
            lo, hi = COMMAND_LIMITS[name]
            if not math.isfinite(value):  # (NaN and ±inf are different faults: each is reported)
                warnings.append((f"{topic}:{name}:{'nan' if value != value else 'inf'}",
                                 f"{topic}: field {name}={value} is not finite; holding {self.last[name]}"))
                value = self.last[name]
            elif not lo <= value <= hi:
                clamped = min(max(value, lo), hi)
                warnings.append((f"{topic}:{name}:out_of_range",
                                 f"{topic}: field {name}={value} outside [{lo}, {hi}]; clamped to {clamped}"))
                value = clamped
            fields[name] = value
        return fields, warnings

    def take(self) -> tuple[float, float, float]:
        """(u_zr, u_za, u_x) to apply now: what arrived for this tick, else the last applied."""
        self.last.update(self.pending)
        return self.last["u_zr"], self.last["u_za"], self.last["u_x"]
