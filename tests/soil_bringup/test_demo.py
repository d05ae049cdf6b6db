"""`make demo` (soil_bringup.demo): a one-episode run over real DDS, and the bag scoring.

The end-to-end test runs the demo as ``make demo`` does (a subprocess starting soil_launch
with the estimator and the recorder, plus its in-process monitor) on its own loopback
domain, in lockstep and short. The scoring tests use a bag written here with known errors.
"""
from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from soil_msgs_py import messages as M
from soil_msgs_py import topics as T
from soil_bag_tools.bag_io import META_KEY, read_episode, write_episode
from soil_msgs_py.params import DEG, GROUND_TRUTH_PARAMS

from soil_bringup import demo as D

pytestmark = pytest.mark.timeout(180)

EST = {n: i for i, n in enumerate(T.ESTIMATE_FIELDS)}
TRUTH = {n: i for i, n in enumerate(GROUND_TRUTH_PARAMS)}


@pytest.fixture(scope="module")
def episode():
    """A real 2 s closed-loop episode (120 ticks) from the batch simulator."""
    from soil_sim_node.rollout import run_episodes
    from soil_sim_node.simulator import EpisodeSpec, SimConfig

    return run_episodes(SimConfig(world_mode="default"), [EpisodeSpec("Clay", 20.0, 0.5, 0.2, seed=3, duration_s=2.0)])[0]


def _estimate(ep, row: int, valid: bool, window: int, offsets=(2 * DEG, 500.0, -1 * DEG, 3 * DEG), f_off=(100.0, -200.0)):
    values = np.zeros(len(T.ESTIMATE_FIELDS))
    values[EST["window_samples"]] = window
    if valid:
        for name, off in zip(("phi", "c", "delta", "beta"), offsets):
            values[EST[name]] = ep.truth[row, TRUTH[name]] + off
        values[EST["f_x_hat"]] = ep.forces[row, 0] + f_off[0]
        values[EST["f_z_hat"]] = ep.forces[row, 1] + f_off[1]
        values[EST["valid"]] = 1.0
    return values


