"""soil_sim_batch --ray on a local Ray instance of 2 CPUs (bound to 127.0.0.1, usage statistics
off): the local pool's bags byte for byte for the same seeds and --workers, the same
dataset.json but for its timing fields, a failing task named with its episodes while the other
bags are kept, and no Ray process left behind. --ray ADDRESS on a cluster started with
`ray start` (on loopback, token authentication on): the same bags, and the cluster still runs.
Pool and Ray write in the same test, so the bags are compared with each other, never with
stored files."""
from __future__ import annotations

import contextlib
import json
import os
import secrets
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from soil_bag_tools.bag_io import find_episode_bags, journal_path
from pinn_estimator import train
from soil_sim_node import batch
from tests.ray_probe import is_loopback, listening_addresses, ray_processes, wait_gone

pytestmark = pytest.mark.live

SMALL = ["--mode", "fee", "--soils", "Clay,Sand", "--relative-densities", "20,80", "--speeds", "0.5", "--depths", "0.1",
         "--seeds", "1", "--duration", "2.0", "--workers", "2", "--quiet"]
TIMING_FIELDS = ("wall_time_s", "simulated_s_per_wall_s")  # how long a run took differs by nature


@pytest.fixture(autouse=True)
def no_ray_usage_stats(monkeypatch):
    monkeypatch.setenv("RAY_USAGE_STATS_ENABLED", "0")


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.mark.parametrize("main", [batch.main, train.main], ids=["soil_sim_batch", "pinn_train"])
def test_a_give_up_time_without_ray_is_refused_not_ignored(main, tmp_path, capsys):
    """--ray-give-up-after is for a run on Ray: without --ray it was ignored in silence (an outside tester's)."""
    with pytest.raises(SystemExit) as exit_:
        main(["--out", str(tmp_path / "x"), "--ray-give-up-after", "5"]
             + (["--data", str(tmp_path)] if main is train.main else []))
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and "--ray-give-up-after 5 is for a run on Ray: give --ray too, or leave it out" in err, err
    assert not (tmp_path / "x").exists()


@pytest.mark.timeout(300)
def test_ray_tasks_write_the_pools_bags_byte_for_byte_and_leave_no_ray_process(tmp_path):
    before = ray_processes()
    assert batch.main([*SMALL, "--out", str(tmp_path / "pool")]) == 0
    assert batch.main([*SMALL, "--out", str(tmp_path / "ray"), "--ray"]) == 0
    assert not wait_gone(ray_processes() - before), "the local Ray instance left processes running"
    pool, ray = _files(tmp_path / "pool"), _files(tmp_path / "ray")
    assert len(find_episode_bags(tmp_path / "ray")) == 4
    assert sorted(pool) == sorted(ray)
    for name in pool:
        if name != "dataset.json":
            assert pool[name] == ray[name], name
    summary_pool, summary_ray = (json.loads(files.pop("dataset.json")) for files in (pool, ray))
    for key in TIMING_FIELDS:
        summary_pool.pop(key), summary_ray.pop(key)
    assert summary_pool == summary_ray and summary_ray["episodes"] == 4
    # the local pool again, in this process that has run Ray (whose threads make a fork unsafe)
    assert batch.main([*SMALL, "--out", str(tmp_path / "pool_after_ray")]) == 0
    after = _files(tmp_path / "pool_after_ray")
    assert all(after[n] == pool[n] for n in pool) and sorted(after) == sorted([*pool, "dataset.json"])


