"""`make demo` (soil_bringup.demo): a one-episode run over real DDS, its bag directory, its
arguments and its report.

The end-to-end test runs the demo as ``make demo`` does (the launch, through
soil_bringup.launch, of the simulator, controller, estimator and recorder, plus the demo's
in-process monitor) on its own loopback domain, in lockstep and short. The report test uses a
bag written here with known errors.
"""
from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

from soil_bag_tools.bag_io import read_episode, write_episode

from soil_bringup import demo as D
from tests.soil_bringup.estimate_bags import estimate, write_bag_with_estimates

pytestmark = [pytest.mark.live, pytest.mark.timeout(180)]



def _not_strict(constant):
    raise ValueError(f"not strict JSON: {constant}")

def test_bag_dir_is_cleared_only_if_it_is_the_demos_and_holds_just_bags(tmp_path, episode):
    root = tmp_path / "bags"
    assert D.prepare_bag_dir(root) is False and root.is_dir()
    write_episode(root / "old", episode)
    (root / "x.partial").mkdir()
    assert D.prepare_bag_dir(root) is True and [e.name for e in root.iterdir()] == [D.OWNER_MARK]
    # bags another tool recorded (no mark: soil_launch --record, soil_sim_batch) are never deleted
    other = tmp_path / "recorded"
    write_episode(other / "mine", episode)
    with pytest.raises(ValueError, match=r"holds 1 episode bag the demo did not record \(e.g. mine; no \.soil_demo_bags"):
        D.prepare_bag_dir(other)
    assert [e.name for e in other.iterdir()] == ["mine"]
    # the default directory, which each run has always cleared, is cleared without the mark (an older
    # demo's); a link to a bag is removed, not what it links to
    (root / "linked").symlink_to(other / "mine", target_is_directory=True)
    (root / D.OWNER_MARK).unlink()
    assert D.prepare_bag_dir(root, adopt_unmarked=True) is True and (other / "mine").is_dir()
    assert [e.name for e in root.iterdir()] == [D.OWNER_MARK]
    # an empty directory becomes the demo's
    (tmp_path / "empty").mkdir()
    assert D.prepare_bag_dir(tmp_path / "empty") is False and (tmp_path / "empty" / D.OWNER_MARK).is_file()
    (root / "notes.txt").write_text("mine")
    with pytest.raises(ValueError, match="holds 1 entry that is not an episode bag .*notes.txt"):
        D.prepare_bag_dir(root)
    (root / "more.txt").write_text("mine")
    with pytest.raises(ValueError, match="holds 2 entries that are not episode bags"):
        D.prepare_bag_dir(root)
    assert (root / "notes.txt").exists() and (root / "more.txt").exists()


def test_bad_arguments_exit_2_with_the_reason(capsys):
    """Every argument is checked while the arguments are read (``parse_args``), before a node
    starts: the first case through the real command line, the others in this process."""
    res = subprocess.run([sys.executable, "-m", "soil_bringup.demo", "--soils", "Peat"], capture_output=True, text=True,
                         timeout=60)
    assert res.returncode == 2 and "Peat" in res.stderr, res.stderr
    for argv, needle in ((["--duration", "0.5"], "window"),
                         (["--densities", "120"], "[0, 100]"),
                         (["--pacing", "lockstep", "--rate", "2"], "--rate 2 is the real-time factor of --pacing realtime"),
                         (["--rate", "5000"], "--rate 5000 outside [0.01, 1000]"),
                         (["--depth", "0.7"], "--depth: target_depth_m=0.7 outside"),
                         (["--depth", "0.005"], "--depth 0.005: the blade cuts from 0.01 m"),
                         (["--speed", "0"], "--speed: target_speed_m_s=0.0 outside")):
        with pytest.raises(SystemExit) as exit_:
            D.parse_args(argv)  # not main: a case it let through would start a graph here
        err = capsys.readouterr().err
        assert exit_.value.code == 2 and needle in err, (argv, err)


