"""Recorder core (no rclpy): routes raw messages into one journal per episode, finishes bags.

``record_node.py`` feeds it what DDS delivers: ``on_status`` with each ``/sim/status`` text,
``on_message`` with each raw CDR message, ``poll`` from a timer, ``close`` at the end.

Routing is by stamp, not by arrival: an ``episode_start`` event opens a session covering
``[first_stamp_ns, ...)``; ``episode_end`` closes its range at ``last_stamp_ns``. A message
goes to the oldest open session whose range covers its stamp and that still expects this
topic; DDS keeps each topic's messages in publication order, so when a replay restarts
stamps at 0 (ranges overlap), a closing episode's backlog still goes to it and the next
episode's messages to the next one. A message no session covers is held for ``hold_s``
(its ``episode_start`` may still be on the way: status and data are separate DDS topics,
delivered in no particular order) and then dropped and counted. A closing session is
finished once every recorded topic reached ``last_stamp_ns``, or once ``end_grace_s`` passed
with no new message for it since the episode_end (a recorder that is merely behind a fast
lockstep graph is still receiving the episode: it is not cut short). ``draining`` says
whether a session waits for such messages, so a node asked to stop can let them in first.

Finishing closes the journal and converts it with ``journal.journal_to_bag``; episode bags
are trimmed to whole ticks, so a bag stopped early (SIGINT, lost tail) still reads with
``bag_io.read_episode``.

What never enters an episode bag, on every topic of the graph (episode topics and labelled
extras such as ``/soil/estimate`` alike): a message whose stamp is off the episode's 60 Hz
tick grid (``first_stamp_ns + floor(k * 1e9 / 60)``), dropped here and counted per topic
(``off_grid``); a labelled message whose layout is not its topic's, dropped as
undecodable (a bag must stay readable). Every message is journaled with its writer's
publication sequence number, and a second claim on a stamp is warned about; the conversion
keeps only the writer that has been recording every tick (``journal.refused_claims``, with
``soil_msgs_py.writer_identity``) and counts the refused messages per topic
(``conflicts``), so a publisher that sends first, or alone at some stamp among the
recording writer's, never gets its data into the bag; a node restarted mid-episode (a new
counter, its ticks after its predecessor's last) is recorded as the writer's successor
(``writer_identity.succession``, which says what it cannot tell apart).
"""
from __future__ import annotations

import logging
import os
import shutil
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

from rosbags.interfaces import Qos

from soil_msgs_py import messages as M
from .bag_io import META_KEY
from soil_msgs_py.episode import MAX_EPISODE_S
from soil_msgs_py.episode_follow import graph_said, same_episode
from soil_msgs_py.graph import EVENT_EPISODE_START, SIM_STATE_TOPICS, EpisodeEvent, bag_finished_log
from soil_msgs_py.messages import NS_PER_S
from soil_msgs_py.params import SAMPLE_RATE_HZ
from soil_msgs_py.topics import CLOCK, GRAPH_TOPICS_BY_NAME, TOPICS_BY_NAME
from soil_msgs_py.writer_identity import FORGET_WRITER_AFTER_TICKS, WriterTracks, tick_index
from .journal import (
    RECORDER_INFO_KEY, BagResult, JournalWriter, NothingRecoverable, claim_name, journal_path,
    journal_to_bag, labelled_values, partial_dir, FIRST_STAMP_KEY,
)

_MAX_HELD = 20_000  # messages waiting for their episode_start (~30 s of ticks)
EXTRA_TOPIC_GRACE_S = 0.3  # once the episode topics are complete, wait until the extras were quiet this long
# ... but no longer than this while they keep coming: an estimator seconds behind a loaded
# machine's simulator is still sending the episode's estimates (END_GRACE_S, 4 s, cut its tail off)
EXTRA_TOPIC_LAG_LIMIT_S = 30.0
EXTRA_TOPIC_BEHIND_NS = NS_PER_S  # an extra topic whose newest stamp is this far before the last tick is behind
_WARN_LIMIT = 5  # per session, kind and topic; the rest are only counted
_MAX_CLAIMS = 4  # messages journaled per (topic, stamp): the recorded one and a few intruders
_SAY_MAKING_FROM = 200_000  # messages (~4 min of episode): a bag this big takes seconds to make, said
# How long an ended episode waits for more of its data after the last message arrived. Longer
# than Fast DDS's default reliable heartbeat period (3 s): a sample a reader's transport
# dropped while the reader was busy is re-sent after the next heartbeat, not before. The
# graph's own writers heartbeat every 0.1 s (soil_msgs_py.dds_profile); a writer outside it
# (another tool, a profile of the user's own) may keep Fast DDS's 3 s. Only an incomplete
# episode waits this long: a complete one is finished once its ticks are in and its extra
# topics were quiet for EXTRA_TOPIC_GRACE_S.
END_GRACE_S = 4.0
# The results of the bags finished that a recorder keeps for its caller (the newest): a recorder runs
# for a shift, one bag per episode, and each result holds its topics' counts (an outside tester's
# long run: ~2.5 kB a bag, never read back by the node).
FINISHED_KEPT = 64
ONLINE_HORIZON_TICKS = 10 * SAMPLE_RATE_HZ  # 10 s: how far past a topic's newest stamp a message is judged on arrival


