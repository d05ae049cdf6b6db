"""Topic names, message types and field mapping of the insitu-soil graph.

Every per-tick message carries the tick's simulation time: in ``header.stamp`` for stamped
geometry_msgs types, and in the first two labelled fields ``stamp_sec``/``stamp_nanosec``
of labelled ``std_msgs/Float64MultiArray`` payloads (which have no header). Labelled
arrays list their field names in ``layout.dim[0].label`` joined by ``|`` so a bag is
self-describing (see ``messages.py``).
"""
from __future__ import annotations

import difflib
from collections.abc import Iterable
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
    # published from an episode's first tick on: a later first message in a bag means some were lost
    # (False: it starts when there is something to say, a valid estimate or a stretch's map)
    from_first_tick: bool = True


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
    "measured cutting force, blade on soil, world frame: wrench.force.x = f_x^b [N], wrench.force.z = f_z^b [N]",
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

# --- what the online estimator publishes (not episode data: a recorder adds them on request) ---
# /soil/estimate payload after the stamp: Θ̂_u (SI: rad, Pa, rad, rad, m), the forces [N] of
# paper §2.2.2 (F̂ = F_FEE + F_r) and the validity flag (1.0: a fresh estimate from a full
# window of consecutive samples; 0.0: no estimate, every other field is 0.0, never NaN).
# window_samples = consecutive samples in the window (0..60): why an estimate is not valid yet.
# Then the soil fused along the path (pinn_estimator.fusion): the posterior over θ = (φ, c, δ)
# from every stretch of cutting since the episode began: means [rad, Pa, rad], β* over the
# posterior [rad], standard deviations and correlations (a Gaussian with these moments is what
# a planner can sample; the posterior itself is a Gaussian sum), the calibrated forecast error
# law σ_j = abs_j + rel_j·|ΔF_j| + limit_j·L_j·ramp [N, 1, 1] (what a forecast adds to the spread
# of θ's force; ΔF the part of the force extrapolated from where the evidence was measured,
# ``predictive.extrapolated_part``; ramp grows from 0 where a sample's |F_x| is the planner's
# margin of the F_x limit to 1 at that limit, L_j is axis j's force limit: ``predictive.near_limit_error_std``),
# fused_valid (1.0 once a stretch was learnt from; independent of ``valid``, which is the PINN
# window's) and the stretches learnt from.
FUSED_FIELDS: tuple[str, ...] = (
    "phi_fused", "c_fused", "delta_fused", "beta_fused",
    "phi_std", "c_std", "delta_std", "beta_std",
    "corr_phi_c", "corr_phi_delta", "corr_c_delta",
    "model_std_abs_x", "model_std_abs_z", "model_std_rel_x", "model_std_rel_z", "model_std_limit_x", "model_std_limit_z",
    "fused_valid", "fused_stretches",
)
ESTIMATE_FIELDS: tuple[str, ...] = (
    "phi", "c", "delta", "beta", "delta_d",
    "f_x_hat", "f_z_hat", "f_x_fee", "f_z_fee", "f_x_r", "f_z_r",
    "valid", "window_samples",
) + FUSED_FIELDS
# /soil/estimate's layouts before fields were added: a bag recorded then, or an estimator of before
# heard live, is read with the fields a layout lacks 0.0, what they meant then (2026-12-07: the
# forecast law's part near the F_x limit, none before). Every parser of a labelled array consults
# ``OLDER_LAYOUTS`` (``messages.parse_labelled``): the recorder, the planner, the readers.
ESTIMATE_LAYOUTS_BEFORE: tuple[tuple[str, ...], ...] = (
    tuple(n for n in ESTIMATE_FIELDS if n not in ("model_std_limit_x", "model_std_limit_z")),
)
OLDER_LAYOUTS: dict[tuple[str, ...], tuple[tuple[str, ...], ...]] = {ESTIMATE_FIELDS: ESTIMATE_LAYOUTS_BEFORE}
ESTIMATE = Topic(
    "/soil/estimate", "std_msgs/msg/Float64MultiArray",
    "PINN estimate from the window ending at the stamped sample: φ [rad], c [Pa], δ [rad], "
    "β [rad], Δd [m], F̂ = F_FEE + F_r [N] (x, z each), validity flag, window fill; then the soil "
    "fused along the path: means, standard deviations and correlations of φ, c, δ (β*), the "
    "model-error law [N, 1, 1], its validity flag and stretch count",
    ESTIMATE_FIELDS,
)
# The fused soil along the path, one point per cell of blade travel (``pinn_estimator.soil_map``).
MAP_FIELDS: tuple[str, ...] = ("x", "y", "z", "phi", "c", "delta", "phi_std", "c_std", "delta_std")
SOIL_MAP = Topic(
    "/soil/map", "sensor_msgs/msg/PointCloud2",
    "soil-property map along the path (frame world): per cell of blade travel x, y = 0, z = cut "
    "floor height [m], fused φ [rad], c [Pa], δ [rad] and their standard deviations (float32 fields)",
    from_first_tick=False,
)
ESTIMATED_FORCE = Topic(
    "/soil/estimate/force", "geometry_msgs/msg/WrenchStamped",
    "predicted cutting force F̂ (valid estimates only): wrench.force.x, wrench.force.z [N], stamp = newest sample used",
    from_first_tick=False,
)
# What the planner example publishes (soil_planner.node), one message per
# /soil/estimate with a Θ_k of the same stamp, stamped like it. max_depth_m: deepest cut depth
# d [m] below the soil surface (Θ_k's d, the blade edge below the surface ahead of the blade;
# ~ the anti-stall controller's target_depth_m, equal on level uncut ground) with every depth
# in [0, d] inside margin x the force limits for a steady, level cut at cut_speed_m_s; f_x_n,
# f_z_n: the predicted force there [N]: with a fused posterior (fused_valid 1) the
# force_quantile upper bound of |F| over it, else the PINN's point estimate (FEE at
# d' = clamp(d + Δd, 0, 0.66 m) with β*, plus the residual of F̂ at the current depth scaled
# with d'; force_quantile 0.0); limited_by_x/z: that limit is exceeded just deeper (1/0; both
# 0: d_max_m was reached); valid 0.0: nothing to plan from, every other field is 0.0, never NaN.
PLAN_FIELDS: tuple[str, ...] = ("max_depth_m", "f_x_n", "f_z_n", "limited_by_x", "limited_by_z", "valid",
                                 "force_quantile")
