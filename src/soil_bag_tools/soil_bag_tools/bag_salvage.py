"""A repaired copy of a finished bag whose chunks fail their CRC (``soil_bag_repair BAG``).

Every chunk that passes its CRC is copied into a new bag (``bag_writer.BagWriter``, same
topics, types, offered QoS, type hashes and custom_data); the chunks that fail are dropped
and reported (``integrity.ChunkInfo.describe``). A file cut short (a copy or a disk that
stopped) ends inside a chunk; of an uncompressed one (this project's bags) the records
written whole are kept and the chunk is reported as torn: what it still held is not lost. Schemas and channels come from the chunks
that pass and from the file's summary, which repeats them, so a bad first chunk does not
orphan the rest. Episode bags keep only ticks present on every episode topic (a tick split
across a dropped chunk's boundary is incomplete), so ``bag_io.read_episode`` can read the
copy; the episode then has a gap in its stamps where the dropped chunks were. The original
is never touched.

A bag whose metadata.yaml is missing or unreadable (deleted, garbled, or cut short: parsing, but
lacking a key rosbag2 requires, ``bag_io.metadata_problem``) while its one .mcap is
whole is copied the same way, its metadata taken from the file's own record of it (the
``rosbag2`` Metadata record rosbag2 and this project's writer put in every bag): no reader takes
the bag without it, and what was recorded is all there.
"""
from __future__ import annotations

import json
import os
import shutil
from collections import defaultdict
from pathlib import Path

from mcap.records import Channel, Message, Schema
from rosbags.rosbag2.metadata import parse_qos

from soil_msgs_py import messages as M
from .bag_io import META_KEY, PARTIAL_SUFFIX, MetadataUnreadable, bag_info, metadata_problem
from .bag_writer import BagWriter
from .integrity import McapScan, read_records
from .journal import REPAIR_INFO_KEY, BagResult, NothingRecoverable, chunk_details, stamps_in_every_topic


def embedded_metadata(mcap: Path) -> str | None:
    """The metadata.yaml text a bag's .mcap keeps in its last ``rosbag2`` Metadata record, or None (a
    file of another writer, or one cut short before its end, where the record is written). The last:
    rosbag2 writes one as it opens the bag (no messages counted) and the whole one as it closes it."""
    from mcap.reader import make_reader

    found = None
    try:
        with open(mcap, "rb") as f:
            for record in make_reader(f).iter_metadata():
                if record.name == "rosbag2" and "serialized_metadata" in record.metadata:
                    found = record.metadata["serialized_metadata"]
    except Exception:  # noqa: BLE001 - any damage means there is no record to trust
        return None
    return found


def embedded_info(bag: Path, problem: str) -> tuple[dict, Path]:
    """(``rosbag2_bagfile_information``, the .mcap) of a bag directory whose metadata.yaml is
    missing or unreadable (``problem``), from its one .mcap's own record; NothingRecoverable if
    there is none to take."""
    import yaml

    mcaps = sorted(p for p in bag.glob("*.mcap") if p.is_file())
    if len(mcaps) != 1:
        raise NothingRecoverable(f"{bag}: {problem}, and it holds {len(mcaps)} .mcap files, not one whose own "
                                 "record of its metadata could stand in")
    text = embedded_metadata(mcaps[0])
    try:
        data = yaml.safe_load(text) if text is not None else None
    except yaml.YAMLError:
        data = None
    # (rosbag2 keeps the inner mapping of metadata.yaml there, without its rosbag2_bagfile_information key)
    info = data.get("rosbag2_bagfile_information", data) if isinstance(data, dict) else None
    if not isinstance(info, dict) or metadata_problem(info):  # (the test a metadata.yaml passes)
        raise NothingRecoverable(f"{bag}: {problem}, and {mcaps[0].name} carries no rosbag2 metadata record (a file of "
                                 "another writer, or cut short before its end): nothing to rebuild it from")
    return dict(info), mcaps[0]


