"""A node started by ``soil_launch`` stops when the launcher dies, however it dies (no rclpy).

Why: the launcher forwards Ctrl-C and SIGTERM to its nodes and stops them in order, but a
launcher killed with SIGKILL (or by the out-of-memory killer) cannot; its nodes then ran on as
orphans on the same DDS domain, where a second controller's commands spoil every tick of the next
launch. The launcher names itself in ``LAUNCHER_PID_ENV``; a node that finds it asks Linux for
SIGTERM when its parent dies (``prctl(PR_SET_PDEATHSIG)``), which the node takes as an ordinary
stop request, so the recorder still finishes its bag. A launcher already gone by then (it died
between the fork and this call) is noticed from the parent's pid, and the node stops at once.
Elsewhere than Linux this is a no-op. The launcher forks its nodes from its main thread, whose end
is what the kernel watches.
"""
from __future__ import annotations

import ctypes
import os
import signal
import sys

LAUNCHER_PID_ENV = "SOIL_LAUNCH_PID"
PR_SET_PDEATHSIG = 1  # <linux/prctl.h>


def stop_with_launcher(environ=os.environ) -> str:
    """Arrange SIGTERM for this process when the launcher named in ``environ`` dies (the variable is
    taken out of ``environ``: this node's own children are not the launcher's). Returns what was
    done: "" (not started by a launcher), "watching", "launcher gone" (SIGTERM sent to this process
    now) or why nothing could be arranged (a bad variable, not Linux, not the launcher's child)."""
    text = environ.pop(LAUNCHER_PID_ENV, "")  # not passed on: a child of this node is not the launcher's
    if not text:
        return ""
    try:
        launcher = int(text)
    except ValueError:
        return f"{LAUNCHER_PID_ENV}={text!r} is not a process id: not watching the launcher"
    if not sys.platform.startswith("linux"):
        return "not Linux: a node outlives a launcher killed with SIGKILL"
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0) != 0:
            return f"prctl(PR_SET_PDEATHSIG) failed ({os.strerror(ctypes.get_errno())}): not watching the launcher"
    except (OSError, AttributeError) as err:
        return f"prctl unavailable ({err}): not watching the launcher"
    if os.getppid() != launcher:
        try:
            os.kill(launcher, 0)
        except ProcessLookupError:  # it died before the request took effect
            os.kill(os.getpid(), signal.SIGTERM)
            return "launcher gone"
        except PermissionError:
            pass
        # something between the launcher and this node (a wrapper that did not exec): its death is what
        # the request watches, not the launcher's
        return f"not the launcher's (pid {launcher}) direct child: a launcher killed outright leaves this node running"
    return "watching"
