"""Counts and seeds of the command-line tools, checked when the arguments are parsed (no ROS).

Why here: ``--workers -1`` or ``--seed -1`` was taken as given and either meant something else
(one process) or failed later in a library's words that do not name the option ("Seed must be
between 0 and 2**32 - 1", "expected non-negative integer"). As an argparse ``type`` the tool
refuses it at once, naming the option and the value (exit 2), like ``cli_paths``.
"""
from __future__ import annotations

import argparse

# numpy's legacy seeding (np.random.seed, which the PINN's training calls) takes [0, 2**32 - 1]
# (a simulated episode's seed is wider: episode.MAX_SEED)
MAX_NUMPY_SEED = 2**32 - 1


def _integer(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None


def workers(text: str) -> int:
    """``--workers`` of a tool that starts that many processes: an integer >= 1."""
    value = _integer(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text!r} must be an integer >= 1 (processes)")
    return value


def seed(text: str) -> int:
    """``--seed``: an integer in [0, MAX_NUMPY_SEED]."""
    value = _integer(text)
    if not 0 <= value <= MAX_NUMPY_SEED:
        raise argparse.ArgumentTypeError(f"{text!r} must be an integer in [0, 2**32 - 1]")
    return value
