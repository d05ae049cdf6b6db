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

Reading tolerates truncation: the MCAP stream reader yields every record of every complete
chunk and then stops at the torn one (DESIGN.md §7), which is all a killed writer leaves.
"""
from __future__ import annotations

import json
import os
import shutil
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from soil_msgs_py import messages as M
from mcap.records import Channel, Footer, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter
from rosbags.interfaces import Qos
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.rosbag2.metadata import dump_qos_v9, parse_qos
import yaml

from soil_msgs_py import messages as M
from .bag_io import META_KEY, PARTIAL_SUFFIX

JOURNAL_METADATA_NAME = "insitu_soil"  # name of the MCAP Metadata record written first
RECORDER_INFO_KEY = "insitu_soil.recorder"
REPAIR_INFO_KEY = "insitu_soil.repair"
_CHUNK_SIZE = 1 << 20  # chunks close at 1 MiB or at the next flush(), whichever comes first


def partial_dir(out_dir: Path, name: str) -> Path:
    return Path(out_dir) / f"{name}{PARTIAL_SUFFIX}"


def journal_path(partial: Path) -> Path:
    """``<name>.partial/<name>.mcap``."""
    return partial / (partial.name[: -len(PARTIAL_SUFFIX)] + ".mcap")


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

    def write(self, topic: str, log_time_ns: int, raw: bytes, publish_time_ns: int = 0) -> None:
        self._mcap.add_message(self._channels[topic], log_time_ns, raw, publish_time_ns or log_time_ns)

    def flush(self) -> None:
        """Close the chunk in progress and push it to the OS: it now survives a SIGKILL."""
        if not self.closed:
            self._mcap.flush()

    def close(self) -> None:
        """Write the summary and footer (a finished journal); idempotent."""
        if self.closed:
            return
        self.closed = True
        try:
            self._mcap.finish()
        finally:
            self._file.close()


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
    complete: bool = False  # the footer was reached: the writer closed the journal
    stop: str = ""  # why reading stopped before the footer ("" if complete)

    @property
    def messages(self) -> int:
        return sum(len(v) for v in self.stamps.values())


def _records(path: Path, scan: JournalScan) -> Iterator[object]:
    """Every readable record; on a torn/corrupt tail, note where and why in ``scan.stop``."""
    with open(path, "rb") as f:
        reader = StreamReader(f, skip_magic=False, validate_crcs=True)
        try:
            for record in reader.records:
                if isinstance(record, Footer):
                    scan.complete = True
                yield record
        except Exception as err:  # noqa: BLE001 - a torn tail is expected, whatever the parser says
            # EndOfFile (an McapError) is the normal end of a killed writer's journal; a corrupt
            # chunk (CRC, zstd) also ends the readable part.
            scan.stop = f"stopped at byte {f.tell()} of {path.stat().st_size}: {type(err).__name__} {err}".strip()


def scan_journal(path: Path) -> JournalScan:
    scan = JournalScan(Path(path))
    schemas: dict[int, Schema] = {}
    for record in _records(scan.path, scan):
        if isinstance(record, Metadata):
            scan.metadata.update(record.metadata)
        elif isinstance(record, Schema):
            schemas[record.id] = record
        elif isinstance(record, Channel) and record.id not in scan.channels:
            schema = schemas.get(record.schema_id)
            if schema is None:
                raise ValueError(f"{path}: channel {record.topic!r} refers to missing schema id {record.schema_id}")
            scan.channels[record.id] = JournalChannel(
                topic=record.topic, msgtype=schema.name, msgdef=schema.data.decode(),
                rihs01=record.metadata.get("topic_type_hash") or M.TYPESTORE.hash_rihs01(schema.name),
                qos=parse_qos(record.metadata.get("offered_qos_profiles", "")),
            )
            scan.stamps.setdefault(record.topic, [])
        elif isinstance(record, Message):
            scan.stamps[scan.channels[record.channel_id].topic].append(record.log_time)
    return scan


def whole_tick_cutoff(stamps: Mapping[str, Sequence[int]]) -> int | None:
    """Highest stamp at which every topic (with any message) has a message, else None.

    Messages after it belong to trailing ticks that were cut short (recorder stopped or
    killed mid-tick); dropping them leaves a bag ``bag_io.read_episode`` can read. Gaps in
    the middle are not touched. Topics with no message at all do not count (a topic nobody
    published must not wipe the bag).
    """
    sets = [set(v) for v in stamps.values() if len(v)]
    if not sets:
        return None
    for s in sorted(set().union(*sets), reverse=True):
        if all(s in x for x in sets):
            return s
    return None


# --- conversion --------------------------------------------------------------------------

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

    def summary(self) -> str:
        counts = set(self.messages.values())
        per_topic = (
            f"{counts.pop()} on each of {len(self.messages)} topics" if len(counts) == 1
            else " ".join(f"{t}={n}" for t, n in self.messages.items())
        )
        return (f"{self.path}: {self.ticks} ticks, {sum(self.messages.values())} messages "
                f"({per_topic}), {self.dropped} dropped")


def journal_to_bag(
    partial: Path, *, trim_partial_ticks: bool = True, info_key: str = RECORDER_INFO_KEY,
    info: Mapping | None = None,
) -> BagResult:
    """Convert the journal in ``partial`` (a ``<name>.partial`` directory) to the bag ``<name>/``.

    The bag is written inside ``partial`` and renamed into place, then ``partial`` is removed,
    so a bag directory is either complete or absent. If ``<name>/`` already exists the bag is
    named ``<name>_2`` etc. Episode metadata found in the journal goes to custom_data
    ``META_KEY``; ``info`` plus the conversion counts go to custom_data ``info_key``. For
    episode journals ``trim_partial_ticks`` drops trailing ticks not present on every topic.
    Raises NothingRecoverable (journal kept) if no message would be written.
    """
    partial = Path(partial)
    if not partial.name.endswith(PARTIAL_SUFFIX):
        raise ValueError(f"{partial} is not a journal directory (name must end in {PARTIAL_SUFFIX})")
    jpath = journal_path(partial)
    if not jpath.is_file():
        raise NothingRecoverable(f"{partial}: no journal file {jpath.name} (not left by soil_bag_record?)")
    scan = scan_journal(jpath)
    if scan.messages == 0:
        why = f" ({scan.stop})" if scan.stop else ""
        raise NothingRecoverable(f"{jpath}: no complete chunk with a message{why}")
    meta_json = scan.metadata.get(META_KEY)
    cutoff = None
    if trim_partial_ticks and meta_json is not None:
        # Whole ticks are judged on the episode topics; extra topics (--topics) keep what is
        # stamped up to the last whole tick.
        tick_topics = {t: v for t, v in scan.stamps.items() if t in M.FIELDS} or scan.stamps
        cutoff = whole_tick_cutoff(tick_topics)
        if cutoff is None:
            raise NothingRecoverable(
                f"{jpath}: {scan.messages} messages recovered but no tick has a message on every topic "
                f"(use --keep-partial-ticks to keep them)"
            )
    keep = (lambda t: True) if cutoff is None else (lambda t: t <= cutoff)
    written = {ch.topic: sum(1 for t in scan.stamps[ch.topic] if keep(t)) for ch in scan.channels.values()}
    kept = [t for v in scan.stamps.values() for t in v if keep(t)]
    result = BagResult(
        path=partial.parent / partial.name[: -len(PARTIAL_SUFFIX)], ticks=len(set(kept)),
        messages={t: n for t, n in written.items()}, recovered=scan.messages,
        dropped=scan.messages - len(kept), last_stamp_ns=max(kept), journal_complete=scan.complete,
        stop=scan.stop,
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
                   messages=result.messages, journal_complete=scan.complete)
    if scan.stop:
        details["journal_stop"] = scan.stop
    with Writer(staging, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        if meta_json is not None:
            writer.set_custom_data(META_KEY, meta_json)
        writer.set_custom_data(info_key, json.dumps(details, sort_keys=True))
        conns = {
            cid: writer.add_connection(ch.topic, ch.msgtype, msgdef=ch.msgdef, rihs01=ch.rihs01,
                                       offered_qos_profiles=ch.qos)
            for cid, ch in scan.channels.items()
        }
        for record in _records(jpath, JournalScan(jpath)):
            if isinstance(record, Message) and keep(record.log_time):
                writer.write(conns[record.channel_id], record.log_time, record.data)
    os.replace(staging, result.path)
    shutil.rmtree(partial)
    return result
