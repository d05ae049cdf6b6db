"""Which writer sent a message, told apart by DDS publication sequence numbers (no ROS).

rclpy's message info carries no publisher gid, only the writer's publication sequence
number (1, 2, 3, ... per writer and topic). A per-tick publisher sends at most one message
per tick, so between two of its messages its counter grows by at least 1 and by at most
the number of ticks between their stamps (less when it skipped ticks). A message whose
sequence number does that *continues* the writer; another publisher has its own counter,
which continues this one only if the two happen to line up at that very tick. Sequence
continuity rather than a fixed "sequence minus tick" offset, because a publisher that
skips a tick shifts its offset for good but still continues its own counter.

The writer a consumer follows on a topic is the one that has sent the most ticks: the
publisher that is there every tick, whichever message of a tick arrives first; of writers
tied on ticks, the one heard first (a newcomer must overtake it). The simulator's command
gate and the recorder while recording decide in arrival order with :class:`WriterTracks`
(for the recorder the rule only decides when an episode looks complete: a second publisher
heard first at the same rate would leave the episode to its grace timeout); a journal
becoming a bag is judged as a whole with :func:`leading_chain`, where a tie means nothing
can be judged (``leader`` says the same of the writers tracked so far).
"""
from __future__ import annotations

import bisect
from collections.abc import Sequence
from dataclasses import dataclass

from .messages import NS_PER_S
from .params import SAMPLE_RATE_HZ, tick_stamp_ns, ticks_in

SEQUENCE_MASK = 0xFFFF_FFFF  # MCAP stores a uint32 sequence; DDS counts in int64: compare modulo 2^32
# A command writer silent this many ticks is forgotten by those who follow the controller's
# commands live (the simulator's gate, the planner): a restarted controller (a new sequence
# counter) is followed once its predecessor has gone quiet for 2 s.
FORGET_WRITER_AFTER_TICKS = 2 * SAMPLE_RATE_HZ


