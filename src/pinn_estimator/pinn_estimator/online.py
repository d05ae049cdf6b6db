"""Online estimation core (no rclpy): per-topic messages -> samples -> 60-sample window -> estimate.

The node (``node.py``) hands every message it receives to ``SampleAssembler.add`` and every
``episode_start`` to ``OnlineEstimator.reset``; whatever comes out is published. Kept free
of ROS so the same code is unit-tested directly and used by the replay comparison.

Synchronisation by stamp
    One sample (paper §2.1.2: o_t and Θ_k at t) needs a message of every input topic with
    the same stamp: the simulator's state and Θ_k for tick t, and the controller's commands
    answering tick t (stamped t). The stamp joiner (``soil_msgs_py.stamp_join``) assembles
    them and *releases them in stamp order*: the oldest pending sample as soon as it is
    complete; if it is still incomplete while a sample ``reorder_ticks`` ticks newer is
    already complete, it is declared missing. A topic twice for one tick spoils that tick.

Validity (never estimate across a gap, never publish NaN)
    The window is the last ``WINDOW_SAMPLES`` released samples *if they are consecutive
    ticks*. A missing tick, a message older than the last released sample (out of order), a
    non-finite or implausible field (beyond ±1e9: a 1e300 pose sample had spoilt the soil
    posterior for the rest of the episode) or a message that does not parse resets the window: the next estimate
    comes only after 60 new consecutive samples. The model's output is checked too; a
    non-finite output is reported and published as invalid.
"""
from __future__ import annotations

import collections
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch

from soil_msgs_py import graph as G
from soil_msgs_py import messages as M
from soil_msgs_py import topics as T
from soil_msgs_py.stamp_join import StampJoiner, Verdict, Why
from soil_msgs_py.stream_checks import RATE_STEPS, cutting_ticks, sign_problem, step_problem
from soil_msgs_py.params import (
    FORCE_FIELDS, FORCE_LIMITS_N, KNOWN_PARAMS, MAX_STRIDE_TICKS, OBSERVATION_FIELDS, SAMPLE_RATE_HZ, TICK_PERIOD_NS,
    UNKNOWN_PARAMS, WINDOW_SAMPLES,
)

from soil_physics.travel import soil_advance, soil_time_step
from .fusion import NOT_A_SOIL_STRETCHES, PathFusion, SoilPosterior, fused_values
from .fusion_config import FusionConfig
from .fusion_calibration import DEFAULT_WORLD, config_for_model, load_calibrated, uncalibrated_physics
from .model import EstimatorNet
from .soil_map import SoilMap

PERIOD_NS = TICK_PERIOD_NS  # one tick [ns] (stamps are integer ns, floor of k/60 s)
MAX_PENDING_TICKS = 2 * SAMPLE_RATE_HZ  # incomplete ticks kept waiting for a late topic (2 s)
# A stamp more than a window behind the last sample is not a late message: a source that started
# over (a bag replayed again, a simulator reset) without an episode_start, or a stray message; one
# more than MAX_AHEAD_TICKS ahead is a stray or a stream that jumped on. Such messages are refused
# (no window reset), and RESTART_AFTER_REFUSED of them in a row, nothing taken between (two whole
# ticks of the input topics), start a new stream: one stray message, or one tick of them, stamped 0
# or 5 s back had wiped the soil posterior learnt along the path (an outside tester's).
RESTART_BACK_TICKS = WINDOW_SAMPLES
MAX_AHEAD_TICKS = 10 * SAMPLE_RATE_HZ  # a hole of up to 10 s is a gap in the stream (the posterior kept)
# The most ticks of an episode that may be taken before its episode_start arrives and still count as
# having begun the stream with it (they overtook the event: a replay's first ticks); a stream that began
# later than this after the event's first stamp joined the episode midway.
MAX_OVERTAKING_TICKS = SAMPLE_RATE_HZ // 4
# Ticks arriving twice again and again (a second message of a tick, before or after the tick
# was released) are most likely a second publisher of the topic on the domain (a node left
# running from another launch): each copy spoils its tick or resets the window, none fills.
REPEATS_BEFORE_HINT = 3
REPEATS_HINT = ("; ticks keep arriving twice: is a second node publishing this topic on this ROS_DOMAIN_ID "
                "(e.g. a controller left running from another launch)?")
