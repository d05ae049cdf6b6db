"""The FEE parameter vector Θ, its units, paper Table 1 ranges and limits, and machine constants.

One source of truth: every other module (simulator, controller, PINN, bags) takes names,
ranges and constants from here. SI inside (m, s, N, Pa, N/m^3, rad); degrees only at the
edges: what a user writes (soil files, node parameters and reports named ``*_deg``), converted
with ``DEG`` where it is read or shown.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

DEG = math.pi / 180.0
GRAVITY_M_S2 = 9.81
INF = math.inf


@dataclass(frozen=True)
class ParamSpec:
    """One entry of paper Table 1, converted to SI.

    ``norm`` is the min-max normalisation range; ``limits`` the physical/plausibility
    limits the PINN clips to and the ReLU loss (Eq. 16) enforces. ``math.inf`` marks an
    open bound ("-" in the table).
    """

    name: str
    unit: str
    norm: tuple[float, float]
    limits: tuple[float, float]
    description: str

    def normalise(self, x):
        lo, hi = self.norm
        span = hi - lo if hi != lo else 1.0
        return (x - lo) / span

    def denormalise(self, x):
        lo, hi = self.norm
        span = hi - lo if hi != lo else 1.0
        return x * span + lo


def _a(lo_deg: float, hi_deg: float) -> tuple[float, float]:
    return (lo_deg * DEG, hi_deg * DEG)


@dataclass(frozen=True)
class Machine:
    """The simple bladed vehicle of §2.1.2 (SI). Its chassis is a 3 × 2 × 2 m box there; the planar
    simulator needs only its mass and the four soil-height probes under it
    (``soil_sim_node.simulator.Dynamics.probe_offsets_m``)."""

    chassis_mass_kg: float = 5000.0
    blade_mass_kg: float = 400.0
    blade_width_m: float = 3.164
    blade_height_m: float = 0.660
    blade_angle_rad: float = 80.0 * DEG  # rho, fixed for all experiments (§3.1)
    horizontal_force_limit_n: float = 20e3  # chassis velocity motor (tractive limit)
    vertical_force_limit_n: float = 30e3  # blade lift joint (penetrative limit)
    blade_min_rel_m: float = -0.3  # edge reach below the surface, chassis on level ground
    blade_max_rel_m: float = 1.0  # edge reach above the surface


MACHINE = Machine()


# Paper Table 1. alpha's normalisation range is printed as [10, 10] deg, which is a
# degenerate (zero-width) range; we keep it and guard the division in ParamSpec. w's range and
# d's limit are the blade's width and height (3.164 m, 0.660 m in the table), taken from MACHINE.
TABLE1: dict[str, ParamSpec] = {
    p.name: p
    for p in (
        ParamSpec("phi", "rad", _a(17, 45), _a(0, 90), "soil internal friction angle"),
        ParamSpec("c", "Pa", (0.0, 10e3), (0.0, INF), "soil cohesion"),
        ParamSpec("delta", "rad", _a(11, 35), _a(0, 90), "soil-tool friction angle"),
        ParamSpec("c_a", "Pa", (0.0, 10e3), (0.0, INF), "soil-tool adhesion"),
        ParamSpec("gamma", "N/m^3", (14e3, 22e3), (0.0, INF), "soil moist unit weight"),
        ParamSpec("rho", "rad", _a(2, 178), _a(2, 178), "blade (soil-tool) angle to the surface"),
        ParamSpec("alpha", "rad", _a(10, 10), _a(-30, 30), "soil surface inclination"),
        ParamSpec("w", "m", (0.0, MACHINE.blade_width_m), (0.0, MACHINE.blade_width_m), "tool width"),
        ParamSpec("d", "m", (0.0, 0.3), (0.0, MACHINE.blade_height_m), "depth of cut d' = d + delta_d"),
        ParamSpec("delta_d", "m", (-5e-2, 5e-2), (-5e-2, 5e-2), "residual depth of cut"),
        ParamSpec("q", "N", (0.0, 10e3), (0.0, INF), "surcharge force"),
        ParamSpec("v_x", "m/s", (0.0, 1.0), (-2.0, 2.0), "blade velocity, x"),
        ParamSpec("v_z", "m/s", (-1.0, 1.0), (-2.0, 2.0), "blade velocity, z"),
        ParamSpec("beta", "rad", _a(11.5, 34.5), _a(11.5, 34.5), "soil failure angle"),
        ParamSpec("dn_gamma_dbeta", "1", (-10.0, 10.0), (-INF, INF), "dN_gamma/dbeta"),
        ParamSpec("eta", "rad", _a(2, 178), _a(2, 178), "eta = delta + rho + phi + beta"),
        ParamSpec("zeta", "rad", _a(11, 35), (0.0, INF), "zeta = phi - delta"),
    )
}

# Θ_u: what the PINN estimates (§2.2). Θ_k: what it is told (§2.2, Table 1).
UNKNOWN_PARAMS: tuple[str, ...] = ("phi", "c", "delta", "beta", "delta_d")
KNOWN_PARAMS: tuple[str, ...] = ("c_a", "gamma", "rho", "alpha", "w", "d", "q", "v_x", "v_z")
# Pseudo-ground truth published by the simulator (§2.1.2). beta is argmin N_gamma of the
# true parameters (Eq. 7); Vortex could not provide it, our simulator can.
GROUND_TRUTH_PARAMS: tuple[str, ...] = (
    "phi", "c", "delta", "c_a", "gamma", "rho", "alpha", "w", "d", "q", "v_x", "v_z", "beta",
)

# Observation vector o_t = [p, v, u] (§2.1.2) and measured force F.
POSITION_FIELDS: tuple[str, ...] = ("p_x_b", "p_z_b", "p_z_c")
VELOCITY_FIELDS: tuple[str, ...] = ("v_z_b", "v_x_c", "v_z_c")
COMMAND_FIELDS: tuple[str, ...] = ("u_zr", "u_za", "u_x")
OBSERVATION_FIELDS: tuple[str, ...] = POSITION_FIELDS + VELOCITY_FIELDS + COMMAND_FIELDS
FORCE_FIELDS: tuple[str, ...] = ("f_x_b", "f_z_b")

SAMPLE_RATE_HZ = 60
TICK_PERIOD_NS = 1e9 / SAMPLE_RATE_HZ  # exact tick period [ns]; tick k is stamped tick_stamp_ns(k)
MAX_STRIDE_TICKS = 60 * SAMPLE_RATE_HZ  # the rarest estimates an estimator may be set to (its stride): one a minute


def ticks_in(seconds: float) -> int:
    """The number of 60 Hz ticks in ``seconds`` (an episode's, a window's), rounded."""
    return int(round(seconds * SAMPLE_RATE_HZ))


def tick_stamp_ns(tick: int) -> int:
    """Stamp of tick k from its episode's first tick [ns]: floor(k · 1e9 / 60), the exact 60 Hz grid
    in integers (no float drift) on which the simulator and the batch generator stamp every tick."""
    return grid_stamp_ns(tick, SAMPLE_RATE_HZ)


def grid_stamp_ns(k: int, hz: float) -> int:
    """Stamp of the k-th point of a grid at ``hz`` from its first [ns]: floor(k · 1e9 / hz), in
    integers for a whole rate (no float drift), as ticks are stamped (``tick_stamp_ns``)."""
    if float(hz).is_integer():
        return (int(k) * 1_000_000_000) // int(hz)
    return math.floor(int(k) * 1e9 / hz)
WINDOW_SAMPLES = 60  # T = 60 samples = 1 s (§2.2.1)
VELOCITY_AVERAGE_SAMPLES = 10  # §3.1: v_t = avg([v_x^c, v_z^b]_{t-10:t})


# The targets an episode may set (simulator, controller): the chassis velocity command's reach
# [m/s] (the simulator clips u_x to it) and a cut no deeper than the blade is high [m].
MAX_TARGET_SPEED_M_S = 2.0
# The slowest target speed [m/s]: below 1 mm/s a cut makes no progress in an episode, and the
# controller's speed-scheduled gain K_v / v̄_x (Eq. 11) grows without bound.
MIN_TARGET_SPEED_M_S = 1e-3
MAX_TARGET_DEPTH_M = MACHINE.blade_height_m
# The graph's default targets (controller and simulator nodes): a cut at 0.5 m/s, 0.2 m deep. The
# planner plans its steady cut at this speed, and the cut report drives every policy at it.
DEFAULT_TARGET_SPEED_M_S = 0.5
DEFAULT_TARGET_DEPTH_M = 0.2
# The anti-stall controller's default velocity-error threshold c_vx (Eq. 11: e_vmin = v̄_x c_vx):
# a machine slower than (1 − c_vx) of its target speed is stalling, where the controller starts
# to lift. The planner's stall memory and the cut report's stall time count stalls by it.
DEFAULT_C_VX = 0.2


def stall_speed_m_s(target_speed_m_s: float, c_vx: float = DEFAULT_C_VX) -> float:
    """The forward speed [m/s] below which a cut at ``target_speed_m_s`` is stalling: the anti-stall
    controller's threshold (Eq. 11), v̄_x (1 − c_vx)."""
    return target_speed_m_s * (1.0 - c_vx)
