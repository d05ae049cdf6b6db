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

import json
import os
import shutil
import subprocess
import sys
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


@pytest.mark.timeout(300)
@pytest.mark.skipif(not _netns_works(), reason="needs `unshare -rn` (a private loopback-only network namespace)")
def test_two_ddp_processes_reach_the_single_process_validation_loss(bags, tmp_path, capsys):
    data = tmp_path / "data"
    shutil.copytree(bags, data)  # its own cache directory, written by rank 0 alone
    assert train_main(["--data", str(data), "--out", str(tmp_path / "one.pt"), "--no-cache", *TINY]) == 0
    capsys.readouterr()
    out = tmp_path / "ddp" / "two.pt"
    run = ("ip link set lo up && exec \"$0\" -m torch.distributed.run --nproc-per-node 2 --master-addr 127.0.0.1 "
           "--master-port 29500 -m pinn_estimator.train \"$@\"")
    env = {**os.environ, "MASTER_ADDR": "127.0.0.1", "GLOO_SOCKET_IFNAME": "lo"}
    proc = subprocess.run(["unshare", "-rn", "sh", "-c", run, sys.executable, "--data", str(data), "--out", str(out),
                           *TINY], env=env, capture_output=True, text=True, timeout=280)
    assert proc.returncode == 0, proc.stderr[-3000:]
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
