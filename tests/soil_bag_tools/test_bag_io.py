"""rosbag2 MCAP episode bags: round trip, on-disk format, atomic writes and read errors.

Bags are the dataset format shared by the simulator, the trainer and ``ros2 bag``, so the
tests check the files with independent readers (pyyaml, the ``mcap`` library) as well as
with our own reader.
"""
from __future__ import annotations

import dataclasses

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader

from soil_bag_tools import bag_io

from soil_msgs_py import messages
from soil_bag_tools.bag_io import META_KEY, find_episode_bags, read_dataset, read_episode, write_episode
from soil_bag_tools.playback import load_bag
from soil_msgs_py.episode import Episode, EpisodeMeta
from soil_msgs_py.messages import ARRAY_FIELDS, TYPESTORE, make_labelled, parse_labelled
from soil_msgs_py.params import GROUND_TRUTH_PARAMS, KNOWN_PARAMS
from soil_msgs_py.topics import EPISODE_TOPICS, STAMP_FIELDS
from tests.bag_fixtures import write_raw

N = 120
ARRAYS = tuple(ARRAY_FIELDS)


def make_episode(n: int = N, seed: int = 0) -> Episode:
    """Random finite arrays with awkward float64 values (tiny, huge, negative zero)."""
    rng = np.random.default_rng(seed)
    meta = EpisodeMeta(
        soil="Loam", relative_density_pct=42.0, world_mode="fee", seed=seed,
        target_speed_m_s=0.4, target_depth_m=0.12, duration_s=n / 60,
        effects=["surcharge"], plugins=["vortex_like"],
    )
    arrays = {a: rng.standard_normal((n, len(f))) * 10.0 ** rng.integers(-9, 9, (n, len(f)))
              for a, f in ARRAY_FIELDS.items()}
    arrays["forces"][0, 0] = -0.0
    arrays["truth"][1, 2] = np.nextafter(1.0, 2.0)
    stamps = np.round(np.arange(n) * 1e9 / 60).astype(np.int64) + 5 * 10**9
    return Episode(meta=meta, stamps_ns=stamps, **arrays)


def assert_same(a: Episode, b: Episode) -> None:
    assert a.meta == b.meta
    assert b.stamps_ns.dtype == np.int64 and np.array_equal(a.stamps_ns, b.stamps_ns)
    for name in ARRAYS:
        x, y = getattr(a, name), getattr(b, name)
        assert y.dtype == np.float64, name
        assert x.tobytes() == y.tobytes(), f"{name} not bit-identical"


@pytest.fixture
def ep() -> Episode:
    return make_episode()


@pytest.fixture
def bag(tmp_path: Path, ep: Episode) -> Path:
    return write_episode(tmp_path / "ep", ep)


def test_round_trip_is_bit_identical(bag: Path, ep: Episode) -> None:
    assert bag.name == "ep" and sorted(p.name for p in bag.iterdir()) == ["ep.mcap", "metadata.yaml"]
    back = read_episode(bag)
    assert_same(ep, back)
    assert np.signbit(back.forces[0, 0])  # -0.0 survives
    assert not (bag.parent / "ep.partial").exists()


