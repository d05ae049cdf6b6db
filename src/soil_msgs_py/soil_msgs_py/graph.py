"""The live graph's contract: QoS per topic, the episode control/status topics and their JSON.

rclpy-free (``ros_adapter.py`` turns these into rclpy objects), so the simulator node, the
controller node, the recorder, the player, the launcher and tests share one definition.

Episodes in a row (the "documented topic-based mechanism")
----------------------------------------------------------
* ``/sim/command`` (std_msgs/String, JSON object) asks the simulator to act:
  ``{"action": "start", <optional EpisodeSpec overrides>}`` queues an episode (fields not
  given come from the node's parameters: soil, relative_density_pct, target_speed_m_s,
  target_depth_m, seed, duration_s, patches); ``{"action": "reset"}`` aborts the running episode and
  clears the queue; ``{"action": "shutdown"}`` ends the node after the running episode.
* ``/sim/status`` (std_msgs/String, JSON object) is what happened, one message per event:
  ``episode_start`` (before the episode's first tick is published; carries the episode
  metadata, the stamp of its first tick and the planned number of ticks) and
  ``episode_end`` (after the episode's last tick and the commands answering it; carries
  the last stamp, the ticks published, the reason and timing statistics). The player
  publishes the same events when it replays episode bags, so a recorder splits a replay
  into the same bags and an estimator resets its buffer at the same instants.

Simulation time (``/clock`` and every stamp) is continuous across the episodes of one run:
episode k+1 starts one tick after episode k ended, so ROS-time consumers never see time
jump back. A bag's stamps are therefore offset from the batch generator's by the episode's
first stamp; ``Episode.time_s`` is relative and equal.
"""
from __future__ import annotations

import dataclasses
import json
import re
from dataclasses import dataclass
from typing import Any

from . import topics as T
from .episode import MAX_SEED, EpisodeMeta
from .messages import MAX_STAMP_NS
from .params import SAMPLE_RATE_HZ
from .patches import PATCH_SYNTAX, check_patches
from .values import finite_number, short_repr

SIM_COMMAND_TOPIC = "/sim/command"
SIM_STATUS_TOPIC = "/sim/status"
# The newest /sim/status event (the episode running, or the one that last ended), latched: a node
# that joins mid-cut learns the episode (its soil patches, targets, graph id, first stamp), which
# /sim/status, VOLATILE, said before it joined.
SIM_EPISODE_TOPIC = "/sim/episode"
# The estimator's posterior physics (``EstimatorPhysics``), latched: what a planner reads θ through.
ESTIMATOR_PHYSICS_TOPIC = "/soil/estimator/physics"
STRING_MSGTYPE = "std_msgs/msg/String"
# Every topic the graph's own nodes make: the contract's data, estimates and plans and the control
# topics. Nodes create them by relative names (``ros_adapter.local``), so one namespace moves a
# machine's whole graph; any other name (a user's ``--topics /tf``) is used as given.
GRAPH_OWN_TOPICS: frozenset[str] = frozenset((*T.GRAPH_TOPICS_BY_NAME, SIM_COMMAND_TOPIC, SIM_STATUS_TOPIC,
                                              SIM_EPISODE_TOPIC, ESTIMATOR_PHYSICS_TOPIC))

EVENT_EPISODE_START = "episode_start"
EVENT_EPISODE_END = "episode_end"
EVENTS = (EVENT_EPISODE_START, EVENT_EPISODE_END)
END_REASONS = ("completed", "reset", "shutdown", "error", "end_of_bag")
# How the simulator paces its ticks (its ``pacing`` parameter), said in every episode_start so
# the nodes of a closed loop can keep step: in lockstep the controller waits for the planner.
PACING_REALTIME, PACING_LOCKSTEP = "realtime", "lockstep"
PACINGS = (PACING_REALTIME, PACING_LOCKSTEP)

