"""Which start method a local process pool may use in this process.

``fork`` starts the workers at once with the parent's state (compiled kernels, module globals a
task reads). A process that has imported Ray has Ray's threads, which may hold a lock at the fork
that a child then waits on for ever (seen as a pool that never finished after Ray sessions in one
process: a benchmark, a notebook). There a pool spawns fresh interpreters, which get everything
through their arguments, or the work runs in this process.
"""
from __future__ import annotations

import sys


def fork_is_safe() -> bool:
    """False once this process has imported Ray (its threads may hold locks at a fork)."""
    return "ray" not in sys.modules


def pool_start_method() -> str:
    """``fork`` where it is safe, else ``spawn`` (the tasks and their arguments must pickle)."""
    return "fork" if fork_is_safe() else "spawn"
