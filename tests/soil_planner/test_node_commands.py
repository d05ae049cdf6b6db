"""The planner node reads the depth the controller commands (−u_za of /blade/cmd) from the
controller's writer only, as the simulator's command gate follows it (no rclpy.init, no DDS:
the node's callback is called with sequence numbers as DDS's message info gives them)."""
from __future__ import annotations

import collections
from types import SimpleNamespace

from soil_msgs_py import messages as M
from soil_msgs_py import topics as T
from soil_msgs_py.writer_identity import FORGET_WRITER_AFTER_TICKS, WriterTracks
from soil_planner.command_wait import CommandWait
from soil_planner.node import PlannerNode

CLASSES = M.ros_message_classes()


def stamp(k: int) -> int:
    return k * 10**9 // 60


def node() -> SimpleNamespace:
    warned = []
    return SimpleNamespace(commanded=collections.OrderedDict(), warned=warned,
                           command_writer=WriterTracks(forget_after_ticks=FORGET_WRITER_AFTER_TICKS),
                           command_wait=CommandWait(), _answer=lambda ticks: None,
                           _warn=lambda kind, text: warned.append(kind))


def send(n, k: int, u_za: float, sequence, values=None) -> None:
    msg = M.make_labelled(CLASSES, stamp(k), T.BLADE_CMD.labels, values or [u_za + 0.3, u_za])
    PlannerNode._on_blade_cmd(n, msg, sequence)


def test_the_controllers_commanded_depth_is_kept_and_an_intruders_is_not():
    n = node()
    for k in range(5):
        send(n, k, -0.10 - 0.01 * k, 1 + k)
    assert n.commanded[stamp(4)] == 0.14
    send(n, 5, -0.30, 1)  # another writer's own counter, first for tick 5
    send(n, 5, -0.15, 6)  # the controller's
    assert n.commanded[stamp(5)] == 0.15
    send(n, 6, float("nan"), 7)  # not finite: nothing for that tick
    assert stamp(6) not in n.commanded


def test_without_sequence_numbers_the_first_command_of_a_tick_counts_and_a_bad_layout_is_warned():
    n = node()
    send(n, 0, -0.12, None)
    send(n, 0, -0.25, None)
    assert n.commanded[stamp(0)] == 0.12
    bad = M.make_labelled(CLASSES, stamp(1), ("u_zr",), [0.1])
    PlannerNode._on_blade_cmd(n, bad, 2)
    assert n.warned == ["blade_cmd:layout"] and stamp(1) not in n.commanded


def test_an_intruders_command_releases_no_tick_waiting_for_the_controllers():
    n = node()
    send(n, 0, -0.10, 1)
    n.command_wait.offer(stamp(1), "tick 1", now_s=0.0)
    send(n, 3, -0.30, 1)  # another writer, stamped ahead
    assert [w.item for w in n.command_wait.waiting] == ["tick 1"]
    send(n, 1, -0.12, 2)  # the controller's own: tick 1 is answered
    assert not n.command_wait.waiting and n.command_wait.newest_command_ns == stamp(1)
