"""`soil_sim_node`: the simulator core as a ROS 2 node (thin adapter; physics in simulator.py).

Each 60 Hz tick of simulation time it publishes /clock, the blade and chassis state, the
measured blade force, Θ_k and the pseudo-ground truth (topics.py), all stamped with the
tick's simulation time, and reads /chassis/cmd_vel and /blade/cmd stamped with the tick
they answer. Two pacings (``pacing.py`` decides when a tick is stepped; this node owns
the timers):

* ``realtime``: a wall-clock timer at 60 Hz × ``rate``; each tick applies the commands that
  answered the previous tick (held from before if they were late, counted as late).
* ``lockstep``: tick k+1 is computed only after both commands for tick k arrived, so a
  run is reproducible to the bit (and equal to ``soil_sim_batch`` for the same seed).

Episodes: ``episodes`` repeats of the plan (soil × relative density, from the
``sequence_*`` lists or the single ``soil``/``relative_density_pct``, or the soil along the
path ``patches`` or ``path``; catalogue soils, or those of the soils YAML ``soil_file``) start by
themselves;
more are started and reset over ``/sim/command``, and every start/end is announced on
``/sim/status`` (graph.py documents both). ``wait_for`` holds each start until the listed
endpoints have matched, so a recorder or controller started alongside loses nothing.

Bad commands never stop the node and never reach the core: see live.CommandGate.
"""
from __future__ import annotations

import collections
import itertools
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from rcl_interfaces.msg import SetParametersResult
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import String

from soil_msgs_py import graph as G
from soil_msgs_py import messages as M
from soil_msgs_py import topics as T
from soil_msgs_py.params import (DEFAULT_TARGET_DEPTH_M, DEFAULT_TARGET_SPEED_M_S, TICK_PERIOD_NS, beyond_lift_reach,
                                 beyond_table1_speed, tick_stamp_ns, ticks_in)
from soil_msgs_py.ros_adapter import (WarnLimiter, declare_parameters, endpoint_node, local, message_class,
                                      publisher_qos, spin_node, topic_qos, wall_timer)

from soil_physics.soils import load_soil_file, path_patches, soil_file_notes

from .effects import PluginError, effects_for_mode, load_plugins
from .live import CommandGate, command_writers, episode_plan
from .pacing import AwaitedEndpoint, Do, Pacer, StartWait, check_pacing, parse_wait_for
from .rollout import episode_meta
from .simulator import ENGINES, EpisodeSpec, SimConfig, SoilSimulator, resolve_checked
from .simulator import check_engine as check_sim_engine
from .warm_up import ready

# Array parameters whose default is empty: rclpy cannot infer a type from [], so they are
# declared by type and read through declare_parameters' getter (unset reads as the default []).
_STR_ARRAY = Parameter.Type.STRING_ARRAY
_DBL_ARRAY = Parameter.Type.DOUBLE_ARRAY

# Nodes of this project that publish /sim/status: another one on the domain is another graph.
GRAPH_STATUS_WRITERS = (G.NODE_NAMES["sim"], G.NODE_NAMES["player"])
GRAPH_NAMES_WAIT_S = 2.0  # the longest a start waits for such a writer's node name [s]
# Before its first episode the node looks for another graph only once DDS has had time to discover
# the domain: its nodes known unchanged for GRAPH_QUIET_S, at least GRAPH_DISCOVERY_S after start, at
# most GRAPH_DISCOVERY_MAX_S [s]. (An outside tester's second launch met its wait_for on the first
# launch's readers 0.4 s after start, before the first simulator's writer was discovered: it was
# not refused, and its bags held both graphs' ticks.)
GRAPH_DISCOVERY_S, GRAPH_QUIET_S, GRAPH_DISCOVERY_MAX_S = 1.0, 0.5, 5.0
MAX_SETTLE_S = 60.0  # settle_s at most [s]: a pause for DDS matches, not a schedule

