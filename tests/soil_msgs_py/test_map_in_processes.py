"""A map over worker processes that fails, in a few seconds and in one line, when a worker dies
(``process_pool.map_in_processes``): ``multiprocessing.Pool`` replaced a killed worker and waited
for its lost task for ever (pinn_train and soil_discrepancy idle, no end, no word)."""
from __future__ import annotations

import os
import signal
from pathlib import Path

import pytest

from soil_msgs_py.process_pool import WorkerDied, map_in_processes


def _square_or_die(x: int) -> int:
    if x == 5:
        os.kill(os.getpid(), signal.SIGKILL)  # what the out-of-memory killer does
    return x * x


def _mark(path: str) -> None:
    Path(path, str(os.getpid())).touch()


@pytest.mark.timeout(60)
def test_results_come_in_order_and_a_dead_worker_is_said():
    assert list(map_in_processes(_square_or_die, [1, 2, 3, 4], 2, what="squaring")) == [1, 4, 9, 16]
    with pytest.raises(WorkerDied, match="a worker process died while squaring"):
        list(map_in_processes(_square_or_die, range(10), 2, what="squaring"))


@pytest.mark.timeout(60)
def test_workers_run_the_initializer_and_ignore_ctrl_c(tmp_path):
    """The terminal's Ctrl-C reaches every worker: the parent takes it, the workers keep still."""
    seen = list(map_in_processes(_sigint_then_square, [2, 3], 2, what="squaring",
                                 initializer=lambda: _mark(str(tmp_path)), start_method="fork"))
    assert seen == [4, 9] and len(list(tmp_path.iterdir())) >= 1


def _sigint_then_square(x: int) -> int:
    os.kill(os.getpid(), signal.SIGINT)
    return x * x


def _signal_dispositions(_) -> tuple[bool, bool]:
    return signal.getsignal(signal.SIGINT) == signal.SIG_IGN, signal.getsignal(signal.SIGTERM) == signal.SIG_DFL


@pytest.mark.timeout(60)
@pytest.mark.parametrize("start_method", ["fork", "spawn"])
def test_workers_of_a_tool_taking_sigterm_as_ctrl_c_die_on_it_and_ignore_ctrl_c(start_method):
    """A tool inside ``terminate_as_interrupt`` forked workers with its SIGTERM handler: a SIGTERM to
    the process group (``timeout``'s) printed each worker's ``Terminated`` traceback. Every worker
    ignores Ctrl-C and takes SIGTERM's default, from fork or spawn alike."""
    from soil_msgs_py.interrupts import terminate_as_interrupt

    with terminate_as_interrupt():
        seen = list(map_in_processes(_signal_dispositions, [0, 1], 2, what="looking", start_method=start_method))
    assert seen == [(True, True), (True, True)]
