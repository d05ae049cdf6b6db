"""`anti_stall_controller`: the Eq. 11-12 controller core as a ROS 2 node (thin adapter).

Subscribes to /chassis/twist (v_x^c) and /chassis/pose (p_z^c), pairs them by stamp, and
answers every state tick with /chassis/cmd_vel (u_x) and /blade/cmd (u_zr, u_za) stamped
with that tick, which is what the simulator's lockstep pacing waits for. Targets and
gains are parameters, validated and applied at run time (``ros2 param set``). On each
``episode_start`` on /sim/status the integrator resets and, with
``follow_episode_targets``, the targets become the episode's (and the parameters say so).
State with a stamp the graph cannot mean, or one implausibly far past the last answered
tick, is refused with a warning and changes nothing (``state_joiner``).

With ``depth_source`` ``planner`` the target depth d̄_z comes from /planner/target_depth (the
soil-aware planner's schedule) instead of the ``target_depth_m`` parameter: each answered tick
uses the newest planner target stamped no later than the tick (half a tick of rounding) if it is
within ``planner_timeout_s`` of it; without one (none yet this episode, the planner silent or its stamps far off) the
parameter's depth is the fallback, and the switch is logged. Once the planner has steered the
cut, a silent planner's fallback is taken at once where it is shallower and at most
``fallback_deepen_rate_m_s`` deeper per second (``planner_fallback``): a deeper one in one tick
had plunged the blade into soil the planner had just ruled out. Eq. 11's anti-stall lift acts on
top of whichever target is in effect: the planner chooses the depth, the controller still
saves the machine from a stall. In a lockstep episode (the simulator's episode_start says its
pacing) the controller keeps step with the planner (``plan_wait``): tick k is answered once the
planner's target for tick k − ``planner_lag_ticks`` has come, and cuts to that one, so the
closed loop does not depend on how fast the estimator and planner run (at most
``planner_wait_s`` of wall time per tick if the planner is silent). Following the planner from
the start, it subscribes to the state only once the planner's writer has matched (at most
``inputs_wait_s``), so a simulator waiting for its state readers waits for that match too.

With ``force_lift_m_s`` > 0 at start (the core's force lift, off by default) the controller
answers a tick once its twist, pose and /blade/force are all in: the blade rises with the force
beyond the machine's limits as well as with the speed error. It subscribes to /blade/force either
way, so that a lockstep simulator waits for that reader too (``graph.CONTROLLER_INPUTS``). Its
gain and share change at run time like the others; switching it on or off takes a restart (it
changes what a tick waits for: a switch between a tick's state and its force would leave that
tick unanswered, and a lockstep simulator waiting).
"""
from __future__ import annotations

import math
import time

from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import String

from soil_msgs_py import graph as G
from soil_msgs_py import messages as M
from soil_msgs_py import topics as T
from soil_msgs_py.params import (DEFAULT_TARGET_DEPTH_M, DEFAULT_TARGET_SPEED_M_S, FORCE_LIMITS_N, MACHINE,
                                 MAX_TARGET_DEPTH_M, MAX_TARGET_SPEED_M_S, MIN_TARGET_SPEED_M_S, SAMPLE_RATE_HZ,
                                 TICK_PERIOD_NS, beyond_lift_reach)
from soil_msgs_py.episode_follow import EpisodeFollower, same_episode
from soil_msgs_py.ros_adapter import (
    InputSilence, JoinAfterInputs, WarnLimiter, declare_parameters, followed_status_event, local, message_class,
    publisher_qos, spin_node, topic_qos, wall_timer,
)
from soil_msgs_py.stamp_join import RESTART_AFTER_REFUSED_TICKS, StampJoiner, Verdict, Why

from .controller import MAX_DITHER_AMPLITUDE_M, MAX_RATE_GAIN_M_S, MIN_DITHER_TICKS, AntiStallController, AntiStallGains
from .plan_wait import DEFAULT_LAG_TICKS, DEFAULT_WAIT_S, MAX_LAG_TICKS, PlanWait
from .planner_fallback import (DEFAULT_FALLBACK_DEEPEN_RATE_M_S, MAX_FALLBACK_DEEPEN_RATE_M_S, check_depth_source,
                               check_rate, fallback_depth)

