"""soil_sim_batch datasets: bags equal the simulated arrays, bad input is refused cleanly,
sample bags are valid rosbag2/MCAP, and the Fig.-3 plot renders."""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader

from soil_bag_tools.bag_io import find_episode_bags, read_dataset, read_episode
from soil_msgs_py.topics import EPISODE_TOPICS
from soil_sim_node import batch
from soil_sim_node.plot import main as plot_main
from soil_sim_node.rollout import run_episodes
from soil_sim_node.simulator import SimConfig

REPO = Path(__file__).resolve().parents[2]
SAMPLES = REPO / "bags" / "samples"
sys.path.insert(0, str(Path(__file__).resolve().parent))


def nan_plugin(state):
    """A broken user plugin: NaN force."""
    return np.full_like(state.v_x, np.nan), 0.0


SMALL = ["--soils", "Clay,Sand", "--relative-densities", "20,80", "--speeds", "0.5", "--depths", "0.1",
         "--seeds", "1", "--duration", "1.0", "--quiet"]


@pytest.mark.parametrize("mode", ["fee", "default"])
def test_generated_bags_read_back_to_the_simulated_arrays(tmp_path, mode):
    out = tmp_path / mode
    assert batch.main(["--mode", mode, "--out", str(out), "--workers", "2", *SMALL]) == 0
    bags = find_episode_bags(out)
    assert len(bags) == 4
    summary = json.loads((out / "dataset.json").read_text())
    assert summary["episodes"] == 4 and summary["mode"] == mode
    # the same episodes simulated directly, in one batch, must equal the bags bit-for-bit
    specs = batch.grid_specs(["Clay", "Sand"], [20.0, 80.0], [0.5], [0.1], 1, 0, 1.0)
    direct = {ep.meta.name: ep for ep in run_episodes(SimConfig(world_mode=mode), specs)}
    for ep in read_dataset(out):
        ref = direct[ep.meta.name]
        assert ep.meta == ref.meta
        for name in ("stamps_ns", "observations", "forces", "known", "truth", "extras"):
            assert np.array_equal(getattr(ep, name), getattr(ref, name)), (ep.meta.name, name)
        assert ep.meta.world_mode == mode and ep.meta.duration_s == 1.0


def test_default_grid_has_the_paper_sizes():
    n_default = len(batch.grid_specs(["Clay", "Loam", "Sand", "Gravel"], batch.DEFAULT_RELATIVE_DENSITIES,
                                     batch.GRID_SPEEDS["default"], batch.GRID_DEPTHS, batch.DEFAULT_SEEDS, 0, 10.0))
    n_fee = len(batch.grid_specs(["Clay", "Loam", "Sand", "Gravel"], batch.DEFAULT_RELATIVE_DENSITIES,
                                 batch.GRID_SPEEDS["fee"], batch.GRID_DEPTHS, batch.DEFAULT_SEEDS, 0, 10.0))
    assert (n_default, n_fee) == (576, 432)
    specs = batch.grid_specs(["Clay"], [0, 100], [0.3, 1.0], [0.05, 0.3], 2, 10, 10.0)
    assert len({s.seed for s in specs}) == len(specs)  # every episode its own seed


@pytest.mark.parametrize(
    "args, needle",
    [
        (["--soils", "Mud"], "soil='Mud'"),
        (["--relative-densities", "101"], "relative_density_pct=101"),
        (["--relative-densities", "-5"], "relative_density_pct=-5"),
        (["--depths", "-0.1"], "target_depth_m=-0.1"),
        (["--speeds", "0"], "target_speed_m_s=0"),
        (["--plugin", "no_such_module:force"], "no_such_module"),
        (["--plugin", "test_dataset:nan_plugin"], "nan_plugin"),
        (["--effects-off", "gravity"], "gravity"),
    ],
)
def test_bad_input_is_refused_naming_the_field_and_leaves_no_complete_bag(tmp_path, capsys, args, needle):
    out = tmp_path / "ds"
    base = ["--mode", "default", "--out", str(out), "--workers", "1", "--duration", "1.0", "--quiet",
            "--soils", "Clay", "--relative-densities", "50", "--speeds", "0.5", "--depths", "0.1", "--seeds", "1"]
    # later flags override earlier ones in argparse
    assert batch.main(base + args) == 2
    err = capsys.readouterr().err
    assert needle in err, err
    assert not out.exists() or find_episode_bags(out) == []
    assert not out.exists() or not any(p.name.endswith(".partial") for p in out.iterdir())


