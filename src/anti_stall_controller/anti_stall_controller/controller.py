"""Gain-scheduled anti-stall blade controller of Wagner et al. §2.1.3 (Eq. 11-12), ROS-free.

The paper's controller, for a desired forward velocity v̄_x and target absolute cut depth d̄_z:

    Δd̄^k = K_Δp (e_vx^k − e_vmin) + Δd̄^{k−1},  clipped to [0, d̄_z + Δd̄_max]      (Eq. 11)
    u_zr  = −(d̄_z − Δd̄^k)                                                          (Eq. 12)

with e_vx = v̄_x − v_x^c (measured chassis forward velocity), the velocity dependent threshold
e_vmin = v̄_x c_vx and the scheduled gain K_Δp = K_v / v̄_x. When the machine slows down
(stalling soil) the velocity error exceeds the threshold and the depth offset Δd̄ grows: the
blade rises, at most to Δd̄_max above the surface. When the machine runs faster than
v̄_x (1 − c_vx) the offset integrates back down to 0 and the blade returns to the target depth.

Interpretation choices of this implementation (the paper leaves these open):

1. Sample-rate independence (Eq. 11). The paper's update is per time step, so its gain
   depends on the 60 Hz step. Here the integrator is written in continuous time and
   discretised with the step ``dt``:

       Δd̄^k = Δd̄^{k−1} + (K_v / v̄_x) (e_vx^k − e_vmin) · dt

   with K_v in m/s: for a velocity error one v̄_x above the threshold (relative error 1)
   the blade rises at K_v m/s. The paper's per-step gain is therefore
   K_Δp,paper = K_v · dt / v̄_x (dimensionless per-step gain on the error in m/s, giving m);
   at dt = 1/60 s and K_v = 0.5 m/s, K_Δp,paper = 0.00833 / v̄_x.

2. Absolute depth (Eq. 12). Eq. 12 is a depth relative to the level original ground
   surface z = 0, so the absolute edge-height target is

       u_za = −(d̄_z − Δd̄^k)

   and the blade-lift joint command, relative to the chassis ground reference p_z^c, is

       u_zr = clip(u_za − p_z^c, MACHINE.blade_min_rel_m, MACHINE.blade_max_rel_m).

   The paper writes Eq. 12 for the *relative* command u_zr. Taken literally, with the
   chassis riding on its own cut floor (the simulated suspension follows the soil height
   under the chassis), the blade would be commanded d̄ below the floor the chassis already
   stands on, so the cut would deepen by d̄ every chassis length. The paper also logs an
   absolute command u_za (§2.1.2), which fits this reading: the depth target is absolute,
   the joint command is derived from it.

3. Chassis velocity command u_x = v̄_x (the paper's motorized velocity constraint tracks it).

4. Depth dither (ours, off by default). The depth target of Eq. 12 may carry a sinusoid,

       d̄_z(t_k) = d̄_z + A sin(2π t_k / T),   t_k = k · dt,

   k the steps since ``reset`` (an episode's ticks), A = ``dither_amplitude_m``, T =
   ``dither_period_s``: the cut depth then sweeps ±A around the target, so one episode shows
   the soil's force over a range of depths (richer data for estimating the soil), not at one
   depth only. Eq. 11's offset and its clip are unchanged; with A = 0 the commands are Eq. 12's
   to the bit. A target that is a ceiling (a planner's deepest cut within the force limits,
   ``dither_below_target``) is swept from below, d̄_z + A (sin − 1), over the same 2A: a sweep
   around it had cut A deeper than the plan allowed (an outside reviewer's).

5. Force lift (ours, off by default). Eq. 11 reacts to a stall's symptom, the chassis slowing
   down, which starts only once the blade force exceeds what the machine can push (its 20 kN
   tractive limit in x) and then takes the lift's time to undo. With a gain g > 0 the offset
   also rises with the cause, the measured blade force F of the tick being answered:

       Δd̄^k += g · max(s^k − θ, 0) · dt,   s^k = max(|F_x| / F_x,lim, |F_z| / F_z,lim)

   (g = ``force_lift_m_s``, θ = ``force_lift_share``; clipped with Eq. 11's offset). With θ = 1
   the blade rises only while a force beyond the machine's limits is slowing it down, at g m/s
   per unit of the excess. A non-finite force adds nothing. With g = 0 the commands are Eq.
   11's to the bit.

Batches: every target and state is a float64 array of shape (B,), one entry per episode
(scalars broadcast). All arithmetic is element-wise IEEE +, −, ×, ÷ and clipping in a fixed
order, so row i of a batch is bit-identical to running that row alone with B = 1.

Measurements that are not finite (NaN/±inf v_x^c or p_z^c) never enter the integrator:
for those episodes the previous depth offset is held, and u_zr is computed from the last
finite p_z^c (0.0, the level surface, before any finite one was seen), so commands stay
finite.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import NamedTuple, Optional

import numpy as np

from soil_msgs_py.params import (DEFAULT_C_VX, DEFAULT_TARGET_SPEED_M_S, FORCE_LIMITS_N, MACHINE, MAX_TARGET_DEPTH_M,
                                 MAX_TARGET_SPEED_M_S, MIN_TARGET_SPEED_M_S, SAMPLE_RATE_HZ)
from soil_msgs_py.values import finite_number

__all__ = ["AntiStallGains", "ControlCommand", "AntiStallController", "limit_shares"]


def limit_shares(force_n) -> np.ndarray:
    """|F| / the machine's force limit per axis, (..., 2) for forces (F_x, F_z) (..., 2) [N]: the
    share of its 20 kN tractive and 30 kN penetrative limits a force uses."""
    return np.abs(np.asarray(force_n, dtype=np.float64)) / np.asarray(FORCE_LIMITS_N)


def _check_scalar(name: str, value, lo: float, lo_open: bool, allowed: str, hi: float = math.inf,
                  hi_open: bool = False) -> float:
    """Return ``value`` as a float, or raise ValueError naming the field, value and range (a bool
    or a text is no number: "0.3" had been taken as 0.3)."""
    if not finite_number(value):
        raise ValueError(f"{name} must be a finite number in {allowed}; got {value!r}")
    x = float(value)
    if x < lo or (lo_open and x == lo) or x > hi or (hi_open and x == hi):
        raise ValueError(f"{name} must be a finite number in {allowed}; got {value!r}")
    return x


# Upper ends of the gains: beyond them a value is a slip of the keyboard, not a tuning. A rise rate
# [m/s] of 10 m/s per unit of error is far beyond any lift joint (the blade's whole travel in
# a tick); c_vx >= 1 puts the threshold e_vmin at or above the target speed, where a forward
# speed error never exceeds it and Eq. 11 never acts (k_v_m_s = 0 is the way to switch it off);
# the blade cannot be raised more than its height above the surface; a dither is a few cm.
MAX_RATE_GAIN_M_S = 10.0
MAX_DITHER_AMPLITUDE_M = 0.1


MIN_DITHER_TICKS = 10  # ticks per dither period at least: at most 2π/10 ≈ 0.63 A of depth change per tick


@dataclass(frozen=True)
class AntiStallGains:
    """Controller parameters (SI). Validated on construction.

    k_v_m_s:        K_v, depth-offset integral gain [m/s]: blade rise rate per unit relative
                    velocity error (e_vx − e_vmin)/v̄_x. K_Δp = K_v / v̄_x (Eq. 11). >= 0;
                    0 disables the anti-stall action (fixed target depth).
    c_vx:           velocity-error threshold as a fraction of v̄_x: e_vmin = v̄_x c_vx. >= 0.
    delta_d_max_m:  Δd̄_max, how far above the surface the blade may be raised [m]: the
                    offset is clipped to [0, d̄_z + Δd̄_max] (Eq. 11). >= 0.
    dt_s:           integration step [s], default one 60 Hz tick. > 0.
    dither_amplitude_m: A, amplitude of the depth dither [m] (module docstring, item 4);
                    0 (default) switches it off, a few cm when on. >= 0.
    dither_period_s: T, period of the depth dither [s], at least MIN_DITHER_TICKS dt_s (a sweep, not jumps).
    force_lift_m_s: g, blade rise rate per unit of force share above ``force_lift_share`` [m/s]
                    (module docstring, item 5); 0 (default) switches it off. >= 0.
    force_lift_share: θ, the share of the machine's force limits above which the force lifts. > 0.
    """

    k_v_m_s: float = 0.5
    c_vx: float = DEFAULT_C_VX
    delta_d_max_m: float = 0.05
    dt_s: float = 1.0 / SAMPLE_RATE_HZ
    dither_amplitude_m: float = 0.0
    dither_period_s: float = 2.0
    force_lift_m_s: float = 0.0
    force_lift_share: float = 1.0

    def __post_init__(self) -> None:
        h = MACHINE.blade_height_m
        checks = (
            ("k_v_m_s", 0.0, False, f"[0, {MAX_RATE_GAIN_M_S:g}]", MAX_RATE_GAIN_M_S, False),
            ("c_vx", 0.0, False, "[0, 1)", 1.0, True),
            ("delta_d_max_m", 0.0, False, f"[0, {h:g}] (the blade's height)", h, False),
            ("dt_s", 0.0, True, "(0, inf)", math.inf, False),
            ("dither_amplitude_m", 0.0, False, f"[0, {MAX_DITHER_AMPLITUDE_M:g}]", MAX_DITHER_AMPLITUDE_M, False),
            ("dither_period_s", 0.0, True, "(0, inf)", math.inf, False),
            ("force_lift_m_s", 0.0, False, f"[0, {MAX_RATE_GAIN_M_S:g}]", MAX_RATE_GAIN_M_S, False),
            ("force_lift_share", 0.0, True, "(0, inf)", math.inf, False),
        )
        for name, lo, lo_open, allowed, hi, hi_open in checks:
            value = _check_scalar(name, getattr(self, name), lo, lo_open, allowed, hi, hi_open)
            object.__setattr__(self, name, value)
        # a sinusoid sampled fewer than MIN_DITHER_TICKS times a period jumps from tick to tick (at 2 ticks
        # it is 0 at every one, at 3 it steps 1.7 A): no sweep of the depth
        if self.dither_period_s < MIN_DITHER_TICKS * self.dt_s:
            raise ValueError(f"dither_period_s={self.dither_period_s!r} must be at least {MIN_DITHER_TICKS} control "
                             f"periods ({MIN_DITHER_TICKS} dt_s = {MIN_DITHER_TICKS * self.dt_s:g} s)")

    def paper_step_gain(self, target_speed_m_s):
        """The paper's per-step gain K_Δp,paper = K_v · dt / v̄_x (Eq. 11 as printed)."""
        return self.k_v_m_s * self.dt_s / np.asarray(target_speed_m_s, dtype=np.float64)

    def force_lift_rate_m_s(self, force_n: np.ndarray) -> np.ndarray:
        """g · max(s − θ, 0) [m/s] per row of ``force_n`` (B, 2) [N] (item 5); 0 where a force is not finite."""
        f = np.asarray(force_n, dtype=np.float64)
        with np.errstate(invalid="ignore"):
            share = limit_shares(f).max(axis=1)
            over = np.maximum(share - self.force_lift_share, 0.0)
        return np.where(np.isfinite(f).all(axis=1), self.force_lift_m_s * over, 0.0)

    def dither_m(self, steps: int) -> float:
        """The depth dither A sin(2π k dt / T) at step k since reset [m] (item 4)."""
        return self.dither_amplitude_m * math.sin(2.0 * math.pi * (steps * self.dt_s) / self.dither_period_s)