_GAINS = AntiStallGains()
PARAMETERS: dict[str, tuple] = {
    "target_speed_m_s": (DEFAULT_TARGET_SPEED_M_S, f"desired forward speed v̄_x [m/s], in [{MIN_TARGET_SPEED_M_S:g}, {MAX_TARGET_SPEED_M_S:g}]"),
    "target_depth_m": (DEFAULT_TARGET_DEPTH_M, f"target cut depth d̄_z below the original surface [m], in [0, {MAX_TARGET_DEPTH_M:g}] "
                            "(the blade height)"),
    "k_v_m_s": (_GAINS.k_v_m_s, f"K_v: blade rise rate per unit relative velocity error [m/s] (Eq. 11), in [0, "
                                f"{MAX_RATE_GAIN_M_S:g}]; 0 = no anti-stall action"),
    "c_vx": (_GAINS.c_vx, "velocity-error threshold as a fraction of v̄_x (e_vmin = v̄_x c_vx), in [0, 1)"),
    "delta_d_max_m": (_GAINS.delta_d_max_m, "Δd̄_max: how far above the surface the blade may rise [m], in [0, "
                                            f"{MACHINE.blade_height_m:g}] (the blade height)"),
    "dither_amplitude_m": (_GAINS.dither_amplitude_m, "depth dither: amplitude A of a sinusoid added to the target "
                                                      f"depth [m], in [0, {MAX_DITHER_AMPLITUDE_M:g}]; 0 = off, a few cm when on"),
    "dither_period_s": (_GAINS.dither_period_s, "depth dither: period T of the sinusoid [s], at least "
                                                f"{MIN_DITHER_TICKS} control periods ({MIN_DITHER_TICKS / SAMPLE_RATE_HZ:g} s)"),
    "follow_episode_targets": (True, "take v̄_x and d̄_z from each episode_start on /sim/status"),
    "depth_source": ("parameter", "where d̄_z comes from: 'parameter' (target_depth_m) or 'planner' "
                                  "(/planner/target_depth; target_depth_m the fallback)"),
    "planner_timeout_s": (1.0, "a planner target counts for ticks within this much simulation time of its stamp [s], > 0"),
    "fallback_deepen_rate_m_s": (DEFAULT_FALLBACK_DEEPEN_RATE_M_S,
                                 "when a planner that steered the cut falls silent, the target moves from its last "
                                 "plan to target_depth_m: at once if that is shallower, else at most this much deeper "
                                 f"per second of simulation time [m/s], in (0, {MAX_FALLBACK_DEEPEN_RATE_M_S:g}]"),
    "planner_lag_ticks": (DEFAULT_LAG_TICKS, "lockstep with depth_source planner: tick k is answered once the planner's "
                                             f"target for tick k - lag came, and cuts to it, [0, {MAX_LAG_TICKS}] and "
                                             "within planner_timeout_s (0: never wait)"),
    "planner_wait_s": (DEFAULT_WAIT_S, "lockstep: the longest a tick waits for its planner target [s of wall time], "
                                       "(0, 60]; then it is answered with the target there is. Keep it below the "
                                       f"simulator's lockstep_timeout_s ({G.LOCKSTEP_TIMEOUT_S:g} s), which ends an "
                                       "episode whose tick "
                                       "is not answered"),
    "graph_id": G.FOLLOWED_GRAPH_ID_PARAMETER,
    "inputs_wait_s": (G.INPUTS_WAIT_S, "with depth_source planner at start: subscribe to the state once the "
                                       f"planner's target has a publisher, or after this long [s], [0, {G.MAX_WAIT_S:g}] "
                                       "(0: at once), so a simulator waiting for this node starts no episode before the "
                                       "controller can hear the planner"),
    "force_lift_m_s": (_GAINS.force_lift_m_s, "force lift: blade rise rate per unit of force share above "
                                              f"force_lift_share [m/s], in [0, {MAX_RATE_GAIN_M_S:g}]; 0 = off (Eq. 11 alone), else "
                                              "/blade/force is joined with the state by stamp"),
    "force_lift_share": (_GAINS.force_lift_share, "force lift: the share of the machine's force limits "
                                                  f"({FORCE_LIMITS_N[0] / 1e3:g} kN x, {FORCE_LIMITS_N[1] / 1e3:g} kN z) "
                                                  "above which the blade rises, > 0"),
}
GAIN_FIELDS = ("k_v_m_s", "c_vx", "delta_d_max_m", "dither_amplitude_m", "dither_period_s", "force_lift_m_s",
               "force_lift_share")
