"""`soil_planner`: the deepest-cut planner (``planner.py``) as a ROS 2 node (thin adapter).

Subscribes to /soil/estimate and /soil/known_params, pairs them by stamp (the estimate of
tick t is planned with Θ_k of tick t, whichever arrives first) and publishes
/planner/max_cut_depth stamped with the estimate's stamp: the deepest cut depth below the soil
surface (Θ_k's d; what to give the anti-stall controller as ``target_depth_m``, see
``planner.py``) for a steady, level cut at ``cut_speed_m_s``. An invalid estimate (valid = 0)
gives a valid = 0 plan (all zeros), so a consumer sees that there is no plan for that tick.
A message that cannot be trusted (wrong layout, NaN, out of Table 1 limits) is reported via
WarnLimiter and nothing is published for it; the node never publishes NaN and never dies
on input. A log line at most once per ``log_period_s`` of simulation time says what the
plan is and why. /blade/cmd gives the depth the controller commands per tick (−u_za): a steady
edge held short of it shows the lift's push in F_z, which does not anchor the plan's z force
(``stretch_planner.HELD_GAP_M``); without commands (no controller) every tick anchors as before.
/blade/force gives the blade's measured force per tick: where it is clearly above the PINN's
F̂_x, it anchors the fused plan (``stretch_planner.SENSOR_GAP_SHARE``, parameter ``sensor_anchor``);
a tick without it keeps F̂. While
commands come, a tick is planned once its own command is in (``command_wait.py``: another
writer's message, which DDS does not order before the estimate), at most ``command_wait_s``
of wall time after it was ready. It subscribes to /soil/known_params only once the estimator's
and the controller's writers have matched (at most ``inputs_wait_s``), so a simulator waiting for
its Θ_k readers waits for those matches too.

Every plan also moves the cut depth the anti-stall controller follows when its
``depth_source`` is ``planner``: /planner/target_depth (stamped like the plan; sent when the
target moved by a millimetre, and at least 5 times a second; every tick in a lockstep episode,
for the controller keeps step with it there), the plan's
deepest cut through the depth schedule's rate limits, start depth and hold
(``depth_schedule.py``; parameters ``start_depth_m``, ``deepen_rate_m_s``, ``shallow_rate_m_s``,
``hold_s``, ``retreat_m``, ``retreat_memory_s``, ``cautious_deepen_rate_m_s``, ``min_target_m``,
``max_target_m``). A tick whose plan was refused, or an invalid
estimate, moves the schedule without a plan (it holds, then backs off). Each new cut (an
episode_start on /sim/status, or two ticks in a row more than a second from the last one
scheduled, either way: one such tick alone is a stray, warned and given no target) starts from
the start depth with no plan carried over; a tick older than the last one planned is not
scheduled again.

The posterior's θ is read through the physics the estimator fitted it with, which the estimator
says on /soil/estimator/physics (latched, heard on joining): the ``terms`` and ``bound_law`` the
node is not given are taken from it (``estimator_physics.py``; ``follow_estimator_physics``).

Parameters (also in ``config/soil_planner.yaml``) are validated at start (a bad one exits
with code 2) and can be changed at run time (``ros2 param set``).
"""
from __future__ import annotations

import collections
import math
import re
import time

import numpy as np
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import String

from soil_msgs_py import messages as M
from soil_msgs_py import topics as T
from soil_msgs_py.params import FORCE_LIMITS_N, KNOWN_PARAMS, SAMPLE_RATE_HZ, TICK_PERIOD_NS
from soil_msgs_py.values import number_in, short_repr
from soil_msgs_py import graph as G
from soil_msgs_py.episode_follow import EpisodeFollower, same_episode
from soil_msgs_py.ros_adapter import (InputSilence, JoinAfterInputs, WarnLimiter, declare_parameters,
                                      followed_status_event, local, message_class, publisher_qos, spin_node, topic_qos,
                                      wall_timer)
from soil_msgs_py.stamp_join import RESTART_AFTER_REFUSED_TICKS, StampJoiner, Verdict
from soil_msgs_py.writer_identity import FORGET_WRITER_AFTER_TICKS, WriterTracks, tick_number
from soil_physics.force_terms import term_texts
from soil_physics.predictive import error_law_text

from .command_wait import DEFAULT_COMMAND_WAIT_S, MAX_COMMAND_WAIT_S, CommandWait, Waiting, check_command_wait
from .depth_schedule import GAP_PACES, DepthSchedule, ScheduleSettings, follows_at_its_pace
from .estimator_physics import physics_text, planning_physics
from .planner import (CUT_SPEED_LIMIT_M_S, D_MAX_LIMIT_M, DEFAULT_CUT_SPEED_M_S, DEFAULT_D_MAX_M, DEFAULT_FORCE_QUANTILE,
                      DEFAULT_MARGIN, NO_PLAN_VALUES, check_switch, describe, fields)
from .stretch_planner import check_target_floor, from_parameters

_SCHEDULE = ScheduleSettings()
# Node parameter -> ScheduleSettings field
SCHEDULE_PARAMETERS = {"start_depth_m": "start_depth_m", "deepen_rate_m_s": "deepen_rate_m_s",
                       "shallow_rate_m_s": "shallow_rate_m_s", "hold_s": "hold_s", "retreat_m": "retreat_m",
                       "retreat_memory_s": "retreat_memory_s", "cautious_deepen_rate_m_s": "cautious_deepen_rate_m_s",
                       "min_target_m": "min_depth_m", "max_target_m": "max_depth_m"}


def schedule_settings(by_parameter: dict) -> ScheduleSettings:
    """``ScheduleSettings`` from the node's parameter values (``SCHEDULE_PARAMETERS``' names); a
    ValueError names the node's parameters (``min_target_m``), not the settings' fields."""
    try:
        return ScheduleSettings(**{f: by_parameter[p] for p, f in SCHEDULE_PARAMETERS.items()})
    except ValueError as err:
        text = str(err)
        for param, field_name in SCHEDULE_PARAMETERS.items():
            text = re.sub(rf"\b{field_name}\b", param, text)
        raise ValueError(text) from None