# name -> (default, description[, array type]); the YAML in config/ mirrors these.
PARAMETERS: dict[str, tuple] = {
    "world_mode": ("default", "world: 'fee' (pure FEE, like D_FEE) or 'default' (extra effects, like D_default)"),
    "engine": ("compiled", "simulator engine: 'compiled' (Numba kernel, default) or 'reference' (the NumPy "
                           "reference of the physics, ~400x slower)"),
    "soil": ("Loam", "soil type of the episodes (Clay, Loam, Sand, Gravel, or a soil of soil_file)"),
    "relative_density_pct": (60.0, "initial relative density I_d [%], 0..100"),
    "patches": ([], "soil along the path, 'x_start_m:soil:relative_density_pct' entries ordered by x, e.g. "
                    "['0.0:Sand:20', '5.0:Clay:90'] (x: the blade's cutting edge in the world frame [m]; the first "
                    "also covers everything before the second; empty: 'soil' everywhere; set: 'soil' and "
                    "'relative_density_pct' are unused, those of the patch under the edge at the start are the episode's)", _STR_ARRAY),
    "target_speed_m_s": (DEFAULT_TARGET_SPEED_M_S, "target forward speed of the episodes [m/s] (sent to the controller in /sim/status)"),
    "target_depth_m": (DEFAULT_TARGET_DEPTH_M, "target cut depth below the original surface [m]"),
    "seed": (0, "seed of the first episode; episode k of the plan uses seed + k"),
    "duration_s": (10.0, "episode length [s] of simulation time"),
    "sequence_soils": ([], "plan: soils to run in a row (empty: just 'soil')", _STR_ARRAY),
    "sequence_relative_densities_pct": ([], "plan: I_d values [%] per soil (empty: just relative_density_pct)", _DBL_ARRAY),
    "episodes": (1, "repeats of the plan started at launch; 0: start episodes only via /sim/command"),
    "exit_when_done": (False, "exit when the plan and all requested episodes are done (code 0; 4 if one ended "
                                "in error); with episodes 0, once at least one requested episode ran"),
    "pacing": ("realtime", "'realtime' (wall clock 60 Hz x rate) or 'lockstep' (wait for each tick's commands)"),
    "rate": (1.0, "real-time factor for pacing=realtime (2.0: twice as fast as real time)"),
    "wait_for": ([], "endpoints to wait for before an episode starts, 'topic:count' (publisher side: matched "
                     "subscriptions; command topics: matched publishers) or 'topic@/namespace/node' (that node's "
                     "own endpoint there)", _STR_ARRAY),
    "wait_timeout_s": (G.SIM_START_WAIT_S, "give up waiting for 'wait_for' after this long and start anyway [s], "
                             f"[0, {G.MAX_WAIT_S:g}] (0: wait forever)"),
    "settle_s": (0.3, "pause after 'wait_for' is met, so reverse-direction DDS matches complete too [s], "
                       f"[0, {MAX_SETTLE_S:g}]"),
    "lockstep_timeout_s": (G.LOCKSTEP_TIMEOUT_S, "lockstep: end the episode (reason 'error') if a tick's commands do not come within "
                                 f"this [s], [0, {G.MAX_WAIT_S:g}]"),
    "soil_file": ("", "YAML of custom soils and named paths (soil_sim_batch --soil-file's format); its soils may be "
                      "named in soil, patches, sequence_soils and /sim/command starts; '': the catalogue only"),
    "path": ("", "the patches of the path of this name in soil_file's 'paths:' section (instead of patches); '': none"),
    "plugins": ([], "extra force terms 'package.module:function' (simulator effect plugins)", _STR_ARRAY),
    "effects_off": ([], "default-world effects to switch off by name", _STR_ARRAY),
    "graph_id": ("", "this graph's id, said in every /sim/status event: a recorder given another (soil_launch gives "
                     "each launch its own) records none of its episodes; '': none"),
}




def check_engine(engine) -> None:
    """``simulator.check_engine``, its error naming the node parameter."""
    try:
        check_sim_engine(engine)
    except ValueError as err:
        raise ValueError(f"parameter {err}") from None


UNLIMITED_WAIT_LOG_S = 10.0  # a start held without limit is named after this long, then as often