class ControlCommand(NamedTuple):
    """Commands of one tick, each a float64 array of shape (B,); order = params.COMMAND_FIELDS."""

    u_zr: np.ndarray  # blade edge height relative to the chassis ground reference [m] (joint)
    u_za: np.ndarray  # absolute blade edge height target, surface at z = 0 [m]
    u_x: np.ndarray  # chassis forward velocity command [m/s]


def _as_batch(name: str, value, batch_size: Optional[int]) -> np.ndarray:
    """float64 array of shape (B,), a fresh copy; scalars and (1,) broadcast."""
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim > 1:
        raise ValueError(f"{name} must be a scalar or a 1-D array of shape (B,); got shape {arr.shape}")
    arr = np.atleast_1d(arr)
    if batch_size is not None and arr.shape[0] != batch_size:
        if arr.shape[0] != 1:
            raise ValueError(
                f"{name} has shape {arr.shape}, which does not match the batch size B={batch_size}"
            )
        arr = np.broadcast_to(arr, (batch_size,))
    return np.array(arr, dtype=np.float64, copy=True)


def _at(i: int, values: np.ndarray) -> str:
    """Where a bad target is: nothing to say for one machine's (a node's scalar parameter)."""
    return f" at index {i}" if np.size(values) > 1 else ""