TARGET_FIELDS = ("target_speed_m_s", "target_depth_m")
MAX_PENDING_STAMPS = 2 * SAMPLE_RATE_HZ  # 2 s of unpaired state samples
# How far past the last answered tick a state stamp is still plausible (ticks lost on the way),
# and how many refused messages in a row (twist and pose of this many ticks) mean the
# simulation time really jumped rather than one stray pair arrived.
MAX_AHEAD_TICKS = SAMPLE_RATE_HZ
MAX_PLANNER_DEPTH_M = MACHINE.blade_height_m  # a planner target deeper than the blade is not a cut


# What the controller reads of each state topic: (column(s) of its parsed values, the field as a
# warning names it, how a tick whose value is not plausible is answered). /chassis/twist carries
# (v_x^c, v_z^c), /chassis/pose (p_x^c, p_z^c), /blade/force (F_x, F_z).
STATE_VALUES = {
    T.CHASSIS_TWIST.name: (0, "v_x^c (linear.x)", "with the controller holding its state"),
    T.CHASSIS_POSE.name: (1, "p_z^c (point.z)", "with the controller holding its state"),
    T.BLADE_FORCE.name: ((0, 1), "(F_x, F_z)", "without the force lift"),
}


def state_topics(force_lift: bool) -> tuple[str, ...]:
    """What one tick's answer waits for: twist and pose, and the blade force with the force lift on."""
    return G.CONTROLLER_STATE_TOPICS + ((T.BLADE_FORCE.name,) if force_lift else ())


def state_joiner(force_lift: bool = False) -> StampJoiner:
    """One tick's twist and pose (and force, ``state_topics``), answered as soon as all are in;
    an older tick still missing one of them is skipped (the controller answers the newest
    state). A stamp more than ``MAX_AHEAD_TICKS`` past the last answered tick is refused: one
    pair stamped in the far future (another node's, a corrupt one) must not become the last
    answered tick, after which every real tick would look stale. State refused for
    ``RESTART_AFTER_REFUSED_TICKS`` ticks in a row is followed from there on (time really
    jumped, or the pair answered before was the stray one): one pair silences the controller
    for at most that long."""
    topics = state_topics(force_lift)
    return StampJoiner(topics, max_pending=MAX_PENDING_STAMPS, max_ahead_ns=MAX_AHEAD_TICKS * TICK_PERIOD_NS,
                       restart_after_refused=len(topics) * RESTART_AFTER_REFUSED_TICKS)


