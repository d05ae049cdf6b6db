"""soil_sim_batch's engine choice (DatasetPlan.engine, --engine): passed into the SimConfig,
refused before any file is written when unknown. Fast: no episode is simulated."""
from __future__ import annotations

import pytest

from soil_msgs_py import cli_numbers
from soil_sim_node import batch
from soil_sim_node.batch import DatasetPlan, generate, parse_args, plan_from_args
from soil_sim_node.effects import effects_for_mode
from soil_sim_node.simulator import ENGINES, EpisodeSpec


ONE_EPISODE = ["--mode", "fee", "--soils", "Clay", "--relative-densities", "50", "--speeds", "0.5", "--depths", "0.2",
               "--seeds", "1", "--duration", "0.5", "--quiet"]  # soil_sim_batch arguments of one short episode

def test_batch_plan_engine_defaults_to_compiled_and_reaches_the_sim_config(tmp_path):
    spec = EpisodeSpec("Loam", 60.0, 0.5, 0.2, seed=0, duration_s=1.0)
    assert DatasetPlan("fee", tmp_path, [spec], effects_for_mode("fee")).config().engine == "compiled"
    for engine in ENGINES:
        assert DatasetPlan("fee", tmp_path, [spec], effects_for_mode("fee"), engine=engine).config().engine == engine
    assert plan_from_args(parse_args(["--engine", "reference", "--out", str(tmp_path)])).engine == "reference"
    with pytest.raises(SystemExit):
        parse_args(["--engine", "turbo"])


def test_batch_unknown_engine_is_refused_before_anything_is_written(tmp_path):
    spec = EpisodeSpec("Loam", 60.0, 0.5, 0.2, seed=0, duration_s=1.0)
    out = tmp_path / "never"
    with pytest.raises(ValueError, match="engine='turbo'"):
        generate(DatasetPlan("fee", out, [spec], effects_for_mode("fee"), engine="turbo"), workers=1, progress=False)
    assert not out.exists()


def test_a_plugin_parameter_its_function_does_not_take_is_refused_before_anything_is_written(tmp_path, capsys):
    """A misspelt plugin parameter ('fx' for 'f_x') was refused only when the first episode ran,
    leaving an empty --out folder behind (an outside reader's run); now when the plugin loads."""
    out = tmp_path / "never"
    assert batch.main([*ONE_EPISODE, "--plugin", "tests.sim_plugins:in_soil_constant_drag fx=3", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "plugin='tests.sim_plugins:in_soil_constant_drag' cannot be called with the parameters ['fx']" in err, err
    assert not out.exists()
    assert batch.main([*ONE_EPISODE, "--plugin", "tests.sim_plugins:in_soil_constant_drag f_x=3", "--out", str(out)]) == 0


def test_more_workers_than_the_machine_can_use_are_refused_before_any_process_starts(tmp_path, capsys):
    """--workers 100000 for one episode forked 100000 processes (the pool was not capped by the
    work) until the machine stopped; now refused, naming the option, and a pool never has more
    processes than chunks of work (16 workers for one episode: one process's work, done)."""
    most = cli_numbers.local_limit()
    assert batch.main([*ONE_EPISODE, "--workers", str(most + 1), "--out", str(tmp_path / "many")]) == 2
    assert f"--workers={most + 1} is more than this machine can use: at most {most}" in capsys.readouterr().err
    assert not (tmp_path / "many").exists()
    assert batch.main([*ONE_EPISODE, "--workers", str(most), "--out", str(tmp_path / "one")]) == 0
    assert len(list((tmp_path / "one").glob("*/metadata.yaml"))) == 1


def test_a_plugin_that_never_acts_is_said_and_its_peak_force_recorded(tmp_path, capsys):
    """surcharge_drag (F_x = k Q) in the fee world, where no pile stands before the blade (Q = 0),
    was accepted without a word, and the discrepancy workflow's check then called the effect
    "missed". The batch records each plugin's largest force and warns of one that never acted."""
    import json

    idle = "soil_physics.force_terms:plugin term=surcharge_drag k=0.3"
    acting = "tests.sim_plugins:in_soil_constant_drag f_x=300"
    out = tmp_path / "fee"
    assert batch.main([*ONE_EPISODE, "--workers", "1", "--plugin", idle, "--plugin", acting, "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert f"plugin {idle!r} returned 0 N in every substep of every episode: it never acted" in err, err
    assert acting not in err, err
    peaks = json.loads((out / "dataset.json").read_text())["plugin_peak_force_n"]
    assert peaks[idle] == 0.0 and peaks[acting] == 300.0, peaks


def test_seeds_that_give_identical_episodes_are_said(tmp_path, capsys):
    """Without noise and particles nothing draws on an episode's seed: --seeds 2 in the fee world
    wrote two identical copies of each episode without a word. Said; not where the seed matters."""
    import numpy as np

    from soil_bag_tools.bag_io import find_episode_bags, read_episode

    argv = [*ONE_EPISODE, "--seeds", "2", "--duration", "2", "--workers", "1"]
    assert batch.main([*argv, "--out", str(tmp_path / "fee")]) == 0
    err = capsys.readouterr().err
    assert "--seeds 2: without noise or particles (the fee world) nothing draws on an episode's seed" in err, err
    a, b = (read_episode(p) for p in find_episode_bags(tmp_path / "fee"))
    assert a.meta.seed != b.meta.seed and np.array_equal(a.forces, b.forces)  # what the note says
    default = [*argv, "--mode", "default", "--out"]
    assert batch.main([*default, str(tmp_path / "default")]) == 0
    assert "nothing draws on" not in capsys.readouterr().err
    assert batch.main([*default, str(tmp_path / "still"), "--effects-off", "noise,particles"]) == 0
    assert "(the default world with --effects-off) nothing draws on" in capsys.readouterr().err
