"""A hostile participant for live fuzzing of the graph, and a clean observer to judge it.

``HostileNode`` joins a running graph on loopback and publishes a bounded, seeded stream of
malformed messages on the graph's topics: non-finite and absurd values, wrong array layouts
and labels, impossible stamps (sec = 1e308 or 2^63, negative, nanosec >= 1e9, far future,
stale, off the 60 Hz grid), corrupt CDR, broken JSON on the control topics, and garbage
copies of real ticks stamped like them (spoofing). Every message is published as CDR bytes
and remembered, so ``GraphObserver`` can tell the graph's own messages from the intruder's
by content: nothing the graph's nodes publish can be byte-identical to a message carrying
garbage.

Why spoofing is timed as it is: the simulator's command gate keeps the first command of a
tick and the controller pairs the first complete (twist, pose) of a stamp, so a copy that
races the real message could legitimately change the run. Copies therefore follow the real
message they imitate (commands right after the controller's, the controller's own inputs
right after its answer), while copies of topics that steer nothing (force, Θ_k, Θ, blade
state, clock, estimates) are also sent *ahead* of the next tick to test "the intruder came
first". Drawing from ``random.Random(seed)`` keeps the stream reproducible up to timing.
"""
from __future__ import annotations

import collections
import json
import math
import random
import struct
import threading
import time

import numpy as np

from rclpy.serialization import deserialize_message, serialize_message
from std_msgs.msg import String

from soil_msgs_py import graph as G
from soil_msgs_py import messages as M
from soil_msgs_py import topics as T
from soil_msgs_py.ros_adapter import message_class, qos_profile, topic_qos

from tests.ros_probe import RosProbe

NS = 10**9
CLASSES = M.ros_message_classes()
GARBAGE = (math.nan, math.inf, -math.inf, 1e308, -1e308, 1e30, 5e-324)
MSGTYPES = {t.name: t.msgtype for t in T.GRAPH_TOPICS_BY_NAME.values()}
MSGTYPES[G.SIM_COMMAND_TOPIC] = MSGTYPES[G.SIM_STATUS_TOPIC] = G.STRING_MSGTYPE

CONTROLLER_INPUTS = G.CONTROLLER_STATE_TOPICS  # (/chassis/twist, /chassis/pose)
# Topics whose same-stamp copies may arrive before the real message without steering the run.
PASSIVE_STATE_TOPICS = tuple(t for t in G.SIM_STATE_TOPICS if t not in CONTROLLER_INPUTS)
LABELLED_TOPICS = (T.KNOWN.name, T.GROUND_TRUTH.name, T.BLADE_CMD.name, T.ESTIMATE.name)
HEADER_TOPICS = (T.BLADE_POSE.name, T.BLADE_TWIST.name, T.CHASSIS_POSE.name, T.CHASSIS_TWIST.name,
                 T.BLADE_FORCE.name, T.CMD_VEL.name, T.ESTIMATED_FORCE.name)
INT32_MAX, UINT32_MAX = 2**31 - 1, 2**32 - 1
# The estimator's per-tick outputs a spoof copies ahead of the next tick (/soil/map is sent per
# stretch, not per tick: a copy "ahead of the next tick" of it is not the attack this models).
SPOOFED_ESTIMATOR_OUTPUTS = (T.ESTIMATE.name, T.ESTIMATED_FORCE.name)


def grid_stamp(first_ns: int, k: int) -> int:
    """Stamp of tick ``k`` of an episode starting at ``first_ns`` (the simulator's 60 Hz grid)."""
    return first_ns + (k * NS) // 60


def tick_index(first_ns: int, stamp_ns: int) -> int:
    return round((stamp_ns - first_ns) * 60 / NS)


def _width(topic: str) -> int:
    if topic == T.ESTIMATE.name:
        return len(T.ESTIMATE_FIELDS)
    if topic == T.SOIL_MAP.name:
        return len(T.MAP_FIELDS)  # one point
    if topic == T.ESTIMATED_FORCE.name:
        return 2
    return M.FIELDS[topic].width


def build(topic: str, stamp_ns: int, values) -> object:
    """A well-typed message of ``topic`` (any stamp, any values): the shape a spoof wears."""
    if topic == T.ESTIMATE.name:
        return M.make_labelled(CLASSES, stamp_ns, T.ESTIMATE_FIELDS, values)
    if topic == T.SOIL_MAP.name:
        return M.make_point_cloud(CLASSES, stamp_ns, T.MAP_FIELDS, [values])
    if topic == T.ESTIMATED_FORCE.name:
        return M.build_message(CLASSES, T.BLADE_FORCE.name, stamp_ns, values)
    return M.build_message(CLASSES, topic, stamp_ns, values)


