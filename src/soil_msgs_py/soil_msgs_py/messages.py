"""Episode rows <-> ROS 2 messages for every topic of ``topics.EPISODE_TOPICS``.

The ONE place that knows which Episode column goes into which message field, so the bag
writer, the bag reader and (later) the rclpy nodes cannot disagree. Builders take a
"class namespace": a rosbags ``Typestore``, a mapping ``msgtype -> class`` (e.g.
``ros_message_classes()``) or a callable. Both rosbags and rclpy message classes accept
all fields as keyword arguments and expose the same attribute names, so the mapping is
shared. rclpy is never imported here; ROS message packages only inside
``ros_message_classes()``.
"""
from __future__ import annotations

import functools
import importlib
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from operator import attrgetter
from typing import Any

import numpy as np
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

from . import topics as T
from .episode import EXTRA_FIELDS, Episode, EpisodeMeta
from .params import FORCE_FIELDS, GROUND_TRUTH_PARAMS, KNOWN_PARAMS, OBSERVATION_FIELDS
from .values import PLAUSIBLE_ABS_LIMIT  # noqa: F401 - the graph's nodes read it here (M.PLAUSIBLE_ABS_LIMIT)

NS_PER_S = 1_000_000_000
LABEL_SEP = "|"
# Jazzy definitions: what the nodes publish and what the bags embed.
TYPESTORE: Typestore = get_typestore(Stores.ROS2_JAZZY)

# Episode array attribute -> its column names (Episode.column() is ambiguous for Θ names
# that are both known and ground truth, e.g. "c_a", so columns are (array, field) pairs).
ARRAY_FIELDS: dict[str, tuple[str, ...]] = {
    "observations": OBSERVATION_FIELDS,
    "forces": FORCE_FIELDS,
    "known": KNOWN_PARAMS,
    "truth": GROUND_TRUTH_PARAMS,
    "extras": EXTRA_FIELDS,
}

Classes = Callable[[str], Any]


def classes_from(ns: Typestore | Mapping[str, Any] | Classes) -> Classes:
    """Normalise a typestore / mapping / callable into ``msgtype -> message class``."""
    if isinstance(ns, Typestore):
        return ns.types.__getitem__
    if isinstance(ns, Mapping):
        return ns.__getitem__
    if callable(ns):
        return ns
    raise TypeError(f"cannot get message classes from {type(ns).__name__}")


def ros_message_classes() -> dict[str, Any]:
    """``msgtype -> class`` from the installed ROS 2 Python message packages (for rclpy nodes)."""
    out: dict[str, Any] = {}
    needed = {t.msgtype for t in T.EPISODE_TOPICS} | {
        "builtin_interfaces/msg/Time", "std_msgs/msg/Header", "std_msgs/msg/MultiArrayLayout",
        "std_msgs/msg/MultiArrayDimension", "geometry_msgs/msg/Point",
        "geometry_msgs/msg/Vector3", "geometry_msgs/msg/Twist", "geometry_msgs/msg/Wrench",
        T.SOIL_MAP.msgtype, "sensor_msgs/msg/PointField",
    }
    for msgtype in sorted(needed):
        pkg, _, name = msgtype.split("/")
        out[msgtype] = getattr(importlib.import_module(f"{pkg}.msg"), name)
    return out


# --- stamps -------------------------------------------------------------------------

# The stamps the graph can mean: a builtin_interfaces/Time (int32 sec) not before the epoch,
# with nanosec below one second.
MAX_STAMP_SEC = 2**31 - 1
MAX_STAMP_NS = MAX_STAMP_SEC * NS_PER_S + NS_PER_S - 1


def split_ns(stamp_ns: int) -> tuple[int, int]:
    """ns -> (sec, nanosec), integers, nanosec in [0, 1e9)."""
    return divmod(int(stamp_ns), NS_PER_S)


def checked_stamp(sec: Any, nanosec: Any, topic: str = "", prefix: str = "stamp.") -> int:
    """ns of a (sec, nanosec) pair, or ValueError naming topic, field (``prefix`` + sec/nanosec) and value.

    The one stamp check of the graph: every parser goes through it, so a consumer only ever
    sees ns in [0, MAX_STAMP_NS]. Why: a labelled array's float seconds can say 1e308 and a
    header's nanosec can be 4e9; passed on, such a stamp crashes a bag writer (a log time
    beyond 64 bits), overflows a log line, or pins a node's "last tick" in the future."""
    where = f"{topic}: " if topic else ""
    for name, value, hi in ((prefix + "sec", sec, MAX_STAMP_SEC), (prefix + "nanosec", nanosec, NS_PER_S - 1)):
        if not _whole_in(value, hi):
            raise ValueError(f"{where}{name}={value!r} must be a whole number in [0, {hi}]")
    return int(sec) * NS_PER_S + int(nanosec)