# A node that refuses its parameters at start exits with this code (``ros_adapter.spin_node``);
# ``soil_launch`` stops the graph on it whatever the node's role: a mistake in the set-up, not a fault.
EXIT_BAD_CONFIG = 2
# The simulator ran its episodes to the end, but at least one ended in error (a lockstep tick no
# controller answered, a state that was not finite): a script can tell that run from a good one.
EXIT_EPISODE_FAILED = 4
# The recorder left an episode without its bag (its journal could not be made, or would not close or
# convert; said when it happened): ``soil_launch`` then ends in EXIT_NODE_DIED, not 0.
EXIT_BAG_NOT_WRITTEN = 5
# The simulator found another publisher of /sim/status on its domain before its first episode (a
# second launch, or a bag player): two graphs on one domain mix their topics, and every bag of
# either holds both robots' data; it starts no episode (``soil_launch`` ends in EXIT_NODE_DIED).
EXIT_ANOTHER_GRAPH = 6
# The simulator's log line of an episode's start or end begins "episode N start" / "episode N end"
# (``episode_log``); soil_launch reads them to tell a run stopped mid-episode from one between episodes.
EPISODE_LOG_PATTERN = re.compile(r"\]: episode \d+ (start|end)\b")


def episode_log(index: int, what: str) -> str:
    """The head of the simulator's log line of episode ``index``'s ``what`` ("start" or "end")."""
    return f"episode {index} {what}"


# The recorder's log line of a bag it finished begins "finished (<how>)" (``bag_finished_log``);
# soil_launch counts them: a recorder that finished a bag for every episode the simulator started
# has nothing in flight, and its stop needs no drain.
BAG_FINISHED_LOG_PATTERN = re.compile(r"\]: finished \(")


def bag_finished_log(how: str) -> str:
    """The head of the recorder's log line of a bag finished ``how`` ("completed", "stopped", ...)."""
    return f"finished ({how})"


# What the ROS graph says of an endpoint whose node is not discovered yet (its name comes a moment
# after its writer): the simulator's and the player's checks for another graph wait for it.
UNKNOWN_NODE_NAME = "_NODE_NAME_UNKNOWN_"

ACTION_START = "start"
ACTION_RESET = "reset"
ACTION_SHUTDOWN = "shutdown"
ACTIONS = (ACTION_START, ACTION_RESET, ACTION_SHUTDOWN)
NUMERIC_START_FIELDS = ("relative_density_pct", "target_speed_m_s", "target_depth_m", "seed", "duration_s")
# patches: the soil along the path, as the node's parameter takes it ("x:SOIL:ID" strings, or mappings);
# [] clears the node's patches or named path for this episode
START_FIELDS = ("soil", *NUMERIC_START_FIELDS, "patches")


@dataclass(frozen=True)
class QosSpec:
    """A ROS 2 QoS profile as plain data (reliability, durability, history depth)."""

    reliability: str  # "reliable" | "best_effort"
    durability: str  # "volatile" | "transient_local"
    depth: int  # KEEP_LAST depth

    def describe(self) -> str:
        return f"{self.reliability.upper()}, {self.durability.upper()}, KEEP_LAST {self.depth}"


# Per-tick data: RELIABLE so a recorder loses nothing; 120 messages = 2 s of ticks queued.
DATA_QOS = QosSpec("reliable", "volatile", 2 * SAMPLE_RATE_HZ)
# What a recorder subscribes with: deeper, so a busy writer never makes DDS drop a sample.
RECORDER_QOS = QosSpec("reliable", "volatile", 2000)
# Episode control/status: rare, must not be lost.
CONTROL_QOS = QosSpec("reliable", "volatile", 50)

TOPIC_QOS: dict[str, QosSpec] = {t.name: DATA_QOS for t in T.GRAPH_TOPICS_BY_NAME.values()}
TOPIC_QOS[SIM_COMMAND_TOPIC] = CONTROL_QOS
TOPIC_QOS[SIM_STATUS_TOPIC] = CONTROL_QOS
# Said once and again only when it changes: a reader wants the newest, and gets it on joining.
STATE_QOS = QosSpec("reliable", "transient_local", 1)
TOPIC_QOS[ESTIMATOR_PHYSICS_TOPIC] = STATE_QOS
TOPIC_QOS[SIM_EPISODE_TOPIC] = STATE_QOS


