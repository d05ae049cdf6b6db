"""A corrupt or truncated bag is named, never a traceback, in every offline tool.

Bytes overwritten in the middle of a sample bag's ``.mcap`` make rosbags raise whatever its
decoder trips over (ReaderError, SerdeError, OverflowError, UnicodeDecodeError, ...);
``bag_io`` turns all of them into one ``BagReadError`` naming the bag. Each CLI is run as a
real subprocess and must exit 2 with the bag's path on stderr and no traceback, also when the
bag is read in a worker process; ``--skip-bad-bags`` skips the bag and says so.
"""
from __future__ import annotations

import pickle
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from soil_bag_tools import bag_io, playback
from soil_msgs_py import topics as T

ROOT = Path(__file__).resolve().parents[2]
SAMPLES = ROOT / "bags" / "samples"
LOAM = SAMPLES / "default_loam_id060_v0.50_d0.200_s7"
CLAY = SAMPLES / "default_clay_id100_v0.50_d0.300_s8"
BIN = Path(sys.executable).parent
TINY_MODEL = ["--d-model", "16", "--n-heads", "2", "--n-layers", "1", "--ff-dim", "32",
              "--epochs", "1", "--batch-size", "64", "--stride", "16", "--eval-stride", "30"]

pytestmark = pytest.mark.timeout(300)  # soil_bag_play's refusal, which needs a DDS domain, is in test_bag_tools.py


def mcap_of(bag: Path) -> Path:
    (mcap,) = bag.glob("*.mcap")
    return mcap


def copy_bag(src: Path, dst: Path) -> Path:
    """A copy under another directory name (the .mcap keeps the name metadata.yaml lists)."""
    shutil.copytree(src, dst)
    return dst


def corrupt(bag: Path, n: int = 256) -> Path:
    """Overwrite ``n`` bytes in the middle of the bag's .mcap (a flipped disk block)."""
    mcap = mcap_of(bag)
    data = bytearray(mcap.read_bytes())
    mid = len(data) // 2
    data[mid:mid + n] = b"\xff" * n
    mcap.write_bytes(bytes(data))
    return bag