def _whole_in(value: Any, hi: int) -> bool:
    """``value`` is a whole number in [0, hi] (NaN, inf, bools and non-numbers are not)."""
    if isinstance(value, bool):
        return False
    try:
        return bool(0 <= value <= hi and value == int(value))
    except (TypeError, ValueError, OverflowError):
        return False


def stamp_ns(t: Any, topic: str = "", prefix: str = "stamp.") -> int:
    """builtin_interfaces/Time -> ns; ValueError (see ``checked_stamp``) if the graph cannot mean it."""
    return checked_stamp(t.sec, t.nanosec, topic, prefix)


def _time(C: Classes, ns: int) -> Any:
    sec, nanosec = split_ns(ns)
    return C("builtin_interfaces/msg/Time")(sec=sec, nanosec=nanosec)


def _header(C: Classes, ns: int) -> Any:
    return C("std_msgs/msg/Header")(stamp=_time(C, ns), frame_id=T.WORLD_FRAME)


def _vec3(C: Classes, x: float, z: float) -> Any:
    return C("geometry_msgs/msg/Vector3")(x=float(x), y=0.0, z=float(z))


# --- point clouds (/soil/map) ---------------------------------------------------------

POINT_FIELD_FLOAT32 = 7  # sensor_msgs/PointField.FLOAT32


def make_point_cloud(ns: Any, stamp_ns: int, names: Sequence[str], rows: np.ndarray) -> Any:
    """PointCloud2 (frame world, little endian, dense, one row of float32 ``names`` per point)."""
    C = classes_from(ns)
    rows = np.ascontiguousarray(np.asarray(rows, dtype="<f4").reshape(-1, len(names)))
    fields = [C("sensor_msgs/msg/PointField")(name=n, offset=4 * i, datatype=POINT_FIELD_FLOAT32, count=1)
              for i, n in enumerate(names)]
    step = 4 * len(names)
    # rosbags' message classes take a uint8 array, rclpy's the bytes
    data = np.frombuffer(rows.tobytes(), np.uint8) if isinstance(ns, Typestore) else rows.tobytes()
    return C("sensor_msgs/msg/PointCloud2")(
        header=_header(C, stamp_ns), height=1, width=len(rows), fields=fields, is_bigendian=False,
        point_step=step, row_step=step * len(rows), data=data, is_dense=True)


def parse_point_cloud(msg: Any, names: Sequence[str], topic: str = "") -> tuple[int, np.ndarray]:
    """(stamp [ns], (n, len(names)) float64 rows) of a PointCloud2 made by ``make_point_cloud``;
    ValueError (naming ``topic``) if its layout is another."""
    where = f"{topic}: " if topic else ""
    got = [(f.name, f.offset, f.datatype, f.count) for f in msg.fields]
    want = [(n, 4 * i, POINT_FIELD_FLOAT32, 1) for i, n in enumerate(names)]
    if got != want or msg.point_step != 4 * len(names) or msg.is_bigendian or msg.height not in (0, 1):
        raise ValueError(f"{where}point cloud layout {got} (step {msg.point_step}) is not the expected float32 {list(names)}")
    data = np.asarray(msg.data, dtype=np.uint8).tobytes() if not isinstance(msg.data, (bytes, bytearray)) else bytes(msg.data)
    if len(data) != msg.width * msg.point_step:
        raise ValueError(f"{where}point cloud holds {len(data)} bytes for {msg.width} points of {msg.point_step}")
    rows = np.frombuffer(data, dtype="<f4").reshape(msg.width, len(names)).astype(float)
    return stamp_ns(msg.header.stamp, topic, "header.stamp."), rows


# --- labelled Float64MultiArray -------------------------------------------------------

@functools.lru_cache(maxsize=64)
def _label(labels: tuple[str, ...]) -> str:
    return LABEL_SEP.join(T.STAMP_FIELDS + tuple(labels))


