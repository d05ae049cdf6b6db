"""One long cut along a path of changing soil under a depth policy, in closed loop without ROS.

The cores composed as the live graph composes them: the simulator (one episode, soil patches
along x), the anti-stall controller (Eq. 11-12, its own lift stays the safety net) and, for
the soil-aware policy, the estimator's core (``OnlineEstimator``: the PINN window and the
soil posterior fused along the path), the planner (``StretchPlanner``: the deepest cut whose
upper force quantile stays within margin x the limits) and its ``DepthSchedule`` (rate
limits, start depth, hold). Tick k: the simulator reports state k, the controller answers it
with the target depth in effect, the estimator takes the complete row k and the plan made
from it reaches the controller ``plan_delay_ticks`` later (default 2: the tick the live
controller answers before the plan exists, and one for the estimator and planner; under load
the live graph is later, and the controller's fallback covers a planner that falls silent).
The fixed policies run the same path, seed and controller with a constant target depth.

Everything is deterministic for a seed (the estimator on one thread), so the policies meet
the same soil, the same noise and the same start.
"""
from __future__ import annotations

import collections
from dataclasses import dataclass, field

import numpy as np
import torch

from anti_stall_controller.controller import AntiStallController, AntiStallGains
from anti_stall_controller.plan_wait import DEFAULT_LAG_TICKS
from pinn_estimator.checkpoint import load_model
from pinn_estimator.shipped import shipped_checkpoint
from pinn_estimator.fusion_calibration import load_fusion_config
from pinn_estimator.online import INPUT_TOPICS, Estimate, OnlineEstimator
from soil_msgs_py import messages as M
from soil_msgs_py import topics as T
from soil_msgs_py.params import GROUND_TRUTH_PARAMS, KNOWN_PARAMS, ticks_in
from soil_planner.depth_schedule import DepthSchedule, ScheduleSettings
from soil_planner.planner import steady_cut_terms
from soil_planner.stretch_planner import StretchPlanner
from soil_sim_node.simulator import EpisodeSpec, SimConfig, SoilSimulator

DEFAULT_PLAN_DELAY_TICKS = DEFAULT_LAG_TICKS  # the live controller's planner_lag_ticks
_PHI, _C = GROUND_TRUTH_PARAMS.index("phi"), GROUND_TRUTH_PARAMS.index("c")
_D, _W = KNOWN_PARAMS.index("d"), KNOWN_PARAMS.index("w")
FUSED_TRACK = ("phi_fused", "phi_std", "c_fused", "c_std", "fused_valid")


@dataclass(frozen=True)
class Policy:
    """A depth policy: a fixed target depth [m], or the soil-aware planner (``fixed_depth_m`` None)."""

    name: str
    fixed_depth_m: float | None = None

    @property
    def soil_aware(self) -> bool:
        return self.fixed_depth_m is None


@dataclass
class SoilAwareSetup:
    """What the soil-aware policy runs: the world's shipped model and calibrated posterior by
    default (or a checkpoint and fusion config of one's own), the planner's settings and the depth schedule."""

    world: str
    planner: dict = field(default_factory=dict)  # StretchPlanner keyword settings
    schedule: ScheduleSettings = field(default_factory=ScheduleSettings)
    plan_delay_ticks: int = DEFAULT_PLAN_DELAY_TICKS
    checkpoint: str | None = None  # None: models/pinn_<world>.pt
    fusion_config: str | None = None  # None: the world's shipped calibration, models/fusion_<world>.json
    # the planner sees the depth the controller commands (−u_za), as the node does on /blade/cmd: an
    # edge held short of it does not anchor the plan's z force (False: as before it did)
    sees_commands: bool = True

    def __post_init__(self) -> None:
        if isinstance(self.plan_delay_ticks, bool) or not isinstance(self.plan_delay_ticks, int) or self.plan_delay_ticks < 1:
            raise ValueError(f"plan_delay_ticks={self.plan_delay_ticks!r} must be an integer >= 1 tick")
        StretchPlanner(**self.planner)  # ValueError naming a bad setting

    def estimator(self, publish) -> OnlineEstimator:
        path = self.checkpoint or str(shipped_checkpoint(self.world))
        model, _ = load_model(path)
        return OnlineEstimator(model, publish, fusion=load_fusion_config(self.fusion_config or "", self.world))


@dataclass
class Cut:
    """One cut's record, one row per tick (SI): what the metrics and the figure need."""

    policy: Policy
    world: str
    spec: EpisodeSpec
    x_b: np.ndarray  # blade edge x [m]
    v_x: np.ndarray  # chassis forward speed [m/s]
    depth: np.ndarray  # Θ_k's d, the edge below the surface ahead [m]
    target: np.ndarray  # the controller's target depth d̄_z in effect [m]
    offset: np.ndarray  # the controller's anti-stall offset Δd̄ [m] (> 0: lifting)
    force: np.ndarray  # (N, 2) measured f_x, f_z [N]
    patch: np.ndarray  # index of the soil patch under the edge
    truth: np.ndarray  # (N, 2) true φ [rad], c [Pa]
    plan: np.ndarray  # the plan's deepest cut [m] (NaN: no valid plan); fixed policies: NaN
    fused: np.ndarray  # (N, len(FUSED_TRACK)) the estimate's fused soil; fixed policies: NaN
    terrain: np.ndarray  # the heightfield after the cut [m], cells of ``cell_m`` from ``x_min_m``
    x_min_m: float
    cell_m: float
    width_m: float  # blade width w [m]
    target_speed_m_s: float
    gains: AntiStallGains
    estimator_counters: dict = field(default_factory=dict)

    @property
    def ticks(self) -> int:
        return len(self.x_b)


