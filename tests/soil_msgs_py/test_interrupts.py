"""Ctrl-C and SIGTERM in the offline tools that write their output at their end
(``interrupts.interruptible``): one line, 130 / 143, no traceback; a real ``pinn_eval`` stopped
by SIGTERM (as ``timeout`` and a scheduler stop it) mid-run."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from soil_msgs_py.interrupts import Terminated, interruptible

SHIPPED_DEFAULT = Path(__file__).resolve().parents[2] / "src" / "pinn_estimator" / "pinn_estimator" / "models" / "pinn_default.pt"


@pytest.mark.parametrize("exc, code, name", [(KeyboardInterrupt, 130, "Ctrl-C"), (Terminated, 143, "SIGTERM")])
def test_an_interrupted_tool_says_one_line_and_exits_128_plus_the_signal(capsys, exc, code, name):
    @interruptible("some_tool")
    def main(argv=None):
        assert argv == ["--x"]
        raise exc()

    before = signal.getsignal(signal.SIGTERM)
    assert main(["--x"]) == code
    assert capsys.readouterr().err == f"some_tool: interrupted ({name}); its output is not written: run it again\n"
    assert interruptible("t")(lambda argv=None: 7)() == 7  # a run that ends gives its own code
    assert signal.getsignal(signal.SIGTERM) is before  # the handler the tool found, given back


def test_pinn_eval_stopped_by_sigterm_mid_run_says_so_and_writes_no_report(tmp_path):
    """SIGTERM had killed it silently; Ctrl-C printed a traceback. Its classical fit's workers, forked
    with its SIGTERM handler, each printed a ``Terminated`` traceback until they took the default."""
    out = tmp_path / "eval"
    log = tmp_path / "log"
    with log.open("w") as f:
        proc = subprocess.Popen([sys.executable, "-m", "pinn_estimator.evaluate", "--checkpoint", str(SHIPPED_DEFAULT),
                                 "--forecast-only", "--forecast-world", "default", "--out", str(out), "--workers", "2"],
                                stdout=f, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        deadline = time.monotonic() + 120  # into the forecast: its classical fit's progress (a run takes ~20 s)
        while "classical FEE fit" not in log.read_text() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.1)
        assert proc.poll() is None, log.read_text()[-2000:]
        os.killpg(proc.pid, signal.SIGTERM)  # to its process group, its fit's workers too, as `timeout` and a scheduler do
        rc = proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    text = log.read_text()
    assert rc == 143, text[-2000:]
    assert "pinn_eval: interrupted (SIGTERM); its output is not written: run it again" in text, text[-2000:]
    assert "Traceback" not in text and not (out.exists() and list(out.glob("*.md"))), text[-2000:]


# --- the console scripts' first instant and last (interrupts.run_tool, soil_msgs_py.tool_entry) ---

_SLOW_TOOL = """
import atexit, os, sys, time
from pathlib import Path
MARKS = Path(os.environ["MARKS"])
(MARKS / "importing").touch()
if os.environ.get("SLOW_IMPORT"):
    time.sleep(2.0)  # a heavy import (torch): where a stop had been a traceback or a silent death

class SlowTeardown:  # a module torn down slowly (torch's): Python's own signal handlers are gone by then
    def __del__(self):
        (MARKS / "tearing_down").touch()
        time.sleep(2.0)


def main(argv=None):
    global kept
    print("done", flush=True)
    def slow_exit():  # the interpreter's exit after the tool has ended
        (MARKS / "exiting").touch()
        time.sleep(2.0)
    if os.environ.get("SLOW_EXIT"):
        atexit.register(slow_exit)
    kept = SlowTeardown()
    return 3