def make_labelled(ns: Any, stamp_ns: int, labels: Sequence[str], values: Sequence[float]) -> Any:
    """Float64MultiArray with data = [stamp_sec, stamp_nanosec, *values], self-describing label."""
    if len(values) != len(labels):
        raise ValueError(f"{len(values)} values for {len(labels)} labels {tuple(labels)}")
    C = classes_from(ns)
    sec, nanosec = split_ns(stamp_ns)
    data = np.empty(len(labels) + 2, dtype=np.float64)
    data[0], data[1], data[2:] = sec, nanosec, values
    n = len(data)
    dim = C("std_msgs/msg/MultiArrayDimension")(label=_label(tuple(labels)), size=n, stride=n)
    layout = C("std_msgs/msg/MultiArrayLayout")(dim=[dim], data_offset=0)
    return C("std_msgs/msg/Float64MultiArray")(layout=layout, data=data)


def parse_labelled(msg: Any, expected_labels: Sequence[str], topic: str = "",
                   older: Sequence[Sequence[str]] | None = None) -> tuple[int, np.ndarray]:
    """Inverse of make_labelled; ValueError (naming ``topic``) if the layout is not the expected one.
    ``older``: the layouts of before fields were added (default: ``topics.OLDER_LAYOUTS``): a message
    in one of them is read into ``expected_labels``' order, the fields it lacks 0.0 (a bag recorded
    then, an estimator of before heard live)."""
    where = f"{topic}: " if topic else ""
    want = _label(tuple(expected_labels))
    dims = msg.layout.dim
    if len(dims) != 1:
        raise ValueError(f"{where}labelled array needs exactly 1 layout dim, got {len(dims)}")
    if dims[0].label != want:
        for labels in T.OLDER_LAYOUTS.get(tuple(expected_labels), ()) if older is None else older:
            if dims[0].label == _label(tuple(labels)):
                stamp, values = parse_labelled(msg, labels, topic, ())
                out = np.zeros(len(expected_labels))
                at = {name: i for i, name in enumerate(expected_labels)}
                out[[at[name] for name in labels]] = values
                return stamp, out
        raise ValueError(f"{where}label mismatch: got {dims[0].label!r}, expected {want!r}")
    data = np.asarray(msg.data, dtype=np.float64)
    n = len(want.split(LABEL_SEP))
    if len(data) != n or dims[0].size != n or dims[0].stride != n or msg.layout.data_offset != 0:
        raise ValueError(
            f"{where}labelled array has len(data)={len(data)}, size={dims[0].size}, "
            f"stride={dims[0].stride}, data_offset={msg.layout.data_offset}; expected {n}, {n}, {n}, 0"
        )
    return _array_stamp(data, topic), data[2:].copy()


def _array_stamp(data: Any, topic: str = "") -> int:
    """ns from a labelled array's leading (stamp_sec, stamp_nanosec) floats (``checked_stamp``)."""
    return checked_stamp(float(data[0]), float(data[1]), topic, "stamp_")


def labelled_stamp(msg: Any) -> int | None:
    """Stamp [ns] of any labelled array (its label starts with the stamp fields), else None.

    For topics outside ``FIELDS`` (``/soil/estimate``, the planner's output): a recorder can
    file them by simulation time without knowing their payload."""
    dims = getattr(getattr(msg, "layout", None), "dim", None)
    if not dims or not dims[0].label.startswith(_label(()) + LABEL_SEP) or len(msg.data) < 2:
        return None
    try:
        return _array_stamp(msg.data)
    except ValueError:
        return None


# --- per-topic mapping ---------------------------------------------------------------

@dataclass(frozen=True)
class TopicFields:
    """Which Episode columns a topic carries, and where they sit in the message."""

    topic: T.Topic
    columns: tuple[tuple[str, str], ...]  # (Episode array, field name), in message order
    paths: tuple[str, ...] = ()  # attribute paths for geometry types; () for labelled/Clock
    stamp_path: str = "header.stamp"

    @property
    def width(self) -> int:
        return len(self.columns)


def _cols(array: str, names: Iterable[str]) -> tuple[tuple[str, str], ...]:
    return tuple((array, n) for n in names)


def _obs(*names: str) -> tuple[tuple[str, str], ...]:
    return _cols("observations", names)