# Input topics and, per topic, (field name, destination, column): destination "obs" -> o_t,
# "known" -> Θ_k. Fields a topic carries that the model does not use (v_x^b, p_x^c) are
# still checked for NaN/inf: a sample with a broken message is not trusted.
INPUT_TOPICS: tuple[str, ...] = tuple(t for t in G.ESTIMATOR_INPUTS if t != G.SIM_STATUS_TOPIC)
RESTART_AFTER_REFUSED = 2 * len(INPUT_TOPICS)  # refusals in a row that start a new stream (see RESTART_BACK_TICKS)
# A stream keeps its ticks' phase within an episode: a message stamped off the grid through the
# episode's last tick taken (at the stream's own mean step) is a stray (a second writer's, a clock
# jump), refused on arrival as the recorder refuses it, and so is one stamped between two ticks
# already taken (no window reset). Held as a tick of its own, it kept the next real tick waiting
# behind it for the reorder horizon, which in lockstep never comes: the planner loop stalled 2 s
# (an outside tester's; one stamped 33 ns after a tick too). A stream on the exact 60 Hz grid (the
# simulator's and a bag's: steps within EXACT_GRID_NS of 1/60 s) is checked against that grid at
# any distance, off meaning more than EXACT_GRID_TOLERANCE_NS; any other (a machine's clock, its
# stamps rounded or jittery) against its own mean step up to GRID_CHECK_TICKS away (farther, the
# mean's error adds up), off meaning more than three times its steps' spread and at least
# GRID_JITTER_FLOOR_NS (a 1.5 ms late tick of a stream jittering by 50 us is no stray; one refused
# never widens the spread it is judged by), at most GRID_TOLERANCE_NS. Checked from GRID_MIN_STEPS
# steps on; a phase move within reach costs two ticks and a window. Refusals of at least two stamps,
# as many in a row as start a new stream (RESTART_AFTER_REFUSED), are a stream whose phase moved.
GRID_TOLERANCE_NS = PERIOD_NS / 4
EXACT_GRID_NS = 2
EXACT_GRID_TOLERANCE_NS = 12
GRID_JITTER_FLOOR_NS = 2_000_000
GRID_MIN_STEPS = 3
GRID_CHECK_TICKS = 8
assert T.ESTIMATE_FIELDS[: len(UNKNOWN_PARAMS)] == UNKNOWN_PARAMS, "estimate fields start with Θ_u"
_V_X, _D = KNOWN_PARAMS.index("v_x"), KNOWN_PARAMS.index("d")
SIGN_JUDGE_TICKS = 60  # the force's sign is judged every this many forward-cutting ticks (warned as the node limits)
# A model's F̂ beyond this many times the machine's force limits (x, z) is no estimate of a cut of
# this machine: it stalls at its 20 kN tractive limit, and the largest force the simulated worlds
# put on the blade is a plunge into dense clay's 46 kN for a tick. Published as invalid. Why: a
# model whose training diverged (pinn_train --lr 1: 103 389 % of the measured force) ran live
# without a word, its F̂ 185-280 times the limits, and the planner anchored its cut to it
# (held at 0.05 m where 0.2 m was asked; an outside tester's).
IMPLAUSIBLE_ESTIMATE_FACTOR = 10.0
_P_X, _P_Z = OBSERVATION_FIELDS.index("p_x_b"), OBSERVATION_FIELDS.index("p_z_b")
_DEST = {"observations": ("obs", OBSERVATION_FIELDS), "known": ("known", KNOWN_PARAMS), "forces": ("force", FORCE_FIELDS)}
FUSED = slice(T.ESTIMATE_FIELDS.index(T.FUSED_FIELDS[0]), len(T.ESTIMATE_FIELDS))
_F_X_HAT, _F_Z_HAT = T.ESTIMATE_FIELDS.index("f_x_hat"), T.ESTIMATE_FIELDS.index("f_z_hat")


def _routes(topic: str) -> tuple[tuple[str, str, int], ...]:
    out = []
    for array, name in M.FIELDS[topic].columns:
        dest, names = _DEST.get(array, ("", ()))
        out.append((name, dest, names.index(name) if dest else -1))
    return tuple(out)


ROUTES: dict[str, tuple[tuple[str, str, int], ...]] = {t: _routes(t) for t in INPUT_TOPICS}
_COVERED = sorted((d, c) for r in ROUTES.values() for _, d, c in r if d)
assert _COVERED == sorted([("obs", i) for i in range(len(OBSERVATION_FIELDS))]
                          + [("known", i) for i in range(len(KNOWN_PARAMS))]
                          + [("force", i) for i in range(len(FORCE_FIELDS))]), "inputs must cover o_t, Θ_k and F once"


@dataclass
class Counters:
    """What happened to the input so far (reported by the node, checked by tests)."""

    samples: int = 0  # released complete samples
    estimates: int = 0  # valid estimates
    invalid: int = 0  # invalid estimate messages
    gaps: int = 0  # missing ticks, wholly or some of their messages (window reset)
    out_of_order: int = 0  # messages older than the last released sample (window reset)
    non_finite: int = 0  # messages with a NaN/inf or implausible field (``messages.plausible_values``; window reset)
    malformed: int = 0  # messages that did not parse (wrong layout/shape)
    duplicates: int = 0  # a second message of a topic for the same tick (tick dropped)
    evicted: int = 0  # incomplete ticks dropped to bound memory (a topic stopped, or bogus stamps)
    restarts: int = 0  # time went back by more than the reorder horizon: a new stream
    model_non_finite: int = 0  # model outputs that were not finite (published invalid)
    model_implausible: int = 0  # model F̂ beyond IMPLAUSIBLE_ESTIMATE_FACTOR times the force limits (published invalid)
    off_rate: int = 0  # ticks dropped because the stream's stamps do not step at 60 Hz (``stream_checks``)


@dataclass
class Sample:
    """One tick's o_t, Θ_k and measured force F (the fused posterior's evidence)."""

    obs: np.ndarray = field(default_factory=lambda: np.full(len(OBSERVATION_FIELDS), np.nan))
    known: np.ndarray = field(default_factory=lambda: np.full(len(KNOWN_PARAMS), np.nan))
    force: np.ndarray = field(default_factory=lambda: np.full(len(FORCE_FIELDS), np.nan))

    @classmethod
    def from_parts(cls, parts: dict[str, np.ndarray]) -> "Sample":
        """The sample of one joined tick (topic -> values in ``ROUTES`` order)."""
        sample = cls()
        for topic, values in parts.items():
            for (_, dest, col), v in zip(ROUTES[topic], values):
                if dest:
                    getattr(sample, dest)[col] = v
        return sample


Warn = Callable[[str, str], None]  # (kind, text): the node rate-limits by kind


def _no_warn(kind: str, text: str) -> None:  # noqa: ARG001
    pass


