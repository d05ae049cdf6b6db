"""The simulator's kernel made ready once per process with Ctrl-C and SIGTERM deferred
(``warm_up.ready``): Numba loads its cache through ctypes callbacks, where an interrupt is lost."""
from __future__ import annotations

import subprocess
import sys

import pytest

_SCRIPT = """
import os, signal, sys
from soil_sim_node import warm_up as W
done = []

def warm():
    os.kill(os.getpid(), getattr(signal, sys.argv[1]))  # as if it came while Numba loads
    done.append(1)
    return 0.5

W.warm_up = warm
from soil_msgs_py.interrupts import terminate_as_interrupt
try:
    with terminate_as_interrupt():
        W.ready()
        print("not stopped")
except KeyboardInterrupt as exc:
    print(type(exc).__name__, "after the warm-up" if done else "inside it")
print("again", W.ready())
"""


@pytest.mark.timeout(60)
@pytest.mark.parametrize("sig, name", [("SIGINT", "KeyboardInterrupt"), ("SIGTERM", "Terminated")])
def test_a_stop_while_the_kernel_is_made_ready_comes_after_it_not_inside(sig, name):
    res = subprocess.run([sys.executable, "-c", _SCRIPT, sig], capture_output=True, text=True, timeout=60)
    assert res.stdout.splitlines() == [f"{name} after the warm-up", "again 0.0"], res.stdout + res.stderr
    assert "Exception ignored" not in res.stderr
