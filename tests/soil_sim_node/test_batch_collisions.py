"""soil_sim_batch into a directory that already holds something: a recorder's journal is never
deleted, existing bags are refused before anything is simulated, a deeper target than the lift
reaches is said, and dataset.json keeps the record of the runs before."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from soil_bag_tools.bag_io import find_episode_bags, journal_path, write_episode
from soil_sim_node import batch
from soil_sim_node.rollout import run_episodes
from soil_sim_node.simulator import EpisodeSpec, SimConfig

ONE = ["--mode", "fee", "--soils", "Sand", "--relative-densities", "50", "--speeds", "0.5", "--seeds", "1",
       "--duration", "1.0", "--workers", "1", "--quiet"]


def test_a_recorders_journal_of_the_same_name_is_kept_and_named(tmp_path, capsys):
    """A killed recorder leaves <name>.partial/<name>.mcap; a batch episode of that name had
    deleted it as a stale staging directory before soil_bag_repair could recover it."""
    out = tmp_path / "site"
    spec = EpisodeSpec("Sand", 50.0, 0.5, 0.1, seed=0, duration_s=1.0)
    name = run_episodes(SimConfig(world_mode="fee"), [spec])[0].meta.name
    journal = journal_path(out / f"{name}.partial")
    journal.parent.mkdir(parents=True)
    journal.write_bytes(b"\x89MCAP0\r\n recorded before the kill")
    assert batch.main([*ONE, "--depths", "0.1", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "recorder's journal waits to be recovered" in err and "soil_bag_repair" in err, err
    assert journal.read_bytes().endswith(b"recorded before the kill") and find_episode_bags(out) == []
    ep = run_episodes(SimConfig(world_mode="fee"), [spec])[0]  # the writer itself refuses it too
    with pytest.raises(FileExistsError, match="holds a recorder's journal"):
        write_episode(out / name, ep)
    assert journal.exists()


def test_existing_bags_are_refused_before_anything_is_simulated_and_earlier_runs_are_kept(tmp_path, capsys):
    out = tmp_path / "site"
    assert batch.main([*ONE, "--depths", "0.1", "--out", str(out)]) == 0
    first = json.loads((out / "dataset.json").read_text())
    # the same grid plus one new episode: refused whole, nothing new written
    assert batch.main([*ONE, "--depths", "0.1,0.15", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "1 of the 2 bags exist" in err and "--overwrite" in err, err
    assert len(find_episode_bags(out)) == 1
    # a second run of other episodes into the same directory keeps the first run's record
    capsys.readouterr()
    assert batch.main([*ONE, "--depths", "0.15", "--seed-base", "5", "--out", str(out)]) == 0
    assert "already holds 1 episode bag(s) of earlier runs; with these 1 it holds 2" in capsys.readouterr().err
    summary = json.loads((out / "dataset.json").read_text())
    assert len(find_episode_bags(out)) == 2 and summary["episodes"] == 1
    assert summary["earlier_runs"] == [first]
    assert batch.main([*ONE, "--depths", "0.2", "--seed-base", "9", "--out", str(out)]) == 0
    third = json.loads((out / "dataset.json").read_text())
    assert [r["episode_names"] for r in third["earlier_runs"]] == [first["episode_names"], summary["episode_names"]]


def test_a_target_deeper_than_the_lift_reaches_is_said(tmp_path, capsys):
    assert batch.main([*ONE, "--depths", "0.2,0.45", "--out", str(tmp_path / "deep")]) == 0
    err = capsys.readouterr().err
    assert "--depths=0.45 m is beyond the lift's reach from level ground (0.3 m" in err, err
    assert "--depths=0.2" not in err


def test_a_target_speed_faster_than_table_1s_is_said(tmp_path, capsys):
    """An outside tester's: --speeds 1.5 ran without a word, where a depth beyond the reach is said."""
    args = [a if a != "0.5" else "0.5,1.5" for a in ONE]
    assert batch.main([*args, "--depths", "0.1", "--duration", "0.2", "--out", str(tmp_path / "fast")]) == 0
    err = capsys.readouterr().err
    assert "--speeds=1.5 m/s is faster than Table 1's v_x (at most 1 m/s)" in err, err
    assert "--speeds=0.5" not in err