def estimate_joiner() -> StampJoiner:
    """Θ_k and the estimate of one tick, planned once both are in; Θ_k arrives in stamp order, so
    older ticks still waiting are given up. A stamp older than the newest planned tick is refused:
    an estimate of the previous episode that comes late, or one stray message, had restarted the
    stream and dropped every tick waiting (an outside reviewer's). Refused for
    RESTART_AFTER_REFUSED_TICKS ticks in a row, a stream that started over without a word (no
    /sim/status) is followed; an episode_start starts it at its first tick at once (``start_at``)."""
    return StampJoiner((T.KNOWN.name, T.ESTIMATE.name), max_pending=MAX_PENDING_STAMPS,
                       restart_after_refused=2 * RESTART_AFTER_REFUSED_TICKS,
                       restart_counts_back_beyond_ns=NEW_CUT_GAP_NS)  # (copies a moment back: no restart)


NEW_CUT_GAP_NS = M.NS_PER_S  # plans further apart than this (simulation time) belong to a new cut
MAX_STARTS_AHEAD = 16  # episode_starts held for the estimates of an earlier episode still coming (``_on_status``)


def episode_end_ns(event: G.EpisodeEvent, last_stamp_ns: int | None) -> int:
    """The last tick's stamp [ns] of the episode ``event`` starts: its end's (``last_stamp_ns``, if
    heard and it published a tick), else as planned."""
    if last_stamp_ns is not None and last_stamp_ns >= 0:
        return last_stamp_ns
    return event.first_stamp_ns + round(max(event.planned_ticks - 1, 0) * TICK_PERIOD_NS)


# /planner/target_depth goes out when the target moved by TARGET_STEP_M, its validity changed,
# or TARGET_HEARTBEAT_NS passed (well inside the controller's planner_timeout_s).
TARGET_STEP_M = 1e-3
TARGET_HEARTBEAT_NS = M.NS_PER_S // 5

MAX_LOG_PERIOD_S = 86400.0  # a day of simulation time: longer than any cut (1e300 s overflowed the ns count)
PARAMETERS: dict[str, tuple] = {
    "margin": (DEFAULT_MARGIN, f"fraction of the force limits ({FORCE_LIMITS_N[0] / 1e3:g} kN tractive x, "
                               f"{FORCE_LIMITS_N[1] / 1e3:g} kN lift z) a cut may use, (0, 1]"),
    "d_max_m": (DEFAULT_D_MAX_M, f"deepest cut depth below the soil surface considered [m], (0, {D_MAX_LIMIT_M:g}]; "
                                 "default: the blade's reach with the chassis on level, uncut ground "
                                 f"({DEFAULT_D_MAX_M:g} m)"),
    "cut_speed_m_s": (DEFAULT_CUT_SPEED_M_S, "blade speed v_x of the planned steady, level cut (v_z = 0) [m/s], "
                                             f"(0, {CUT_SPEED_LIMIT_M_S:g}]; default: the anti-stall controller's "
                                             "default target speed"),
    "follow_episode_speed": (True, "take cut_speed_m_s from each episode_start on /sim/status: the target speed the "
                                   "controller cuts at when it follows the episodes (its follow_episode_targets), so "
                                   "the plans and the stall memory's threshold are the cut's; a cut_speed_m_s given "
                                   "holds until the next episode_start; false: cut_speed_m_s as given (soil_launch sets "
                                   "it so when the controller does not follow)"),
    "include_residual": (True, "anchor the FEE to the estimated force F̂ at the current depth (residual ∝ depth in soil)"),
    "force_quantile": (DEFAULT_FORCE_QUANTILE, "plan from the fused soil posterior: the deepest cut whose this upper "
                                               "quantile of |F| stays within the limits, [0.5, 1); 0: the PINN's point estimate only"),
    "terms": ([], "the fused posterior's physics beside the FEE, 'name=k' entries: the plan reads the posterior's θ "
                  "through the model it was fitted with; empty: the estimator's, as it says it on "
                  f"{G.ESTIMATOR_PHYSICS_TOPIC} (follow_estimator_physics), else the FEE alone; given: these "
                  "(a difference from the estimator's is said)", Parameter.Type.STRING_ARRAY),
    "bound_law": ([], "the error law of the fused bound a plan keeps within the limits, [abs_x N, abs_z N, rel_x, "
                      "rel_z] (σ = abs + rel·|ΔF|, as the estimate's model_std_*), calibrated on anchored bounds "
                      "(its fusion config's bound_*), used where the bound is anchored to the force now; empty: the "
                      f"estimator's, as it says it on {G.ESTIMATOR_PHYSICS_TOPIC} (follow_estimator_physics), else "
                      "the estimate's model_std_*, the law calibrated for its forecast intervals (which an unanchored "
                      "bound always uses)", Parameter.Type.DOUBLE_ARRAY),
    "follow_estimator_physics": (True, f"take terms and bound_law the node is not given from the estimator "
                                       f"({G.ESTIMATOR_PHYSICS_TOPIC}, latched; what soil_launch --planner relies "
                                       "on); false: the FEE alone and the estimate's model_std_* unless given"),
    "sensor_anchor": (True, "where the blade's measured F_x (/blade/force), averaged over the recent steady cut, "
                            "is clearly above the PINN's F̂_x (by more than 15 % and 3 standard errors), the fused "
                            "plan is anchored to the measured force (a model outside its training is trusted no "
                            "further than the sensor); a measured force below F̂ never makes a plan deeper. Fused "
                            "plans only (no effect with force_quantile 0)"),
    "log_period_s": (1.0, "at most one plan log line per this much simulation time [s], "
                     f"in [0, {MAX_LOG_PERIOD_S:g}] (0: every plan)"),
    "command_wait_s": (DEFAULT_COMMAND_WAIT_S, "while the controller's /blade/cmd comes, a tick is planned once its "
                                               "command is in, waiting at most this long [s of wall time], "
                                               f"[0, {MAX_COMMAND_WAIT_S:g}] (0: never wait)"),
    "graph_id": G.FOLLOWED_GRAPH_ID_PARAMETER,
    "inputs_wait_s": (G.INPUTS_WAIT_S, "subscribe to /soil/known_params once /soil/estimate and /blade/cmd have a "
                                       f"publisher, or after this long [s], [0, {G.MAX_WAIT_S:g}] (0: at once), so a "
                                       "simulator waiting for this node starts no episode before the planner can hear "
                                       "the estimator and the controller"),
    "start_depth_m": (_SCHEDULE.start_depth_m, "controller target before the first valid plan of a cut [m]"),
    "deepen_rate_m_s": (_SCHEDULE.deepen_rate_m_s, "the target deepens by at most this per second of simulation time [m/s]"),
    "shallow_rate_m_s": (_SCHEDULE.shallow_rate_m_s, "the target rises by at most this per second [m/s]"),
    "hold_s": (_SCHEDULE.hold_s, "without a valid plan the last target is held this long [s], then backs off to start_depth_m"),
    "retreat_m": (_SCHEDULE.retreat_m, "a plan shallower than the target by more than this is a retreat [m], >= 0"),
    "retreat_memory_s": (_SCHEDULE.retreat_memory_s, "after a retreat the target deepens at cautious_deepen_rate_m_s "
                                                     "for this long [s], >= 0 (0: never)"),
    "cautious_deepen_rate_m_s": (_SCHEDULE.cautious_deepen_rate_m_s, "the deepening rate after a retreat [m/s], "
                                                                     "> 0 (at most deepen_rate_m_s)"),
    "min_target_m": (_SCHEDULE.min_depth_m, "shallowest target depth [m] (the edge kept in the soil)"),
    "max_target_m": (_SCHEDULE.max_depth_m, "deepest target depth [m] (default: the lift joint's reach on level ground)"),
}
# Ticks waiting for their partner message: a minute of them. Θ_k comes on time from the simulator,
# the estimate as late as the estimator is behind: on a loaded machine, or a bag replayed faster
# than it can follow, seconds (with 2 s every estimate past that lag was dropped for good); in a
# lockstep run whose controller stopped waiting for a silent planner, the simulator outruns the
# estimator by more (an outside tester's planner, started 2 s into such a run, found its estimates
# 11.7 s, then 17.9 s behind their Θ_k with 10 s kept: it never planned; once it plans, the
# controller waits for its targets again and the loop falls back into step). The controller takes
# a target only within its planner_timeout_s of the tick it answers, so a late plan steers nothing
# live; it is still published and recorded.
MAX_PENDING_STAMPS = 60 * SAMPLE_RATE_HZ
PLANNER_SETTINGS = ("margin", "d_max_m", "cut_speed_m_s", "include_residual", "force_quantile", "terms",
                    "sensor_anchor", "bound_law")  # StretchPlanner's
