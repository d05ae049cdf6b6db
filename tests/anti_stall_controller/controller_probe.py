"""What the controller node tests share: tick stamps, and sending a tick until it is answered."""
from __future__ import annotations

from typing import Callable

from soil_msgs_py import messages as M
from soil_msgs_py.params import TICK_PERIOD_NS

FIRST = 100 * M.NS_PER_S  # the episode's first stamp [ns]


def tick_stamp(k: int) -> int:
    """Stamp [ns] of tick k of the episode."""
    return FIRST + int(k * TICK_PERIOD_NS)


def send_until_answered(probe, send: Callable[[], None], answered: Callable[[], bool], what: str) -> None:
    """``send()`` the tick's state, again every 2 s, until ``answered()`` (10 sends at most):
    topics are not ordered with each other, so on a loaded machine the first tick can reach the
    node before its episode_start."""
    for _ in range(10):
        send()
        try:
            probe.wait_for(answered, 2, what)
            return
        except AssertionError:
            continue
    probe.wait_for(answered, 1, f"{what} (sent 10 times)")