def test_a_patch_the_blade_never_reaches_is_said(tmp_path, capsys):
    """The edge starts at x = 2 m; at 0.5 m/s for 2 s it gets to about 3 m, short of a patch at 4 m."""
    base = ["--mode", "fee", "--speeds", "0.5", "--depths", "0.1", "--seeds", "1", "--duration", "2", "--workers", "1",
            "--quiet", "--patch", "0:Sand:20", "--patch", "2.5:Clay:80", "--patch", "4:Loam:50"]
    assert batch.main([*base, "--out", str(tmp_path / "short")]) == 0
    err = capsys.readouterr().err
    assert "patches[2] (Loam from x = 4 m) starts beyond where the blade's edge gets in 2 s at 0.5 m/s (x ≈ 3.00 m)" in err
    assert "patches[1]" not in err and "behind" not in err
    # a patch that ends where the edge starts: never cut, said; the episode is named and labelled
    # after the soil it starts in (it had been after the patch never cut: an outside reviewer's)
    behind = [*base[:-6], "--patch", "0:Sand:20", "--patch", "2:Clay:80"]
    assert batch.main([*behind, "--out", str(tmp_path / "behind")]) == 0
    err = capsys.readouterr().err
    assert ("patches[0] (Sand from x = 0 m) ends at x = 2 m, behind where the blade's edge starts (x = 2 m): "
            "never cut") in err, err
    names = [p.name for p in (tmp_path / "behind").iterdir() if p.is_dir()]
    assert names and all(n.startswith("fee_clay_id080_") for n in names), names


def test_a_soil_file_without_soils_naming_its_soils_is_said(tmp_path, capsys):
    soils = tmp_path / "site.yaml"
    soils.write_text("soils:\n  - {name: Silt, phi_deg: [26, 34], cohesion_pa: [500, 4000], unit_weight_n_m3: [15500, 19000]}\n")
    grid = ["--mode", "fee", "--relative-densities", "50", "--speeds", "0.5", "--depths", "0.1", "--seeds", "1",
            "--duration", "1", "--workers", "1", "--quiet", "--soil-file", str(soils)]
    assert batch.main([*grid, "--out", str(tmp_path / "a")]) == 0
    assert "--soil-file's soils ['Silt'] are not simulated without --soils naming them" in capsys.readouterr().err
    replaced = tmp_path / "sand.yaml"  # a soil named like a catalogue one replaces it: simulated, not said
    replaced.write_text(soils.read_text().replace("name: Silt", "name: Sand"))
    assert batch.main([*grid[:-1], str(replaced), "--soils", "Sand", "--out", str(tmp_path / "c")]) == 0
    assert batch.main([*grid[:-1], str(replaced), "--out", str(tmp_path / "d")]) == 0
    assert "not simulated" not in capsys.readouterr().err
    assert batch.main([*grid, "--soils", "Silt,Sand", "--out", str(tmp_path / "b")]) == 0
    assert "not simulated" not in capsys.readouterr().err
    assert sorted(b.name.split("_")[1] for b in find_episode_bags(tmp_path / "b")) == ["sand", "silt"]