# Latched topics: the writer keeps what it sent for a reader that joins later (TRANSIENT_LOCAL,
# like a map server's /map). Each /soil/map holds every cell learnt so far and is sent only after
# a stretch of evidence, so a planner of a later pass started after the cut got no map at all.
# Readers keep the graph's VOLATILE (a VOLATILE reader matches a TRANSIENT_LOCAL writer); one that
# wants the newest map on joining subscribes TRANSIENT_LOCAL. A recorder stays VOLATILE: a
# restarted one must not write a past episode's maps into the episode it joins.
# The estimator's physics is said once (and again when its model changes): a planner started after it
# subscribes TRANSIENT_LOCAL and gets it on joining, like a robot_description.
# The episode's event and the estimator's physics are states, as a robot_description is: their
# writers keep the newest alone (``LATCHED_STATE_TOPICS``), so a latecomer is sent what holds now,
# not the episodes or models before it.
LATCHED_TOPICS: tuple[str, ...] = (T.SOIL_MAP.name, ESTIMATOR_PHYSICS_TOPIC, SIM_EPISODE_TOPIC)
LATCHED_STATE_TOPICS: tuple[str, ...] = (ESTIMATOR_PHYSICS_TOPIC, SIM_EPISODE_TOPIC)
# A latched topic's writer history: each sample is the whole state (every map cell so far), so a
# reader that misses one loses only a moment of it, and the writer keeps this many, not a
# recorder's depth: 2000 maps (up to 144 kB each) had grown an estimator by ~25 MB in 15 min of an
# episode (an outside soak test), and a latecomer was sent every one of them. 60 maps are 30 s of
# stretches.
LATCHED_WRITER_DEPTH = 60


def publisher_qos_spec(topic: str) -> QosSpec:
    """What a node publishes ``topic`` with (and so what a bag records as offered): the
    graph's QoS with a writer history as deep as a recorder's reader (``RECORDER_QOS``), and
    TRANSIENT_LOCAL for ``LATCHED_TOPICS`` (``LATCHED_WRITER_DEPTH`` deep, a state's one). A KEEP_LAST writer
    overwrites samples a reliable reader has not acknowledged yet, so with the graph's depth a
    reader starved of CPU for a moment while a lockstep graph runs far above 60 Hz would lose
    them; with this depth they are re-sent."""
    spec = TOPIC_QOS.get(topic, DATA_QOS)
    if topic in LATCHED_TOPICS:
        # (not max with the topic's depth: /soil/map's is the data topics' 120, and its writer had kept 120 maps)
        return dataclasses.replace(spec, durability="transient_local",
                                   depth=1 if topic in LATCHED_STATE_TOPICS else LATCHED_WRITER_DEPTH)
    return dataclasses.replace(spec, depth=max(spec.depth, RECORDER_QOS.depth))


# A fully qualified ROS name as rcl validates one (a namespace, a node's name with its namespace):
# absolute, tokens of ASCII letters, digits and '_' not starting with a digit
ROS_PATH_RE = re.compile(r"(/[A-Za-z_][A-Za-z0-9_]*)+")
# A count in 'topic:count' (the simulator's wait_for, soil_launch --wait-for): ASCII digits (str.isdigit
# takes '²', which int() refuses in words that name neither the entry nor the parameter)
COUNT_RE = re.compile(r"[0-9]+")

# Each node's name (a graph's namespace + '/' + it is the node's fully qualified name): soil_launch
# tells its simulator to wait for its own nodes' endpoints by these, so readers outside the launch
# (a monitor, another recorder) cannot start an episode before the launch's own recorder listens.
NODE_NAMES: dict[str, str] = {"sim": "soil_sim_node", "controller": "anti_stall_controller",
                              "estimator": "pinn_estimator", "planner": "soil_planner",
                              "recorder": "soil_bag_record", "player": "soil_bag_play"}

