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

import math

from soil_msgs_py.graph import MAX_WAIT_S
from soil_msgs_py.params import CAUTIOUS_DEEPEN_RATE_M_S
from soil_msgs_py.messages import NS_PER_S

DEPTH_SOURCES = ("parameter", "planner")  # the controller's target depth: its parameter's, or the planner's

DEFAULT_FALLBACK_DEEPEN_RATE_M_S = CAUTIOUS_DEEPEN_RATE_M_S  # deepening where a stall threatened
MAX_FALLBACK_DEEPEN_RATE_M_S = 10.0  # beyond it the fallback is reached within a tick: a jump


def check_rate(rate_m_s) -> float:
    """``fallback_deepen_rate_m_s`` as a float; ValueError naming it unless in (0, 10] m/s."""
    if isinstance(rate_m_s, bool) or not isinstance(rate_m_s, (int, float)) or not math.isfinite(rate_m_s) \
            or not 0.0 < rate_m_s <= MAX_FALLBACK_DEEPEN_RATE_M_S:
        raise ValueError(f"fallback_deepen_rate_m_s={rate_m_s!r} must be in (0, {MAX_FALLBACK_DEEPEN_RATE_M_S:g}] m/s")
    return float(rate_m_s)


def check_depth_source(source, timeout_s) -> tuple[str, int]:
    """(``depth_source``, ``planner_timeout_s`` in ns); ValueError naming the parameter and value
    unless the source is one of DEPTH_SOURCES and the timeout a number of seconds in (0, MAX_WAIT_S]."""
    if source not in DEPTH_SOURCES:
        raise ValueError(f"depth_source={source!r} must be one of {DEPTH_SOURCES}")
    if isinstance(timeout_s, bool) or not isinstance(timeout_s, (int, float)) or not 0.0 < timeout_s <= MAX_WAIT_S:
        raise ValueError(f"planner_timeout_s={timeout_s!r} must be a number of seconds in (0, {MAX_WAIT_S:g}]")
    return source, int(timeout_s * NS_PER_S)


def fallback_depth(current_m: float, fallback_m: float, dt_s: float, deepen_rate_m_s: float) -> float:
    """The target [m] one step of ``dt_s`` [s] after ``current_m`` on the way to ``fallback_m``:
    the fallback itself if it is not deeper, else at most ``deepen_rate_m_s`` · dt deeper."""
    if fallback_m <= current_m:
        return fallback_m
    return min(fallback_m, current_m + deepen_rate_m_s * max(dt_s, 0.0))
