"""Which chunks of an MCAP file pass their CRC, which do not, and what the bad ones held.

An MCAP chunk stores the CRC-32 of its (uncompressed) records; the DataEnd record the CRC of
the whole data section and the Footer that of the summary (0 everywhere means "not
computed", as in bags written before ``bag_writer.py``). :func:`read_records` walks a file
once with the ``mcap`` library's stream reader, checks every chunk itself instead of letting
the library stop at the first bad one, and notes each chunk's place (index, byte offset, log
time range) and its message counts per channel (from the message index records that follow
it, outside the chunk), so a reader can name the damage and a repair can skip exactly the
bad chunks and say what they held. A file cut inside an uncompressed chunk (a copy or a disk
that stopped short) still holds that chunk's first records whole; ``torn_tail`` reads them too,
unchecked, since the CRC covers records the file no longer has.
"""
from __future__ import annotations

import io
import struct
import zlib
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path

from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, DataEnd, Footer, McapRecord, Message
from mcap.stream_reader import CRCValidationError, StreamReader, breakup_chunk, get_chunk_data_stream

_CHUNK_FIXED_BYTES = 1 + 8 + 8 + 8 + 8 + 4 + 4 + 8  # opcode, length, times, size, crc, string len, data len
_CHUNK_HEAD_BYTES = 1 + 8 + 8 + 8 + 8 + 4 + 4  # opcode, length, times, size, crc, compression's length
_FOOTER_BYTES = 1 + 8 + 8 + 8 + 4  # opcode, length, summary_start, summary_offset_start, summary_crc


@dataclass
class IndexCount:
    """A message index record reduced to what a scan reports: its channel and entry count."""

    channel_id: int
    count: int


