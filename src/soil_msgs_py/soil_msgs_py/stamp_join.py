"""Join messages of several topics that carry the same header stamp (no ROS; cf. ROS
``message_filters`` ExactTime synchronizer).

Every per-tick message carries its tick's simulation time, and DDS orders each topic but not
topics against each other, so every consumer pairs by stamp. ``StampJoiner`` is the one place
that does it; where consumers genuinely differ (what a repeated message means, how far back
a stamp may go, how long an incomplete tick may wait) they say so in constructor arguments.

Policy (stamps are integer ns):

* A *set* is the messages of one stamp, at most one per topic; it is complete once every
  topic has one.
* Sets leave in stamp order (``Joined`` items, returned by ``offer``). The oldest pending set
  leaves as soon as it is complete; while incomplete it blocks newer sets until a complete set
  at least ``reorder_ns`` newer exists, then it leaves incomplete (``OVERTAKEN``).
  ``reorder_ns=0``: give up an incomplete set as soon as any newer set is complete.
* A stamp not newer than the last set that left (or before ``reset``'s first stamp) is
  ``STALE`` and refused; one more than ``restart_back_ns`` behind it means the source started
  over (a bag replayed again): everything pending is forgotten and the stamp starts a new
  stream (``RESTART``, taken).
* A stamp more than ``max_ahead_ns`` past the next expected stamp is ``FUTURE`` and refused
  (``0``: only the stamp given to ``reset``).
* After ``restart_after_refused`` refusals in a row (STALE or FUTURE, nothing taken between)
  the source is taken to have moved on for good: the stamp refused last starts a new stream
  (``RESTART``, taken). One stray message (a far-future pair from another node) is refused
  and changes nothing; a stream that really jumped is followed after a short while rather
  than ignored for ever. ``0``: never.
* A second message of a topic for a pending stamp is ``DUPLICATE``; ``duplicates`` says what
  happens to it: ``"replace"`` (the newest counts), ``"keep_first"`` (it is dropped) or
  ``"spoil"`` (the set is marked bad: the tick is not to be trusted).
* ``slot_ns`` (0: off): stamps closer than this are one tick's. A set within ``slot_ns`` of the
  set that left last, or an incomplete one within it of a complete pending set (or of another
  pending set, once it would be given up), is the same tick under a second stamp (another
  writer's, 1 ns off the grid): it leaves as ``STRAY``, without moving the order on, so a tick
  is never given out twice and a stray never makes the real tick wait or leave incomplete. Of
  two incomplete sets of one tick the one with fewer messages is the stray. A stream that starts
  a new phase (``new_phase``: an episode whose ticks may keep another phase) is no stray of the
  set that left before it.
* At most ``max_pending`` sets wait; beyond that the one that has waited longest leaves
  (``EVICTED``, out of stamp order and without moving the order on). Longest waiting, not
  lowest stamp, so a burst of bogus future stamps ages out instead of pushing out real ticks.
"""
from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import Any, NamedTuple

from .params import SAMPLE_RATE_HZ

DUPLICATE_POLICIES = ("replace", "keep_first", "spoil")
# Messages refused this many ticks in a row (each of a joiner's topics) mean the stream's time
# really jumped, not that one stray message came: the nodes' ``restart_after_refused`` per topic.
RESTART_AFTER_REFUSED_TICKS = SAMPLE_RATE_HZ // 2


class Verdict(enum.Enum):
    """What ``offer`` did with one message."""

    TAKEN = "taken"
    DUPLICATE = "duplicate"  # its topic already has a message for this stamp (see ``duplicates``)
    STALE = "stale"  # not newer than the last set that left: refused
    FUTURE = "future"  # beyond ``max_ahead_ns``: refused
    RESTART = "restart"  # far back (or refused ``restart_after_refused`` times in a row): a new stream, taken


