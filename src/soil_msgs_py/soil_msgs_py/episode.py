"""One recorded episode as arrays, and its metadata.

This is the in-memory form of a bag: the batch generator produces it, the bag writer
writes it, the bag reader returns it, the trainer consumes it. Rows are 60 Hz ticks.
"""
from __future__ import annotations

import dataclasses
import json
from dataclasses import asdict, dataclass, field

import numpy as np

from .params import (FORCE_FIELDS, GROUND_TRUTH_PARAMS, KNOWN_PARAMS, MIN_TARGET_SPEED_M_S, OBSERVATION_FIELDS,
                     TICK_PERIOD_NS)
from .patches import SoilPatch, check_patches, patches_tag
from .values import PLAUSIBLE_ABS_LIMIT, finite_number, short_repr
from .soil_labels import UNKNOWN_SOILS

WORLD_MODES = ("fee", "default")
EPISODE_SCHEMA_VERSION = 1

# Per-tick extras that are not part of o_t but that users and plots want.
EXTRA_FIELDS: tuple[str, ...] = ("p_x_c", "v_x_b")


# What a bag's metadata may say of a world no simulator made (a machine's bags): what it may say of
# a soil nobody named
UNKNOWN_WORLDS = UNKNOWN_SOILS
# The largest seed: a signed 64-bit integer (the nodes' integer parameter type, numpy, bag readers)
MAX_SEED = 2**63 - 1
# The longest episode [s]: an hour of cut, far beyond any use, whose arrays still fit in memory
MAX_EPISODE_S = 3600.0

