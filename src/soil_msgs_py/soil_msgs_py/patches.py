"""Soil patches along the path: the soil of an episode may change with x.

A path is an ordered tuple of ``SoilPatch(x_start_m, soil, relative_density_pct)``. Patch j
holds from its ``x_start_m`` up to the next patch's start; the first patch also covers
everything before the second's start (its own ``x_start_m`` is recorded, never a bound). x is
the world x of the blade's cutting edge, p_x^b [m]: the soil in effect is the patch under the
edge. An episode without patches has one soil everywhere (``EpisodeMeta.soil``).

This module is the contract only (the shape of a path, as episode metadata records it); soil
names are checked against the soils known where they are known (``soil_physics.soils``,
``soil_sim_node.simulator.EpisodeSpec``). One entry syntax for users (the simulator node's
``patches`` parameter, ``soil_sim_batch --patch``, a soils YAML's ``paths:``): ``"X:SOIL:ID"``,
e.g. ``"5.0:Clay:90"``.
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, fields

from .values import finite_number, plain_zero, short_repr

PATCH_SYNTAX = "'X:SOIL:ID' (x_start_m:soil:relative_density_pct, e.g. '5.0:Clay:90')"
# The most patches one path may have: the episode_start event carries the path, and a /sim/status
# text is bounded (``graph.MAX_JSON_CHARS``, 64 k characters), which 256 patches of 64-byte soil names
# and full-precision numbers keep inside (~43 k). A path of 1200 patches had made an event its readers refused: the episode
# ran, the controller never took its targets and no bag was written (an outside tester's).
MAX_PATCHES = 256


@dataclass(frozen=True)
class SoilPatch:
    """One stretch of the path: from ``x_start_m`` [m] on, ``soil`` at ``relative_density_pct`` [%]."""

    x_start_m: float
    soil: str
    relative_density_pct: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "x_start_m", plain_zero(self.x_start_m))
        object.__setattr__(self, "relative_density_pct", plain_zero(self.relative_density_pct))

    def as_dict(self) -> dict:
        return asdict(self)


FIELDS = tuple(f.name for f in fields(SoilPatch))


def parse_patch(text: str, where: str = "patch") -> SoilPatch:
    """``'X:SOIL:ID'`` -> SoilPatch (numbers unchecked: ``check_patches`` checks ranges)."""
    parts = str(text).split(":")
    if len(parts) != 3 or not parts[1].strip():
        raise ValueError(f"{where}={text!r} must look like {PATCH_SYNTAX}")
    try:
        return SoilPatch(float(parts[0]), parts[1].strip(), float(parts[2]))
    except ValueError:
        raise ValueError(f"{where}={text!r}: x_start_m and relative_density_pct must be numbers; "
                         f"expected {PATCH_SYNTAX}") from None


def glue_negative_patches(argv: list[str], option: str = "--patch") -> list[str]:
    """``argv`` with ``--patch -3:Sand:20`` written ``--patch=-3:Sand:20``: argparse reads a value
    that starts with '-' and is no plain number as an option, so a patch from x < 0 (behind the
    blade's start) was refused as "expected one argument"."""
    out: list[str] = []
    for arg in argv:
        if out and out[-1] == option and arg.startswith("-") and arg[1:2].isdigit():
            out[-1] = f"{option}={arg}"
        else:
            out.append(arg)
    return out


def to_patch(item, where: str = "patch") -> SoilPatch:
    """One patch from any entry form: a SoilPatch, ``'X:SOIL:ID'``, a mapping of the field
    names (metadata JSON, YAML) or an (x_start_m, soil, relative_density_pct) sequence."""
    if isinstance(item, SoilPatch):
        return item
    if isinstance(item, str):
        return parse_patch(item, where)
    if isinstance(item, dict):
        if set(item) != set(FIELDS):
            raise ValueError(f"{where}={item!r} must have exactly the keys {list(FIELDS)}")
        return SoilPatch(**item)
    if isinstance(item, (list, tuple)) and len(item) == 3:
        return SoilPatch(*item)
    raise ValueError(f"{where}={item!r} must be {PATCH_SYNTAX}, a mapping of {list(FIELDS)} "
                     "or an (x_start_m, soil, relative_density_pct) triple")


def check_patches(patches, field: str = "patches") -> tuple[SoilPatch, ...]:
    """Validate a path; ValueError naming ``field[i]``, the key and the value. () if empty."""
    out = []
    patches = list(patches or ())
    if len(patches) > MAX_PATCHES:
        raise ValueError(f"{field}: {len(patches)} patches, more than {MAX_PATCHES} (an episode's path travels with "
                         "its episode_start event, whose size is bounded); split the path into episodes")
    for i, item in enumerate(patches):
        where = f"{field}[{i}]"
        p = to_patch(item, where)
        if not finite_number(p.x_start_m):
            raise ValueError(f"{where}.x_start_m={short_repr(p.x_start_m)} must be a finite number [m]")
        if not isinstance(p.soil, str) or not p.soil.strip():
            raise ValueError(f"{where}.soil={p.soil!r} must be a soil name")
        if not finite_number(p.relative_density_pct) or not 0.0 <= p.relative_density_pct <= 100.0:
            raise ValueError(f"{where}.relative_density_pct={short_repr(p.relative_density_pct)} outside [0, 100] %")
        out.append(SoilPatch(float(p.x_start_m), p.soil.strip(), float(p.relative_density_pct)))
    name = field.rsplit(": ", 1)[-1]  # the field without where it came from, said once
    for i in range(1, len(out)):
        if not out[i].x_start_m > out[i - 1].x_start_m:
            raise ValueError(f"{field}[{i}].x_start_m={out[i].x_start_m!r} must be greater than "
                             f"{name}[{i - 1}].x_start_m={out[i - 1].x_start_m!r}: patches are ordered along x")
    return tuple(out)


def patch_under(patches, x_edge_m):
    """Index into ``patches`` (ordered by x, as ``check_patches`` gives them) of the patch under the
    edge at each x [m] (array-like): patch j holds from its start to the next patch's, the first
    also before its own start."""
    import numpy as np

    starts = np.array([float(p.x_start_m) for p in patches[1:]])
    return np.searchsorted(starts, np.asarray(x_edge_m, float), side="right")


def patches_tag(patches) -> str:
    """A short, stable tag of a path for episode names: ``p<count>-<6 hex digits>``."""
    path = check_patches(patches)
    digest = hashlib.sha1(json.dumps([p.as_dict() for p in path], sort_keys=True).encode()).hexdigest()
    return f"p{len(path)}-{digest[:6]}"
