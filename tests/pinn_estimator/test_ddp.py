"""pinn_train under torchrun: 2 processes (DistributedDataParallel, gloo) against one.

torchrun runs inside a private network namespace whose only interface is loopback: its
rendezvous store listens on every interface of its namespace, and there that is 127.0.0.1 alone.
Dropout is off so that the two runs differ only by what DDP changes: the order in which the
gradients are summed (float rounding, ~1e-7 relative per step) and the weighting of the
masked-mean loss terms by windows rather than masked windows (none: every window of these
episodes is in soil). A 1e-3 relative tolerance on every epoch's losses is far above the first
and far below a wrong gradient (a step on another share of the batch than the single process's
changes them by percent). That the shares partition each batch is checked by the window count.
"""
from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from pinn_estimator.checkpoint import load_model
from pinn_estimator.dataset import CACHE_DIR_NAME
from pinn_estimator.distributed import Ranks, ranks_from_env, share
from pinn_estimator.train import main as train_main
from tests.tiny_data import write_tiny_bags

pytestmark = pytest.mark.live

TINY = ["--d-model", "16", "--n-heads", "2", "--n-layers", "1", "--ff-dim", "32", "--dropout", "0", "--epochs", "3",
        "--batch-size", "64", "--threads", "2", "--quiet"]


def torchrun_env(scratch: Path) -> dict:
    """torchrun's environment: loopback, and TMPDIR in the test's own directory (torchrun makes a
    ``torchelastic_*`` directory in TMPDIR at every start and leaves it: /tmp held 112 of them)."""
    return {**os.environ, "MASTER_ADDR": "127.0.0.1", "GLOO_SOCKET_IFNAME": "lo", "TMPDIR": str(scratch)}


def _torchrun(*train_args: str) -> list[str]:
    """``torchrun --nproc-per-node 2 -m pinn_estimator.train ARGS`` in a loopback-only network
    namespace; the process started is torchrun's own (unshare and sh exec into it)."""
    run = ("ip link set lo up && exec \"$0\" -m torch.distributed.run --nproc-per-node 2 --master-addr 127.0.0.1 "
           "--master-port 29500 -m pinn_estimator.train \"$@\"")
    return ["unshare", "-rn", "sh", "-c", run, sys.executable, *train_args]


def _netns_works() -> bool:
    if not (shutil.which("unshare") and shutil.which("ip")):
        return False
    return subprocess.run(["unshare", "-rn", "ip", "link", "set", "lo", "up"], capture_output=True).returncode == 0


@pytest.fixture(scope="module")
def bags(tmp_path_factory) -> Path:
    return write_tiny_bags(tmp_path_factory.mktemp("ddp_bags"))


def test_shares_cover_a_batch_once_and_torchrun_variables_are_checked():
    for n in (0, 1, 5, 64):
        parts = [share(n, Ranks(r, 3, 3)) for r in range(3)]
        assert [i for p in parts for i in range(n)[p]] == list(range(n))
        assert max(p.stop - p.start for p in parts) - min(p.stop - p.start for p in parts) <= 1
    assert ranks_from_env({}) == Ranks(0, 1, 1)
    assert ranks_from_env({"RANK": "1", "WORLD_SIZE": "4", "LOCAL_WORLD_SIZE": "2"}) == Ranks(1, 4, 2)
    with pytest.raises(ValueError, match="WORLD_SIZE='two'"):
        ranks_from_env({"WORLD_SIZE": "two"})
    with pytest.raises(ValueError, match="RANK=2, WORLD_SIZE=2"):
        ranks_from_env({"RANK": "2", "WORLD_SIZE": "2"})
    # more processes on this machine than its cores can take (17 ranks on 2 cores ran, exit 0)
    with pytest.raises(ValueError, match=r"LOCAL_WORLD_SIZE \(torchrun --nproc-per-node\)=100000 is more than"):
        ranks_from_env({"RANK": "0", "WORLD_SIZE": "100000", "LOCAL_WORLD_SIZE": "100000"})
    assert ranks_from_env({"RANK": "0", "WORLD_SIZE": "100000", "LOCAL_WORLD_SIZE": "2"}).world == 100000  # a fleet