"""


def _run_slow_tool(tmp_path, slow_import: bool, mark: str, sig: int):
    (tmp_path / "slowtool.py").write_text(_SLOW_TOOL)
    marks = tmp_path / "marks"
    marks.mkdir()
    env = dict(os.environ, MARKS=str(marks), PYTHONPATH=f"{tmp_path}{os.pathsep}{os.environ.get('PYTHONPATH', '')}",
               SLOW_IMPORT="1" if slow_import else "", SLOW_EXIT="1" if mark == "exiting" else "")
    script = "import sys; from soil_msgs_py.interrupts import run_tool; sys.exit(run_tool('slowtool', 'slowtool'))"
    proc = subprocess.Popen([sys.executable, "-c", script], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    try:
        deadline = time.monotonic() + 60
        while not (marks / mark).exists() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.02)
        assert (marks / mark).exists(), proc.communicate(timeout=30)
        time.sleep(0.2)  # into the sleep
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    return proc.returncode, out, err


@pytest.mark.timeout(90)
@pytest.mark.parametrize("sig, code, name", [(signal.SIGINT, 130, "Ctrl-C"), (signal.SIGTERM, 143, "SIGTERM")])
def test_a_stop_while_a_tool_still_imports_is_one_line(tmp_path, sig, code, name):
    rc, out, err = _run_slow_tool(tmp_path, slow_import=True, mark="importing", sig=sig)
    assert rc == code, err
    assert err == f"slowtool: interrupted ({name}); it stopped as it started: nothing was done\n" and "done" not in out


@pytest.mark.timeout(90)
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
@pytest.mark.parametrize("mark", ["exiting", "tearing_down"])
def test_a_stop_after_a_tool_ended_ends_it_with_its_own_code(tmp_path, sig, mark):
    """The tool said how it ended (here: done, exit 3); a signal during the interpreter's exit (its
    exit hooks; its modules' teardown, where Python's own handlers are gone) does not change that
    code, nor print a traceback: it had killed the tool, −2 / −15."""
    rc, out, err = _run_slow_tool(tmp_path, slow_import=False, mark=mark, sig=sig)
    assert rc == 3 and out == "done\n" and err == "", (rc, out, err)



def test_a_tools_own_warning_is_one_line_in_the_tools_form(tmp_path):
    """An outside tester's: soil_cut_report printed Python's form of a warning of its own code (the
    source file and line, the warning call's code beneath), where its other warnings are one line."""
    (tmp_path / "warntool.py").write_text("import warnings\n\ndef main(argv=None):\n"
                                          "    warnings.warn('phi=12° is below delta=15°', stacklevel=2)\n"
                                          "    warnings.warn('divide by zero', RuntimeWarning, stacklevel=1)\n    return 0\n")
    env = dict(os.environ, PYTHONPATH=f"{tmp_path}{os.pathsep}{os.environ.get('PYTHONPATH', '')}")
    script = "import sys; from soil_msgs_py.interrupts import run_tool; sys.exit(run_tool('warntool', 'warntool'))"
    done = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=60)
    lines = done.stderr.splitlines()
    assert done.returncode == 0 and lines[0] == "warntool: warning: phi=12° is below delta=15°", done.stderr
    assert "RuntimeWarning: divide by zero" in done.stderr  # a library's kind keeps Python's form, which names it


_POOL_TOOL = """
import os, time
from pathlib import Path
from soil_msgs_py.process_pool import map_in_processes

def task(x):
    Path(os.environ["MARKS"], str(os.getpid())).touch()
    time.sleep(4.0)
    return x

def main(argv=None):
    return sum(map_in_processes(task, range(4), 2, what="waiting", start_method="fork"))
"""


