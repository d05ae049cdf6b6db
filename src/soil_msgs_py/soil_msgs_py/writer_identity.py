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
publisher that is there every tick, whoever sent first. The simulator's command gate and
the recorder both decide with :class:`WriterTracks`.
"""
from __future__ import annotations

from dataclasses import dataclass

from .messages import NS_PER_S
from .params import SAMPLE_RATE_HZ

SEQUENCE_MASK = 0xFFFF_FFFF  # MCAP stores a uint32 sequence; DDS counts in int64: compare modulo 2^32


def tick_index(stamp: int, first_stamp_ns: int) -> int | None:
    """k if ``stamp`` is the episode's tick stamp ``first + floor(k * 1e9 / 60)`` (how the
    simulator and the batch generator stamp), else None (off the 60 Hz grid)."""
    d = stamp - first_stamp_ns
    if d < 0:
        return None
    k = -(-d * SAMPLE_RATE_HZ // NS_PER_S)  # the only tick whose floored stamp can equal d
    return k if k * NS_PER_S // SAMPLE_RATE_HZ == d else None


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

    def observe(self, sequence: int | None, tick: int) -> int | None:
        """The writer (an id) of a message with publication ``sequence`` for ``tick``; None when
        the sequence number is unknown (None or 0: the rmw gave none)."""
        if not sequence:
            return None
        sequence &= SEQUENCE_MASK
        if self.forget_after_ticks is not None:
            self._writers = {i: w for i, w in self._writers.items()
                             if tick - w.last_tick <= self.forget_after_ticks}
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
        """Whether ``ident`` has sent at least as many ticks as any other writer (an unknown
        writer, None, is never judged: True)."""
        if ident is None or ident not in self._writers:
            return ident is None
        return self._writers[ident].ticks >= max(w.ticks for w in self._writers.values())

    def leader(self) -> int | None:
        """The one writer with the most ticks; None if none was seen or several tie (then
        the sequence numbers tell nothing about which one to trust)."""
        ranked = sorted(self._writers.values(), key=lambda w: w.ticks, reverse=True)
        if not ranked or (len(ranked) > 1 and ranked[1].ticks == ranked[0].ticks):
            return None
        return ranked[0].ident