def test_pinn_train_refuses_a_malformed_torchrun_variable(bags, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("WORLD_SIZE", "many")
    assert train_main(["--data", str(bags), "--out", str(tmp_path / "m.pt"), *TINY]) == 2
    assert "WORLD_SIZE='many'" in capsys.readouterr().err and not (tmp_path / "m.pt").exists()


def _gloo_abort(stderr: str) -> bool:
    """Whether a torchrun run failed because a rank died of SIGABRT in gloo's own threads (upstream:
    pytorch/pytorch#188266, gloo's tcp pair aborting the process when the peer address cannot be
    read; seen once in this namespace on a busy machine, "terminate called without an active
    exception"), not by anything the trainer did: the trainer raises Python errors, never aborts."""
    return "exitcode  : -6" in stderr and "terminate called" in stderr


@pytest.mark.timeout(300)
@pytest.mark.skipif(not _netns_works(), reason="needs `unshare -rn` (a private loopback-only network namespace)")
def test_two_ddp_processes_reach_the_single_process_validation_loss(bags, tmp_path, capsys):
    assert train_main(["--data", str(bags), "--out", str(tmp_path / "one.pt"), "--no-cache", *TINY]) == 0
    capsys.readouterr()
    for attempt in (1, 2):  # once more after gloo's own abort (_gloo_abort), on fresh bags and output
        data, out = tmp_path / f"data{attempt}", tmp_path / f"ddp{attempt}" / "two.pt"
        shutil.copytree(bags, data)  # its own cache directory, written by rank 0 alone
        proc = subprocess.run(_torchrun("--data", str(data), "--out", str(out), *TINY), env=torchrun_env(tmp_path),
                              capture_output=True, text=True, timeout=130)
        if proc.returncode == 0 or not _gloo_abort(proc.stderr):
            break
    # the ranks write to torchrun's stderr, before its own failure summary (~2.5 kB): keep both
    assert proc.returncode == 0, proc.stderr[-12000:]
    assert proc.stdout.count('"checkpoint"') == 1, proc.stdout  # rank 0 alone reports
    assert json.loads(proc.stdout[proc.stdout.index("{"):])["checkpoint"] == str(out)
    assert sorted(p.name for p in out.parent.iterdir()) == ["two.pt", "two_curve.png"]
    assert len(list((data / CACHE_DIR_NAME).iterdir())) == 1  # one cache file, no leftover temporaries
    _, one = load_model(tmp_path / "one.pt")
    _, two = load_model(out)  # the plain model's weights (no DDP "module." prefix), strict load
    assert (one["metrics"]["processes"], two["metrics"]["processes"]) == (1, 2)
    assert two["split"] == one["split"]
    assert two["metrics"]["train_windows_per_epoch"] == one["metrics"]["train_windows_per_epoch"] > 0
    assert two["history"]["epoch"] == one["history"]["epoch"] == [1, 2, 3]
    assert two["history"]["val_loss"] == pytest.approx(one["history"]["val_loss"], rel=1e-3)
    assert two["history"]["train_loss"] == pytest.approx(one["history"]["train_loss"], rel=1e-3)


def _ranks(agent: int) -> dict[int, int]:
    """{rank: pid} of the processes torchrun ``agent`` started (RANK from their environment)."""
    out = {}
    for pid in Path(f"/proc/{agent}/task/{agent}/children").read_text().split():
        with contextlib.suppress(OSError):
            env = Path(f"/proc/{pid}/environ").read_bytes().split(b"\0")
            out.update({int(e[5:]): int(pid) for e in env if e.startswith(b"RANK=")})
    return out


def _train_until_epoch(bags: Path, out: Path, log: Path, epochs: int) -> subprocess.Popen:
    """A 2-process training far longer than the test, returned once its progress bar shows
    ``epochs`` validated epochs (a best model to keep); its stderr goes to ``log``."""
    # (--max-minutes: a test that fails before it stops the job leaves no training running for long)
    args = [*TINY, "--epochs", "100000", "--patience", "100000", "--max-minutes", "3"]
    args.remove("--quiet")
    proc = subprocess.Popen(_torchrun("--data", str(bags), "--out", str(out), *args), env=torchrun_env(log.parent),
                            stdout=subprocess.PIPE, stderr=log.open("w"), text=True, start_new_session=True)
    deadline = time.monotonic() + 200
    while proc.poll() is None and time.monotonic() < deadline:
        if re.search(rf"training pinn:.*\| *{epochs}/100000", log.read_text(errors="replace")):
            return proc
        time.sleep(0.2)
    proc.kill()
    raise AssertionError(f"the training never showed {epochs} epochs: {log.read_text(errors='replace')[-2000:]}")


@pytest.mark.timeout(300)
@pytest.mark.skipif(not _netns_works(), reason="needs `unshare -rn` (a private loopback-only network namespace)")
def test_ctrl_c_or_a_killed_rank_under_torchrun_keeps_the_best_model(bags, tmp_path):
    """Ctrl-C in a terminal reaches every process of torchrun's group, and torchrun forwards it
    once more: rank 0 took the second as "stop harder" and wrote nothing (and gloo aborted).
    Now every rank notes the signal and stops at one step, and rank 0 writes the best model. A
    rank killed outright (OOM, a node lost) broke rank 0's collective with a RuntimeError that
    lost the training: now rank 0 writes the best model it holds and says what happened."""
    data = tmp_path / "data"
    shutil.copytree(bags, data)
    out = tmp_path / "ctrl_c" / "m.pt"
    proc = _train_until_epoch(data, out, tmp_path / "ctrl_c.log", 3)
    try:
        os.killpg(proc.pid, signal.SIGINT)  # what the terminal does: every process of the foreground group
        stdout = proc.communicate(timeout=120)[0]
    finally:
        proc.kill()
    err = (tmp_path / "ctrl_c.log").read_text(errors="replace")
    assert stdout.count('"checkpoint"') == 1, stdout + err[-3000:]
    # (torchrun's own agent may still print its traceback and, at its exit under load, a C++
    # "terminate called": the ranks' outcome is what is checked)
    assert "nothing written" not in err and "pinn_train: interrupted (Ctrl-C) in epoch" in err, err[-3000:]
    _, ckpt = load_model(out)
    metrics = ckpt["metrics"]
    assert re.fullmatch(r"interrupted \(Ctrl-C\) in epoch \d+", metrics["stop_reason"]), metrics["stop_reason"]
    assert metrics["processes"] == 2 and metrics["epochs_run"] >= 3 and metrics["best_epoch"] <= metrics["epochs_run"]
    assert len(ckpt["history"]["val_loss"]) == metrics["epochs_run"]

    out = tmp_path / "killed" / "m.pt"
    proc = _train_until_epoch(data, out, tmp_path / "killed.log", 3)
    try:
        os.kill(_ranks(proc.pid)[1], signal.SIGKILL)
        stdout = proc.communicate(timeout=120)[0]
    finally:
        proc.kill()
    err = (tmp_path / "killed.log").read_text(errors="replace")
    assert proc.returncode != 0, "torchrun reports the job as failed"
    assert "pinn_train: error: another process of the job failed in epoch" in err, err[-3000:]
    assert f"the best model validated before it is written to {out}" in err, err[-3000:]
    _, ckpt = load_model(out)
    assert ckpt["metrics"]["stop_reason"].startswith("another process of the job failed in epoch")
    assert stdout.count('"checkpoint"') == 1

    # torchrun itself killed outright (kill -9, the OOM killer): its ranks, each in a session of its
    # own, had trained on to the end (hours under a cluster's --max-minutes, an outside tester's); now
    # each notes its parent gone and stops as on SIGTERM, rank 0 writing the best model
    out = tmp_path / "orphaned" / "m.pt"
    proc = _train_until_epoch(data, out, tmp_path / "orphaned.log", 3)
    ranks = {}
    try:
        ranks = _ranks(proc.pid)
        proc.kill()
        proc.wait(timeout=30)
        deadline = time.monotonic() + 120  # (a bound for a hung rank, not a figure: it is killed after it)
        while any(Path(f"/proc/{pid}").exists() and "zombie" not in _state(pid) for pid in ranks.values()) \
                and time.monotonic() < deadline:
            time.sleep(0.2)
        left = [pid for pid in ranks.values() if Path(f"/proc/{pid}").exists() and "zombie" not in _state(pid)]
    finally:
        for pid in ranks.values():
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGKILL)
    err = (tmp_path / "orphaned.log").read_text(errors="replace")
    assert not left, f"ranks {left} trained on after their torchrun was killed: {err[-3000:]}"
    assert "its torchrun (pid" in err and "is gone; stopping as on SIGTERM" in err, err[-3000:]
    _, ckpt = load_model(out)
    assert re.fullmatch(r"interrupted \(SIGTERM\) in epoch \d+", ckpt["metrics"]["stop_reason"]), ckpt["metrics"]
    assert ckpt["metrics"]["epochs_run"] >= 3


def _state(pid: int) -> str:
    """A process's state as /proc says it ('' once it is gone)."""
    try:
        return Path(f"/proc/{pid}/status").read_text().split("State:")[1].split("\n")[0]
    except (OSError, IndexError):
        return ""