class SimNode(Node):
    def __init__(self) -> None:
        super().__init__(G.NODE_NAMES["sim"])
        self._value = declare_parameters(self, PARAMETERS)  # name -> current value
        self.finished = False
        self.exit_code = 0
        if self.get_parameter("use_sim_time").value:
            # (on the ROS clock its timers had waited for the /clock only they publish: no episode and no
            # word, an outside tester's; a shared params file's `/**: use_sim_time: true` gives it to every node)
            self.get_logger().warning("use_sim_time=True changes nothing here: the simulator is the graph's clock "
                                      "(it publishes /clock from its ticks) and paces itself on the wall clock")
        p = {name: self._value(name) for name in PARAMETERS}
        self._validate_static(p)
        self.custom_soils, self.named_path = self._load_soil_file(p["soil_file"], p["path"], p["patches"])
        for note in soil_file_notes(self.custom_soils):
            self.get_logger().warning(f"parameter soil_file={p['soil_file']!r}: {note}")
        if p["engine"] == "compiled":  # compile or load the kernel now, not at the first tick
            self.get_logger().info(f"simulator kernel ready in {ready():.1f} s")
        self.pacer = Pacer(p["pacing"], p["rate"], p["lockstep_timeout_s"])
        self.start_wait = StartWait(p["wait_timeout_s"], p["settle_s"])
        self.exit_when_done = bool(p["exit_when_done"])
        if problem := G.graph_id_problem(p["graph_id"]):
            raise ValueError(f"parameter graph_id={p['graph_id']!r} {problem}")
        self.graph_id = p["graph_id"]
        self.wait_for = parse_wait_for(p["wait_for"], set(G.SIM_WAITABLE_TOPICS))
        if self.pacer.lockstep and not self.wait_for:
            # Lockstep cannot run without a controller: wait for one unless told otherwise.
            self.wait_for = [AwaitedEndpoint(t, 1) for t in G.COMMAND_TOPICS + G.CONTROLLER_INPUTS]
        # each by its name in this graph's namespace, as said when it is missing (/dozer1/blade/cmd)
        self.wait_names = {w.topic: self.resolve_topic_name(local(w.topic)) for w in self.wait_for}
        effects = effects_for_mode(p["world_mode"])
        if p["effects_off"]:
            effects = effects.with_switches(**{name: False for name in p["effects_off"]})
        self.config = SimConfig(world_mode=p["world_mode"], effects=effects, plugins=tuple(p["plugins"]),
                                engine=p["engine"])
        load_plugins(self.config.plugins)  # a plugin that does not load is a bad parameter (exit 2), not a crash later
        self._warn = WarnLimiter(self.get_logger())
        self.queue: collections.deque[EpisodeSpec] = collections.deque()
        base = self._spec_from_params({})
        plan = {"sequence_soils": list(p["sequence_soils"]),
                "sequence_relative_densities_pct": list(p["sequence_relative_densities_pct"])}
        self._check_plan_entries(base, plan)
        self._enqueue(episode_plan(base, plan["sequence_soils"], plan["sequence_relative_densities_pct"],
                                   int(p["episodes"])))
        self.add_on_set_parameters_callback(self._on_set_parameters)

        self.classes = M.ros_message_classes()
        self.pubs = {name: self.create_publisher(message_class(T.TOPICS_BY_NAME[name].msgtype), local(name),
                                                 publisher_qos(name)) for name in G.SIM_STATE_TOPICS}
        self.status_pub = self.create_publisher(String, local(G.SIM_STATUS_TOPIC), topic_qos(G.SIM_STATUS_TOPIC))
        self.episode_pub = self.create_publisher(String, local(G.SIM_EPISODE_TOPIC), publisher_qos(G.SIM_EPISODE_TOPIC))
        self.cmd_subs = [
            self.create_subscription(message_class(T.TOPICS_BY_NAME[name].msgtype), local(name),
                                     self._command_callback(name), topic_qos(name))
            for name in G.COMMAND_TOPICS
        ]
        self.create_subscription(String, local(G.SIM_COMMAND_TOPIC), self._on_sim_command, topic_qos(G.SIM_COMMAND_TOPIC))

        # episode state
        self.sim: SoilSimulator | None = None
        self.command_writers = command_writers()  # who answers the ticks, across episodes
        self.gate = CommandGate(self.command_writers)
        self.episode_index = -1
        self.planned_at_start = bool(self.queue)  # (a plan a reset cleared is done: exit_when_done exits)
        self._names_wait_since: float | None = None  # a /sim/status writer's node name awaited since (monotonic)
        self._born = time.monotonic()
        self._nodes_seen: tuple[set, float] = (set(), self._born)  # the domain's nodes, and since when unchanged
        self.meta = None
        self.tick = 0
        self.planned_ticks = 0
        self.first_stamp_ns = 0
        self.next_first_stamp_ns = 0
        self.shutdown_requested = False

        self.timer = wall_timer(self, self.pacer.period_s, self._on_timer)
        # Real time: how long a tick waits for late commands (pacing.COMMAND_GRACE).
        self.grace_timer = wall_timer(self, 1.0, self._on_grace)
        self.grace_timer.cancel()
        self.get_logger().info(
            f"{p['world_mode']} world, engine={p['engine']}, pacing={self.pacer.pacing}"
            + (f" x{self.pacer.rate}" if not self.pacer.lockstep else "")
            + f", {len(self.queue)} episode(s) queued; commands on /sim/command"
        )

    # ------------------------------------------------------------------ parameters
    @staticmethod
    def _validate_static(p: dict) -> None:
        check_pacing(p["pacing"], p["rate"])
        effects_for_mode(p["world_mode"])
        check_engine(p.get("engine", ENGINES[0]))
        if int(p["episodes"]) < 0:
            raise ValueError(f"parameter episodes={p['episodes']} must be >= 0")
        plan = [name for name in ("sequence_soils", "sequence_relative_densities_pct") if p.get(name)]
        if p.get("patches") and plan:
            raise ValueError(f"parameter patches={list(p['patches'])} cannot be combined with {' and '.join(plan)}: "
                             "the patches set the soil along the path")
        if p.get("path") and plan:
            raise ValueError(f"parameter path={p['path']!r} cannot be combined with {' and '.join(plan)}: "
                             "the path sets the soil along it")
        # (an hour bounds what a start or a tick may be held; a pause of 1e300 s never started an episode)
        for name, most in (("wait_timeout_s", G.MAX_WAIT_S), ("settle_s", MAX_SETTLE_S), ("lockstep_timeout_s", G.MAX_WAIT_S)):
            if name in p and not 0.0 <= float(p[name]) <= most:  # (NaN fails too)
                raise ValueError(f"parameter {name}={p[name]} must be a number of seconds in [0, {most:g}]")

    @staticmethod
    def _load_soil_file(soil_file: str, path: str, patches) -> tuple[dict, tuple]:
        """(custom soils by name, the patches of the named ``path`` or ()) from parameter soil_file;
        ValueError naming the parameter, the file and the value."""
        loaded = None
        if soil_file:
            try:
                loaded = load_soil_file(Path(soil_file).expanduser())
            except (FileNotFoundError, ValueError) as err:
                raise ValueError(f"parameter soil_file={soil_file!r}: {err}") from None
        named = path_patches(loaded, path, patches, path_opt="parameter path", file_opt="parameter soil_file",
                             patches_opt="parameter patches", file_shown=soil_file)
        return (loaded.soils if loaded else {}), (named or ())

    def _spec_from_params(self, overrides: dict) -> EpisodeSpec:
        get = lambda name: overrides.get(name, self._value(name))  # noqa: E731
        patches = list(get("patches") or []) or list(self.named_path if "patches" not in overrides else [])
        unused = sorted({"soil", "relative_density_pct"} & set(overrides))
        if patches and unused:
            source = f"parameter path={self._value('path')!r}" if not get("patches") else f"parameter patches={patches}"
            raise ValueError(f"{' and '.join(unused)} unused while {source} sets the soil along the path (a "
                             "/sim/command start may clear the patches: 'patches': [])")
        spec = EpisodeSpec(str(get("soil")), float(get("relative_density_pct")), float(get("target_speed_m_s")),
                           float(get("target_depth_m")), seed=int(get("seed")), duration_s=float(get("duration_s")),
                           patches=patches)
        # ValueError naming the field and value, or a soil that resists nothing; with patches, the soil the edge starts in
        resolved = resolve_checked(self.config, spec, self.custom_soils)[0]
        if note := beyond_lift_reach("target_depth_m", resolved.target_depth_m):
            self._warn(f"beyond_lift_reach {resolved.target_depth_m:g}", note)  # each depth said once
        if note := beyond_table1_speed("target_speed_m_s", resolved.target_speed_m_s):
            self._warn(f"beyond_table1_speed {resolved.target_speed_m_s:g}", note)
        return resolved

    def _check_plan_entries(self, base: EpisodeSpec, plan: dict[str, list]) -> None:
        """ValueError naming the plan's entries an episode of it is refused for (the spec's own error
        named only 'soil' or 'relative_density_pct', not which list or entry). Each combination the
        plan runs is checked, with the base's value where a list is empty, as ``episode_plan`` makes them."""
        soils = list(enumerate(plan["sequence_soils"])) or [(None, base.soil)]
        densities = list(enumerate(plan["sequence_relative_densities_pct"])) or [(None, base.relative_density_pct)]
        for (i, soil), (j, density) in itertools.product(soils, densities):
            try:
                resolve_checked(self.config, replace(base, soil=soil, relative_density_pct=density), self.custom_soils)
            except ValueError as err:
                named = [f"parameter {n}[{k}]={v!r}" for n, k, v in (("sequence_soils", i, soil),
                                                                       ("sequence_relative_densities_pct", j, density))
                         if k is not None]
                raise ValueError(f"{' with '.join(named)}: {err}") from None

    def _enqueue(self, specs: list[EpisodeSpec]) -> None:
        for spec in specs:
            resolve_checked(self.config, spec, self.custom_soils)  # refused here, not when its turn comes
            self.queue.append(spec)

    def _on_set_parameters(self, params) -> SetParametersResult:
        """Episode parameters apply to episodes started later; rate applies at once."""
        changes = {p.name: p.value for p in params}
        fixed = {"world_mode", "engine", "pacing", "plugins", "effects_off", "wait_for", "sequence_soils",
                 "sequence_relative_densities_pct", "episodes", "soil_file", "path", "graph_id"} & set(changes)
        if fixed:
            return SetParametersResult(successful=False, reason=f"{sorted(fixed)} can only be set at start-up")
        try:
            if self.named_path and "patches" in changes:  # (a /sim/command start may still clear it for one episode)
                raise ValueError(f"patches={list(changes['patches'])} cannot be set while parameter "
                                 f"path={self._value('path')!r} gives the patches (path is fixed at start-up)")
            spec_fields = {k: v for k, v in changes.items() if k in G.START_FIELDS}
            if spec_fields:
                self._spec_from_params(spec_fields)
            self._validate_static({"pacing": self.pacer.pacing, "rate": changes.get("rate", self.pacer.rate),
                                   "world_mode": self.config.world_mode, "episodes": 0,
                                   **{k: v for k, v in changes.items()
                                      if k in ("wait_timeout_s", "settle_s", "lockstep_timeout_s")}})
        except (ValueError, TypeError) as err:
            return SetParametersResult(successful=False, reason=str(err))
        if "rate" in changes:
            self.pacer.set_rate(changes["rate"])
            self._reset_timer()
        for owner, name in ((self, "exit_when_done"), (self.start_wait, "wait_timeout_s"),
                            (self.start_wait, "settle_s"), (self.pacer, "lockstep_timeout_s")):
            if name in changes:
                setattr(owner, name, type(getattr(owner, name))(changes[name]))
        return SetParametersResult(successful=True)

    def _reset_timer(self) -> None:
        self.timer.cancel()
        self.destroy_timer(self.timer)
        self.timer = wall_timer(self, self.pacer.period_s, self._on_timer)
        if getattr(self, "grace_timer", None) is not None:
            self.grace_timer.cancel()
            self.destroy_timer(self.grace_timer)
            self.grace_timer = wall_timer(self, self.pacer.grace_s, self._on_grace)
            self.grace_timer.cancel()
            self.pacer.timers_restarted()

    # ------------------------------------------------------------------ episode control
    def _on_sim_command(self, msg: String) -> None:
        try:
            cmd = G.SimCommand.from_json(msg.data)
            if cmd.action == G.ACTION_START:
                spec = self._spec_from_params(cmd.overrides)
                self.queue.append(spec)
                self.get_logger().info(f"episode queued: {spec.soil} I_d={spec.relative_density_pct} seed={spec.seed}")
            elif cmd.action == G.ACTION_RESET:
                self.queue.clear()
                if self.sim is not None:
                    self._end_episode("reset")
            elif cmd.action == G.ACTION_SHUTDOWN:
                self.queue.clear()
                self.shutdown_requested = True
                if self.sim is not None:
                    self._end_episode("shutdown")
        except (ValueError, TypeError, ArithmeticError) as err:  # a bad command never stops the node: logged
            where = "" if str(err).startswith(G.SIM_COMMAND_TOPIC) else f"{G.SIM_COMMAND_TOPIC}: "
            self.get_logger().warning(f"{where}{err}; ignored")

    def _endpoint_counts(self) -> dict[str, tuple[int, int]]:
        """{awaited topic, or 'topic of /node': (matched endpoints now, how many are awaited)}."""
        counts = {}
        subs = dict(zip(G.COMMAND_TOPICS, self.cmd_subs))
        nodes: dict[str, set[str]] = {}  # topic -> its endpoints' nodes, asked once per topic (soil_launch names 4 nodes)
        for topic, count, node in self.wait_for:
            if node:  # that node's own endpoint (by its name, which DDS tells a moment after the endpoint)
                if topic not in nodes:
                    infos = (self.get_publishers_info_by_topic if topic in subs
                             else self.get_subscriptions_info_by_topic)(self.wait_names[topic])
                    nodes[topic] = {endpoint_node(i) for i in infos}
                counts[f"{self.wait_names[topic]} of {node}"] = (int(node in nodes[topic]), 1)
                continue
            if topic in subs:
                have = subs[topic].get_publisher_count()
            elif topic == G.SIM_STATUS_TOPIC:
                have = self.status_pub.get_subscription_count()
            else:
                have = self.pubs[topic].get_subscription_count()
            shown = self.wait_names[topic]
            counts[shown] = (have, max(count, counts.get(shown, (0, 0))[1]))  # given twice: each must hold
        return counts

    def _try_start(self) -> None:
        poll, missing = self.start_wait.poll_endpoints(self._endpoint_counts())
        if poll.gave_up:
            self.get_logger().warning(f"starting without {missing} after {self.start_wait.wait_timeout_s} s; later "
                                      "episodes start without them too, until they match again")
        elif missing and not self.start_wait.wait_timeout_s and self.start_wait.waited_s() >= UNLIMITED_WAIT_LOG_S:
            # waiting for ever (wait_timeout_s 0) and for a while now: say for what, every so often
            self.get_logger().warning(f"waiting for {missing} before the next episode for "
                                      f"{self.start_wait.waited_s():.0f} s (wait_timeout_s 0: no limit)",
                                      throttle_duration_sec=UNLIMITED_WAIT_LOG_S)
        if poll.go and not self._another_graph():
            self._start_episode(self.queue.popleft())

    def _another_graph(self) -> bool:
        """Whether to hold this start because of another graph on the domain: another simulator or a
        bag player publishing /sim/status (told by their node names; a writer whose node is not
        discovered yet holds the start up to ``GRAPH_NAMES_WAIT_S``). Before the first episode the
        node then starts none and ends (``EXIT_ANOTHER_GRAPH``); later (a graph that came after this
        one) it says so at each episode and goes on, the other simulator refusing itself. Two
        launches on one domain had cut each other's bags short and mixed their state, both ending in
        0. A writer of another name (a monitor, a hostile node) is said and changes nothing, but for
        the wait for its name. (A simulator killed outright may show for its DDS lease, ~20 s: a run
        started in that time may then be refused, and the message says so.)"""
        now = time.monotonic()
        if self.episode_index < 0 and now - self._born < GRAPH_DISCOVERY_MAX_S:  # (discovery still under way?)
            nodes = set(self.get_node_names_and_namespaces())
            if nodes != self._nodes_seen[0]:
                self._nodes_seen = (nodes, now)
            if now - self._born < GRAPH_DISCOVERY_S or now - self._nodes_seen[1] < GRAPH_QUIET_S:
                return True
        topic = self.status_pub.topic_name  # (its name in this graph's namespace)
        infos = self.get_publishers_info_by_topic(topic)
        names = [endpoint_node(i) for i in infos]
        if any(i.node_name == G.UNKNOWN_NODE_NAME for i in infos):  # (its node's name comes a moment after its writer)
            self._names_wait_since = self._names_wait_since or now
            if now - self._names_wait_since < GRAPH_NAMES_WAIT_S:
                return True
        self._names_wait_since = None
        ours = {self.get_name(), *GRAPH_STATUS_WRITERS}
        rivals = sum(i.node_name in ours for i in infos) - 1  # (this node's own writer counts)
        foreign = sorted({n for i, n in zip(infos, names) if i.node_name not in ours})
        if foreign:
            self._warn("foreign_status", f"{', '.join(foreign)} also publish {topic}: not a simulator or "
                                         "bag player of this project; its messages are not this simulator's")
        if rivals <= 0:
            return False
        said = (f"{rivals} other simulator(s) or bag player(s) publish {topic} on ROS_DOMAIN_ID "
                f"{self.context.get_domain_id()} (nodes {', '.join(sorted(set(names)))}): two graphs in one namespace "
                "of one domain mix their topics, and every bag of either would hold both")
        if self.episode_index < 0:  # (no episode started yet)
            self.get_logger().error(f"{said}; starting no episode: stop the other graph or give this one another "
                                    "ROS_DOMAIN_ID (soil_launch --domain-id) or a namespace of its own (soil_launch "
                                    "--namespace); a node killed in the last 20 s still shows until its DDS lease "
                                    "runs out: then start again in a moment")
            self.queue.clear()
            self.exit_code, self.finished = G.EXIT_ANOTHER_GRAPH, True
            return True
        self._warn("another_graph", f"{said}; going on (it came after this graph)")
        return False

    def _start_episode(self, spec: EpisodeSpec) -> None:
        self.sim = SoilSimulator(self.config, [spec], self.custom_soils)
        self.episode_index += 1
        self.meta = episode_meta(self.config, self.sim.specs[0], self.sim.soils[0].name, self.sim.effects.enabled())
        self.meta.source = "soil_sim_node"
        self.tick = 0
        self.planned_ticks = ticks_in(spec.duration_s)
        self.first_stamp_ns = self.next_first_stamp_ns
        self.pacer.start_episode()
        self.gate = CommandGate(self.command_writers)
        event = G.EpisodeEvent(G.EVENT_EPISODE_START, self.episode_index, self.meta.name, self.meta,
                               self.first_stamp_ns, planned_ticks=self.planned_ticks, pacing=self.pacer.pacing,
                               graph=self.graph_id)
        self._say(event)
        # Topics are not ordered with each other: make sure every subscriber's DDS reader
        # holds the start before tick 0 goes out (the controller resets on it).
        if not self.status_pub.wait_for_all_acked(Duration(seconds=2.0)):
            self.get_logger().warning("episode_start not acknowledged by every /sim/status subscriber within 2 s")
        self.get_logger().info(f"{G.episode_log(self.episode_index, 'start')}: {self.meta.name} ({self.planned_ticks} ticks)")
        self._reset_timer()
        self._publish_tick(self.sim.reset())

    def _say(self, event: G.EpisodeEvent) -> None:
        """An episode's event on /sim/status, and latched on /sim/episode for a node that joins later."""
        text = event.to_json()
        self.status_pub.publish(String(data=text))
        self.episode_pub.publish(String(data=text))

    def _end_episode(self, reason: str) -> None:
        last = self.first_stamp_ns + tick_stamp_ns(self.tick) if self.tick >= 0 else self.first_stamp_ns
        stats = self.pacer.end_episode()
        stats.update(commands_rejected=self.gate.rejected, commands_sanitised=self.gate.sanitised)
        event = G.EpisodeEvent(G.EVENT_EPISODE_END, self.episode_index, self.meta.name, self.meta,
                               self.first_stamp_ns, planned_ticks=self.planned_ticks, last_stamp_ns=last,
                               ticks=self.tick + 1, reason=reason, stats=stats, graph=self.graph_id)
        self._say(event)
        if not self.status_pub.wait_for_all_acked(Duration(seconds=1.0)):  # the node may exit next
            self.get_logger().warning("episode_end not acknowledged by every /sim/status subscriber within 1 s")
        self.get_logger().info(f"{G.episode_log(self.episode_index, 'end')} ({reason}): {self.tick + 1} ticks; timing {stats}")
        if reason == "error":
            self.exit_code = G.EXIT_EPISODE_FAILED  # the node goes on with its queue, and says so when it exits
        self.next_first_stamp_ns = last + int(round(TICK_PERIOD_NS))
        self.sim = None
        self.gate.idle()
        self._reset_timer()

    # ------------------------------------------------------------------ ticks
    def _publish_tick(self, out) -> None:
        """Publish the state of the current tick (or end the episode if it is not finite)."""
        rows = {"observations": np.concatenate([out.positions[0], out.velocities[0], np.zeros(3)]),
                "forces": out.forces[0], "known": out.known[0], "truth": out.truth[0], "extras": out.extras[0]}
        stamp = self.first_stamp_ns + out.stamp_ns
        values = {name: M.tick_values(name, rows) for name in G.SIM_STATE_TOPICS}
        bad = [(name, v) for name, vals in values.items() for v in vals if not np.isfinite(v)]
        if bad:
            self.get_logger().error(f"simulator state is not finite at stamp {stamp} ns ({bad[0][0]}={bad[0][1]}); "
                                    "ending the episode instead of publishing it")
            self.tick -= 1
            self._end_episode("error")
            return
        self.gate.expect(stamp)
        for name in G.SIM_STATE_TOPICS:
            self.pubs[name].publish(M.build_message(self.classes, name, stamp, values[name]))
        self.pacer.published()

    def _advance(self) -> None:
        """Apply this tick's commands, step the core, publish the next tick or end the episode."""
        u_zr, u_za, u_x = self.gate.take()
        if self.tick + 1 >= self.planned_ticks:
            self._end_episode("completed")
            return
        try:
            out = self.sim.step(u_zr, u_za, u_x)
        except PluginError as err:  # a user's force plugin raised or returned garbage: this episode cannot go on
            self.get_logger().error(f"{err}; ending the episode")
            self._end_episode("error")
            return
        self.tick += 1
        self._publish_tick(out)

    def _command_callback(self, topic: str):
        """Message plus message info (two parameters, so rclpy passes the info): the writer's
        publication sequence number tells the controller from another publisher."""
        def callback(msg, info) -> None:
            self._on_command(topic, msg, info.get("publication_sequence_number"))
        return callback

    def _on_command(self, topic: str, msg, sequence: int | None = None) -> None:
        try:
            stamp, values = M.parse_message(topic, msg)
        except ValueError as err:
            self._warn(f"{topic}:layout", f"{err}; ignored")
            return
        for kind, text in self.gate.offer(topic, stamp, values, sequence):
            self._warn(kind, text)
        if self.gate.complete and not self.gate.ready:  # an implausible command: the timer steps it (gate doc)
            self.pacer.hold()
        self._do(self.pacer.on_commands(self.gate.ready))

    def _on_timer(self) -> None:
        if self.sim is None:
            if self.queue and not self.shutdown_requested:
                self._try_start()
            elif self.shutdown_requested or (self.exit_when_done and not self.queue
                                             and (self.planned_at_start or self.episode_index >= 0)):
                # (with episodes 0 the plan is empty: done once a commanded episode ran, not at start-up)
                self.finished = True
            return
        self._do(self.pacer.on_timer(self.gate.complete))

    def _on_grace(self) -> None:
        self.grace_timer.cancel()
        self._do(self.pacer.on_grace())

    def _do(self, what: Do) -> None:
        """Carry out the pacing core's decision."""
        if what is Do.STEP:
            self.grace_timer.cancel()
            self._advance()
        elif what is Do.WAIT_GRACE:
            self.grace_timer.reset()
        elif what is Do.TIMED_OUT:
            self.get_logger().error(
                f"lockstep: no complete command for stamp {self.gate.stamp_ns} ns after {self.pacer.lockstep_timeout_s} s "
                f"(have {sorted(self.gate.arrived)}); ending the episode")
            self._end_episode("error")
        elif what is Do.STALLED:
            self._warn("lockstep_stall", f"lockstep: waiting for the commands for stamp {self.gate.stamp_ns} ns "
                                         f"(have {sorted(self.gate.arrived)}); is the controller running (and, if it "
                                         "follows a planner, the planner: it waits planner_wait_s for its targets)?")

    def close(self) -> None:
        if self.sim is not None:
            self._end_episode("shutdown")


def main(args: list[str] | None = None) -> int:
    return spin_node(SimNode, args, PARAMETERS, __doc__.splitlines()[0])


if __name__ == "__main__":
    raise SystemExit(main())
