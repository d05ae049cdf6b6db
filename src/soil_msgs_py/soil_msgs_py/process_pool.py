"""Which start method a local process pool may use in this process, and a map over worker
processes that fails when one of them dies.

``fork`` starts the workers at once with the parent's state (compiled kernels, module globals a
task reads). A process that has imported Ray has Ray's threads, which may hold a lock at the fork
that a child then waits on for ever (seen as a pool that never finished after Ray sessions in one
process: a benchmark, a notebook). There a pool spawns fresh interpreters, which get everything
through their arguments, or the work runs in this process.
"""
from __future__ import annotations

import functools
import signal
import sys
from typing import Callable, Iterable, Iterator

from .interrupts import interrupts_deferred, unblock_stop_signals


def fork_is_safe() -> bool:
    """False once this process has imported Ray (its threads may hold locks at a fork)."""
    return "ray" not in sys.modules


def pool_start_method() -> str:
    """``fork`` where it is safe, else ``spawn`` (the tasks and their arguments must pickle)."""
    return "fork" if fork_is_safe() else "spawn"


class WorkerDied(RuntimeError):
    """A worker process of ``map_in_processes`` died (killed: out of memory, a signal)."""


def worker_died(what: str) -> WorkerDied:
    """The error of a pool whose worker died while doing ``what`` (e.g. "reading bags")."""
    return WorkerDied(f"a worker process died while {what} (killed: out of memory, or a signal; or it failed to start: "
                      "its error is above): run again (with fewer --workers if memory was short)")


def map_in_processes(fn: Callable, items: Iterable, workers: int, *, what: str, chunksize: int = 1,
                     initializer: Callable | None = None, start_method: str | None = None,
                     stop_workers: bool = False) -> Iterator:
    """``fn(item)`` for each item, in order, from ``workers`` processes; WorkerDied naming ``what``
    (e.g. "reading bags") if one of them dies. Why not ``multiprocessing.Pool``: it replaces a
    worker that was killed and waits for its lost task for ever (an out-of-memory kill of a
    bag-reading worker left ``pinn_train`` idle with no end and no word, and one of
    ``soil_sim_batch``'s workers left the batch waiting). ``stop_workers``: an error or an
    interrupt also sends the running workers SIGTERM, for tasks too long to wait out (without it
    they finish the task they hold)."""
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor
    from concurrent.futures.process import BrokenProcessPool

    context = mp.get_context(start_method or pool_start_method())
    executor = ProcessPoolExecutor(max_workers=workers, mp_context=context,
                                   initializer=functools.partial(_worker_start, initializer))
    finished = False
    try:
        # the tasks' futures, not executor.map: its results' iterator cancels the queued futures when
        # an interrupt leaves it, and Python 3.11's pool, finding the workers this map then stops,
        # fails every pending future, cancelled ones too, and its manager thread died printing
        # InvalidStateError (beside a busy core, a SIGTERM test's one line had a traceback above it)
        items = list(items)
        with interrupts_deferred():  # the workers start (fork) here: a signal is handled after, not lost in a hook
            futures = [executor.submit(_apply, fn, items[i:i + chunksize]) for i in range(0, len(items), chunksize)]
        for future in futures:
            yield from future.result()
        finished = True
    except BrokenProcessPool:
        raise worker_died(what) from None
    finally:  # an interrupt or an error: the queued tasks are dropped, not run to the end
        if finished:
            executor.shutdown(wait=True)
        else:
            # a second signal (Ctrl-C twice) is handled once the workers are stopped, not in the midst of it
            with interrupts_deferred():
                if stop_workers:
                    # (CPython's own record of the workers; Python 3.14 says it as terminate_workers())
                    for process in list((getattr(executor, "_processes", None) or {}).values()):
                        if process.is_alive():
                            process.terminate()
                # (workers stopped: nothing cancelled, the pool fails what is left as broken)
                executor.shutdown(wait=False, cancel_futures=not stop_workers)


def _apply(fn: Callable, chunk: list) -> list:
    """One task of ``map_in_processes``: ``fn`` over a chunk of its items."""
    return [fn(item) for item in chunk]


def _worker_start(initializer: Callable | None) -> None:
    """A worker ignores Ctrl-C (the terminal sends it to the whole process group): the parent takes
    it and ends the map, where each worker's traceback, and its death read as a broken pool, said
    nothing of use. SIGTERM ends it: a worker forked from a tool inside
    ``interrupts.terminate_as_interrupt`` had its handler, and a SIGTERM to the process group
    (``timeout``'s, a scheduler's) printed each worker's ``Terminated`` traceback. A worker starts
    with both signals blocked (``interrupts_deferred``, forked or spawned alike): one that came while
    it started, or imported, is handled here, a Ctrl-C ignored, a SIGTERM its end."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    unblock_stop_signals()
    if initializer is not None:
        initializer()
