"""Player core (no rclpy): which bags, which raw messages, when to publish each one.

``play_node.py`` only creates publishers and calls ``publish(raw)``; everything a test can
check without DDS lives here: expanding BAG arguments, loading a bag's raw CDR messages in
log-time order (stable: a tick's messages in stored order), the ``/sim/status`` events of
an episode bag, synthetic ``/clock`` messages, and the :class:`Pacer` that turns bag time
into absolute wall-clock deadlines (``start + (t - t0) / rate`` on ``time.perf_counter``:
sleep until ~0.5 ms before, then spin), so lateness never accumulates.
"""
from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

from rosbags.highlevel import AnyReader

from soil_msgs_py import messages as M
from soil_msgs_py.params import grid_stamp_ns
from .bag_io import (META_KEY, PARTIAL_SUFFIX, bag_custom_data, is_bag, passed_by_note, reading, scan_bags,
                     topics_namespace)
from soil_msgs_py.episode import EpisodeMeta
from soil_msgs_py.graph import (EVENT_EPISODE_END, EVENT_EPISODE_START, GRAPH_OWN_TOPICS, REALTIME_FACTOR_RANGE,
                                STRING_MSGTYPE, EpisodeEvent)
from soil_msgs_py.topics import CLOCK, EPISODE_TOPICS, GRAPH_TOPICS_BY_NAME, GROUND_TRUTH, with_guesses

CLOCK_TOPIC = CLOCK.name
RATE_LIMITS = REALTIME_FACTOR_RANGE  # replay speed factors a player accepts, the simulator's


def check_rate(rate: float) -> float:
    """``rate`` if it is a replay speed factor within ``RATE_LIMITS``; ValueError naming it if not (NaN too)."""
    lo, hi = RATE_LIMITS
    if not lo <= rate <= hi:
        raise ValueError(f"rate {rate} must be a finite number in [{lo:g}, {hi:g}]")
    return rate

CLOCK_MSGTYPE = CLOCK.msgtype


class BagPathError(ValueError):
    """A BAG argument that is not a bag nor a directory of bags."""


def expand_bag_args(paths: Sequence[str | os.PathLike], notes: list[str] | None = None) -> list[Path]:
    """Bag directories in play order: each argument is a bag, or a directory of bags (path order).
    What a directory's search passed by (a killed recorder's journal, a stray .mcap) is appended to
    ``notes`` for the user, and named in the error when it found no bag at all."""
    bags: list[Path] = []
    for arg in paths:
        path = Path(arg)
        if is_bag(path):
            bags.append(path)
        elif path.name.endswith(PARTIAL_SUFFIX) and path.is_dir():
            raise BagPathError(f"{path}: a recorder journal, not a bag (a killed recorder's or one still being "
                               f"written): soil_bag_repair {path} turns a killed recorder's into a bag")
        elif path.is_dir():
            found, strays = scan_bags(path)
            note = passed_by_note(strays, path)
            if not found:
                raise BagPathError(f"{path}: not a rosbag2 bag (no metadata.yaml) and contains no bags"
                                   + (f"; {note}" if note else ""))
            if note and notes is not None:
                notes.append(f"{path}: {note}")
            bags += found
        elif path.exists():
            raise BagPathError(f"{path}: not a rosbag2 bag directory")
        else:
            raise BagPathError(f"{path}: no such bag or directory")
    return bags


@dataclass
class LoadedBag:
    path: Path
    topics: dict[str, str]  # topic -> msgtype, of the messages kept
    messages: list[tuple[int, str, bytes]]  # (log time ns, topic, CDR), publish order
    meta: EpisodeMeta | None  # episode metadata if the bag has some
    held: frozenset[str] = frozenset()  # every topic of the bag: said when the selection keeps none

    @property
    def name(self) -> str:
        return self.path.name

    @property
    def ticks(self) -> int:
        return len({t for t, _, _ in self.messages})


def absent_topics(bag: Path, option: str, asked: Iterable[str], held: Iterable[str]) -> str:
    """The warning for the topics ``option`` (--topics, --exclude) names that ``bag`` does not hold,
    each with the bag's or the contract's topic it may have been meant as ("" if it holds them all;
    for --exclude, a topic of the graph's contract a bag lacks is no mistake and not said): a
    mistyped ``--exclude /soil/estimat`` had played the estimate in silence."""
    held = set(held)
    missing = sorted(set(asked) - held)
    if option == "--exclude":  # a graph topic a bag lacks is excluded all the same (docs/bags.md's list of the
        missing = [t for t in missing if t not in GRAPH_TOPICS_BY_NAME]  # estimator's outputs, on a batch's bags)
    if not missing:
        return ""
    effect = "not played" if option == "--topics" else "nothing excluded for it"
    return f"{bag}: no topic(s) {with_guesses(missing, held | set(GRAPH_TOPICS_BY_NAME))}, named by {option}: {effect}"