# Topics the simulator publishes each tick (state, force, Θ_k, Θ, /clock) and the commands it reads.
SIM_STATE_TOPICS: tuple[str, ...] = (
    T.CLOCK.name, T.BLADE_POSE.name, T.BLADE_TWIST.name, T.CHASSIS_POSE.name,
    T.CHASSIS_TWIST.name, T.BLADE_FORCE.name, T.KNOWN.name, T.GROUND_TRUTH.name,
)
COMMAND_TOPICS: tuple[str, ...] = (T.CMD_VEL.name, T.BLADE_CMD.name)
# What the simulator's 'wait_for' may name: the endpoints of its own topics (those it publishes and
# the commands it reads). soil_launch refuses any other before it starts a node.
SIM_WAITABLE_TOPICS: tuple[str, ...] = (*SIM_STATE_TOPICS, *COMMAND_TOPICS, SIM_STATUS_TOPIC)
assert set(SIM_STATE_TOPICS) | set(COMMAND_TOPICS) == {t.name for t in T.EPISODE_TOPICS}
# What the controller node reads (it answers on COMMAND_TOPICS) and what a recorder reads:
# the launcher tells the simulator to wait for these endpoints before an episode starts.
# The controller always reads /blade/force, though only its force lift joins it to a tick's state:
# a reader the simulator does not wait for could miss a lockstep episode's first tick for good.
CONTROLLER_STATE_TOPICS: tuple[str, ...] = (T.CHASSIS_TWIST.name, T.CHASSIS_POSE.name)
CONTROLLER_INPUTS: tuple[str, ...] = CONTROLLER_STATE_TOPICS + (T.BLADE_FORCE.name, SIM_STATUS_TOPIC)
RECORDER_INPUTS: tuple[str, ...] = SIM_STATE_TOPICS + COMMAND_TOPICS + (SIM_STATUS_TOPIC,)
# The online estimator reads the state, the measured force (the evidence its fused posterior
# learns from), Θ_k and commands of each tick (and the status, to reset its window) and
# publishes its estimate and map; a recorder started with it records them.
ESTIMATOR_STATE_TOPICS: tuple[str, ...] = (
    T.BLADE_POSE.name, T.BLADE_TWIST.name, T.CHASSIS_POSE.name, T.CHASSIS_TWIST.name, T.BLADE_FORCE.name, T.KNOWN.name,
)
ESTIMATOR_INPUTS: tuple[str, ...] = ESTIMATOR_STATE_TOPICS + COMMAND_TOPICS + (SIM_STATUS_TOPIC,)
ESTIMATOR_OUTPUTS: tuple[str, ...] = (T.ESTIMATE.name, T.ESTIMATED_FORCE.name, T.SOIL_MAP.name)
# What the soil-aware planner reads from the simulator and publishes (the controller reads the target).
PLANNER_STATE_TOPICS: tuple[str, ...] = (T.KNOWN.name, T.BLADE_FORCE.name)
PLANNER_OUTPUTS: tuple[str, ...] = (T.PLAN.name, T.TARGET_DEPTH.name)
# How long a node waits for the writers of other nodes' topics it reads before it joins the
# simulator's topics anyway (``ros_adapter.JoinAfterInputs``): well inside the simulator's own
# start wait (its ``wait_timeout_s``, 10 s), which would otherwise start without the node's readers.
INPUTS_WAIT_S = 5.0
SIM_START_WAIT_S = 10.0  # the simulator's own wait_timeout_s, for a simulator started by hand [s]
# soil_launch's simulator's start wait for the launch's own nodes (its ``wait_timeout_s`` unless
# given; a node's ``inputs_wait_s`` then half of it, as above). Those nodes are coming, and the
# estimator's start (torch's import and its model) took 2–9 s on a loaded 2-core machine: with the
# nodes' own 5 s the planner joined without its estimates, missed the first ones, and a lockstep
# controller waited planner_wait_s for the first targets. The cost: a launched node that dies
# before the first episode delays it this long (the ones after a death mid-run too, once).
LAUNCH_START_WAIT_S = 30.0
MAX_WAIT_S = 3600.0  # the longest any start-up or tick wait of the graph may be set to [s]
# Wall time without an input mid-episode before a node says so, and takes the episode's source for
# gone (``episode_follow``): longer than a lockstep tick may wait for a silent planner (the
# controller's planner_wait_s, 2 s), so a wait is not called a death.
INPUT_SILENCE_S = 5.0
# The parameter of the nodes that follow a simulator's episodes (controller, estimator, planner):
# soil_launch gives them its graph's id, as to its simulator and recorder (``episode_follow``).
FOLLOWED_GRAPH_ID_PARAMETER = ("", "the graph whose /sim/status episodes this node follows (soil_launch gives its "
                                   "own): events of another graph id or of none are ignored; \"\": any graph's, a "
                                   "start taken whenever it comes")
# Lockstep: how long the simulator waits for a tick's commands before it ends the episode [s of
# wall time] (its lockstep_timeout_s); a node that holds a tick must wait less.
LOCKSTEP_TIMEOUT_S = 10.0
# Real-time factors the graph's clock may run at, the simulator's pacing (its ``rate``) and the
# player's replay alike: a 10 s episode takes between 10 ms and ~17 min. Beyond them a rate is no
# timing at all: inf played every message at its first deadline (unpaced, what a reliable reader's
# history may not hold), 1e-300 scheduled the second message past any wait.
REALTIME_FACTOR_RANGE = (0.01, 1000.0)