class _CountingReader(StreamReader):
    """The ``mcap`` stream reader, but a message index's entries are counted, not parsed into a
    tuple per message (that parsing was 80 % of a scan's time)."""

    def _read_record(self, opcode: int, length: int):
        if opcode == Opcode.MESSAGE_INDEX:
            channel_id = self._stream.read2()
            size = self._stream.read4()
            self._stream.read(size)
            return IndexCount(channel_id, size // 16)  # entries: (log_time u64, offset u64)
        return super()._read_record(opcode, length)


@dataclass
class ChunkInfo:
    index: int  # 0-based, file order
    offset: int  # byte offset of the Chunk record in the file
    start_ns: int  # log time range of its messages, as its header says
    end_ns: int
    crc: int  # stored CRC-32 of its records; 0: not computed
    problem: str = ""  # why it was skipped; "" if it passed
    messages: dict[int, int] = field(default_factory=dict)  # per channel id, from its message index

    def describe(self, topics: Mapping[int, str]) -> str:
        """One line naming the chunk, what it held and (if bad) what is wrong with it."""
        names = sorted(topics.get(c, f"channel {c}") for c in self.messages)
        held = f"{sum(self.messages.values())} messages on {', '.join(names)}" if names else "messages unknown"
        text = f"chunk {self.index} at byte {self.offset} (log time {self.start_ns}..{self.end_ns} ns, {held})"
        return f"{text}: {self.problem}" if self.problem else text


@dataclass
class McapScan:
    """What :func:`read_records` learnt about one file."""

    path: Path
    chunks: list[ChunkInfo] = field(default_factory=list)
    topics: dict[int, str] = field(default_factory=dict)  # channel id -> topic (chunks and summary)
    data_problem: str = ""  # data-section / summary CRC mismatch
    stop: str = ""  # why reading stopped before the footer ("" if it was reached)
    complete: bool = False  # the footer was reached: the writer finished the file
    # the chunk the file ends inside, when its complete records were read (``torn_tail``); its
    # ``messages`` count those records per channel, its ``problem`` says what was left out
    torn: ChunkInfo | None = None

    @property
    def bad(self) -> list[ChunkInfo]:
        return [c for c in self.chunks if c.problem]

    @property
    def has_crcs(self) -> bool:
        """Whether the writer computed chunk CRCs (all 0: a bag from before CRCs were written)."""
        return any(c.crc for c in self.chunks) or bool(self.torn and self.torn.crc)


def _crc_of_range(path: Path, start: int, stop: int) -> int:
    crc = 0
    with open(path, "rb") as f:
        f.seek(start)
        left = stop - start
        while left > 0 and (block := f.read(min(left, 1 << 20))):
            crc = zlib.crc32(block, crc)
            left -= len(block)
    return crc


def _check_chunk(chunk: Chunk, info: ChunkInfo, open_chunk: bool) -> list[McapRecord]:
    """The chunk's records (none unless ``open_chunk``); a CRC or decoding failure goes to
    ``info.problem``."""
    try:
        if open_chunk:
            return breakup_chunk(chunk, validate_crc=True)
        get_chunk_data_stream(chunk, validate_crc=True)
    except CRCValidationError as err:
        info.problem = (f"CRC mismatch: stored 0x{err.expected:08x}, computed 0x{err.actual:08x} "
                        f"over its {chunk.uncompressed_size} bytes of records")
    except Exception as err:  # noqa: BLE001 - whatever a damaged chunk makes the decoder raise
        info.problem = f"records do not decode ({type(err).__name__}: {err})"
    return []


def _torn_chunk(path: Path, offset: int, index: int) -> tuple[ChunkInfo, list[McapRecord]] | None:
    """The complete records of the chunk that starts at ``offset`` and that the file ends inside,
    if it is uncompressed (a compressed stream cut short is not read) and holds a whole message,
    else None."""
    left = Path(path).stat().st_size - offset
    with open(path, "rb") as f:
        f.seek(offset)
        head = f.read(_CHUNK_HEAD_BYTES)
        if len(head) < _CHUNK_HEAD_BYTES or head[0] != Opcode.CHUNK:
            return None
        start_ns, end_ns, size, crc, name_len = struct.unpack_from("<QQQII", head, 9)
        if name_len:  # compressed (or a header the cut left unreadable)
            return None
        length = f.read(8)
        if len(length) < 8:
            return None
        (records_len,) = struct.unpack("<Q", length)
        if records_len != size:  # an uncompressed chunk's two lengths agree: else a damaged header, not a cut
            return None
        data = f.read(min(records_len, max(left, 0)))  # (never more than the file holds)
    info = ChunkInfo(index, offset, start_ns, end_ns, crc)
    if len(data) >= records_len:  # whole, yet unread: not a cut this can read past
        return None
    records: list[McapRecord] = []
    reader = StreamReader(io.BytesIO(data), skip_magic=True)
    try:
        for record in reader.records:
            records.append(record)
    except Exception:  # noqa: BLE001 - the record the cut went through, whatever the parser says
        pass
    used = sum(1 for r in records if isinstance(r, Message))
    if not used:  # (schemas and channels alone: no message to keep)
        return None
    for r in records:
        if isinstance(r, Message):
            info.messages[r.channel_id] = info.messages.get(r.channel_id, 0) + 1
    info.problem = (f"the file ends inside it ({len(data)} of its {records_len} bytes of records): its first "
                    f"{used} messages read whole, not checked by its CRC")
    return info, records


def read_records(path: Path, scan: McapScan, *, open_chunks: bool = True, torn_tail: bool = False) -> Iterator[McapRecord]:
    """Every record of ``path`` in file order, each good chunk replaced by its records (if
    ``open_chunks``); a chunk failing its CRC is skipped and noted in ``scan.chunks``, a torn
    or unparseable tail ends the iteration (noted in ``scan.stop``). ``torn_tail``: where the
    file ends inside an uncompressed chunk, that chunk's complete records end it (``scan.torn``)."""
    path = Path(path)
    last_end = 0  # where the last whole top-level record ended
    at_end = False  # reading stopped because the file ended
    with open(path, "rb") as f:
        reader = _CountingReader(f, emit_chunks=True)
        try:
            for record in reader.records:
                last_end = f.tell()
                if isinstance(record, Chunk):
                    size = _CHUNK_FIXED_BYTES + len(record.compression.encode()) + len(record.data)
                    info = ChunkInfo(len(scan.chunks), f.tell() - size, record.message_start_time,
                                     record.message_end_time, record.uncompressed_crc)
                    scan.chunks.append(info)
                    for inner in _check_chunk(record, info, open_chunks):
                        if isinstance(inner, Channel):
                            scan.topics[inner.id] = inner.topic
                        yield inner
                    continue
                if isinstance(record, IndexCount) and scan.chunks:  # follows its chunk
                    scan.chunks[-1].messages[record.channel_id] = record.count
                elif isinstance(record, Channel):
                    scan.topics.setdefault(record.id, record.topic)
                elif isinstance(record, DataEnd) and record.data_section_crc:
                    actual = _crc_of_range(path, 0, f.tell() - (1 + 8 + 4))
                    if actual != record.data_section_crc:
                        scan.data_problem = (f"data section CRC mismatch: stored 0x{record.data_section_crc:08x}, "
                                             f"computed 0x{actual:08x}")
                elif isinstance(record, Footer):
                    scan.complete = True
                    if record.summary_start and record.summary_crc and not scan.data_problem:
                        end = f.tell() - _FOOTER_BYTES + (1 + 8 + 8 + 8)
                        actual = _crc_of_range(path, record.summary_start, end)
                        if actual != record.summary_crc:
                            scan.data_problem = (f"summary CRC mismatch: stored 0x{record.summary_crc:08x}, "
                                                 f"computed 0x{actual:08x}")
                yield record
        except Exception as err:  # noqa: BLE001 - a torn tail is expected, whatever the parser says
            size = path.stat().st_size
            at_end = f.tell() >= size
            what = ("the file ends there, where a record should follow" if at_end and last_end >= size else
                    f"the file ends inside the record that starts there, {size - last_end} bytes of it written"
                    if at_end else f"the record there does not parse ({type(err).__name__}{f': {err}' if str(err) else ''})")
            scan.stop = f"its whole records end at byte {last_end} of {size}: {what}"
    if scan.stop and torn_tail and at_end and (torn := _torn_chunk(path, last_end, len(scan.chunks))):
        scan.torn, records = torn
        for inner in records:
            if isinstance(inner, Channel):
                scan.topics[inner.id] = inner.topic
            yield inner


def scan_file(path: Path) -> McapScan:
    """Check every chunk (and the data-section/summary CRCs) of ``path`` without decoding messages
    (a torn uncompressed chunk at its end is read, to tell what a repair keeps of it)."""
    scan = McapScan(Path(path))
    for _ in read_records(scan.path, scan, open_chunks=False, torn_tail=True):
        pass
    return scan