def run_cut(world: str, spec: EpisodeSpec, policy: Policy, setup: SoilAwareSetup | None = None,
            gains: AntiStallGains | None = None, custom_soils: dict | None = None, plugins=()) -> Cut:
    """Simulate ``spec`` (its patches, seed, speed and duration; its target depth unused) under
    ``policy``; ``custom_soils``: soils by name beside the catalogue (``load_soil_file``);
    ``plugins``: force terms the world has beside its own effects (a fusion config's
    ``calibration_plugins``). ValueError naming the field for a bad spec or setting."""
    gains = gains or AntiStallGains()
    sim = SoilSimulator(SimConfig(world_mode=world, plugins=tuple(plugins)), [spec], custom_soils)
    spec = sim.specs[0]
    n = ticks_in(spec.duration_s)
    start = policy.fixed_depth_m
    schedule = planner = estimator = None
    published: list[Estimate] = []
    if policy.soil_aware:
        setup = setup or SoilAwareSetup(world)
        schedule = DepthSchedule(setup.schedule)
        torch.set_num_threads(1)
        estimator = setup.estimator(published.append)
        # the plan reads the posterior's θ through the posterior's own physics (what of it a
        # steady cut can evaluate: a term on travel or time in soil is left out)
        cfg = estimator.posterior.cfg  # the posterior's physics and the bound law calibrated for it, as the estimator says them to the planner
        # at the cut's own speed unless told otherwise, as the planner node follows each episode's
        # target speed (its follow_episode_speed): the plans and the stall memory's threshold
        planner = StretchPlanner(**{"terms": steady_cut_terms(cfg.terms)[0], "bound_law": cfg.planner_bound_law() or (),
                                    "cut_speed_m_s": float(spec.target_speed_m_s), **setup.planner})
        estimator.start_episode(0)
        start = schedule.target_m
    controller = AntiStallController(gains, spec.target_speed_m_s, start)
    controller.dither_below_target = policy.soil_aware  # (the plan is the deepest cut allowed)
    queue: collections.deque[float] = collections.deque()  # targets on their way to the controller
    rec = {k: np.full(n, np.nan) for k in ("x_b", "v_x", "depth", "target", "offset", "patch", "plan")}
    force, truth = np.zeros((n, 2)), np.zeros((n, 2))
    fused = np.full((n, len(FUSED_TRACK)), np.nan)
    out = sim.reset()
    for k in range(n):
        if schedule is not None and len(queue) >= setup.plan_delay_ticks:
            controller.set_targets(target_depth_m=queue.popleft())
        rec["target"][k] = controller.target_depth_m[0]
        cmd = controller.step(out.velocities[:, 1], out.positions[:, 2], out.forces)
        rec["x_b"][k], rec["v_x"][k] = out.positions[0, 0], out.velocities[0, 1]
        rec["depth"][k], rec["offset"][k] = out.known[0, _D], controller.depth_offset_m[0]
        rec["patch"][k] = sim.patch_at(out.positions[:, 0])[0]
        force[k], truth[k] = out.forces[0], out.truth[0, [_PHI, _C]]
        if estimator is not None:
            obs = np.concatenate([out.positions[0], out.velocities[0], [cmd.u_zr[0], cmd.u_za[0], cmd.u_x[0]]])
            rows = {"observations": obs, "forces": out.forces[0], "known": out.known[0], "truth": out.truth[0],
                    "extras": out.extras[0]}
            for topic in INPUT_TOPICS:
                estimator.assembler.add_values(topic, out.stamp_ns, np.asarray(M.tick_values(topic, rows)))
            depth = None
            for est in published:  # one per released tick (the assembler holds none back in order)
                values = dict(zip(T.ESTIMATE_FIELDS, est.values.tolist()))
                fused[k] = [values[name] for name in FUSED_TRACK]
                try:
                    plan, _ = planner.plan(values, dict(zip(KNOWN_PARAMS, out.known[0].tolist())),
                                           -float(cmd.u_za[0]) if setup.sees_commands else None, out.forces[0])
                except ValueError:
                    plan = None  # a refused estimate: no plan for this tick (the node warns and skips it)
                depth = plan.max_depth_m if plan is not None else None
            published.clear()
            rec["plan"][k] = np.nan if depth is None else depth
            queue.append(schedule.update(out.stamp_ns, depth))
        out = sim.step(cmd.u_zr, cmd.u_za, cmd.u_x)
    return Cut(policy=policy, world=world, spec=spec, x_b=rec["x_b"], v_x=rec["v_x"], depth=rec["depth"],
               target=rec["target"], offset=rec["offset"], force=force, patch=rec["patch"].astype(int),
               truth=truth, plan=rec["plan"], fused=fused, terrain=sim.terrain[0].copy(), x_min_m=sim.x_min,
               cell_m=sim.dyn.terrain_cell_m, width_m=float(out.known[0, _W]),
               target_speed_m_s=float(spec.target_speed_m_s), gains=gains,
               estimator_counters=vars(estimator.counters).copy() if estimator is not None else {})


def sweep_fixed_depths(world: str, spec: EpisodeSpec, depths_m, gains: AntiStallGains | None = None,
                       custom_soils: dict | None = None, plugins=()) -> list[Cut]:
    """Fixed-depth cuts of ``spec`` at each of ``depths_m`` (the hindsight sweep)."""
    return [run_cut(world, spec, Policy(f"fixed {d:.3f} m", float(d)), gains=gains, custom_soils=custom_soils,
                    plugins=plugins) for d in depths_m]
