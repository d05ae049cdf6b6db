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