def test_a_checkpoint_the_online_estimator_cannot_run_is_refused_before_the_graph_starts(tmp_path, capsys):
    """A physics-free model (no soil parameters) failed the launch seconds after the graph started;
    a file that is no checkpoint, the same. Both are refused while the arguments are read."""
    import numpy as np

    from pinn_estimator.checkpoint import save_checkpoint
    from pinn_estimator.model import EstimatorNet, ModelConfig

    free = tmp_path / "free.pt"
    net = EstimatorNet(ModelConfig(kind="physics_free", d_model=16, n_heads=2, n_layers=1, ff_dim=32), np.zeros(9), np.ones(9))
    save_checkpoint(free, net, train_config={}, dataset={}, split={}, metrics={}, history={})
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a checkpoint")
    for path, needle in ((free, "kind='physics_free'"), (junk, str(junk))):
        with pytest.raises(SystemExit) as exit_:
            D.parse_args(["--checkpoint", str(path)])
        err = capsys.readouterr().err
        assert exit_.value.code == 2 and f"--checkpoint {path}" in err and needle in err, err
    # without one, the world's shipped model, named: the live estimates and the forecast beside them
    # used the default world's label and model while the fee-world launch ran the fee world's
    from pinn_estimator.shipped import shipped_checkpoint

    assert D.parse_args(["--world-mode", "fee"]).checkpoint == shipped_checkpoint("fee")
    assert D.parse_args([]).checkpoint == shipped_checkpoint("default")


def test_the_depth_and_speed_go_to_the_simulator_and_the_forecast_goes_around_the_depth():
    """Every episode cut at 0.2 m: a user could not see the estimator, or the planner's question,
    at another depth without building the launch by hand."""
    from soil_bringup.demo_forecast import OTHER_DEPTHS_M, other_depths

    assert OTHER_DEPTHS_M == (0.1, 0.25) and other_depths(0.2) == OTHER_DEPTHS_M
    assert other_depths(0.15) == (0.075, 0.188)
    assert other_depths(0.3) == (0.15,)  # 0.375 m is beyond the lift's reach: kept at 0.3 m, the live depth
    assert other_depths(0.4) == (0.15,)  # a target beyond the reach is cut at about the reach first
    assert other_depths(0.06) == (0.05, 0.075)
    args = D.parse_args(["--depth", "0.15", "--speed", "0.4"])
    sim = D.launch_arguments(args, 100.0).sim_param
    assert "target_depth_m:=0.15" in sim and "target_speed_m_s:=0.4" in sim, sim
    assert not any(p.startswith("settle_s:=") for p in sim), sim  # real time: the simulator's own pause
    # lockstep: each episode waits for the estimator, which trails the simulator, to show its last lines
    sim = D.launch_arguments(D.parse_args(["--pacing", "lockstep"]), 100.0).sim_param
    assert f"settle_s:={D.LOCKSTEP_SETTLE_S!r}" in sim, sim


def test_a_fusion_config_of_ones_own_goes_to_the_estimator_and_another_worlds_is_refused(tmp_path, capsys):
    """The main job ran only the shipped posterior config: a user's own (pinn_fusion_calibrate --out)
    could go into soil_launch and soil_cut_report but not here (an outside tester's). It goes to the
    live estimator (and the forecast beside it); another world's, or no file, is refused while the
    arguments are read."""
    from pinn_estimator.fusion_calibration import config_path
    from pinn_estimator.fusion_config import FusionConfig

    mine = tmp_path / "mine.json"
    FusionConfig.load(config_path("default")).save(mine)
    args = D.parse_args(["--fusion-config", str(mine)])
    assert args.fusion_config == str(mine.resolve())
    assert f"fusion_config:={mine.resolve()}" in D.launch_arguments(args, 100.0).estimator_param
    assert "fusion_config:=" not in " ".join(D.launch_arguments(D.parse_args([]), 100.0).estimator_param)
    for argv, needle in ((["--fusion-config", str(config_path("fee"))], "calibrated in the fee world, not the default"),
                         (["--fusion-config", str(tmp_path / "none.json")], "none.json")):
        with pytest.raises(SystemExit) as exit_:
            D.parse_args(argv)
        err = capsys.readouterr().err
        assert exit_.value.code == 2 and "--fusion-config" in err and needle in err, err


SILT_YAML = "name: Silt\nphi_deg: [24, 32]\ncohesion_pa: [2000, 6000]\nunit_weight_n_m3: [16500, 19500]\n"