def refuse_contract_types(bag: Path, topics: dict[str, str]) -> None:
    """BagPathError for a topic of ``topics`` (name -> type, the contract's names) that has the
    contract's name but another type: the graph's nodes would not hear it (DDS matches name and
    type) and the player had said only that it had too few subscribers (an outside tester's
    /blade/force recorded as a Wrench; the bag readers refuse it too)."""
    if wrong := sorted((t, m) for t, m in topics.items() if t in GRAPH_TOPICS_BY_NAME and m != GRAPH_TOPICS_BY_NAME[t].msgtype):
        topic, msgtype = wrong[0]
        raise BagPathError(f"{bag}: topic {topic} is {msgtype} in it, but the graph's contract is "
                           f"{GRAPH_TOPICS_BY_NAME[topic].msgtype}: no node of the graph would hear it; "
                           f"--exclude {topic} plays the rest")


def load_bag(
    bag: Path, *, topics: Iterable[str] | None = None, exclude: Iterable[str] = (), drop: Iterable[str] = (),
    log: Callable[[str], None] = lambda s: None,
) -> LoadedBag:
    """Raw messages of ``bag`` (all topics, or ``topics``), minus ``exclude`` and ``drop``, in
    log-time order; a topic of ``topics`` or ``exclude`` the bag lacks is said (``absent_topics``),
    one of ``drop`` is not (the player's own: --clock's /clock).

    A bag a machine's own recorder wrote under one namespace (``/dozer1/blade/force``, as the
    readers take it: ``bag_io.topics_namespace``) gives the graph's topics by the contract's names,
    which ``topics`` and ``exclude`` name too, so a player puts them into its own namespace; before,
    it sent them to the recorded machine's (``/dozer1``) whatever its own.

    BagReadError (naming the bag) if it is truncated or corrupt."""
    include = None if topics is None else set(topics)
    skip = set(exclude) | set(drop)
    meta = None
    custom = bag_custom_data(bag)
    if META_KEY in custom:
        try:
            meta = EpisodeMeta.from_json(custom[META_KEY])
            meta.validate(machine_world=True)  # as the bag readers: a machine's bag frames its episode too
        except (TypeError, ValueError) as err:
            log(f"{bag}: bad episode metadata ({err}); playing without /sim/status events")
            meta = None
    with reading(bag), AnyReader([bag], default_typestore=M.TYPESTORE) as reader:
        ns = topics_namespace(bag, {c.topic for c in reader.connections})

        def named(topic: str) -> str:  # the contract's name of a graph topic under the bag's namespace
            return topic[len(ns):] if ns and topic.startswith(ns + "/") and topic[len(ns):] in GRAPH_OWN_TOPICS else topic

        conns = [c for c in reader.connections
                 if (include is None or named(c.topic) in include) and named(c.topic) not in skip]
        found = {named(c.topic): c.msgtype for c in conns}
        held = frozenset(named(c.topic) for c in reader.connections)
        messages = ([(t, named(c.topic), bytes(raw)) for c, t, raw in reader.messages(connections=conns)]
                    if conns else [])
    refuse_contract_types(bag, found)
    for option, asked in (("--topics", include or ()), ("--exclude", skip - set(drop))):
        if note := absent_topics(bag, option, asked, held):  # absent from the bag (not merely excluded)
            log(note)
    if meta is not None and (include is None or include <= held) and (missing := [t.name for t in EPISODE_TOPICS if t.name not in held  # (a machine's bag
                                           and t.name not in (GROUND_TRUTH.name, CLOCK.name)]):  # has no truth, no clock)
        # played all the same (a player sends what a bag holds), but every bag reader refuses it
        log(f"{bag}: an episode bag without topic(s) {missing}: its ticks are incomplete (the bag readers "
            "refuse it; what a replay feeds lacks them too)")
    return LoadedBag(path=bag, topics=found, messages=messages, meta=meta, held=held)


def check_readable(bag: Path, topics: Iterable[str] | None = None, exclude: Iterable[str] = ()) -> None:
    """What ``load_bag`` checks of a bag before reading its messages (its metadata.yaml, every chunk's
    CRC, rosbags opening it, one machine's namespace, the types of the contract's topics it would
    play, ``topics`` (None: all) but ``exclude``): BagReadError naming the bag and, where it can
    mend it, ``soil_bag_repair``; BagPathError for a contract topic of another type
    (``refuse_contract_types``)."""
    bag_custom_data(bag)
    with reading(bag), AnyReader([bag], default_typestore=M.TYPESTORE) as reader:
        ns = topics_namespace(bag, {c.topic for c in reader.connections})
        types = {c.topic[len(ns):] if ns and c.topic.startswith(ns + "/") else c.topic: c.msgtype for c in reader.connections}
    played = {t: m for t, m in types.items() if (topics is None or t in set(topics)) and t not in set(exclude)}
    refuse_contract_types(bag, played)