def set_header_stamp(msg, sec: int, nanosec: int):
    """Header (or Clock) stamp as raw (sec, nanosec): non-canonical pairs included."""
    stamp = msg.clock if hasattr(msg, "clock") else msg.header.stamp
    stamp.sec, stamp.nanosec = sec, nanosec
    return msg


def _deep_json(depth: int, kind: str) -> str:
    return ("[" * depth + "]" * depth) if kind == "list" else ('{"a":' * depth + "1" + "}" * depth)


# /sim/command texts that must all be refused (none is a valid start, reset or shutdown).
BAD_SIM_COMMANDS = (
    "{not json", "", "null", "[]", "42", '"reset"', "true", "[" * 10,
    _deep_json(100_000, "list"), _deep_json(50_000, "dict"),
    json.dumps({"action": "start", "soil": "x" * 300_000}),
    json.dumps({"action": "explode"}), json.dumps({"action": "RESET"}), json.dumps({"action": None}),
    json.dumps({"action": ["start"]}), json.dumps({"action": {"nested": [1, 2]}}), json.dumps({}),
    json.dumps({"action": "start", "relative_density_pct": 250}), json.dumps({"action": "start", "soil": 5}),
    json.dumps({"action": "start", "soil": "Mud"}), json.dumps({"action": "start", "seed": -1}),
    json.dumps({"action": "start", "seed": 0.5}), json.dumps({"action": "start", "duration_s": -1.0}),
    json.dumps({"action": "start", "duration_s": True}), json.dumps({"action": "start", "bogus": 1}),
    json.dumps({"action": "start", "target_speed_m_s": 1e308}), json.dumps({"action": "reset", "now": True}),
    json.dumps({"action": "shutdown", "x": 1}),
    '{"action": "start", "duration_s": NaN}', '{"action": "start", "target_depth_m": 1e999}',
    '{"action": "start", "relative_density_pct": -Infinity}',
)
# /sim/status texts that must all be refused by every node reading it.
BAD_SIM_STATUS = (
    "{not json", "", "null", "[]", "3.5", _deep_json(100_000, "list"), _deep_json(50_000, "dict"),
    json.dumps({"event": "explode"}), json.dumps({"event": "episode_start"}),
    json.dumps({"event": "episode_start", "episode": -1, "name": "x", "meta": {}, "first_stamp_ns": 0,
                "planned_ticks": 1}),
    json.dumps({"event": "episode_end", "episode": 0, "name": "../../etc", "meta": None, "first_stamp_ns": 2**70,
                "planned_ticks": "many", "last_stamp_ns": 1.5, "ticks": -3}),
    '{"event": "episode_start", "episode": NaN, "first_stamp_ns": Infinity}',
    json.dumps({"event": "episode_end", "x": "y" * 300_000}),
)


