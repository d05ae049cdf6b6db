"""The tests' ROS_DOMAIN_ID leases keep two processes (two suites at once) off each other's domain."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests import ros_domains

pytestmark = pytest.mark.live

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def leases(tmp_path, monkeypatch):
    """This process and the children below lease in a directory of their own (a suite running
    beside this one cannot take an id between two of these steps), from an empty start."""
    monkeypatch.setattr(ros_domains, "LEASE_DIR", tmp_path / "leases")
    monkeypatch.setattr(ros_domains, "_held", type(ros_domains._held)())
    yield tmp_path / "leases"
    for _, fd in ros_domains._held:
        os.close(fd)


def _in_another_process(lease_dir: Path, code: str):
    env = {**os.environ, "INSITU_SOIL_DOMAIN_LEASES": str(lease_dir)}
    out = subprocess.run([sys.executable, "-c", "import json\nfrom tests import ros_domains\n" + code],
                         cwd=ROOT, env=env, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


def test_a_domain_leased_here_is_skipped_by_another_process_and_freed_when_its_holder_exits(leases):
    mine = [ros_domains.next_domain_id() for _ in range(ros_domains.HELD_LEASES)]
    assert len(set(mine)) == len(mine)
    # another process walks the whole range and never gets one of ours
    theirs = _in_another_process(leases,
        "span = ros_domains.LAST_ID - ros_domains.FIRST_ID + 1 - ros_domains.HELD_LEASES\n"
        "print(json.dumps([ros_domains.next_domain_id() for _ in range(span)]))")
    assert not set(mine) & set(theirs)
    assert set(mine) | set(theirs) == set(range(ros_domains.FIRST_ID, ros_domains.LAST_ID + 1))
    assert _in_another_process(leases, f"print(json.dumps(ros_domains._try_lease({mine[0]}) is None))") is True
    # a lease another process held until it exited is free again
    fd = ros_domains._try_lease(theirs[-1])
    assert fd is not None
    os.close(fd)
    # and the lock files are open to every user's suites
    assert (leases.stat().st_mode & 0o777) == 0o777 and (leases / f"{mine[0]}.lock").stat().st_mode & 0o777 == 0o666


def test_a_process_keeps_only_its_newest_leases(leases):
    taken = [ros_domains.next_domain_id() for _ in range(ros_domains.HELD_LEASES + 2)]
    held = _in_another_process(leases, f"print(json.dumps([ros_domains._try_lease(d) is None for d in {taken}]))")
    assert held == [False] * 2 + [True] * ros_domains.HELD_LEASES


def test_every_id_leased_elsewhere_is_a_clear_error_not_a_shared_domain(leases):
    fds = [ros_domains._try_lease(d) for d in range(ros_domains.FIRST_ID, ros_domains.LAST_ID + 1)]
    try:
        err = _in_another_process(leases, "try:\n    ros_domains.next_domain_id()\nexcept RuntimeError as e:\n"
                                          "    print(json.dumps(str(e)))")
    finally:
        for fd in fds:
            os.close(fd)
    assert "every test ROS_DOMAIN_ID 100..230 is leased" in err