def unreadable_bags(bags: Sequence[Path], topics: Iterable[str] | None = None, exclude: Iterable[str] = ()) -> list[str]:
    """Why each of ``bags`` that ``check_readable`` refuses cannot be played, in play order ([]: all
    pass). The player asks before it plays the first: a directory with a truncated bag among its
    bags had played those before it and stopped there, exit 2, half a dataset replayed."""
    problems = []
    for bag in bags:
        try:
            check_readable(bag, topics, exclude)
        except ValueError as err:  # BagReadError, and a metadata.yaml custom_data that is no mapping
            problems.append(str(err))
    return problems


def string_cdr(text: str) -> bytes:
    return bytes(M.TYPESTORE.serialize_cdr(M.TYPESTORE.types[STRING_MSGTYPE](data=text), STRING_MSGTYPE))


def clock_cdr(stamp_ns: int) -> bytes:
    msg = M.build_message(M.TYPESTORE, CLOCK_TOPIC, stamp_ns)
    return bytes(M.TYPESTORE.serialize_cdr(msg, CLOCK_MSGTYPE))


def episode_events(bag: LoadedBag, episode: int) -> tuple[EpisodeEvent, EpisodeEvent] | None:
    """The ``episode_start``/``episode_end`` pair a replay of an episode bag publishes, else None."""
    if bag.meta is None or not bag.messages:
        return None
    first, last, ticks = bag.messages[0][0], bag.messages[-1][0], bag.ticks
    start = EpisodeEvent(event=EVENT_EPISODE_START, episode=episode, name=bag.name, meta=bag.meta,
                         first_stamp_ns=first, planned_ticks=ticks)
    end = EpisodeEvent(event=EVENT_EPISODE_END, episode=episode, name=bag.name, meta=bag.meta,
                       first_stamp_ns=first, planned_ticks=ticks, last_stamp_ns=last, ticks=ticks,
                       reason="end_of_bag", stats={"source": "soil_bag_play"})
    return start, end


def with_clock(messages: Sequence[tuple[int, str, bytes]], hz: float) -> Iterator[tuple[int, str, bytes]]:
    """``messages`` without their own /clock, merged with /clock at ``hz`` from the first to the last
    stamp: clock k at first + floor(k·1e9/hz) ns, at 60 Hz the ticks' own stamps (the simulator
    stamps tick k of an episode first + floor(k·1e9/60); rounded, a third were off that grid and a
    recorder of the replay dropped them).

    A clock tick at the same time as a message goes first (time advances, then data at it).
    """
    if not hz > 0:
        raise ValueError(f"clock rate {hz} Hz must be > 0")
    data = [m for m in messages if m[1] != CLOCK_TOPIC]
    if not data:
        return
    t0 = data[0][0]
    k = 0
    next_clock = t0
    for m in data:
        while next_clock <= m[0]:
            yield next_clock, CLOCK_TOPIC, clock_cdr(next_clock)
            k += 1
            next_clock = t0 + grid_stamp_ns(k, hz)
        yield m


class Pacer:
    """Absolute-deadline timing: message at bag time t is due at ``start + (t - t0) / rate``."""

    def __init__(self, rate: float, *, spin_s: float = 0.0005,
                 now: Callable[[], float] = time.perf_counter, sleep: Callable[[float], None] = time.sleep):
        self.rate, self.spin_s, self.now, self.sleep = check_rate(rate), spin_s, now, sleep
        self.start = 0.0
        self.t0 = 0

    def begin(self, t0_ns: int, start: float | None = None) -> None:
        """Bag time ``t0_ns`` happens at wall time ``start`` (default: now)."""
        self.t0, self.start = t0_ns, self.now() if start is None else start

    def deadline(self, t_ns: int) -> float:
        return self.start + (t_ns - self.t0) * 1e-9 / self.rate

    def wait(self, t_ns: int) -> float:
        """Block until bag time ``t_ns`` is due; returns how late we are [s] (>= 0)."""
        due = self.deadline(t_ns)
        while True:
            remaining = due - self.now()
            if remaining <= 0:
                return -remaining
            if remaining > self.spin_s:
                self.sleep(remaining - self.spin_s)