def test_a_machines_bag_has_no_ground_truth_and_reads_with_truth_nan(tmp_path: Path, ep: Episode) -> None:
    """A real machine records no /soil/ground_truth: such a bag reads, every other array
    bit-identical, truth NaN; a bag missing any other episode topic is refused, naming it."""
    ep.truth[:] = np.nan  # a machine knows none: not written, so not checked
    bag = write_episode(tmp_path / "machine", ep, ground_truth=False)
    with AnyReader([bag]) as reader:
        assert "/soil/ground_truth" not in {c.topic for c in reader.connections}
        assert {c.topic for c in reader.connections} == {t.name for t in EPISODE_TOPICS} - {"/soil/ground_truth"}
    back = read_episode(bag)
    assert not back.has_ground_truth and np.isnan(back.truth).all() and back.truth.shape == ep.truth.shape
    for name in set(ARRAYS) - {"truth"}:
        assert getattr(back, name).tobytes() == getattr(ep, name).tobytes(), name
    assert make_episode().has_ground_truth
    with pytest.raises(ValueError, match="Episode.truth"):  # a simulator's bag must carry a finite truth
        write_episode(tmp_path / "sim", ep)
    # a machine's world is no simulator's: written as such (the README's recipe), read back as such;
    # a simulator's bag (with its truth) must name its world
    unknown = dataclasses.replace(ep, meta=dataclasses.replace(ep.meta, soil="unknown", world_mode="unknown"))
    assert read_episode(write_episode(tmp_path / "unknown", unknown, ground_truth=False)).meta.world_mode == "unknown"
    with pytest.raises(ValueError, match="world_mode='unknown' is not one of"):
        write_episode(tmp_path / "sim_unknown", dataclasses.replace(make_episode(), meta=unknown.meta))
    no_force = write_raw(tmp_path / "no_force", make_episode(), skip=lambda topic, i: topic == "/blade/force")
    with pytest.raises(bag_io.BagReadError, match="has no topic /blade/force"):
        read_episode(no_force)
    # the recorder of a replay that left the truth or the clock out: their channels there, empty
    sim = make_episode()
    for topic in ("/soil/ground_truth", "/clock"):
        emptied = write_raw(tmp_path / topic.replace("/", "_"), sim, skip=lambda t, i: t == topic and i is not None)
        with AnyReader([emptied]) as reader:
            assert topic in {c.topic for c in reader.connections}
        back = read_episode(emptied)
        assert back.stamps_ns.tobytes() == sim.stamps_ns.tobytes() and back.forces.tobytes() == sim.forces.tobytes()
        assert back.has_ground_truth == (topic != "/soil/ground_truth")
    silent_force = write_raw(tmp_path / "silent_force", sim, skip=lambda t, i: t == "/blade/force" and i is not None)
    with pytest.raises(bag_io.BagReadError, match="topic /blade/force has no messages"):
        read_episode(silent_force)


def test_metadata_yaml(bag: Path, ep: Episode) -> None:
    doc = yaml.safe_load((bag / "metadata.yaml").read_text())
    info = doc["rosbag2_bagfile_information"]
    assert info["version"] == 9
    assert info["storage_identifier"] == "mcap"
    assert info["message_count"] == N * len(EPISODE_TOPICS)
    assert info["starting_time"]["nanoseconds_since_epoch"] == ep.stamps_ns[0]
    counts = {t["topic_metadata"]["name"]: (t["topic_metadata"]["type"], t["message_count"],
                                            t["topic_metadata"]["serialization_format"])
              for t in info["topics_with_message_count"]}
    assert counts == {t.name: (t.msgtype, N, "cdr") for t in EPISODE_TOPICS}
    stored = json.loads(info["custom_data"][META_KEY])
    assert EpisodeMeta(**stored) == ep.meta