def _write_bag_with_estimates(path: Path, ep, estimates: list[tuple[int, np.ndarray]]) -> Path:
    """An episode bag like the recorder's: the episode topics plus /soil/estimate."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        writer.set_custom_data(META_KEY, ep.meta.to_json())
        conns = {t.name: writer.add_connection(t.name, t.msgtype, typestore=M.TYPESTORE)
                 for t in (*T.EPISODE_TOPICS, T.ESTIMATE)}
        for topic, stamp, raw in M.serialize_episode(ep, M.TYPESTORE):
            writer.write(conns[topic], stamp, raw)
        for stamp, values in estimates:
            msg = M.make_labelled(M.TYPESTORE, stamp, T.ESTIMATE_FIELDS, values)
            writer.write(conns[T.ESTIMATE.name], stamp, M.TYPESTORE.serialize_cdr(msg, T.ESTIMATE.msgtype))
    return path


def test_summarise_matches_valid_estimates_to_ticks_and_scores_them(tmp_path, episode):
    ep = episode
    stamps = ep.stamps_ns
    estimates = [(int(stamps[k]), _estimate(ep, k, False, k + 1)) for k in range(59)]  # window filling
    valid_rows = [k for k in range(59, len(ep)) if not 80 <= k < 90]  # 10 ticks without an estimate
    estimates += [(int(stamps[k]), _estimate(ep, k, True, 60)) for k in valid_rows]
    wild = _estimate(ep, 100, True, 60, offsets=(40 * DEG, 9e3, 40 * DEG, 40 * DEG), f_off=(9e3, 9e3))
    estimates.append((int(stamps[100]), wild))  # a second estimate for tick 100: the first one counts
    estimates.append((int(stamps[100]) + 1, wild))  # not on a tick: ignored
    bag = _write_bag_with_estimates(tmp_path / ep.meta.name, ep, estimates)

    s = D.summarise(bag)
    assert s["ticks"] == len(ep) == 120 and s["estimates"] == len(estimates)
    assert s["valid_estimates"] == len(valid_rows) == 51
    assert s["duplicate_valid"] == 1 and s["valid_off_tick"] == 1
    assert s["pct_ticks_valid"] == pytest.approx(100 * 51 / 120)
    assert s["pct_full_window_ticks_valid"] == pytest.approx(100 * 51 / 61)
    assert s["first_valid_s"] == pytest.approx(59 / 60, abs=1e-6)
    assert s["soil"] == "Clay" and s["relative_density_pct"] == 20.0
    p, f = s["params"], s["force"]
    assert p["phi_mae_deg"] == pytest.approx(2.0) and p["c_mae_kPa"] == pytest.approx(0.5)
    assert p["delta_mae_deg"] == pytest.approx(1.0) and p["beta_mae_deg"] == pytest.approx(3.0)
    assert f["mae_x_n"] == pytest.approx(100.0) and f["mae_z_n"] == pytest.approx(200.0)
    assert f["windows"] == 51
    rows = np.array(valid_rows)
    assert f["mae_x_pct_measured"] == pytest.approx(100 * 100.0 / np.abs(ep.forces[rows, 0]).mean())
    assert s["truth_mean"]["phi_deg"] == pytest.approx(ep.truth[rows, TRUTH["phi"]].mean() / DEG)
    assert s["estimate_mean"]["phi_deg"] == pytest.approx(s["truth_mean"]["phi_deg"] + 2.0)

    score = D.score_episode(bag)
    total = D.overall([score, score])
    assert total["valid_estimates"] == 102 and total["ticks"] == 240
    assert total["params"]["phi_mae_deg"] == pytest.approx(2.0) and total["force"]["mae_z_n"] == pytest.approx(200.0)
    table = D.table_text([s], total)
    assert "Clay" in table and "overall" in table and "2.0" in table
    assert max(len(line) for line in table.splitlines()) <= 120


def test_summarise_names_the_bag_without_estimates(tmp_path, episode):
    bag = write_episode(tmp_path / "no_estimator", episode)
    with pytest.raises(ValueError, match=r"no topic /soil/estimate.*estimator"):
        D.summarise(bag)
    only_invalid = [(int(s), _estimate(episode, k, False, min(k + 1, 59))) for k, s in enumerate(episode.stamps_ns)]
    bag = _write_bag_with_estimates(tmp_path / "never_valid", episode, only_invalid)
    with pytest.raises(ValueError, match=r"no valid estimate.*59/60"):
        D.summarise(bag)


def test_live_lines_fit_120_columns_and_say_when_the_window_fills(episode):
    truth = episode.truth[70]
    force = np.array([-19_999.0, 29_999.0])
    valid = _estimate(episode, 70, True, 60)
    valid[EST["c"]] = 99_999.0  # wide numbers must not break the layout
    lines = [*D.header_lines(), D.estimate_line("Gravel", 100.0, 59.0, valid, truth, force),
             D.estimate_line("Clay", 20.0, 0.5, _estimate(episode, 29, False, 30), truth, force),
             D.estimate_line("Sand", 0.0, 3.0, None, None, None, note="no estimate received")]
    assert all(len(line) <= 120 for line in lines), [len(x) for x in lines]
    assert "filling window 30/60" in lines[3] and "--/" in lines[3]
    assert f"{truth[TRUTH['phi']] / DEG:.1f}" in lines[2]


def test_bag_dir_is_cleared_only_if_it_holds_just_bags(tmp_path, episode):
    root = tmp_path / "bags"
    assert D.prepare_bag_dir(root) is False and root.is_dir()
    write_episode(root / "old", episode)
    (root / "x.partial").mkdir()
    assert D.prepare_bag_dir(root) is True and list(root.iterdir()) == []
    (root / "notes.txt").write_text("mine")
    with pytest.raises(ValueError, match="not episode bags.*notes.txt"):
        D.prepare_bag_dir(root)
    assert (root / "notes.txt").exists()


def test_bad_arguments_exit_2_with_the_reason():
    for argv, needle in ((["--soils", "Peat"], "Peat"), (["--duration", "0.5"], "window"),
                         (["--densities", "120"], "[0, 100]")):
        res = subprocess.run([sys.executable, "-m", "soil_bringup.demo", *argv], capture_output=True, text=True,
                             timeout=60)
        assert res.returncode == 2 and needle in res.stderr, res.stderr


def test_demo_runs_one_episode_over_dds_and_writes_the_summary(tmp_path):
    from tests.ros_probe import next_domain_id

    out, bags = tmp_path / "out", tmp_path / "bags"
    argv = [sys.executable, "-m", "soil_bringup.demo", "--pacing", "lockstep", "--soils", "Clay",
            "--densities", "20", "--duration", "3.0", "--out", str(out), "--bags", str(bags),
            "--domain-id", str(next_domain_id())]
    res = subprocess.run(argv, capture_output=True, text=True, timeout=120)
    log = out / "launch.log"
    context = f"stdout:\n{res.stdout}\nstderr:\n{res.stderr}\nlaunch log tail:\n" + (
        "\n".join(log.read_text().splitlines()[-30:]) if log.exists() else "(none)")
    assert res.returncode == 0, context

    summary = json.loads((out / "summary.json").read_text())
    assert len(summary["episodes"]) == 1, context
    ep = summary["episodes"][0]
    assert ep["soil"] == "Clay" and ep["relative_density_pct"] == 20.0 and ep["ticks"] == 180
    assert ep["valid_estimates"] > 0 and summary["overall"]["valid_estimates"] == ep["valid_estimates"]
    errors = [*ep["force"].values(), *ep["params"].values()]
    assert all(math.isfinite(v) for v in errors), ep
    assert (out / "summary.md").read_text().count("| Clay |") == 2
    png = out / "online_estimates.png"
    assert png.is_file() and png.stat().st_size > 10_000

    recorded = read_episode(Path(ep["bag"]))
    assert len(recorded) == 180 and recorded.meta.soil == "Clay"
    # the live part: an episode header, the window filling, one line per simulated second, all <= 120 columns
    lines = res.stdout.splitlines()
    assert any(line.startswith("=== episode 1/1: Clay, I_d 20 %") for line in lines), context
    assert any("filling window" in line for line in lines), context
    assert sum(line.startswith("Clay    20%") for line in lines) == 3, context
    assert all(len(line) <= 120 for line in lines if line.startswith(("Clay", "soil", " "))), context
    assert "bags/" in res.stdout and "online_estimates.png" in res.stdout


def test_only_nodes_still_running_their_logged_command_are_killed(tmp_path):
    mine = subprocess.Popen(["sleep", "60"])
    other = subprocess.Popen(["sleep", "61"])
    try:
        log = tmp_path / "launch.log"
        log.write_text(f"[launch] started sim (pid {mine.pid}): sleep 60\n"
                       f"[launch] started recorder (pid {other.pid}): sleep 99\n"  # not what runs under that pid
                       f"[launch] started controller (pid 999999999): sleep 60\n")
        assert D._kill_leftover_nodes(log) == [f"sim ({mine.pid})"]
        assert mine.wait(timeout=5) == -9 and other.poll() is None
    finally:
        for p in (mine, other):
            p.kill()
            p.wait(timeout=5)


def test_report_writes_the_summary_and_fails_on_a_missing_episode(tmp_path, episode, capsys):
    import time

    out, root = tmp_path / "out", tmp_path / "bags"
    args = D.parse_args(["--soils", "Clay", "Sand", "--densities", "20", "--out", str(out), "--bags", str(root)])
    root.mkdir()
    estimates = [(int(s), _estimate(episode, k, k >= 59, min(k + 1, 60))) for k, s in enumerate(episode.stamps_ns)]
    _write_bag_with_estimates(root / episode.meta.name, episode, estimates)
    pairs = [("Clay", 20.0), ("Sand", 20.0)]
    assert D.report(args, pairs, None, time.monotonic(), 5.0, out / "launch.log") == D.EXIT_FAILED
    captured = capsys.readouterr()
    assert "no usable bag for 1 of 2 planned episode(s): Sand I_d 20 %" in captured.err
    summary = json.loads((out / "summary.json").read_text())
    assert [e["soil"] for e in summary["episodes"]] == ["Clay"] and summary["run"]["errors"]
    assert summary["episodes"][0]["params"]["phi_mae_deg"] == pytest.approx(2.0)
    assert (out / "online_estimates.png").stat().st_size > 5_000 and "| **overall** |" in (out / "summary.md").read_text()
    assert "overall" in captured.out and "valid estimates" in captured.out