def test_a_soil_file_goes_to_the_simulator_and_its_soils_may_be_named(tmp_path, capsys):
    """A user's own soils: before, the demo knew the catalogue's only (soil_launch and soil_cut_report
    took a soils file, the main job did not)."""
    soils = tmp_path / "soils.yaml"
    soils.write_text(SILT_YAML)
    with pytest.raises(SystemExit):
        D.parse_args(["--soils", "Silt"])  # not a catalogue soil
    assert "soil='Silt' is unknown" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        D.parse_args(["--soil-file", str(tmp_path / "none.yaml")])
    assert "--soil-file" in capsys.readouterr().err
    args = D.parse_args(["--soil-file", str(soils), "--soils", "silt,Clay"])
    assert args.soils == ["Silt", "Clay"] and set(args.custom_soils) == {"Silt"}
    assert f"soil_file:={soils.resolve()}" in D.launch_arguments(args, 100.0).sim_param
    assert not any(p.startswith("soil_file:=") for p in D.launch_arguments(D.parse_args([]), 100.0).sim_param)


def test_demo_runs_one_episode_over_dds_and_writes_the_summary(tmp_path):
    """One live episode of a soil of the user's own (simulated, scored and forecast from its file)."""
    from tests.ros_probe import next_domain_id

    out, bags = tmp_path / "out", tmp_path / "bags"
    soils = tmp_path / "soils.yaml"
    soils.write_text(SILT_YAML)
    argv = [sys.executable, "-m", "soil_bringup.demo", "--pacing", "lockstep", "--soils", "Silt",
            "--soil-file", str(soils), "--densities", "20", "--duration", "3.0", "--out", str(out), "--bags", str(bags),
            "--domain-id", str(next_domain_id()), "--depth", "0.15"]
    res = subprocess.run(argv, capture_output=True, text=True, timeout=120)
    log = out / "launch.log"
    context = f"stdout:\n{res.stdout}\nstderr:\n{res.stderr}\nlaunch log tail:\n" + (
        "\n".join(log.read_text().splitlines()[-30:]) if log.exists() else "(none)")
    assert res.returncode == 0, context

    summary = json.loads((out / "summary.json").read_text(), parse_constant=_not_strict)  # strict JSON
    assert len(summary["episodes"]) == 1, context
    ep = summary["episodes"][0]
    assert ep["soil"] == "Silt" and ep["relative_density_pct"] == 20.0 and ep["ticks"] == 180
    assert ep["valid_estimates"] > 0 and summary["overall"]["valid_estimates"] == ep["valid_estimates"]
    errors = [*ep["force"].values(), *ep["params"].values()]
    assert all(math.isfinite(v) for v in errors), ep
    assert (out / "summary.md").read_text().count("| Silt |") == 3  # errors, mean estimates, the fused soil
    assert "of 3 s at 0.15 m and 0.5 m/s" in (out / "summary.md").read_text()
    # the planner's question: from the live episode (0.15 m) to the simulator cutting the same soil at half
    # and 1.25 times that depth
    forecast = summary["forecast"]
    assert forecast["live_episodes"] == 1 and forecast["simulated_episodes"] == 2 and forecast["pairs"] >= 1, forecast
    assert forecast["depths_m"] == [0.075, 0.188] and summary["run"]["target_depth_m"] == 0.15, forecast
    # of the 2 possible forecasts, those not made are said with why (a summary had read "10 forecasts" of 12)
    assert forecast["pairs"] == 2 or forecast["no_steady_part"] + forecast["same_depth_pairs"] > 0, forecast
    assert (forecast["pairs"] == 2) == ("Not paired" not in (out / "summary.md").read_text()), forecast
    for name in ("fused", "pinn", "true_fee", "naive_same_force"):
        assert math.isfinite(forecast["forecast"][name]["x"]["all"]["mean_abs_pct"]), (name, forecast)
    assert forecast["physics"]["fused"] == [["form:-qnq*tanhvx0.1", 0.756]], "the live estimator's posterior physics"
    # every pair in one group of where the forecast law was calibrated: a 7.5 cm cut and the live cut's 0.5 m/s are not
    strata = forecast["calibration_strata"]["posteriors"]["fused"]
    assert sum(group["pairs"] for group in strata.values()) == forecast["pairs"] and not strata["calibrated"]["pairs"]
    assert "where its forecast law was calibrated" in (out / "summary.md").read_text()
    assert "The planner's question" in (out / "summary.md").read_text() and "The planner's question" in res.stdout
    fused = ep["fused_end"]
    assert fused["stretches"] >= 1 and all(math.isfinite(fused[p]["std_deg" if p != "c" else "std_kPa"]) for p in ("phi", "c", "delta"))
    png = out / "online_estimates.png"
    assert png.is_file() and png.stat().st_size > 10_000

    recorded = read_episode(Path(ep["bag"]))
    assert len(recorded) == 180 and recorded.meta.soil == "Silt" and recorded.meta.target_depth_m == 0.15
    # the live part: an episode header, the window filling, one line per simulated second, all <= 120 columns
    lines = res.stdout.splitlines()
    assert any(line.startswith("=== episode 1/1: Silt, I_d 20 %") for line in lines), context
    assert any("filling window" in line for line in lines), context
    assert sum(line.startswith("Silt    20%") for line in lines) == 3, context
    assert all(len(line) <= 120 for line in lines if line.startswith(("Silt", "soil", " "))), context
    assert "bags/" in res.stdout and "online_estimates.png" in res.stdout


