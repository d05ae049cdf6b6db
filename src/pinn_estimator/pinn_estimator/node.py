"""`pinn_estimator`: the online estimator as a ROS 2 node (thin adapter over ``online.py``).

Subscribes to the state, force, command and Θ_k topics (``online.INPUT_TOPICS``) and to
``/sim/status``; publishes ``/soil/estimate`` (labelled Float64MultiArray, fields
``topics.ESTIMATE_FIELDS``: the PINN's window estimate and the soil fused along the path) and
``/soil/estimate/force`` (WrenchStamped, valid estimates only), each stamped with the newest
sample of the window, and ``/soil/map`` (PointCloud2, after each stretch of evidence); and,
latched, ``/soil/estimator/physics`` (String, JSON ``graph.EstimatorPhysics``): the terms beside
the FEE its posterior is fitted with and the planner's bound law, at start and whenever a new
checkpoint changes them, so a planner reads θ through the same physics. Each
``episode_start`` empties the window and restarts the soil posterior. It joins /sim/status
only once every input topic has a publisher (at most ``inputs_wait_s``), so a simulator that
waits for its status readers starts no episode before this node hears the whole tick.

Parameters (also in ``config/pinn_estimator.yaml``) are validated; ``checkpoint`` and
``stride`` can be changed at run time (``ros2 param set``): a checkpoint that does not load
is refused with the reason and the running model stays.
"""
from __future__ import annotations

import time
from typing import TYPE_CHECKING

from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from std_msgs.msg import String

from soil_msgs_py import cli_numbers
from soil_msgs_py import graph as G
from soil_msgs_py import messages as M
from soil_msgs_py import topics as T
from soil_msgs_py.params import MAX_STRIDE_TICKS
from soil_msgs_py.episode import WORLD_MODES
from soil_msgs_py.episode_follow import EpisodeFollower
from soil_msgs_py.ros_adapter import (
    InputSilence, WarnLimiter, declare_parameters, local, message_class, publisher_qos, qos_profile, spin_node, status_after_inputs,
    followed_status_event,
)

from soil_physics.predictive import near_limit_text

from .fusion_calibration import announced_physics, checkpoint_world, checkpoint_world_words, config_path, estimator_fusion
from .shipped import shipped_checkpoint

# The model's modules import torch (about 2 s): imported once a node is made, so that --help and a
# refused argument answer at once (spin_node handles both before it makes the node).
if TYPE_CHECKING:
    from .online import Estimate

PARAMETERS: dict[str, tuple] = {
    "checkpoint": ("", "PINN checkpoint (.pt) to load; empty: the shipped pinn_default.pt"),
    "stride": (1, f"estimate every n-th tick once the window is full (1: every tick, 60 Hz; at most {MAX_STRIDE_TICKS}; "
                  "1 with the planner in lockstep, whose controller waits for a plan of every tick)"),
    "reorder_ticks": (3, "a tick still incomplete when one this many ticks newer is complete counts as missing (1-120)"),
    "threads": (1, "torch CPU threads for the model (1 keeps the node to one core and deterministic)"),
    "fusion_config": ("", "soil posterior's config JSON (pinn_fusion_calibrate); empty: the shipped models/fusion_<world>.json "
                          "of the checkpoint's training world (fusion_default.json if several or none)"),
    "graph_id": G.FOLLOWED_GRAPH_ID_PARAMETER,
    "inputs_wait_s": (G.INPUTS_WAIT_S, "join /sim/status once every input topic has a publisher, or after this long "
                                       f"[s], [0, {G.MAX_WAIT_S:g}] (0: at once)"),
}

DRAIN_QUIET_S = 1.0  # asked to stop, an ended episode's queued ticks are taken while one comes at least this often
DRAIN_SAID_EVERY_S = 2.0  # and it says how far it got this often (soil_launch waits for a stopping node that reports)
DRAIN_ENDED_EPISODE_LIMIT_S = 120.0  # the most it spends so: a lockstep run's backlog can be seconds of estimation