PLAN = Topic(
    "/planner/max_cut_depth", "std_msgs/msg/Float64MultiArray",
    "deepest cut within the force limits from the estimate of the stamped tick: depth below the soil "
    "surface [m], predicted force there [N] (x, z), which limit binds (1/0 each; both 0: d_max reached), "
    "validity flag, the force quantile planned with (0: the PINN's point estimate)",
    PLAN_FIELDS,
)
# The cut depth the planner asks the anti-stall controller for (soil_planner.node, one message
# per plan, stamped like it): target_depth_m, the controller's d̄_z [m] below the original
# surface: the plan's max_depth_m passed through the planner's rate limits and fallbacks
# (soil_planner.depth_schedule); max_depth_m the plan it followed [m] (0.0 without one);
# plan_valid 1/0: a valid plan was in effect (0: the start depth or the last plan held).
TARGET_DEPTH_FIELDS: tuple[str, ...] = ("target_depth_m", "max_depth_m", "plan_valid")
TARGET_DEPTH = Topic(
    "/planner/target_depth", "std_msgs/msg/Float64MultiArray",
    "cut depth for the anti-stall controller (d̄_z below the original surface [m]) after the planner's rate "
    "limits, the plan's deepest cut [m], whether a valid plan was in effect (1/0)",
    TARGET_DEPTH_FIELDS,
)

# Every topic this project defines, episode data or not (e.g. what a recorder can type without discovery).
GRAPH_TOPICS_BY_NAME: dict[str, Topic] = {t.name: t for t in (*EPISODE_TOPICS, ESTIMATE, ESTIMATED_FORCE, SOIL_MAP, PLAN,
                                                                  TARGET_DEPTH)}


def with_guesses(topics: Iterable[str], candidates: Iterable[str]) -> str:
    """The topics, each with the one of ``candidates`` it may have been meant as (a mistyped
    ``/soil/estimat``: "/soil/estimat (did you mean /soil/estimate?)"), for every tool that says a
    topic it was given is not there (the recorder of the graph's names, the player of a bag's)."""
    names = sorted(set(candidates))
    said = []
    for topic in topics:  # (a topic of the contract is no typo: no guess of another for it)
        guess = [] if topic in GRAPH_TOPICS_BY_NAME else difflib.get_close_matches(
            topic, [n for n in names if n != topic], n=1, cutoff=0.75)
        said.append(f"{topic} (did you mean {guess[0]}?)" if guess else topic)
    return ", ".join(said)