class Why(enum.Enum):
    """Why a set left the joiner."""

    COMPLETE = "complete"
    OVERTAKEN = "overtaken"  # a complete set ``reorder_ns`` newer exists: given up
    EVICTED = "evicted"  # ``max_pending`` sets were waiting: the longest waiting was dropped
    STRAY = "stray"  # within ``slot_ns`` of another set of the same tick (see ``slot_ns``): dropped
    DRAINED = "drained"  # ``drain`` gave up every pending set


@dataclass
class Joined:
    """One stamp's messages as they left the joiner."""

    stamp_ns: int
    parts: dict[str, Any] = field(default_factory=dict)  # topic -> payload, in arrival order
    missing: tuple[str, ...] = ()  # topics that never came (empty when complete)
    bad: str = ""  # why the set must not be used ('' when it may): the first reason given
    why: Why = Why.COMPLETE
    previous_ns: int = -1  # the stamp that left in order before this one (-1: none since reset)
    twin_ns: int = -1  # STRAY: the stamp of the set of the same tick it was dropped beside

    @property
    def complete(self) -> bool:
        return not self.missing

    @property
    def usable(self) -> bool:
        """Complete and not marked bad."""
        return not self.missing and not self.bad


class Offer(NamedTuple):
    verdict: Verdict
    out: list[Joined]  # sets that left because of this offer, in the order they left


def _check_count(name: str, value: Any, lo: int, unit: str) -> None:
    if not isinstance(value, int) or isinstance(value, bool) or value < lo:
        raise ValueError(f"{name}={value!r} must be an integer >= {lo} {unit}")


