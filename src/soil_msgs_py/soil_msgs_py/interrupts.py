"""SIGTERM handled like Ctrl-C by the offline tools (``soil_sim_batch``, ``pinn_train``, and through
``interruptible`` the others that write their output at their end).

Why: SIGTERM is what ``timeout``, a batch scheduler (SLURM) and a container runtime send. With
its default action the tool died at once, silently, leaving its pool workers orphaned and still
writing bags; handled as an interrupt it takes the Ctrl-C path: the finished work is kept, its
own staging removed, one line said, exit 128 + 15.

Processes that stop together (the ranks of a torchrun job) note the signal instead of raising it
(``stop_requests``): raised, it would leave one rank inside a collective its peers have left, and
under torchrun every rank gets Ctrl-C twice (from the terminal, then forwarded by torchrun), so a
second interrupt cannot mean "stop harder" there."""
from __future__ import annotations

import contextlib
import functools
import os
import signal
import sys
import warnings

EXIT_INTERRUPTED = 130  # 128 + SIGINT
EXIT_TERMINATED = 143  # 128 + SIGTERM


class Terminated(KeyboardInterrupt):
    """A SIGTERM, raised where a KeyboardInterrupt would be (so every Ctrl-C path handles it)."""


# Whether a SIGTERM came within the present ``terminate_as_interrupt``: a handler's exception raised
# inside a library's C code can come out as a plain KeyboardInterrupt (Ray's wait turns any
# signal's into one), and the run then said "Ctrl-C", 130. Leaving the context turns such an
# interrupt back into ``Terminated`` and clears the note, so the exception's type stays the one
# thing that tells (nothing leaks into a later run in the same process). So does an error leaving
# it after a SIGTERM: a handler's exception raised inside a callback Python calls from C (an
# at-fork hook, ``__del__``) is printed as "Exception ignored" and lost, and what then failed (a
# pool whose workers the same SIGTERM stopped) is the stop's consequence, not a fault to report.
_received = {"sigterm": False}


def _raise_terminated(signum, frame):  # noqa: ARG001
    _received["sigterm"] = True
    raise Terminated()


@contextlib.contextmanager
def terminate_as_interrupt():
    """Within: SIGTERM raises ``Terminated`` in the main thread; the previous handler after (unless
    a handler was put in place within, e.g. ``end_at_further_stops``: that one stays). A context
    inside another leaves the outer one's note of a SIGTERM as it found it."""
    outer = _received["sigterm"]
    _received["sigterm"] = False
    previous = signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        yield
    except KeyboardInterrupt as exc:
        if _received["sigterm"] and not isinstance(exc, Terminated):
            raise Terminated() from exc
        raise
    except Exception as exc:
        if _received["sigterm"]:
            raise Terminated() from exc
        raise
    finally:
        _received["sigterm"] = outer
        if signal.getsignal(signal.SIGTERM) is _raise_terminated:
            signal.signal(signal.SIGTERM, previous)


def interrupt_exit_code(exc: BaseException) -> int:
    """143 for a SIGTERM, 130 for a Ctrl-C."""
    return EXIT_TERMINATED if isinstance(exc, Terminated) else EXIT_INTERRUPTED


def interrupt_name(exc: BaseException) -> str:
    """How the run was stopped, for a stop reason: 'SIGTERM' or 'Ctrl-C'."""
    return "SIGTERM" if isinstance(exc, Terminated) else "Ctrl-C"


def said_interrupted(prog: str, exc: KeyboardInterrupt, outcome: str) -> int:
    """One line on stderr for an offline tool stopped by Ctrl-C or SIGTERM (``outcome``: what is
    left, e.g. "no report written"), and its exit code; an error that came after the SIGTERM and was
    taken for it (``terminate_as_interrupt``) is named in it. A second signal waits for the line."""
    cause = exc.__cause__
    after = (f" (then: {type(cause).__name__}: {cause})" if isinstance(cause, Exception) else "")
    with stop_requests():
        print(f"{prog}: interrupted ({interrupt_name(exc)}); {outcome}{after}", file=sys.stderr)
    return interrupt_exit_code(exc)