def test_an_interrupted_run_is_resumed_with_skip_existing(tmp_path, capsys):
    """Ctrl-C on soil_sim_batch kept the bags finished, and the same command then refused them
    all ("1 of the 2 bags exist"): --skip-existing keeps them and simulates the rest."""
    out = tmp_path / "site"
    assert batch.main([*ONE, "--depths", "0.1", "--out", str(out)]) == 0
    first = find_episode_bags(out)
    stamp = first[0].stat().st_mtime_ns
    capsys.readouterr()
    assert batch.main([*ONE, "--depths", "0.1,0.15", "--out", str(out), "--skip-existing"]) == 0
    said = capsys.readouterr()
    err = said.err
    assert "1 of the 2 bags exist" in err and "simulating the other 1" in err, err
    assert len(find_episode_bags(out)) == 2 and first[0].stat().st_mtime_ns == stamp
    resumed = json.loads((out / "dataset.json").read_text())
    assert resumed["kept_existing"] == [first[0].name]
    # the record counts every bag of the plan (it had said "episodes": 1 of the two), and says which were simulated
    assert resumed["episodes"] == 2 and resumed["simulated_episodes"] == 1
    assert resumed["episode_names"] == sorted(b.name for b in find_episode_bags(out))
    assert "2 fee episodes (1 simulated, 1 kept from the run before) ->" in said.out, said.out
    record = (out / "dataset.json").read_text()
    assert batch.main([*ONE, "--depths", "0.1,0.15", "--out", str(out), "--skip-existing"]) == 0  # nothing left
    assert "simulating the other 0" in capsys.readouterr().err
    assert (out / "dataset.json").read_text() == record  # the complete run's record stays
    # every bag written but the record not (a run killed after its last bag, an outside tester's Ray head):
    # with nothing left to simulate the record is written all the same, every bag kept
    (out / "dataset.json").unlink()
    assert batch.main([*ONE, "--depths", "0.1,0.15", "--out", str(out), "--skip-existing"]) == 0
    assert json.loads((out / "dataset.json").read_text())["kept_existing"] == sorted(b.name for b in find_episode_bags(out))
    assert batch.main([*ONE, "--depths", "0.1", "--out", str(out), "--skip-existing", "--overwrite"]) == 2
    assert "contradict" in capsys.readouterr().err


def test_ctrl_c_removes_only_this_runs_staging_and_says_it_in_one_line(tmp_path, capsys, monkeypatch):
    """Ctrl-C (as the pool's end leaves it: a bag of the plan half written in its staging
    directory) ends in one line, exit 130; another run's staging and a recorder's journal stay."""
    out = tmp_path / "site"
    assert batch.main([*ONE, "--depths", "0.1", "--out", str(out)]) == 0
    (name,) = [b.name for b in find_episode_bags(out)]
    mine = out / f"{name}.partial" / name
    theirs = out / "someone_elses.partial" / "someone_elses"
    journal = journal_path(out / "recorded.partial")

    def interrupted(plan, **_):
        for d in (mine, theirs, journal.parent):
            d.mkdir(parents=True)
        journal.write_bytes(b"\x89MCAP0\r\n")
        raise KeyboardInterrupt

    monkeypatch.setattr(batch, "generate", interrupted)
    capsys.readouterr()
    assert batch.main([*ONE, "--depths", "0.1", "--out", str(out), "--overwrite"]) == 130
    err = capsys.readouterr().err
    # (an --overwrite run: the bags it had not reached are the earlier run's, so not --skip-existing)
    # (it had finished none of its own: said so, not "the bags finished are kept", an outside tester's)
    assert err.count("\n") == 1 and "interrupted; it had finished no bag under" in err and "--skip-existing" not in err, err
    assert "the earlier run's, not overwritten yet: the same command (with --overwrite) makes them all" in err, err
    assert not mine.parent.exists() and theirs.exists() and journal.exists()


def test_sigterm_ends_the_batch_like_ctrl_c_and_leaves_no_worker_writing(tmp_path):
    """SIGTERM (what `timeout`, a scheduler or a container runtime sends) takes the Ctrl-C path:
    one line, exit 143, the finished bags kept, no staging left, and the pool's workers stopped
    with it (before, the batch died at once and silently, its orphaned workers writing bags on)."""
    import signal
    import time

    out = tmp_path / "run"
    proc = _two_workers_at_work(out)
    try:
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 143, err
    assert err.count("\n") == 1 and "interrupted (SIGTERM); the bags finished under" in err, err
    kept = {b.name for b in find_episode_bags(out)}
    assert 0 < len(kept) < 32 and not list(out.glob("*.partial")), (kept, list(out.iterdir()))
    time.sleep(3.0)
    assert {b.name for b in find_episode_bags(out)} == kept and not list(out.glob("*.partial"))  # nothing writes on