# Bounds on /sim/command and /sim/status text, checked before decoding: a status event with
# its timing stats is about 2 kB and 3 levels deep, so these only ever refuse abuse (a deeply
# nested array would otherwise exhaust the decoder's recursion).
MAX_JSON_CHARS = 65_536
MAX_JSON_DEPTH = 8
_JSON_STRING = re.compile(r'"(?:[^"\\]|\\.)*"')


def _nesting_depth(text: str) -> int:
    """How deep arrays and objects nest in JSON ``text`` (brackets inside strings do not count)."""
    depth = deepest = 0
    for ch in _JSON_STRING.sub("", text):
        if ch in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif ch in "]}":
            depth -= 1
    return deepest


class _RepeatedKey(Exception):
    """A JSON object with a field given twice (``json`` keeps the last silently)."""


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise _RepeatedKey(key)
        out[key] = value
    return out


def _json_object(text: str, what: str) -> dict[str, Any]:
    """The JSON object in ``text``; every way it can fail is a ValueError naming ``what`` (the topic)."""
    if not isinstance(text, str):
        raise ValueError(f"{what}: expected JSON text, got {type(text).__name__}")
    if len(text) > MAX_JSON_CHARS:
        raise ValueError(f"{what}: {len(text)} characters, more than {MAX_JSON_CHARS}; not decoded")
    if (depth := _nesting_depth(text)) > MAX_JSON_DEPTH:
        raise ValueError(f"{what}: nested {depth} deep, more than {MAX_JSON_DEPTH}; not decoded")
    try:
        data = json.loads(text, object_pairs_hook=_unique_keys)
    except json.JSONDecodeError as err:
        raise ValueError(f"{what}: not JSON ({err.msg} at char {err.pos}): {text[:80]!r}") from None
    except _RepeatedKey as err:  # ({"action": "start", "action": "shutdown"} shut the simulator down without a word)
        raise ValueError(f"{what}: field {err.args[0]!r} is given twice; not decoded (which one is meant?)") from None
    except (ValueError, RecursionError) as err:  # e.g. an integer of more digits than Python converts
        raise ValueError(f"{what}: not decodable ({type(err).__name__}: {err}): {text[:80]!r}") from None
    if not isinstance(data, dict):
        raise ValueError(f"{what}: expected a JSON object, got {type(data).__name__}")
    return data


# --- /sim/status ------------------------------------------------------------------------