def _lacking_ticks(messages: Mapping[str, int], recorded: Sequence[str], unmatched: set[str]) -> tuple[int, dict[str, int]]:
    """(ticks of the fullest episode topic, per recorded episode topic how many fewer it has) (the
    fullest not counting /clock, which a replay's ``--clock`` may publish at another rate; extra
    topics do not count: they may be sparse or carry other stamps). A topic without any message whose
    writer had not matched when the recorder joined (``unmatched``) is said as such elsewhere (a
    machine's graph publishes no ground truth)."""
    ticks = max((n for t, n in messages.items() if t in TOPICS_BY_NAME and t != CLOCK.name), default=0)
    counts = {t: messages.get(t, 0) for t in recorded if t in TOPICS_BY_NAME}
    return ticks, {t: ticks - n for t, n in counts.items() if n < ticks and (n > 0 or t not in unmatched)}


def _from_first_tick(topic: str) -> bool:
    """Whether ``topic`` is published from an episode's first tick on (an extra --topics one: taken so)."""
    known = GRAPH_TOPICS_BY_NAME.get(topic)
    return known is None or known.from_first_tick


def decode_stamp(topic: str, msgtype: str, raw: bytes | memoryview) -> int | None:
    """Simulation stamp [ns] of a raw CDR message, or None if it has none / does not decode.

    Graph topics must parse as their topic's layout (``journal.labelled_values``: episode
    topics, labelled extras); other types fall back to a labelled array's stamp fields,
    ``header.stamp`` or ``clock``.
    """
    try:
        if (parsed := labelled_values(topic, msgtype, raw)) is not None:
            return parsed[0]
        msg = M.TYPESTORE.deserialize_cdr(raw, msgtype)
        if (stamp := M.labelled_stamp(msg)) is not None:
            return stamp
        for path in ("header.stamp", "clock", "stamp"):
            obj = msg
            for part in path.split("."):
                obj = getattr(obj, part, None)
            if obj is not None and hasattr(obj, "nanosec"):
                return M.stamp_ns(obj)
    except Exception:  # noqa: BLE001 - any undecodable message is counted, never fatal
        return None
    return None


@contextmanager
def reporting(say: Callable[[float], None], every_s: float = 2.0) -> Iterator[None]:
    """``say(seconds spent)`` every ``every_s`` from a helper thread while the block runs. Why: a
    recorder stopped after an hour-long episode works ~30 s making its bag, and what stops it
    (``soil_launch``) waits for a node while it reports; silent, it had been killed half-way."""
    done, start = threading.Event(), time.monotonic()

    def run() -> None:
        while not done.wait(every_s):
            say(time.monotonic() - start)

    helper = threading.Thread(target=run, name="reporting", daemon=True)
    helper.start()
    try:
        yield
    finally:
        done.set()
        helper.join()


class StampClaims:
    """How many messages were journaled per (topic, stamp) of one episode: for a stamp on the
    episode's 60 Hz grid one byte per tick and topic (an hour's 216,000 ticks: 216 kB a topic),
    a mapping for the others (stamps off the grid or past ``MAX_TICKS``, which only a foreign
    writer sends). Why: a mapping entry per message (~140 B) grew a recorder by 7 MB per minute of
    episode (an outside soak test: 89 → 212 MB over 15 min, +450 MB over an hour)."""

    MAX_TICKS = int(MAX_EPISODE_S * SAMPLE_RATE_HZ) + 1  # the longest episode's; past it, the mapping

    def __init__(self) -> None:
        self.per_tick: dict[str, bytearray] = {}
        self.other: dict[tuple[str, int], int] = {}

    def add(self, topic: str, stamp: int, tick: int | None) -> int:
        """Count one more message for ``(topic, stamp)`` (``tick``: its grid index or None); the
        count so far (at most 255 kept per tick)."""
        if tick is None or tick >= self.MAX_TICKS:
            n = self.other[(topic, stamp)] = self.other.get((topic, stamp), 0) + 1
            return n
        counts = self.per_tick.setdefault(topic, bytearray())
        if tick >= len(counts):
            grown = min(max(tick + 1, 2 * len(counts)), self.MAX_TICKS)  # (doubling: amortised; at most MAX_TICKS)
            counts.extend(bytes(grown - len(counts)))
        counts[tick] = min(counts[tick] + 1, 255)
        return counts[tick]