def load_estimator_model(path: str):
    """(model, checkpoint dict, resolved path); ValueError with the reason if it cannot be used."""
    from .checkpoint import DEFAULT_CHECKPOINT, load_model
    from .online import check_compatible

    resolved = str(path) if path else str(DEFAULT_CHECKPOINT)
    try:
        model, ckpt = load_model(resolved)
    except FileNotFoundError as err:
        raise ValueError(f"parameter checkpoint: {err}") from None
    except ValueError as err:
        raise ValueError(f"parameter checkpoint refused: {err}") from None
    try:
        check_compatible(model)
    except ValueError as err:
        raise ValueError(f"parameter checkpoint refused: {resolved}: {err}") from None
    return model, ckpt, resolved


class EstimatorNode(Node):
    def __init__(self) -> None:
        super().__init__(G.NODE_NAMES["estimator"])
        get = declare_parameters(self, PARAMETERS)
        threads = get("threads")
        if not isinstance(threads, int) or not 1 <= threads <= cli_numbers.local_limit():
            raise ValueError(f"parameter threads={threads!r} must be an integer in [1, {cli_numbers.local_limit()}] "
                             f"({cli_numbers.PER_CORE} per core of this machine at the most)")
        import torch

        from .online import INPUT_TOPICS, OnlineEstimator

        torch.set_num_threads(threads)
        model, ckpt, self.checkpoint_path = load_estimator_model(get("checkpoint"))
        self._warn = WarnLimiter(self.get_logger())
        # the shipped calibration of the checkpoint's world unless a config is given (its world as it
        # records it: None where it does not)
        self.fusion_path = get("fusion_config")
        fusion, self.fusion_world = estimator_fusion(self.fusion_path, ckpt)
        self._fusion_world_words = checkpoint_world_words(ckpt)
        self._worlds_warned: set[str] = set()
        self.episode = None  # the last episode started (``G.EpisodeEvent``)
        self.core = OnlineEstimator(model, self._publish, stride=get("stride"), reorder_ticks=get("reorder_ticks"),
                                    warn=self._warn, fusion=fusion, publish_map=self._publish_map)
        self.add_on_set_parameters_callback(self._on_set_parameters)

        self.classes = M.ros_message_classes()
        self.estimate_pub = self.create_publisher(
            message_class(T.ESTIMATE.msgtype), local(T.ESTIMATE.name), publisher_qos(T.ESTIMATE.name))
        self.force_pub = self.create_publisher(
            message_class(T.ESTIMATED_FORCE.msgtype), local(T.ESTIMATED_FORCE.name), publisher_qos(T.ESTIMATED_FORCE.name))
        self.map_pub = self.create_publisher(
            message_class(T.SOIL_MAP.msgtype), local(T.SOIL_MAP.name), publisher_qos(T.SOIL_MAP.name))
        self.physics_pub = self.create_publisher(String, local(G.ESTIMATOR_PHYSICS_TOPIC),
                                                 publisher_qos(G.ESTIMATOR_PHYSICS_TOPIC))
        self._physics_said: tuple | None = None
        self._drain_said = 0.0  # time.monotonic() it last said it is finishing an ended episode (0: not yet)
        self.drain_limit_s = DRAIN_ENDED_EPISODE_LIMIT_S  # (``spin_node``'s bound on ``draining``)
        self._say_physics()
        # Deep input queues (like a recorder's): a model step that runs late must not make DDS
        # drop a sample, which would cost a whole window.
        deep = qos_profile(G.RECORDER_QOS)
        self.silence = InputSilence(self, "samples (the simulator's state and the controller's commands)")
        self.follower = EpisodeFollower(get("graph_id"))  # a stray /sim/status event neither restarts nor ends it
        inputs = {name: self.create_subscription(message_class(T.TOPICS_BY_NAME[name].msgtype), local(name),
                                                 lambda msg, n=name: self._on_input(n, msg), deep)
                  for name in INPUT_TOPICS}
        # /sim/status last, once every input has a publisher (at most inputs_wait_s): matched late
        # under load, the first second's ticks lacked the controller's commands. (A tick that
        # overtakes its episode_start is kept: ``OnlineEstimator.start_episode``.)
        self.status = status_after_inputs(
            self, inputs, self._on_status, get("inputs_wait_s"),
            lambda missing: self.get_logger().warning(f"following /sim/status without a publisher of {missing} yet"))
        self.get_logger().info(
            f"model {self.checkpoint_path} ({ckpt.get('dataset', {}).get('world_modes')} data), "
            f"stride {self.core.stride}, {threads} thread(s), soil posterior {self.fusion_source} (evidence law rel "
            f"{self.core.posterior.cfg.rel_std}; forecast law {_law(self.core.posterior.cfg)}, published as "
            f"{T.ESTIMATE.name}'s model_std_*); publishing {T.ESTIMATE.name}, {T.ESTIMATED_FORCE.name}, {T.SOIL_MAP.name}, "
            f"{G.ESTIMATOR_PHYSICS_TOPIC}")

    # ------------------------------------------------------------------ parameters
    def _on_set_parameters(self, params) -> SetParametersResult:
        changes = {p.name: p.value for p in params}
        try:
            model = load_estimator_model(changes["checkpoint"]) if "checkpoint" in changes else None
            if "stride" in changes:
                type(self.core)._check_stride(changes["stride"])
            if fixed := sorted({"reorder_ticks", "threads", "fusion_config", "inputs_wait_s", "graph_id"} & set(changes)):
                raise ValueError(f"{fixed} can only be set at start-up; restart the node to change them")
        except ValueError as err:
            return SetParametersResult(successful=False, reason=str(err))
        if model is not None:
            fusion = None  # a config chosen by the checkpoint's world follows the new checkpoint's
            if not self.fusion_path and checkpoint_world(model[1]) != self.fusion_world:  # (a config given stays)
                fusion, self.fusion_world = estimator_fusion("", model[1])
                self._worlds_warned.clear()
            if not self.fusion_path:
                self._fusion_world_words = checkpoint_world_words(model[1])
                if self.episode is not None:  # the episode under way may be of another world than the new model's
                    self._say_if_other_world(self.episode)
            self.core.set_model(model[0], fusion)
            self.checkpoint_path = model[2]
            self._say_physics()
            self.get_logger().info(f"model now {self.checkpoint_path}"
                                   + (f", soil posterior {self.fusion_source}" if fusion is not None else ""))
        if "stride" in changes:
            self.core.set_stride(changes["stride"])
        return SetParametersResult(successful=True)

    # ------------------------------------------------------------------ callbacks
    def _on_status(self, msg: String) -> None:
        event = followed_status_event(msg.data, self._warn, self.follower, self.silence)
        if event is None:
            return
        if event.event == G.EVENT_EPISODE_START:
            self.silence.start(event.name)
            self.core.start_episode(event.first_stamp_ns)
            self.get_logger().info(f"episode {event.name}: new window from stamp {event.first_stamp_ns} ns")
            self.episode = event
            self._say_if_other_world(event)
            self._say_if_stride_holds_a_lockstep_planner(event)
        else:
            self.silence.end()
            self.episode = None  # (a model swap between episodes has no episode under way to warn of)
            if event.last_stamp_ns >= 0:
                self.core.end_episode(event.last_stamp_ns)

    def _say_if_stride_holds_a_lockstep_planner(self, event: G.EpisodeEvent) -> None:
        """Warned at a lockstep episode's start when a planner reads the estimates and the stride is
        above 1: its controller keeps step with a plan for every tick, the planner plans a tick from
        its estimate, and each tick without one waits the controller's planner_wait_s (42 s for a 1 s
        episode at stride 3). soil_launch refuses the combination; a graph started by hand, or a
        stride set at run time, is told here."""
        if event.pacing != G.PACING_LOCKSTEP or self.core.stride == 1:
            return
        readers = self.get_subscriptions_info_by_topic(self.resolve_topic_name(local(T.ESTIMATE.name)))
        if any(i.node_name == G.NODE_NAMES["planner"] for i in readers):
            self.get_logger().warning(f"episode {event.name}: stride {self.core.stride} with a planner in lockstep: its "
                                      "controller waits planner_wait_s at each tick without an estimate; set stride 1")

    @property
    def fusion_source(self) -> str:
        """Where the soil posterior's config came from, for the log."""
        return self.fusion_path or f"{config_path(self.fusion_world)} ({self._fusion_world_words})"

    def _say_physics(self) -> None:
        """/soil/estimator/physics, latched, when what it says has changed (the source alone does not count)."""
        said = announced_physics(self.core.posterior.cfg, f"{self.fusion_source}, model {self.checkpoint_path}")
        if self._physics_said != (said.terms, said.bound_law):
            self._physics_said = (said.terms, said.bound_law)
            self.physics_pub.publish(String(data=said.to_json()))
            if uncalibrated := self.core.uncalibrated_physics():
                self.get_logger().warning(uncalibrated)

    def _say_if_other_world(self, event) -> None:
        """Once per world: an episode of a world other than the one whose calibration the soil
        posterior took (the checkpoint world's shipped one, or a given config's recorded world;
        its error laws are that world's; pinn_eval warns alike)."""
        world = getattr(event.meta, "world_mode", "") if event.meta is not None else ""
        if (self.fusion_world is None or not world or world not in WORLD_MODES  # a machine's: no simulator world's
                or world == self.fusion_world or world in self._worlds_warned):
            return
        self._worlds_warned.add(world)
        self.get_logger().warning(
            f"episode {event.name} is the {world} world's; the soil posterior uses the {self.fusion_world} world's "
            f"calibration ({self.fusion_source}): its intervals are not calibrated here. Give fusion_config:="
            f"{config_path(world)}" + (" (it exists)" if config_path(world).exists() else "")
            + ("" if self.fusion_path else  # (a given config stays whatever the checkpoint)
               " or a checkpoint trained in that world"
               + (f", e.g. its shipped checkpoint:={shipped} (soil_launch gives it when no checkpoint is given)"
                  if (shipped := shipped_checkpoint(world)).is_file() else "")))

    def _on_input(self, topic: str, msg) -> None:
        self.silence.heard()
        self.core.add(topic, msg)

    def _publish(self, est: Estimate) -> None:
        self.estimate_pub.publish(M.make_labelled(self.classes, est.stamp_ns, T.ESTIMATE_FIELDS, est.values))
        if est.valid:
            self.force_pub.publish(M.build_message(self.classes, T.BLADE_FORCE.name, est.stamp_ns,
                                                   [est["f_x_hat"], est["f_z_hat"]]))

    def _publish_map(self, stamp_ns: int, rows) -> None:
        self.map_pub.publish(M.make_point_cloud(self.classes, stamp_ns, T.MAP_FIELDS, rows))

    def draining(self) -> bool:
        """Asked to stop (``spin_node``): an episode that ended but whose last ticks are still
        queued is estimated to its end first (``OnlineEstimator.owes_ended_episode``), while they
        keep coming at least every ``DRAIN_QUIET_S`` (a tick that never completes does not hold
        the stop; ``spin_node`` bounds the whole by ``drain_limit_s``, a second signal ends it), and
        says so every ``DRAIN_SAID_EVERY_S``. A stop mid-episode is not delayed."""
        now = time.monotonic()
        owed = self.core.owes_ended_episode and now - self.silence.last < DRAIN_QUIET_S
        if owed and now - self._drain_said >= DRAIN_SAID_EVERY_S:
            self._drain_said = now
            self.get_logger().info(f"finishing the ended episode first: at stamp {self.core.assembler.last_released} "
                                   f"ns of its last, {self.core.ended_at_ns} ns")
        return owed

    def close(self) -> None:
        from .online import IMPLAUSIBLE_ESTIMATE_FACTOR

        c = self.core.counters
        self.get_logger().info(
            f"{c.estimates} estimates, {c.invalid} invalid; {c.samples} samples, {c.gaps} gaps, "
            f"{c.out_of_order} out of order, {c.non_finite} non-finite or implausible, {c.malformed} malformed, "
            f"{c.duplicates} duplicates, {c.evicted} evicted, {c.restarts} restarts"
            + (f", {c.off_rate} off the 60 Hz rate" if c.off_rate else "")
            + (f"; model outputs: {c.model_non_finite} not finite, {c.model_implausible} beyond "
               f"{IMPLAUSIBLE_ESTIMATE_FACTOR:g} times the force limits (published invalid)"
               if c.model_non_finite or c.model_implausible else ""))


def main(args: list[str] | None = None) -> int:
    return spin_node(EstimatorNode, args, PARAMETERS, __doc__.splitlines()[0])


if __name__ == "__main__":
    raise SystemExit(main())


def _law(cfg) -> str:
    """The forecast's error law σ_j = abs_j + rel_j·|ΔF_j| (+ its part near the F_x limit) per axis, as
    the start line says it."""
    return ", ".join(f"{axis} {a:g} N + {r:g}·|ΔF|{near_limit_text(s)}"
                     for axis, a, r, s in zip("xz", cfg.forecast_abs_std_n, cfg.forecast_rel_std, cfg.forecast_limit_std))