@pytest.mark.timeout(90)
def test_a_second_ctrl_c_ends_the_tool_and_its_pool_workers_too(tmp_path):
    """A map that lets its workers finish their task (``stop_workers`` off) after a first Ctrl-C: the
    second ends the process at once (``end_at_further_stops``); its workers had been left behind,
    waiting on their queue for ever, holding the tool's output open (an outside reviewer's)."""
    (tmp_path / "pooltool.py").write_text(_POOL_TOOL)
    marks = tmp_path / "marks"
    marks.mkdir()
    env = dict(os.environ, MARKS=str(marks), PYTHONPATH=f"{tmp_path}{os.pathsep}{os.environ.get('PYTHONPATH', '')}")
    script = "import sys; from soil_msgs_py.interrupts import run_tool; sys.exit(run_tool('pooltool', 'pooltool'))"
    proc = subprocess.Popen([sys.executable, "-c", script], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True, start_new_session=True)
    workers = []
    try:
        deadline = time.monotonic() + 60
        while len(list(marks.iterdir())) < 2 and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.02)
        workers = [int(p.name) for p in marks.iterdir()]
        assert len(workers) == 2, proc.communicate(timeout=30)
        os.killpg(proc.pid, signal.SIGINT)
        time.sleep(0.3)
        os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=30)
        assert proc.returncode == 130 and "pooltool: interrupted (Ctrl-C)" in err, err
        deadline = time.monotonic() + 10  # (well past the tasks' 4 s: a worker left behind waits for ever)
        while any(Path(f"/proc/{pid}").exists() for pid in workers) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not any(Path(f"/proc/{pid}").exists() for pid in workers), workers
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        for pid in workers:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass


def test_run_tool_called_with_argv_gives_the_process_its_handlers_back(tmp_path, monkeypatch):
    """In-process (a notebook) the handlers are the caller's again after the tool: only a console
    script's process ends at once on a later signal."""
    (tmp_path / "quicktool.py").write_text("def main(argv=None):\n    return len(argv)\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    from soil_msgs_py.interrupts import run_tool

    before = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    assert run_tool("quicktool", "quicktool", ["a", "b"]) == 2
    assert {sig: signal.getsignal(sig) for sig in before} == before


def test_an_error_taken_for_the_stop_is_named_in_its_line(capsys):
    from soil_msgs_py.interrupts import said_interrupted

    try:
        try:
            raise OSError(28, "No space left on device")
        except OSError as err:
            raise Terminated() from err
    except Terminated as exc:
        assert said_interrupted("t", exc, "nothing written") == 143
    assert capsys.readouterr().err == "t: interrupted (SIGTERM); nothing written (then: OSError: [Errno 28] No space left on device)\n"


def test_a_signal_the_process_ignores_stays_ignored_after_the_tool():
    """A background job (``tool &``) has Ctrl-C ignored: the tool's end does not make it fatal."""
    script = ("import signal, sys\nsignal.signal(signal.SIGINT, signal.SIG_IGN)\n"
              "from soil_msgs_py.interrupts import end_at_further_stops\nend_at_further_stops(0)\n"
              "print(signal.getsignal(signal.SIGINT) == signal.SIG_IGN, signal.getsignal(signal.SIGTERM) != signal.SIG_DFL)\n")
    res = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert res.stdout.split() == ["True", "True"], res.stdout + res.stderr


def test_every_kind_of_stop_noted_while_deferred_is_handled_after_it_in_order():
    """A pool worker (Ctrl-C ignored) deferring its kernel's warm-up noted the terminal's Ctrl-C and
    then its pool's SIGTERM: only the first was raised again, ignored, and the worker ran a whole
    batch on after the stop (an outside tester's: 160 bags after a Ctrl-C during the pool's start)."""
    script = ("import os, signal\n"
              "from soil_msgs_py.interrupts import interrupts_deferred\n"
              "signal.signal(signal.SIGINT, signal.SIG_IGN)\n"
              "with interrupts_deferred():\n"
              "    os.kill(os.getpid(), signal.SIGINT)\n"
              "    os.kill(os.getpid(), signal.SIGTERM)\n"
              "print('ran on', flush=True)\n")
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert proc.returncode == -signal.SIGTERM and "ran on" not in proc.stdout, (proc.returncode, proc.stdout, proc.stderr)