@dataclass
class Session:
    """One bag being recorded: its journal, its stamp range and what arrived so far."""

    name: str  # bag directory name (may carry a _2 suffix)
    journal: JournalWriter
    meta_json: str | None  # episode metadata; None for a --no-split recording
    event: EpisodeEvent | None = None  # the episode_start that opened it
    first_stamp_ns: int = 0
    last_stamp_ns: int | None = None  # set by episode_end; None while running
    closing_since: float | None = None
    last_write: float | None = None  # clock() of the last message written into it
    silent_polls: int = 0  # polls in a row that found no new message for it
    polled_write: float | None = None  # ``last_write`` the last poll saw
    ticks_done_since: float | None = None  # when every episode topic reached the last stamp
    end_event: EpisodeEvent | None = None
    cut_by: str | None = None  # the episode whose episode_start came before this one's episode_end
    counts: dict[str, int] = field(default_factory=dict)
    topic_max: dict[str, int] = field(default_factory=dict)
    topic_min: dict[str, int] = field(default_factory=dict)  # first stamp per topic (its recorded writer's)
    topic_seq: dict[str, int] = field(default_factory=dict)  # the highest publication sequence number written per topic
    reached_tick: int = 0  # the newest tick any topic's recorded writer has reached (the episode's progress)
    # its episode_start heard again while it runs: the event again, or its source started over (``Recorder._restarted``)
    start_again: EpisodeEvent | None = None
    superseded: bool = False  # its source started over: the episode's events are the new session's
    moved_on: set[str] = field(default_factory=set)  # topics whose writer went back to a newer session's stamps
    claims: StampClaims = field(default_factory=StampClaims)  # messages per (topic, stamp)
    duplicates: int = 0  # messages claiming a stamp already claimed on their topic
    off_grid: dict[str, int] = field(default_factory=dict)  # episode-topic messages off the tick grid
    warned: dict[tuple[str, str], int] = field(default_factory=dict)  # (kind, topic) -> warnings
    writers: dict[str, WriterTracks] = field(default_factory=dict)  # who publishes each topic
    flushed_stamp_ns: int = 0  # stamp at the last flush triggered by simulation time
    order: int = 0  # the sessions opened before it (``Recorder._complete``: a writer still on an older one is behind)
    opened_at: float = 0.0  # clock() when it opened

    @property
    def total(self) -> int:
        return sum(self.counts.values())

    def covers(self, stamp: int) -> bool:
        return stamp >= self.first_stamp_ns and (self.last_stamp_ns is None or stamp <= self.last_stamp_ns)

    def topic_done(self, topic: str) -> bool:
        return self.last_stamp_ns is not None and self.topic_max.get(topic, -1) >= self.last_stamp_ns

    def same_episode(self, ev: EpisodeEvent) -> bool:
        return self.event is not None and not self.superseded and same_episode(self.event, ev)