def salvage_bag(bag: Path, out: Path, *, keep_partial_ticks: bool = False) -> BagResult:
    """Write the chunks of ``bag`` that pass their CRC as the new bag ``out``.

    NothingRecoverable if ``bag`` is not a bag, carries no CRCs (damage cannot be located),
    is undamaged with its metadata.yaml, or no message survives; FileExistsError if ``out`` exists."""
    bag, out = Path(bag), Path(out)
    if not bag.is_dir() or bag.name.endswith(PARTIAL_SUFFIX):
        raise NothingRecoverable(f"{bag} is not a finished rosbag2 bag directory")
    if out.exists():
        raise FileExistsError(f"--out {out} exists; the repaired copy never replaces anything")
    rebuilt = ""  # why metadata.yaml is taken from the .mcap's own record ("": it was read)
    try:
        info = bag_info(bag)
    except MetadataUnreadable as err:  # missing, unparsable, or lacking what a reader needs (cut short)
        info, mcap = embedded_info(bag, err.reason)
        rebuilt = err.reason
    else:
        files = [str(f) for f in info.get("relative_file_paths") or []]
        if len(files) != 1 or not files[0].endswith(".mcap"):
            raise NothingRecoverable(f"{bag}: expected one .mcap file in metadata.yaml, found {files}")
        mcap = bag / files[0]
        if not mcap.is_file():  # (renamed or moved: as every reader says it)
            raise NothingRecoverable(f"{bag}: metadata.yaml lists {files[0]}, which does not exist")
    scan = McapScan(mcap)
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    messages: list[Message] = []
    for record in read_records(mcap, scan, torn_tail=True):
        if isinstance(record, Schema):
            schemas.setdefault(record.id, record)
        elif isinstance(record, Channel):
            channels.setdefault(record.id, record)
        elif isinstance(record, Message):
            messages.append(record)
    if not (scan.chunks or scan.torn):  # (cut inside a compressed first chunk, or before any)
        raise NothingRecoverable(f"{bag}: holds no complete chunk"
                                 + (f" ({scan.stop})" if scan.stop else "") + "; nothing to recover")
    # (a file without CRCs, whole, that only lost its metadata.yaml is copied as it was written)
    if not scan.has_crcs and (scan.stop or scan.bad or scan.data_problem or not rebuilt):
        what = f"is {'truncated or unreadable (' + scan.stop + ')' if scan.stop else 'damaged'}, and "
        raise NothingRecoverable(f"{bag}: {what if (scan.stop or scan.bad or scan.data_problem) else ''}carries no chunk "
                                 "CRCs (written by another tool, or by this project before it computed them), so its "
                                 "damaged chunks cannot be told from good ones: nothing is salvaged")
    if not (scan.bad or scan.stop or scan.data_problem or rebuilt):
        raise NothingRecoverable(f"{bag}: all {len(scan.chunks)} chunks pass their CRC; nothing to repair")

    usable = {cid: ch for cid, ch in channels.items() if ch.schema_id in schemas}
    kept_msgs = [m for m in messages if m.channel_id in usable]
    orphans = len(messages) - len(kept_msgs)
    custom = dict(info.get("custom_data") or {})
    if META_KEY in custom and not keep_partial_ticks:
        stamps: dict[str, list[int]] = defaultdict(list)
        for m in kept_msgs:
            stamps[usable[m.channel_id].topic].append(m.log_time)
        ticks = stamps_in_every_topic({t: v for t, v in stamps.items() if t in M.FIELDS})
        kept_msgs = [m for m in kept_msgs if usable[m.channel_id].topic not in M.FIELDS or m.log_time in ticks]
    if not kept_msgs:
        lines = "; ".join(c.describe(scan.topics) for c in scan.bad) or scan.stop or scan.data_problem
        raise NothingRecoverable(f"{bag}: no message survives ({lines})")

    counts: dict[str, int] = defaultdict(int)
    for m in kept_msgs:
        counts[usable[m.channel_id].topic] += 1
    result = BagResult(
        path=out, ticks=len({m.log_time for m in kept_msgs}), messages=dict(counts),
        recovered=len(messages), dropped=len(messages) - len(kept_msgs) - orphans,
        last_stamp_ns=max(m.log_time for m in kept_msgs), journal_complete=scan.complete, stop=scan.stop,
        dropped_chunks=[c.describe(scan.topics) for c in scan.bad], orphans=orphans,
        torn_chunk=scan.torn.describe(scan.topics) if scan.torn else "", metadata_from_mcap=rebuilt,
    )
    details = {"source_bag": str(bag), "keep_partial_ticks": keep_partial_ticks,
               "dropped_chunks": chunk_details(scan.bad, scan.topics), "orphaned_messages": orphans,
               "torn_chunk": chunk_details([scan.torn], scan.topics)[0] if scan.torn else None,
               "recovered_messages": result.recovered, "written_messages": len(kept_msgs),
               "dropped_messages": result.dropped, "ticks": result.ticks, "messages": result.messages}
    for key, text in (("stop", scan.stop), ("data_problem", scan.data_problem), ("metadata_from_mcap", rebuilt)):
        if text:
            details[key] = text
    custom[REPAIR_INFO_KEY] = json.dumps(details, sort_keys=True)

    # Topic entries of metadata.yaml: the offered QoS and type hash rosbag2 recorded.
    topic_meta = {t["topic_metadata"]["name"]: t["topic_metadata"] for t in info.get("topics_with_message_count") or []}
    staging = out.with_name(out.name + PARTIAL_SUFFIX)
    shutil.rmtree(staging, ignore_errors=True)
    staging.mkdir(parents=True)
    try:
        with BagWriter(staging / out.name) as writer:
            for key, value in custom.items():
                writer.set_custom_data(key, value)
            conns = {}
            for cid, ch in sorted(usable.items()):
                schema, meta = schemas[ch.schema_id], topic_meta.get(ch.topic, {})
                conns[cid] = writer.add_connection(
                    ch.topic, schema.name, msgdef=schema.data.decode(), serialization_format=ch.message_encoding,
                    rihs01=ch.metadata.get("topic_type_hash") or meta.get("type_description_hash")
                    or M.TYPESTORE.hash_rihs01(schema.name),
                    offered_qos_profiles=parse_qos(meta.get("offered_qos_profiles") or ch.metadata.get("offered_qos_profiles", "")),
                )
            for m in kept_msgs:
                writer.write(conns[m.channel_id], m.log_time, m.data)
        os.replace(staging / out.name, out)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return result