class SampleAssembler:
    """Per-topic messages -> complete samples, released in stamp order (see module doc)."""

    def __init__(self, on_sample: Callable[[int, Sample | None], None], *, reorder_ticks: int = 3, warn: Warn = _no_warn,
                 counters: Counters | None = None, on_restart: Callable[[], None] = lambda: None):
        if not isinstance(reorder_ticks, int) or isinstance(reorder_ticks, bool) or not 1 <= reorder_ticks <= MAX_PENDING_TICKS:
            raise ValueError(f"reorder_ticks={reorder_ticks!r} must be an integer in [1, {MAX_PENDING_TICKS}] ticks (a tick "
                             f"still incomplete after {MAX_PENDING_TICKS} newer ones is dropped whatever the horizon)")
        self.on_sample = on_sample  # (stamp, sample) for each released tick; sample None = missing/broken
        self.on_restart = on_restart  # time went back without an episode_start: a new stream
        self.reorder_ticks = reorder_ticks
        self.warn = warn
        self.counters = counters or Counters()
        # Far back or far ahead: refused; a stream that stays there (the source restarted without
        # an episode_start) is followed after RESTART_AFTER_REFUSED refusals in a row, rather than
        # waiting for time to catch up (RESTART_BACK_TICKS)
        self.joiner = StampJoiner(INPUT_TOPICS, max_pending=MAX_PENDING_TICKS, duplicates="spoil",
                                  reorder_ns=reorder_ticks * PERIOD_NS - PERIOD_NS / 2,
                                  max_ahead_ns=MAX_AHEAD_TICKS * PERIOD_NS, restart_after_refused=RESTART_AFTER_REFUSED,
                                  restart_counts_back_beyond_ns=RESTART_BACK_TICKS * PERIOD_NS,
                                  # a second stamp within the grid check's widest tolerance of one (another
                                  # writer's, 1 ns off the grid) is a stray: held as a tick of its own it reset
                                  # the window and its invalid estimate went out beside the real tick's, two in
                                  # one tick, which the recorder took for two writers (it dropped 273 of 600).
                                  # Not wider: a 120 Hz stream's every other tick would be a stray, and its
                                  # rate no longer said
                                  slot_ns=GRID_TOLERANCE_NS)
        self.repeats = 0  # second messages of a tick so far (duplicates and copies of the last one)
        # refusals off the stream's grid, nothing taken since, and the first stamp refused (``_off_grid``)
        self.off_grid_in_a_row, self.off_grid_first_ns, self.off_grid_stamps_differ = 0, -1, False
        self.grid_from_ns = -1  # the grid is checked through ticks from this stamp on (the episode's: ``regrid``)
        self.expect_restart(None)  # (``expect_restart``: its fields)
        self.on_expected_restart: Callable[[int], None] = lambda first_ns: None
        self.steps: collections.deque[int] = collections.deque(maxlen=RATE_STEPS)  # the last stamp steps [ns]
        self._grid: tuple[float, float] | None = None  # (period, tolerance) [ns] of these steps (``_grid_of_steps``)
        self.newest: dict[str, int] = {}  # each topic's newest stamp offered [ns]
        self.off_rate = False  # the stream's stamps were last judged off the 60 Hz rate
        # the last tick of the announced episode end the stream has not crossed yet, and the first tick
        # of the episode announced after it (None: none) [ns]: no tick is due between them (``_hole_ticks``)
        self.ended_ns: int | None = None
        self.next_first_ns: int | None = None

    @property
    def last_released(self) -> int:
        """Stamp [ns] of the newest released sample; -1: none yet."""
        return self.joiner.last_ns

    def reset(self, first_stamp_ns: int | None = None) -> None:
        """Forget everything (a new stream); stamps from ``first_stamp_ns`` on are expected."""
        self.joiner.reset(first_stamp_ns)
        self.expect_restart(None)
        self._forget_stream()

    def expect_restart(self, first_ns: int | None, before_ns: int | None = None) -> None:
        """An episode_start that may be its source starting over (``OnlineEstimator.start_episode``): a
        message stamped back at ``first_ns`` (and before ``before_ns``, the stream's first sample, if
        given) restarts the stream there (``on_expected_restart``); None: nothing is in question."""
        self.expected_restart_ns, self.expected_before_ns = first_ns, before_ns

    def _forget_stream(self) -> None:
        """The rate's steps and the topics' newest stamps belong to one stream (a new one, or time
        gone back: the old stream's stamps would mislead both)."""
        self.steps.clear()
        self._grid = None
        self.newest.clear()
        self.off_rate = False
        self.off_grid_in_a_row = 0
        self.ended_ns = self.next_first_ns = None

    def episode_ended(self, last_ns: int) -> None:
        """An episode ended with its tick at ``last_ns``: the stamps after it up to the next episode's
        first tick are no missing ticks (``_hole_ticks``). Why: a replay of bags that do not follow
        each other (episodes 0 and 2 of a recording) was said to have lost episode 1's 240 ticks,
        and counted a gap (an outside tester's). Of two ends the stream has not crossed, the
        earlier (a stray end far ahead must not hide the real one)."""
        last = int(last_ns)
        if self.ended_ns is None or self.ended_ns <= self.last_released or last < self.ended_ns:
            self.ended_ns, self.next_first_ns = last, None

    def episode_started(self, first_ns: int) -> None:
        """An episode begins at ``first_ns``: after an announced end, the next episode's first tick
        (of two starts the earlier: a stray start far ahead must not hide ticks the real one lost),
        and stamps up to ``MAX_AHEAD_TICKS`` past it are the stream's, however far the end lies
        behind (episodes 0 and 4 of a recording, 12 s apart: refused as far ahead, the stream then
        restarted and lost the episode's first ticks, a reviewer's)."""
        first = int(first_ns)
        if self.ended_ns is not None and first > self.ended_ns:
            self.next_first_ns = first if self.next_first_ns is None else min(self.next_first_ns, first)
            self.joiner.announce(self.next_first_ns)

    def _hole_ticks(self, previous_ns: int, stamp: int) -> tuple[int, bool]:
        """(ticks missing between two released ticks, whether the step crosses an announced episode
        end). Across an end only the ended episode's last ticks and the next one's first ticks count
        (those before its first tick, if its start is announced yet: its ticks may overtake it)."""
        missing = round((stamp - previous_ns) / PERIOD_NS) - 1
        end, first = self.ended_ns, self.next_first_ns
        if end is None or not previous_ns <= end < stamp:
            return missing, False
        self.ended_ns = self.next_first_ns = None  # (crossed)
        head = round((stamp - first) / PERIOD_NS) if first is not None and first <= stamp else 0
        return round((end - previous_ns) / PERIOD_NS) + head, True

    def regrid(self, from_ns: int) -> None:
        """An episode boundary: the grid is checked again only through a tick stamped from ``from_ns``
        on (a new episode, a machine's or a bag's, may keep another phase than the last one's)."""
        self.grid_from_ns = int(from_ns)
        self.off_grid_in_a_row = 0
        self.joiner.new_phase(from_ns)  # (nor is its first tick a stray of the last one's)

    def add(self, topic: str, msg) -> None:
        """One received message of an ``INPUT_TOPICS`` topic (rclpy or rosbags object)."""
        try:
            stamp, values = M.parse_message(topic, msg)
        except (ValueError, AttributeError, TypeError) as err:
            self.counters.malformed += 1
            self.warn(f"{topic}:malformed", f"{topic}: {err}; message ignored (its tick will be missing)")
            return
        self.add_values(topic, stamp, values)

    def add_values(self, topic: str, stamp: int, values: np.ndarray) -> None:
        routes = ROUTES[topic]
        if len(values) != len(routes):
            self.counters.malformed += 1
            self.warn(f"{topic}:malformed", f"{topic}: {len(values)} values, expected {len(routes)}; ignored")
            return
        first, horizon = self.expected_restart_ns, self.reorder_ticks * PERIOD_NS
        # the source started over: its new stream's first ticks, older than anything of this stream that
        # may still come late (a late copy of one of its own ticks had restarted it, a reviewer's)
        if (first is not None and first <= stamp <= first + horizon and self.joiner.last_ns - stamp > horizon
                and (self.expected_before_ns is None or stamp < self.expected_before_ns)):
            self.on_expected_restart(first)
        if self._off_grid(topic, stamp):
            return
        broken = next(((name, v) for (name, _, _), v in zip(routes, values) if not M.plausible_values(v, subnormal=True)), None)
        self.newest[topic] = max(stamp, self.newest.get(topic, stamp))
        was_bad, last = self.joiner.bad(stamp), self.joiner.last_ns
        verdict, out = self.joiner.offer(topic, stamp, values, bad=f"{topic} {broken[0]}={broken[1]}" if broken else "")
        # (nothing released since the stream (re)started: the stamp it is expected from, not "-1 ns")
        ref = f"the last sample {last} ns" if self.joiner.left_since_reset else f"the stream's expected start {last + 1} ns"
        if verdict is Verdict.FUTURE or (verdict is Verdict.STALE and last - stamp > RESTART_BACK_TICKS * PERIOD_NS):
            self.counters.out_of_order += 1
            self.warn(f"{topic}:far", f"{topic}: stamp {stamp} ns is {_seconds(abs(stamp - last))} s "
                                      f"{'after' if stamp > last else 'before'} {ref}; ignored "
                                      f"(a new stream once {RESTART_AFTER_REFUSED // len(INPUT_TOPICS)} ticks of such "
                                      "stamps come in a row)")
            return
        if verdict is Verdict.STALE:
            self.counters.out_of_order += 1
            self.repeats += stamp == last  # a copy of the tick just released
            self.warn(f"{topic}:out_of_order", f"{topic}: stamp {stamp} ns is not newer than {ref} (out of order); "
                                               "window reset" + self._repeats_hint())
            self.on_sample(last, None)
            return
        if verdict is Verdict.RESTART:
            self.counters.restarts += 1
            self.warn("restart", f"{topic}: stamp {stamp} ns is {_seconds(abs(last - stamp))} s "
                                 f"{'after' if stamp > last else 'before'} the last sample, as the messages before it; "
                                 "a new stream: new window, the soil posterior and map start over")
            self.on_sample(last, None)
            self.on_restart()
            self._forget_stream()
            self.newest[topic] = stamp
        if verdict is Verdict.DUPLICATE:
            self.counters.duplicates += 1
            self.repeats += 1
            self.warn(f"{topic}:duplicate", f"{topic}: two messages with stamp {stamp} ns; that tick is dropped"
                      + self._repeats_hint())
        elif broken and not was_bad:
            self.counters.non_finite += 1
            self.warn(f"{topic}:non_finite", f"{topic}: field {broken[0]}={broken[1]} at stamp {stamp} ns is not "
                                             f"finite or is beyond ±{M.PLAUSIBLE_ABS_LIMIT:g}: no "
                                             "value of the graph; that tick is dropped and the window reset")
        for joined in out:
            self._released(joined)

    def _off_grid(self, topic: str, stamp: int) -> bool:
        """Refuse (True) a message stamped off the stream's grid (``GRID_TOLERANCE_NS``)."""
        last = self.joiner.last_ns
        # (a new episode's first ticks keep a phase of their own: the last episode's ticks still due are checked)
        if self.off_rate or last < 0 or last < self.grid_from_ns <= stamp or stamp == last:
            return False
        if self._grid is None:
            self._grid = self._grid_of_steps()
        period, tolerance = self._grid
        if not period:
            return False
        ticks = round(abs(stamp - last) / period)
        if ticks > GRID_CHECK_TICKS and period != PERIOD_NS:
            return False
        off = abs(abs(stamp - last) - ticks * period)  # from the nearest tick of the grid
        if ticks >= 1 and off <= tolerance:  # (nearest the last tick itself: never another tick)
            self.off_grid_in_a_row = 0
            return False
        if not self.off_grid_in_a_row:
            self.off_grid_first_ns, self.off_grid_stamps_differ = stamp, False
        self.off_grid_in_a_row += 1
        self.off_grid_stamps_differ |= stamp != self.off_grid_first_ns
        if self.off_grid_in_a_row > RESTART_AFTER_REFUSED and self.off_grid_stamps_differ:
            self._forget_stream()  # the phase moved (not one stray sent again and again): taken
            return False
        self.counters.out_of_order += 1
        ns = f"{off:.0f} ns" if off < 1e5 else f"{off / 1e6:.1f} ms"
        self.warn(f"{topic}:off_grid", f"{topic}: stamp {stamp} ns is {ns} off the stream's grid of ticks "
                                       f"(its last tick {last} ns); ignored")
        return True

    def _grid_of_steps(self) -> tuple[float, float]:
        """(period, tolerance) [ns] of the grid the recent steps keep ((0, 0): too few to tell), kept
        until the steps change: the check runs for every message, the steps change once a tick."""
        steps = sorted(self.steps)
        median = steps[len(steps) // 2] if steps else 0
        steady = [s for s in steps if median / 2 < s < 1.5 * median]  # (a gap's step is no tick's)
        if len(steady) < GRID_MIN_STEPS:
            return 0.0, 0.0
        if all(abs(s - PERIOD_NS) <= EXACT_GRID_NS for s in steady):  # the exact 60 Hz grid (its floor: ±1 ns)
            return PERIOD_NS, EXACT_GRID_TOLERANCE_NS
        period = sum(steady) / len(steady)
        return period, min(GRID_TOLERANCE_NS, max(3 * max(abs(s - period) for s in steady), GRID_JITTER_FLOOR_NS))

    def _repeats_hint(self) -> str:
        """What ticks arriving twice again and again most likely are (``REPEATS_HINT``), once they do."""
        return REPEATS_HINT if self.repeats >= REPEATS_BEFORE_HINT else ""

    def _released(self, joined) -> None:
        """One tick out of the joiner: a sample, a missing tick or a tick dropped to bound memory."""
        stamp = joined.stamp_ns
        if joined.why is Why.STRAY:  # the same tick as joined.twin_ns under another stamp: no tick of its own
            self.counters.out_of_order += 1
            self.warn("stray", f"stamp {stamp} ns lies within a quarter tick of tick {joined.twin_ns} ns: the same tick "
                               f"under a second stamp (another writer's); its messages ({', '.join(sorted(joined.parts))}) "
                               "ignored")
            return
        missing, crossed = self._hole_ticks(joined.previous_ns, stamp) if joined.previous_ns >= 0 else (0, False)
        if joined.previous_ns >= 0 and joined.why is not Why.EVICTED and not crossed:  # (a new episode's phase: ``regrid``)
            self.steps.append(stamp - joined.previous_ns)
            self._grid = None
            if len(self.steps) == RATE_STEPS and (problem := step_problem(self.steps)):
                # (a 50 or 100 Hz machine's stream had windows of 1.2 or 0.6 s estimated on as one second)
                self.counters.off_rate += 1
                self.warn("rate", f"{problem}; no estimate from these ticks")
                if not self.off_rate:  # what the soil posterior learnt from them before it was judged goes too
                    self.off_rate = True  # (first: the tick's own invalid estimate carries none of it)
                    self.on_restart()
                self.on_sample(stamp, None)
                return
            self.off_rate = False
        if joined.why is Why.EVICTED:  # a topic that never comes must not grow memory
            self.counters.evicted += 1
            # (a machine's sensors, each stamping by its own clock: the topics came, never at one stamp)
            coming = all(self.newest.get(t, -1) > stamp for t in joined.missing)
            self.warn("evicted", f"tick {stamp} ns never got {sorted(joined.missing)} within {MAX_PENDING_TICKS} "
                                 "ticks; dropped" + (" (they come, stamped otherwise: every topic of a tick must carry "
                                                     "the tick's stamp, not its sensor's own)" if coming else ""))
            return
        if joined.why is Why.OVERTAKEN:
            self.counters.gaps += 1
            self.warn("incomplete", f"tick {stamp} ns never got {sorted(joined.missing)}; window reset")
        if missing > 0:
            self.counters.gaps += 1
            self.warn("gap", f"{missing} tick(s) missing before stamp {stamp} ns" + (" (at an episode boundary)" if crossed
                                                                                    else "") + "; window reset")
            self.on_sample(joined.previous_ns, None)
        if joined.usable:
            self.counters.samples += 1
            self.on_sample(stamp, Sample.from_parts(joined.parts))
        else:
            self.on_sample(stamp, None)


def _seconds(ns: int) -> str:
    """Whole ns as seconds with 3 decimals, in integer arithmetic: a log line formats any
    distance between two stamps (a float conversion overflows beyond 1e308)."""
    sign, ns = ("-" if ns < 0 else ""), abs(int(ns))
    return f"{sign}{ns // M.NS_PER_S}.{ns % M.NS_PER_S // 1_000_000:03d}"


def check_compatible(model: EstimatorNet) -> None:
    """ValueError unless the model can run online: a PINN (it estimates soil parameters) on
    ``WINDOW_SAMPLES``-sample windows (what the ring buffer holds)."""
    if model.cfg.kind != "pinn":
        raise ValueError(f"model kind={model.cfg.kind!r}: the online estimator needs a 'pinn' model "
                         "(a physics-free model estimates no soil parameters)")
    if model.cfg.window != WINDOW_SAMPLES:
        raise ValueError(f"model window={model.cfg.window} samples; the online estimator feeds {WINDOW_SAMPLES}")


@dataclass(frozen=True)
class Estimate:
    """What one ``/soil/estimate`` message carries (SI), ``values`` in ``T.ESTIMATE_FIELDS`` order."""

    stamp_ns: int
    values: np.ndarray

    @property
    def valid(self) -> bool:
        return bool(self.values[T.ESTIMATE_FIELDS.index("valid")] == 1.0)

    def __getitem__(self, name: str) -> float:
        return float(self.values[T.ESTIMATE_FIELDS.index(name)])


def invalid_estimate(stamp_ns: int, window_samples: int) -> Estimate:
    values = np.zeros(len(T.ESTIMATE_FIELDS))
    values[T.ESTIMATE_FIELDS.index("window_samples")] = window_samples
    return Estimate(int(stamp_ns), values)


class WindowBuffer:
    """Ring buffer of the last ``window`` consecutive samples (o_t float64 rows) and the newest Θ_k."""

    def __init__(self, window: int = WINDOW_SAMPLES):
        self.window = window
        self.obs = np.zeros((2 * window, len(OBSERVATION_FIELDS)))  # doubled: a window is always one slice
        self.known = np.zeros(len(KNOWN_PARAMS))
        self.count = 0  # consecutive samples held (saturates at window)
        self._head = 0  # next write position in [0, window)

    def clear(self) -> None:
        self.count = 0

    def push(self, obs: np.ndarray, known: np.ndarray) -> None:
        self.obs[self._head] = obs
        self.obs[self._head + self.window] = obs
        self.known[:] = known
        self._head = (self._head + 1) % self.window
        self.count = min(self.count + 1, self.window)

    @property
    def full(self) -> bool:
        return self.count == self.window

    def window_obs(self) -> np.ndarray:
        """(window, 9) oldest first; only meaningful when ``full``."""
        return self.obs[self._head : self._head + self.window]


class OnlineEstimator:
    """Samples -> window -> model -> ``Estimate`` per released tick (every ``stride``-th full window).

    ``publish(estimate)`` is called with a valid estimate at every ``stride``-th tick whose
    window is full, and with an invalid one (zeros, ``window_samples`` < 60) at the same
    stride while the window is filling, so a subscriber always knows the estimator is alive.

    Beside the window, every ``fusion.update_ticks`` consecutive samples are one stretch of
    evidence for the soil posterior (``fusion.py``); it spans the whole episode (a gap drops
    only the stretch in progress) and starts over with each episode. Every estimate carries
    its newest state (``topics.FUSED_FIELDS``, ``fused_valid`` 0 until a stretch was learnt
    from), and ``publish_map(stamp, rows)`` gets the map along the path after each stretch.
    """

    def __init__(self, model: EstimatorNet, publish: Callable[[Estimate], None], *, stride: int = 1,
                 reorder_ticks: int = 3, warn: Warn = _no_warn, fusion: FusionConfig | None = None,
                 publish_map: Callable[[int, np.ndarray], None] | None = None):
        check_compatible(model)
        self.model = model.eval()
        self.publish = publish
        self.stride = self._check_stride(stride)
        self.warn = warn
        self.counters = Counters()
        self.buffer = WindowBuffer(WINDOW_SAMPLES)
        self.assembler = SampleAssembler(self._on_sample, reorder_ticks=reorder_ticks, warn=warn, counters=self.counters,
                                         on_restart=self._on_restart)
        self.assembler.on_expected_restart = self._restart_at
        self._tick = 0  # released ticks since the last reset (stride phase)
        self._last_tick_ns = -1  # the newest tick through the stride phase, estimated or dropped (-1: none this stream)
        self.window_first_stamp = -1  # stamp of the oldest sample since the window was last emptied
        self._boundary: int | None = None  # last stamp of the previous episode: later samples start a new window
        # Every such boundary no sample has passed yet, oldest first: events can overtake the ticks of
        # more than one episode (a replay of bags in a row, faster than this node), and one boundary,
        # overwritten by the next episode's end, let a window and posterior run on across episodes.
        self._pending: list[int] = []
        self._stream_first_ns: int | None = None  # the first sample's stamp since the stream (re)started
        self._open_first: int | None = None  # first stamp of the episode whose start was taken and whose end has not come
        self._ended_at: int | None = None  # last stamp of the episode whose end was the last event taken
        # Blade travel [m] and time [s] in soil since the episode's first tick, for models with
        # terms on them (extra_terms compaction_hardening, a discovered form on time); known only
        # for an episode seen from its start.
        self._forget_path(known=False)
        self._fusion_config = fusion  # as given: a new model's physics is merged into it (set_model)
        self.fusion = PathFusion(SoilPosterior(config_for_model(fusion, model)))
        self._not_a_soil_run = 0  # stretches in a row whose posterior was no soil (``SoilPosterior.not_a_soil``)
        self.soil_map = SoilMap()
        self.publish_map = publish_map
        self._fused = fused_values(None, self.posterior.cfg)

    @property
    def posterior(self) -> SoilPosterior:
        return self.fusion.posterior

    def _reset_fusion(self) -> None:
        """A new path: the posterior back to the prior, no stretch in progress, an empty map."""
        self.fusion.reset()
        self._not_a_soil_run = 0
        self.soil_map.clear()
        self._fused = fused_values(None, self.posterior.cfg)

    @staticmethod
    def _check_stride(stride) -> int:
        if not isinstance(stride, int) or isinstance(stride, bool) or not 1 <= stride <= MAX_STRIDE_TICKS:
            raise ValueError(f"stride={stride!r} must be an integer in [1, {MAX_STRIDE_TICKS}] ticks (at least one "
                             "estimate a minute: a larger stride left the planner without any)")
        return stride

    def set_stride(self, stride: int) -> None:
        self.stride = self._check_stride(stride)

    def set_model(self, model: EstimatorNet, fusion: FusionConfig | None = None) -> None:
        """Swap the model (a retrained checkpoint); the window is kept: inputs mean the same.
        The posterior keeps what it learnt unless the new model's physics (its catalogue terms)
        is another, or ``fusion`` (a new posterior config, e.g. another world's calibration)
        changes it, which makes that evidence mean something else: then it starts over."""
        check_compatible(model)
        self.model = model.eval()
        if fusion is not None:
            self._fusion_config = fusion
        cfg = config_for_model(self._fusion_config, model)
        if cfg != self.posterior.cfg:
            self.fusion = PathFusion(SoilPosterior(cfg))
            self._reset_fusion()

    def uncalibrated_physics(self) -> str:
        """``fusion_calibration.uncalibrated_physics`` of the posterior's config as given and the model."""
        return uncalibrated_physics(self._fusion_config or load_calibrated(DEFAULT_WORLD), self.model)

    def reset(self, first_stamp_ns: int | None = None) -> None:
        """Forget everything: empty window; stamps from ``first_stamp_ns`` on are expected."""
        self.buffer.clear()
        self.assembler.reset(first_stamp_ns)
        self._tick = 0
        self._last_tick_ns = -1 if first_stamp_ns is None else int(first_stamp_ns) - 1
        self._boundary = None
        self._pending = []
        self._stream_first_ns = None
        self._open_first = None
        self._ended_at = None
        self._forget_path(known=False)
        self._reset_fusion()

    def _forget_path(self, known: bool) -> None:
        """Travel and time in soil back to 0; ``known``: counted from an episode's start. (And the
        forward-cutting ticks the force's sign is judged on, ``stream_checks.sign_problem``.)"""
        self.distance_m = self.time_in_soil_s = 0.0
        self._path_known = known
        self._cutting = [0, 0]  # (forward-cutting ticks, those with f_x < 0)

    def end_episode(self, last_stamp_ns: int) -> None:
        """``episode_end``: samples after ``last_stamp_ns`` start a fresh window. Ticks up to it
        that are still queued complete this episode's windows normally (the executor serves
        /sim/status first, so the event can overtake the episode's last ticks).

        The end of an episode whose boundary ticks after it have crossed already (a late copy of the
        event) changes nothing: pending again, it had restarted the next episode's stride phase, path
        and soil posterior at its next tick (a reviewer's)."""
        last = int(last_stamp_ns)
        if self._boundary is not None and last <= self._boundary and last not in self._pending \
                and self.assembler.last_released > last:
            return
        self._set_boundary(last)
        self.assembler.episode_ended(last)
        self._open_first = None
        self._ended_at = last
        self.assembler.expect_restart(None)
        self.assembler.regrid(last + 1)

    @property
    def owes_ended_episode(self) -> bool:
        """The last event taken was an ``episode_end`` whose last tick is not released yet: ticks
        still queued would finish that episode's estimates. Why: a lockstep simulator ends seconds
        of simulated time ahead of this estimator, and a node stopped then lost the episode's last
        estimates (139 of 600 in an outside tester's demo beside a busy machine)."""
        return self._ended_at is not None and self.assembler.last_released < self._ended_at

    @property
    def ended_at_ns(self) -> int | None:
        """The last stamp of the episode whose end was the last event taken (None: none, or a new one began)."""
        return self._ended_at

    def start_episode(self, first_stamp_ns: int) -> None:
        """``episode_start``: the window holds only samples from ``first_stamp_ns`` on.

        Ticks of this episode that overtook the event (status and data are separate topics)
        are kept; older ticks still queued finish the previous episode's windows; if time
        went back (a replay starting over), everything restarts at ``first_stamp_ns``.

        A start at or before one the stream is already past, whose ticks did not start the stream
        (the episode under way never ended, or the node joined it midway), is either this
        episode's event again (a late or repeated delivery: nothing changes) or its source
        starting over (a simulator killed and started again, stamps from 0 again). The ticks tell
        them apart: the first one stamped back at ``first_stamp_ns`` restarts everything there.
        (Restarting at once reset a live episode on a repeated event; waiting for a stream restart
        refused the new episode's first ticks as far back and lost them: the estimates differed
        from a replay's, an outside tester's.)"""
        first = int(first_stamp_ns)
        self.assembler.regrid(first)
        self.assembler.episode_started(first)
        if self._ended_at is not None and first > self._ended_at:
            self._ended_at = None  # a new episode is under way: stopping now stops it midway
        open_first, self._open_first = self._open_first, first
        self.assembler.expect_restart(None)
        if self.assembler.last_released < first:  # nothing of this episode released yet
            self._set_boundary(first - 1)
            self._last_tick_ns = max(self._last_tick_ns, first - 1)  # (its ticks from ``first`` on are due)
            return
        stream_first = self._stream_first_ns
        if open_first is not None and first <= open_first:  # (a later first: a new episode, its end lost)
            self._open_first = open_first
            self.assembler.expect_restart(first)
            return
        if self._boundary is None and stream_first is not None and stream_first >= first:
            if stream_first - first > MAX_OVERTAKING_TICKS * PERIOD_NS:  # joined midway, not overtaken
                # (a tick stamped before the stream's first cannot be a late one of the ticks it took)
                self.assembler.expect_restart(first, before_ns=stream_first)
                return
            # The stream began with this episode's ticks (they overtook the event, e.g. a replay's
            # first tick): window, stride phase, path and posterior all started with the episode,
            # as if the event had come first; restarting would lose those ticks (replay != live).
            self._boundary = first - 1  # (crossed already: not pending)
            self._path_known = True
            return
        if self._boundary is not None and self._boundary < first <= self.window_first_stamp:
            return  # the window already started after the previous episode, at or after this one's start
        self._restart_at(first)

    def _restart_at(self, first: int) -> None:
        """Everything restarts with the episode that begins at ``first`` (its episode_start taken)."""
        self.reset(first)
        self._set_boundary(first - 1)
        self._path_known = True
        self._open_first = first

    def add(self, topic: str, msg) -> None:
        self.assembler.add(topic, msg)

    def _set_boundary(self, last_ns: int) -> None:
        """Samples after ``last_ns`` belong to a new episode: the first of them starts a new window.
        Pending boundaries beyond it go: a graph's events come in stamp order, so they were a stray
        event's (a start or end far ahead, which had lingered and reset a later episode midway)."""
        self._boundary = last_ns
        if last_ns not in self._pending:  # (the same boundary again, a repeated event, drops none)
            self._pending = [b for b in self._pending if b < last_ns] + [last_ns]

    def _on_restart(self) -> None:
        self._boundary = None
        self._pending = []
        self._open_first = None
        self._ended_at = None  # (a stream started over: the ended episode's ticks are not coming)
        self.assembler.expect_restart(None)  # (an episode_start before this stream's is no longer in question)
        self._stream_first_ns = None
        self._tick = 0
        self._last_tick_ns = -1
        self._forget_path(known=False)
        self._reset_fusion()

    def _on_sample(self, stamp: int, sample: Sample | None) -> None:
        if self._pending and stamp > self._pending[0]:
            # the first tick of a new episode (a sample, or one dropped): no window spans two,
            crossed = max(b for b in self._pending if b < stamp)
            self._pending = [b for b in self._pending if b >= stamp]
            if self.buffer.count and self.window_first_stamp <= crossed:
                self.buffer.clear()
            self._tick = 0  # and the stride phase starts with the episode (live == replay)
            self._forget_path(known=True)
            self._reset_fusion()
        if sample is None:  # missing, broken or out of order: nothing estimated across it
            self.buffer.clear()
            self.fusion.gap()  # nor fused: the stretch in progress is dropped, the posterior kept
            self._dropped(stamp)
            return
        if self._stream_first_ns is None:
            self._stream_first_ns = stamp
        if self.buffer.count == 0:
            self.window_first_stamp = stamp
        self.buffer.push(sample.obs, sample.known)
        self._judge_sign(sample)
        self.distance_m += float(soil_advance(sample.known[_V_X], sample.known[_D]))
        self.time_in_soil_s += float(soil_time_step(sample.known[_D]))
        self._fuse(stamp, sample)
        self._last_tick_ns = stamp
        tick, self._tick = self._tick, self._tick + 1
        if tick % self.stride:
            return
        if not self.buffer.full or ((self.model.needs_distance or self.model.needs_time) and not self._path_known):
            # (a model with a distance or time term needs the episode from its start: invalid until one begins)
            self.counters.invalid += 1
            self.publish(self._with_fused(invalid_estimate(stamp, self.buffer.count)))
            return
        est = self.estimate(stamp)
        if est.valid:
            self.counters.estimates += 1
        else:
            self.counters.invalid += 1
        self.publish(self._with_fused(est))

    def _dropped(self, stamp: int) -> None:
        """A tick dropped (two messages of a topic, a broken value, a topic missing, off the rate)
        gets an invalid estimate in its stride phase, as a tick the window is still filling after.
        Why: a lockstep planner plans a tick once its estimate is in, and the controller waits for
        that plan; one duplicate /blade/force cost the loop the controller's ``planner_wait_s``
        (2 s) and the cut differed from a clean run's. Not for a stamp already through the phase
        (an out-of-order or gap report names the last tick), nor in a stream that restarted without
        an episode_start before a tick of it was taken (-1): a hostile node's copies stamped seconds
        back had restarted the stream, and their incomplete ticks were estimated a second time at
        stamps already published. A new episode's first tick dropped has begun the episode
        (``_on_sample``): its fused fields are the prior's."""
        if self._last_tick_ns < 0 or stamp <= self._last_tick_ns:
            return
        self._last_tick_ns = stamp
        tick, self._tick = self._tick, self._tick + 1
        if tick % self.stride == 0:
            self.counters.invalid += 1
            self.publish(self._with_fused(invalid_estimate(stamp, self.buffer.count)))

    def _judge_sign(self, sample: Sample) -> None:
        """Said (judged every 60 forward-cutting ticks, as the node's limiter lets it through): a
        measured force of the other sign than the contract's (a machine's sensor; its estimates are
        not the soil's, and nothing else said so)."""
        cutting, negative = cutting_ticks(sample.force[0], sample.known[_D], sample.known[_V_X])
        self._cutting[0] += cutting
        self._cutting[1] += negative
        if self._cutting[0] % SIGN_JUDGE_TICKS == 0 and cutting and (problem := sign_problem(*self._cutting)):
            self.warn("force_sign", problem)

    def _fuse(self, stamp: int, sample: Sample) -> None:
        """One sample into the stretch; a complete stretch into the posterior and the map."""
        if not self.fusion.add(sample.force, sample.known, self.distance_m, sample.obs, self.time_in_soil_s):
            return
        summary = self.posterior.summary()
        self._fused = fused_values(summary, self.posterior.cfg)
        problem = self.posterior.not_a_soil(summary)
        self._not_a_soil_run = self._not_a_soil_run + 1 if problem else 0
        if self._not_a_soil_run == NOT_A_SOIL_STRETCHES:  # held that long (an early posterior passes such corners)
            self.warn("not_a_soil", f"{problem} (for {NOT_A_SOIL_STRETCHES} stretches in a row)")
        if self.soil_map.add(float(sample.obs[_P_X]), float(sample.obs[_P_Z]), summary) and self.publish_map:
            self.publish_map(stamp, self.soil_map.rows())

    def _with_fused(self, est: Estimate) -> Estimate:
        est.values[FUSED] = self._fused
        return est

    @torch.inference_mode()
    def estimate(self, stamp: int) -> Estimate:
        """Run the model on the current (full) window; invalid if any output is not finite."""
        obs = torch.as_tensor(self.buffer.window_obs(), dtype=torch.float32).unsqueeze(0)
        known = torch.as_tensor(self.buffer.known, dtype=torch.float32).unsqueeze(0)
        distance = torch.tensor([self.distance_m], dtype=torch.float32)
        time_in_soil = torch.tensor([self.time_in_soil_s], dtype=torch.float32)
        values = estimate_values(self.model(obs, known, distance, time_in_soil))[0]
        values[T.ESTIMATE_FIELDS.index("window_samples")] = self.buffer.count
        if not np.isfinite(values).all():
            self.counters.model_non_finite += 1
            bad = T.ESTIMATE_FIELDS[int(np.flatnonzero(~np.isfinite(values))[0])]
            self.warn("model_non_finite", f"model output {bad} is not finite at stamp {stamp} ns; published as invalid")
            return invalid_estimate(stamp, self.buffer.count)
        force = values[[_F_X_HAT, _F_Z_HAT]]
        if (np.abs(force) > IMPLAUSIBLE_ESTIMATE_FACTOR * np.asarray(FORCE_LIMITS_N)).any():
            self.counters.model_implausible += 1
            self.warn("model_implausible", f"model output F̂ = ({force[0]:.3g}, {force[1]:.3g}) N at stamp {stamp} ns is "
                      f"more than {IMPLAUSIBLE_ESTIMATE_FACTOR:g} times the machine's force limits ({FORCE_LIMITS_N[0] / 1e3:g} / "
                      f"{FORCE_LIMITS_N[1] / 1e3:g} kN): no cut of this machine meets it (a model whose training diverged, "
                      "or of another machine?); published as invalid")
            return invalid_estimate(stamp, self.buffer.count)
        return Estimate(int(stamp), values)


def estimate_values(out: dict) -> np.ndarray:
    """(B, len(ESTIMATE_FIELDS)) ``/soil/estimate`` values of a PINN output dict, valid = 1, the
    fused fields 0 (``fused_valid`` 0).

    The one mapping from model outputs to the message, used online and offline (so the
    replay and offline comparisons compare like with like)."""
    parts = [out["theta"][:, : len(UNKNOWN_PARAMS)], out["force"], out["force_fee"], out["force_residual"]]
    values = torch.cat([p.double() for p in parts], dim=1).numpy()
    flags = np.tile([[1.0, WINDOW_SAMPLES]], (len(values), 1))
    fused = np.zeros((len(values), len(T.FUSED_FIELDS)))  # filled by the caller that fuses (OnlineEstimator)
    return np.concatenate([values, flags, fused], axis=1)
