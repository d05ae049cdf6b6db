"""Crash-safe recording: a live MCAP journal per bag, and its conversion to the final bag.

While a bag is being recorded its messages go to ``<out>/<name>.partial/<name>.mcap``, an
ordinary chunked MCAP file (profile ``ros2``, ``ros2msg`` schemas from the Jazzy typestore,
``cdr`` channels carrying rosbag2's ``offered_qos_profiles``/``topic_type_hash`` channel
metadata) that starts with a Metadata record holding the episode metadata. ``flush()``
closes the chunk in progress and flushes the OS stream, so every flushed chunk survives a
SIGKILL of the recorder (not a power cut: there is no fsync). A journal is never the final
product: the recorder (clean finish) and ``soil_bag_repair`` (after a crash) both turn it
into the rosbag2 bag ``<out>/<name>/`` with :func:`journal_to_bag`, the same format as
``bag_io.write_episode`` (version 9, MCAP, custom_data ``bag_io.META_KEY``).

Reading tolerates truncation and damage (``integrity.read_records``): every record of every
complete chunk that passes its CRC; a chunk failing it is skipped and reported (index, byte
offset, log time range, messages per topic from its message index) and reading goes on; the
torn tail a killed writer leaves ends the reading. Messages whose channel was defined in a
skipped chunk cannot be attributed and are dropped and counted too.

Claims: an episode journal may hold messages of one topic from several writers (a second
publisher, a redelivery). Each message's MCAP ``sequence`` is the DDS publication sequence
number of its writer (0: unknown), so the conversion can tell the writers apart
(:func:`refused_claims`, with ``soil_msgs_py.writer_identity.leading_chain``): on a topic of
the graph's tick grid the bag keeps only the writer that sent the most ticks, i.e. the
publisher that has been recording every tick, whether another writer's stamp is also
claimed or not, judged over the whole journal, and the writers wholly before or after it (a
publisher restarted with a new counter: ``writer_identity.succession``); of messages still claiming one (topic,
stamp) it keeps the one with plausible values (finite, within ``messages.PLAUSIBLE_ABS_LIMIT``),
then the first to arrive. The others are
counted per topic in the bag's recorder info (``conflicts``).
"""
from __future__ import annotations

import fcntl
import json
import logging
import os
import shutil
from collections import defaultdict
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from mcap.records import Channel, DataEnd, Message, Metadata, Schema
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter
from rosbags.interfaces import Qos
from rosbags.rosbag2.metadata import dump_qos_v9, parse_qos
import yaml

from soil_msgs_py import messages as M
from soil_msgs_py.topics import GRAPH_TOPICS_BY_NAME
from soil_msgs_py.writer_identity import SEQUENCE_MASK, leading_chain, succession, tick_index
from .bag_io import META_KEY, PARTIAL_SUFFIX, journal_path
from .bag_writer import BagWriter
from .integrity import ChunkInfo, McapScan, read_records

JOURNAL_METADATA_NAME = "insitu_soil"  # name of the MCAP Metadata record written first
RECORDER_INFO_KEY = "insitu_soil.recorder"
REPAIR_INFO_KEY = "insitu_soil.repair"
FIRST_STAMP_KEY = "insitu_soil.first_stamp_ns"  # journal metadata: the episode's tick 0
_CHUNK_SIZE = 1 << 20  # chunks close at 1 MiB or at the next flush(), whichever comes first


def partial_dir(out_dir: Path, name: str) -> Path:
    return Path(out_dir) / f"{name}{PARTIAL_SUFFIX}"