def test_mcap_file_with_independent_reader(bag: Path, ep: Episode) -> None:
    with open(bag / "ep.mcap", "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        summary = reader.get_summary()
        assert summary is not None
        channels = summary.channels.values()
        assert {c.topic for c in channels} == {t.name for t in EPISODE_TOPICS}
        types = {t.name: t.msgtype for t in EPISODE_TOPICS}
        for c in channels:
            schema = summary.schemas[c.schema_id]
            assert c.message_encoding == "cdr"
            assert schema.encoding == "ros2msg"
            assert schema.name == types[c.topic]
            assert schema.data.strip(), c.topic
            assert summary.statistics.channel_message_counts[c.id] == N
        log_times = [m.log_time for _, _, m in reader.iter_messages(topics=["/clock"])]
    assert log_times == ep.stamps_ns.tolist()


def _raw_messages(bag: Path, topic: str) -> list:
    with AnyReader([bag]) as r:
        conns = [c for c in r.connections if c.topic == topic]
        return [r.deserialize(raw, c.msgtype) for c, _, raw in r.messages(connections=conns)]


def test_field_mapping_on_the_wire(bag: Path, ep: Episode) -> None:
    """The documented topic <-> Episode column mapping, checked field by field."""
    col = ep.column
    i = 7
    sec, nsec = divmod(int(ep.stamps_ns[i]), 10**9)

    def stamped(topic: str):
        msg = _raw_messages(bag, topic)[i]
        assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (sec, nsec)
        assert msg.header.frame_id == "world"
        return msg

    clock = _raw_messages(bag, "/clock")[i].clock
    assert (clock.sec, clock.nanosec) == (sec, nsec)
    p = stamped("/blade/pose").point
    assert (p.x, p.y, p.z) == (col("p_x_b")[i], 0.0, col("p_z_b")[i])
    p = stamped("/chassis/pose").point
    assert (p.x, p.y, p.z) == (col("p_x_c")[i], 0.0, col("p_z_c")[i])
    t = stamped("/blade/twist").twist
    assert (t.linear.x, t.linear.y, t.linear.z) == (col("v_x_b")[i], 0.0, col("v_z_b")[i])
    assert (t.angular.x, t.angular.y, t.angular.z) == (0.0, 0.0, 0.0)
    t = stamped("/chassis/twist").twist
    assert (t.linear.x, t.linear.z) == (col("v_x_c")[i], col("v_z_c")[i])
    t = stamped("/chassis/cmd_vel").twist
    assert (t.linear.x, t.linear.z) == (col("u_x")[i], 0.0)
    w = stamped("/blade/force").wrench
    assert (w.force.x, w.force.y, w.force.z) == (col("f_x_b")[i], 0.0, col("f_z_b")[i])
    assert (w.torque.x, w.torque.y, w.torque.z) == (0.0, 0.0, 0.0)


@pytest.mark.parametrize(
    "topic, labels, expected",
    [
        ("/soil/known_params", KNOWN_PARAMS, lambda ep, i: ep.known[i]),
        ("/soil/ground_truth", GROUND_TRUTH_PARAMS, lambda ep, i: ep.truth[i]),
        ("/blade/cmd", ("u_zr", "u_za"), lambda ep, i: [ep.column("u_zr")[i], ep.column("u_za")[i]]),
    ],
)
def test_labelled_array_layout(bag: Path, ep: Episode, topic, labels, expected) -> None:
    msgs = _raw_messages(bag, topic)
    assert len(msgs) == N
    for i in (0, N - 1):
        msg = msgs[i]
        n = len(labels) + 2
        assert len(msg.layout.dim) == 1
        dim = msg.layout.dim[0]
        assert dim.label == "|".join(STAMP_FIELDS + tuple(labels))
        assert dim.label.startswith("stamp_sec|stamp_nanosec|")
        assert (dim.size, dim.stride, msg.layout.data_offset, len(msg.data)) == (n, n, 0, n)
        assert (msg.data[0], msg.data[1]) == divmod(int(ep.stamps_ns[i]), 10**9)
        assert np.array_equal(msg.data[2:], expected(ep, i))


def test_make_and_parse_labelled() -> None:
    msg = make_labelled(TYPESTORE, 3 * 10**9 + 17, ("a", "b"), [1.5, -2.0])
    assert parse_labelled(msg, ("a", "b"))[0] == 3 * 10**9 + 17
    assert np.array_equal(parse_labelled(msg, ("a", "b"))[1], [1.5, -2.0])
    with pytest.raises(ValueError, match=r"/x/y: label mismatch.*a\|b"):
        parse_labelled(msg, ("a", "c"), topic="/x/y")
    msg.data = msg.data[:-1]
    with pytest.raises(ValueError, match="len"):
        parse_labelled(msg, ("a", "b"))
    with pytest.raises(ValueError, match="2 labels"):
        make_labelled(TYPESTORE, 0, ("a", "b"), [1.0])


@pytest.mark.parametrize(
    "array, col, bad",
    [("forces", 1, np.nan), ("truth", 12, np.inf), ("observations", 0, -np.inf), ("extras", 0, np.nan),
     ("observations", 3, 1e12), ("forces", 0, -2e9)],  # (finite, but beyond what the live nodes take: no reader takes it)
)
def test_non_finite_or_implausible_rejected_naming_column(tmp_path: Path, ep: Episode, array, col, bad) -> None:
    getattr(ep, array)[17, col] = bad
    getattr(ep, array)[90, col] = bad
    name = ARRAY_FIELDS[array][col]
    with pytest.raises(ValueError, match=rf"^bag {tmp_path / 'ep'} not written: Episode.{array} column '{name}' is .* at row 17 "):
        write_episode(tmp_path / "ep", ep)
    assert list(tmp_path.iterdir()) == []


def test_bad_stamps_and_meta_rejected(tmp_path: Path, ep: Episode) -> None:
    ep.stamps_ns[5] = ep.stamps_ns[4]
    with pytest.raises(ValueError, match="strictly increasing at row 5"):
        write_episode(tmp_path / "a", ep)
    ep2 = make_episode()
    ep2.meta.world_mode = "moon"
    with pytest.raises(ValueError, match="world_mode"):
        write_episode(tmp_path / "b", ep2)
    assert list(tmp_path.iterdir()) == []


def _fail_after(monkeypatch, calls: int) -> None:
    real = TYPESTORE.serialize_cdr
    count = {"n": 0}

    def flaky(*args, **kwargs):
        count["n"] += 1
        if count["n"] > calls:
            raise RuntimeError("injected serializer failure")
        return real(*args, **kwargs)

    monkeypatch.setattr(TYPESTORE, "serialize_cdr", flaky)


def test_failed_write_leaves_nothing(tmp_path: Path, ep: Episode, monkeypatch) -> None:
    _fail_after(monkeypatch, 55 * len(EPISODE_TOPICS) + 3)
    with pytest.raises(RuntimeError, match="injected"):
        write_episode(tmp_path / "ep", ep)
    assert list(tmp_path.iterdir()) == []
    assert find_episode_bags(tmp_path) == []


def test_overwrite(tmp_path: Path, ep: Episode, monkeypatch) -> None:
    bag = write_episode(tmp_path / "ep", ep)
    other = make_episode(seed=1)
    with pytest.raises(FileExistsError, match="overwrite"):
        write_episode(bag, other)
    _fail_after(monkeypatch, 10)
    with pytest.raises(RuntimeError, match="injected"):
        write_episode(bag, other, overwrite=True)
    monkeypatch.undo()
    assert_same(ep, read_episode(bag))  # failed overwrite kept the old bag
    write_episode(bag, other, overwrite=True)
    assert_same(other, read_episode(bag))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ep"]
    (tmp_path / "notabag").mkdir()
    (tmp_path / "notabag" / "precious.txt").write_text("x")
    with pytest.raises(FileExistsError, match="not a rosbag2 bag"):
        write_episode(tmp_path / "notabag", ep, overwrite=True)


def test_failed_final_rename_restores_old_bag(tmp_path: Path, ep: Episode, monkeypatch) -> None:
    bag = write_episode(tmp_path / "ep", ep)
    real = bag_io.os.replace

    def failing(src, dst):
        if Path(src) == tmp_path / "ep.partial" / "ep":
            raise OSError("injected rename failure")
        return real(src, dst)

    monkeypatch.setattr(bag_io.os, "replace", failing)
    with pytest.raises(OSError, match="injected"):
        write_episode(bag, make_episode(seed=3), overwrite=True)
    monkeypatch.undo()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ep"]
    assert_same(ep, read_episode(bag))


def test_stale_partial_is_ignored_and_replaced(tmp_path: Path, ep: Episode) -> None:
    stale = write_raw(tmp_path / "ep.partial" / "ep", ep)  # looks like a bag, inside staging
    assert find_episode_bags(tmp_path) == []
    with pytest.raises(ValueError, match="unfinished"):
        read_episode(tmp_path / "ep.partial")
    write_episode(tmp_path / "ep", ep)
    assert not stale.exists() and find_episode_bags(tmp_path) == [tmp_path / "ep"]


def test_missing_topic_named(tmp_path: Path, ep: Episode) -> None:
    bag = write_raw(tmp_path / "nof", ep, skip=lambda topic, i: topic == "/blade/force")
    with pytest.raises(ValueError, match="/blade/force"):
        read_episode(bag)


def test_the_player_says_an_episode_bag_lacks_a_topic(tmp_path: Path, ep: Episode) -> None:
    """Every bag reader refuses an episode bag without /blade/force; the player played it without a word."""
    bag = write_raw(tmp_path / "noforce", ep, skip=lambda topic, i: topic == "/blade/force")
    said: list[str] = []
    played = load_bag(bag, log=said.append)
    assert "/blade/force" not in played.topics and played.meta is not None
    assert any("an episode bag without topic(s) ['/blade/force']" in line for line in said), said
    said.clear()
    whole = write_episode(tmp_path / "whole", ep, ground_truth=False)  # a machine's bag: no truth, nothing missing
    load_bag(whole, exclude=("/blade/pose",), log=said.append)  # and leaving one out on purpose is no warning
    assert said == [], said


def test_a_tick_one_topic_lacks_is_dropped_and_said(tmp_path: Path, ep: Episode, caplog) -> None:
    """One lost message refused a machine's whole bag offline, where the live estimator resets its
    window and goes on (an outside tester's): now that tick is a gap, and said."""
    bag = write_raw(tmp_path / "gap", ep, skip=lambda topic, i: topic == "/blade/twist" and i == 7)
    with caplog.at_level("WARNING"):
        back = read_episode(bag)
    assert len(back) == len(ep) - 1 and ep.stamps_ns[7] not in back.stamps_ns
    assert f"1 of {len(ep)} ticks lack a topic (e.g. /blade/twist has no message at {ep.stamps_ns[7]} ns)" in caplog.text


def test_topics_stamped_each_by_its_own_clock_are_refused_saying_so(tmp_path: Path, ep: Episode) -> None:
    bag = write_raw(tmp_path / "apart", ep, skip=lambda topic, i: topic == "/blade/force" and i is not None and i % 3 != 0)
    with pytest.raises(ValueError, match="its topics' stamps do not line up: .* every topic of a tick must carry the tick's stamp"):
        read_episode(bag)


def test_a_machines_bag_without_a_clock_is_read_from_its_other_topics(tmp_path: Path, ep: Episode) -> None:
    back = read_episode(write_raw(tmp_path / "noclock", ep, skip=lambda topic, i: topic == "/clock"))
    assert np.array_equal(back.stamps_ns, ep.stamps_ns) and back.forces.tobytes() == ep.forces.tobytes()
    # a /clock of its own rate (a machine's recorder ticking at 30 Hz) is no topic the ticks lack
    half = read_episode(write_raw(tmp_path / "halfclock", ep, skip=lambda topic, i: topic == "/clock" and bool(i and i % 2)))
    assert np.array_equal(half.stamps_ns, ep.stamps_ns)


def test_a_bag_of_a_namespaced_graph_is_read_under_its_namespace(tmp_path: Path, ep: Episode) -> None:
    """A machine's own recorder (``ros2 bag record`` of a graph launched in /dozer1) writes
    /dozer1/blade/force: read as the contract's topics; two machines' in one bag are refused."""
    back = read_episode(write_raw(tmp_path / "ns", ep, namespaces=("/site/dozer1",)))
    assert np.array_equal(back.stamps_ns, ep.stamps_ns) and back.forces.tobytes() == ep.forces.tobytes()
    with pytest.raises(ValueError, match=r"holds the episode topics of 2 namespaces \(/dozer1, /dozer2\): several"):
        read_episode(write_raw(tmp_path / "two", ep, namespaces=("/dozer1", "/dozer2")))
    with pytest.raises(ValueError, match=r"2 namespaces \(the root namespace, /dozer2\): several machines' data"):
        read_episode(write_raw(tmp_path / "root_and_two", ep, namespaces=("", "/dozer2")))
    # a player takes its topics by the contract's names (selected so too) and sends them into its own namespace
    from soil_bag_tools.playback import load_bag

    loaded = load_bag(tmp_path / "ns", exclude=["/soil/ground_truth"])
    assert set(loaded.topics) == {t.name for t in EPISODE_TOPICS} - {"/soil/ground_truth"}
    assert {topic for _, topic, _ in loaded.messages} == set(loaded.topics)


def test_ticks_at_another_rate_are_refused_and_a_flipped_force_is_said(tmp_path: Path, caplog) -> None:
    """A 30 Hz bag crashed pinn_eval and pinn_train, 50 and 100 Hz ones ran as 60 Hz; a force sensor
    of the other sign ran on (outside tester's): the rate is refused, the sign said."""
    from dataclasses import replace

    from soil_sim_node.rollout import run_episodes
    from soil_sim_node.simulator import EpisodeSpec, SimConfig

    sim = run_episodes(SimConfig(world_mode="fee"), [EpisodeSpec("Clay", 40.0, 0.5, 0.1, seed=1, duration_s=3.0)])[0]
    half = Episode(meta=replace(sim.meta, duration_s=3.0), stamps_ns=sim.stamps_ns[::2],
                   **{a: getattr(sim, a)[::2] for a in ARRAYS})
    with pytest.raises(ValueError, match=r"every 33.3 ms \(30 Hz\) by their stamps; .* resample the topics to 60 Hz"):
        read_episode(write_episode(tmp_path / "hz30", half))
    with caplog.at_level("WARNING"):
        read_episode(write_episode(tmp_path / "right", sim))
    assert "f_x < 0" not in caplog.text
    flipped = Episode(meta=sim.meta, stamps_ns=sim.stamps_ns, **{a: getattr(sim, a) for a in ARRAYS if a != "forces"},
                      forces=-sim.forces)
    with caplog.at_level("WARNING"):
        read_episode(write_episode(tmp_path / "flipped", flipped))
    assert "ticks cutting forward" in caplog.text and "a sensor of the other sign?" in caplog.text


def test_label_mismatch_in_bag_named(tmp_path: Path, ep: Episode) -> None:
    wrong = make_labelled(TYPESTORE, int(ep.stamps_ns[3]), ("u_za", "u_zr"), [0.0, 0.0])
    bag = write_raw(tmp_path / "lab", ep, replace=(("/blade/cmd", 3), wrong))
    with pytest.raises(ValueError, match=r"/blade/cmd: label mismatch"):
        read_episode(bag)


def test_missing_episode_metadata(tmp_path: Path, ep: Episode) -> None:
    bag = write_raw(tmp_path / "nometa", ep, meta=False)
    with pytest.raises(ValueError, match="no episode metadata"):
        read_episode(bag)
    # written into metadata.yaml by hand as a YAML mapping, not the JSON text rosbag2 keeps there
    import yaml

    meta = bag / "metadata.yaml"
    info = yaml.safe_load(meta.read_text())
    info["rosbag2_bagfile_information"]["custom_data"] = {"insitu_soil.episode": json.loads(ep.meta.to_json())}
    meta.write_text(yaml.safe_dump(info))
    with pytest.raises(ValueError, match="must be one JSON text .* not a dict: write it as json.dumps"):
        read_episode(bag)


def test_the_readmes_recipe_adds_the_episode_metadata_to_a_bag_ros2_bag_record_wrote(tmp_path: Path) -> None:
    """The README's snippet for a machine's bag whose ``custom_data`` is null (as ``ros2 bag record``
    writes it): run as printed on such a copy of a sample bag, the bag is then read as a machine's."""
    import shutil

    import yaml

    root = Path(__file__).resolve().parents[2]
    text = (root / "README.md").read_text()
    start = text.index("import json, yaml   # add the episode metadata")
    code = text[start:text.index("```", start)]
    bag = shutil.copytree(root / "bags/samples/default_loam_id060_v0.50_d0.200_s7", tmp_path / "run_0001")
    meta = bag / "metadata.yaml"
    info = yaml.safe_load(meta.read_text())
    info["rosbag2_bagfile_information"]["custom_data"] = None
    meta.write_text(yaml.safe_dump(info))
    with pytest.raises(ValueError, match="no episode metadata"):
        read_episode(bag)
    exec(compile(code.replace("bags/site/run_0001/metadata.yaml", str(meta)), "README.md", "exec"), {})
    ep = read_episode(bag)
    assert ep.meta.soil == "unknown" and ep.meta.world_mode == "unknown" and len(ep) > 0


@pytest.mark.parametrize("field, value, needle", [("relative_density_pct", "eighty", "relative_density_pct='eighty' must be a finite number"),
                                                  ("relative_density_pct", 150, r"relative_density_pct=150 outside \[0, 100\]"),
                                                  ("relative_density_pct", float("nan"), "relative_density_pct=nan must be a finite number"),
                                                  ("world_mode", "moon", "world_mode='moon' is not one of"),
                                                  # (these three were read on: a bag of another metadata version,
                                                  # a soil named by a number, which failed later naming no bag)
                                                  ("schema_version", 2, "schema_version=2: this code reads"),
                                                  ("soil", 5, "soil=5 must be a soil's name"),
                                                  ("effects", "noise", "effects='noise' must be a list of names")])
def test_episode_metadata_a_bag_was_edited_to_is_refused_naming_the_field(tmp_path: Path, ep: Episode, field, value, needle) -> None:
    """A bag's metadata is checked as it is read: a density of 150 % or of "eighty" and a world no
    simulator has were read on (a wrong density in every report, a "could not convert string to
    float" naming no bag). A machine's bag, whose world is "unknown", still reads."""
    bag = write_episode(tmp_path / "edited", ep)
    path = bag / "metadata.yaml"
    doc = yaml.safe_load(path.read_text())
    info = doc["rosbag2_bagfile_information"]
    meta = json.loads(info["custom_data"][META_KEY])
    info["custom_data"][META_KEY] = json.dumps({**meta, "world_mode": "unknown"})
    path.write_text(yaml.safe_dump(doc))
    assert read_episode(bag).meta.world_mode == "unknown"
    played = load_bag(bag)  # the player frames its episode with /sim/status, as a simulated one's
    assert played.meta is not None and played.meta.world_mode == "unknown"
    info["custom_data"][META_KEY] = json.dumps({**meta, field: value})
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(ValueError, match=rf"edited.*bad episode metadata.*{needle}"):
        read_episode(bag)


def test_read_errors(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="does not exist"):
        read_episode(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="not a rosbag2 directory"):
        read_episode(tmp_path / "empty")
    with pytest.raises(ValueError, match=f"no bags found under {tmp_path / 'empty'}"):
        read_dataset(tmp_path / "empty")
    with pytest.raises(FileNotFoundError):
        read_dataset(tmp_path / "nope")


def test_a_dataset_of_links_to_recorded_bags_is_found_once_and_a_link_loop_ends(tmp_path: Path) -> None:
    runs, data = tmp_path / "runs", tmp_path / "data"
    eps = [make_episode(n=30, seed=k) for k in range(2)]
    for k, e in enumerate(eps):
        write_episode(runs / f"r{k}", e)
    data.mkdir()
    (data / "first").symlink_to(runs / "r0", target_is_directory=True)  # a link to one bag
    (data / "all").symlink_to(runs, target_is_directory=True)  # and to the folder holding both
    (runs / "back").symlink_to(tmp_path, target_is_directory=True)  # a loop up the tree
    found = find_episode_bags(data)
    assert found == [data / "all" / "r0", data / "all" / "r1"], "each bag once, by the first link in name order"
    assert sorted(e.meta.seed for e in read_dataset(data)) == [0, 1]


def test_read_dataset_finds_nested_bags(tmp_path: Path) -> None:
    eps = [make_episode(n=30 + 10 * k, seed=k) for k in range(3)]
    paths = [tmp_path / "b" / "x", tmp_path / "a", tmp_path / "b" / "c" / "y"]
    for p, e in zip(paths, eps):
        write_episode(p, e)
    (tmp_path / "b" / "notes").mkdir()
    assert find_episode_bags(tmp_path) == sorted(paths)
    assert find_episode_bags(paths[1]) == [paths[1]]
    got = read_dataset(tmp_path, progress=True)
    by_seed = {e.meta.seed: e for e in got}
    assert [e.meta.seed for e in got] == [1, 2, 0]  # sorted path order: a, b/c/y, b/x
    for e in eps:
        assert_same(e, by_seed[e.meta.seed])


def test_600_ticks_read_back_whole(tmp_path: Path) -> None:
    """A 10 s episode reads back tick for tick (how fast: benchmarks/bench_bag_tools.py)."""
    ep = make_episode(n=600)
    bag = write_episode(tmp_path / "long", ep)
    assert_same(ep, read_episode(bag))


def test_mapping_works_with_ros_message_classes(ep: Episode) -> None:
    """Same builders/parsers on the real ROS 2 Python message classes (what rclpy nodes publish)."""
    pytest.importorskip("geometry_msgs.msg")
    ros = messages.ros_message_classes()
    i = 4
    for name, f in messages.FIELDS.items():
        values = messages.topic_rows(ep, name)[i].tolist()
        msg = messages.build_message(ros, name, int(ep.stamps_ns[i]), values)
        assert type(msg) is ros[f.topic.msgtype]
        stamp, back = messages.parse_message(name, msg)
        assert stamp == ep.stamps_ns[i] and back.tolist() == values, name


def test_no_rclpy_import() -> None:
    code = "import sys, soil_bag_tools.bag_io; sys.exit('rclpy' in sys.modules)"
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0


def test_a_bag_write_stopped_midway_is_said_as_such_not_as_a_recorder_journal(tmp_path):
    """A writer killed mid-write (a lost Ray cluster's worker) leaves its staging directory, the bag
    inside it unfinished: it was named a recorder journal to repair. A recorder's journal is still one."""
    from soil_bag_tools.bag_io import passed_by_note, scan_bags

    (tmp_path / "ep1.partial" / "ep1").mkdir(parents=True)  # write_episode's staging: the bag being written
    (tmp_path / "ep1.partial" / "ep1" / "ep1.mcap").write_bytes(b"")
    (tmp_path / "ep2.partial").mkdir()
    (tmp_path / "ep2.partial" / "ep2.mcap").write_bytes(b"")  # a recorder's journal
    found, strays = scan_bags(tmp_path)
    note = passed_by_note(strays, tmp_path)
    assert not found and "1 recorder journal(s)" in note and "ep2.partial" in note.split("unfinished")[0]
    assert "1 unfinished bag write(s)" in note and "ep1.partial; nothing to recover" in note, note
    (tmp_path / "ep3.partial" / "replaced").mkdir(parents=True)  # an --overwrite's old bag, parked mid-write
    note = passed_by_note(scan_bags(tmp_path)[1], tmp_path)
    assert "1 old bag(s) parked by an overwrite that stopped midway" in note and "ep3.partial" in note.split("parked")[1]
    assert "1 unfinished bag write(s)" in note, note