def interruptible(prog: str, outcome: str = "its output is not written: run it again"):
    """Decorator for an offline tool's ``main(argv)`` that writes its output at its end: Ctrl-C or
    SIGTERM within says one line (``said_interrupted``) and returns 130 / 143. Why: these tools
    (minutes of calibration or evaluation) printed a KeyboardInterrupt traceback, and died
    silently on SIGTERM, the signal of ``timeout`` and a batch scheduler."""
    def wrap(main):
        @functools.wraps(main)
        def run(argv=None):
            try:
                with terminate_as_interrupt():
                    return main(argv)
            except KeyboardInterrupt as exc:
                return said_interrupted(prog, exc, outcome)
        return run
    return wrap


class StopRequest:
    """The SIGINT and SIGTERM received inside ``stop_requests``: ``signum`` the first (None: none
    yet), ``signums`` each kind once, in the order they came."""

    def __init__(self) -> None:
        self.signums: list[int] = []

    @property
    def signum(self) -> int | None:
        return self.signums[0] if self.signums else None

    def _note(self, signum, frame) -> None:  # noqa: ARG002
        if signum not in self.signums:
            self.signums.append(signum)


def interrupt_for(signum: int) -> KeyboardInterrupt:
    """The exception the Ctrl-C paths take for a noted signal: Terminated for SIGTERM."""
    return Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()