# How far the lift holds the edge below the ground the chassis stands on [m]: the deepest cut at the
# start of a pass on level ground. Deeper targets (up to the blade's height) are reached only once
# the chassis rides on its own cut floor, which ``beyond_lift_reach`` says.
LIFT_REACH_M = -MACHINE.blade_min_rel_m


def beyond_lift_reach(name: str, depth_m: float) -> str | None:
    """A warning naming ``name`` when a target depth [m] is deeper than the lift reaches from level
    ground, else None (also beyond the blade's height, which the depth's own range check refuses:
    a warning about reaching it, then the refusal, said the same value twice)."""
    if LIFT_REACH_M + 1e-9 < depth_m <= MAX_TARGET_DEPTH_M:
        return (f"{name}={depth_m:g} m is beyond the lift's reach from level ground ({LIFT_REACH_M:g} m below the "
                "chassis): the first metres of the pass are cut at about that depth, deeper only once the chassis "
                "rides on its own cut floor")
    return None


def beyond_table1_speed(name: str, speed_m_s: float) -> str | None:
    """A warning naming ``name`` when a target speed [m/s] is faster than Table 1's v_x, which the
    simulator drives (up to MAX_TARGET_SPEED_M_S) but the shipped models never saw, else None."""
    fastest = TABLE1["v_x"].norm[1]
    if fastest + 1e-9 < speed_m_s <= MAX_TARGET_SPEED_M_S:  # (beyond it refused, as beyond_lift_reach's depth)
        return (f"{name}={speed_m_s:g} m/s is faster than Table 1's v_x (at most {fastest:g} m/s): simulated, but the "
                "shipped models were trained within it and their forecasts calibrated at slower cuts")
    return None