class StampJoiner:
    """Messages of ``topics`` -> one ``Joined`` per stamp, in stamp order (see module doc)."""

    def __init__(self, topics, *, max_pending: int, reorder_ns: float = 0, duplicates: str = "replace",
                 restart_back_ns: float | None = None, max_ahead_ns: float | None = None,
                 restart_after_refused: int = 0, restart_counts_back_beyond_ns: float = 0, slot_ns: float = 0):
        self.topics = tuple(topics)
        if not self.topics or len(set(self.topics)) != len(self.topics):
            raise ValueError(f"topics={self.topics!r} must be distinct and at least one")
        _check_count("max_pending", max_pending, 1, "set")
        _check_count("restart_after_refused", restart_after_refused, 0, "messages")
        if duplicates not in DUPLICATE_POLICIES:
            raise ValueError(f"duplicates={duplicates!r} is not one of {DUPLICATE_POLICIES}")
        for name, value in (("reorder_ns", reorder_ns), ("restart_back_ns", restart_back_ns),
                            ("max_ahead_ns", max_ahead_ns), ("restart_counts_back_beyond_ns", restart_counts_back_beyond_ns),
                            ("slot_ns", slot_ns)):
            if value is not None and not value >= 0:
                raise ValueError(f"{name}={value!r} must be >= 0 ns")
        self.max_pending = max_pending
        self.reorder_ns = reorder_ns
        self.duplicates = duplicates
        self.restart_back_ns = restart_back_ns
        self.max_ahead_ns = max_ahead_ns
        self.restart_after_refused = restart_after_refused
        # a stale stamp this close behind is a late or repeated message (a second publisher's copies),
        # refused without counting towards a restart: a burst of such copies had started a new stream
        self.restart_counts_back_beyond_ns = restart_counts_back_beyond_ns
        self.slot_ns = slot_ns
        self._left_ns = -1  # the stamp of the set that left last in order (``slot_ns``; -1: none since reset)
        self._phase_from_ns = -1  # stamps from here on keep a phase of their own (``new_phase``)
        self._refused = 0  # refusals in a row (nothing taken since)
        self._pending: dict[int, Joined] = {}  # insertion order = how long a set has waited
        self._complete_stamps: set[int] = set()  # of the pending sets (an estimator seconds behind: few of many)
        self.last_ns = -1  # the newest stamp that left in order (or reset's first stamp - 1)
        self._expecting = False  # a next stamp is defined (reset with a first stamp, or a set left)
        self.left_since_reset = False  # a set left since the last reset (else last_ns is the first stamp - 1, or -1)
        self.announced_ns = -1  # a stream's next start, announced ahead (``announce``; -1: none)

    def __len__(self) -> int:
        """Sets waiting."""
        return len(self._pending)

    def reset(self, first_stamp_ns: int | None = None) -> None:
        """Forget every pending set; stamps from ``first_stamp_ns`` on are expected (None: any)."""
        self._pending.clear()
        self._complete_stamps.clear()
        self._refused = 0
        self._left_ns = -1
        self.last_ns = -1 if first_stamp_ns is None else int(first_stamp_ns) - 1
        self._expecting = first_stamp_ns is not None
        self.left_since_reset = False
        self.announced_ns = -1

    def start_at(self, first_stamp_ns: int) -> None:
        """A stream that starts (again) at ``first_stamp_ns`` (an episode's first tick): pending sets
        older than it are forgotten, sets of it and later keep waiting (their messages may come
        before the news of the start), and older stamps are refused from now on."""
        first = int(first_stamp_ns)
        for stamp in [s for s in self._pending if s < first]:
            del self._pending[stamp]
            self._complete_stamps.discard(stamp)
        self._refused = 0
        self._left_ns = -1  # (what left before the start is no tick of this stream)
        self.last_ns = first - 1
        self._expecting = True

    def new_phase(self, from_ns: int) -> None:
        """Sets stamped from ``from_ns`` on may keep another phase than those before (a new episode of
        a machine or a bag): one within ``slot_ns`` of the set that left before it is no stray of it."""
        self._phase_from_ns = int(from_ns)

    def announce(self, first_stamp_ns: int) -> None:
        """The stream goes on at ``first_stamp_ns`` (an episode announced after the last one ended):
        ``max_ahead_ns`` counts from there too, not only from the last set that left, so a hole
        between two episodes longer than it is no jump of the stream. Sets before it still come."""
        self.announced_ns = int(first_stamp_ns)

    def bad(self, stamp_ns: int) -> str:
        """Why the pending set of ``stamp_ns`` is marked bad ('' if it is not, or none is pending)."""
        pending = self._pending.get(stamp_ns)
        return pending.bad if pending is not None else ""

    def offer(self, topic: str, stamp_ns: int, payload: Any = None, *, bad: str = "") -> Offer:
        """One message; ``bad`` (non-empty) marks its stamp's set as not to be used, with the reason.

        Returns the verdict on the message and the sets that left because of it."""
        if topic not in self.topics:
            raise ValueError(f"topic {topic!r} is not one of {self.topics}")
        stamp_ns = int(stamp_ns)
        verdict = Verdict.TAKEN
        refused = None
        if stamp_ns <= self.last_ns:
            if self.restart_back_ns is None or self.last_ns - stamp_ns <= self.restart_back_ns:
                refused = Verdict.STALE
            else:
                self.reset(stamp_ns)
                verdict = Verdict.RESTART
        elif (self.max_ahead_ns is not None and self._expecting
              and stamp_ns - max(self.last_ns + 1, self.announced_ns) > self.max_ahead_ns):
            refused = Verdict.FUTURE
        if refused is Verdict.STALE and self.last_ns - stamp_ns <= self.restart_counts_back_beyond_ns:
            return Offer(refused, [])  # (neither counted nor ending a count)
        if refused is not None:
            self._refused += 1
            if not self.restart_after_refused or self._refused < self.restart_after_refused:
                return Offer(refused, [])
            self.reset(stamp_ns)
            verdict = Verdict.RESTART
        self._refused = 0
        joined = self._pending.get(stamp_ns)
        if joined is None:
            joined = self._pending[stamp_ns] = Joined(stamp_ns)
        if topic in joined.parts:
            verdict = Verdict.DUPLICATE
            if self.duplicates == "spoil":
                joined.bad = joined.bad or f"{topic} twice"
            if self.duplicates != "keep_first":
                joined.parts[topic] = payload
        else:
            joined.parts[topic] = payload
        joined.bad = joined.bad or bad
        if self._complete(joined):
            self._complete_stamps.add(stamp_ns)
        out = self._evict()
        out += self._release()
        return Offer(verdict, out)

    def newest_stamp_ns(self) -> int | None:
        """The newest stamp waiting (None: nothing waits)."""
        return max(self._pending, default=None)

    def drain(self) -> list[Joined]:
        """Give up every pending set, oldest stamp first (the end of a stream)."""
        out = []
        for stamp in sorted(self._pending):
            if stamp not in self._pending:
                continue  # (given up as the stray of an older set of its tick)
            if self.slot_ns and (twin := self._twin(stamp, incomplete_too=True)) is not None:
                out.append(self._stray(*self._weaker(stamp, twin)) if twin in self._pending else self._stray(stamp, twin))
                if stamp not in self._pending:
                    continue
            out.append(self._leave(stamp, Why.DRAINED))
        return out

    # ------------------------------------------------------------------ internals
    def _complete(self, joined: Joined) -> bool:
        return len(joined.parts) == len(self.topics)

    def _evict(self) -> list[Joined]:
        out = []
        while len(self._pending) > self.max_pending:
            waited = next(iter(self._pending))
            gone = self._pending.pop(waited)
            self._complete_stamps.discard(waited)
            gone.missing, gone.why, gone.previous_ns = self._missing(gone), Why.EVICTED, self.last_ns
            out.append(gone)
        return out

    def _release(self) -> list[Joined]:
        out = []
        while self._pending:
            oldest = min(self._pending)
            if self.slot_ns and (twin := self._twin(oldest)) is not None:
                out.append(self._stray(oldest, twin))
            elif not self._complete(self._pending[oldest]):
                newest_complete = max(self._complete_stamps, default=None)
                if newest_complete is None or newest_complete - oldest < self.reorder_ns:
                    break
                if self.slot_ns and (twin := self._twin(oldest, incomplete_too=True)) is not None:
                    # two incomplete sets of one tick: the one with fewer messages is the stray, the
                    # other speaks for the tick (given up as it comes next, or now)
                    out.append(self._stray(*self._weaker(oldest, twin)))
                else:
                    out.append(self._leave(oldest, Why.OVERTAKEN))
            else:
                out.append(self._leave(oldest, Why.COMPLETE))
        return out

    def _twin(self, stamp: int, incomplete_too: bool = False) -> int | None:
        """The stamp of another set of the tick of the pending set ``stamp`` (``slot_ns``) that makes
        it a stray: the set that left last, a complete pending one if it is incomplete, or (once it
        would be given up) any pending one. None: it is its tick's only set."""
        if (self._left_ns >= 0 and abs(stamp - self._left_ns) < self.slot_ns
                and not self._left_ns < self._phase_from_ns <= stamp):
            return self._left_ns
        if self._complete(self._pending[stamp]):
            return None
        near = [s for s in (self._pending if incomplete_too else self._complete_stamps)
                if s != stamp and abs(s - stamp) < self.slot_ns]
        return min(near, default=None)

    def _weaker(self, stamp: int, twin: int) -> tuple[int, int]:
        """(stray, the set it lies beside) of two pending sets of one tick: the one with fewer
        messages is the stray; of two alike, the newer (its stamp farther from the order's)."""
        a, b = len(self._pending[stamp].parts), len(self._pending[twin].parts)
        return (stamp, twin) if a < b or (a == b and stamp > twin) else (twin, stamp)

    def _stray(self, stamp: int, twin: int) -> Joined:
        gone = self._pending.pop(stamp)
        self._complete_stamps.discard(stamp)
        gone.missing, gone.why, gone.previous_ns, gone.twin_ns = self._missing(gone), Why.STRAY, self.last_ns, twin
        return gone

    def _leave(self, stamp: int, why: Why) -> Joined:
        gone = self._pending.pop(stamp)
        self._complete_stamps.discard(stamp)
        gone.missing, gone.why, gone.previous_ns = self._missing(gone), why, self.last_ns
        self.last_ns, self._expecting, self.left_since_reset = stamp, True, True
        self._left_ns = stamp
        return gone

    def _missing(self, joined: Joined) -> tuple[str, ...]:
        return tuple(t for t in self.topics if t not in joined.parts)