@pytest.mark.timeout(300)
def test_a_failing_ray_task_is_named_with_its_episodes_and_the_other_bags_are_kept(tmp_path, capsys):
    out = tmp_path / "ds"
    blocked = out / "fee_sand_id080_v0.50_d0.100_s3"  # the 4th episode of the grid: a directory that is not a bag
    blocked.mkdir(parents=True)
    (blocked / "notes.txt").write_text("not a bag")
    before = ray_processes()
    assert batch.main([*SMALL, "--out", str(out), "--ray"]) == 2  # an existing file: the input's fault
    err = capsys.readouterr().err
    assert "1 of 4 Ray tasks failed" in err and f"episodes {blocked.name}: FileExistsError" in err, err
    assert sorted(b.name for b in find_episode_bags(out)) == [
        "fee_clay_id020_v0.50_d0.100_s0", "fee_clay_id080_v0.50_d0.100_s1", "fee_sand_id020_v0.50_d0.100_s2"]
    assert (blocked / "notes.txt").read_text() == "not a bag"
    assert not (out / "dataset.json").exists()
    assert not [p for p in out.iterdir() if p.name.endswith(".partial")]
    assert not wait_gone(ray_processes() - before)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _stop(pids: set[int]) -> None:
    """Stop the processes `ray start` launched for this test, by their ids (never `ray stop`:
    it stops every Ray instance on the machine)."""
    for sig in (signal.SIGTERM, signal.SIGKILL):
        for pid in pids:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, sig)
        pids = wait_gone(pids, 20.0)


@pytest.mark.timeout(360)
def test_ray_address_runs_the_tasks_on_that_cluster_and_leaves_it_running_and_a_lost_cluster_is_said(tmp_path):
    """The user's cluster listens on loopback alone (started with RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0);
    the driver is run without that variable, as a user would (Ray's driver had dialled the
    machine's routable address for ever). Then a run whose cluster is stopped midway: Ray's
    driver aborted the process after 60 s without a word and left a half-written bag."""
    port = _free_port()
    env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0", "RAY_AUTH_MODE": "token",
           "RAY_AUTH_TOKEN": secrets.token_hex(32)}
    env.pop("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", None)
    before = ray_processes()
    elsewhere = tmp_path / "where_ray_started"  # its workers start there: relative paths are the driver's
    elsewhere.mkdir()
    started = subprocess.run([str(Path(sys.executable).with_name("ray")), "start", "--head", "--port", str(port),
                              "--num-cpus", "2", "--include-dashboard", "false", "--disable-usage-stats"],
                             env={**env, "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0"},  # the user's cluster, on loopback
                             capture_output=True, text=True, timeout=180, cwd=elsewhere)
    cluster = ray_processes() - before
    try:
        assert started.returncode == 0, started.stderr[-2000:]
        listening = listening_addresses(cluster)
        assert listening and all(is_loopback(ip) for _, ip in listening), listening
        # a relative --out, as the README's example gives it: the bags had landed where `ray start` ran
        run = subprocess.run([sys.executable, "-m", "soil_sim_node.batch", *SMALL, "--out", "ray",
                              "--ray", f"127.0.0.1:{port}"], env=env, capture_output=True, text=True, timeout=120,
                             cwd=tmp_path)
        assert run.returncode == 0, run.stderr[-2000:]
        assert not (elsewhere / "ray").exists()
        read = subprocess.run([sys.executable, "-c", "from pinn_estimator.dataset import load_dataset; "
                               f"print(len(load_dataset('ray', cache=False, ray_address='127.0.0.1:{port}').names))"],
                              env=env, capture_output=True, text=True, timeout=120, cwd=tmp_path)
        assert read.returncode == 0 and read.stdout.split()[-1] == str(len(find_episode_bags(tmp_path / "ray"))), \
            read.stderr[-2000:]
        local = subprocess.run([sys.executable, "-m", "soil_sim_node.batch", *SMALL, "--out", str(tmp_path / "pool")],
                               env=env, capture_output=True, text=True, timeout=240)
        assert local.returncode == 0, local.stderr[-2000:]
        pool, ray = _files(tmp_path / "pool"), _files(tmp_path / "ray")
        assert sorted(pool) == sorted(ray) and all(pool[n] == ray[n] for n in pool if n != "dataset.json")
        servers = {pid for pid in cluster if _name(pid) in ("gcs_server", "raylet")}
        assert len(servers) == 2 and servers <= ray_processes(), "the user's cluster was stopped"

        out = tmp_path / "lost"
        longer = [*SMALL, "--seeds", "16", "--duration", "30.0"]  # 64 episodes, 16 per task (~3 s each here)
        lost = subprocess.Popen([sys.executable, "-m", "soil_sim_node.batch", *longer, "--out", str(out),
                                 "--ray", f"127.0.0.1:{port}", "--ray-give-up-after", "4"],
                                env=env, stderr=subprocess.PIPE, text=True)
        try:
            deadline = time.monotonic() + 120
            while not (out.is_dir() and find_episode_bags(out)) and lost.poll() is None and time.monotonic() < deadline:
                time.sleep(0.1)
            assert lost.poll() is None, "the run ended before its cluster was stopped"
            workers = {pid for pid in ray_processes() - before if _parent(pid) in cluster}  # its raylet's children
            _stop(cluster)
            err = lost.communicate(timeout=120)[1]
            driver_done = time.time()
        finally:
            lost.kill()
        _stop(workers & ray_processes())  # the workers its raylet started, which may outlive it for a moment
        assert lost.returncode == 1, err[-2000:]
        # Ray's driver notices the stopped raylet at once in some runs (the tasks fail as
        # LocalRayletDiedError), hangs on the head in others (given up after 4 s): either is said
        assert "has refused connections for 4 s" in err or "LocalRayletDiedError" in err, err[-2000:]
        assert "--skip-existing simulates the missing episodes once the cluster is back" in err, err[-2000:]
        assert "soil_sim_batch: error:" in err and "Ray tasks failed" in err, err[-2000:]
        # every bag may have landed before the stop took effect, their tasks' answers lost with the
        # cluster (a machine that simulates 16 ten-second episodes in a second did): whole, kept
        written = find_episode_bags(out)
        assert 0 < len(written) <= 64 and not (out / "dataset.json").exists()
        # no half-written bag the driver could see: a staging directory left is one a worker wrote to
        # after the driver had finished (it outlived its cluster for a moment); no reader takes it
        left = [p for p in out.iterdir() if p.name.endswith(".partial")]
        assert all(batch._last_written(p) > driver_done for p in left), sorted(p.name for p in out.iterdir())
        assert not [p for p in left if journal_path(p).exists()] and not set(left) & set(written)
    finally:
        _stop(cluster)