FIELDS: dict[str, TopicFields] = {
    f.topic.name: f
    for f in (
        TopicFields(T.CLOCK, (), stamp_path="clock"),
        TopicFields(T.BLADE_POSE, _obs("p_x_b", "p_z_b"), ("point.x", "point.z")),
        TopicFields(T.BLADE_TWIST, (("extras", "v_x_b"),) + _obs("v_z_b"),
                    ("twist.linear.x", "twist.linear.z")),
        TopicFields(T.CHASSIS_POSE, (("extras", "p_x_c"),) + _obs("p_z_c"), ("point.x", "point.z")),
        TopicFields(T.CHASSIS_TWIST, _obs("v_x_c", "v_z_c"), ("twist.linear.x", "twist.linear.z")),
        TopicFields(T.BLADE_FORCE, _cols("forces", FORCE_FIELDS), ("wrench.force.x", "wrench.force.z")),
        TopicFields(T.KNOWN, _cols("known", KNOWN_PARAMS)),
        TopicFields(T.GROUND_TRUTH, _cols("truth", GROUND_TRUTH_PARAMS)),
        TopicFields(T.CMD_VEL, _obs("u_x"), ("twist.linear.x",)),
        TopicFields(T.BLADE_CMD, _obs("u_zr", "u_za")),
    )
}
assert tuple(FIELDS) == tuple(t.name for t in T.EPISODE_TOPICS), "mapping out of sync with topics.py"
_ALL = sorted(c for f in FIELDS.values() for c in f.columns)
assert _ALL == sorted((a, n) for a, names in ARRAY_FIELDS.items() for n in names), (
    "every Episode column must be carried by exactly one topic"
)


def build_message(ns: Any, topic: str, stamp: int, values: Sequence[float] = ()) -> Any:
    """One message of ``topic`` for a tick; ``values`` in ``FIELDS[topic].columns`` order."""
    f = FIELDS[topic]
    C = classes_from(ns)
    if len(values) != f.width:
        raise ValueError(f"{topic}: {len(values)} values, expected {f.width} {f.columns}")
    mt = f.topic.msgtype
    if f.topic.labels:
        return make_labelled(C, stamp, f.topic.labels, values)
    if mt == "rosgraph_msgs/msg/Clock":
        return C(mt)(clock=_time(C, stamp))
    if mt == "geometry_msgs/msg/PointStamped":
        x, z = values
        point = C("geometry_msgs/msg/Point")(x=float(x), y=0.0, z=float(z))
        return C(mt)(header=_header(C, stamp), point=point)
    if mt == "geometry_msgs/msg/TwistStamped":
        x, z = (values[0], 0.0) if len(values) == 1 else values
        twist = C("geometry_msgs/msg/Twist")(linear=_vec3(C, x, z), angular=_vec3(C, 0.0, 0.0))
        return C(mt)(header=_header(C, stamp), twist=twist)
    if mt == "geometry_msgs/msg/WrenchStamped":
        x, z = values
        wrench = C("geometry_msgs/msg/Wrench")(force=_vec3(C, x, z), torque=_vec3(C, 0.0, 0.0))
        return C(mt)(header=_header(C, stamp), wrench=wrench)
    raise AssertionError(f"no builder for {mt}")


@functools.lru_cache(maxsize=None)
def _getters(topic: str) -> tuple[Callable[[Any], Any], Callable[[Any], Any] | None]:
    f = FIELDS[topic]
    values = attrgetter(*f.paths) if f.paths else None
    return attrgetter(f.stamp_path), values


def parse_message(topic: str, msg: Any) -> tuple[int, np.ndarray]:
    """Inverse of build_message: (stamp ns, values in ``FIELDS[topic].columns`` order); ValueError
    naming topic, field and value for a stamp the graph cannot mean (``checked_stamp``)."""
    f = FIELDS[topic]
    if f.topic.labels:
        return parse_labelled(msg, f.topic.labels, topic)
    get_stamp, get_values = _getters(topic)
    stamp = stamp_ns(get_stamp(msg), topic, f.stamp_path + ".")
    if get_values is None:
        return stamp, np.empty(0)
    vals = get_values(msg)
    return stamp, np.array(vals if isinstance(vals, tuple) else (vals,), dtype=np.float64)


def plausible_values(values: Any, subnormal: bool = False) -> bool:
    """Whether every value could be a graph node's: finite, within ±``PLAUSIBLE_ABS_LIMIT`` and
    (unless ``subnormal``) not subnormal. What tells two claims of one tick apart when their
    writers cannot be (same stamp, same sequence number): a finite 1e30 is as much garbage as a
    NaN, and so is 5e-324: no SI quantity of the graph comes within 300 orders of magnitude of a
    subnormal. A node judging a measured state value alone takes a subnormal (``subnormal``): a
    quantity decaying to rest (a surcharge shed, a velocity) may pass through one, and it is 0 to
    any physics, where dropping its tick would reset a window."""
    a = np.abs(np.asarray(values, dtype=np.float64))
    tiny = 0.0 if subnormal else np.finfo(np.float64).tiny
    return bool(((a <= PLAUSIBLE_ABS_LIMIT) & ((a == 0.0) | (a >= tiny))).all())  # NaN: False


