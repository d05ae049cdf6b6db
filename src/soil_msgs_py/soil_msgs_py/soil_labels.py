"""Which soil an episode cut, where its bag may not say (a machine's bags carry no soil label).

Why here: the forecast's pairs (``pinn_eval --forecast-data``) and the discrepancy workflow's
θ-groups both need "the same soil"; without a label both take episodes of one measured unit
weight γ, and must agree on what "no label" and "one γ" mean.
"""
from __future__ import annotations

import numpy as np

from .values import short_repr

# Metadata soil names that say "not known": a machine's bags carry no soil label.
UNKNOWN_SOILS = ("", "unknown", "none", "?")
UNKNOWN_SOIL = "unknown"
# Unlabelled episodes whose measured unit weight γ differs from the previous (sorted) one by less
# than this share are one soil. The catalogue's soils and densities differ by >= 0.5 % in γ where
# they differ at all (15.5-21 kN/m³); a machine's γ is a configured or weighed number.
GAMMA_GROUP_RTOL = 0.002


def says_unknown(name: str) -> bool:
    """True if a soil name is one of those that say "not known" (UNKNOWN_SOILS, any case)."""
    return name.strip().lower() in UNKNOWN_SOILS


def soil_label(meta) -> str:
    """An episode's soil name from its metadata, or UNKNOWN_SOIL where it has none."""
    soil = str(getattr(meta, "soil", "") or "").strip()
    return UNKNOWN_SOIL if says_unknown(soil) else soil


def unlabelled_count(metas) -> int:
    """How many of the episodes' metadata carry no soil label (``soil_label``)."""
    return sum(soil_label(m) == UNKNOWN_SOIL for m in metas)


GAMMA_GROUP_PREFIX = "γ≈"  # a γ group's name starts with it (bags without soil labels)


def gamma_group_names(gamma) -> list[str]:
    """Per value of ``gamma`` [N/m³], the name of its group: chains of sorted γ whose steps stay
    within GAMMA_GROUP_RTOL, named after the chain's smallest γ. ValueError on a non-finite γ."""
    gamma = np.asarray(gamma, float)
    if not np.isfinite(gamma).all():
        raise ValueError(f"gamma={short_repr(gamma[~np.isfinite(gamma)][0])} is not finite; cannot group by it")
    out = [""] * len(gamma)
    order = np.argsort(gamma, kind="stable")
    start = gamma[order[0]] if len(order) else 0.0
    for j, i in enumerate(order):
        if j and gamma[i] > gamma[order[j - 1]] * (1 + GAMMA_GROUP_RTOL):
            start = gamma[i]
        out[i] = f"{GAMMA_GROUP_PREFIX}{start / 1e3:.4g} kN/m³"  # 4 digits: chain starts > 0.2 % apart never share a name
    return out
