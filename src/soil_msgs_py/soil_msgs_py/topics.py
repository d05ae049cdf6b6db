"""Topic names, message types and field mapping of the insitu-soil graph (DESIGN.md §5).

Every per-tick message carries the tick's simulation time: in ``header.stamp`` for stamped
geometry_msgs types, and in the first two labelled fields ``stamp_sec``/``stamp_nanosec``
of labelled ``std_msgs/Float64MultiArray`` payloads (which have no header). Labelled
arrays list their field names in ``layout.dim[0].label`` joined by ``|`` so a bag is
self-describing (see ``messages.py``).
"""
from __future__ import annotations

from dataclasses import dataclass

from .params import GROUND_TRUTH_PARAMS, KNOWN_PARAMS

WORLD_FRAME = "world"
STAMP_FIELDS: tuple[str, ...] = ("stamp_sec", "stamp_nanosec")


@dataclass(frozen=True)
class Topic:
    name: str
    msgtype: str  # rosbags / ROS 2 interface name, e.g. "geometry_msgs/msg/PointStamped"
    description: str
    labels: tuple[str, ...] = ()  # Float64MultiArray payload fields after the stamp


CLOCK = Topic("/clock", "rosgraph_msgs/msg/Clock", "simulation time, once per tick")
BLADE_POSE = Topic(
    "/blade/pose", "geometry_msgs/msg/PointStamped",
    "blade cutting edge in world frame: point.x = p_x^b [m], point.z = p_z^b [m] (surface at z=0)",
)
BLADE_TWIST = Topic(
    "/blade/twist", "geometry_msgs/msg/TwistStamped",
    "blade velocity in world frame: linear.x = v_x^b [m/s], linear.z = v_z^b [m/s]",
)
CHASSIS_POSE = Topic(
    "/chassis/pose", "geometry_msgs/msg/PointStamped",
    "chassis ground reference: point.x [m], point.z = p_z^c [m]",
)
CHASSIS_TWIST = Topic(
    "/chassis/twist", "geometry_msgs/msg/TwistStamped",
    "chassis velocity: linear.x = v_x^c [m/s], linear.z = v_z^c [m/s]",
)
BLADE_FORCE = Topic(
    "/blade/force", "geometry_msgs/msg/WrenchStamped",
    "measured cutting force, blade on soil, world frame: force.x = f_x^b [N], force.z = f_z^b [N]",
)
KNOWN = Topic(
    "/soil/known_params", "std_msgs/msg/Float64MultiArray",
    "known FEE parameters Θ_k (SI) of the tick", KNOWN_PARAMS,
)
GROUND_TRUTH = Topic(
    "/soil/ground_truth", "std_msgs/msg/Float64MultiArray",
    "pseudo-ground-truth Θ (SI) of the tick", GROUND_TRUTH_PARAMS,
)
CMD_VEL = Topic(
    "/chassis/cmd_vel", "geometry_msgs/msg/TwistStamped",
    "chassis forward velocity command: linear.x = u_x [m/s]; stamp = state tick it answers",
)
BLADE_CMD = Topic(
    "/blade/cmd", "std_msgs/msg/Float64MultiArray",
    "blade edge height commands: u_zr relative to chassis ground reference, u_za absolute [m]",
    ("u_zr", "u_za"),
)

# Everything one tick of an episode produces; the order is the order in a bag.
EPISODE_TOPICS: tuple[Topic, ...] = (
    CLOCK, BLADE_POSE, BLADE_TWIST, CHASSIS_POSE, CHASSIS_TWIST, BLADE_FORCE,
    KNOWN, GROUND_TRUTH, CMD_VEL, BLADE_CMD,
)
TOPICS_BY_NAME: dict[str, Topic] = {t.name: t for t in EPISODE_TOPICS}