# what is read once, at start: a change at run time is refused (it would change nothing)
START_ONLY = frozenset(PARAMETERS) - {*PLANNER_SETTINGS, *SCHEDULE_PARAMETERS, "log_period_s", "command_wait_s",
                                      "follow_estimator_physics", "follow_episode_speed"}
PHYSICS_SETTINGS = ("terms", "bound_law")  # the user's, or the estimator's where not given (``estimator_physics``)


def _keep_by_stamp(by_stamp: collections.OrderedDict, stamp: int, value) -> None:
    """A tick's value kept until its estimate is planned: the newest MAX_PENDING_STAMPS ticks'."""
    by_stamp[stamp] = value
    while len(by_stamp) > MAX_PENDING_STAMPS:
        by_stamp.popitem(last=False)


def check_log_period(value) -> float:
    return number_in("log_period_s", value, 0.0, MAX_LOG_PERIOD_S, unit=" s")


class PlannerNode(Node):
    def __init__(self) -> None:
        super().__init__(G.NODE_NAMES["planner"])
        get = declare_parameters(self, PARAMETERS)
        self.planner = from_parameters({name: get(name) for name in PLANNER_SETTINGS})
        # what the user gave of the posterior's physics, and whether the estimator's fills what was not
        self.own_physics = {name: self.planner.settings()[name] for name in PHYSICS_SETTINGS}
        self.follow_physics = check_switch("follow_estimator_physics", get("follow_estimator_physics"))
        self.follow_speed = check_switch("follow_episode_speed", get("follow_episode_speed"))
        self.announced: G.EstimatorPhysics | None = None
        self.schedule = DepthSchedule(schedule_settings({p: get(p) for p in SCHEDULE_PARAMETERS}))
        check_target_floor(self.planner, self.schedule.settings)
        self._target_sent: tuple[int, float, float] | None = None  # (stamp, target, plan_valid) last published
        self._jumped_to: int | None = None  # a tick far from the last scheduled one, until the next follows it (``_target``)
        self._pace_ns: int | None = None  # estimates further apart than NEW_CUT_GAP_NS: their spacing (``_target``)
        self._pace_seen_ns: int | None = None  # such a spacing seen once, taken as the pace when seen again
        # in a lockstep episode (its episode_start says so) every tick's target goes out: the controller
        # answers tick k once the target of tick k − lag came (anti_stall_controller.plan_wait)
        self.lockstep = False
        self.log_period_ns = int(check_log_period(get("log_period_s")) * M.NS_PER_S)
        # the depth the controller commands per tick stamp (−u_za of /blade/cmd): a steady edge held
        # short of it is pressed onto a floor, and its F_z (the lift's push) does not anchor z
        self.commanded: collections.OrderedDict[int, float] = collections.OrderedDict()
        self.command_writer = WriterTracks(forget_after_ticks=FORGET_WRITER_AFTER_TICKS)  # the controller's
        self.command_wait = CommandWait(get("command_wait_s"))  # ValueError names the field
        # the blade's measured (F_x, F_z) per tick stamp (/blade/force): where it is clearly above
        # F̂, it anchors the plan (``stretch_planner.SENSOR_GAP_SHARE``)
        self.measured: collections.OrderedDict[int, tuple[float, float]] = collections.OrderedDict()
        self.sensed = 0  # fused plans made with their tick's measured force (the point plan takes none)
        # ticks of the cut under way whose Θ_k never came (``_note_known``); the newest Θ_k stamp of the cut
        # under way, and a hole after it not yet confirmed by the stamp after it ((before, after) [ns])
        self.missed, self.cut_known_ns, self.known_jump = 0, None, None
        self.add_on_set_parameters_callback(self._on_set_parameters)

        self.classes = M.ros_message_classes()
        self._warn = WarnLimiter(self.get_logger())
        self.silence = InputSilence(self, f"estimates ({T.ESTIMATE.name})")
        self.follower = EpisodeFollower(get("graph_id"))  # a stray /sim/status event does not restart its cut
        self.joiner = estimate_joiner()
        self.cut_first_ns: int | None = None  # the first tick of the episode followed (None: none now)
        self.cut_end_ns: int | None = None  # its last tick as planned, then as it ended
        # episode_starts taken while the estimates of an earlier episode still come, each with its
        # episode_end's last stamp once heard: the cut starts when its first estimate does (``_on_estimate``)
        self.starts_ahead: collections.deque[list] = collections.deque()
        self.cut_newest_ns: int | None = None  # the newest estimate's stamp of the cut under way
        # the newest estimate's stamp of any cut since time last went back: a held start at or before the
        # cut under way (a replay started over) starts once an estimate comes at or before it (``_start_ahead``)
        self.timeline_newest_ns: int | None = None
        self.previous_cut_ticks = 0  # ticks of an episode before it, come after it began: not planned
        self.last_log_ns: int | None = None
        self.published = 0
        self.dropped = 0  # estimates given up for want of their Θ_k
        self.plan_pub = self.create_publisher(message_class(T.PLAN.msgtype), local(T.PLAN.name), publisher_qos(T.PLAN.name))
        self.target_pub = self.create_publisher(message_class(T.TARGET_DEPTH.msgtype), local(T.TARGET_DEPTH.name),
                                                publisher_qos(T.TARGET_DEPTH.name))
        # /sim/status first: a new episode starts a new cut (schedule, plan cache) before its ticks.
        self.create_subscription(String, local(G.SIM_STATUS_TOPIC), self._on_status, topic_qos(G.SIM_STATUS_TOPIC))
        # the estimator's physics, latched: heard on joining, whenever the estimator started
        self.create_subscription(String, local(G.ESTIMATOR_PHYSICS_TOPIC), self._on_physics,
                                 topic_qos(G.ESTIMATOR_PHYSICS_TOPIC))
        # the tick's measured force comes from the simulator before the estimator can answer it;
        # one that is lost leaves that tick anchored to F̂ alone
        self.create_subscription(message_class(T.BLADE_FORCE.msgtype), local(T.BLADE_FORCE.name), self._on_blade_force,
                                 topic_qos(T.BLADE_FORCE.name))
        # /blade/cmd before /soil/estimate: the executor serves ready subscriptions in the order they
        # were made, so a tick's command, sent before its estimate, is mostly taken first (command_wait
        # makes sure of it)
        inputs = {
            T.BLADE_CMD.name: self.create_subscription(
                message_class(T.BLADE_CMD.msgtype), local(T.BLADE_CMD.name),
                lambda msg, info: self._on_blade_cmd(msg, info.get("publication_sequence_number")),
                topic_qos(T.BLADE_CMD.name)),
            T.ESTIMATE.name: self.create_subscription(message_class(T.ESTIMATE.msgtype), local(T.ESTIMATE.name),
                                                      self._on_estimate, topic_qos(T.ESTIMATE.name)),
        }
        # Θ_k (which a simulator waits for) once the controller's and the estimator's writers have
        # matched (at most inputs_wait_s): matched late under load, the first estimates or commands
        # were lost, and a lockstep controller waited for their plans.
        self.known_join = JoinAfterInputs(
            self, inputs, lambda: self.create_subscription(message_class(T.KNOWN.msgtype), local(T.KNOWN.name), self._on_known,
                                                           topic_qos(T.KNOWN.name)),
            get("inputs_wait_s"), lambda missing: self.get_logger().warning(
                f"following {T.KNOWN.name} without a publisher of {missing} yet"))
        # a tick whose command is lost, or a controller gone quiet: released after command_wait_s
        wall_timer(self, 0.05, lambda: self._answer(self.command_wait.expire(time.monotonic())))
        p = self.planner
        self.get_logger().info(
            f"margin {p.margin}, force quantile {p.force_quantile if p.force_quantile is not None else 'none (the point plan)'}, "
            f"d_max {p.d_max_m} m, cut speed {p.cut_speed_m_s} m/s, "
            f"residual {'on' if p.include_residual else 'off'}, "
            f"sensor anchor {'on (' + T.BLADE_FORCE.name + ')' if p.anchor.sensor else 'off'}"
            f"{' (no effect without a force quantile)' if p.anchor.sensor and p.force_quantile is None else ''}, physics "
            f"{physics_text(p.terms)}, bound law {error_law_text(p.bound_law) if p.bound_law else 'model_std_* of the estimate'}"
            f"{self._physics_pending()}, "
            f"depth schedule {self.schedule.settings}; "
            f"{T.ESTIMATE.name} + {T.KNOWN.name} -> {T.PLAN.name}, {T.TARGET_DEPTH.name}")

    # ------------------------------------------------------------------ parameters
    def _on_set_parameters(self, params) -> SetParametersResult:
        """Validate everything first, then apply together (a rejected change alters nothing)."""
        changes = {p.name: p.value for p in params}
        if fixed := sorted(set(changes) & START_ONLY):  # (they were taken, unchecked, and changed nothing)
            return SetParametersResult(successful=False, reason=f"{fixed} can only be set at start-up")
        try:
            planner = from_parameters({**self.planner.settings(),
                                       **{name: changes[name] for name in PLANNER_SETTINGS if name in changes}})
            period = check_log_period(changes.get("log_period_s", self.log_period_ns / M.NS_PER_S))
            wait_s = check_command_wait(changes.get("command_wait_s", self.command_wait.max_wait_s))
            current = self.schedule.settings.to_dict()
            schedule = schedule_settings({p: changes.get(p, current[f]) for p, f in SCHEDULE_PARAMETERS.items()})
            check_target_floor(planner, schedule)
            follow = check_switch("follow_estimator_physics", changes.get("follow_estimator_physics", self.follow_physics))
            follow_speed = check_switch("follow_episode_speed", changes.get("follow_episode_speed", self.follow_speed))
        except ValueError as err:
            return SetParametersResult(successful=False, reason=str(err))
        planner.keep_evidence_of(self.planner)  # new settings are no new cut
        self.planner = planner
        for name in PHYSICS_SETTINGS:
            if name in changes:  # the user's choice now ([]: the estimator's again, where it is followed)
                self.own_physics[name] = planner.settings()[name]
        self.follow_physics = follow
        self.follow_speed = follow_speed
        self.schedule.settings = schedule
        self.log_period_ns = int(period * M.NS_PER_S)
        self.command_wait.max_wait_s = wait_s
        shown = {name: list(v) if hasattr(v, "__len__") and not isinstance(v, str) else v for name, v in changes.items()}
        self.get_logger().info("parameters now " + ", ".join(f"{name}={short_repr(v)}" for name, v in shown.items()))
        if {*PHYSICS_SETTINGS, "follow_estimator_physics"} & set(changes):
            self._take_physics()
        return SetParametersResult(successful=True)

    def _physics_pending(self) -> str:
        """What the start line adds while the estimator's physics may still fill what was not given."""
        if not self.follow_physics or all(self.own_physics.values()):
            return ""
        return f" until the estimator says its own ({G.ESTIMATOR_PHYSICS_TOPIC})"

    def _on_physics(self, msg) -> None:
        """The estimator's posterior physics (latched): plan with it where the user gave none. One
        the planner cannot plan with (a layout, a term or a law it refuses) is said and changes
        nothing: the physics heard before stays (it had fallen back to the FEE alone)."""
        try:
            heard = G.EstimatorPhysics.from_json(msg.data)
            choice = planning_physics(self.own_physics["terms"], self.own_physics["bound_law"], heard, True)
            from_parameters({**self.planner.settings(), "terms": term_texts(choice.terms),
                             "bound_law": list(choice.bound_law)})
        except ValueError as err:
            self._warn(f"physics:refused:{err}", f"{G.ESTIMATOR_PHYSICS_TOPIC}: {err}; not taken, the plans' physics "
                                                 "stays as it was")
            return
        self.announced = heard
        self._take_physics()

    def _take_physics(self) -> None:
        """The planner's terms and bound law from the user's and the estimator's (``planning_physics``);
        a change is said, and the next plan is made with it (the cut's evidence kept)."""
        choice = planning_physics(self.own_physics["terms"], self.own_physics["bound_law"], self.announced,
                                  self.follow_physics)
        for note in choice.notes:
            self._warn(f"physics:{note}", note)
        current = self.planner.settings()
        wanted = {"terms": term_texts(choice.terms), "bound_law": list(choice.bound_law)}
        if all(current[name] == wanted[name] for name in PHYSICS_SETTINGS):
            return
        planner = from_parameters({**current, **wanted})  # (checked as it was heard, ``_on_physics``)
        planner.keep_evidence_of(self.planner)
        self.planner = planner
        def whose(name: str) -> str:
            return "given" if self.own_physics[name] else "the estimator's" if choice.adopted else "none given"

        self.get_logger().info(
            f"plans read the posterior through {physics_text(planner.terms)} ({whose('terms')}), bound law "
            f"{error_law_text(planner.bound_law) if planner.bound_law else 'model_std_* of the estimate'} "
            f"({whose('bound_law')})" + (f"; the estimator's from {self.announced.source}" if choice.adopted else ""))

    # ------------------------------------------------------------------ callbacks
    def _on_status(self, msg) -> None:
        """A new episode is a new cut from its first estimate on, not from its episode_start: an
        estimator behind (a replay of bags in a row faster than it) still sends the last episode's
        estimates, which are planned and published as that episode's; had the cut started at the
        event, they were dropped as the previous cut's, and a replay at 8x published no plan after
        its first episode (an outside tester's). A start with no cut under way, or none of whose
        estimates came (an estimator not there: nothing of it is due), or at or before the cut under
        way (time went back: a replay started over) starts the cut at once; while other starts are
        held, it is held behind them (``_start_ahead``)."""
        event = followed_status_event(msg.data, self._warn, self.follower, self.silence)
        if event is not None and event.event == G.EVENT_EPISODE_START:
            self.silence.start(event.name)
            if self.starts_ahead and same_episode(event, self.starts_ahead[-1][0]):
                return  # (the start held last, come again)
            if self.starts_ahead or self._estimates_still_due(event.first_stamp_ns):
                # held behind the others, in order: one at or before the cut under way (a replay started
                # over) starts once an estimate goes back to it (``_start_ahead``)
                self.starts_ahead.append([event, None])
                while len(self.starts_ahead) > MAX_STARTS_AHEAD:  # (an estimator this far behind: start the oldest)
                    self._start_cut(*self.starts_ahead.popleft(), ahead=True)
            else:
                self._start_cut(event, None, ahead=False)
        elif event is not None:
            if self.starts_ahead and event.first_stamp_ns == self.starts_ahead[-1][0].first_stamp_ns:
                self.starts_ahead[-1][1] = event.last_stamp_ns  # (its cut has not started: said when it does)
            elif event.last_stamp_ns >= 0 and self.cut_first_ns is not None:  # (-1: it published no tick)
                self.cut_end_ns = event.last_stamp_ns
            self.silence.end()

    def _estimates_still_due(self, first_stamp_ns: int) -> bool:
        """Whether the cut under way has estimates still to come before a new episode's first tick
        ``first_stamp_ns``: some of its ticks were estimated, not its last, and time goes forward."""
        newest, first, end = self.cut_newest_ns, self.cut_first_ns, self.cut_end_ns
        return (first is not None and newest is not None and first <= newest < first_stamp_ns
                and (end is None or newest < end))

    def _start_ahead(self, stamp: int) -> None:
        """Start the held cut whose episode the estimate at ``stamp`` is of, and those held before it.
        An estimate beyond every held episode is a stray's (one an hour ahead had started them all, and
        the late estimates of the cut under way were dropped again, a reviewer's); one held at or
        before the cut under way (a replay started over) starts once an estimate comes at or before the
        newest of the cuts so far (``timeline_newest_ns``): time went back. (Before the cut under way's
        newest: a cut of one estimate, at its first tick, never let it start; and a cut started early
        with none yet, at ``MAX_STARTS_AHEAD``, is still owed the previous cut's late estimates, which
        are no replay's, a reviewer's. A replay the estimator skipped into then, its stamps those of
        cuts still owed theirs, is planned in the cuts of those stamps: nothing tells them apart.)"""
        for i, (event, last) in enumerate(self.starts_ahead):
            first, end = event.first_stamp_ns, episode_end_ns(event, last)
            back = self.cut_first_ns is not None and first <= self.cut_first_ns
            if first <= stamp <= end and (not back or (self.timeline_newest_ns is not None
                                                       and stamp <= self.timeline_newest_ns)):
                for _ in range(i):  # (held before it: episodes none of whose estimates came, or strays: dropped,
                    self.starts_ahead.popleft()  # started they had cleared this one's commands and forces)
                self.starts_ahead.popleft()
                self._start_cut(event, last, ahead=not back, back=back)
                return

    def _start_cut(self, event: G.EpisodeEvent, last_stamp_ns: int | None, ahead: bool, back: bool = False) -> None:
        """The cut of the episode ``event`` starts (``last_stamp_ns``: its end's last tick, if heard;
        ``ahead``: taken ahead of its estimates, so its ticks' commands and forces may be in already;
        ``back``: held, at or before the cut before it (a replay started over): those near its first
        tick are kept, as where time jumps (all had been cleared, a reviewer's))."""
        self._answer(self.command_wait.drain())  # the last episode's ticks, before its cut ends
        self.lockstep = event.pacing == G.PACING_LOCKSTEP
        if self.follow_speed and event.meta.target_speed_m_s != self.planner.cut_speed_m_s:
            # the cut's speed (the controller's target): the stall memory counts a stall where v_x
            # falls below 80 % of the planned speed, and planned at 0.5 m/s, a cut at 0.35 m/s,
            # never reaching 0.4 m/s, counted none, and one at 0.45 m/s one at every dip below 0.4
            result = self.set_parameters([Parameter("cut_speed_m_s", value=float(event.meta.target_speed_m_s))])
            if not all(r.successful for r in result):
                self._warn("speed", f"episode {event.name}: its target speed is not planned at: "
                                    f"{[r.reason for r in result]}")
        if back:
            self._new_cut(event.first_stamp_ns)
        else:
            self._new_cut(keep_from_ns=event.first_stamp_ns if ahead else None)
        self._follow_cut(event, last_stamp_ns)
        self.joiner.start_at(event.first_stamp_ns)

    def _follow_cut(self, event: G.EpisodeEvent, last_stamp_ns: int | None) -> None:
        """The episode whose estimates the cut under way plans: its range, none of its estimates yet."""
        before = self.cut_first_ns
        self.cut_first_ns, self.cut_newest_ns = event.first_stamp_ns, None
        if self.timeline_newest_ns is not None and event.first_stamp_ns <= self.timeline_newest_ns:
            self.timeline_newest_ns = None  # (time went back: the newest is the new timeline's)
        self.cut_end_ns = episode_end_ns(event, last_stamp_ns)
        # the Θ_k stamps heard so far go on counting where they are the new cut's (its ticks come before
        # the estimate that starts it, time going forward), else the count starts afresh with it
        ahead = before is None or before < self.cut_first_ns
        if self.cut_known_ns is not None and not (ahead and self.cut_first_ns <= self.cut_known_ns <= self.cut_end_ns):
            if self.known_jump is not None:  # (the last cut's hole, the stamp after it never heard: counted)
                self._count_missed(*self.known_jump)
            self.cut_known_ns, self.known_jump = None, None

    def _new_cut(self, at_stamp_ns: int | None = None, keep_from_ns: int | None = None) -> None:
        """A new cut: the schedule back to its start depth, no plan carried over. ``at_stamp_ns``:
        the first stamp of the new cut when time jumped to it: the commands and forces of its ticks,
        which come before their estimates, are kept (the old cut's are far from it). ``keep_from_ns``:
        the first stamp of a cut started ahead of its estimates: its ticks' commands and forces, in
        already, are kept (those of the cut before are older)."""
        self.schedule.reset()
        self.planner.forget()
        self._target_sent = None
        self._jumped_to = None
        for by_stamp in (self.commanded, self.measured):
            for stamp in [s for s in by_stamp if (s < keep_from_ns if keep_from_ns is not None else
                                                  at_stamp_ns is None or abs(s - at_stamp_ns) > NEW_CUT_GAP_NS)]:
                del by_stamp[stamp]
        newest = self.command_wait.newest_command_ns
        if keep_from_ns is None or newest is None or newest < keep_from_ns:
            self.command_wait.forget_commands()
        # the controller's writer followed afresh: in a replay of bags in a row the ticks start again
        # at 0, where its track (hundreds of ticks, never forgotten: its last tick lies ahead) led over
        # the same writer's new messages, whose commands were dropped until they outnumbered the old
        # ones (an outside tester: the second bag's plans anchored otherwise from 5 s on)
        self.command_writer = WriterTracks(forget_after_ticks=FORGET_WRITER_AFTER_TICKS)

    def _on_blade_cmd(self, msg, sequence: int | None = None) -> None:
        """The depth the controller commands for a tick, −u_za: only its writer's, the one that
        answers every tick (``writer_identity``, as the simulator's command gate follows it)."""
        try:
            stamp, values = M.parse_labelled(msg, T.BLADE_CMD.labels, T.BLADE_CMD.name)
        except ValueError as err:
            self._warn("blade_cmd:layout", f"{err}; ignored")
            return
        u_za = float(values[T.BLADE_CMD.labels.index("u_za")])
        if not self.command_writer.leads(self.command_writer.observe(sequence, tick_number(stamp))):
            return
        if not math.isfinite(u_za) or (stamp in self.commanded and sequence is None):
            return  # (without sequence numbers the first command of a stamp counts)
        _keep_by_stamp(self.commanded, stamp, -u_za)
        self._answer(self.command_wait.command(stamp, time.monotonic()))

    def _on_blade_force(self, msg) -> None:
        """The blade's measured force of a tick, kept by stamp until its estimate is planned."""
        try:
            stamp, values = M.parse_message(T.BLADE_FORCE.name, msg)
        except ValueError as err:
            self._warn("blade_force:layout", f"{err}; ignored")
            return
        if not M.plausible_values(values, subnormal=True):
            self._warn("blade_force:implausible", f"{T.BLADE_FORCE.name} at stamp {stamp} ns: force="
                                                  f"{values.tolist()} N is not a force the blade can measure; "
                                                  "that tick is anchored to F̂ alone")
            self.measured.pop(stamp, None)
            return
        _keep_by_stamp(self.measured, stamp, (float(values[0]), float(values[1])))

    def _on_known(self, msg) -> None:
        try:
            stamp, values = M.parse_labelled(msg, KNOWN_PARAMS, T.KNOWN.name)
        except ValueError as err:
            self._warn("known:layout", f"{err}; ignored")
            return
        self._note_known(stamp)
        self._join(T.KNOWN.name, stamp, fields(values, KNOWN_PARAMS))

    def _note_known(self, stamp: int) -> None:
        """Θ_k comes every tick: a hole between two of the cut under way's is ticks this node never
        heard, counted and said. Why: a planner behind its inputs (a replay at 8x into a planner
        started by hand) lost hundreds of ticks from its reader's history of 2 s, and its summary
        said 4 estimates unpaired (an outside tester's). Counted once the stamp after the hole
        follows it: a single stray stamp far ahead, the stream then going on from before it, is no
        hole (and hides none, a reviewer's); not across cuts (bags whose stamps restart, a replay
        started over), nor for ticks of a cut held behind the one under way (they are counted by
        no cut: a known gap)."""
        first, end = self.cut_first_ns, self.cut_end_ns
        if first is None or stamp < first or (end is not None and stamp > end):
            return
        if self.known_jump is not None:
            before, after = self.known_jump
            if stamp <= before or stamp == after:
                return  # (late, or a copy)
            self.known_jump = None
            if stamp > after:  # the stream goes on past the hole: it was one
                self._count_missed(before, after)
            elif stamp < after:  # it goes on from before the stamp that jumped: that one was a stray's
                self.cut_known_ns = before
        last = self.cut_known_ns
        if last is None or stamp > last:
            if last is not None and round((stamp - last) / TICK_PERIOD_NS) > 1:
                self.known_jump = (last, stamp)
            self.cut_known_ns = stamp

    def _count_missed(self, before: int, after: int) -> None:
        """The ticks between Θ_k stamps ``before`` and ``after`` never came: counted and said."""
        missed = round((after - before) / TICK_PERIOD_NS) - 1
        self.missed += missed
        depth = G.TOPIC_QOS.get(T.KNOWN.name, G.DATA_QOS).depth
        self._warn("known:missed", f"{missed} tick(s) of {T.KNOWN.name} never heard before stamp {after} ns: they get "
                                   "no plan (a planner behind its inputs, e.g. a replay faster than it plans, loses "
                                   f"what its reader's history of {depth} messages no longer holds)")

    def _on_estimate(self, msg) -> None:
        self.silence.heard()
        try:
            stamp, values = M.parse_labelled(msg, T.ESTIMATE_FIELDS, T.ESTIMATE.name)
        except ValueError as err:
            self._warn("estimate:layout", f"{err}; ignored")
            return
        self._note_estimate(stamp)
        est = fields(values, T.ESTIMATE_FIELDS)
        fused = self.planner.plans_fused(est)
        if est["valid"] == 0.0 and not fused:  # nothing to plan from yet: say so for this tick, no Θ_k needed
            self._answer(self.command_wait.offer(stamp, (est, None), time.monotonic()))
            return
        self._join(T.ESTIMATE.name, stamp, est)

    def _note_estimate(self, stamp: int) -> None:
        """An estimate at ``stamp`` came: it may start a held cut, and counts as its cut's newest."""
        self._start_ahead(stamp)
        if self.cut_first_ns is not None and self.cut_first_ns <= stamp <= (self.cut_end_ns or stamp):
            self.cut_newest_ns = max(stamp, self.cut_newest_ns or stamp)  # (a stray beyond the cut is not of it)
            self.timeline_newest_ns = max(stamp, self.timeline_newest_ns or stamp)

    def _join(self, topic: str, stamp: int, payload: dict[str, float]) -> None:
        newest = self.joiner.last_ns
        verdict, out = self.joiner.offer(topic, stamp, payload)
        if verdict is Verdict.STALE and topic == T.ESTIMATE.name:
            if self.cut_first_ns is not None and stamp < self.cut_first_ns:
                self._previous_cut(stamp)
            else:
                self._warn("unpaired", f"{topic} at stamp {stamp} ns came after the plan of a newer tick ({newest} ns); "
                                       "dropped (again and again: a second publisher of it on this domain, e.g. a bag "
                                       "played beside a live estimator)")
        elif verdict is Verdict.RESTART:
            self._warn("restart", f"{topic}: stamps stayed behind the newest planned tick {newest} ns; following the "
                                  f"stream from stamp {stamp} ns")
            self._unfollow_episode()  # (time went back without a /sim/status: no episode of it is known)
        for joined in out:
            if joined.complete:
                item = (joined.parts[T.ESTIMATE.name], joined.parts[T.KNOWN.name])
                self._answer(self.command_wait.offer(joined.stamp_ns, item, time.monotonic()))
            elif T.ESTIMATE.name in joined.parts:  # (Θ_k alone: no estimate or an invalid one, answered at once)
                self.dropped += 1
                newest = self.joiner.newest_stamp_ns()
                behind = "" if newest is None else f" (estimates {(newest - joined.stamp_ns) / M.NS_PER_S:.1f} s behind it)"
                self._warn("unpaired", f"{T.ESTIMATE.name} at stamp {joined.stamp_ns} ns never got its "
                                       f"{T.KNOWN.name}{behind}; dropped")

    def _unfollow_episode(self) -> None:
        """The stream left the episode followed without a /sim/status (a replay of bags started over,
        ``--topics`` without it): its first tick no longer marks earlier ticks as the previous cut's
        (they had all been dropped from then on, an outside reviewer's)."""
        self.cut_first_ns = self.cut_end_ns = self.cut_newest_ns = self.timeline_newest_ns = None
        self.starts_ahead.clear()  # (episodes of the timeline left)

    def _previous_cut(self, stamp: int) -> None:
        """An estimate of a tick before the episode followed began: the previous episode's, come
        late (an estimator seconds behind); planned, it had moved the new cut's target and evidence."""
        self.previous_cut_ticks += 1
        self._warn("previous_cut", f"{T.ESTIMATE.name} at stamp {stamp} ns is of a tick before the episode under way "
                                   f"(its first tick {self.cut_first_ns} ns); not planned")

    def _answer(self, ticks: list[Waiting]) -> None:
        """Plan the ticks ``command_wait`` released, in order (Θ_k None: an invalid estimate,
        answered without a plan)."""
        for tick in ticks:
            est, known = tick.item
            if self.cut_first_ns is not None and tick.stamp_ns < self.cut_first_ns:
                self._previous_cut(tick.stamp_ns)  # (none of the episode followed: no plan, no target)
            elif known is None:
                self._publish(tick.stamp_ns, NO_PLAN_VALUES)
                self._target(tick.stamp_ns, None)
            else:
                self._plan(tick.stamp_ns, est, known)

    def _awaiting_physics(self) -> bool:
        """Whether the estimator's physics is on its way: followed, not all given, not heard yet, and
        a writer of it on the graph (its latched sample comes on matching, a moment after its other
        topics' may: a plan made meanwhile read θ through the FEE alone). Without a writer (a replay
        with no estimator) the plan goes on with what it has."""
        return (self.announced is None and self.follow_physics and not all(self.own_physics.values())
                and self.count_publishers(local(G.ESTIMATOR_PHYSICS_TOPIC)) > 0)

    def _plan(self, stamp: int, est: dict[str, float], known: dict[str, float]) -> None:
        if self._awaiting_physics():
            self._warn("physics:awaited", f"stamp {stamp} ns: the estimator's physics ({G.ESTIMATOR_PHYSICS_TOPIC}) is "
                                          "on its way; no plan until it is heard")
            self._publish(stamp, NO_PLAN_VALUES)
            self._target(stamp, None)
            return
        try:
            measured = self.measured.get(stamp)
            plan, new = self.planner.plan(est, known, self.commanded.get(stamp), measured)
            self.sensed += measured is not None and self.planner.plans_fused(est)
        except ValueError as err:
            self._warn(f"bad:{str(err).split('=')[0]}", f"stamp {stamp} ns: {err}; no plan published")
            self._target(stamp, None)
            return
        if plan is None:  # valid flag 0 was handled on arrival; kept for safety
            self._publish(stamp, NO_PLAN_VALUES)
            self._target(stamp, None)
            return
        published = self._publish(stamp, plan.values())
        self._target(stamp, plan.max_depth_m if published else None)  # a plan not published moves no target
        if not new:
            return
        if self.last_log_ns is None or stamp < self.last_log_ns or stamp - self.last_log_ns >= self.log_period_ns:
            self.last_log_ns = stamp
            self.get_logger().info(describe(plan, est, known, self.planner.sensor_gap_n))

    def _publish(self, stamp: int, values) -> bool:
        """Whether the plan ``values`` went out (never a non-finite one)."""
        values = np.asarray(values, dtype=np.float64)
        if not np.isfinite(values).all():  # should not happen (the core checks its inputs and forces); never let NaN out
            self._warn("non_finite_plan", f"plan at stamp {stamp} ns is not finite ({values.tolist()}); not published")
            return False
        self.plan_pub.publish(M.make_labelled(self.classes, stamp, T.PLAN_FIELDS, values))
        self.published += 1
        return True

    def _target(self, stamp: int, plan_depth_m: float | None) -> None:
        """The controller's target for this tick through the depth schedule (a new cut restarts it).
        A tick more than NEW_CUT_GAP_NS from the last one scheduled starts a new cut only once the
        next tick follows it there (time jumped: a replay started over, a restarted simulator); one
        stray message stamped 0 or an hour ahead had restarted the cut, its schedule and evidence,
        without a word (an outside tester's). Until then it moves no target. Estimates seconds apart
        (the estimator's ``stride`` over a second of ticks) are its pace, not a new cut each: had
        every one of them waited for a tick within a second of it, none would have come, and the
        planner published no target at all (``follows_at_its_pace``). The spacing is taken as the
        pace once a third tick comes at it: two strays seconds apart would otherwise set it, and the
        stream's own ticks, then behind the second, were dropped (a reviewer's)."""
        last = self.schedule.last_stamp_ns
        # (a tick more: stamps are whole ns of k/60 s, and two strides of 125 ticks measured 1 ns over 2 paces)
        new_cut_gap_ns = (max(NEW_CUT_GAP_NS, GAP_PACES * self._pace_ns + TICK_PERIOD_NS) if self._pace_ns
                          else NEW_CUT_GAP_NS)
        if last is not None and abs(stamp - last) > new_cut_gap_ns:
            # ahead within the episode followed: ticks lost (a loaded machine), the same cut
            gap = (stamp > last and self.cut_first_ns is not None and last >= self.cut_first_ns
                   and (self.cut_end_ns is None or stamp <= self.cut_end_ns))
            paced = self._jumped_to is not None and follows_at_its_pace(last, self._jumped_to, stamp)
            seen, self._pace_seen_ns = self._pace_seen_ns, (stamp - self._jumped_to) if paced else None
            if paced and seen is not None and abs(self._pace_seen_ns - seen) <= TICK_PERIOD_NS:
                self._pace_ns = self._pace_seen_ns  # the same cut, estimated this seldom
            elif paced:
                self._jumped_to = stamp  # (a spacing seen once: held, as the jump before it)
                return
            elif self._jumped_to is None or abs(stamp - self._jumped_to) > new_cut_gap_ns:
                # (at the estimates' pace, not a second: at a stride over 60 the tick after a jump is a stride on)
                self._jumped_to = stamp
                self._warn("jump", f"stamp {stamp} ns is {(stamp - last) / M.NS_PER_S:+.3g} s from the last tick "
                                   f"scheduled ({last} ns); no target for it (" + (
                                       "estimates lost? the cut goes on once the next tick follows it" if gap else
                                       "a new cut once the next tick follows it") + "; or estimates this far apart, "
                                   "an estimator stride over a second of ticks: its pace once the next one follows)")
                return
            elif not gap:  # (a gap keeps the cut's evidence and stall memory; the schedule backs off over it)
                self._new_cut(stamp)
                self._unfollow_episode()  # (a cut no /sim/status announced: none of the episode followed)
        elif last is not None and stamp <= last:
            return  # a tick that came after a newer one (its estimate waited for Θ_k): the schedule has moved on
        elif last is not None and stamp - last <= NEW_CUT_GAP_NS:
            self._pace_ns = None  # estimates within a second of each other again (the stride set lower)
        self._jumped_to = self._pace_seen_ns = None
        target = self.schedule.update(stamp, plan_depth_m)
        values = [target, plan_depth_m if plan_depth_m is not None else 0.0, float(self.schedule.plan_valid)]
        sent = self._target_sent
        if (not self.lockstep and sent is not None and stamp >= sent[0] and stamp - sent[0] < TARGET_HEARTBEAT_NS
                and abs(target - sent[1]) < TARGET_STEP_M and values[2] == sent[2]):
            return  # the controller's target has not moved: fewer messages on the 60 Hz loop's machine
        self._target_sent = (stamp, target, values[2])
        self.target_pub.publish(M.make_labelled(self.classes, stamp, T.TARGET_DEPTH_FIELDS, values))

    def close(self) -> None:
        if self.known_jump is not None:
            self._count_missed(*self.known_jump)
            self.known_jump = None
        unpaired = self.dropped + sum(T.ESTIMATE.name in joined.parts for joined in self.joiner.drain())
        unanswered = len(self.command_wait.drain(planned=False))
        self.get_logger().info(f"{self.published} plans published, {unpaired} estimates unpaired, "
                               f"{self.command_wait.waited} waited for their command, "
                               f"{self.command_wait.timed_out} planned without it, "
                               f"{self.sensed} fused with the blade's measured force"
                               f"{f', {unanswered} still waiting for it' if unanswered else ''}, "
                               f"{self.missed} ticks never heard")


def main(args: list[str] | None = None) -> int:
    return spin_node(PlannerNode, args, PARAMETERS, __doc__.splitlines()[0])


if __name__ == "__main__":
    raise SystemExit(main())
