"""What the controller node tests share: tick stamps, sending a tick until it is answered, and
the probe as the simulator and the planner of a controller that follows the planner."""
from __future__ import annotations

from typing import Callable

from std_msgs.msg import String

from soil_msgs_py import graph as G
from soil_msgs_py import messages as M
from soil_msgs_py import topics as T
from soil_msgs_py.params import TICK_PERIOD_NS
from tests.ros_probe import NodeProc

FIRST = 100 * M.NS_PER_S  # the episode's first stamp [ns]


def tick_stamp(k: int) -> int:
    """Stamp [ns] of tick k of the episode."""
    return FIRST + int(k * TICK_PERIOD_NS)


def send_until_answered(probe, send: Callable[[], None], answered: Callable[[], bool], what: str) -> None:
    """``send()`` the tick's state, again every 2 s, until ``answered()`` (10 sends at most):
    topics are not ordered with each other, so on a loaded machine the first tick can reach the
    node before its episode_start."""
    for _ in range(10):
        send()
        try:
            probe.wait_for(answered, 2, what)
            return
        except AssertionError:
            continue
    probe.wait_for(answered, 1, f"{what} (sent 10 times)")


class PlannerSide:
    """The probe as the simulator and the planner of a controller node started with
    ``depth_source:=planner``: the state topics, /sim/status and /planner/target_depth published,
    /blade/cmd read. ``start`` waits for the node's endpoints and sends the episode_start."""

    def __init__(self, probe, controller_args: list[str], domain: int, tmp_path):
        self.probe, self.classes = probe, M.ros_message_classes()
        self.twist_topic, self.pose_topic, self.blade_topic = T.CHASSIS_TWIST.name, T.CHASSIS_POSE.name, T.BLADE_CMD.name
        self.fields = T.TARGET_DEPTH_FIELDS
        probe.subscribe(self.blade_topic, T.BLADE_CMD.msgtype)
        self.status = probe.publisher(G.SIM_STATUS_TOPIC, G.STRING_MSGTYPE)
        self.twist = probe.publisher(self.twist_topic, T.CHASSIS_TWIST.msgtype)
        self.pose = probe.publisher(self.pose_topic, T.CHASSIS_POSE.msgtype)
        self.target = probe.publisher(T.TARGET_DEPTH.name, T.TARGET_DEPTH.msgtype)
        self.ctl = NodeProc("anti_stall_controller", ["--ros-args", "-p", "depth_source:=planner", *controller_args],
                            domain, tmp_path)

    def start(self, meta, pacing: str = "") -> None:
        self.probe.wait_for(lambda: all(p.get_subscription_count() >= 1
                                        for p in (self.status, self.twist, self.pose, self.target))
                            and self.probe.matched_publishers(self.blade_topic) >= 1, 30, "controller endpoints")
        self.status.publish(String(data=G.EpisodeEvent(G.EVENT_EPISODE_START, 0, meta.name, meta, FIRST,
                                                       planned_ticks=1800, pacing=pacing).to_json()))

    def u_za(self) -> dict[int, float]:
        """Stamp [ns] -> u_za [m] of every /blade/cmd answer so far."""
        return {s: v[1] for s, v in (M.parse_message(self.blade_topic, m) for m in self.probe.messages(self.blade_topic))}

    def send(self, k: int) -> None:
        """Tick k's state at the target speed (no anti-stall offset)."""
        self.twist.publish(M.build_message(self.classes, self.twist_topic, tick_stamp(k), [0.5, 0.0]))
        self.pose.publish(M.build_message(self.classes, self.pose_topic, tick_stamp(k), [0.0, 0.0]))

    def tick(self, k: int) -> float:
        """Tick k sent (again every 2 s) until answered; the answer's u_za [m]."""
        send_until_answered(self.probe, lambda: self.send(k), lambda: tick_stamp(k) in self.u_za(),
                            f"the answer to tick {k}")
        return self.u_za()[tick_stamp(k)]

    def answer(self, k: int) -> float:
        """The answer's u_za to tick k, sent already (not sent again: it is held, not lost)."""
        self.probe.wait_for(lambda: tick_stamp(k) in self.u_za(), 20, f"the answer to tick {k}")
        return self.u_za()[tick_stamp(k)]

    def plan(self, k: int, depth: float) -> None:
        """The planner's target depth [m] made from tick k."""
        self.target.publish(M.make_labelled(self.classes, tick_stamp(k), self.fields, [depth, depth, 1.0]))

    def stop(self) -> str:
        """Stop the controller; its output."""
        self.ctl.stop()
        return self.ctl.output
