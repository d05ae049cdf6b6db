"""launcher_death: a node started by soil_launch asks for SIGTERM when the launcher dies."""
from __future__ import annotations

import os
import subprocess
import sys

from soil_msgs_py.launcher_death import LAUNCHER_PID_ENV, stop_with_launcher

CHILD = ("import signal, sys; from soil_msgs_py.launcher_death import stop_with_launcher; "
         "got = []; signal.signal(signal.SIGTERM, lambda *_: got.append('SIGTERM')); "
         "said = stop_with_launcher(); "
         "import time; time.sleep(0.2); print(said, got)")


def test_a_node_not_started_by_the_launcher_or_given_no_pid_is_left_alone():
    assert stop_with_launcher({}) == ""
    environ = {LAUNCHER_PID_ENV: "soil"}
    assert "not a process id" in stop_with_launcher(environ)
    assert environ == {}  # taken out: the node's own children are not the launcher's


def test_a_node_whose_launcher_is_its_parent_watches_it_and_one_whose_launcher_is_gone_stops():
    env = dict(os.environ)
    env[LAUNCHER_PID_ENV] = str(os.getpid())  # this test is the child's parent: the launcher
    out = subprocess.run([sys.executable, "-c", CHILD], env=env, capture_output=True, text=True, timeout=60)
    assert out.stdout.strip() == "watching []", out.stderr
    gone = subprocess.Popen(["true"])
    gone.wait()  # a launcher that died before the child could ask (its pid no process has now)
    env[LAUNCHER_PID_ENV] = str(gone.pid)
    out = subprocess.run([sys.executable, "-c", CHILD], env=env, capture_output=True, text=True, timeout=60)
    assert out.stdout.strip() == "launcher gone ['SIGTERM']", out.stderr
    # a live launcher that is not the parent (a wrapper between them): said, and no SIGTERM
    env[LAUNCHER_PID_ENV] = str(os.getppid())
    out = subprocess.run([sys.executable, "-c", CHILD], env=env, capture_output=True, text=True, timeout=60)
    assert "direct child" in out.stdout and out.stdout.strip().endswith("[]"), out.stdout