def truncate(bag: Path) -> Path:
    mcap = mcap_of(bag)
    data = mcap.read_bytes()
    mcap.write_bytes(data[: len(data) // 2])
    return bag


DAMAGE = {"corrupt": corrupt, "truncated": truncate}


def run(tool: str, *args, env=None, timeout: float = 240) -> subprocess.CompletedProcess:
    return subprocess.run([str(BIN / tool), *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, env=env)


def assert_refused(out: subprocess.CompletedProcess, bag: Path) -> None:
    """Exit 2, the bag named on stderr, no traceback anywhere."""
    text = out.stdout + out.stderr
    assert out.returncode == 2, text
    assert str(bag) in out.stderr, text
    assert "Traceback" not in text, text


@pytest.fixture(scope="module")
def dirs(tmp_path_factory):
    """good/: the three samples plus two more episodes of the loam one's soil, density and targets
    (other seeds: a soil group of three, so every split is non-empty; copies would be one episode,
    kept in one split); with_bad/: the same plus a corrupt copy of the clay bag."""
    from soil_sim_node.rollout import run_episodes
    from soil_sim_node.simulator import EpisodeSpec, SimConfig

    base = tmp_path_factory.mktemp("corrupt_bags")
    good = base / "good"
    for src in sorted(SAMPLES.iterdir()):
        copy_bag(src, good / src.name)
    meta = bag_io.read_episode(LOAM).meta
    specs = [EpisodeSpec(meta.soil, meta.relative_density_pct, meta.target_speed_m_s, meta.target_depth_m, seed=seed,
                         duration_s=meta.duration_s) for seed in (101, 102)]
    for ep in run_episodes(SimConfig(world_mode=meta.world_mode), specs):
        bag_io.write_episode(good / ep.meta.name, ep)
    with_bad = base / "with_bad"
    shutil.copytree(good, with_bad)
    bad = corrupt(copy_bag(CLAY, with_bad / f"{CLAY.name}_broken"))
    return {"good": good, "with_bad": with_bad, "bad": bad, "base": base}


@pytest.fixture(params=sorted(DAMAGE))
def damaged(request, tmp_path) -> Path:
    return DAMAGE[request.param](copy_bag(LOAM, tmp_path / "damaged" / LOAM.name))


# ------------------------------------------------------------------------------ library
def test_reader_raises_one_error_naming_the_bag(damaged):
    with pytest.raises(bag_io.BagReadError) as err:
        bag_io.read_episode(damaged)
    assert err.value.bag == str(damaged) and str(damaged) in str(err.value)
    assert f"soil_bag_repair {damaged} --out NEW_BAG" in str(err.value)  # truncated or not, its good chunks copy
    with pytest.raises(bag_io.BagReadError, match=str(damaged)):
        bag_io.read_labelled_topic(damaged, T.BLADE_CMD.name, ("u_zr", "u_za"))
    with pytest.raises(bag_io.BagReadError, match=str(damaged)):
        playback.load_bag(damaged)


def test_a_damaged_metadata_yaml_is_said_in_one_line(tmp_path):
    """A YAML error was shown as its repr, a dump of the parser's Mark objects."""
    bag = copy_bag(LOAM, tmp_path / LOAM.name)
    meta = bag / "metadata.yaml"
    meta.write_text(meta.read_text().replace("rosbag2_bagfile_information:", "rosbag2_bagfile_information: [", 1))
    with pytest.raises(bag_io.BagReadError) as err:
        bag_io.read_episode(bag)
    text = str(err.value)
    assert "unreadable metadata.yaml: " in text and "Error: " in text and str(bag) in text, text
    assert "\n" not in text and "object at 0x" not in text, text
    # YAML that parses but is no rosbag2 metadata: said so, not as "TypeError: string indices must be integers"
    meta.write_text("just a string\n")
    with pytest.raises(bag_io.BagReadError, match="not a rosbag2 metadata file .*found 'just a string'"):
        bag_io.read_episode(bag)


def test_bag_read_error_survives_pickling():
    """It crosses process boundaries (dataset and analysis workers) intact."""
    err = bag_io.BagReadError("/x/bag", "Truncated record at offset 5")
    back = pickle.loads(pickle.dumps(err))
    assert type(back) is bag_io.BagReadError
    assert (back.bag, back.problem, str(back)) == (err.bag, err.problem, str(err))
    assert isinstance(back, ValueError)
    err = bag_io.MetadataUnreadable("/x/bag", "unreadable metadata.yaml: it lacks 'version'")
    back = pickle.loads(pickle.dumps(err))
    assert type(back) is bag_io.MetadataUnreadable and (back.reason, str(back)) == (err.reason, str(err))


def rosbag2_copy(src: Path, dst: Path, storage: str, compression: str | None) -> Path:
    """``src`` written again as ``ros2 bag record`` can write it: sqlite3 or MCAP storage, zstd
    compression of the whole file or of each message (rosbags' writer), its metadata kept."""
    import yaml
    from rosbags.highlevel import AnyReader
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.rosbag2.enums import CompressionFormat, CompressionMode

    with AnyReader([src]) as reader:
        conns = {c.topic: c for c in reader.connections}
        msgs = [(c.topic, t, bytes(raw)) for c, t, raw in reader.messages()]
    custom = yaml.safe_load((src / "metadata.yaml").read_text())["rosbag2_bagfile_information"]["custom_data"]
    writer = Writer(dst, version=9, storage_plugin=getattr(StoragePlugin, storage))
    if compression:
        writer.set_compression(getattr(CompressionMode, compression), CompressionFormat.ZSTD)
    with writer:
        for key, value in custom.items():
            writer.set_custom_data(key, value)
        out = {topic: writer.add_connection(topic, c.msgtype, typestore=bag_io.M.TYPESTORE) for topic, c in conns.items()}
        for topic, stamp, raw in msgs:
            writer.write(out[topic], stamp, raw)
    return dst


@pytest.mark.parametrize("storage, compression, suffix, kind", [
    ("MCAP", "FILE", ".mcap.zstd", "compressed as a whole (zstd)"), ("SQLITE3", None, ".db3", "a sqlite3 file"),
    ("SQLITE3", "MESSAGE", ".db3", "a sqlite3 file")])
def test_rosbag2s_own_storage_and_compression_damaged_is_the_one_error_and_unchecked_is_said(
        tmp_path, caplog, storage, compression, suffix, kind):
    """A bag of rosbag2's sqlite3 storage or zstd compression is read as the MCAP bag it was made
    from, with a warning that nothing checks it (no CRC this project reads: a flipped byte it decodes
    is read as data). Damaged, it is the one BagReadError naming it: zstd's and sqlite's (apsw's)
    errors had escaped every tool as a traceback, and ``--skip-bad-bags`` did not skip the bag."""
    bag = rosbag2_copy(LOAM, tmp_path / "ok" / LOAM.name, storage, compression)
    (stored,) = [p for p in bag.iterdir() if p.name.endswith(suffix)]
    with caplog.at_level("WARNING", logger=bag_io.log.name):
        assert bag_io.read_episode(bag).forces.tolist() == bag_io.read_episode(LOAM).forces.tolist()
    assert f"{stored.name} is {kind}, which carries no CRCs this project checks" in caplog.text
    original, refused = stored.read_bytes(), 0
    for k in range(1, 200, 8):  # one byte flipped at each of 25 places, one at a time
        data = bytearray(original)
        data[k * len(data) // 200] ^= 0x5A
        stored.write_bytes(bytes(data))
        try:
            bag_io.read_episode(bag)
        except bag_io.BagReadError as err:  # (anything else fails the test)
            assert str(bag) in str(err)
            refused += 1
    assert refused >= 3


@pytest.fixture(scope="module")
def flip_target(tmp_path_factory):
    bag = copy_bag(LOAM, tmp_path_factory.mktemp("flips") / LOAM.name)
    return bag, mcap_of(bag).read_bytes()


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(where=st.floats(0.0, 1.0), length=st.integers(1, 64), byte=st.integers(0, 255))
def test_random_damage_gives_an_episode_or_the_one_error(flip_target, where, length, byte):
    bag, original = flip_target
    data = bytearray(original)
    start = min(int(where * len(data)), len(data) - 1)
    data[start:start + length] = bytes([byte]) * len(data[start:start + length])
    mcap_of(bag).write_bytes(bytes(data))
    try:
        bag_io.read_episode(bag)
    except bag_io.BagReadError as err:
        assert str(bag) in str(err)
    try:
        playback.load_bag(bag)
    except bag_io.BagReadError as err:
        assert str(bag) in str(err)


def test_dataset_refuses_in_workers_or_skips_and_never_caches_a_bad_bag(dirs, tmp_path):
    from pinn_estimator.dataset import load_dataset

    cache = tmp_path / "cache"
    with pytest.raises(bag_io.BagReadError, match=str(dirs["bad"])):
        load_dataset(dirs["with_bad"], cache_dir=cache, workers=2)
    said = []
    ds = load_dataset(dirs["with_bad"], cache_dir=cache, workers=2, skip_bad_bags=True, log=said.append)
    assert len(ds) == 5 and dirs["bad"].name not in ds.names
    assert [s["bag"] for s in ds.skipped] == [str(dirs["bad"])]
    assert "skipped 1 " in said[0] and str(dirs["bad"]) in said[0]
    assert not list(cache.glob("*.npz"))  # a dataset missing a bag is never served from the cache
    with pytest.raises(bag_io.BagReadError, match=str(dirs["bad"])):
        load_dataset(dirs["with_bad"], cache_dir=cache)


# ------------------------------------------------------------------------------ CLIs
def test_pinn_train_refuses_a_damaged_bag_naming_it(damaged, tmp_path):
    out = run("pinn_train", "--data", damaged.parent, "--out", tmp_path / "m.pt", "--quiet", "--no-cache",
              "--workers", "2", *TINY_MODEL)
    assert_refused(out, damaged)
    assert not (tmp_path / "m.pt").exists()


@pytest.fixture(scope="module")
def trained(dirs):
    ckpt = dirs["base"] / "skip.pt"
    out = run("pinn_train", "--data", dirs["with_bad"], "--out", ckpt, "--quiet", "--workers", "2",
              "--skip-bad-bags", *TINY_MODEL)
    return out, ckpt


def test_pinn_train_skip_bad_bags_trains_and_says_1_skipped(trained, dirs):
    out, ckpt = trained
    assert out.returncode == 0, out.stdout + out.stderr
    assert "skipped 1 " in out.stderr and str(dirs["bad"]) in out.stderr
    assert ckpt.is_file()
    assert not list((dirs["with_bad"] / ".insitu_cache").glob("*.npz"))


def test_pinn_eval_refuses_or_skips_a_corrupt_bag(trained, dirs, tmp_path):
    out, ckpt = trained
    assert out.returncode == 0, out.stderr
    common = ["--checkpoint", ckpt, "--data", dirs["with_bad"], "--no-classical", "--quiet", "--workers", "2",
              "--stride", "120", "--forecast-world", "none"]  # the bags are what is tested, not the forecast
    assert_refused(run("pinn_eval", *common, "--out", tmp_path / "a"), dirs["bad"])
    out = run("pinn_eval", *common, "--out", tmp_path / "b", "--skip-bad-bags")
    assert out.returncode == 0, out.stdout + out.stderr
    assert "skipped 1 " in out.stderr


def test_an_episode_of_the_split_skipped_as_unreadable_is_said_so(dirs):
    """A test-split bag damaged after training and skipped: pinn_eval said it was "not in the dataset"
    and to evaluate on the directory the model was trained from, which it was (an outside tester's)."""
    from pinn_estimator.dataset import load_dataset

    ds = load_dataset(dirs["with_bad"], cache=False, skip_bad_bags=True, log=lambda s: None)
    (skipped,) = ds.skipped
    name = Path(skipped["bag"]).name
    with pytest.raises(ValueError, match=rf"1 episode\(s\) of the split were skipped as unreadable .*'{name}': "):
        ds.index([ds.names[0], name])
    with pytest.raises(ValueError, match=r"\(1 more are not in the dataset at "):
        ds.index([name, "elsewhere"])


def test_soil_discrepancy_refuses_a_corrupt_bag_read_in_workers(dirs, tmp_path):
    out = run("soil_discrepancy", dirs["with_bad"], "--out", tmp_path / "disc", "--workers", "2",
              "--no-cache", "--no-plots", "--quiet")
    assert_refused(out, dirs["bad"])


def test_soil_plot_episode_refuses_a_corrupt_bag(dirs, tmp_path):
    out = run("soil_plot_episode", dirs["bad"], "-o", tmp_path / "fig.png", timeout=60)
    assert_refused(out, dirs["bad"])
    assert not (tmp_path / "fig.png").exists()