class ControllerNode(Node):
    def __init__(self) -> None:
        super().__init__(G.NODE_NAMES["controller"])
        get = declare_parameters(self, PARAMETERS)
        gains = AntiStallGains(**{k: get(k) for k in GAIN_FIELDS})  # ValueError names the field
        self.core = AntiStallController(gains, get("target_speed_m_s"), get("target_depth_m"))
        self.follow = bool(get("follow_episode_targets"))
        self.depth_source, self.planner_timeout_ns = check_depth_source(get("depth_source"), get("planner_timeout_s"))
        self.core.dither_below_target = self.depth_source == "planner"  # the plan is the deepest cut allowed
        self.param_depth_m = float(get("target_depth_m"))  # the parameter's d̄_z (the planner's fallback)
        self.plan_wait = PlanWait(get("planner_lag_ticks"), get("planner_wait_s"),
                                  self.planner_timeout_ns / 1e9)  # ValueError names the field
        self.following_planner = False
        # switched from a planner that had steered the cut to the parameter's depth: a deeper one is
        # reached at the fallback rate, as from a silent planner (``_answer``)
        self.ramp_to_parameter = False
        self.fallback_rate_m_s = check_rate(get("fallback_deepen_rate_m_s"))
        self.planned = False  # a planner target steered a tick of this episode (the fallback then ramps)
        self.last_answer_ns: int | None = None
        self.add_on_set_parameters_callback(self._on_set_parameters)

        self.classes = M.ros_message_classes()
        self.cmd_vel_pub = self.create_publisher(message_class(T.CMD_VEL.msgtype), local(T.CMD_VEL.name), publisher_qos(T.CMD_VEL.name))
        self.blade_pub = self.create_publisher(message_class(T.BLADE_CMD.msgtype), local(T.BLADE_CMD.name), publisher_qos(T.BLADE_CMD.name))
        # /sim/status first: the executor serves ready subscriptions in creation order, so an
        # episode_start that arrived with its tick 0 resets the controller before tick 0 is answered.
        self.create_subscription(String, local(G.SIM_STATUS_TOPIC), self._on_status, topic_qos(G.SIM_STATUS_TOPIC))
        target_sub = self.create_subscription(message_class(T.TARGET_DEPTH.msgtype), local(T.TARGET_DEPTH.name),
                                              self._on_planner_target, topic_qos(T.TARGET_DEPTH.name))
        self.joiner = state_joiner(self._force_lift)
        self._warn = WarnLimiter(self.get_logger())
        self.silence = InputSilence(self, "state from the simulator")
        self.follower = EpisodeFollower(get("graph_id"))  # a stray /sim/status event neither retargets nor stops it
        # Between an episode_end and the next episode_start, state is held (not answered), so
        # a tick 0 that overtook its episode_start is answered after the reset. None: not held.
        self.held: list[tuple[str, object]] | None = None
        # (first, last) stamp [ns] of the episode that ended: its own ticks that come after its
        # episode_end are answered, not held (``_on_state``). None: no episode ended since the last start.
        self.ended_ns: tuple[int, int] | None = None
        # an episode_start taken while the ended episode's last ticks were still to come: the episode
        # starts with its first tick (``_on_state``), the ended one's answered until then
        self.start_held: G.EpisodeEvent | None = None
        # The state readers (which a simulator waits for) once the planner's writer has matched
        # when following it (at most inputs_wait_s): matched late under load, a lockstep tick
        # waited planner_wait_s for the first targets, which had gone out before the match.
        following = self.depth_source == "planner"
        self.state_join = JoinAfterInputs(
            self, {T.TARGET_DEPTH.name: target_sub} if following else {}, self._subscribe_state,
            get("inputs_wait_s"), lambda missing: self.get_logger().warning(
                f"following the state without a publisher of {missing} yet (depth_source planner)"))
        self.get_logger().info(f"targets v={get('target_speed_m_s')} m/s d={get('target_depth_m')} m, gains {gains}")
        self._say_if_beyond_reach()
        if self._force_lift:
            self.get_logger().info(f"force lift on: each tick is answered once {', '.join(self.joiner.topics)} are in")
        wall_timer(self, 0.05, self._on_wait_timer)  # a silent planner holds a lockstep tick at most planner_wait_s

    def _say_if_beyond_reach(self) -> None:
        """Warn of a target deeper than the lift reaches, each depth once (episodes set it again and again)."""
        if note := beyond_lift_reach("target_depth_m", self.param_depth_m):
            self._warn(f"beyond_lift_reach {self.param_depth_m:g}", note)

    def _subscribe_state(self) -> None:
        for name in state_topics(True):  # the force reaches the join only with the force lift on
            self.create_subscription(message_class(T.TOPICS_BY_NAME[name].msgtype), local(name),
                                     lambda msg, n=name: self._on_state(n, msg), topic_qos(name))

    # ------------------------------------------------------------------ parameters
    def _on_set_parameters(self, params) -> SetParametersResult:
        """Validate everything first, then apply atomically (a rejected change alters nothing)."""
        changes = {p.name: p.value for p in params}
        if fixed := sorted({"inputs_wait_s", "graph_id"} & set(changes)):  # read once, at start (it was taken
            # unchecked and changed nothing)
            return SetParametersResult(successful=False, reason=f"{fixed} can only be set at start-up")
        try:
            source, timeout_ns = check_depth_source(
                changes.get("depth_source", self.depth_source),
                changes.get("planner_timeout_s", self.planner_timeout_ns / 1e9))
            gains = {k: changes[k] for k in GAIN_FIELDS if k in changes}
            new_gains = AntiStallGains(**{**{k: getattr(self.core.gains, k) for k in GAIN_FIELDS}, **gains})
            speed = changes.get("target_speed_m_s", self.core.target_speed_m_s[0])
            depth = changes.get("target_depth_m", self.param_depth_m)  # (the core's may be the planner's)
            AntiStallController(new_gains, speed, depth)  # validates targets
            lag = changes.get("planner_lag_ticks", self.plan_wait.lag_ticks)
            wait = changes.get("planner_wait_s", self.plan_wait.wait_s)
            PlanWait(lag, wait, timeout_ns / 1e9)  # validates them
            rate = check_rate(changes.get("fallback_deepen_rate_m_s", self.fallback_rate_m_s))
            if (new_gains.force_lift_m_s > 0.0) != self._force_lift:
                raise ValueError(
                    f"force_lift_m_s={new_gains.force_lift_m_s!r} would switch the force lift "
                    f"{'on' if new_gains.force_lift_m_s > 0.0 else 'off'}, which changes what a tick waits for: "
                    "restart the node with it (--ros-args -p force_lift_m_s:=G); while running, "
                    f"{'a value > 0' if self._force_lift else 'only 0'} is accepted")
        except (ValueError, TypeError) as err:
            return SetParametersResult(successful=False, reason=str(err))
        if gains:
            self.core.set_gains(new_gains)
        # leaving a planner that had steered the cut: its target was the deepest the plan allowed, and
        # the parameter's depth in one tick plunged the blade deeper (an outside reviewer's); ramped instead
        ramp = source != "planner" and (self.ramp_to_parameter or (self.depth_source == "planner" and self.planned))
        if any(k in changes for k in TARGET_FIELDS):  # following a planner, the core's depth is its (or the
            # fallback's on its way): a new target_depth_m is the fallback, reached as _depth_for moves there
            self.core.set_targets(speed, None if source == "planner" or ramp else depth)
            self.param_depth_m = float(depth)
            self._say_if_beyond_reach()
        self.plan_wait.set_lag(lag, wait)
        self.fallback_rate_m_s = rate
        ramping = self.ramp_to_parameter
        if source != self.depth_source:  # a switch takes effect at the next tick, from the parameter's depth
            if not ramp and not ramping:  # (else from where the blade is, towards it: ``_answer``, ``_depth_for``)
                self.core.set_targets(target_depth_m=self.param_depth_m)
            self.plan_wait.targets.clear()
            self.following_planner = False
            # back to the planner mid-ramp: until its first target, on from the ramp's depth at the fallback
            # rate (a planner that had steered), not the parameter's depth at once
            self.planned = source == "planner" and ramping
        self.ramp_to_parameter = ramp
        self.depth_source, self.planner_timeout_ns = source, timeout_ns
        # the dither stays below the target while a planner's ceiling (or the ramp from it) holds the cut;
        # switched off there at once it had stepped the depth A deeper (an outside reviewer's)
        self.core.dither_below_target = source == "planner" or ramp or self.core.dither_below_target
        if source != "planner":  # ticks held for the planner are answered now: in lockstep no next tick
            for held in self.plan_wait.drain():  # comes to release them until they are
                self._answer(*held)
        if "follow_episode_targets" in changes:
            self.follow = bool(changes["follow_episode_targets"])
        return SetParametersResult(successful=True)

    @property
    def _force_lift(self) -> bool:
        return self.core.gains.force_lift_m_s > 0.0

    def _on_status(self, msg: String) -> None:
        event = followed_status_event(msg.data, self._warn, self.follower, self.silence)
        if event is None:
            return
        if self.start_held is not None and same_episode(event, self.start_held):
            return  # (the held start again)
        if self.start_held is not None:  # (an event more before any tick of the held episode: it starts now)
            self._start_episode(self.start_held)
        if event.event == G.EVENT_EPISODE_END:
            for held in self.plan_wait.end_episode():  # the episode is over: nothing waits
                self._answer(*held)
            self.held = []
            self.ended_ns = (event.first_stamp_ns, event.last_stamp_ns)
            self.silence.end()
            return
        self.silence.start(event.name)
        if (self.ended_ns is not None and self.joiner.last_ns < self.ended_ns[1] < event.first_stamp_ns
                and not any((s := self._stamp_of(*m)) is not None and s >= event.first_stamp_ns for m in self.held or ())):
            # the ended episode's last ticks are still to come (taken after both events: the executor
            # serves /sim/status first): answered with its state, this episode starting at its first
            # tick (or once the ended one is answered to its last)
            self.start_held = event
            return
        self._start_episode(event)

    def _start_episode(self, event: G.EpisodeEvent) -> None:
        """Targets, core, plan wait and state join start afresh with the episode ``event``."""
        self.start_held = None
        # a new cut: no ramp from the last one's planner carries over (under way, it had kept the episode's
        # own depth out of the core for the whole episode: an outside reviewer's)
        self.ramp_to_parameter = self.planned = False
        self.core.dither_below_target = self.depth_source == "planner"
        if self.follow:
            result = self.set_parameters([
                Parameter("target_speed_m_s", value=float(event.meta.target_speed_m_s)),
                Parameter("target_depth_m", value=float(event.meta.target_depth_m)),
            ])
            if not all(r.successful for r in result):
                self._warn("targets", f"episode {event.name}: targets refused: {[r.reason for r in result]}")
        self.core.reset()
        # the previous cut's plan does not carry over (nor its held ticks: the reset core must not step
        # on them); in lockstep the controller keeps step with the planner
        self.plan_wait.start_episode(event.first_stamp_ns, event.pacing == G.PACING_LOCKSTEP)
        self.following_planner = False  # (planned and ramp_to_parameter: cleared above, before the targets)
        self.last_answer_ns = None
        self.core.set_targets(target_depth_m=self.param_depth_m)  # (the planner's fallback, or the depth itself)
        self.joiner.reset(event.first_stamp_ns)
        self.get_logger().info(f"episode {event.name}: reset, targets v={self.core.target_speed_m_s[0]} m/s "
                               f"d={self.core.target_depth_m[0]} m")
        held, self.held, self.ended_ns = self.held or [], None, None
        for topic, msg in held:  # state of this episode that arrived before its start
            self._on_state(topic, msg)

    # ------------------------------------------------------------------ control
    def _of_ended_episode(self, stamp: int | None) -> bool:
        """Whether the tick stamped ``stamp`` is of the episode that just ended, not answered yet. The executor
        serves /sim/status before the state topics, so a controller a few ticks behind took the
        episode_end before the episode's last ticks; held for the next episode, they were then
        dropped as stale, and the bag lacked their commands (an outside tester's: 350 of 360 at
        --rate 4 under load). Ticks at or before the last answered are not: in bags whose stamps
        restart, the next bag's first ticks, come before its start (a reviewer's)."""
        return (self.ended_ns is not None and stamp is not None
                and max(self.ended_ns[0], self.joiner.last_ns + 1) <= stamp <= self.ended_ns[1])

    def _stamp_of(self, topic: str, msg) -> int | None:
        """``msg``'s stamp [ns] (None: a layout or stamp the graph cannot mean, said once it is handled)."""
        try:
            return M.parse_message(topic, msg)[0]
        except ValueError:
            return None

    def _on_state(self, topic: str, msg) -> None:
        self._take_state(topic, msg)
        if self.start_held is not None and self.ended_ns is not None and self.joiner.last_ns >= self.ended_ns[1]:
            self._start_episode(self.start_held)  # the ended episode answered to its last tick

    def _take_state(self, topic: str, msg) -> None:
        self.silence.heard()
        if topic not in self.joiner.topics:  # the force, with the force lift off
            return
        # between episodes only (mid-episode neither is set, and nothing more is parsed here)
        stamp = self._stamp_of(topic, msg) if self.start_held is not None or self.held is not None else None
        ended = self._of_ended_episode(stamp)
        if self.start_held is not None and not ended and stamp is not None and stamp >= self.start_held.first_stamp_ns:
            self._start_episode(self.start_held)  # its first tick: the held episode starts
        if self.held is not None and not ended:
            most = len(self.joiner.topics) * MAX_PENDING_STAMPS
            if len(self.held) < most:
                self.held.append((topic, msg))
            else:
                self._warn("held", f"{topic}: state between episodes beyond {most} held "
                                   "messages dropped (no episode_start came)")
            return
        try:
            stamp, values = M.parse_message(topic, msg)
        except ValueError as err:
            self._warn(f"{topic}:layout", f"{err}; ignored")
            return
        columns, field, answered = STATE_VALUES[topic]
        value = float(values[columns]) if isinstance(columns, int) else tuple(float(values[c]) for c in columns)
        # a value that is not finite or implausible goes on as NaN: the tick is still answered (a
        # lockstep simulator waits for it), the core holding its state for it (a NaN force: no force
        # lift that tick); a finite 1e300 pose had raised the blade to its stop without a word
        implausible = None if M.plausible_values(value, subnormal=True) else value
        if implausible is not None:
            value = math.nan if isinstance(columns, int) else (math.nan,) * len(columns)
        last = self.joiner.last_ns
        verdict, out = self.joiner.offer(topic, stamp, value)
        if verdict is Verdict.STALE:
            self._warn(f"{topic}:stale", f"{topic}: stamp {stamp} ns is not newer than the last answered tick "
                                         f"{last} ns; ignored")
            return
        if verdict is Verdict.FUTURE:
            self._warn(f"{topic}:future", f"{topic}: stamp {stamp} ns is more than {MAX_AHEAD_TICKS} ticks in the "
                                          f"future of the last answered tick {last} ns; ignored")
            return
        if verdict is Verdict.RESTART:
            self._warn("restart", f"{topic}: state stamps stayed away from the last answered tick {last} ns; "
                                  f"following the stream from stamp {stamp} ns")
        if implausible is not None:  # (taken: a refused message said so above)
            self._warn(f"{topic}:implausible", f"{topic}: {field}={implausible!r} at stamp {stamp} ns is not finite or "
                                               f"is beyond ±{M.PLAUSIBLE_ABS_LIMIT:g}; that tick is answered "
                                               f"{answered}")
        for joined in out:
            if joined.complete:
                self._tick((joined.stamp_ns, joined.parts[T.CHASSIS_TWIST.name], joined.parts[T.CHASSIS_POSE.name],
                            joined.parts.get(T.BLADE_FORCE.name)))
            else:
                fate = "dropped" if joined.why is Why.EVICTED else "skipped"
                self._warn("unpaired", f"state at stamp {joined.stamp_ns} ns never got all of "
                                       f"{', '.join(self.joiner.topics)}; {fate}")

    def _on_planner_target(self, msg) -> None:
        try:
            stamp, values = M.parse_labelled(msg, T.TARGET_DEPTH_FIELDS, T.TARGET_DEPTH.name)
        except ValueError as err:
            self._warn("planner:layout", f"{err}; ignored")
            return
        depth = float(values[0])
        if not 0.0 <= depth <= MAX_PLANNER_DEPTH_M:  # (NaN fails too)
            self._warn(f"planner:value:{'nan' if depth != depth else 'range'}",
                       f"{T.TARGET_DEPTH.name}: target_depth_m={depth!r} outside "
                                        f"[0, {MAX_PLANNER_DEPTH_M}] m; ignored")
            return
        before = self.plan_wait.targets.get(stamp)
        if before is not None and before != depth:  # (a planner plans each stamp once)
            self._warn("planner:twice", f"{T.TARGET_DEPTH.name}: two targets for stamp {stamp} ns ({before:.4f} m, "
                                        f"then {depth:.4f} m): is a second planner publishing on this domain? The "
                                        "controller follows whichever came last")
        if not self.plan_wait.note_target(stamp, depth):
            self._warn("planner:stale", f"{T.TARGET_DEPTH.name}: stamp {stamp} ns is before this episode's first "
                                        f"tick {self.plan_wait.first_stamp_ns} ns: a late target of an earlier "
                                        "episode, whose ticks are answered already, harmless at an episode's "
                                        "boundary (a planner behind); if it goes on, the planner's stamps are "
                                        "not this episode's; ignored")
            return
        self._answer_released(*self.plan_wait.release(time.monotonic()))

    def _tick(self, item: tuple) -> None:
        """A tick whose state is in: answered now, or (lockstep, following the planner) once its plan came."""
        if self.depth_source != "planner":  # (nothing is held then: a switch away answers held ticks)
            self._answer(*item)
            return
        self._answer_released(*self.plan_wait.offer(item[0], item, time.monotonic()))

    def _on_wait_timer(self) -> None:
        if self.plan_wait.pending:
            self._answer_released(*self.plan_wait.release(time.monotonic()))

    def _answer_released(self, items: list, late: int) -> None:
        if late:
            self._warn("planner:late", f"a lockstep tick answered without its planner target after "
                                       f"{self.plan_wait.wait_s:g} s of waiting (planner_wait_s): the planner is "
                                       "silent, ticks do not wait for it until its next target")
        for item in items:
            self._answer(*item)

    def _depth_for(self, stamp: int) -> float:
        """d̄_z for the tick at ``stamp``: the planner's target if it is recent enough, else the parameter's."""
        if self.depth_source != "planner":
            return self.param_depth_m
        target = self.plan_wait.target_for(stamp)
        fresh = target is not None and abs(stamp - target[0]) <= self.planner_timeout_ns
        current = float(self.core.target_depth_m[0])
        if fresh != self.following_planner:
            self.following_planner = fresh
            ramp = (self.planned and self.param_depth_m > current)
            self.get_logger().info(f"tick {stamp} ns: " + (
                "following the planner's target depth" if fresh else
                f"no planner target within {self.planner_timeout_ns / 1e9:g} s; target_depth_m "
                f"{self.param_depth_m} m until one comes" + (
                    f" (deepening from the planner's last {current:.3f} m at most {self.fallback_rate_m_s:g} m/s)"
                    if ramp else "")))
        if fresh:
            self.planned = True
            return target[1]
        if not self.planned:  # no plan this episode yet: the parameter's depth, as without a planner
            return self.param_depth_m
        return self._toward_parameter(stamp)

    def _toward_parameter(self, stamp: int) -> float:
        """d̄_z at ``stamp`` on the way from the core's to the parameter's: shallower at once, deeper
        at the fallback rate since the last tick answered (``planner_fallback.fallback_depth``)."""
        dt_s = 0.0 if self.last_answer_ns is None else (stamp - self.last_answer_ns) / 1e9
        return fallback_depth(float(self.core.target_depth_m[0]), self.param_depth_m, dt_s, self.fallback_rate_m_s)

    def _answer(self, stamp: int, v_x_c: float, p_z_c: float, force_n=None) -> None:
        if self.depth_source == "planner":
            depth = self._depth_for(stamp)
            if depth != self.core.target_depth_m[0]:
                self.core.set_targets(target_depth_m=depth)
        elif self.ramp_to_parameter:
            depth = self._toward_parameter(stamp)
            self.core.set_targets(target_depth_m=depth)
            self.ramp_to_parameter = depth != self.param_depth_m
        cmd = self.core.step(v_x_c, p_z_c, force_n)  # non-finite inputs: core holds its state
        self.last_answer_ns = stamp
        self.cmd_vel_pub.publish(M.build_message(self.classes, T.CMD_VEL.name, stamp, [cmd.u_x[0]]))
        self.blade_pub.publish(M.build_message(self.classes, T.BLADE_CMD.name, stamp, [cmd.u_zr[0], cmd.u_za[0]]))


def main(args: list[str] | None = None) -> int:
    return spin_node(ControllerNode, args, PARAMETERS, __doc__.splitlines()[0])


if __name__ == "__main__":
    raise SystemExit(main())