def claim_name(out_dir: Path, name: str) -> str:
    """``name`` or ``name_2``, ``name_3``... : the first free bag name under ``out_dir``.

    A name is taken if either the bag or its ``.partial`` journal directory exists; the
    journal directory is created here (exclusively), so two sessions never share a name.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    k = 1
    while True:
        cand = name if k == 1 else f"{name}_{k}"
        if not (out_dir / cand).exists():
            try:
                partial_dir(out_dir, cand).mkdir()
                return cand
            except FileExistsError:
                pass
        k += 1


def _qos_yaml(qos: Sequence[Qos]) -> str:
    """offered_qos_profiles as rosbag2 (Jazzy, bag version 9) writes it in channel metadata."""
    if not qos:
        return ""
    return yaml.safe_dump(dump_qos_v9(list(qos)), default_flow_style=False, sort_keys=False).strip()


# --- writing -----------------------------------------------------------------------------

class JournalWriter:
    """One live journal file; ``write`` buffers into the current chunk, ``flush`` persists it."""

    def __init__(self, path: Path, metadata: Mapping[str, str]):
        self.path = Path(path)
        self._file = open(self.path, "wb")  # noqa: SIM115 - closed in close()
        _lock(self._file, wait=True)  # until closed: no repair converts a journal still being written
        self._mcap = McapWriter(self._file, chunk_size=_CHUNK_SIZE, compression=CompressionType.ZSTD)
        self._mcap.start(profile="ros2", library="insitu-soil soil_bag_record")
        # Written straight to the stream (not into a chunk) and flushed at once, so even a
        # journal killed before its first chunk tells what it was recording.
        self._mcap.add_metadata(JOURNAL_METADATA_NAME, dict(metadata))
        self._mcap.flush()
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self.closed = False

    def add_channel(self, topic: str, msgtype: str, qos: Sequence[Qos] = ()) -> None:
        """Register ``topic`` (idempotent); the definition comes from the Jazzy typestore."""
        if topic in self._channels:
            return
        if msgtype not in self._schemas:
            msgdef, _ = M.TYPESTORE.generate_msgdef(msgtype, ros_version=2)
            self._schemas[msgtype] = self._mcap.register_schema(msgtype, "ros2msg", msgdef.encode())
        self._channels[topic] = self._mcap.register_channel(
            topic, "cdr", self._schemas[msgtype],
            {"offered_qos_profiles": _qos_yaml(qos), "topic_type_hash": M.TYPESTORE.hash_rihs01(msgtype)},
        )

    def write(self, topic: str, log_time_ns: int, raw: bytes, publish_time_ns: int = 0, sequence: int = 0) -> None:
        """``sequence``: the writer's DDS publication sequence number (0: unknown)."""
        self._mcap.add_message(self._channels[topic], log_time_ns, raw, publish_time_ns or log_time_ns,
                               sequence & SEQUENCE_MASK)

    def flush(self) -> None:
        """Close the chunk in progress and push it to the OS: it now survives a SIGKILL."""
        if not self.closed:
            self._mcap.flush()

    def close(self, keep_lock: bool = False) -> int | None:
        """Write the summary and footer (a finished journal); idempotent. ``keep_lock``: returns a
        descriptor that keeps the journal's lock after the close (an flock belongs to the open
        file, which the duplicate keeps open), for ``journal_to_bag(locked=True)``: no repair takes
        the journal between its writer's close and its conversion."""
        if self.closed:
            return None
        self.closed = True
        try:
            self._mcap.finish()
            return os.dup(self._file.fileno()) if keep_lock else None
        finally:
            self._file.close()


class JournalInUse(ValueError):
    """Another process holds the journal's lock: a recorder still writing it (or a repair
    converting it). It is left alone; the recorder turns it into a bag itself."""


_log = logging.getLogger(__name__)
_unlocked_warned: set[int] = set()