def tick_index(stamp: int, first_stamp_ns: int) -> int | None:
    """k if ``stamp`` is the episode's tick stamp ``first + tick_stamp_ns(k)`` (how the simulator and
    the batch generator stamp), else None (off the 60 Hz grid)."""
    d = stamp - first_stamp_ns
    if d < 0:
        return None
    k = -(-d * SAMPLE_RATE_HZ // NS_PER_S)  # the only tick whose floored stamp can equal d
    return k if tick_stamp_ns(k) == d else None


def tick_number(stamp_ns: int) -> int:
    """The nearest 60 Hz tick counted from stamp 0: consecutive episodes continue one grid,
    so this counts ticks across episodes too."""
    return (int(stamp_ns) * SAMPLE_RATE_HZ + NS_PER_S // 2) // NS_PER_S


@dataclass
class _Writer:
    ident: int
    last_sequence: int
    last_tick: int
    ticks: int = 1  # messages that continued it


class WriterTracks:
    """The writers seen on one topic, each followed by sequence continuity (module doc).

    Feed messages in stamp order: a message stamped far ahead with a higher counter would
    otherwise pass for the next one of the writer it is compared with.

    ``forget_after_ticks``: a writer silent that long is forgotten, so a restarted publisher
    (a new counter) is followed once the old one has gone (None: never forget, for a
    recording judged as a whole). At most ``max_writers`` are kept (the smallest go).
    """

    def __init__(self, forget_after_ticks: int | None = None, max_writers: int = 16):
        self.forget_after_ticks = forget_after_ticks
        self.max_writers = max_writers
        self._writers: dict[int, _Writer] = {}
        self._next_ident = 0

    def observe(self, sequence: int | None, tick: int, now_tick: int | None = None) -> int | None:
        """The writer (an id) of a message with publication ``sequence`` for ``tick``; None when
        the sequence number is unknown (None or 0: the rmw gave none). ``now_tick``: how far the
        stream has got, which silences are judged against (default ``tick``; a consumer that takes
        messages stamped ahead of the stream must give it, else one message stamped 2 s ahead
        makes every writer look silent and be forgotten)."""
        if not sequence:
            return None
        sequence &= SEQUENCE_MASK
        if self.forget_after_ticks is not None:
            now = tick if now_tick is None else now_tick
            self._writers = {i: w for i, w in self._writers.items()
                             if now - w.last_tick <= self.forget_after_ticks}
        fits = [w for w in self._writers.values()
                if 0 < (sequence - w.last_sequence) & SEQUENCE_MASK <= tick - w.last_tick]
        if fits:
            writer = max(fits, key=lambda w: w.ticks)
            writer.last_sequence, writer.last_tick, writer.ticks = sequence, tick, writer.ticks + 1
            return writer.ident
        if len(self._writers) >= self.max_writers:
            del self._writers[min(self._writers.values(), key=lambda w: w.ticks).ident]
        writer = self._writers[self._next_ident] = _Writer(self._next_ident, sequence, tick)
        self._next_ident += 1
        return writer.ident

    def leads(self, ident: int | None) -> bool:
        """Whether ``ident`` is the writer followed now: the most ticks, and of writers tied on
        ticks the one heard first (an unknown writer, None, is never judged: True).

        Why ties go to the writer heard first: a newcomer must overtake, not merely equal, the
        writer already followed. Early in an episode the controller has answered one or two
        ticks; an intruder's first copy of a tick (its own fresh counter, one tick) that
        arrives before the controller's would otherwise tie and be taken."""
        if ident is None or ident not in self._writers:
            return ident is None
        return ident == max(self._writers.values(), key=lambda w: (w.ticks, -w.ident)).ident

    def leader(self) -> int | None:
        """The one writer with the most ticks; None if none was seen or several tie (then
        the sequence numbers tell nothing about which one to trust)."""
        ranked = sorted(self._writers.values(), key=lambda w: w.ticks, reverse=True)
        if not ranked or (len(ranked) > 1 and ranked[1].ticks == ranked[0].ticks):
            return None
        return ranked[0].ident


def leading_chain(ticks: Sequence[int], sequences: Sequence[int],
                  weights: Sequence[int] | None = None, *, apart_ties: bool = False) -> set[int] | None:
    """Indices of the messages the leading writer sent, judged over a whole recording; None if
    nothing can be judged or two writers tie.

    A writer's messages form a *chain*: in tick order its counter grows by at least 1 and by
    at most the ticks between them (module doc), i.e. the sequence number rises strictly
    while ``sequence - tick`` never rises. The leader is the heaviest chain (``weights``,
    default 1 per message). Judged message by message in arrival order (``WriterTracks``) an
    intruder's counter that lands in a gap the writer left (a skipped tick) continues the
    writer and pushes the writer's next message out as a stranger's; judged as a whole, the
    writer's counter grows by exactly one per message, so the intruder's message can only
    take the place of one or more of the writer's, and weights (e.g. plausible values) decide
    that exchange. O(n log n): a Fenwick tree of the best chain over ``sequence - tick``.

    Ties: if the heaviest chain among the remaining messages weighs as much, the writers
    cannot be told apart by their counters (None); with ``apart_ties``, unless the two chains'
    ticks do not interleave (one writer after the other: the heavier-first chain is returned,
    the other is left for the caller to judge apart).
    """
    n = len(ticks)
    if n == 0:
        return None
    w = [1] * n if weights is None else [int(x) for x in weights]
    seq = _unwrapped([int(s) & SEQUENCE_MASK for s in sequences])
    ticks = [int(t) for t in ticks]
    best = _heaviest_chain(ticks, seq, w, range(n))
    if best is None:
        return None
    chain, weight = best
    rest = [i for i in range(n) if i not in chain]
    runner_up = _heaviest_chain(ticks, seq, w, rest) if rest else None
    if runner_up is not None and runner_up[1] == weight:
        if not apart_ties or _interleave([ticks[i] for i in chain], [ticks[i] for i in runner_up[0]]):
            return None
    return chain


def _interleave(a: Sequence[int], b: Sequence[int]) -> bool:
    """Whether two sets of ticks overlap in range (neither lies wholly before the other)."""
    return not (max(a) < min(b) or max(b) < min(a))


# A writer kept beside the leading one (``succession``) has sent at least half a second of the
# topic's messages (30 ticks at 60 Hz), and at least two: a restarted node publishes on, a stray
# intruder's plausible message in a silent stretch does not get in. Counted in the topic's own
# messages, not ticks: a restarted estimator's 2 Hz map, 26 maps in 13 s, had been refused as
# an intruder's under a rule of 30 messages (an outside tester's).
SUCCESSOR_MIN_S = 0.5
SUCCESSOR_MIN_MESSAGES = ticks_in(SUCCESSOR_MIN_S)


def typical_spacing(ticks: Sequence[int]) -> int:
    """The median step [ticks] between a writer's messages at ``ticks`` (1 for fewer than two)."""
    ordered = sorted(set(ticks))
    steps = sorted(b - a for a, b in zip(ordered, ordered[1:]))
    return max(steps[len(steps) // 2], 1) if steps else 1


def successor_min_messages(ticks: Sequence[int]) -> int:
    """Messages a successor must have sent on a topic whose writer sent at ``ticks``: half a second
    of them at the topic's typical spacing, at least 2 and at most SUCCESSOR_MIN_MESSAGES."""
    return _min_messages_at(typical_spacing(ticks))


def _min_messages_at(spacing: int) -> int:
    """``successor_min_messages`` of a writer ``spacing`` ticks between its messages."""
    return max(2, min(SUCCESSOR_MIN_MESSAGES, -(-SUCCESSOR_MIN_MESSAGES // spacing)))


def succession(ticks: Sequence[int], sequences: Sequence[int], chain: set[int],
               eligible: Sequence[bool] | None = None,
               max_silence_ticks: int = FORGET_WRITER_AFTER_TICKS, min_messages: int | None = None) -> set[int]:
    """The writers of a recording one after another, from its leading ``chain``: a publisher that
    died and was restarted (or replaced) starts a new counter, which no rule of continuity joins
    to its predecessor's, so judged as a whole either it or its predecessor leads and the other's
    messages would be refused; and once the new counter passes the old one's last number, its
    tail continues the old chain. So the chain is cut where it is silent for more than
    ``max_silence_ticks`` (a writer that long silent is gone, as those who follow writers live
    take it: ``WriterTracks``) or where, within one of its gaps longer than twice its typical step,
    SUCCESSOR_MIN_MESSAGES or more carry numbers below its own (a counter that started again), its longest stretch is kept, and each span of ticks before and
    after that stretch is judged the same way on its own (its leading chain, where two tie only
    if their ticks interleave, cut, its longest stretch, ...). A writer whose ticks interleave
    with a kept stretch's is an intruder and gets nothing there; one beside it keeps its
    messages only if it sent at least SUCCESSOR_MIN_MESSAGES and ``eligible`` (default: all)
    allows them (e.g. plausible values only: graph nodes publish nothing else). What cannot be
    told apart: an intruder that publishes plausible values, and enough of them, while no writer
    of the topic does (before its first message, after its last, in a silence of more than
    ``max_silence_ticks``, or with a counter behind the writer's in a gap longer than twice the
    writer's typical step: two maps in a pause of the 2 Hz map's writer), is taken for a restarted writer. ``min_messages`` (default: half a
    second of the topic's messages, ``successor_min_messages`` of the chain's ticks) stands for
    SUCCESSOR_MIN_MESSAGES above. Returns indices into ``ticks``."""
    n = len(ticks)
    spacing = typical_spacing([ticks[i] for i in chain])
    if min_messages is None:
        min_messages = _min_messages_at(spacing)
    ok = [True] * n if eligible is None else [bool(e) for e in eligible]
    seq = _unwrapped([int(x) & SEQUENCE_MASK for x in sequences])
    kept: set[int] = set()
    work: list[tuple[set[int], list[int]]] = [(set(chain), list(range(n)))] if chain else []
    first = True
    while work:
        found, members = work.pop()
        order = sorted(found, key=lambda i: ticks[i])
        others = sorted((ticks[i], seq[i]) for i in members if i not in found and ok[i])
        other_ticks = [t for t, _ in others]
        stretches = [[order[0]]]
        for a, b in zip(order, order[1:]):
            # a silence, or a counter restarted inside the gap: as many messages there as a successor
            # needs, numbered behind the chain (fewer, e.g. a second publisher's in ticks the writer
            # skipped, must not cut the writer into stretches too short to keep), in a gap longer than
            # the writer's own steps (two strays between two maps of a 2 Hz writer were cut out as a
            # successor, a reviewer's)
            lo_i, hi_i = bisect.bisect_right(other_ticks, ticks[a]), bisect.bisect_left(other_ticks, ticks[b])
            restarted = (ticks[b] - ticks[a] > 2 * spacing
                         and sum(others[k][1] < seq[a] for k in range(lo_i, hi_i)) >= min_messages)
            if ticks[b] - ticks[a] > max_silence_ticks or restarted:
                stretches.append([])
            stretches[-1].append(b)
        best = max(stretches, key=len)
        if not first and len(best) < min_messages:
            continue
        first = False
        kept.update(best)
        lo, hi = ticks[best[0]], ticks[best[-1]]
        for span in ([i for i in members if ok[i] and ticks[i] < lo], [i for i in members if ok[i] and ticks[i] > hi]):
            if len(span) < min_messages:
                continue
            lead = leading_chain([ticks[i] for i in span], [sequences[i] for i in span], apart_ties=True)
            if lead is not None:
                work.append(({span[j] for j in lead}, span))
    return kept


def _unwrapped(seq: list[int]) -> list[int]:
    """Sequence numbers stored as uint32 (MCAP) that straddle 2^32: the small ones continue."""
    quarter = (SEQUENCE_MASK + 1) // 4
    if any(s < quarter for s in seq) and any(s >= 3 * quarter for s in seq):
        return [s + SEQUENCE_MASK + 1 if s < quarter else s for s in seq]
    return seq


def _heaviest_chain(ticks: list[int], seq: list[int], weights: list[int],
                    members) -> tuple[set[int], int] | None:
    """(indices, weight) of the heaviest chain among ``members`` (ties: the earliest message
    ends it), None if ``members`` is empty. Points are taken in sequence order (all of one
    sequence number queried before any is inserted: a chain's numbers rise strictly) and a
    point may follow any inserted point whose offset ``sequence - tick`` is at least its own."""
    members = list(members)
    if not members:
        return None
    offsets = sorted({seq[i] - ticks[i] for i in members}, reverse=True)
    rank = {o: r + 1 for r, o in enumerate(offsets)}  # 1 = highest offset: prefix = offsets >= o
    size = len(offsets)
    tree: list[tuple[int, int]] = [(0, 1)] * (size + 1)  # (weight, -index) of the best chain end
    best_to: dict[int, int] = {}
    before: dict[int, int | None] = {}
    order = sorted(members, key=lambda i: (seq[i], i))
    start = 0
    while start < len(order):
        stop = start
        while stop < len(order) and seq[order[stop]] == seq[order[start]]:
            stop += 1
        group = order[start:stop]
        for i in group:
            r, found = rank[seq[i] - ticks[i]], (0, 1)
            while r > 0:
                found = max(found, tree[r])
                r -= r & -r
            before[i] = -found[1] if found[1] <= 0 else None
            best_to[i] = found[0] + weights[i]
        for i in group:
            r = rank[seq[i] - ticks[i]]
            while r <= size:
                tree[r] = max(tree[r], (best_to[i], -i))
                r += r & -r
        start = stop
    end = max(members, key=lambda i: (best_to[i], -i))
    chain, i = set(), end
    while i is not None:
        chain.add(i)
        i = before[i]
    return chain, best_to[end]