def _check_targets(speed: np.ndarray, depth: np.ndarray) -> None:
    """The machine's reach (``params.MIN_TARGET_SPEED_M_S``, ``MAX_TARGET_*``: the simulator's limits too)."""
    bad = ~np.isfinite(speed) | (speed < MIN_TARGET_SPEED_M_S) | (speed > MAX_TARGET_SPEED_M_S)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(
            f"target_speed_m_s must be finite and in [{MIN_TARGET_SPEED_M_S:g}, {MAX_TARGET_SPEED_M_S:g}] m/s; got {float(speed[i])!r}{_at(i, speed)}"
        )
    bad = ~np.isfinite(depth) | (depth < 0.0) | (depth > MAX_TARGET_DEPTH_M)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(
            f"target_depth_m must be finite and in [0, {MAX_TARGET_DEPTH_M:g}] m (the blade's height); "
            f"got {float(depth[i])!r}{_at(i, depth)}"
        )


class AntiStallController:
    """Eq. 11-12 for a batch of B episodes. See the module docstring for the interpretation.

    ``AntiStallController(gains, target_speed_m_s, target_depth_m, batch_size=None)``:
    targets are scalars or arrays of shape (B,); B is taken from them (or ``batch_size``,
    to which scalar targets broadcast). Call ``step(v_x_c, p_z_c)`` once per tick.
    """

    def __init__(
        self,
        gains: Optional[AntiStallGains] = None,
        target_speed_m_s=DEFAULT_TARGET_SPEED_M_S,
        target_depth_m=0.1,
        batch_size: Optional[int] = None,
    ) -> None:
        if gains is None:
            gains = AntiStallGains()
        if not isinstance(gains, AntiStallGains):
            raise ValueError(f"gains must be an AntiStallGains; got {type(gains).__name__}")
        if batch_size is not None and (int(batch_size) != batch_size or batch_size < 1):
            raise ValueError(f"batch_size must be an integer >= 1; got {batch_size!r}")
        speed = np.atleast_1d(np.asarray(target_speed_m_s, dtype=np.float64))
        depth = np.atleast_1d(np.asarray(target_depth_m, dtype=np.float64))
        if batch_size is None:
            try:
                batch_size = int(np.broadcast_shapes(speed.shape, depth.shape)[0])
            except ValueError:
                raise ValueError(
                    f"target_speed_m_s shape {speed.shape} and target_depth_m shape "
                    f"{depth.shape} do not broadcast to one batch (B,)"
                ) from None
        self._batch_size = int(batch_size)
        speed = _as_batch("target_speed_m_s", speed, self._batch_size)
        depth = _as_batch("target_depth_m", depth, self._batch_size)
        _check_targets(speed, depth)
        self._gains = gains
        self._speed = speed
        self._depth = depth
        self._offset = np.zeros(self._batch_size)
        self._last_p_z_c = np.zeros(self._batch_size)
        self._steps = 0  # since reset: the dither's clock
        # the depth target is a ceiling (a planner's): the dither sweeps below it (item 4)
        self.dither_below_target = False

    # ------------------------------------------------------------------ properties
    @property
    def batch_size(self) -> int:
        return self._batch_size

    @property
    def gains(self) -> AntiStallGains:
        return self._gains

    @property
    def target_speed_m_s(self) -> np.ndarray:
        return self._speed.copy()

    @property
    def target_depth_m(self) -> np.ndarray:
        return self._depth.copy()

    @property
    def depth_offset_m(self) -> np.ndarray:
        """Δd̄^k of Eq. 11 (>= 0; positive raises the blade), shape (B,). A copy."""
        return self._offset.copy()

    def offset_upper_bound_m(self) -> np.ndarray:
        """Upper clip of Eq. 11: d̄_z + Δd̄_max (blade Δd̄_max above the surface)."""
        return self._depth + self._gains.delta_d_max_m

    # ------------------------------------------------------------------ configuration
    def reset(self, depth_offset_m=0.0) -> None:
        """Start new episodes: offset (default 0, blade at target depth), clipped to range."""
        offset = _as_batch("depth_offset_m", depth_offset_m, self._batch_size)
        if not np.all(np.isfinite(offset)):
            raise ValueError(f"depth_offset_m must be finite; got {offset!r}")
        self._offset = np.clip(offset, 0.0, self.offset_upper_bound_m())
        self._last_p_z_c = np.zeros(self._batch_size)
        self._steps = 0

    def set_targets(self, target_speed_m_s=None, target_depth_m=None) -> None:
        """Change v̄_x and/or d̄_z at run time (None keeps the current value).

        The integrator state is kept, clipped to the new range [0, d̄_z + Δd̄_max].
        Validation happens before anything changes: on ValueError the controller is intact.
        """
        speed = self._speed if target_speed_m_s is None else _as_batch(
            "target_speed_m_s", target_speed_m_s, self._batch_size)
        depth = self._depth if target_depth_m is None else _as_batch(
            "target_depth_m", target_depth_m, self._batch_size)
        _check_targets(speed, depth)
        self._speed = speed.copy()
        self._depth = depth.copy()
        self._offset = np.clip(self._offset, 0.0, self.offset_upper_bound_m())

    def set_gains(self, gains: Optional[AntiStallGains] = None, **changes) -> None:
        """Replace the gains (an AntiStallGains) and/or change fields by keyword, e.g.
        ``set_gains(k_v_m_s=0.3)``. Validated; the offset is clipped to the new range."""
        base = self._gains if gains is None else gains
        if not isinstance(base, AntiStallGains):
            raise ValueError(f"gains must be an AntiStallGains; got {type(base).__name__}")
        if changes:
            known = {f.name for f in dataclasses.fields(AntiStallGains)}
            unknown = sorted(set(changes) - known)
            if unknown:
                raise ValueError(f"unknown gain field(s) {unknown}; allowed: {sorted(known)}")
            base = dataclasses.replace(base, **changes)  # __post_init__ validates
        self._gains = base
        self._offset = np.clip(self._offset, 0.0, self.offset_upper_bound_m())

    # ------------------------------------------------------------------ control
    def step(self, v_x_c, p_z_c, force_n=None) -> ControlCommand:
        """One tick: measured chassis forward velocity v_x^c [m/s] and chassis ground
        reference height p_z^c [m] (scalars or shape (B,)) -> ControlCommand. ``force_n``: the
        blade force (F_x, F_z) [N] of the same tick, shape (2,) or (B, 2); needed only with
        the force lift on (item 5), ValueError without it then."""
        v = _as_batch("v_x_c", v_x_c, self._batch_size)
        pz = _as_batch("p_z_c", p_z_c, self._batch_size)
        g = self._gains
        speed = self._speed
        lift = None
        if g.force_lift_m_s > 0.0:
            if force_n is None:
                raise ValueError("force_n (F_x, F_z) [N] is needed with force_lift_m_s > 0")
            f = np.asarray(force_n, dtype=np.float64)
            if f.shape not in ((2,), (self._batch_size, 2)):
                raise ValueError(f"force_n must have shape (2,) or (B, 2) = ({self._batch_size}, 2); got {f.shape}")
            lift = g.force_lift_rate_m_s(np.broadcast_to(f, (self._batch_size, 2)))

        # Eq. 11, continuous-time form discretised with dt (see module docstring, item 1).
        e_vx = speed - v  # velocity tracking error
        e_vmin = speed * g.c_vx  # velocity dependent threshold
        k_dp = g.k_v_m_s / speed  # gain schedule K_Δp = K_v / v̄_x  [1/s · m/s / (m/s)]
        candidate = self._offset + (k_dp * (e_vx - e_vmin)) * g.dt_s
        if lift is not None:  # item 5
            candidate = candidate + lift * g.dt_s
        candidate = np.clip(candidate, 0.0, self.offset_upper_bound_m())

        # Non-finite measurements: hold the previous offset (integrator not corrupted).
        ok = np.isfinite(v) & np.isfinite(pz)
        self._offset = np.where(ok, candidate, self._offset)
        pz_finite = np.isfinite(pz)
        self._last_p_z_c = np.where(pz_finite, pz, self._last_p_z_c)

        # Eq. 12 as an absolute target (item 2) with the dithered depth target (item 4), then
        # the joint command relative to p_z^c.
        dither = g.dither_m(self._steps) - (g.dither_amplitude_m if self.dither_below_target else 0.0)
        u_za = -((self._depth + dither) - self._offset)
        self._steps += 1
        u_zr = np.clip(u_za - self._last_p_z_c, MACHINE.blade_min_rel_m, MACHINE.blade_max_rel_m)
        u_x = speed.copy()  # item 3
        return ControlCommand(u_zr=u_zr, u_za=u_za, u_x=u_x)