@dataclass(frozen=True)
class EpisodeEvent:
    """One ``/sim/status`` message.

    episode_start: ``first_stamp_ns`` (stamp of tick 0), ``planned_ticks``, ``meta``, ``pacing``
                   (PACINGS; "" when not said, e.g. by a replay, which keeps recorded time).
    episode_end:   ``first_stamp_ns``, ``last_stamp_ns`` (last tick published), ``ticks``
                   published, ``reason`` (END_REASONS), ``stats`` (timing figures, free form).
    both:          ``graph``: the launch's id of the publishing graph ("" not said: a simulator
                   started by hand, a replay), so a recorder of another launch on the same topics
                   (two graphs in one namespace of one domain) records none of its episodes.
    """

    event: str
    episode: int  # 0-based index within the publishing process's run
    name: str  # bag directory name (EpisodeMeta.name)
    meta: EpisodeMeta
    first_stamp_ns: int
    planned_ticks: int = 0
    last_stamp_ns: int = -1
    ticks: int = 0
    reason: str = ""
    stats: dict | None = None
    pacing: str = ""
    graph: str = ""

    def to_json(self) -> str:
        data = {
            "event": self.event, "episode": self.episode, "name": self.name,
            "meta": json.loads(self.meta.to_json()), "first_stamp_ns": self.first_stamp_ns,
            "planned_ticks": self.planned_ticks,
        }
        if self.event == EVENT_EPISODE_END:
            data.update(last_stamp_ns=self.last_stamp_ns, ticks=self.ticks, reason=self.reason,
                        stats=self.stats or {})
        if self.pacing:
            data["pacing"] = self.pacing
        if self.graph:
            data["graph"] = self.graph
        # ensure_ascii=False: MAX_JSON_CHARS counts characters; escaped, a soil name of 64 bytes of "é"
        # took 192 of them and a path of MAX_PATCHES such patches made an event its readers refused
        return json.dumps(data, sort_keys=True, ensure_ascii=False)

    @classmethod
    def from_json(cls, text: str) -> "EpisodeEvent":
        """Parse and validate; ValueError naming the field and value."""
        d = _json_object(text, SIM_STATUS_TOPIC)
        event = d.get("event")
        if event not in EVENTS:
            raise ValueError(f"{SIM_STATUS_TOPIC}: event={event!r} is not one of {EVENTS}")
        for key in ("episode", "first_stamp_ns", "planned_ticks") + (
            ("last_stamp_ns", "ticks") if event == EVENT_EPISODE_END else ()
        ):
            v = d.get(key)
            if not isinstance(v, int) or isinstance(v, bool) or (v < 0 and key != "last_stamp_ns"):
                raise ValueError(f"{SIM_STATUS_TOPIC}: {key}={v!r} must be a non-negative integer")
            if key.endswith("stamp_ns") and v > MAX_STAMP_NS:
                raise ValueError(f"{SIM_STATUS_TOPIC}: {key}={v!r} is beyond the last stamp a message can "
                                 f"carry ({MAX_STAMP_NS} ns)")
        if not isinstance(d.get("meta"), dict):
            raise ValueError(f"{SIM_STATUS_TOPIC}: meta={d.get('meta')!r} must be an object")
        try:
            meta = EpisodeMeta.from_json(json.dumps(d["meta"]))
            meta.validate(machine_world=True)  # a machine's bag replayed: its world is not a simulator's
        except (TypeError, ValueError) as err:  # a missing, unknown, mistyped or out-of-range field
            raise ValueError(f"{SIM_STATUS_TOPIC}: bad meta: {err}") from None
        if d.get("stats") is not None and not isinstance(d["stats"], dict):
            raise ValueError(f"{SIM_STATUS_TOPIC}: stats={d['stats']!r} must be an object")
        reason = d.get("reason", "")
        if event == EVENT_EPISODE_END and reason not in END_REASONS:
            raise ValueError(f"{SIM_STATUS_TOPIC}: reason={reason!r} is not one of {END_REASONS}")
        name = d.get("name")
        if not isinstance(name, str) or not name or "/" in name:
            raise ValueError(f"{SIM_STATUS_TOPIC}: name={name!r} must be a non-empty name without '/'")
        pacing = d.get("pacing", "")
        if pacing not in ("", *PACINGS):
            raise ValueError(f"{SIM_STATUS_TOPIC}: pacing={pacing!r} is not one of {PACINGS}")
        graph = d.get("graph", "")
        if problem := graph_id_problem(graph):
            raise ValueError(f"{SIM_STATUS_TOPIC}: graph={short_repr(graph)} {problem}")
        return cls(event=event, episode=d["episode"], name=name, meta=meta,
                   first_stamp_ns=d["first_stamp_ns"], planned_ticks=d["planned_ticks"],
                   last_stamp_ns=d.get("last_stamp_ns", -1), ticks=d.get("ticks", 0),
                   reason=reason, stats=d.get("stats"), pacing=pacing, graph=graph)


GRAPH_ID_MAX_LEN = 64


def graph_id_problem(graph: object) -> str:
    """What is wrong with a graph id (``EpisodeEvent.graph``), "" if nothing: a string of at most
    ``GRAPH_ID_MAX_LEN`` letters, digits, '-' and '_' ("" for none)."""
    if not isinstance(graph, str) or len(graph) > GRAPH_ID_MAX_LEN or not re.fullmatch(r"[A-Za-z0-9_-]*", graph):
        return f"must be a string of at most {GRAPH_ID_MAX_LEN} letters, digits, '-' and '_'"
    return ""


# --- /sim/command -----------------------------------------------------------------------

