"""Tiny array-namespace shim so the FEE is written once for NumPy and torch.

NumPy and torch agree on most elementwise names (sin, cos, tanh, arcsin, arctan2, sqrt,
where, remainder, ...); the few that differ are wrapped here. torch is imported lazily and
only if a torch tensor is actually passed in, so the simulator never pays for it.
"""
from __future__ import annotations

import numpy as np


_NOT_TORCH = frozenset({np.ndarray, np.float64, float, int, type(None)})


def namespace(*arrays):
    """Return ``torch`` if any argument is a torch tensor, else ``numpy``."""
    for a in arrays:
        if type(a) in _NOT_TORCH:  # the simulator's every substep: no string test for the common types
            continue
        if type(a).__module__.startswith("torch"):
            import torch

            return torch
    return np


def is_torch(xp) -> bool:
    return xp is not np


def clip_min(xp, x, lo: float):
    return xp.clamp(x, min=lo) if is_torch(xp) else np.maximum(x, lo)


def positive_part(xp, x):
    """max(x, 0) elementwise: a depth or a speed that counts only where it is positive."""
    return clip_min(xp, x, 0.0)


def clip(xp, x, lo, hi):
    """Elementwise clip; lo/hi may be floats or arrays."""
    if is_torch(xp):
        return xp.clamp(x, min=lo, max=hi)
    return np.clip(x, lo, hi)


def remainder(xp, x, period: float):
    """x mod ``period`` (> 0) in [0, period], as ``xp.remainder`` to the bit, signed zeros, dtype
    and a scalar's type too (a negative x a hair below 0 rounds to ``period`` itself, as there).
    With NumPy from ``fmod``, which is exact, and the same one addition where it is negative:
    NumPy's own remainder costs 3-4x as much (a sixth of the FEE's beta* where a fit evaluates it)."""
    if is_torch(xp):
        return xp.remainder(x, period)
    r = np.fmod(x, period)
    out = np.where(r < 0, r + period, r + 0.0)  # + 0.0: fmod's −0.0 is NumPy's +0.0 (NaNs kept as they are)
    return out[()] if out.ndim == 0 else out


def full_like(xp, x, value: float):
    return xp.full_like(x, value) if is_torch(xp) else np.full_like(np.asarray(x, dtype=float), value)


def coerce(*arrays):
    """(xp, *arrays) with every argument an array of xp; with torch, python scalars and NumPy
    arrays become tensors of the first tensor's dtype and device (so float32 stays float32)."""
    xp = namespace(*arrays)
    if not is_torch(xp):
        return (xp, *arrays)
    like = next(a for a in arrays if isinstance(a, xp.Tensor))
    return (xp, *(a if isinstance(a, xp.Tensor) else xp.as_tensor(a, dtype=like.dtype, device=like.device) for a in arrays))