def _lock(file, wait: bool = False) -> None:
    """An exclusive advisory lock on an open journal (``flock``: the kernel drops it when the
    holder exits, also on SIGKILL, so a dead recorder's journal is free to repair); ``wait``:
    block until it is free (a writer, behind a repair of its brand-new empty file).

    Some shared file systems have no flock (ENOSYS, ENOLCK, EOPNOTSUPP; NFS emulates it only for
    files open for writing, EBADF): there the journal goes on unlocked, said once per error."""
    try:
        fcntl.flock(file.fileno(), fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
    except BlockingIOError:  # (EWOULDBLOCK / EAGAIN: held)
        raise JournalInUse(f"{file.name}: another process is writing or converting it (a running recorder "
                           "turns it into a bag itself when its episode ends); not touched") from None
    except OSError as err:
        if err.errno not in _unlocked_warned:
            _unlocked_warned.add(err.errno)
            _log.warning("journal %s: this file system refuses a lock (%s): journals go unlocked, so do not run "
                         "soil_bag_repair on a directory a recorder is writing", file.name, err.strerror or err)


# --- reading -----------------------------------------------------------------------------

@dataclass
class JournalChannel:
    topic: str
    msgtype: str
    msgdef: str
    rihs01: str
    qos: list[Qos]


@dataclass
class JournalScan:
    """What a (possibly truncated) journal holds: first pass of :func:`journal_to_bag`."""

    path: Path
    metadata: dict[str, str] = field(default_factory=dict)
    channels: dict[int, JournalChannel] = field(default_factory=dict)
    stamps: dict[str, list[int]] = field(default_factory=dict)  # log times per topic, file order
    sequences: dict[str, list[int]] = field(default_factory=dict)  # writer sequence numbers, same order
    orphans: int = 0  # messages in good chunks whose channel was defined in a skipped chunk
    mcap: McapScan | None = None  # chunks read and skipped, where reading stopped

    @property
    def messages(self) -> int:
        return sum(len(v) for v in self.stamps.values())

    @property
    def complete(self) -> bool:
        """The footer was reached: the writer closed the journal."""
        return self.mcap is not None and self.mcap.complete

    @property
    def stop(self) -> str:
        """Why reading stopped before the footer ("" if complete)."""
        return "" if self.mcap is None else self.mcap.stop

    @property
    def bad_chunks(self) -> list[ChunkInfo]:
        return [] if self.mcap is None else self.mcap.bad


def _records(path: Path, scan: JournalScan) -> Iterator[object]:
    """Every readable record, chunks failing their CRC skipped (noted in ``scan.mcap``)."""
    scan.mcap = McapScan(path)
    yield from read_records(path, scan.mcap)


def scan_journal(path: Path) -> JournalScan:
    scan = JournalScan(Path(path))
    schemas: dict[int, Schema] = {}
    summary = False  # past DataEnd: the summary's repeated schemas/channels come after their
    # messages, so a channel lost with a skipped chunk stays lost (every pass agrees on orphans)
    for record in _records(scan.path, scan):
        if isinstance(record, Metadata):
            scan.metadata.update(record.metadata)
        elif isinstance(record, DataEnd):
            summary = True
        elif isinstance(record, Schema) and not summary:
            schemas[record.id] = record
        elif isinstance(record, Channel) and record.id not in scan.channels and not summary:
            schema = schemas.get(record.schema_id)
            if schema is None and scan.bad_chunks:
                continue  # its schema was in a skipped chunk: its messages are orphans
            if schema is None:
                raise ValueError(f"{path}: channel {record.topic!r} refers to missing schema id {record.schema_id}")
            scan.channels[record.id] = JournalChannel(
                topic=record.topic, msgtype=schema.name, msgdef=schema.data.decode(),
                rihs01=record.metadata.get("topic_type_hash") or M.TYPESTORE.hash_rihs01(schema.name),
                qos=parse_qos(record.metadata.get("offered_qos_profiles", "")),
            )
            scan.stamps.setdefault(record.topic, [])
            scan.sequences.setdefault(record.topic, [])
        elif isinstance(record, Message):
            if record.channel_id not in scan.channels:
                scan.orphans += 1
                continue
            topic = scan.channels[record.channel_id].topic
            scan.stamps[topic].append(record.log_time)
            scan.sequences[topic].append(record.sequence)
    return scan


def labelled_values(topic: str, msgtype: str, raw: bytes | memoryview):
    """(stamp, values) of a message of a graph topic (episode or labelled extra), None for
    another topic; ValueError/TypeError etc. if it does not parse as its topic's layout."""
    f = M.FIELDS.get(topic)
    msg = M.TYPESTORE.deserialize_cdr(raw, msgtype)
    if f is not None and f.topic.msgtype == msgtype:
        return M.parse_message(topic, msg)
    t = GRAPH_TOPICS_BY_NAME.get(topic)
    if t is not None and t.labels and t.msgtype == msgtype:
        return M.parse_labelled(msg, t.labels, topic)
    return None


def _plausible(topic: str, msgtype: str, raw: bytes) -> bool:
    try:
        parsed = labelled_values(topic, msgtype, raw)
    except Exception:  # noqa: BLE001 - an undecodable claim is as bad as a non-finite one
        return False
    return parsed is None or M.plausible_values(parsed[1])  # other topics: not ours to judge


def refused_claims(scan: JournalScan) -> dict[str, set[int]]:
    """Per topic, indices (file order) of messages the bag does not keep.

    On the tick grid a message's writer is told by sequence continuity, judged over the whole
    journal (``writer_identity.leading_chain``): every message off the leading writer's chain
    is refused, but for the writers whose ticks lie wholly before or after it (a publisher that
    died and was restarted, its new counter a chain of its own; ``writer_identity.succession``),
    plausible values only. Where several writers' messages could be that chain (an intruder's counter
    that fits a tick the writer skipped, or meets it at a tick), the chain with the most
    messages with plausible values (``messages.plausible_values``: finite, no 1e30, no subnormal) wins, and once
    another writer showed up on the topic an implausible message is never taken for the chain's
    (graph nodes publish none). Of the messages left, those claiming one stamp keep the one with
    plausible values, then the
    first to arrive (writers unknown: no sequence numbers, or writers that sent equally many
    ticks). A message with the very stamp and sequence
    number of one on the chain is not refused by sequence: two counters that meet at a tick
    cannot be told apart there, so the values decide, like for unknown writers.
    """
    if not any(scan.stamps.values()):
        return {}
    first = int(scan.metadata.get(FIRST_STAMP_KEY) or min(min(v) for v in scan.stamps.values() if v))
    judged: dict[str, list[int]] = {}  # per topic, messages on the grid with a sequence number
    chains: dict[str, set[int] | None] = {}
    for topic, stamps in scan.stamps.items():
        ticks = [tick_index(t, first) for t in stamps]
        judged[topic] = [i for i, k in enumerate(ticks) if k is not None and scan.sequences[topic][i]]
        chains[topic] = _chain(scan, topic, judged[topic], first)
    # One writer per topic is the rule: values are read only where another writer showed up.
    plausible = _plausible_values(scan, {t: set(judged[t]) for t, c in chains.items()
                                         if c is not None and len(c) < len(judged[t])})
    refused: dict[str, set[int]] = {}
    contested: dict[str, list[list[int]]] = {}
    for topic, stamps in scan.stamps.items():
        sequences, chain = scan.sequences[topic], chains[topic]
        if chain is not None and len(chain) < len(judged[topic]):
            weights = [2 if plausible.get((topic, i), True) else 1 for i in judged[topic]]
            chain = _chain(scan, topic, judged[topic], first, weights)
            # Graph nodes never publish implausible values; with another writer about, such a
            # claim on the chain is an intruder's whose counter fitted a tick the writer left
            # free with nothing after it to displace (a skipped last tick, a lost message).
            chain = None if chain is None else {i for i in chain if plausible.get((topic, i), True)}
            if chain:  # a publisher restarted (a new counter) before or after the leader: its ticks are its own
                js = judged[topic]
                chain = {js[j] for j in succession(
                    [tick_index(stamps[i], first) for i in js], [sequences[i] for i in js],
                    {j for j, i in enumerate(js) if i in chain}, [plausible.get((topic, i), True) for i in js])}
        foreign: set[int] = set()
        if chain is not None:
            claims = {(stamps[i], sequences[i]) for i in chain}
            foreign = {i for i in judged[topic] if i not in chain and (stamps[i], sequences[i]) not in claims}
        by_stamp: dict[int, list[int]] = defaultdict(list)
        for i, stamp in enumerate(stamps):
            if i not in foreign:
                by_stamp[stamp].append(i)
        if foreign:
            refused[topic] = foreign
        if groups := [g for g in by_stamp.values() if len(g) > 1]:
            contested[topic] = groups
    if not contested:
        return refused
    wanted = {t: {i for g in groups for i in g} for t, groups in contested.items()}
    plausible.update(_plausible_values(scan, {t: {i for i in v if (t, i) not in plausible} for t, v in wanted.items()}))
    for topic, groups in contested.items():
        for g in groups:
            keep = min(g, key=lambda i: (not plausible.get((topic, i), False), i))
            refused.setdefault(topic, set()).update(i for i in g if i != keep)
    return refused


def _chain(scan: JournalScan, topic: str, judged: Sequence[int], first: int,
           weights: Sequence[int] | None = None) -> set[int] | None:
    """The leading writer's messages among ``judged`` (file-order indices), as file indices."""
    stamps, sequences = scan.stamps[topic], scan.sequences[topic]
    chain = leading_chain([tick_index(stamps[i], first) for i in judged], [sequences[i] for i in judged], weights)
    return None if chain is None else {judged[j] for j in chain}


def _plausible_values(scan: JournalScan, wanted: Mapping[str, set[int]]) -> dict[tuple[str, int], bool]:
    """Whether each wanted message (topic, file index) has plausible values (one pass over the file)."""
    out: dict[tuple[str, int], bool] = {}
    if not any(wanted.values()):
        return out
    index: dict[str, int] = defaultdict(int)
    for record in _records(scan.path, JournalScan(scan.path)):
        if isinstance(record, Message) and (ch := scan.channels.get(record.channel_id)) is not None:
            i = index[ch.topic]
            index[ch.topic] += 1
            if i in wanted.get(ch.topic, ()):
                out[(ch.topic, i)] = _plausible(ch.topic, ch.msgtype, record.data)
    return out


def stamps_in_every_topic(stamps: Mapping[str, Sequence[int]]) -> set[int]:
    """Stamps at which every topic with any message has one (a topic nobody published must
    not wipe the bag)."""
    sets = [set(v) for v in stamps.values() if len(v)]
    return set.intersection(*sets) if sets else set()


def whole_tick_cutoff(stamps: Mapping[str, Sequence[int]]) -> int | None:
    """Highest stamp at which every topic (with any message) has a message, else None.

    Messages after it belong to trailing ticks that were cut short (recorder stopped or
    killed mid-tick); dropping them leaves a bag ``bag_io.read_episode`` can read. Gaps in
    the middle are not touched (``journal_to_bag`` drops the ticks a skipped chunk split).
    """
    return max(stamps_in_every_topic(stamps), default=None)


# --- conversion --------------------------------------------------------------------------

def chunk_details(chunks: Sequence[ChunkInfo], topics: Mapping[int, str]) -> list[dict]:
    """Skipped chunks as the JSON a bag's custom_data records (what was dropped, and why)."""
    return [{"chunk": c.index, "byte_offset": c.offset, "log_time_ns": [c.start_ns, c.end_ns],
             "messages": {topics.get(k, f"channel {k}"): n for k, n in sorted(c.messages.items())},
             "problem": c.problem} for c in chunks]


class NothingRecoverable(ValueError):
    """The journal has no message that can go into a bag."""


@dataclass
class BagResult:
    path: Path
    ticks: int  # distinct stamps written
    messages: dict[str, int]  # written per topic
    recovered: int  # messages read from the journal
    dropped: int  # recovered but not written (trailing partial ticks)
    last_stamp_ns: int
    journal_complete: bool
    stop: str
    conflicts: dict[str, int] = field(default_factory=dict)  # refused claims on a stamp, per topic
    dropped_chunks: list[str] = field(default_factory=list)  # chunks skipped (failed CRC), one line each
    orphans: int = 0  # messages dropped because their channel was defined in a skipped chunk
    torn_chunk: str = ""  # the chunk the file ends inside, whose whole records were kept (one line)
    metadata_from_mcap: str = ""  # why metadata.yaml was rebuilt from the .mcap's own record ("": it was read)

    def summary(self) -> str:
        counts = set(self.messages.values())
        per_topic = (
            f"{counts.pop()} on each of {len(self.messages)} topics" if len(counts) == 1
            else " ".join(f"{t}={n}" for t, n in self.messages.items())
        )
        refused = (f", {sum(self.conflicts.values())} refused claims on stamps of "
                   f"{', '.join(sorted(self.conflicts))}" if self.conflicts else "")
        skipped = (f", {len(self.dropped_chunks)} corrupt chunk(s) skipped" if self.dropped_chunks else "")
        orphans = f", {self.orphans} messages of channels defined in them" if self.orphans else ""
        return (f"{self.path}: {self.ticks} ticks, {sum(self.messages.values())} messages "
                f"({per_topic}), {self.dropped} dropped{refused}{skipped}{orphans}")


def journal_to_bag(
    partial: Path, *, trim_partial_ticks: bool = True, info_key: str = RECORDER_INFO_KEY,
    info: Mapping | None = None, locked: bool = False,
) -> BagResult:
    """Convert the journal in ``partial`` (a ``<name>.partial`` directory) to the bag ``<name>/``.

    The bag is written inside ``partial`` and renamed into place, then ``partial`` is removed,
    so a bag directory is either complete or absent. If ``<name>/`` already exists the bag is
    named ``<name>_2`` etc. Episode metadata found in the journal goes to custom_data
    ``META_KEY``; ``info`` plus the conversion counts go to custom_data ``info_key``. For
    episode journals ``trim_partial_ticks`` drops trailing ticks not present on every topic.
    Raises NothingRecoverable (journal kept) if no message would be written, JournalInUse
    (journal untouched) if another process holds its lock (a recorder still writing it).
    ``locked``: the caller holds the journal's lock (``JournalWriter.close(keep_lock=True)``).
    """
    partial = Path(partial)
    if not partial.name.endswith(PARTIAL_SUFFIX):
        raise ValueError(f"{partial} is not a journal directory (name must end in {PARTIAL_SUFFIX})")
    jpath = journal_path(partial)
    if not jpath.is_file():
        raise NothingRecoverable(f"{partial}: no journal file {jpath.name} (not left by soil_bag_record?)")
    if locked:
        return _convert(partial, jpath, trim_partial_ticks, info_key, info)
    with _open_to_lock(jpath) as lock:
        _lock(lock)  # held until the journal is gone: nothing appends to it meanwhile
        if not jpath.is_file():  # another repair converted it while this one waited to open it
            raise NothingRecoverable(f"{partial}: converted by another process meanwhile")
        return _convert(partial, jpath, trim_partial_ticks, info_key, info)


def _open_to_lock(jpath: Path):
    """The journal opened for its lock: for writing where allowed (NFS's flock needs it), else
    for reading (a read-only copy of a journal, whose directory can still be converted)."""
    try:
        return open(jpath, "r+b")  # noqa: SIM115 - closed by the caller's with
    except PermissionError:
        return open(jpath, "rb")  # noqa: SIM115


def _convert(partial: Path, jpath: Path, trim_partial_ticks: bool, info_key: str, info: Mapping | None) -> BagResult:
    """``journal_to_bag``'s work, on a journal nobody else holds."""
    scan = scan_journal(jpath)
    if scan.messages == 0:
        why = "; ".join([c.describe(scan.mcap.topics) for c in scan.bad_chunks] + ([scan.stop] if scan.stop else []))
        raise NothingRecoverable(f"{jpath}: no complete chunk with a message" + (f" ({why})" if why else ""))
    meta_json = scan.metadata.get(META_KEY)
    refused = refused_claims(scan) if meta_json is not None else {}
    cutoff = None
    split: dict[str, set[int]] = {}  # per episode topic, stamps of ticks a skipped chunk split
    if trim_partial_ticks and meta_json is not None:
        # Whole ticks are judged on the episode topics' kept messages; extra topics
        # (--topics) keep what is stamped up to the last whole tick.
        kept_stamps = {t: [s for i, s in enumerate(v) if i not in refused.get(t, ())]
                       for t, v in scan.stamps.items()}
        tick_topics = {t: v for t, v in kept_stamps.items() if t in M.FIELDS} or kept_stamps
        cutoff = whole_tick_cutoff(tick_topics)
        if cutoff is None:
            raise NothingRecoverable(
                f"{jpath}: {scan.messages} messages recovered but no tick has a message on every topic "
                f"(use --keep-partial-ticks to keep them)"
            )
        if scan.bad_chunks:  # a skipped chunk's edges split ticks: their other messages go too
            whole = stamps_in_every_topic(tick_topics)
            split = {t: {s for s in v if s not in whole} for t, v in tick_topics.items()}
    in_range = (lambda t: True) if cutoff is None else (lambda t: t <= cutoff)

    def keep(topic: str, i: int) -> bool:
        stamp = scan.stamps[topic][i]
        return in_range(stamp) and i not in refused.get(topic, ()) and stamp not in split.get(topic, ())

    kept_by_topic = {t: [s for i, s in enumerate(v) if keep(t, i)] for t, v in scan.stamps.items()}
    kept = [s for v in kept_by_topic.values() for s in v]
    result = BagResult(
        path=partial.parent / partial.name[: -len(PARTIAL_SUFFIX)], ticks=len(set(kept)),
        messages={ch.topic: len(kept_by_topic[ch.topic]) for ch in scan.channels.values()},
        recovered=scan.messages, dropped=scan.messages - len(kept), last_stamp_ns=max(kept),
        journal_complete=scan.complete, stop=scan.stop,
        conflicts={t: n for t, idx in sorted(refused.items()) if (n := sum(1 for i in idx if in_range(scan.stamps[t][i])))},
        dropped_chunks=[c.describe(scan.mcap.topics) for c in scan.bad_chunks], orphans=scan.orphans,
    )
    base = result.path.name
    k = 1
    while result.path.exists():
        k += 1
        result.path = partial.parent / f"{base}_{k}"
    staging = partial / result.path.name
    shutil.rmtree(staging, ignore_errors=True)  # left by an interrupted conversion

    details = dict(info or {})
    details.update(recovered_messages=result.recovered, written_messages=len(kept),
                   dropped_messages=result.dropped, ticks=result.ticks, last_stamp_ns=result.last_stamp_ns,
                   messages=result.messages, journal_complete=scan.complete, conflicts=result.conflicts)
    if scan.stop:
        details["journal_stop"] = scan.stop
    if scan.bad_chunks:
        details["dropped_chunks"] = chunk_details(scan.bad_chunks, scan.mcap.topics)
        details["orphaned_messages"] = scan.orphans
    with BagWriter(staging) as writer:
        if meta_json is not None:
            writer.set_custom_data(META_KEY, meta_json)
        writer.set_custom_data(info_key, json.dumps(details, sort_keys=True))
        conns = {
            cid: writer.add_connection(ch.topic, ch.msgtype, msgdef=ch.msgdef, rihs01=ch.rihs01,
                                       offered_qos_profiles=ch.qos)
            for cid, ch in scan.channels.items()
        }
        index: dict[str, int] = defaultdict(int)  # per topic, as in scan.stamps
        for record in _records(jpath, JournalScan(jpath)):
            if isinstance(record, Message) and record.channel_id in scan.channels:
                topic = scan.channels[record.channel_id].topic
                i = index[topic]
                index[topic] += 1
                if keep(topic, i):
                    writer.write(conns[record.channel_id], record.log_time, record.data)
    os.replace(staging, result.path)
    shutil.rmtree(partial)
    return result