class Recorder:
    """Episode-splitting (or single-bag) recorder over journals; see the module docstring."""

    def __init__(
        self, out_dir: str | Path, topics: Mapping[str, str], *, split: bool = True,
        end_grace_s: float = END_GRACE_S, hold_s: float = 1.0, flush_sim_s: float = 0.25, qos_for: Callable[[str], Sequence[Qos]] = lambda t: (),
        log: logging.Logger | None = None, clock: Callable[[], float] = time.monotonic, graph_id: str = "",
    ):
        if end_grace_s < 0:
            raise ValueError(f"end_grace_s={end_grace_s} must be >= 0 s")
        self.out_dir = Path(out_dir)
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self.topics: dict[str, str] = dict(topics)
        self.split = split
        self.end_grace_s = end_grace_s
        self.hold_s = hold_s
        # Flush also every flush_sim_s of simulation time: in lockstep the simulation runs
        # several times faster than the wall-clock flush timer, and the loss bound is in data.
        self.flush_sim_ns = int(flush_sim_s * 1e9)
        self.qos_for = qos_for
        self.log = log or logging.getLogger("soil_bag_record")
        self.clock = clock
        self.sessions: list[Session] = []  # oldest first
        self.held: deque[tuple[float, str, int, bytes, int, int]] = deque()
        self.finished: deque[BagResult] = deque(maxlen=FINISHED_KEPT)  # the newest bags finished, for a caller
        # episodes without a bag: its journal could not be made, or would not close or convert, or its bag
        # holds no message of the simulator's state at all (each said when it happened); the recorder's exit
        # code says so (record_node), so a launch does not end in 0
        self.unwritten: list[str] = []
        self.dropped = {"outside_episode": 0, "undecodable": 0}  # messages not recorded, by cause
        self.opened = 0  # sessions opened so far
        # per topic, the ``order`` of the session its newest message went into and when (``_complete``)
        self.heard: dict[str, tuple[int, float]] = {}
        # topics whose writer had not matched when the recorder joined the simulator's topics
        # (record_node's --inputs-wait ran out): their first messages may be missing from a bag
        self.joined_without: set[str] = set()
        self._undecodable_warned: set[str] = set()
        # this launch's graph id (``EpisodeEvent.graph``): another graph's episodes are not recorded
        self.graph_id = graph_id
        self._others_said: set[str] = set()
        if not split:
            name = "record_" + datetime.now(timezone.utc).strftime("%Y%m%d_%H%M%S")
            self.sessions.append(self._open(name, None, {"insitu_soil.mode": "no_split"}))

    # --- inputs ---------------------------------------------------------------------------

    def add_topic(self, topic: str, msgtype: str) -> None:
        """A topic whose type became known after start (discovered on the graph)."""
        self.topics[topic] = msgtype
        for s in self.sessions:
            s.journal.add_channel(topic, msgtype, self.qos_for(topic))

    def on_status(self, text: str) -> None:
        """One ``/sim/status`` message; a bad one is logged and ignored."""
        if not self.split:
            return
        try:
            ev = EpisodeEvent.from_json(text)
        except Exception as err:  # noqa: BLE001 - a bad message is logged, never fatal: a recorder loses no episode to one
            self.log.warning(f"ignoring bad /sim/status message: {err}")
            return
        if self.graph_id and ev.graph != self.graph_id:  # another launch's simulator, or a stray, on our topics
            self._say_once(ev.name, f"{ev.event} of {ev.name} from another graph ({graph_said(ev.graph)}, this "
                                    f"recorder's {self.graph_id}) on this recorder's topics: none of its episodes is "
                                    "recorded")
        elif ev.event == EVENT_EPISODE_START and (held := self._held_start(ev)):
            self._say_once(ev.name, f"/sim/status: {held}")
        elif ev.event == EVENT_EPISODE_START:
            self._start(ev)
        else:
            self._end(ev)

    def _say_once(self, episode_name: str, text: str) -> None:
        """A warning about another graph's or a stray's episode, once per episode name (its every event)."""
        if episode_name not in self._others_said:
            self._others_said.add(episode_name)
            self.log.warning(text)

    def on_message(self, topic: str, raw: bytes, recv_ns: int, publication_seq: int | None = None) -> None:
        """``publication_seq``: the writer's DDS sequence number (message info), None if unknown;
        it tells two publishers of one topic apart when they claim the same stamp."""
        seq = publication_seq or 0
        msgtype = self.topics.get(topic)
        if msgtype is None:
            return
        stamp = decode_stamp(topic, msgtype, raw)
        if not self.split:
            s = self.sessions[0]
            self._write(s, topic, recv_ns if stamp is None else stamp, raw, recv_ns, seq, episode=False)
            return
        if stamp is None:
            self.dropped["undecodable"] += 1
            if topic not in self._undecodable_warned:
                self._undecodable_warned.add(topic)
                self.log.warning(f"{topic}: message without a decodable stamp dropped (further ones only counted)")
            return
        if any(x.start_again is not None for x in self.sessions):
            self._restarted(topic, stamp)
        s = self._route(topic, stamp, seq)
        if s is None:
            self.held.append((self.clock(), topic, stamp, raw, recv_ns, seq))
            if len(self.held) > _MAX_HELD:
                self.held.popleft()
                self.dropped["outside_episode"] += 1
            return
        self._write(s, topic, stamp, raw, recv_ns, seq)
        if s.closing_since is not None and self._complete(s):
            self._finish(s, "completed")

    def poll(self) -> list[BagResult]:
        """Timer work: flush journals, finish sessions whose grace expired, expire held messages."""
        now = self.clock()
        done: list[BagResult] = []
        for s in list(self.sessions):
            if s.closing_since is not None:
                s.silent_polls = s.silent_polls + 1 if s.last_write == s.polled_write else 0
                s.polled_write = s.last_write
            if s.closing_since is not None and (self._complete(s) or self._stalled(s, now)):
                r = self._finish(s, "completed" if self._complete(s) else "grace_timeout")
                done += [r] if r else []
            else:
                s.journal.flush()
        expired = 0
        while self.held and now - self.held[0][0] > self.hold_s:
            self.held.popleft()
            expired += 1
        if expired:
            self.dropped["outside_episode"] += expired
            self.log.debug(f"dropped {expired} message(s) outside any episode "
                           f"({self.dropped['outside_episode']} so far)")
        return done

    def _stalled(self, s: Session, now: float) -> bool:
        """The end grace expired: nothing arrived for ``s`` for ``end_grace_s`` since its episode_end,
        and two polls in a row found nothing new (a recorder starved of CPU for a while has its
        messages waiting behind the timer, not lost: the poll after them must see them first)."""
        heard = max(self._still_on_older(s), default=s.closing_since)  # (its writer streaming an older episode's)
        return (s.silent_polls >= 2
                and now - max(s.closing_since, s.last_write or s.closing_since, heard) >= self.end_grace_s)

    def _still_on_older(self, s: Session) -> list[float]:
        """When each topic of ``s`` without a message of its episode yet, whose newest message went
        into an older session since ``s`` opened (its writer more than an episode behind), was last
        heard. Heard before it opened, the writer has stopped, or its episode has none of the topic:
        waiting for it had held every later bag open for the end grace and, in a replay whose stamps
        start again with each bag, filed the next bag's messages into the waiting one (a reviewer's)."""
        return [self.heard[t][1] for t in self.topics if t not in s.topic_max and t in self.heard
                and self.heard[t][0] < s.order and self.heard[t][1] >= s.opened_at]

    def draining(self) -> bool:
        """Whether an ended episode still waits for messages in flight (finished by ``poll``)."""
        return any(s.closing_since is not None for s in self.sessions)

    def close(self) -> list[BagResult]:
        """Stop: every open session is finished with what arrived (episode bags: whole ticks)."""
        self.dropped["outside_episode"] += len(self.held)
        self.held.clear()
        done = [r for s in list(self.sessions) if (r := self._finish(s, "stopped"))]
        if any(self.dropped.values()):
            self.log.info(f"messages not recorded: {self.dropped}")
        return done

    # --- sessions -------------------------------------------------------------------------

    def _open(self, wanted: str, meta_json: str | None, extra: Mapping[str, str] | None = None) -> Session:
        name = claim_name(self.out_dir, wanted)
        if name != wanted:
            self.log.warning(f"bag {self.out_dir / wanted} exists; recording to {self.out_dir / name}")
        metadata = dict(extra or {})
        if meta_json is not None:
            metadata[META_KEY] = meta_json
        journal = JournalWriter(journal_path(partial_dir(self.out_dir, name)), metadata)
        for topic, msgtype in self.topics.items():
            journal.add_channel(topic, msgtype, self.qos_for(topic))
        self.log.info(f"recording {self.out_dir / name} (journal {journal.path})")
        self.opened += 1
        return Session(name=name, journal=journal, meta_json=meta_json, order=self.opened, opened_at=self.clock())

    def _held_start(self, ev: EpisodeEvent) -> str:
        """Why the ``episode_start`` ``ev`` is held, not opened ("": it is opened), by a recorder given no
        graph id (given one, it takes that graph's events only): one without the graph id of a launched
        graph's episode under way is a stray's or that graph's simulator started again by hand, and
        only the ticks tell them apart. It waits as the episode's ``start_again`` (a
        message stamped back at its start opens it, ``_restarted``). Opened at once, one stray start
        had closed a launch's bag cut short and filed the rest under the stranger's name, losing a
        third of its ticks as off its grid (an outside tester's)."""
        under_way = [s for s in self.sessions if s.end_event is None and not s.superseded and s.event is not None
                     and s.event.graph and s.event.graph != ev.graph]
        for s in under_way:
            s.start_again = ev
        if not under_way:
            return ""
        cur = under_way[-1].event
        return (f"episode_start of {ev.name} ({graph_said(ev.graph)}) while {cur.name} "
                f"of graph {cur.graph} is under way: held until its ticks show a simulator started over there "
                "(stamped back at its start), else never recorded")

    def _start(self, ev: EpisodeEvent) -> None:
        same = next((s for s in self.sessions if s.same_episode(ev)), None)
        if same is not None:
            if same.last_stamp_ns is None and same.topic_max:  # while it runs: the ticks will tell (``_restarted``)
                same.start_again = ev
            return  # the same event twice
        self._open_episode(ev)

    def _restarted(self, topic: str, stamp: int) -> None:
        """A session whose episode_start came again while it ran, and a message of it stamped back at
        the episode's start, before what the session holds of that topic: its source started over
        (a simulator killed and started again with the same episode, whose event is the same to the
        letter). The session is closed, cut short, and the new run gets a bag of its own; before,
        its event was taken for the same one twice and its ticks refused as another writer's
        claims on the first run's stamps (3000 of them, a reviewer's)."""
        for s in self.sessions:
            ev = s.start_again
            if (ev is not None and s.last_stamp_ns is None and ev.first_stamp_ns <= stamp
                    < min(s.topic_max.get(topic, -1), ev.first_stamp_ns + NS_PER_S)):
                s.start_again, s.superseded = None, True
                self._open_episode(ev)
                return

    def _open_episode(self, ev: EpisodeEvent) -> None:
        for s in self.sessions:
            if s.last_stamp_ns is None:  # its episode_end never came
                s.last_stamp_ns = max(s.topic_max.values(), default=s.first_stamp_ns)
                s.closing_since, s.polled_write = self.clock(), s.last_write
                s.cut_by = ev.name
                self.log.warning(f"episode_start of {ev.name} while {s.name} has not ended: closing {s.name} "
                                 f"at its last stamp {s.last_stamp_ns} ns, cut short (a restarted simulator, or a "
                                 "second graph or bag player on this domain, whose data would mix with it)")
        try:
            s = self._open(ev.name, ev.meta.to_json(), {FIRST_STAMP_KEY: str(ev.first_stamp_ns)})
        except OSError as err:  # the bag cannot be made (a name the file system refuses, a full or read-only disk):
            # this episode is not recorded, the others and the bags already written are kept
            self.log.error(f"episode {ev.name!r}: cannot open its bag under {self.out_dir}: {err}; not recorded")
            self.unwritten.append(ev.name)
            return
        s.event, s.first_stamp_ns, s.flushed_stamp_ns = ev, ev.first_stamp_ns, ev.first_stamp_ns
        self.sessions.append(s)
        held, self.held = self.held, deque()
        for item in held:  # messages that arrived before their episode_start
            _, topic, stamp, raw, recv_ns, seq = item
            target = self._route(topic, stamp, seq)
            if target is None:
                self.held.append(item)
            else:
                self._write(target, topic, stamp, raw, recv_ns, seq)

    def _end(self, ev: EpisodeEvent) -> None:
        s = next((s for s in self.sessions if s.same_episode(ev)), None)
        if s is None:
            self.log.warning(f"episode_end of {ev.name} (episode {ev.episode}) without its episode_start: ignored")
            return
        if s.end_event is not None:
            return
        s.end_event, s.last_stamp_ns, s.closing_since = ev, ev.last_stamp_ns, self.clock()
        s.polled_write = s.last_write
        if self._complete(s) or ev.last_stamp_ns < s.first_stamp_ns:
            self._finish(s, "completed")

    def _route(self, topic: str, stamp: int, seq: int = 0) -> Session | None:
        """The oldest session whose stamps cover ``stamp`` and whose ``topic`` is not done yet; but
        where a newer session covers it too (a replay's stamps restart with each bag), a message
        that has gone back in time against what the older one holds of its topic is the newer
        episode's: stamped before its newest, or at it by a later publication of the writer (a
        redelivery carries its old sequence number). A writer's stamps only grow within an
        episode. (Sparse topics, the planner's targets and the map, never reach an episode's last
        stamp: the next bag's were filed into the previous one while it waited out its end grace.)
        Once a topic's message has gone back so, the older session takes no more of that topic: its
        writer has moved on to the newer episode, whose later stamps may rise past the older one's
        newest again (a simulator started again on the same episode: the controller's next commands
        went into the first run's bag, a reviewer's)."""
        covering = [s for s in self.sessions if s.covers(stamp) and not s.topic_done(topic) and topic not in s.moved_on]
        for i, s in enumerate(covering):
            newest = s.topic_max.get(topic, -1)
            if i + 1 < len(covering) and (stamp < newest or (stamp == newest and seq > s.topic_seq.get(topic, seq))):
                s.moved_on.add(topic)
                continue
            return s
        return None

    def _warn(self, s: Session, kind: str, topic: str, text: str) -> None:
        n = s.warned[(kind, topic)] = s.warned.get((kind, topic), 0) + 1
        if n <= _WARN_LIMIT:
            self.log.warning(f"{s.name}: {text}" + (" (further ones only counted)" if n == _WARN_LIMIT else ""))

    def _write(self, s: Session, topic: str, stamp: int, raw: bytes, recv_ns: int, seq: int,
               *, episode: bool = True) -> None:
        if episode:
            tick = tick_index(stamp, s.first_stamp_ns)
            if topic in GRAPH_TOPICS_BY_NAME and tick is None:
                s.off_grid[topic] = s.off_grid.get(topic, 0) + 1
                self._warn(s, "off_grid", topic, f"{topic} message with stamp {stamp} ns is off the 60 Hz grid "
                           f"of the episode (first stamp {s.first_stamp_ns} ns); dropped")
                return
            claims = s.claims.add(topic, stamp, tick)
            if claims > 1:
                s.duplicates += 1
                self._warn(s, "duplicate", topic, f"duplicate {topic} stamp {stamp} ns (a second publisher or a "
                           "redelivery); the bag keeps the recorded publisher's message")
                if claims > _MAX_CLAIMS:
                    return
        s.journal.write(topic, stamp, raw, recv_ns, seq)
        s.last_write = self.clock()
        self.heard[topic] = (s.order, s.last_write)
        if stamp - s.flushed_stamp_ns >= self.flush_sim_ns and s.meta_json is not None:
            s.journal.flush()
            s.flushed_stamp_ns = stamp
        s.counts[topic] = s.counts.get(topic, 0) + 1
        if seq:
            s.topic_seq[topic] = max(seq, s.topic_seq.get(topic, 0))
        recorded_writer = not episode or self._from_recorded_writer(s, topic, stamp, seq)
        if stamp > s.topic_max.get(topic, -1) and recorded_writer:
            s.topic_max[topic] = stamp
            if episode and (k := tick_index(stamp, s.first_stamp_ns)) is not None:
                s.reached_tick = max(s.reached_tick, k)
        if recorded_writer and stamp < s.topic_min.get(topic, stamp + 1):
            s.topic_min[topic] = stamp

    @staticmethod
    def _from_recorded_writer(s: Session, topic: str, stamp: int, seq: int) -> bool:
        """Whether the message's writer leads the topic so far (or is unknown): only those
        advance ``topic_max``, so a publisher sending a stamp early cannot make the episode
        look complete before the recorded publisher's message for it arrived. A stamp more
        than ``ONLINE_HORIZON_TICKS`` past the topic's newest cannot be judged in arrival
        order (any higher counter "continues" a writer across that many ticks): it is
        journaled and judged when the bag is made, and never advances ``topic_max``. "Past the
        newest" is judged against the episode's progress, the newest tick any topic's recorded
        writer reached (``reached_tick``): against a topic's own newest, a planner started 12 s
        into the episode never advanced its topic (the bag said it had no message while holding
        1173, an outside tester's), nor a controller restarted more than 10 s after it died. A
        writer silent for 2 s of that progress is gone, as the bag's succession takes it
        (``FORGET_WRITER_AFTER_TICKS``): a controller restarted with a new counter leads at once,
        not once it has sent as many commands as the dead one; judged against the progress, not
        the arriving stamp, so a message stamped seconds ahead makes no writer look silent."""
        k = tick_index(stamp, s.first_stamp_ns)
        if k is None:
            return True
        if k > s.reached_tick + ONLINE_HORIZON_TICKS:
            return False
        writers = s.writers.setdefault(topic, WriterTracks(forget_after_ticks=FORGET_WRITER_AFTER_TICKS))
        return writers.leads(writers.observe(seq, k, now_tick=min(k, s.reached_tick + 1)))

    def _complete(self, s: Session) -> bool:
        """Every episode topic reached the last stamp, and so did every extra ``--topics`` one, or
        the session was quiet for ``EXTRA_TOPIC_GRACE_S`` (``end_grace_s`` while an extra topic is
        more than ``EXTRA_TOPIC_BEHIND_NS`` behind the last tick) since the ticks were complete (extras
        such as /soil/estimate follow the ticks but may run at other rates, skip the last stamp,
        or lag: an estimator on a loaded machine still streaming its last estimates is not cut
        off), at most ``EXTRA_TOPIC_LAG_LIMIT_S`` (or ``end_grace_s`` if longer) after the ticks
        were complete. An extra topic with no message of this episode yet whose newest message went
        into an older session (an estimator more than an episode behind a lockstep simulator or a
        fast replay) is behind too, and quiet only once that topic is: its episodes had been
        finished 0.3 s after their ticks, before its first message, which was then dropped, and the
        bag said it was complete (an outside tester's)."""
        tick_topics = [t for t in self.topics if t in M.FIELDS] or list(self.topics)
        if not all(s.topic_done(t) for t in tick_topics):
            return False
        if all(s.topic_done(t) for t in self.topics):
            return True
        now = self.clock()
        if s.ticks_done_since is None:
            s.ticks_done_since = now
        quiet_since = max(s.ticks_done_since, s.last_write or s.ticks_done_since)
        # an extra topic seconds behind the last tick (a lagging estimator) may pause longer than the
        # short grace between its bursts: it gets the end grace of quiet
        behind = any(not s.topic_done(t) and s.topic_max.get(t) is not None
                     and s.last_stamp_ns - s.topic_max[t] > EXTRA_TOPIC_BEHIND_NS for t in self.topics)
        if still_on_older := self._still_on_older(s):
            behind, quiet_since = True, max(quiet_since, *still_on_older)
        if now - quiet_since >= (self.end_grace_s if behind else EXTRA_TOPIC_GRACE_S):
            return True
        limit = max(self.end_grace_s, EXTRA_TOPIC_LAG_LIMIT_S)
        if now - s.ticks_done_since < limit:
            return False
        if ("lag_limit", "") not in s.warned:  # (_complete is asked more than once per poll)
            self._warn(s, "lag_limit", "", f"extra topics still arriving {limit:g} s after the episode's ticks "
                                           f"were complete; finished without the rest (last stamp received, want "
                                           f"{s.last_stamp_ns}): {self._short_topics(s)}")
        return True

    def _short_topics(self, s: Session) -> dict[str, int | None]:
        """The topics that have not reached the episode's last stamp, with the last stamp received."""
        return {t: s.topic_max.get(t) for t in self.topics if not s.topic_done(t)}

    def _finish(self, s: Session, how: str) -> BagResult | None:
        """Close the journal and convert it; on failure the journal stays for soil_bag_repair."""
        self.sessions.remove(s)
        partial = partial_dir(self.out_dir, s.name)
        try:
            held = s.journal.close(keep_lock=True)  # its lock kept until converted: no repair takes it between
        except Exception as err:  # noqa: BLE001 - the flushed chunks are still repairable
            self.log.error(f"{s.name}: closing the journal failed ({err!r}); run soil_bag_repair {partial}")
            self.unwritten.append(s.name)
            return None
        try:
            return self._convert(s, how, partial, locked=held is not None)
        finally:
            if held is not None:
                os.close(held)

    def _convert(self, s: Session, how: str, partial: Path, *, locked: bool) -> BagResult | None:
        """The closed journal of ``s`` to its bag (``locked``: this recorder still holds its lock)."""
        if how == "grace_timeout":
            self.log.warning(f"{s.name}: end grace {self.end_grace_s} s expired; short topics "
                             f"(last stamp received, want {s.last_stamp_ns}): {self._short_topics(s)}")
        if s.total == 0:
            shutil.rmtree(partial, ignore_errors=True)
            self.log.warning(f"{s.name}: no message recorded; no bag written")
            return None
        if s.cut_by is not None:  # its ticks are complete up to where it was cut, not to its planned end
            how = "cut_short"
        info = {"end": how, "received": dict(s.counts), "duplicates": s.duplicates, "off_grid": dict(s.off_grid)}
        if s.cut_by is not None:
            info["cut_by"] = s.cut_by
        if s.meta_json is not None:  # an episode: the tick each topic's recorded messages start at
            info["first_tick"] = {t: tick_index(v, s.first_stamp_ns) for t, v in sorted(s.topic_min.items())}
            # (a topic that starts when it has something to say, the first valid estimate's force at
            # tick 59, says nothing by its first tick: only its having no message is said)
            late = {t: f"starts at tick {k}" for t, k in info["first_tick"].items()
                    if t in self.joined_without and k and _from_first_tick(t)}
        else:  # one bag of the whole run (--no-split): when each topic's messages start after the first one's
            # (the graph's topics, stamped in simulation time; an extra --topics one may carry wall-clock stamps)
            sim = {t: v for t, v in s.topic_min.items() if t in GRAPH_TOPICS_BY_NAME}
            first = min(sim.values(), default=0)
            info["first_stamp_s"] = {t: (v - first) / 1e9 for t, v in sorted(sim.items())}
            late = {t: f"starts {v:.3f} s after the first recorded message" for t, v in info["first_stamp_s"].items()
                    if t in self.joined_without and v > 0.0 and _from_first_tick(t)}
        silent = [t for t in sorted(self.joined_without) if t not in s.topic_min]
        if late:  # (unsaid in a --no-split bag before 2026-12-04: a first episode's commands went missing)
            self.log.warning(f"{s.name}: {', '.join(f'{t} {what}' for t, what in late.items())}: the recorder "
                             "joined before their writers had matched (--inputs-wait), so their first messages "
                             "may be missing from the bag")
        if silent:  # (it was said as a late match too, where nothing had published them at all)
            self.log.warning(f"{s.name}: {', '.join(silent)} has no message: no node published it during the "
                             "episode (or its writer matched only after it)")
        if s.event is not None:
            info.update(episode=s.event.episode, planned_ticks=s.event.planned_ticks)
        if s.end_event is not None:
            info.update(reason=s.end_event.reason, published_ticks=s.end_event.ticks, stats=s.end_event.stats or {})
        try:
            if s.total >= _SAY_MAKING_FROM:  # (seconds of work: said)
                self.log.info(f"{s.name}: making its bag of {s.total} messages")
            with reporting(lambda spent: self.log.info(f"{s.name}: making its bag of {s.total} messages: "
                                                       f"{spent:.0f} s so far")):
                result = journal_to_bag(partial, trim_partial_ticks=s.meta_json is not None,
                                        info_key=RECORDER_INFO_KEY, info=info, locked=locked)
        except (NothingRecoverable, OSError, ValueError) as err:
            self.log.error(f"{s.name}: no bag written: {err}")
            self.unwritten.append(s.name)
            return None
        extra = f", {s.duplicates} duplicates" if s.duplicates else ""
        # "completed" is the recording's (every tick of the episode in); how the episode itself
        # ended (a Ctrl-C is "shutdown") is said beside it where it did not simply run its course
        if s.end_event is not None and s.end_event.reason != "completed":
            extra += f"; the episode ended: {s.end_event.reason}"
        self.log.info(f"{bag_finished_log(how)} {result.summary()}{extra}")
        # (said: a controller restarted mid-episode, matched by the recorder seconds after the simulator,
        # left 5 s of commands out of a bag that reported nothing dropped, and its replay differed there)
        ticks, lacking = _lacking_ticks(result.messages, list(self.topics), self.joined_without)
        # not one message of the simulator's state, only commands: no reader takes the bag as an episode
        # (a launch's recorder bypassed by an outside one had written such bags, exit 0). One state topic
        # missing is a replay's selection or a machine's graph without ground truth: warned below.
        state = [t for t in SIM_STATE_TOPICS if t in self.topics]
        if (s.meta_json is not None and state and not any(result.messages.get(t, 0) for t in state)
                and any(result.messages.get(t, 0) for t in TOPICS_BY_NAME)):
            why = ("no writer of them had matched when the recorder joined" if set(state) <= self.joined_without
                   else "the recorder joined after the episode's ticks?")
            self.log.error(f"{s.name}: no message of the simulator's state ({', '.join(state)}) reached the "
                           f"recorder, only commands: the bag is no episode any reader takes ({why})")
            self.unwritten.append(s.name)
        elif s.meta_json is not None and lacking:
            # a topic with no message at all had no writer (a replay that left it out, a machine without
            # ground truth), not a writer matched late: said apart (an outside tester's)
            silent = [t for t, k in lacking.items() if k >= ticks]
            partial = {t: k for t, k in lacking.items() if k < ticks}
            if silent:
                self.log.warning(f"{s.name}: no message of {', '.join(silent)} reached the recorder in this episode "
                                 f"({ticks} ticks): nothing sent it (a replay that left it out, a node that died before "
                                 "the episode or never joined it); the bag holds it empty")
            if partial:
                self.log.warning(f"{s.name}: the bag lacks ticks of {', '.join(f'{t} ({k} of {ticks})' for t, k in partial.items())}: "
                                 "their messages never reached the recorder (a writer it matched late, e.g. a node "
                                 "restarted mid-episode, or one that skipped ticks); those ticks are incomplete in the "
                                 "bag, and a replay of it differs from the live run there")
        if result.conflicts or s.off_grid:
            self.log.warning(
                f"{s.name}: other publishers claimed stamps of the recorded data; refused per topic: "
                f"{result.conflicts or {}} (another writer's: claims on the recorded publisher's stamps, or too few "
                f"messages beside it for a restarted node's), {s.off_grid} (off the tick grid)")
        self.finished.append(result)
        return result