@dataclass(frozen=True)
class SimCommand:
    """One ``/sim/command`` message: an action and, for ``start``, EpisodeSpec overrides."""

    action: str
    overrides: dict

    def to_json(self) -> str:
        return json.dumps({"action": self.action, **self.overrides}, sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> "SimCommand":
        d = _json_object(text, SIM_COMMAND_TOPIC)
        action = d.pop("action", None)
        if action not in ACTIONS:
            raise ValueError(f"{SIM_COMMAND_TOPIC}: action={action!r} is not one of {ACTIONS}")
        if action != ACTION_START and d:
            raise ValueError(f"{SIM_COMMAND_TOPIC}: action {action!r} takes no fields, got {sorted(d)}")
        unknown = sorted(set(d) - set(START_FIELDS))
        if unknown:
            raise ValueError(f"{SIM_COMMAND_TOPIC}: unknown field(s) {unknown}; allowed {START_FIELDS}")
        if "soil" in d and not isinstance(d["soil"], str):
            raise ValueError(f"{SIM_COMMAND_TOPIC}: soil={d['soil']!r} must be a string")
        if "patches" in d:
            if not isinstance(d["patches"], list):
                raise ValueError(f"{SIM_COMMAND_TOPIC}: patches={d['patches']!r} must be a list of patches "
                                 f"({PATCH_SYNTAX} each), [] for none")
            check_patches(d["patches"], f"{SIM_COMMAND_TOPIC}: patches")  # ValueError naming the entry and value
        for key in NUMERIC_START_FIELDS:
            if key in d:
                v = d[key]
                # (an integer of hundreds of digits has no float: math.isfinite would raise OverflowError)
                if isinstance(v, int) and not isinstance(v, bool) and abs(v) > MAX_SEED:
                    raise ValueError(f"{SIM_COMMAND_TOPIC}: {key}={short_repr(v)} must be at most 2**63 - 1 in magnitude")
                if not finite_number(v):
                    kind = "an integer in [0, 2**63 - 1]" if key == "seed" else "a finite number"
                    raise ValueError(f"{SIM_COMMAND_TOPIC}: {key}={short_repr(v)} must be {kind}")
        if "seed" in d and (not float(d["seed"]).is_integer() or not 0 <= d["seed"] <= MAX_SEED):
            raise ValueError(f"{SIM_COMMAND_TOPIC}: seed={short_repr(d['seed'])} must be an integer in [0, 2**63 - 1]")
        return cls(action=action, overrides=d)


# --- /soil/estimator/physics ------------------------------------------------------------

BOUND_LAW_FIELDS = ("abs_x_n", "abs_z_n", "rel_x", "rel_z")


@dataclass(frozen=True)
class EstimatorPhysics:
    """One ``/soil/estimator/physics`` message: the physics the estimator's fused posterior is
    fitted with, which a planner must read θ through (the same φ, c, δ mean another soil through
    the FEE alone: the default world's 95 % F_x bound differed by 1.6× in an outside reader's
    planner run by hand), and the error law of the bound a plan keeps, calibrated with it.

    ``terms``: the terms beside the FEE, 'name=k' texts (``force_terms.term_texts``); ``bound_law``:
    (abs_x [N], abs_z [N], rel_x, rel_z), or () where the config has none (the planner then takes
    the estimate's ``model_std_*``); ``source``: where they came from (fusion config, checkpoint),
    for the planner's log."""

    terms: tuple[str, ...]
    bound_law: tuple[float, ...]
    source: str = ""

    def to_json(self) -> str:
        return json.dumps({"terms": list(self.terms), "bound_law": list(self.bound_law), "source": self.source},
                          sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> "EstimatorPhysics":
        """Parse and check the layout; ValueError naming the field and value (the terms' names and
        the law's values are the planner's to check, as for its own parameters)."""
        d = _json_object(text, ESTIMATOR_PHYSICS_TOPIC)
        if unknown := sorted(set(d) - {"terms", "bound_law", "source"}):
            raise ValueError(f"{ESTIMATOR_PHYSICS_TOPIC}: unknown field(s) {unknown}")
        terms, law, source = d.get("terms"), d.get("bound_law"), d.get("source", "")
        if not isinstance(terms, list) or not all(isinstance(t, str) and "=" in t for t in terms):
            raise ValueError(f"{ESTIMATOR_PHYSICS_TOPIC}: terms={short_repr(terms)} must be a list of 'name=k' texts")
        if (not isinstance(law, list) or len(law) not in (0, len(BOUND_LAW_FIELDS))
                or not all(finite_number(v) and v >= 0 for v in law)):
            raise ValueError(f"{ESTIMATOR_PHYSICS_TOPIC}: bound_law={short_repr(law)} must be [] or "
                             f"{len(BOUND_LAW_FIELDS)} finite numbers >= 0 ({', '.join(BOUND_LAW_FIELDS)})")
        if not isinstance(source, str):
            raise ValueError(f"{ESTIMATOR_PHYSICS_TOPIC}: source={short_repr(source)} must be a string")
        return cls(terms=tuple(terms), bound_law=tuple(float(v) for v in law), source=source)