def _parent(pid: int) -> int | None:
    """The parent process id of ``pid`` (None once it is gone)."""
    try:
        return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])
    except (OSError, ValueError, IndexError):
        return None


def _name(pid: int) -> str:
    """The process's name; "" once it has exited (a Ray worker may end between listing and reading)."""
    try:
        return Path(f"/proc/{pid}/comm").read_text().strip()
    except (FileNotFoundError, ProcessLookupError):
        return ""


def test_an_unreachable_ray_address_is_refused_at_once(tmp_path, capsys):
    address = f"127.0.0.1:{_free_port()}"  # nothing listens there
    assert batch.main([*SMALL, "--out", str(tmp_path / "ds"), "--ray", address]) == 2
    err = capsys.readouterr().err
    assert f"cannot reach the Ray cluster at --ray={address!r}" in err, err
    assert not (tmp_path / "ds").exists()  # (it was left behind, empty: an outside tester's)


def test_a_port_where_another_service_listens_is_refused_at_once(tmp_path, capsys):
    """An HTTP server where a Ray head was expected: Ray's driver retried "Failed to get cluster ID
    from GCS server" for ever (an outside tester's run, killed after 150 s)."""
    import http.server
    import threading

    server = http.server.HTTPServer(("127.0.0.1", 0), http.server.SimpleHTTPRequestHandler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    address = f"127.0.0.1:{server.server_address[1]}"
    try:
        assert batch.main([*SMALL, "--out", str(tmp_path / "ds"), "--ray", address]) == 2
    finally:
        server.shutdown()
        server.server_close()
    err = capsys.readouterr().err
    assert f"no Ray head answers at --ray={address!r}: something listens there but it did not answer as a gRPC" in err, err
    assert not (tmp_path / "ds").exists()  # (nothing written: no empty --out left)


def test_auto_pointing_at_a_stopped_cluster_or_an_empty_address_is_refused_at_once(tmp_path, capsys, monkeypatch):
    """``--ray auto`` is RAY_ADDRESS or the address the last ``ray start`` here left behind; a stale
    one made Ray retry forever (a run ignored SIGTERM for 40 s). An empty address ran the local pool."""
    address = f"127.0.0.1:{_free_port()}"
    monkeypatch.setenv("RAY_ADDRESS", address)  # what a cluster stopped long ago leaves pointing nowhere
    assert batch.main([*SMALL, "--out", str(tmp_path / "ds"), "--ray", "auto"]) == 2
    err = capsys.readouterr().err
    assert "cannot reach the Ray cluster at --ray='auto' (where --ray='auto' points" in err and address in err, err
    with pytest.raises(SystemExit) as exit_:
        batch.main([*SMALL, "--out", str(tmp_path / "ds"), "--ray", ""])
    assert exit_.value.code == 2 and "argument --ray: '' is no address" in capsys.readouterr().err
    assert not (tmp_path / "ds").exists()  # (nothing written: no empty --out left)


@pytest.mark.parametrize("main", [batch.main, train.main], ids=["soil_sim_batch", "pinn_train"])
@pytest.mark.parametrize("bad", ["0", "-3", "nan", "60", "soon"])
def test_a_give_up_time_ray_cannot_honour_is_refused(main, bad, tmp_path, capsys):
    """--ray-give-up-after: past 50 s Ray's driver aborts the process first (at 60 s); 0 or less
    would give a cluster up at its first slow answer."""
    with pytest.raises(SystemExit) as exit_:
        main(["--out", str(tmp_path / "x"), "--ray", "--ray-give-up-after", bad])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and "argument --ray-give-up-after:" in err and bad in err, err
    assert not (tmp_path / "x").exists()


@pytest.mark.timeout(300)
def test_a_ray_session_leaves_sigterm_to_the_tool_and_a_sigterm_is_said_as_one():
    """ray.init takes SIGTERM over (a handler that exits at once): soil_sim_batch --ray on SIGTERM
    exited 15 with unfinished bags left, and its workers finished them after it died (an outside
    tester found). The tool's handler is put back; and a SIGTERM whose exception a library's C code
    turned into a plain KeyboardInterrupt (Ray's wait does) is still said as a SIGTERM, 143."""
    from soil_msgs_py import interrupts
    from soil_sim_node.ray_cluster import LOCAL, ray_session

    before = ray_processes()
    with interrupts.terminate_as_interrupt():
        mine = signal.getsignal(signal.SIGTERM)
        with ray_session(LOCAL, num_cpus=1):
            assert signal.getsignal(signal.SIGTERM) is mine
            with pytest.raises(interrupts.Terminated):  # (it was the process's death, exit 15)
                os.kill(os.getpid(), signal.SIGTERM)
                time.sleep(5)  # (the handler raises at the next bytecode)
        with pytest.raises(interrupts.Terminated):  # after the session too
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(5)
    with pytest.raises(interrupts.Terminated) as got:  # a SIGTERM's interrupt that came out as a plain one
        with interrupts.terminate_as_interrupt():
            with contextlib.suppress(interrupts.Terminated):
                os.kill(os.getpid(), signal.SIGTERM)
                time.sleep(5)
            raise KeyboardInterrupt  # as it comes out of ray.wait
    assert interrupts.interrupt_exit_code(got.value) == 143
    with pytest.raises(KeyboardInterrupt) as got:  # the next run starts clean: a Ctrl-C is a Ctrl-C
        with interrupts.terminate_as_interrupt():
            raise KeyboardInterrupt
    assert interrupts.interrupt_exit_code(got.value) == 130
    assert not wait_gone(ray_processes() - before)
