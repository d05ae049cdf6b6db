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

    assert main(["--x"]) == code
    assert capsys.readouterr().err == f"some_tool: interrupted ({name}); its output is not written: run it again\n"
    assert interruptible("t")(lambda argv=None: 7)() == 7  # a run that ends gives its own code
    assert signal.getsignal(signal.SIGTERM) is not None and signal.getsignal(signal.SIGTERM) != Terminated


def test_pinn_eval_stopped_by_sigterm_mid_run_says_so_and_writes_no_report(tmp_path):
    """SIGTERM had killed it silently; Ctrl-C printed a traceback."""
    out = tmp_path / "eval"
    log = tmp_path / "log"
    with log.open("w") as f:
        proc = subprocess.Popen([sys.executable, "-m", "pinn_estimator.evaluate", "--checkpoint", str(SHIPPED_DEFAULT),
                                 "--forecast-only", "--forecast-world", "default", "--out", str(out), "--workers", "1"],
                                stdout=f, stderr=subprocess.STDOUT)
    try:
        time.sleep(8)  # past its imports, into the forecast (a run takes ~20 s)
        assert proc.poll() is None, log.read_text()[-2000:]
        proc.send_signal(signal.SIGTERM)
        rc = proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    text = log.read_text()
    assert rc == 143, text[-2000:]
    assert "pinn_eval: interrupted (SIGTERM); its output is not written: run it again" in text, text[-2000:]
    assert "Traceback" not in text and not list(out.glob("*.md")) if out.exists() else True, text[-2000:]
