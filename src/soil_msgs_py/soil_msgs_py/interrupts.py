"""SIGTERM handled like Ctrl-C by the offline tools (``soil_sim_batch``, ``pinn_train``).

Why: SIGTERM is what ``timeout``, a batch scheduler (SLURM) and a container runtime send. With
its default action the tool died at once, silently, leaving its pool workers orphaned and still
writing bags; handled as an interrupt it takes the Ctrl-C path: the finished work is kept, its
own staging removed, one line said, exit 128 + 15."""
from __future__ import annotations

import contextlib
import signal

EXIT_INTERRUPTED = 130  # 128 + SIGINT
EXIT_TERMINATED = 143  # 128 + SIGTERM


class Terminated(KeyboardInterrupt):
    """A SIGTERM, raised where a KeyboardInterrupt would be (so every Ctrl-C path handles it)."""


def _raise_terminated(signum, frame):  # noqa: ARG001
    raise Terminated()


@contextlib.contextmanager
def terminate_as_interrupt():
    """Within: SIGTERM raises ``Terminated`` in the main thread; the previous handler after."""
    previous = signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def interrupt_exit_code(exc: BaseException) -> int:
    """143 for a SIGTERM, 130 for a Ctrl-C."""
    return EXIT_TERMINATED if isinstance(exc, Terminated) else EXIT_INTERRUPTED


def interrupt_name(exc: BaseException) -> str:
    """How the run was stopped, for a stop reason: 'SIGTERM' or 'Ctrl-C'."""
    return "SIGTERM" if isinstance(exc, Terminated) else "Ctrl-C"


def default_sigterm() -> None:
    """For pool workers forked from a process inside ``terminate_as_interrupt``: SIGTERM (which
    ``Pool.terminate`` sends them) ends them, not an interrupt raised in the middle of a task."""
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
