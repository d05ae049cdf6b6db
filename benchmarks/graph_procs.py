"""Shared by bench_graph.py and bench_sim.py: start the graph with soil_launch on a loopback
ROS domain, find its node processes, read their CPU time, stop everything.

Every launch is bounded (soil_launch --timeout, a wait timeout here) and cleaned up: the
launcher gets SIGINT (it stops its nodes in order), is killed if it hangs, and any node it
logged as started that still runs afterwards (nodes run in their own sessions) is killed by
pid via ``soil_bringup.launch.stop_logged_nodes``.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.pop("ROS_LOCALHOST_ONLY", None)

from soil_bringup.launch import stop_logged_nodes  # noqa: E402

BIN = Path(sys.executable).parent
CLK_TCK = os.sysconf("SC_CLK_TCK")


class Graph:
    """One soil_launch process (``args`` after the domain), its log in a temporary file."""

    def __init__(self, args: list[str], domain: int):
        self.log = Path(tempfile.mkstemp(prefix="bench_launch_", suffix=".log")[1])
        self._out = self.log.open("w")
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain))
        self.proc = subprocess.Popen([str(BIN / "soil_launch"), "--domain-id", str(domain), *args],
                                     stdout=self._out, stderr=subprocess.STDOUT, env=env)

    def wait(self, timeout: float) -> int:
        try:
            return self.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.close()
            return -1

    def close(self) -> None:
        """Stop the launch (SIGINT, then SIGKILL) and kill any node it left running."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout=40)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=10)
        for left in stop_logged_nodes(self.log):
            print(f"  (killed a node left running: {left})", file=sys.stderr)
        self._out.close()

    def text(self) -> str:
        return self.log.read_text(errors="replace")

    def __enter__(self) -> Graph:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
        self.log.unlink(missing_ok=True)


def children(pid: int) -> dict[str, int]:
    """name -> pid of the launcher's node processes."""
    out = {}
    res = subprocess.run(["pgrep", "-P", str(pid)], capture_output=True, text=True, timeout=10)
    for child in res.stdout.split():
        try:
            cmd = Path(f"/proc/{child}/cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        script = next((Path(c.decode()).name for c in cmd if b"soil_" in c or b"anti_stall" in c or b"pinn" in c), "?")
        out[script] = int(child)
    return out


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLK_TCK  # utime + stime


def cpu_per_node(seconds: float, domain: int, extra: list[str] = (), record: bool = True,
                 warmup_s: float = 8.0) -> dict[str, float]:
    """% of one core (user+system CPU time over a steady ``seconds`` window at 60 Hz, rate 1)
    of each node of the graph: sim + controller (+ recorder if ``record``), ``extra`` soil_launch args."""
    with tempfile.TemporaryDirectory() as tmp:
        rec = ["--record", tmp] if record else []
        with Graph([*rec, "--rate", "1", "--sim-param", f"duration_s:={seconds + warmup_s + 15}",
                    "--timeout", str(seconds + warmup_s + 60), *extra], domain) as graph:
            time.sleep(warmup_s)  # start-up, discovery, first ticks
            pids = children(graph.proc.pid)
            before = {n: cpu_seconds(p) for n, p in pids.items()}
            t0 = time.monotonic()
            time.sleep(seconds)
            after = {}
            for n, p in pids.items():
                try:
                    after[n] = cpu_seconds(p)
                except OSError:  # it died: report what we have
                    after[n] = float("nan")
            wall = time.monotonic() - t0
            if graph.proc.poll() is not None:
                print(f"  (the launch ended during the window, exit {graph.proc.returncode})", file=sys.stderr)
    return {n: 100.0 * (after[n] - before[n]) / wall for n in pids}


class Load:
    """``n`` busy-looping processes (a loaded machine), killed on exit; bounded by ``max_s``."""

    def __init__(self, n: int, max_s: float):
        code = f"import time\nt=time.monotonic()+{max_s}\nwhile time.monotonic()<t: pass"
        self.procs = [subprocess.Popen([sys.executable, "-c", code]) for _ in range(n)]

    def __enter__(self) -> Load:
        return self

    def __exit__(self, *exc) -> None:
        for p in self.procs:
            if p.poll() is None:
                p.kill()
            p.wait(timeout=10)
