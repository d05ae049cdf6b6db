"""Bags carry their integrity: CRCs, offered QoS and type hashes; damage is named, repaired, never trained on.

The files are checked with independent readers (the ``mcap`` library with CRC validation,
pyyaml, rosbags); damage is bytes flipped inside one chunk's records, located through the
file's own chunk index; the CLIs run as real subprocesses (helpers from test_corrupt_bags).
"""
from __future__ import annotations

import json
import logging
import shutil
import zlib
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap.records import Chunk, DataEnd, Footer, MessageIndex
from mcap.stream_reader import StreamReader
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.rosbag2.metadata import parse_qos

from soil_bag_tools import bag_io, bag_writer, journal, playback
from soil_bag_tools.bag_salvage import salvage_bag
from soil_msgs_py.graph import publisher_qos_spec
from soil_msgs_py.messages import TYPESTORE
from soil_msgs_py.topics import BLADE_CMD, EPISODE_TOPICS
from tests.soil_bag_tools.test_bag_tools import _journal_from_sample, assert_same_episode
from tests.soil_bag_tools.test_corrupt_bags import (
    CLAY, LOAM, SAMPLES, TINY_MODEL, assert_refused, copy_bag, mcap_of, run,
)

pytestmark = pytest.mark.timeout(300)
TICKS = 600  # the sample episodes
CHUNK_RECORDS_AT = 9 + 8 + 8 + 8 + 4 + 4  # opcode, length, start/end time, size, crc, compression length


def flip_chunk(mcap: Path, k: int, n: int = 16):
    """Invert ``n`` bytes in the middle of chunk ``k``'s records; returns its ChunkIndex."""
    with open(mcap, "rb") as f:
        idx = make_reader(f).get_summary().chunk_indexes[k]
    data = bytearray(mcap.read_bytes())
    mid = idx.chunk_start_offset + CHUNK_RECORDS_AT + len(idx.compression) + 8 + idx.compressed_size // 2
    data[mid:mid + n] = bytes(b ^ 0xFF for b in data[mid:mid + n])
    mcap.write_bytes(bytes(data))
    return idx


def indexed_messages(mcap: Path, k: int) -> int:
    """Messages chunk ``k`` holds, per the message index records that follow it."""
    n, chunk = 0, -1
    with open(mcap, "rb") as f:
        for r in StreamReader(f, emit_chunks=True).records:
            chunk += isinstance(r, Chunk)
            n += len(r.records) if isinstance(r, MessageIndex) and chunk == k else 0
    return n


@pytest.fixture(scope="module")
def episode():
    return bag_io.read_episode(LOAM)


@pytest.fixture
def fresh(tmp_path, episode) -> Path:
    return bag_io.write_episode(tmp_path / LOAM.name, episode)


# ------------------------------------------------------------------------------ writing
def test_fresh_bag_has_crcs_that_validate_and_is_deterministic(fresh, episode, tmp_path):
    mcap = mcap_of(fresh)
    with open(mcap, "rb") as f:
        records = list(StreamReader(f, emit_chunks=True, validate_crcs=True).records)  # raises on a bad data CRC
    chunks = [r for r in records if isinstance(r, Chunk)]
    assert len(chunks) > 5  # small chunks: damage costs a second of an episode, not all of it
    for c in chunks:
        assert c.uncompressed_crc != 0 and c.uncompressed_crc == zlib.crc32(c.data)
    (data_end,) = [r for r in records if isinstance(r, DataEnd)]
    (footer,) = [r for r in records if isinstance(r, Footer)]
    assert data_end.data_section_crc != 0 and footer.summary_crc != 0
    with open(mcap, "rb") as f:
        assert sum(1 for _ in make_reader(f, validate_crcs=True).iter_messages()) == TICKS * len(EPISODE_TOPICS)
    again = bag_io.write_episode(tmp_path / "again" / LOAM.name, episode)
    for name in (mcap.name, "metadata.yaml"):
        assert (again / name).read_bytes() == (fresh / name).read_bytes(), name
    assert_same_episode(bag_io.read_episode(fresh), episode)


