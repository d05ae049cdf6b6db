"""The tests' ROS_DOMAIN_ID leases keep two processes (two suites at once) off each other's domain."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from tests import ros_domains
from tests.ros_domains import next_domain_id

ROOT = Path(__file__).resolve().parents[2]


def _in_another_process(code: str):
    out = subprocess.run([sys.executable, "-c", "import json\nfrom tests import ros_domains\n" + code],
                         cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


def test_a_domain_leased_here_is_skipped_by_another_process_and_freed_when_its_holder_exits():
    mine = [next_domain_id() for _ in range(ros_domains.HELD_LEASES)]
    assert len(set(mine)) == len(mine)
    # another process walks the whole range and never gets one of ours
    theirs = _in_another_process(
        "span = ros_domains.LAST_ID - ros_domains.FIRST_ID + 1 - ros_domains.HELD_LEASES\n"
        "print(json.dumps([ros_domains.next_domain_id() for _ in range(span)]))")
    assert not set(mine) & set(theirs)
    assert _in_another_process(f"print(json.dumps(ros_domains._try_lease({mine[0]}) is None))") is True
    # a lease another process held until it exited is free again
    assert _in_another_process(f"print(json.dumps(ros_domains._try_lease({theirs[-1]}) is not None))") is True
    fd = ros_domains._try_lease(theirs[-1])
    assert fd is not None
    os.close(fd)


def test_a_process_keeps_only_its_newest_leases():
    taken = [next_domain_id() for _ in range(ros_domains.HELD_LEASES + 2)]
    oldest, newest = taken[:2], taken[2:]
    held = _in_another_process(f"print(json.dumps([ros_domains._try_lease(d) is None for d in {taken}]))")
    assert held == [False] * len(oldest) + [True] * len(newest)