# (x, z) force limits [N]: the scale forces are normalised by (PINN loss, classical fit, reports).
FORCE_LIMITS_N: tuple[float, float] = (MACHINE.horizontal_force_limit_n, MACHINE.vertical_force_limit_n)
# The largest force any soil puts on the blade [N]: 300 times the larger limit. Beyond it no soil
# acts on a 5.4 t machine; it is a bug (units, a sign of an exponent) or a coefficient far too large.
MAX_PLAUSIBLE_FORCE_N = 300.0 * max(FORCE_LIMITS_N)
# Share of the force limits a planned cut may use by default (``soil_planner``'s margin). Of 0.8 / 0.85 /
# 0.9 (force quantile 0.95) the one that stalled least over the five default-world paths with three
# seeds each, with 5 % more volume per metre than 0.8 (benchmarks/bench_planner_margin.py --seeds 3;
# docs/planner_in_the_loop.md). A cut whose forecast force lies beyond it the planner does not plan:
# the forecast report scores those apart (``pinn_estimator.forecast.margin_strata``).
PLANNER_FORCE_MARGIN = 0.85
# A steady cut: the edge moves vertically slower than this [m/s] (a 1:25 slope at 0.5 m/s). Faster,
# the force carries transients a quasi-static model lacks (sinking: the penetration reaction).
STEADY_CUT_MAX_ABS_V_Z_M_S = 0.02
# The blade cuts (rather than skims the surface) from this depth [m]: a shallower force carries no
# evidence about the soil (the posterior's stretches, the discrepancy workflow's ticks, a forecast's
# steady part).
MIN_CUT_DEPTH_M = 0.01
# The shallowest cut a depth is planned or swept at [m]: at 2 cm a weak soil after a strong one
# cannot show, and a cut would stay there (the planner's depth schedule, the cut report's sweep,
# the demo's forecast depths).
MIN_PLANNED_DEPTH_M = 0.05
# How fast a target deepens where a stall threatened [m/s]: the planner's schedule after a retreat,
# and the controller's ramp to its own target when the planner falls silent.
CAUTIOUS_DEEPEN_RATE_M_S = 0.03

# Soil-tool constants of §3.1.
ADHESION_PA = 200.0  # c_a, all soils
SOIL_TOOL_FRICTION_DEFAULT_RAD = 10.0 * DEG  # delta in the default world
SOIL_TOOL_FRICTION_FEE_RAD = 15.0 * DEG  # delta overridden in the fee world (§3.1)