def test_an_empty_grid_axis_is_refused_and_the_dataset_record_is_kept(tmp_path, capsys):
    """'--soils ,' (or an empty --speeds, --depths, --relative-densities) made a plan of no episode:
    exit 0, "0 fee episodes", and the directory's dataset.json replaced by one of 0 episodes. And
    '--soils ""' silently meant all four soils. Each is refused naming the flag, the record kept."""
    out = tmp_path / "ds"
    base = ["--mode", "fee", "--out", str(out), "--workers", "1", "--duration", "1.0", "--quiet",
            "--soils", "Clay", "--relative-densities", "50", "--speeds", "0.5", "--depths", "0.1", "--seeds", "1"]
    assert batch.main(base) == 0
    record = (out / "dataset.json").read_text()
    capsys.readouterr()
    for flag in ("--soils", "--speeds", "--depths", "--relative-densities"):
        for empty in (",", ""):
            assert batch.main([*base, flag, empty]) == 2, (flag, empty)
            err = capsys.readouterr().err
            assert f"{flag}={empty!r}" in err and ("no soil" in err or "no value" in err), err
    assert (out / "dataset.json").read_text() == record
    # generate itself refuses an empty plan before it touches the directory
    plan = batch.plan_from_args(batch.parse_args(base))
    plan.specs = []
    with pytest.raises(ValueError, match="has no episode"):
        batch.generate(plan, workers=1, progress=False)
    assert (out / "dataset.json").read_text() == record