class MalformedMessages:
    """Seeded generator of malformed messages; every kind comes once per shuffled round."""

    def __init__(self, seed: int):
        self.rng = random.Random(seed)
        self.kinds = [getattr(self, n) for n in sorted(dir(self)) if n.startswith("kind_")]
        self._round: list = []

    def draw(self, first_ns: int, now_ns: int) -> list[tuple[str, object]]:
        """(topic, message or CDR bytes) of one malformed publication, near tick ``now_ns``."""
        if not self._round:
            self._round = list(self.kinds)
            self.rng.shuffle(self._round)
        return self._round.pop()(first_ns, now_ns)

    # --- helpers ----------------------------------------------------------------------------
    def _garbage(self, n: int) -> list[float]:
        return [self.rng.choice(GARBAGE) for _ in range(n)]

    def _plausible(self, n: int) -> list[float]:
        return [self.rng.uniform(-1.0, 1.0) for _ in range(n)]

    def _bad_but_whole_stamp(self, first_ns: int, now_ns: int) -> int:
        """A stamp the simulator never publishes: stale, far future or off the grid."""
        k = tick_index(first_ns, now_ns)
        return self.rng.choice([
            first_ns - NS // 60, grid_stamp(first_ns, max(k - 5, 0)) - 7, now_ns + 3600 * NS, now_ns + 10**6 * NS,
            grid_stamp(first_ns, k + 1) + 1, now_ns + NS // 120,
        ])

    # --- kinds ------------------------------------------------------------------------------
    def kind_labelled_impossible_stamp(self, first_ns, now_ns):
        topic = self.rng.choice(LABELLED_TOPICS)
        msg = build(topic, now_ns, self._plausible(_width(topic)))
        sec, nanosec = self.rng.choice([(1e308, 0.0), (2.0**63, 0.0), (-1.0, 0.0), (math.nan, 0.0), (math.inf, 0.0),
                                        (1.5, 0.0), (0.0, 1e9), (0.0, -1.0), (0.0, 0.5), (0.0, math.nan),
                                        (2.0**63, 1e308), (-1e308, 4e9)])
        msg.data[0], msg.data[1] = sec, nanosec
        return [(topic, msg)]

    def kind_labelled_non_finite(self, first_ns, now_ns):
        topic = self.rng.choice(LABELLED_TOPICS)
        return [(topic, build(topic, self._bad_but_whole_stamp(first_ns, now_ns), self._garbage(_width(topic))))]

    def kind_labelled_wrong_labels(self, first_ns, now_ns):
        topic = self.rng.choice(LABELLED_TOPICS)
        n = _width(topic)
        msg = build(topic, now_ns, self._plausible(n))
        labels = msg.layout.dim[0].label.split(M.LABEL_SEP)
        msg.layout.dim[0].label = self.rng.choice([
            M.LABEL_SEP.join(reversed(labels)), M.LABEL_SEP.join(labels[2:]), "", "x" * 70_000,
            M.LABEL_SEP.join(labels[:2] + ["u_zr", "u_zb"] + labels[4:]), M.LABEL_SEP.join(labels + ["extra"]),
            M.LABEL_SEP.join(labels[:2] + labels[3:]),
        ])
        return [(topic, msg)]

    def kind_labelled_wrong_shape(self, first_ns, now_ns):
        topic = self.rng.choice(LABELLED_TOPICS)
        msg = build(topic, now_ns, self._plausible(_width(topic)))
        how = self.rng.randrange(6)
        if how == 0:
            msg.data = msg.data[:2]
        elif how == 1:
            msg.data = []
        elif how == 2:
            msg.data = list(msg.data) + [0.0] * 5
        elif how == 3:
            msg.layout.dim = []
        elif how == 4:
            msg.layout.dim = [msg.layout.dim[0], msg.layout.dim[0]]
        else:
            msg.layout.dim[0].size, msg.layout.dim[0].stride, msg.layout.data_offset = UINT32_MAX, 0, 3
        return [(topic, msg)]

    def kind_header_impossible_stamp(self, first_ns, now_ns):
        topic = self.rng.choice(HEADER_TOPICS + (T.CLOCK.name,))
        msg = build(topic, now_ns, self._plausible(_width(topic)))
        sec, nanosec = divmod(now_ns, NS)
        return [(topic, set_header_stamp(msg, *self.rng.choice([
            (INT32_MAX, UINT32_MAX), (-(2**31), 0), (-1, 0), (0, UINT32_MAX), (sec, NS), (sec, 3 * NS),
            (INT32_MAX, 0), (sec + 3600, 0),
        ])))]

    def kind_header_non_finite(self, first_ns, now_ns):
        topic = self.rng.choice(HEADER_TOPICS)
        msg = build(topic, self._bad_but_whole_stamp(first_ns, now_ns), self._garbage(_width(topic)))
        if self.rng.random() < 0.3:
            msg.header.frame_id = "w" * 65_536
        return [(topic, msg)]

    def kind_clock_off_grid(self, first_ns, now_ns):
        k = tick_index(first_ns, now_ns)
        stamp = self.rng.choice([grid_stamp(first_ns, k) + 1, grid_stamp(first_ns, k + 2) - 3, now_ns + NS // 7])
        return [(T.CLOCK.name, build(T.CLOCK.name, stamp, []))]

    def kind_controller_pair_from_the_future(self, first_ns, now_ns):
        """twist + pose of one bogus stamp: a complete tick the controller must not answer."""
        ahead_sec, ahead_ns = divmod(grid_stamp(first_ns, tick_index(first_ns, now_ns) + 30), NS)
        sec, nanosec = self.rng.choice([
            divmod(now_ns + 3600 * NS, NS), divmod(now_ns + 10**6 * NS, NS), (INT32_MAX, 999_999_999),
            (0, UINT32_MAX),
            # half a second ahead, written with nanosec >= 1e9 (another spelling of a grid stamp)
            (ahead_sec - 1, ahead_ns + NS) if ahead_sec >= 1 else (INT32_MAX, 0),
        ])
        twist = set_header_stamp(build(T.CHASSIS_TWIST.name, now_ns, [0.5, 0.0]), sec, nanosec)
        pose = set_header_stamp(build(T.CHASSIS_POSE.name, now_ns, [1.0, -0.05]), sec, nanosec)
        return [(T.CHASSIS_TWIST.name, twist), (T.CHASSIS_POSE.name, pose)]

    def kind_command_bad_stamp(self, first_ns, now_ns):
        topic = self.rng.choice(G.COMMAND_TOPICS)
        values = self._garbage(_width(topic)) if self.rng.random() < 0.5 else self._plausible(_width(topic))
        return [(topic, build(topic, self._bad_but_whole_stamp(first_ns, now_ns), values))]

    def kind_sim_command_json(self, first_ns, now_ns):
        return [(G.SIM_COMMAND_TOPIC, String(data=self.rng.choice(BAD_SIM_COMMANDS)))]

    def kind_sim_status_json(self, first_ns, now_ns):
        return [(G.SIM_STATUS_TOPIC, String(data=self.rng.choice(BAD_SIM_STATUS)))]

    def kind_sim_status_stray_event(self, first_ns, now_ns):
        """Well formed, but not this graph's: another episode's start (2 m/s, 0.6 m: it would
        retarget the controller) or end (it would stop it answering), without a graph id or with
        another's. Nothing may take it for the episode under way's."""
        from soil_msgs_py.episode import EpisodeMeta

        meta = EpisodeMeta(soil="Sand", relative_density_pct=20.0, world_mode="default", seed=99,
                           target_speed_m_s=2.0, target_depth_m=0.6, duration_s=10.0)
        event = self.rng.choice([G.EVENT_EPISODE_START, G.EVENT_EPISODE_END])
        end = {"last_stamp_ns": now_ns, "ticks": 5, "reason": "completed"} if event == G.EVENT_EPISODE_END else {}
        # (stamped as another episode's, a day on: ticks stamped back at a start are what would show a
        # simulator started over there, ``recorder._held_start``)
        stray = G.EpisodeEvent(event, 7, f"stray_episode_{self.rng.randrange(1000)}", meta, first_ns + 86_400 * NS,
                               planned_ticks=600, graph=self.rng.choice(["", "launch-other"]), **end)
        return [(G.SIM_STATUS_TOPIC, String(data=stray.to_json()))]

    def kind_corrupt_cdr(self, first_ns, now_ns):
        """Bytes no well-behaved writer produces: truncated, lying lengths, invalid UTF-8."""
        topic = self.rng.choice(HEADER_TOPICS + LABELLED_TOPICS + (G.SIM_COMMAND_TOPIC, G.SIM_STATUS_TOPIC))
        if topic in (G.SIM_COMMAND_TOPIC, G.SIM_STATUS_TOPIC):
            body = self.rng.choice([b"\xff\xfe{\x80", b'{"action": "reset"\xc3'])
            raw = b"\x00\x01\x00\x00" + struct.pack("<I", len(body) + 1) + body + b"\x00"
            if self.rng.random() < 0.5:
                raw = b"\x00\x01\x00\x00" + struct.pack("<I", 2**31) + b"abc\x00"
            return [(topic, raw)]
        raw = bytearray(serialize_message(build(topic, now_ns, self._plausible(_width(topic)))))
        how = self.rng.randrange(3)
        if how == 0:
            raw = raw[: len(raw) // 2]
        elif how == 1:
            raw[4:8] = struct.pack("<I", UINT32_MAX)  # first length/count field after the encapsulation
        else:
            raw = raw[:4]
        return [(topic, bytes(raw))]


class HostileNode(RosProbe):
    """Publishes a bounded, seeded stream of malformed messages into a running graph.

    Reacts to the simulator's ticks as it sees them (so the stream lands inside the episode
    whatever the pacing): per tick one message of ``MalformedMessages`` and, at random, garbage
    copies of real messages stamped like them (see the module docstring for their timing)."""

    def __init__(self, domain_id: int, seed: int, budget: int):
        super().__init__(domain_id, name="hostile")
        self.generator = MalformedMessages(seed)
        self.rng = random.Random(seed + 1)
        self.budget = budget
        self.sent = 0
        self.sent_raw: collections.Counter = collections.Counter()  # (topic, CDR bytes) -> times published
        self.first_ns: int | None = None
        self.now_ns = 0
        self.sent_by_tick: dict[int, int] = {}  # real tick stamp -> messages sent when it was seen
        self.spoofed_stamps: set[tuple[str, int]] = set()
        self._own = set()
        self._pub_lock = threading.Lock()
        for topic in (*G.SIM_STATE_TOPICS, *G.COMMAND_TOPICS):
            self.node.create_subscription(message_class(MSGTYPES[topic]), topic,
                                          lambda raw, t=topic: self._on_real(t, raw), topic_qos(topic), raw=True)
        for topic in MSGTYPES:
            self.publisher(topic, MSGTYPES[topic])

    # --- publishing --------------------------------------------------------------------------
    def send(self, topic: str, msg) -> bool:
        """Publish one message (object or CDR bytes) unless the budget is spent."""
        with self._pub_lock:
            if self.sent >= self.budget:
                return False
            raw = msg if isinstance(msg, bytes) else serialize_message(msg)
            self.sent += 1
            self.sent_raw[(topic, raw)] += 1
            self._own.add((topic, raw))
        self.pubs[topic].publish(raw)
        return True

    def _spoof(self, topic: str, stamp_ns: int) -> None:
        """A garbage copy of ``topic`` stamped ``stamp_ns`` (for the clock: a non-canonical stamp)."""
        msg = build(topic, stamp_ns, [self.rng.choice(GARBAGE) for _ in range(_width(topic))])
        if topic == T.CLOCK.name or (topic in HEADER_TOPICS and self.rng.random() < 0.25):
            sec, nanosec = divmod(stamp_ns, NS)
            if sec > 0:  # the same instant written as (sec - 1, nanosec + 1e9)
                set_header_stamp(msg, sec - 1, nanosec + NS)
        if self.send(topic, msg):
            self.spoofed_stamps.add((topic, stamp_ns))

    # --- reacting to the real graph ----------------------------------------------------------
    def _on_real(self, topic: str, raw: bytes) -> None:
        if (topic, raw) in self._own:
            return
        try:
            stamp, _ = M.parse_message(topic, deserialize_message(raw, message_class(MSGTYPES[topic])))
        except Exception:  # noqa: BLE001 - another intruder's message; not ours to judge here
            return
        if self.first_ns is None:
            self.first_ns = stamp
        if topic == T.CHASSIS_POSE.name and stamp > self.now_ns:
            self.now_ns = stamp
            self.sent_by_tick[stamp] = self.sent
            for t, msg in self.generator.draw(self.first_ns, stamp):
                self.send(t, msg)
        if topic in PASSIVE_STATE_TOPICS:
            if self.rng.random() < 0.15:  # after the real one
                self._spoof(topic, stamp)
            if self.rng.random() < 0.15:  # ahead of the next tick, before the real one can exist
                k = tick_index(self.first_ns, stamp)
                self._spoof(self.rng.choice(PASSIVE_STATE_TOPICS + SPOOFED_ESTIMATOR_OUTPUTS),
                            grid_stamp(self.first_ns, k + 1))
        elif topic in G.COMMAND_TOPICS and self.rng.random() < 0.3:
            self._spoof(topic, stamp)  # right after the controller's own command of that tick
            if topic == T.BLADE_CMD.name and self.rng.random() < 0.5:
                for t in CONTROLLER_INPUTS:  # the tick is answered: its state comes again, as garbage
                    self._spoof(t, stamp)


class GraphObserver(RosProbe):
    """A clean participant that records every message on the given topics as CDR bytes.

    It subscribes as deep as the recorder does: a lockstep graph runs as fast as its slowest
    node, far above 60 Hz, and a reader that fell 120 samples behind (the graph's depth)
    would lose messages the graph did publish."""

    QOS = qos_profile(G.RECORDER_QOS)

    def __init__(self, domain_id: int, topics, held=(), until_matched: dict[str, int] | None = None,
                 limit_s: float = 60.0):
        """``held`` topics are subscribed only once the subscription of each topic in
        ``until_matched`` has matched that many publishers (at most ``limit_s``): a simulator that
        waits for the held topics' subscribers (``--wait-for``) then starts its episode only when
        the observer also hears the nodes publishing the other topics. Without it a busy machine
        let the first second of the controller's commands pass by the observer (VOLATILE: lost)."""
        super().__init__(domain_id, name="observer")
        self.raw: dict[str, list[bytes]] = collections.defaultdict(list)
        self.subs = {}
        for topic in topics:
            if topic not in held:
                self._subscribe(topic)
        self.matched_s: float | None = None  # how long the held topics waited (None: not yet / never)
        if held:
            threading.Thread(target=self._hold, args=(tuple(held), dict(until_matched or {}), limit_s),
                             daemon=True).start()

    def _subscribe(self, topic: str) -> None:
        self.subs[topic] = self.node.create_subscription(message_class(MSGTYPES[topic]), topic,
                                                         lambda raw, t=topic: self._keep(t, raw), self.QOS, raw=True)

    def _hold(self, held, until_matched, limit_s) -> None:
        start = time.monotonic()
        while time.monotonic() - start < limit_s and not self._stop.is_set():
            if all(self.subs[t].get_publisher_count() >= n for t, n in until_matched.items()):
                self.matched_s = time.monotonic() - start
                break
            time.sleep(0.02)
        if not self._stop.is_set():
            for topic in held:
                self._subscribe(topic)

    def _keep(self, topic: str, raw: bytes) -> None:
        with self.lock:
            self.raw[topic].append(raw)

    def settle(self, quiet_s: float = 1.0, limit_s: float = 20.0) -> None:
        """Wait until no message arrived for ``quiet_s`` (at most ``limit_s``): on a loaded machine
        the observer, sharing its process with the hostile node, may still be taking messages
        a fast lockstep graph published."""
        deadline = time.monotonic() + limit_s
        seen, since = -1, time.monotonic()
        while time.monotonic() < deadline:
            with self.lock:
                n = sum(len(v) for v in self.raw.values())
            if n != seen:
                seen, since = n, time.monotonic()
            elif time.monotonic() - since >= quiet_s:
                return
            time.sleep(0.1)

    def graph_messages(self, topic: str, hostile: HostileNode) -> list[object]:
        """What the graph's own nodes published on ``topic``: every observed message minus one
        copy of each message the hostile node published, deserialised."""
        left = collections.Counter({k: v for k, v in hostile.sent_raw.items() if k[0] == topic})
        out = []
        with self.lock:
            raws = list(self.raw[topic])
        for raw in raws:
            if left[(topic, raw)] > 0:
                left[(topic, raw)] -= 1
                continue
            out.append(deserialize_message(raw, message_class(MSGTYPES[topic])))
        return out


def non_finite_fields(msg) -> list[str]:
    """Names of the float fields of a graph message that are not finite (and impossible stamps)."""
    bad = []
    if isinstance(msg, String):
        try:
            json.loads(msg.data, parse_constant=lambda c: (_ for _ in ()).throw(ValueError(c)))
        except ValueError as err:
            bad.append(f"json: {err}")
        return bad
    for path in ("point", "twist.linear", "twist.angular", "wrench.force", "wrench.torque"):
        obj = msg
        for part in path.split("."):
            obj = getattr(obj, part, None)
        if obj is not None:
            bad += [f"{path}.{a}={getattr(obj, a)}" for a in "xyz" if not math.isfinite(getattr(obj, a))]
    stamp = getattr(getattr(msg, "header", None), "stamp", None) or getattr(msg, "clock", None)
    if stamp is not None and not (0 <= stamp.nanosec < NS and stamp.sec >= 0):
        bad.append(f"stamp=({stamp.sec}, {stamp.nanosec})")
    if hasattr(msg, "point_step"):  # a point cloud (/soil/map): every float32 field of every point
        try:
            _, rows = M.parse_point_cloud(msg, T.MAP_FIELDS)
        except ValueError as err:
            return bad + [str(err)]
        bad += [f"point {i} {T.MAP_FIELDS[j]}={rows[i, j]}" for i, j in zip(*np.nonzero(~np.isfinite(rows)))]
        return bad
    if hasattr(msg, "data") and hasattr(msg, "layout"):
        bad += [f"data[{i}]={v}" for i, v in enumerate(msg.data) if not math.isfinite(v)]
        if M.labelled_stamp(msg) is None:
            bad.append(f"labelled stamp {list(msg.data[:2])}")
    return bad