@dataclass
class EpisodeMeta:
    """What a user needs to know about how an episode was made (stored in the bag).

    ``patches``: the soil along the path (``patches.py``), as ``SoilPatch.as_dict()`` mappings;
    empty (and then absent from the JSON, as in bags made before patches existed) when the
    episode has one soil. With patches, ``soil`` and ``relative_density_pct`` are those of the patch
    under the blade's edge at the start (the first, unless the next starts at or behind it).
    """

    soil: str
    relative_density_pct: float
    world_mode: str
    seed: int
    target_speed_m_s: float
    target_depth_m: float
    duration_s: float
    effects: list[str] = field(default_factory=list)
    plugins: list[str] = field(default_factory=list)
    source: str = "soil_sim_batch"
    schema_version: int = EPISODE_SCHEMA_VERSION
    patches: list[dict] = field(default_factory=list)

    def soil_patches(self) -> tuple[SoilPatch, ...]:
        """The path as SoilPatch values (validated); () for a one-soil episode."""
        return check_patches(self.patches)

    def validate(self, machine_world: bool = False) -> None:
        """Raise ValueError naming the field and value if the metadata is not usable.
        ``machine_world``: a bag read back may also say its world is not known (``UNKNOWN_WORLDS``
        or null: a machine's, which no simulator world made)."""
        if self.schema_version != EPISODE_SCHEMA_VERSION or isinstance(self.schema_version, bool):
            raise ValueError(f"schema_version={short_repr(self.schema_version)}: this code reads episode metadata "
                             f"of version {EPISODE_SCHEMA_VERSION}")
        if not isinstance(self.soil, str):  # it names the bag and groups the training data ("" or "unknown": nobody's)
            raise ValueError(f"soil={short_repr(self.soil)} must be a soil's name (a string)")
        if not isinstance(self.source, str):
            raise ValueError(f"source={short_repr(self.source)} must be a string (the program that made the episode)")
        for name in ("effects", "plugins"):
            value = getattr(self, name)
            if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) for v in value):
                raise ValueError(f"{name}={short_repr(value)} must be a list of names (strings)")
        worlds = WORLD_MODES + (UNKNOWN_WORLDS if machine_world else ())
        if self.world_mode not in worlds and not (machine_world and self.world_mode is None):
            raise ValueError(f"world_mode={short_repr(self.world_mode)} is not one of {worlds}")
        for name in ("relative_density_pct", "target_speed_m_s", "target_depth_m", "duration_s"):
            value = getattr(self, name)
            if not finite_number(value):
                raise ValueError(f"{name}={short_repr(value)} must be a finite number")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or not 0 <= self.seed <= MAX_SEED:
            raise ValueError(f"seed={short_repr(self.seed)} must be an integer in [0, 2**63 - 1]")
        if not 0.0 <= self.relative_density_pct <= 100.0:
            raise ValueError(f"relative_density_pct={self.relative_density_pct} outside [0, 100] %")
        if self.target_depth_m < 0.0:
            raise ValueError(f"target_depth_m={self.target_depth_m} must be >= 0 m")
        if self.target_speed_m_s < MIN_TARGET_SPEED_M_S:
            raise ValueError(f"target_speed_m_s={self.target_speed_m_s} must be >= {MIN_TARGET_SPEED_M_S:g} m/s")
        if self.duration_s <= 0.0:
            raise ValueError(f"duration_s={self.duration_s} must be > 0 s")
        if not isinstance(self.patches, (list, tuple)):
            raise ValueError(f"patches={self.patches!r} must be a list of patches")
        self.soil_patches()

    def to_json(self) -> str:
        data = asdict(self)
        if not self.patches:  # a one-soil episode's metadata stays what it was before patches
            del data["patches"]
        else:
            data["patches"] = [p.as_dict() for p in self.soil_patches()]
        return json.dumps(data, sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> "EpisodeMeta":
        if not isinstance(text, (str, bytes)):  # (a metadata.yaml's custom_data written as a YAML mapping: "the
            # JSON object must be str, bytes or bytearray, not dict", naming neither what nor how)
            raise ValueError(f"episode metadata must be one JSON text (custom_data values are strings in rosbag2), "
                             f"not a {type(text).__name__}: write it as json.dumps of its fields")
        data = json.loads(text)
        if not isinstance(data, dict):  # (a list had read "unknown keys [1, 2]")
            raise ValueError(f"episode metadata must be a JSON object of its fields, not a {type(data).__name__}")
        known = {f for f in cls.__dataclass_fields__}
        unknown = set(data) - known
        if unknown:
            raise ValueError(f"episode metadata has unknown keys {sorted(map(str, unknown))}")
        required = [f.name for f in dataclasses.fields(cls)
                    if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING]
        if missing := [name for name in required if name not in data]:  # (it was a TypeError of __init__)
            raise ValueError(f"episode metadata lacks the field(s) {missing}")
        return cls(**data)

    @property
    def name(self) -> str:
        """A stable, human-readable episode name (also the bag directory name)."""
        return (
            f"{self.world_mode}_{self.soil.lower()}_id{self.relative_density_pct:03.0f}"
            f"_v{self.target_speed_m_s:.2f}_d{self.target_depth_m:.3f}_s{self.seed}"
            + (f"_{patches_tag(self.patches)}" if self.patches else "")
        )


def world_modes(metas) -> list[str]:
    """The sorted world modes (``world_mode``) of episodes' metadata, leaving out an empty or
    "unknown" one: which worlds a set of bags is from (the tools take one world's, or warn)."""
    return sorted({str(getattr(m, "world_mode", "") or "") for m in metas} - set(UNKNOWN_WORLDS))


@dataclass
class Episode:
    """Arrays of one episode, one row per 60 Hz tick.

    stamps_ns    (N,)   int64, simulation time of the tick [ns]
    observations (N, 9) OBSERVATION_FIELDS  o_t = [p, v, u]      [m, m/s]
    forces       (N, 2) FORCE_FIELDS        measured blade force [N], blade-on-soil, x fwd, z up
    known        (N, 9) KNOWN_PARAMS        Θ_k                  [SI]
    truth        (N,13) GROUND_TRUTH_PARAMS pseudo-ground-truth Θ [SI]
    extras       (N, 2) EXTRA_FIELDS        chassis x [m], blade x velocity [m/s]
    """

    meta: EpisodeMeta
    stamps_ns: np.ndarray
    observations: np.ndarray
    forces: np.ndarray
    known: np.ndarray
    truth: np.ndarray
    extras: np.ndarray

    def __post_init__(self) -> None:
        n = len(self.stamps_ns)
        expected = {
            "observations": len(OBSERVATION_FIELDS),
            "forces": len(FORCE_FIELDS),
            "known": len(KNOWN_PARAMS),
            "truth": len(GROUND_TRUTH_PARAMS),
            "extras": len(EXTRA_FIELDS),
        }
        for name, width in expected.items():
            arr = getattr(self, name)
            if arr.shape != (n, width):
                raise ValueError(f"Episode.{name} has shape {arr.shape}, expected ({n}, {width})")

    def __len__(self) -> int:
        return len(self.stamps_ns)

    @property
    def has_ground_truth(self) -> bool:
        """False for a machine's bag, recorded without ``/soil/ground_truth`` (truth all NaN)."""
        return bool(np.isfinite(self.truth).any())

    def column(self, name: str) -> np.ndarray:
        """Any named per-tick column, e.g. ``ep.column('p_z_b')`` or ``ep.column('q')``."""
        for fields, arr in (
            (OBSERVATION_FIELDS, self.observations),
            (FORCE_FIELDS, self.forces),
            (EXTRA_FIELDS, self.extras),
            (KNOWN_PARAMS, self.known),
            (GROUND_TRUTH_PARAMS, self.truth),
        ):
            if name in fields:
                return arr[:, fields.index(name)]
        raise KeyError(f"no column named {name!r}")

    @property
    def time_s(self) -> np.ndarray:
        return (self.stamps_ns - self.stamps_ns[0]) * 1e-9

    def problems(self) -> list[str]:
        """What a reader of this episode should be told before trusting a plot of it: gaps in its
        stamps (a repaired bag's dropped chunks) and non-finite or implausible values (ground truth excepted: a
        machine's bag has none)."""
        out = []
        gaps = np.flatnonzero(stamp_gaps(self.stamps_ns))
        if len(gaps):
            t = self.time_s
            spans = ", ".join(f"{t[i - 1]:.2f}-{t[i]:.2f} s" for i in gaps[:3]) + (" ..." if len(gaps) > 3 else "")
            out.append(f"{len(gaps)} gap(s) in its ticks ({spans})")
        for _, attr, fields in MODEL_INPUTS:
            if (first := first_implausible(getattr(self, attr), fields)) is not None:
                field, value, row, count = first
                out.append(f"{field!r} is {value} at tick {row} ({count} non-finite values or beyond "
                           f"±{PLAUSIBLE_ABS_LIMIT:g})")
        return out


# The arrays of an episode a model reads (ground truth and the simulator's extras aside): (what a
# message calls one of its values, the ``Episode`` attribute and a dataset cache's key, its fields).
MODEL_INPUTS = (("observation", "observations", OBSERVATION_FIELDS), ("force", "forces", FORCE_FIELDS),
                ("known parameter", "known", KNOWN_PARAMS))


def first_implausible(arr: np.ndarray, fields) -> tuple[str, float, int, int] | None:
    """(field, value, row, how many such values in all) of the first value of a (rows, fields)
    array, in row order, that is non-finite or beyond ±``PLAUSIBLE_ABS_LIMIT`` (the bound the
    live nodes drop a message at), or None if there is none. Why the bound offline too: one tick
    of v_z = 1e12 in a training bag set that channel's normalisation std to 1.7e10 and erased it
    from every window of the model (an outside tester's)."""
    with np.errstate(invalid="ignore"):
        bad = ~(np.abs(arr) <= PLAUSIBLE_ABS_LIMIT)  # (NaN compares False)
    if not bad.any():
        return None
    row, col = (int(i) for i in np.argwhere(bad)[0])
    return fields[col], float(arr[row, col]), row, int(bad.sum())


def stamp_gaps(stamps_ns: np.ndarray) -> np.ndarray:
    """(N,) bool: each stamp is more than 1.5 tick periods after the one before it."""
    return np.concatenate([[False], np.diff(np.asarray(stamps_ns, np.int64)) > 1.5 * TICK_PERIOD_NS])