def test_report_writes_the_summary_and_fails_on_a_missing_episode(tmp_path, episode, capsys):
    import time

    out, root = tmp_path / "out", tmp_path / "bags"
    args = D.parse_args(["--soils", "Clay", "Sand", "--densities", "20", "--out", str(out), "--bags", str(root)])
    root.mkdir()
    estimates = [(int(s), estimate(episode, k, k >= 59, min(k + 1, 60))) for k, s in enumerate(episode.stamps_ns)]
    write_bag_with_estimates(root / episode.meta.name, episode, estimates)
    pairs = [("Clay", 20.0), ("Sand", 20.0)]
    assert D.report(args, pairs, None, time.monotonic(), 5.0, out / "launch.log") == D.EXIT_FAILED
    captured = capsys.readouterr()
    assert "no usable bag for 1 of 2 planned episode(s): Sand I_d 20 %" in captured.err
    summary = json.loads((out / "summary.json").read_text(), parse_constant=_not_strict)  # strict JSON
    assert [e["soil"] for e in summary["episodes"]] == ["Clay"] and summary["run"]["errors"]
    assert summary["episodes"][0]["params"]["phi_mae_deg"] == pytest.approx(2.0)
    assert (out / "online_estimates.png").stat().st_size > 5_000 and "| **overall** |" in (out / "summary.md").read_text()
    assert "overall" in captured.out and "valid estimates" in captured.out


def test_a_run_whose_commands_came_late_says_so(tmp_path, episode, capsys):
    """--rate 1000: 119 of 120 ticks' commands came late, and the demo printed its usual table (an
    outside tester's): the figures are a lagging controller's, and the run now says so."""
    import time
    from types import SimpleNamespace

    from soil_bringup.monitor import LiveEpisode

    out, root = tmp_path / "out", tmp_path / "bags"
    args = D.parse_args(["--soils", "Clay", "--densities", "20", "--out", str(out), "--bags", str(root), "--rate", "50",
                         "--no-forecast"])
    root.mkdir()
    estimates = [(int(s), estimate(episode, k, k >= 59, min(k + 1, 60))) for k, s in enumerate(episode.stamps_ns)]
    write_bag_with_estimates(root / episode.meta.name, episode, estimates)
    lagging = LiveEpisode(0, episode.meta.name, "Clay", 20.0, int(episode.stamps_ns[0]), len(episode), 0.0, wall_end=1.0,
                          reason="completed", ticks=len(episode), late_commands=len(episode) - 1)
    monitor = SimpleNamespace(episodes=[lagging], problems={})
    assert D.report(args, [("Clay", 20.0)], monitor, time.monotonic(), 5.0, out / "launch.log") == 0
    err = capsys.readouterr().err
    assert f"the commands of {len(episode) - 1} of its {len(episode)} ticks came after their real-time deadline" in err
    assert "--rate 50" in err
    summary = json.loads((out / "summary.json").read_text(), parse_constant=lambda c: None)
    assert summary["run"]["warnings"] and summary["episodes"][0]["live"]["late_commands"] == len(episode) - 1