# --- whole episodes --------------------------------------------------------------------

def topic_rows(ep: Episode, topic: str) -> np.ndarray:
    """(N, width) float64 matrix of the Episode columns that ``topic`` carries."""
    cols = [getattr(ep, a)[:, ARRAY_FIELDS[a].index(n)] for a, n in FIELDS[topic].columns]
    return np.stack(cols, axis=1) if cols else np.empty((len(ep), 0))


def serialize_episode(ep: Episode, typestore: Typestore = TYPESTORE,
                      topics: tuple[str, ...] | None = None) -> Iterator[tuple[str, int, memoryview]]:
    """(topic, log time ns, CDR bytes) per tick, topics in EPISODE_TOPICS order within a tick
    (``topics``: only those; default every episode topic)."""
    names = [n for n in FIELDS if topics is None or n in topics]
    rows = {name: topic_rows(ep, name).tolist() for name in names}
    for i, stamp in enumerate(ep.stamps_ns.tolist()):
        for name in names:
            f = FIELDS[name]
            msg = build_message(typestore, name, stamp, rows[name][i])
            yield name, stamp, typestore.serialize_cdr(msg, f.topic.msgtype)


def decode_topic(
    topic: str, raws: Iterable[bytes | memoryview], typestore: Typestore = TYPESTORE
) -> tuple[np.ndarray, np.ndarray]:
    """CDR messages of one topic -> (stamps int64 (n,), values float64 (n, width))."""
    f = FIELDS[topic]
    deser, mt = typestore.deserialize_cdr, f.topic.msgtype
    stamps: list[int] = []
    rows: list[np.ndarray] = []
    for raw in raws:
        s, v = parse_message(topic, deser(raw, mt))
        stamps.append(s)
        rows.append(v)
    values = np.stack(rows) if rows else np.empty((0, f.width))
    return np.asarray(stamps, dtype=np.int64), values.reshape(len(stamps), f.width)


def assemble_episode(meta: EpisodeMeta, decoded: Mapping[str, tuple[np.ndarray, np.ndarray]]) -> Episode:
    """Per-topic (stamps, values) -> Episode; ValueError naming the topic and stamp of any gap."""
    for name in FIELDS:
        if name not in decoded:
            raise ValueError(f"topic {name} missing")
    all_stamps = np.unique(np.concatenate([decoded[n][0] for n in FIELDS]))
    n = len(all_stamps)
    arrays = {a: np.empty((n, len(names))) for a, names in ARRAY_FIELDS.items()}
    for name, f in FIELDS.items():
        stamps, values = decoded[name]
        order = np.argsort(stamps, kind="stable")
        stamps, values = stamps[order], values[order]
        if len(stamps) > 1 and (dup := np.flatnonzero(np.diff(stamps) == 0)).size:
            raise ValueError(f"topic {name} has two messages with stamp {stamps[dup[0]]} ns")
        if len(stamps) != n:  # stamps is a sorted unique subset of all_stamps
            missing = np.setdiff1d(all_stamps, stamps)[0]
            raise ValueError(f"topic {name} has no message for tick stamp {missing} ns")
        for j, (a, col) in enumerate(f.columns):
            arrays[a][:, ARRAY_FIELDS[a].index(col)] = values[:, j]
    return Episode(meta=meta, stamps_ns=all_stamps.astype(np.int64), **arrays)


@functools.lru_cache(maxsize=None)
def _row_index(topic: str) -> tuple[tuple[str, int], ...]:
    return tuple((a, ARRAY_FIELDS[a].index(n)) for a, n in FIELDS[topic].columns)


def tick_values(topic: str, rows: Mapping[str, Sequence[float]]) -> list[float]:
    """Values of ``topic`` for one tick from per-array rows, e.g. ``{"forces": (fx, fz), ...}``
    (keys as in ARRAY_FIELDS; only the arrays the topic carries are needed). What a live
    node publishes for a tick, in the same column order ``build_message`` expects."""
    return [float(rows[a][i]) for a, i in _row_index(topic)]
