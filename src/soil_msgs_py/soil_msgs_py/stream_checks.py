"""What a stream of ticks must be for this project's models, said where a machine's data is not.

A machine's bags and topics come from other software: another rate (the PINN's window is 60
samples of a 60 Hz stream, one second), or a force sensor of the other sign (the contract is the
force the blade exerts on the soil, paper Eq. 8: a resisting soil gives f_x > 0). Either made
the estimator, pinn_eval, pinn_train and soil_discrepancy run on without a word (an outside
tester's 50 and 100 Hz bags gave estimates over windows of 1.2 and 0.6 s; a flipped sensor,
forecasts 500 % off). The offline readers and the live estimator judge a stream here alike.
rclpy-free.
"""
from __future__ import annotations

import numpy as np

from .params import SAMPLE_RATE_HZ, TICK_PERIOD_NS

# The median step between consecutive ticks' stamps may be this far off 1/60 s (a machine's
# stamps rounded to the millisecond step 16 or 17 ms: 2 %).
RATE_TOLERANCE = 0.05
# Steps the live estimator judges the rate from: well before its 60-sample window fills.
RATE_STEPS = 30
# A forward cut (edge below the surface, moving forward) whose measured f_x is negative in most
# of its ticks is a sensor of the other sign: judged once this many such ticks were seen.
SIGN_MIN_TICKS = 60
SIGN_NEGATIVE_SHARE = 0.8
CUTTING_DEPTH_M = 0.02  # the edge this far below the surface [m]
CUTTING_SPEED_M_S = 0.05  # and moving forward at least this fast [m/s]


def rate_problem(stamps_ns) -> str:
    """'' if the ticks of ``stamps_ns`` (sorted, one per tick, gaps allowed) come at 60 Hz by their
    median step, else what is wrong, for the user: the rate they come at and what to do."""
    return step_problem(np.diff(np.asarray(stamps_ns, dtype=np.int64)))


def step_problem(steps_ns) -> str:
    """``rate_problem`` of the steps between consecutive ticks' stamps [ns]."""
    steps = np.asarray(steps_ns, dtype=np.float64)
    steps = steps[steps > 0]
    if steps.size == 0:
        return ""
    step = float(np.median(steps))
    if abs(step / TICK_PERIOD_NS - 1.0) <= RATE_TOLERANCE:
        return ""
    return (f"its ticks come every {step / 1e6:.3g} ms ({1e9 / step:.3g} Hz) by their stamps; this project's models "
            f"take {SAMPLE_RATE_HZ} Hz samples (a window of one second): resample the topics to {SAMPLE_RATE_HZ} Hz, "
            "every topic of a tick stamped alike")


def cutting_ticks(f_x_n, d_m, v_x_m_s) -> tuple[int, int]:
    """(forward-cutting ticks, those with f_x < 0): what ``sign_problem`` judges."""
    f_x, d, v_x = (np.asarray(a, dtype=np.float64) for a in (f_x_n, d_m, v_x_m_s))
    cutting = (d > CUTTING_DEPTH_M) & (v_x > CUTTING_SPEED_M_S)
    return int(cutting.sum()), int((cutting & (f_x < 0.0)).sum())


def sign_problem(cutting: int, negative: int) -> str:
    """'' unless most forward-cutting ticks measured f_x < 0 (``cutting_ticks``); else what that means."""
    if cutting < SIGN_MIN_TICKS or negative <= SIGN_NEGATIVE_SHARE * cutting:
        return ""
    return (f"f_x < 0 in {negative} of {cutting} ticks cutting forward: this project's force is the one the blade "
            "exerts on the soil (a resisting soil gives f_x > 0, paper Eq. 8); a sensor of the other sign? Flip "
            "f_x and f_z before using it: the estimates and forecasts from it are not the soil's")
