"""load_dataset over Ray (``ray_address``): the local reader's arrays exactly, the same bad
bag named or skipped, on a local Ray instance whose every process listens on loopback only and
is gone afterwards."""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from pinn_estimator import dataset
from pinn_estimator.dataset import load_dataset
from soil_bag_tools.bag_io import BagReadError
from soil_sim_node.ray_cluster import LOCAL, ray_session
from tests.ray_probe import is_loopback, listening_addresses, ray_processes, wait_gone
from tests.tiny_data import write_tiny_bags

pytestmark = pytest.mark.live

ARRAYS = ("offsets", "observations", "forces", "known", "truth")


@pytest.fixture(autouse=True)
def no_ray_usage_stats(monkeypatch):
    monkeypatch.setenv("RAY_USAGE_STATS_ENABLED", "0")


def _same(a, b) -> bool:
    return (a.names == b.names and a.metas == b.metas and a.fingerprint == b.fingerprint and a.skipped == b.skipped
            and all(np.array_equal(getattr(a, k), getattr(b, k)) for k in ARRAYS))


@pytest.mark.timeout(300)
def test_reading_bags_over_ray_equals_the_local_reader(tmp_path, monkeypatch):
    root = write_tiny_bags(tmp_path / "bags")
    monkeypatch.setattr(dataset, "RAY_BAGS_PER_TASK", 4)  # 6 good bags + 1 bad: two tasks
    broken = root / "zz_truncated"
    shutil.copytree(min(p for p in root.iterdir() if p.is_dir()), broken)
    mcap = next(broken.glob("*.mcap"))
    mcap.write_bytes(mcap.read_bytes()[: mcap.stat().st_size // 2])

    local = load_dataset(root, cache=False, skip_bad_bags=True, log=lambda _: None)
    before = ray_processes()
    with ray_session(LOCAL, num_cpus=2):
        ours = ray_processes() - before
        listening = listening_addresses(ours)
        over_ray = load_dataset(root, cache=False, skip_bad_bags=True, log=lambda _: None, ray_address=LOCAL)
        with pytest.raises(BagReadError, match="zz_truncated"):
            load_dataset(root, cache=False, ray_address=LOCAL)
    assert not wait_gone(ours), "the local Ray instance left processes running"
    assert listening and all(is_loopback(ip) for _, ip in listening), listening
    assert len(local) == 6 and [Path(s["bag"]).name for s in local.skipped] == ["zz_truncated"]
    assert _same(local, over_ray)
    # two local processes again, in this process that has run Ray (a fork there may hang): spawned
    assert _same(local, load_dataset(root, cache=False, skip_bad_bags=True, log=lambda _: None, workers=2))
