"""Counts and seeds of the command-line tools, checked when the arguments are parsed (no ROS).

Why here: ``--workers -1`` or ``--seed -1`` was taken as given and either meant something else
(one process) or failed later in a library's words that do not name the option ("Seed must be
between 0 and 2**32 - 1", "expected non-negative integer"). As an argparse ``type`` the tool
refuses it at once, naming the option and the value (exit 2), like ``cli_paths``.
"""
from __future__ import annotations

import argparse
import os

# numpy's legacy seeding (np.random.seed, which the PINN's training calls) takes [0, 2**32 - 1]
# (a simulated episode's seed is wider: episode.MAX_SEED)
MAX_NUMPY_SEED = 2**32 - 1
# The most processes (or threads) a tool starts on this machine, per core: a CPU-bound worker
# beyond the cores only waits, and a count far beyond them (``--workers 100000``) forks until the
# machine stops, or makes torch's thread pool fail to map its memory (a segfault).
PER_CORE = 8


def cores() -> int:
    """Cores this process may use (its CPU affinity where the system says it, e.g. in a cpuset)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def local_limit() -> int:
    """The most processes or threads of one tool on this machine: ``PER_CORE`` per core it may use."""
    return PER_CORE * cores()


def check_local_count(name: str, value: int) -> int:
    """``value`` if it is at most ``local_limit()``; else ValueError naming ``name`` and the value."""
    if value > local_limit():
        raise ValueError(f"{name}={value} is more than this machine can use: at most {local_limit()} "
                         f"({PER_CORE} per core, {cores()} cores)")
    return value


def _integer(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None


def workers(text: str) -> int:
    """``--workers`` of a tool that starts that many processes here: an integer in [0, local_limit()],
    0 meaning one per core (as ``soil_sim_batch --workers 0`` always did: the tools disagreed)."""
    value = _integer(text)
    if not 0 <= value <= local_limit():
        raise argparse.ArgumentTypeError(f"{text!r} must be an integer in [0, {local_limit()}] (processes: "
                                         f"{PER_CORE} per core of this machine at the most; 0: one per core)")
    return value or cores()


def seed(text: str) -> int:
    """``--seed``: an integer in [0, MAX_NUMPY_SEED]."""
    value = _integer(text)
    if not 0 <= value <= MAX_NUMPY_SEED:
        raise argparse.ArgumentTypeError(f"{text!r} must be an integer in [0, 2**32 - 1]")
    return value
