"""Blade travel in soil: the one definition of how far the edge has cut.

An increment is max(v_x, 0)·dt where the depth of cut d > 0, else 0: forward travel with the
blade in the soil. Two integrals of it exist, on purpose:

* the **estimator's** (the contract for every model, the PINN, the online estimator and the
  discrepancy workflow): ``distance_in_soil`` over Θ_k's v_x and d, one increment per 60 Hz
  tick, since the episode started. It needs nothing but what a real machine measures;
* the **simulator's** ground truth (``soil_sim_node.simulator``): the same ``soil_advance``
  summed per physics substep with the chassis' instantaneous velocity. It drives compaction
  and is what the simulator's force terms see (``ForceInputs.distance_in_soil``).

They differ slightly (Θ_k's v_x is a 10-sample average, which lags at start-up: the
estimator's value runs ~3 cm short after 2 m of cut); only the estimator's is reproducible
from a bag.

Time in soil is the same sum with dt for max(v_x, 0)·dt: how long the edge has been below the
surface since the episode started [s] (``time_in_soil``; the simulator's per substep). Why both:
an effect that grows with time (pore pressure settling, a soil that stiffens while it is
loaded) and one that grows with travel (compaction ahead of the blade) are told apart only
across speeds, where s = ∫ v_x dt and time differ.
"""
from __future__ import annotations

import numpy as np

from soil_msgs_py.params import KNOWN_PARAMS, SAMPLE_RATE_HZ

TICK_S = 1.0 / SAMPLE_RATE_HZ
_V_X, _D = KNOWN_PARAMS.index("v_x"), KNOWN_PARAMS.index("d")


def soil_advance(v_x, d, dt: float = TICK_S):
    """Blade travel in soil during one step of ``dt`` [s]: max(v_x, 0)·dt where d > 0, else 0 [m].

    The one increment of ``distance_in_soil``. An online estimator keeps a running sum
    (``distance = 0`` at episode_start; for every tick, oldest first, *including* ticks that
    do not complete a window: ``distance += soil_advance(v_x, d)``, then the tick's value is
    ``distance``) and gets the offline pipeline's values.
    """
    return np.maximum(np.asarray(v_x, dtype=float), 0.0) * dt * (np.asarray(d, dtype=float) > 0)


def distance_in_soil(v_x, d, dt: float = TICK_S) -> np.ndarray:
    """Blade travel with d > 0 since the episode started [m], at every tick of one episode.

    ``v_x`` [m/s], ``d`` [m]: Θ_k's columns over the whole episode, oldest first (1-D). The
    value at tick t is Σ_{j<=t} max(v_x_j, 0)·dt·[d_j > 0], cumulative up to and including t.
    A window's value is the one at its newest sample: it needs the episode from its start,
    not only the 60-sample window.
    """
    adv = soil_advance(v_x, d, dt)
    if adv.ndim != 1:
        raise ValueError(f"distance_in_soil wants 1-D per-tick arrays of one episode, got shape {adv.shape}")
    return np.cumsum(adv)


def soil_time_step(d, dt: float = TICK_S):
    """Time in soil during one step of ``dt`` [s]: dt where d > 0, else 0 [s] (the one increment
    of ``time_in_soil``; an online estimator keeps its running sum as it keeps the travel's)."""
    return dt * (np.asarray(d, dtype=float) > 0)


def time_in_soil(d, dt: float = TICK_S) -> np.ndarray:
    """Time with d > 0 since the episode started [s], at every tick of one episode (1-D ``d``
    [m], oldest first; cumulative up to and including the tick, as ``distance_in_soil``)."""
    step = soil_time_step(d, dt)
    if step.ndim != 1:
        raise ValueError(f"time_in_soil wants 1-D per-tick arrays of one episode, got shape {step.shape}")
    return np.cumsum(step)


def _known_rows(known) -> np.ndarray | None:
    """ONE episode's Θ_k rows as (N, 9) floats; None if empty; ValueError naming the shape."""
    k = np.asarray(known, dtype=float)
    if k.ndim != 2 or k.shape[1] != len(KNOWN_PARAMS):
        if k.size == 0:
            return None
        raise ValueError(f"known must be (N, {len(KNOWN_PARAMS)}) Θ_k rows of one episode, got shape {k.shape}")
    return k


def distance_in_soil_of_known(known, dt: float = TICK_S) -> np.ndarray:
    """``distance_in_soil`` of ONE episode's Θ_k rows ((N, 9), KNOWN_PARAMS order) [m] per tick."""
    k = _known_rows(known)
    return np.zeros(0) if k is None else distance_in_soil(k[:, _V_X], k[:, _D], dt)


def time_in_soil_of_known(known, dt: float = TICK_S) -> np.ndarray:
    """``time_in_soil`` of ONE episode's Θ_k rows ((N, 9), KNOWN_PARAMS order) [s] per tick."""
    k = _known_rows(known)
    return np.zeros(0) if k is None else time_in_soil(k[:, _D], dt)
