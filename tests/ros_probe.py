"""Test-side ROS 2 helpers: start real node processes and watch them from a probe node.

``RosProbe`` is an rclpy node in its own context and domain, spun by a background thread,
that subscribes/publishes like any other participant. ``NodeProc`` starts a console
script as a separate process on the same loopback domain and keeps its output. Every
wait is bounded.
"""
from __future__ import annotations

import contextlib
import signal
import subprocess
import sys
import threading
import time
from collections import defaultdict
from pathlib import Path

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from soil_msgs_py.ros_adapter import init_context, message_class, topic_qos
from soil_bringup.launch import loopback_env, stop_logged_nodes

from tests.ros_domains import next_domain_id  # noqa: F401 - re-exported for the tests

BIN = Path(sys.executable).parent


def start_launch(args: list[str], domain: int, log_path: Path) -> subprocess.Popen:
    """``soil_launch --domain-id domain args`` with loopback-only DDS, its output into ``log_path``
    (also ``proc.log_path``)."""
    with Path(log_path).open("w") as log:
        proc = subprocess.Popen([str(BIN / "soil_launch"), "--domain-id", str(domain), *args],
                                env=loopback_env(domain), stdout=log, stderr=subprocess.STDOUT, text=True)
    proc.log_path = Path(log_path)
    return proc


@contextlib.contextmanager
def launched(args: list[str], domain: int, log_path: Path):
    """``start_launch``; on leaving, the launch killed if it still runs and no node of it left
    running (its nodes run in sessions of their own: a launch stopped by this fixture's SIGKILL
    stops them through ``launcher_death``, and this makes sure of it)."""
    proc = start_launch(args, domain, log_path)
    try:
        yield proc
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)
        stop_logged_nodes(log_path)


def run_launch(args: list[str], domain: int, log_path: Path, timeout_s: float) -> int:
    """``soil_launch args`` to its end: its exit code (killed after ``timeout_s``)."""
    with launched(args, domain, log_path) as proc:
        try:
            return proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            return proc.wait(timeout=10)


def wait_until(predicate, timeout: float, what: str, poll: float = 0.05):
    """Poll ``predicate()`` until truthy and return it; AssertionError naming ``what`` on timeout."""
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        result = predicate()
        if result:
            return result
        time.sleep(poll)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")


class NodeProc:
    """A console script in its own process; output collected in a file."""

    def __init__(self, script: str, args: list[str], domain_id: int, log_dir: Path):
        self.log_path = log_dir / f"{script}_{time.monotonic_ns()}.log"
        self._log = self.log_path.open("w")
        self.proc = subprocess.Popen([str(BIN / script), *args], env=loopback_env(domain_id),
                                     stdout=self._log, stderr=subprocess.STDOUT, text=True)

    @property
    def output(self) -> str:
        if not self._log.closed:
            self._log.flush()
        return self.log_path.read_text()

    def wait(self, timeout: float) -> int:
        return self.proc.wait(timeout=timeout)

    def stop(self, sig=signal.SIGINT, timeout: float = 15.0) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
            try:
                self.proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=5)
        self._log.close()
        return self.proc.returncode


class RosProbe:
    """An in-process participant: records what arrives (with perf_counter receive times)."""

    def __init__(self, domain_id: int, name: str = "probe"):
        self.context = init_context(domain_id)
        self.node = Node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.received: dict[str, list[tuple[float, object]]] = defaultdict(list)
        self.lock = threading.Lock()
        self.pubs: dict[str, object] = {}
        self.subs: dict[str, object] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        while not self._stop.is_set() and self.context.ok():
            self.executor.spin_once(timeout_sec=0.05)

    def subscribe(self, topic: str, msgtype: str, qos=None) -> None:
        def cb(msg, topic=topic):
            t = time.perf_counter()
            with self.lock:
                self.received[topic].append((t, msg))
        self.subs[topic] = self.node.create_subscription(message_class(msgtype), topic, cb, qos or topic_qos(topic))

    def matched_publishers(self, topic: str) -> int:
        """Publishers this probe's subscription to ``topic`` is matched with (DDS endpoint matching,
        not merely seen in the graph): from then on what they publish reaches the probe."""
        return self.subs[topic].get_publisher_count()

    def publisher(self, topic: str, msgtype: str, qos=None):
        if topic not in self.pubs:
            self.pubs[topic] = self.node.create_publisher(message_class(msgtype), topic, qos or topic_qos(topic))
        return self.pubs[topic]

    def messages(self, topic: str) -> list:
        with self.lock:
            return [m for _, m in self.received[topic]]

    def wait_for(self, predicate, timeout: float, what: str, poll: float = 0.05):
        return wait_until(predicate, timeout, what, poll)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self.executor.shutdown(timeout_sec=1)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)

    def __enter__(self) -> "RosProbe":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def call_service(send, what: str = "a service call", timeout: float = 60.0, resend_after_s: float = 10.0):
    """Call ``send()`` (which sends one request and returns its future) and return the answer.

    A request sent just after a service was discovered can be dropped by DDS while the
    server's reply writer is not yet matched to this client's reader, so an unanswered
    request is sent again every ``resend_after_s``; only use it for idempotent requests
    (getting or setting parameters). The first answer wins. ``timeout`` is a hang guard
    only, never a speed check.
    """
    futures = [send()]
    t_end = time.monotonic() + timeout
    next_send = time.monotonic() + resend_after_s
    while time.monotonic() < t_end:
        for future in futures:
            if future.done():
                return future.result()
        if time.monotonic() >= next_send:
            futures.append(send())
            next_send = time.monotonic() + resend_after_s
        time.sleep(0.05)
    raise AssertionError(f"timed out after {timeout} s waiting for {what} ({len(futures)} requests sent)")