@pytest.mark.timeout(180)
@pytest.mark.parametrize("second", ["SIGINT", "SIGTERM"])
def test_a_second_signal_while_the_batch_cleans_up_waits_for_it(tmp_path, second):
    """Ctrl-C, then a second signal 0.2 s later (an impatient Ctrl-C, timeout's SIGTERM after the
    terminal's), to the console script's process group: the second had interrupted the staging's
    removal (a traceback, exit −2 or a silent −15, half-written bags' folders left; an outside
    tester's, 7 of 8). Now the clean-up finishes, the first signal's line and code stand."""
    import os
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "run"
    cmd = [str(Path(sys.executable).parent / "soil_sim_batch"), "--mode", "fee", "--soils", "Sand,Clay",
           "--relative-densities", "20,80", "--speeds", "0.4,0.5,0.6,0.7", "--depths", "0.1,0.2", "--seeds", "1", "--duration", "30",
           "--workers", "2", "--quiet", "--out", str(out)]
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while not (out.exists() and find_episode_bags(out)):
            assert proc.poll() is None and time.monotonic() < deadline, "no bag written"
            time.sleep(0.2)
        os.killpg(proc.pid, signal.SIGINT)
        time.sleep(0.2)
        if proc.poll() is None:
            os.killpg(proc.pid, getattr(signal, second))
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130, err
    assert "Traceback" not in err and "interrupted; the bags finished under" in err, err
    assert find_episode_bags(out) and not list(out.glob("*.partial")), list(out.iterdir())


def test_bags_finished_before_a_plugin_failed_are_said_with_what_to_do(tmp_path, capsys):
    """A plugin refused mid-run (a force beyond any machine's at the deeper target) ends the run with
    exit 2; the bag finished before it stays, and the error now says so and that it was made with the
    input that failed (a later --skip-existing would keep it)."""
    out = tmp_path / "site"
    argv = [*ONE, "--depths", "0.05,0.3", "--plugin", "tests.sim_plugins:deep_drag k=1e6", "--out", str(out)]
    assert batch.main(argv) == 2
    err = capsys.readouterr().err
    kept = find_episode_bags(out)
    assert len(kept) == 1 and "d0.050" in kept[0].name and not (out / "dataset.json").exists()
    assert "returned f_x=" in err and f"1 episode bag(s) finished before the failure are kept under {out}" in err, err
    assert "after mending it, run again with --overwrite" in err, err
    assert "(simulating episodes fee_sand_id050_v0.50_d0.300" in err, err  # which (Ray's tasks named them; the pool did not)
    assert batch.main([*ONE, "--depths", "0.1", "--plugin", "tests.sim_plugins:deep_drag k=1e6",
                       "--out", str(tmp_path / "fine")]) == 0  # never below 0.2 m: nothing refused, nothing said
    assert "finished before the failure" not in capsys.readouterr().err


def test_a_grid_value_given_twice_is_said(tmp_path, capsys):
    """'--speeds 0.5,0.5' or '--soils Sand,sand' ran the same grid point twice under other seeds, silently."""
    assert batch.main([*ONE, "--depths", "0.1,0.10", "--speeds", "0.5", "--out", str(tmp_path / "a")]) == 0
    assert "--depths lists 0.10 more than once: its episodes run again under other seeds" in capsys.readouterr().err
    argv = ["--mode", "fee", "--soils", "Sand,sand", "--relative-densities", "50", "--speeds", "0.5", "--depths", "0.1",
            "--seeds", "1", "--duration", "1.0", "--workers", "1", "--quiet", "--out", str(tmp_path / "b")]
    assert batch.main(argv) == 0
    assert "--soils lists sand more than once" in capsys.readouterr().err
    assert batch.main([*ONE, "--depths", "0.1", "--out", str(tmp_path / "c")]) == 0
    assert "more than once" not in capsys.readouterr().err


