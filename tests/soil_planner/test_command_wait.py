"""A tick is planned once the controller's command of that tick is in (``command_wait``):
in the order ticks came, a lost command not waited for once a later one is in, bounded in wall
time and in ticks, and nothing waits where no command comes."""
from __future__ import annotations

import pytest

from soil_planner.command_wait import CommandWait


def items(released) -> list:
    return [w.item for w in released]


def test_without_commands_nothing_waits():
    w = CommandWait(max_wait_s=5.0)
    assert items(w.offer(10, "a", now_s=0.0)) == ["a"]
    assert items(w.offer(11, "b", now_s=0.0)) == ["b"] and w.timed_out == 0


def test_a_tick_waits_for_its_command_and_the_ticks_behind_it_wait_with_it():
    w = CommandWait(max_wait_s=5.0)
    assert w.command(9, now_s=0.0) == []
    assert items(w.offer(9, "k9", now_s=0.0)) == ["k9"]  # its command is in: at once
    assert w.offer(10, "k10", now_s=0.0) == []  # its command is not
    assert w.offer(10, "k10 invalid again", now_s=0.0) == []
    assert w.offer(8, "k8 late", now_s=0.1) == []  # commanded already, but behind k10: order is kept
    assert items(w.command(10, now_s=0.2)) == ["k10", "k10 invalid again", "k8 late"]
    assert w.timed_out == 0 and w.waited == 3


def test_a_later_command_releases_a_tick_whose_own_command_was_lost():
    w = CommandWait(max_wait_s=5.0)
    w.command(1, now_s=0.0)
    assert w.offer(2, "k2", now_s=0.0) == [] and w.offer(3, "k3", now_s=0.0) == [] and w.offer(4, "k4", now_s=0.0) == []
    assert items(w.command(3, now_s=0.1)) == ["k2", "k3"]
    assert items(w.drain()) == ["k4"] and not w.waiting and w.timed_out == 1  # answered without its command
    w.offer(5, "k5", now_s=0.2)
    assert items(w.drain(planned=False)) == ["k5"] and w.timed_out == 1  # shutdown: dropped, not planned


def test_the_wait_is_bounded_in_wall_time_and_in_ticks():
    w = CommandWait(max_wait_s=0.5, max_ticks=3)
    w.command(0, now_s=0.0)
    assert w.offer(1, "k1", now_s=0.0) == [] and w.offer(2, "k2", now_s=0.3) == []
    assert w.expire(now_s=0.49) == []
    assert items(w.expire(now_s=0.5)) == ["k1"]  # k1 waited 0.5 s; k2 only 0.2 s
    assert items(w.expire(now_s=0.8)) == ["k2"] and w.timed_out == 2
    for k in range(3, 6):
        assert w.offer(k, k, now_s=1.0) == []
    assert items(w.offer(6, 6, now_s=1.0)) == [3]  # four waiting: the oldest goes


def test_a_new_cut_does_not_wait_until_its_controller_commands_and_zero_never_waits():
    w = CommandWait(max_wait_s=5.0)
    w.command(100, now_s=0.0)
    assert w.offer(101, "old cut", now_s=0.0) == []
    assert items(w.drain()) == ["old cut"]
    w.forget_commands()
    assert items(w.offer(5, "new cut", now_s=0.0)) == ["new cut"]
    z = CommandWait(max_wait_s=0.0)
    z.command(1, now_s=0.0)
    assert items(z.offer(2, "k2", now_s=0.0)) == ["k2"] and z.timed_out == 0


@pytest.mark.parametrize("bad", [-0.1, float("nan"), 11.0, True, "1"])
def test_a_bad_wait_is_named(bad):
    with pytest.raises(ValueError, match="command_wait_s="):
        CommandWait(max_wait_s=bad)