def test_qos_and_type_hash_per_topic_in_metadata_and_channels(fresh):
    info = yaml.safe_load((fresh / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["version"] == 9
    entries = {t["topic_metadata"]["name"]: t["topic_metadata"] for t in info["topics_with_message_count"]}
    assert set(entries) == {t.name for t in EPISODE_TOPICS}
    for t in EPISODE_TOPICS:
        spec = publisher_qos_spec(t.name)
        (qos,) = entries[t.name]["offered_qos_profiles"]  # v9: a list of profiles, not a YAML string
        assert (qos["history"], qos["depth"], qos["reliability"], qos["durability"]) == \
            ("keep_last", spec.depth, spec.reliability, spec.durability)
        assert entries[t.name]["type_description_hash"] == TYPESTORE.hash_rihs01(t.msgtype)
    with AnyReader([fresh]) as reader:
        for c in reader.connections:
            assert c.ext.offered_qos_profiles == bag_writer.offered_qos(c.topic), c.topic
            assert c.digest == TYPESTORE.hash_rihs01(c.msgtype)
    with open(mcap_of(fresh), "rb") as f:
        channels = make_reader(f).get_summary().channels.values()
    for ch in channels:
        assert ch.metadata["topic_type_hash"] == entries[ch.topic]["type_description_hash"]
        assert parse_qos(ch.metadata["offered_qos_profiles"]) == bag_writer.offered_qos(ch.topic)


# ------------------------------------------------------------------------------ reading
def test_flipped_chunk_bytes_are_named_by_every_reader(fresh):
    idx = flip_chunk(mcap_of(fresh), 3)
    for read in (bag_io.read_episode, playback.load_bag,
                 lambda b: bag_io.read_labelled_topic(b, BLADE_CMD.name, ("u_zr", "u_za"))):
        with pytest.raises(bag_io.BagReadError) as err:
            read(fresh)
        text = str(err.value)
        assert err.value.bag == str(fresh)
        assert f"chunk 3 at byte {idx.chunk_start_offset}" in text, text
        assert f"log time {idx.message_start_time}..{idx.message_end_time} ns" in text, text
        assert "CRC mismatch: stored 0x" in text and "computed 0x" in text, text


def test_damage_outside_the_chunks_is_caught_by_the_data_section_crc(fresh):
    """A message index (between chunks, not covered by a chunk CRC) with a flipped byte."""
    mcap = mcap_of(fresh)
    with open(mcap, "rb") as f:
        idx = make_reader(f).get_summary().chunk_indexes[1]
    where = min(idx.message_index_offsets.values()) + 9 + 2 + 4 + 3  # inside its first entry's time
    data = bytearray(mcap.read_bytes())
    data[where] ^= 0x01
    mcap.write_bytes(bytes(data))
    with open(mcap, "rb") as f:  # the message index still parses: only the CRC can tell
        assert any(isinstance(r, MessageIndex) for r in StreamReader(f, emit_chunks=True).records)
    with pytest.raises(bag_io.BagReadError, match="data section CRC mismatch.*outside the chunks"):
        bag_io.read_episode(fresh)


@pytest.fixture
def old(tmp_path, episode, monkeypatch) -> Path:
    """The episode as bags were written before bag_writer.py: rosbags' own Writer, every CRC 0."""
    monkeypatch.setattr(bag_io, "BagWriter",
                        lambda path: Writer(path, version=9, storage_plugin=StoragePlugin.MCAP))
    bag = bag_io.write_episode(tmp_path / "old", episode)
    monkeypatch.undo()
    return bag


def test_bag_without_crcs_reads_and_says_so(old, caplog, episode):
    with caplog.at_level(logging.WARNING, logger="soil_bag_tools.bag_io"):
        assert_same_episode(bag_io.read_episode(old), episode)
        bag_io.read_episode(old)
    said = [r.getMessage() for r in caplog.records if "without chunk CRCs" in r.getMessage()]
    assert len(said) == 1 and str(old) in said[0]  # once per bag and process


# ------------------------------------------------------------------------------ training
@pytest.fixture(scope="module")
def crc_dirs(tmp_path_factory):
    """The three samples rewritten with CRCs plus two loam copies (one episode under three names,
    kept in one split), and the same with a clay copy whose chunk 5 has flipped bytes."""
    base = tmp_path_factory.mktemp("crc_bags")
    good = base / "good"
    for src in sorted(SAMPLES.iterdir()):
        bag_io.write_episode(good / src.name, bag_io.read_episode(src))
    for i in (1, 2):
        copy_bag(good / LOAM.name, good / f"{LOAM.name}_copy{i}")
    with_bad = base / "with_bad"
    copy_bag(good, with_bad)
    bad = copy_bag(good / CLAY.name, with_bad / f"{CLAY.name}_flipped")
    flip_chunk(mcap_of(bad), 5)
    return {"with_bad": with_bad, "bad": bad, "base": base}


def test_pinn_train_refuses_a_bag_failing_its_crc_and_skips_it_on_request(crc_dirs, tmp_path):
    common = ["--data", crc_dirs["with_bad"], "--quiet", "--no-cache", "--workers", "2", *TINY_MODEL]
    out = run("pinn_train", *common, "--out", tmp_path / "a.pt")
    assert_refused(out, crc_dirs["bad"])
    assert "chunk 5 at byte" in out.stderr and "CRC mismatch" in out.stderr, out.stderr
    assert not (tmp_path / "a.pt").exists()
    out = run("pinn_train", *common, "--out", tmp_path / "b.pt", "--skip-bad-bags")
    assert out.returncode == 0, out.stdout + out.stderr
    assert "skipped 1 " in out.stderr and str(crc_dirs["bad"]) in out.stderr
    assert (tmp_path / "b.pt").is_file()


# ------------------------------------------------------------------------------ repair
@pytest.mark.parametrize("k", [0, 4])  # chunk 0 also holds the schemas and channels
def test_repair_copies_the_good_chunks_of_a_damaged_bag(fresh, episode, k):
    idx = flip_chunk(mcap_of(fresh), k)
    damaged = mcap_of(fresh).read_bytes()
    out = run("soil_bag_repair", fresh, timeout=60)
    assert out.returncode == 0, out.stdout + out.stderr
    copy = fresh.with_name(fresh.name + "_repaired")
    assert f"dropped chunk {k} at byte {idx.chunk_start_offset}" in out.stdout, out.stdout
    assert f"log time {idx.message_start_time}..{idx.message_end_time} ns" in out.stdout
    assert "/blade/force" in out.stdout and "CRC mismatch" in out.stdout
    assert mcap_of(fresh).read_bytes() == damaged  # the original is never touched
    got = bag_io.read_episode(copy)  # whole ticks only, CRCs of its own
    s = episode.stamps_ns
    inside = (s > idx.message_start_time) & (s < idx.message_end_time)
    edges = (s >= idx.message_start_time) & (s <= idx.message_end_time)  # edge ticks may be split
    assert inside.sum() <= TICKS - len(got) <= edges.sum()
    keep = np.isin(s, got.stamps_ns)
    assert not keep[inside].any()
    np.testing.assert_array_equal(got.forces, episode.forces[keep])
    info = json.loads(bag_io.bag_custom_data(copy)[journal.REPAIR_INFO_KEY])
    (dropped,) = info["dropped_chunks"]
    assert dropped["chunk"] == k and dropped["byte_offset"] == idx.chunk_start_offset
    assert sum(dropped["messages"].values()) == indexed_messages(mcap_of(fresh), k)
    assert info["source_bag"] == str(fresh)


@pytest.mark.parametrize("k", [0, 2])  # chunk 0 also holds the schemas and channels
def test_repair_keeps_the_whole_records_of_the_chunk_a_cut_file_ends_inside(fresh, episode, tmp_path, k):
    """A file cut short (a copy or a disk that stopped) ends inside a chunk: the records of that
    chunk written whole are kept, every whole tick up to the cut, and the torn chunk is named."""
    with open(mcap_of(fresh), "rb") as f:
        idx = make_reader(f).get_summary().chunk_indexes[k]
    cut_at = idx.chunk_start_offset + CHUNK_RECORDS_AT + len(idx.compression) + 8 + idx.compressed_size // 2
    with open(mcap_of(fresh), "r+b") as f:
        f.truncate(cut_at)
    refused = bag_io.BagReadError
    with pytest.raises(refused, match=r"the file ends inside the record .* copies what it holds whole"):
        bag_io.read_episode(fresh)
    out = run("soil_bag_repair", fresh, "--out", tmp_path / "new", timeout=60)
    assert out.returncode == 0, out.stdout + out.stderr
    assert f"kept the whole records of chunk {k} at byte {idx.chunk_start_offset}" in out.stdout, out.stdout
    assert "not checked by its CRC" in out.stdout
    got = bag_io.read_episode(tmp_path / "new")
    s = episode.stamps_ns
    whole = s < idx.message_end_time  # the ticks up to the cut (the chunk's second half is gone)
    assert s[0] in got.stamps_ns and len(got) > (s < idx.message_start_time).sum() + 1
    assert len(got) < whole.sum()
    keep = np.isin(s, got.stamps_ns)
    assert keep[:len(got)].all()  # every tick from the start, none skipped
    np.testing.assert_array_equal(got.forces, episode.forces[keep])
    info = json.loads(bag_io.bag_custom_data(tmp_path / "new")[journal.REPAIR_INFO_KEY])
    assert info["torn_chunk"]["chunk"] == k and info["dropped_chunks"] == []
    assert "the file ends inside it" in info["torn_chunk"]["problem"]


def test_repair_cli_refuses_what_it_cannot_or_need_not_repair(fresh, old, tmp_path):
    out = run("soil_bag_repair", fresh, timeout=60)
    assert out.returncode == 1 and "all " in out.stderr and "nothing to repair" in out.stderr, out.stderr
    out = run("soil_bag_repair", old, timeout=60)
    assert out.returncode == 1 and "no chunk CRCs" in out.stderr, out.stderr
    cut = tmp_path / "cut"  # a finished bag cut inside its first chunk: truncated, not "without CRCs"
    shutil.copytree(fresh, cut)
    with open(mcap_of(cut), "r+b") as f:
        f.truncate(2000)
    out = run("soil_bag_repair", cut, timeout=60)  # its channels whole, no message yet
    assert out.returncode == 1 and "holds no complete chunk" in out.stderr and "CRC" not in out.stderr, out.stderr
    with open(mcap_of(cut), "r+b") as f:  # cut before the first chunk's header is whole
        f.truncate(40)
    out = run("soil_bag_repair", cut, timeout=60)
    assert out.returncode == 1 and "holds no complete chunk" in out.stderr and "CRC" not in out.stderr, out.stderr
    flip_chunk(mcap_of(fresh), 2)
    out = run("soil_bag_repair", fresh, "--out", old, timeout=60)  # exists: never replaced
    assert out.returncode == 2 and "exists" in out.stderr and "Traceback" not in out.stderr
    out = run("soil_bag_repair", fresh, old, "--out", tmp_path / "new", timeout=60)
    assert out.returncode == 2 and "exactly one" in out.stderr
    out = run("soil_bag_repair", fresh, "--out", fresh / "inner", timeout=60)  # where no bag search looks
    assert out.returncode == 2 and "is inside the bag" in out.stderr and not (fresh / "inner").exists(), out.stderr
    out = run("soil_bag_repair", tmp_path / "mistyped", timeout=60)  # was exit 1, "nothing recoverable"
    assert out.returncode == 2 and f"{tmp_path / 'mistyped'} does not exist" in out.stderr, out.stderr
    out = run("soil_bag_repair", fresh, "--out", tmp_path / "new", timeout=60)
    assert out.returncode == 0, out.stderr
    assert "dropped chunk 2 at byte" in out.stdout
    assert len(bag_io.read_episode(tmp_path / "new")) < TICKS


def test_repair_rebuilds_a_lost_or_garbled_metadata_yaml_from_the_mcaps_own_record(fresh, old, episode, tmp_path):
    """A bag whose metadata.yaml was deleted or garbled is read by no tool, though its .mcap holds
    every message and its own record of the metadata (an outside tester's: soil_bag_repair said
    "no *.partial journal directory inside" or "nothing repaired"). It is copied, the metadata.yaml
    rebuilt from that record; the original stays as it is."""
    for damage, given, source in (("lost", "dir", fresh), ("garbled", "mcap", fresh), ("lost_old", "dir", old)):
        bag = tmp_path / damage  # (old: a bag of before the CRCs, whole: copied as it was written)
        shutil.copytree(source, bag)
        if damage.startswith("lost"):
            (bag / "metadata.yaml").unlink()
        else:
            (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: [\n")
        with pytest.raises(bag_io.BagReadError, match="metadata.yaml"):
            bag_io.read_episode(bag)
        out = run("soil_bag_repair", mcap_of(bag) if given == "mcap" else bag, timeout=60)
        assert out.returncode == 0 and "its metadata.yaml rebuilt from the .mcap's own record" in out.stdout, \
            out.stdout + out.stderr
        copy = bag_io.read_episode(tmp_path / f"{damage}_repaired")
        assert copy.meta == episode.meta and len(copy) == TICKS
        for name in ("observations", "forces", "known", "truth", "stamps_ns"):
            assert np.array_equal(getattr(copy, name), getattr(episode, name)), name
        assert json.loads(bag_io.bag_custom_data(tmp_path / f"{damage}_repaired")[journal.REPAIR_INFO_KEY])[
            "metadata_from_mcap"].startswith("unreadable metadata.yaml")
        assert (bag / "metadata.yaml").exists() == (damage == "garbled")  # (the original untouched)
        if damage == "lost_old":
            assert "carries no chunk CRCs" not in out.stderr
    out = run("soil_bag_repair", tmp_path, timeout=60)  # a directory of bags: the ones without metadata.yaml named
    assert out.returncode == 1 and "2 bag directories without a metadata.yaml" in out.stderr, out.stderr
    assert str(tmp_path / "lost") in out.stderr and str(tmp_path / "lost_old") in out.stderr, out.stderr
    cut = tmp_path / "cut"  # no metadata.yaml, and the file cut before its end, where the record is
    shutil.copytree(fresh, cut)
    (cut / "metadata.yaml").unlink()
    with open(mcap_of(cut), "r+b") as f:
        f.truncate(mcap_of(cut).stat().st_size // 2)
    out = run("soil_bag_repair", cut, timeout=60)
    assert out.returncode == 1 and "carries no rosbag2 metadata record" in out.stderr, out.stderr
    # and the readers do not send such a bag to the repair (an outside tester's: a bag `ros2 bag record`
    # was killed in, sent to soil_bag_repair, which then found nothing to rebuild it from)
    (cut / "metadata.yaml").write_text("rosbag2_bagfile_information: [\n")
    with pytest.raises(bag_io.BagReadError) as err:
        bag_io.read_episode(cut)
    assert "soil_bag_repair" not in str(err.value) and f"`ros2 bag reindex {cut}`" in str(err.value), str(err.value)
    (cut / "metadata.yaml").unlink()
    note = bag_io.passed_by_note([mcap_of(cut)], tmp_path)
    assert "`ros2 bag reindex DIR`" in note and "soil_bag_repair" not in note, note
    assert "soil_bag_repair DIR copies it with one rebuilt" in bag_io.passed_by_note([mcap_of(fresh)], tmp_path)
    # a recordings directory holding a loose .mcap beside a killed recorder's journal is searched, as
    # before: its journal becomes a bag, the loose file is no bag to copy (an outside reviewer's)
    live = tmp_path / "live"
    live.mkdir()
    shutil.copy(mcap_of(fresh), live / "exported.mcap")
    partial, writer = _journal_from_sample(live, 3000, 500)
    writer.close()  # (a killed recorder's: flushed, not converted)
    out = run("soil_bag_repair", live / "exported.mcap", timeout=60)  # a loose file: no bag, no journal
    assert out.returncode == 1 and "neither" in out.stderr and not (tmp_path / "live_repaired").exists(), out.stderr
    out = run("soil_bag_repair", live, timeout=60)
    assert out.returncode == 0 and not (tmp_path / "live_repaired").exists(), out.stdout + out.stderr
    assert bag_io.is_bag(live / partial.name.removesuffix(bag_io.PARTIAL_SUFFIX)), sorted(live.iterdir())


def test_a_metadata_yaml_cut_short_is_garbled_named_by_the_readers_and_rebuilt(fresh, episode, tmp_path):
    """A metadata.yaml cut short (its first 3000 bytes) still parses as YAML but lacks what rosbag2
    requires (``version`` is written last): an outside tester's was refused by every reader as
    "AnyReaderError: A metadata key is missing KeyError('version')", naming neither metadata.yaml nor
    the repair, while soil_bag_repair said "all N chunks pass their CRC; nothing to repair"."""
    bag = tmp_path / "cut_yaml"
    shutil.copytree(fresh, bag)
    whole = (bag / "metadata.yaml").read_bytes()
    (bag / "metadata.yaml").write_bytes(whole[:3000])
    assert isinstance(yaml.safe_load(whole[:3000]), dict)  # (it parses: not the garbled case tested above)
    for read in (bag_io.read_episode, playback.load_bag):
        with pytest.raises(bag_io.BagReadError) as err:
            read(bag)
        text = str(err.value)
        assert "metadata.yaml" in text and "'version'" in text and f"soil_bag_repair {bag}" in text, text
        assert "KeyError" not in text, text
    out = run("soil_bag_repair", bag, timeout=60)
    assert out.returncode == 0 and "its metadata.yaml rebuilt from the .mcap's own record" in out.stdout, \
        out.stdout + out.stderr
    copy = bag_io.read_episode(tmp_path / "cut_yaml_repaired")
    assert copy.meta == episode.meta and len(copy) == TICKS
    assert np.array_equal(copy.forces, episode.forces)
    assert (bag / "metadata.yaml").read_bytes() == whole[:3000]  # (the original untouched)


def test_metadata_problem_names_what_a_reader_needs_and_passes_a_whole_one(fresh):
    info = bag_io.bag_info(fresh)
    assert bag_io.metadata_problem(info) == ""
    assert "'version'" in bag_io.metadata_problem({k: v for k, v in info.items() if k != "version"})
    broken = dict(info, topics_with_message_count=[{"message_count": 1, "topic_metadata": {"name": "/x"}}])
    assert "topics_with_message_count entry" in bag_io.metadata_problem(broken)
    assert "'duration.nanoseconds'" in bag_io.metadata_problem(dict(info, duration=None))


def test_repair_skips_a_corrupt_journal_chunk_and_converts_the_rest(tmp_path):
    partial, w = _journal_from_sample(tmp_path, n_msgs=900, flush_every=150)  # 6 chunks of 15 ticks
    w.close()
    jpath = journal.journal_path(partial)
    idx = flip_chunk(jpath, 2)  # zstd-compressed records: a CRC or decoding failure, either is named
    out = run("soil_bag_repair", partial, timeout=60)
    assert out.returncode == 0, out.stdout + out.stderr
    assert f"dropped chunk 2 at byte {idx.chunk_start_offset}" in out.stdout, out.stdout
    assert f"log time {idx.message_start_time}..{idx.message_end_time} ns, 150 messages on" in out.stdout
    assert "1 corrupt chunk(s) skipped" in out.stdout
    bag = tmp_path / LOAM.name
    got = bag_io.read_episode(bag)
    want = bag_io.read_episode(LOAM)
    assert len(got) == 75  # 90 ticks journaled, the 15 of chunk 2 dropped, the rest kept
    assert not np.isin(got.stamps_ns, want.stamps_ns[30:45]).any()
    np.testing.assert_array_equal(got.forces, np.delete(want.forces[:90], np.s_[30:45], axis=0))
    info = json.loads(bag_io.bag_custom_data(bag)[journal.REPAIR_INFO_KEY])
    (dropped,) = info["dropped_chunks"]
    assert dropped["chunk"] == 2 and sum(dropped["messages"].values()) == 150
    assert set(dropped["messages"]) == {t.name for t in EPISODE_TOPICS}


def test_a_corrupt_journal_chunk_that_split_ticks_takes_only_whole_ticks_with_it(tmp_path):
    """Chunks flushed mid-tick (a recorder flushes by time, not by tick): the ticks at the skipped
    chunk's two edges keep some messages in the chunks beside it. Those ticks go too, so the
    repaired bag reads as an episode (it had a tick without /clock and every reader refused it)."""
    partial, w = _journal_from_sample(tmp_path, n_msgs=900, flush_every=155)  # 10 messages per tick
    w.close()
    flip_chunk(journal.journal_path(partial), 2)  # messages 310..464
    out = run("soil_bag_repair", partial, timeout=60)
    assert out.returncode == 0, out.stdout + out.stderr
    messages = playback.load_bag(LOAM).messages[:900]  # as _journal_from_sample wrote them
    lost = {t for t, _, _ in messages[310:465]}
    want = sorted({t for t, _, _ in messages} - lost)
    got = bag_io.read_episode(tmp_path / LOAM.name)
    assert got.stamps_ns.tolist() == want and len(want) == 90 - 16  # ticks 31..45 and the split 46
    full = bag_io.read_episode(LOAM)
    keep = np.isin(full.stamps_ns, want)
    np.testing.assert_array_equal(got.forces, full.forces[keep])


def test_repair_names_a_journal_chunk_that_took_the_channel_table_with_it(tmp_path):
    """Chunk 0 of a journal also holds its schemas and channels: without them no later message
    can be attributed to a topic, so nothing is recoverable, and the journal is kept."""
    partial, w = _journal_from_sample(tmp_path, n_msgs=300, flush_every=150)
    w.close()
    idx = flip_chunk(journal.journal_path(partial), 0)
    out = run("soil_bag_repair", partial, timeout=60)
    assert out.returncode == 1 and "Traceback" not in out.stderr, out.stderr
    assert f"chunk 0 at byte {idx.chunk_start_offset}" in out.stderr, out.stderr
    assert partial.exists() and not (tmp_path / LOAM.name).exists()


def test_no_training_window_spans_the_gap_a_repair_leaves(fresh, tmp_path):
    """Dropping a chunk leaves a gap in the stamps; the dataset never builds a window across it
    (the online estimator empties its window at a missing tick), and a cached dataset agrees."""
    from pinn_estimator.dataset import WINDOW_SAMPLES, load_dataset

    flip_chunk(mcap_of(fresh), 4)
    salvage_bag(fresh, tmp_path / "repaired" / fresh.name)
    stamps = bag_io.read_episode(tmp_path / "repaired" / fresh.name).stamps_ns
    gap = int(np.flatnonzero(np.diff(stamps) > 1.5 * 1e9 / 60)[0]) + 1  # first row after the gap
    for _ in range(2):  # the second load reads the cache the first wrote
        ds = load_dataset(tmp_path / "repaired")
        ends = ds.window_ends([0])
        assert len(ends) and not np.any((ends >= gap) & (ends - WINDOW_SAMPLES + 1 < gap))
        before = np.arange(WINDOW_SAMPLES - 1, gap)
        after = np.arange(gap + WINDOW_SAMPLES - 1, len(stamps))
        assert np.array_equal(ends, np.concatenate([before, after]))