def test_a_disk_filling_up_mid_run_is_said_in_one_line_and_leaves_no_staging(tmp_path, capsys, monkeypatch):
    """A full disk in the local pool ended in a worker's raw traceback and left <bag>.partial
    directories (an outside tester's; Ray's path said it cleanly): now one line, exit 1, the
    bags finished kept and said, the staging of this run removed. (In this process, one worker:
    a pool re-raises its worker's OSError alike.)"""
    out = tmp_path / "site"
    real, calls = batch.write_episode, [0]

    def filling(bag_dir, ep, **kw):
        calls[0] += 1
        if calls[0] == 1:
            return real(bag_dir, ep, **kw)
        (bag_dir.parent / f"{bag_dir.name}.partial").mkdir()
        raise OSError(28, "No space left on device", str(bag_dir))

    monkeypatch.setattr(batch, "write_episode", filling)
    assert batch.main([*ONE, "--depths", "0.1,0.15", "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert "soil_sim_batch: error: writing the bags failed: [Errno 28] No space left on device" in err, err
    assert "1 episode bag(s) finished before the failure are kept" in err and "--skip-existing" in err, err
    assert len(find_episode_bags(out)) == 1 and not list(out.glob("*.partial"))


def test_a_worker_killed_mid_run_ends_the_batch_saying_so_and_keeps_the_finished_bags(tmp_path):
    """A worker killed outright (what the out-of-memory killer does): multiprocessing.Pool replaced it
    and waited for its chunk for ever, the batch idle with no end and no word. Now the run ends with
    exit 1, the death said in one line, the bags finished before it kept and the resume said, the
    other worker stopped and no staging left."""
    import os
    import signal
    import subprocess
    import time

    out = tmp_path / "run"
    proc = _two_workers_at_work(out)
    try:
        workers = subprocess.run(["pgrep", "-P", str(proc.pid)], capture_output=True, text=True).stdout.split()
        assert workers, "no worker process"  # (a fork start: the workers are the batch's only children)
        os.kill(int(workers[0]), signal.SIGKILL)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 1, err
    assert "soil_sim_batch: error: a worker process died while simulating episodes" in err, err
    assert "finished before the failure are kept under" in err and "--skip-existing" in err, err
    kept = {b.name for b in find_episode_bags(out)}
    assert 0 < len(kept) < 32 and not list(out.glob("*.partial")), (kept, list(out.iterdir()))
    time.sleep(3.0)
    assert {b.name for b in find_episode_bags(out)} == kept  # the other worker writes nothing more


def _two_workers_at_work(out):
    """A 32-episode batch in two local workers writing into ``out``, once its first bag is in."""
    import subprocess
    import sys
    import time

    cmd = [sys.executable, "-m", "soil_sim_node.batch", "--mode", "fee", "--soils", "Sand,Clay", "--relative-densities",
           "20,80", "--speeds", "0.4,0.5,0.6,0.7", "--depths", "0.1,0.2", "--seeds", "1", "--duration", "30", "--workers", "2",
           "--quiet", "--out", str(out)]
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    try:
        while not find_episode_bags(out) if out.exists() else True:
            assert proc.poll() is None and time.monotonic() < deadline, "no bag written"
            time.sleep(0.2)
    except BaseException:
        proc.kill()
        raise
    return proc


def test_an_overwrite_run_that_stopped_is_told_to_run_again_not_to_skip_existing(tmp_path, capsys):
    """An --overwrite run stopped midway was told "--skip-existing simulates the rest", which kept the
    bags it had not reached, the earlier run's: a dataset of two runs without a word (an outside
    tester's). Its bags are told apart by their time, and the hint is to run it again."""
    import time

    from soil_bag_tools.bag_io import read_episode

    out = tmp_path / "site"
    assert batch.main([*ONE, "--depths", "0.1,0.2", "--out", str(out)]) == 0
    first, second = find_episode_bags(out)
    since = time.time()
    time.sleep(0.05)
    write_episode(first, read_episode(first), overwrite=True)  # this run's, the other the earlier run's
    kept = batch.kept_after_failure(out, {first.name, second.name}, bad_input=False, overwrite=True, since=since)
    assert kept.startswith(f"1 episode bag(s) finished before the failure are kept under {out} (e.g. {first.name}")
    assert kept.endswith("the others there are the earlier run's, not overwritten yet: the same command (with "
                         "--overwrite) makes them all this run's"), kept
    assert batch.kept_after_failure(out, {first.name, second.name}, bad_input=False) == ""  # not overwriting: none new
    assert batch.resume_hint(False) == "the same command with --skip-existing simulates the rest"
    # every bag of the plan this run's (an --overwrite run into an empty folder, or all rewritten): nothing stale
    kept = batch.kept_after_failure(out, {first.name}, bad_input=False, overwrite=True, since=since,
                                    planned={first.name})
    assert kept.endswith(": the same command with --skip-existing simulates the rest"), kept
    # the hint is not said twice where the error said it (a Ray run's)
    assert not batch.kept_after_failure(out, {first.name, second.name}, bad_input=False, overwrite=True, since=since,
                                        said=f"  {batch.resume_hint(True)}").endswith("this run's")
    # a bag gone meanwhile (renamed away by another run) is not this run's, not an error
    assert not batch.written_since(out / "gone", since)


@pytest.mark.parametrize("exc_name, code, how", [("KeyboardInterrupt", 130, ""), ("Terminated", 143, " (SIGTERM)")])
def test_a_stop_before_the_plan_is_made_says_which(tmp_path, capsys, monkeypatch, exc_name, code, how):
    """Through the console script (run_tool) a SIGTERM reaches the batch before its plan is made too;
    it was said as a Ctrl-C there, exit 130."""
    from soil_msgs_py import interrupts

    def stopped(args):
        raise interrupts.Terminated() if exc_name == "Terminated" else KeyboardInterrupt()

    monkeypatch.setattr(batch, "plan_from_args", stopped)
    assert batch.main([*ONE, "--out", str(tmp_path / "out")]) == code
    assert capsys.readouterr().err == f"soil_sim_batch: interrupted{how} before anything was written\n"


def test_a_plugin_idle_in_the_episodes_a_resumed_run_simulates_is_said_of_those_only(tmp_path, capsys):
    """A plugin that acts only in deep cuts, its deep episode written by an interrupted run and kept:
    the resumed run simulated only the shallow one, where it never acted, and the warning said "every
    episode ... the bags hold no such effect" of a folder whose kept bag holds it (a reviewer's)."""
    out = tmp_path / "site"
    plugin = ["--plugin", "tests.sim_plugins:deep_drag k=1 d0=0.1"]
    argv = [*ONE, "--duration", "3", *plugin, "--out", str(out)]
    assert batch.main([*argv, "--depths", "0.2", "--seed-base", "1"]) == 0  # the seed it has in the whole grid
    assert "never acted" not in capsys.readouterr().err
    (out / "dataset.json").unlink()  # as an interrupted run leaves its bags: no record
    assert batch.main([*argv, "--depths", "0.05,0.2", "--skip-existing"]) == 0
    err = capsys.readouterr().err
    assert "returned 0 N in every substep of the 1 episodes simulated now (the 1 kept from the run before are not " \
           "known)" in err, err


def test_a_resume_with_other_settings_is_refused_not_mixed(tmp_path, capsys):
    """--skip-existing with another --plugin or --duration than the bags it would keep had mixed two
    datasets under one dataset.json, without a word (an outside tester's): refused before anything
    is simulated, naming the bag and the setting; the same settings resume as before."""
    out = tmp_path / "site"
    plugin = ["--plugin", "tests.sim_plugins:in_soil_constant_drag f_x=300"]
    assert batch.main([*ONE, *plugin, "--depths", "0.1", "--out", str(out)]) == 0
    capsys.readouterr()
    for other in (["--plugin", "tests.sim_plugins:constant_force f_x=300"], [*plugin, "--duration", "2"], []):
        assert batch.main([*ONE, *other, "--depths", "0.1,0.15", "--out", str(out), "--skip-existing"]) == 2
        err = capsys.readouterr().err
        assert "which --skip-existing would keep, was made with" in err and "keeping it would mix two datasets" in err, err
        assert len(find_episode_bags(out)) == 1
    assert batch.main([*ONE, *plugin, "--depths", "0.1,0.15", "--out", str(out), "--skip-existing"]) == 0
    assert len(find_episode_bags(out)) == 2