def test_a_soil_file_with_a_huge_integer_is_refused_naming_the_field(tmp_path, capsys):
    """A 400-digit integer in the soils YAML ended soil_sim_batch in an OverflowError traceback."""
    soil_file = tmp_path / "soils.yaml"
    soil_file.write_text(f"name: Big\nphi_deg: [30, 40]\ncohesion_pa: [1000, {10**400}]\nunit_weight_n_m3: [16000, 20000]\n")
    out = tmp_path / "ds"
    assert batch.main(["--mode", "fee", "--out", str(out), "--soil-file", str(soil_file), "--soils", "Big", "--seeds", "1",
                       "--relative-densities", "50", "--speeds", "0.5", "--depths", "0.1", "--duration", "1.0", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "cohesion_pa=[1000, 1000" in err and len(err) < 300 and not out.exists(), err


def test_custom_soil_from_yaml(tmp_path):
    soil_file = tmp_path / "soils.yaml"
    soil_file.write_text(yaml.safe_dump({"name": "SiltyClay", "phi_deg": [20, 30], "cohesion_pa": [3000, 9000],
                                         "unit_weight_n_m3": [16000, 20000]}))
    out = tmp_path / "custom"
    assert batch.main(["--mode", "fee", "--out", str(out), "--soil-file", str(soil_file), "--soils", "SiltyClay",
                       "--relative-densities", "50", "--speeds", "0.5", "--depths", "0.1", "--seeds", "1",
                       "--duration", "1.0", "--workers", "1", "--quiet"]) == 0
    (ep,) = read_dataset(out)
    assert ep.meta.soil == "SiltyClay"
    phi = ep.truth[0, 0]
    assert phi == pytest.approx(np.deg2rad(25.0))


@pytest.mark.parametrize("bag", sorted(p.name for p in SAMPLES.iterdir() if p.is_dir()))
def test_sample_bags_are_valid_rosbag2_mcap(bag):
    path = SAMPLES / bag
    meta = yaml.safe_load((path / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["version"] == 9 and meta["storage_identifier"] == "mcap"
    counts = {t["topic_metadata"]["name"]: t["message_count"] for t in meta["topics_with_message_count"]}
    assert set(counts) == {t.name for t in EPISODE_TOPICS}
    assert set(counts.values()) == {600}
    with open(path / meta["relative_file_paths"][0], "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    for channel in summary.channels.values():
        schema = summary.schemas[channel.schema_id]
        assert schema.encoding == "ros2msg" and schema.data
        assert channel.message_encoding == "cdr"
    ep = read_episode(path)
    assert ep.meta.name == bag and len(ep) == 600
    assert np.all(np.isfinite(ep.forces))


def test_fig3_plot_renders_png(tmp_path):
    out = tmp_path / "fig3.png"
    assert plot_main([str(SAMPLES / "default_loam_id060_v0.50_d0.200_s7"), "-o", str(out)]) == 0
    data = out.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 20_000
    assert plot_main([str(tmp_path / "missing_bag")]) == 2


def test_the_readers_warnings_are_said_again_when_the_cache_answers(tmp_path):
    """A flipped force sensor was said by the first reader of a folder only: the dataset cache then
    answered without it, and pinn_train trained on the flipped bags in silence (an outside
    tester's). The warnings are kept with the cache and said, each kind once, on every load."""
    from dataclasses import replace

    from pinn_estimator.dataset import load_dataset
    from soil_bag_tools.bag_io import write_episode
    from soil_sim_node.simulator import EpisodeSpec

    # (another depth and length each: their counts of ticks differ, and are one kind of warning all the same)
    specs = [EpisodeSpec("Clay", 40.0, 0.5, depth, seed=k, duration_s=d) for k, (depth, d) in enumerate(((0.1, 3.0), (0.15, 4.0)))]
    for ep in (run_episodes(SimConfig(world_mode="fee"), [spec])[0] for spec in specs):
        write_episode(tmp_path / "flipped" / ep.meta.name, replace(ep, forces=-ep.forces))
    for _ in range(2):  # the bags, then the cache
        said = []
        load_dataset(tmp_path / "flipped", log=said.append)
        (line,) = [s for s in said if "f_x < 0" in s]
        assert "a sensor of the other sign?" in line and "(and 1 other bag(s) alike)" in line, said


def test_a_bag_with_a_value_no_sensor_gives_is_refused_naming_it_or_skipped(tmp_path, monkeypatch):
    """One tick of v_z = 1e12 in a training bag (finite: the readers took it) set that channel's
    normalisation std to 1.7e10, erasing it from every window of the model (an outside tester's).
    The readers refuse what the live nodes drop, beyond ±PLAUSIBLE_ABS_LIMIT, naming bag, field,
    value and tick; ``skip_bad_bags`` leaves the bag out. (Our writer refuses to write such a bag:
    it is written here past that check, as another tool might.)"""
    from dataclasses import replace

    from pinn_estimator import dataset
    from pinn_estimator.dataset import load_dataset
    from soil_bag_tools import bag_io
    from soil_bag_tools.bag_io import BagReadError, write_episode
    from soil_msgs_py.params import OBSERVATION_FIELDS
    from soil_sim_node.simulator import EpisodeSpec

    good, bad = run_episodes(SimConfig(world_mode="fee"), [EpisodeSpec("Clay", 40.0, 0.5, d, seed=1, duration_s=2.0)
                                                           for d in (0.1, 0.15)])
    obs = bad.observations.copy()
    col = OBSERVATION_FIELDS.index("v_z_b")
    obs[70, col] = 1e12
    write_episode(tmp_path / "d" / good.meta.name, good)
    monkeypatch.setattr(bag_io, "_check_arrays", lambda ep, skip=(): None)
    write_episode(tmp_path / "d" / bad.meta.name, replace(bad, observations=obs))
    monkeypatch.undo()
    with pytest.raises(BagReadError, match=rf"{bad.meta.name}.*'v_z_b' is 1000000000000.0 at tick 70; .* beyond ±1e\+09"):
        load_dataset(tmp_path / "d", cache=False)
    # a cache written before the readers refused such values answers no more: the bags are read again
    monkeypatch.setattr(dataset, "_check_plausible", lambda *a: None)
    assert len(load_dataset(tmp_path / "d")) == 2  # (the cache written, the 1e12 in it)
    monkeypatch.undo()
    with pytest.raises(BagReadError, match="'v_z_b' is 1000000000000.0 at tick 70"):
        load_dataset(tmp_path / "d")
    kept = load_dataset(tmp_path / "d", cache=False, skip_bad_bags=True, log=lambda s: None)
    (skipped,) = kept.skipped
    assert bad.meta.name in str(skipped) and "'v_z_b' is 1000000000000.0" in str(skipped), skipped
    assert kept.names == [good.meta.name], kept.names


def test_a_cache_that_answers_says_ray_was_not_contacted_and_too_short_episodes_are_warned_of(tmp_path, capsys):
    """``--ray ADDRESS`` with a cached dataset trained and exited 0 whatever the address (a wrong one
    surfaced only once the bags changed), and ``--duration 0.5`` wrote bags every reader refuses,
    in silence (an outside tester's)."""
    from pinn_estimator.dataset import load_dataset

    assert batch.main(["--mode", "fee", "--soils", "Clay", "--relative-densities", "20", "--speeds", "0.5",
                       "--depths", "0.1,0.15", "--seeds", "1", "--duration", "2", "--out", str(tmp_path / "d"),
                       "--quiet"]) == 0
    assert "warning" not in capsys.readouterr().err
    load_dataset(tmp_path / "d")  # (the cache written)
    said = []
    ds = load_dataset(tmp_path / "d", ray_address="127.0.0.1:1", log=said.append)  # nothing listens there
    assert len(ds) == 2 and any("--ray 127.0.0.1:1 not contacted" in s for s in said), said
    assert batch.main(["--mode", "fee", "--soils", "Clay", "--relative-densities", "20", "--speeds", "0.5",
                       "--depths", "0.1", "--seeds", "1", "--duration", "0.5", "--out", str(tmp_path / "short"),
                       "--quiet"]) == 0
    assert "fewer ticks than one 60-sample window" in capsys.readouterr().err


def test_bags_written_again_are_said_to_hold_the_trained_episodes_not_to_differ(tmp_path):
    """The fingerprint hashes the bags' bytes: bags written again from the same seeds by a later
    recorder differ in bytes, not in data, and the shipped models' reports said their own
    training bags "differ". The same episodes by name and ticks are said as such; others differ."""
    from pinn_estimator.dataset import load_dataset
    from pinn_estimator.evaluate import differ_from_training

    ds = load_dataset(SAMPLES, workers=1, progress=False, cache_dir=tmp_path)
    names = list(ds.names)
    trained = {"dataset": {"fingerprint": "0" * 64, "episodes": len(ds), "ticks": int(ds.offsets[-1])},
               "split": {"train": names[:1], "val": names[1:2], "test": names[2:]}}
    said = differ_from_training(ds, trained)
    assert "not byte for byte" in said and f"hold its {len(ds)} episodes by name" in said, said
    for other in ({"dataset": {**trained["dataset"], "ticks": 1}},
                  {"split": {**trained["split"], "test": ["another_episode"]}}):
        assert "differ from those the model was trained on" in differ_from_training(ds, {**trained, **other})
