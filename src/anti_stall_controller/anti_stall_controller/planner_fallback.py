"""Where the target depth goes when the planner falls silent (``depth_source`` planner).

The planner's last target is the deepest cut it judged within the machine's limits; the
``target_depth_m`` parameter is the fallback the user set. Jumping to a deeper fallback in one
tick plunged the blade 7 cm into a dense clay the planner had just ruled out (an outside tester:
F_x 27.6 kN against the 20 kN limit, and the machine crawling until the planner came back). So a
shallower fallback is taken at once (rising is always safe), a deeper one at most
``deepen_rate_m_s`` of simulation time, the planner's own cautious deepening after a retreat.
No ROS here.
"""
from __future__ import annotations

from soil_msgs_py.graph import MAX_WAIT_S
from soil_msgs_py.params import CAUTIOUS_DEEPEN_RATE_M_S
from soil_msgs_py.messages import NS_PER_S
from soil_msgs_py.values import number_in

DEPTH_SOURCES = ("parameter", "planner")  # the controller's target depth: its parameter's, or the planner's

DEFAULT_FALLBACK_DEEPEN_RATE_M_S = CAUTIOUS_DEEPEN_RATE_M_S  # deepening where a stall threatened
MAX_FALLBACK_DEEPEN_RATE_M_S = 10.0  # beyond it the fallback is reached within a tick: a jump


def check_rate(rate_m_s) -> float:
    """``fallback_deepen_rate_m_s`` as a float; ValueError naming it unless in (0, 10] m/s."""
    return number_in("fallback_deepen_rate_m_s", rate_m_s, 0.0, MAX_FALLBACK_DEEPEN_RATE_M_S, lo_open=True, unit=" m/s")


def check_depth_source(source, timeout_s) -> tuple[str, int]:
    """(``depth_source``, ``planner_timeout_s`` in ns); ValueError naming the parameter and value
    unless the source is one of DEPTH_SOURCES and the timeout a number of seconds in (0, MAX_WAIT_S]."""
    if source not in DEPTH_SOURCES:
        raise ValueError(f"depth_source={source!r} must be one of {DEPTH_SOURCES}")
    timeout_s = number_in("planner_timeout_s", timeout_s, 0.0, MAX_WAIT_S, lo_open=True, what="a number of seconds")
    return source, int(timeout_s * NS_PER_S)


def fallback_depth(current_m: float, fallback_m: float, dt_s: float, deepen_rate_m_s: float) -> float:
    """The target [m] one step of ``dt_s`` [s] after ``current_m`` on the way to ``fallback_m``:
    the fallback itself if it is not deeper, else at most ``deepen_rate_m_s`` · dt deeper."""
    if fallback_m <= current_m:
        return fallback_m
    return min(fallback_m, current_m + deepen_rate_m_s * max(dt_s, 0.0))