@contextlib.contextmanager
def stop_requests():
    """Within: SIGINT and SIGTERM are noted on the yielded ``StopRequest``, never raised; the
    previous handlers after."""
    request = StopRequest()
    previous = {sig: signal.signal(sig, request._note) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield request
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


@contextlib.contextmanager
def interrupts_deferred():
    """Within: SIGINT and SIGTERM are noted, not handled, and blocked in this thread; on leaving,
    the previous handlers are back and each signal noted (or still pending) is handled as it
    would have been, a moment later, in the order they came. For starting worker processes, which inherit the blocked
    signals and unblock them once their own dispositions are set (``unblock_stop_signals``).

    Why: a fork runs Python's at-fork hooks (logging's lock, in the parent and the child), and a
    KeyboardInterrupt or ``Terminated`` a handler raises inside one is printed as "Exception
    ignored" and lost: a tool sent SIGTERM to its process group while its pool started ran on, took
    its workers' death for a failure and exited 1 (not 143), and a Ctrl-C could be lost alike. A
    spawned worker (a fresh interpreter) took the terminal's Ctrl-C while it still imported, each
    printing a KeyboardInterrupt traceback. Outside the main thread (no handler can be set there)
    nothing changes."""
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield None
        return
    request = None
    try:
        with stop_requests() as request:
            blocked = signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
            try:
                yield request
            finally:  # (a signal pending on this thread is handled here: the noting handler takes it)
                signal.pthread_sigmask(signal.SIG_SETMASK, blocked)
    finally:
        # each kind noted, in order, as its handler takes it: a pool worker (Ctrl-C ignored) deferring
        # its kernel's warm-up had noted the terminal's Ctrl-C first and its pool's SIGTERM after; only
        # the Ctrl-C was raised again, ignored, and the worker ran the whole batch on after the stop
        for signum in request.signums if request is not None else ():
            signal.raise_signal(signum)


def unblock_stop_signals() -> None:
    """SIGINT and SIGTERM unblocked in this thread: a worker started inside ``interrupts_deferred``
    calls it once its dispositions are set, and a signal that came meanwhile is handled by them."""
    signal.pthread_sigmask(signal.SIG_UNBLOCK, STOP_SIGNALS)


def run_tool(prog: str, module: str, argv=None):
    """A console script's whole run with its stops handled from the first instant: ``module`` imported
    and its ``main(argv)`` run inside ``terminate_as_interrupt``; a stop the tool does not say itself
    is said here in one line (130 / 143); once the tool has ended, a further Ctrl-C or SIGTERM ends
    the process at once with the tool's own exit code (``end_at_further_stops``).

    Why: the tools' imports take up to 2 s (torch, scipy, matplotlib), and a Ctrl-C there printed
    a traceback, a SIGTERM killed the tool in silence (exit −15); a second signal after the tool had
    said how it stopped (an impatient Ctrl-C, ``timeout``'s SIGTERM after the terminal's) killed it
    with −2 / −15, or printed a traceback from the interpreter's exit."""
    import atexit
    import importlib

    script = argv is None  # a console script's process; called with argv (a notebook), handlers are given back
    if script:
        # a warning of the tool's own code (a soil the FEE resists nothing in while rising) in the tool's one-line
        # form, as its other warnings: it printed Python's, the source file and line of the warning call beneath;
        # the libraries' (numpy's RuntimeWarnings, deprecations) keep Python's form, which names their kind
        shown = warnings.showwarning

        def one_line(message, category, *args, **kwargs):
            if category is UserWarning:
                print(f"{prog}: warning: {message}", file=sys.stderr)
            else:
                shown(message, category, *args, **kwargs)

        warnings.showwarning = one_line
        # the last exit hook to run (registered before the tool's own): from there on the interpreter
        # tears its modules down with Python's handlers gone, and a signal then killed the tool
        # (−2 / −15) however it had ended
        atexit.register(_ignore_stops)
    previous = {sig: signal.getsignal(sig) for sig in STOP_SIGNALS}
    main, code = None, 1
    try:
        with terminate_as_interrupt():
            main = importlib.import_module(module).main
            code = main(argv)
            if script:
                end_at_further_stops(code)  # (within: no moment between the tool's end and this)
    except KeyboardInterrupt as exc:
        code = said_interrupted(prog, exc, "it stopped as it started: nothing was done" if main is None else
                                "it stopped before its end: run it again")
    except SystemExit as exc:  # (argparse's --help and refusals)
        code = exc.code
        raise
    finally:
        if script:
            end_at_further_stops(code)
        else:
            for sig, handler in previous.items():
                signal.signal(sig, handler)
    return code


def tool_entry(prog: str, module: str):
    """A console script's entry function, ``prog(argv=None)``, running ``module``'s ``main`` through
    ``run_tool``; ``module`` is kept on it as ``tool_module``. Each package's ``entry_points.py``
    names its tools so: that module and the package's ``__init__`` import nothing heavy."""
    def entry(argv=None):
        return run_tool(prog, module, argv)

    entry.__name__ = entry.__qualname__ = prog
    entry.tool_module = module
    return entry


TEARDOWN_LIMIT_S = 30  # most the interpreter's teardown may take once the stop signals are ignored


def _ignore_stops() -> None:
    """SIGINT and SIGTERM ignored (``run_tool``'s last exit hook): Python keeps an ignored signal
    ignored while it finalises, where it resets a handled one to the default action. A teardown that
    hangs (a library's thread or destructor) cannot be stopped by them then, so an alarm ends it
    after ``TEARDOWN_LIMIT_S`` (SIGALRM's default action), not only SIGKILL."""
    try:
        for sig in STOP_SIGNALS:
            signal.signal(sig, signal.SIG_IGN)
        signal.signal(signal.SIGALRM, signal.SIG_DFL)
        signal.alarm(TEARDOWN_LIMIT_S)
    except ValueError:  # not the main thread
        pass


def end_at_further_stops(code) -> None:
    """From here on a SIGINT or SIGTERM ends this process at once, its streams flushed, with
    ``code`` (an exit status; None is 0, anything else not an int 1): the tool has ended and said
    how; what is left is the interpreter's exit. A signal the process ignores (Ctrl-C in a
    background job) stays ignored."""
    status = code if isinstance(code, int) else (0 if code is None else 1)

    def end(signum, frame):  # noqa: ARG001
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError):  # (a closed or broken stream: nothing more to say)
                pass
        # pool workers the exit would have waited for (a map that lets its workers finish their task):
        # left behind by os._exit they waited on their queue for ever, holding the tool's output open
        if "multiprocessing" in sys.modules:
            for child in sys.modules["multiprocessing"].active_children():
                child.terminate()
        os._exit(status)

    try:
        for sig in STOP_SIGNALS:
            if signal.getsignal(sig) != signal.SIG_IGN:  # (a background job's Ctrl-C stays ignored)
                signal.signal(sig, end)
    except ValueError:  # not the main thread: nothing to do there
        pass
