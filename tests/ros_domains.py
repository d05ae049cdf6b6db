"""ROS_DOMAIN_IDs for the tests, leased so that no two processes on this machine share one.

Each DDS test runs its nodes on a domain of its own. A fixed or pid-derived id is not enough:
two suites on one machine (two clones, a CI run beside a developer's run) would sooner or
later put two tests on the same domain, and each would read the other's ticks (a replay that
"differs from live", a recorder with foreign messages). So an id is leased: an exclusive
``flock`` on ``<LEASE_DIR>/<id>.lock``, skipped by every other process while held, dropped by
the kernel when the holder exits. A process keeps its newest ``HELD_LEASES`` leases (a test
uses one or two at a time; tests run one after another) and releases older ones as it takes
new ones. The directory is one fixed path for every user and every TMPDIR (DDS domains are
machine-wide), world-writable; ``INSITU_SOIL_DOMAIN_LEASES`` moves it (the lease tests do).
"""
from __future__ import annotations

import fcntl
import itertools
import os
from collections import deque
from pathlib import Path

FIRST_ID, LAST_ID = 100, 230  # the DDS tests' range (0..99 are left to users and benchmarks)
HELD_LEASES = 6
LEASE_DIR = Path(os.environ.get("INSITU_SOIL_DOMAIN_LEASES", "/tmp/insitu-soil-ros-domains"))

_span = LAST_ID - FIRST_ID + 1
_next = itertools.count(os.getpid() % _span)  # processes start at different ids: fewer collisions to skip
_held: deque[tuple[int, int]] = deque()  # (domain id, locked fd), oldest first


def _lease_dir() -> Path:
    """LEASE_DIR, made world-writable if this process creates or owns it."""
    LEASE_DIR.mkdir(parents=True, exist_ok=True)
    try:
        os.chmod(LEASE_DIR, 0o777)  # (the umask narrowed mkdir's mode) so other users' suites lease too
    except PermissionError:  # another user's directory: theirs to open up
        pass
    return LEASE_DIR


def _try_lease(domain_id: int) -> int | None:
    """The locked fd of ``domain_id``'s lease file, or None if another holder has it (or this
    user may not open it: the id is then someone else's to use)."""
    path = _lease_dir() / f"{domain_id}.lock"
    try:
        fd = os.open(path, os.O_CREAT | os.O_RDONLY, 0o666)  # flock needs no write access; not inherited
    except PermissionError:
        return None
    try:
        os.fchmod(fd, 0o666)
    except PermissionError:  # another user's file: still lockable read-only
        pass
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:  # held by another process (or by an older lease of ours: flock is per open file)
        os.close(fd)
        return None
    return fd


def next_domain_id() -> int:
    """A domain id in FIRST_ID..LAST_ID that no other process on this machine holds now."""
    for _ in range(_span):
        domain_id = FIRST_ID + next(_next) % _span
        fd = _try_lease(domain_id)
        if fd is None:
            continue
        _held.append((domain_id, fd))
        while len(_held) > HELD_LEASES:
            os.close(_held.popleft()[1])
        return domain_id
    raise RuntimeError(f"every test ROS_DOMAIN_ID {FIRST_ID}..{LAST_ID} is leased by other processes "
                       f"(lock files in {LEASE_DIR}); too many suites at once on this machine")
