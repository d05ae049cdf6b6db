"""Planar soil + bladed-vehicle simulator (paper §2.1), vectorised over a batch of episodes.

No ROS here: ``soil_sim_node.node`` is a thin adapter. One ``SoilSimulator`` advances B
episodes in lock-step with NumPy arrays of shape (B,); a row of a batch is bit-identical to
the same episode run alone (elementwise NumPy only; per-episode RNG streams).

Model (SI; x forward, z up; the original surface is level at z = 0)
------------------------------------------------------------------
* Chassis (5000 kg) + blade (400 kg) move together in x. A velocity motor ("motorized
  constraint") pushes with k_m (u_x - v_x), saturating at the 20 kN tractive limit.
* The chassis ground reference p_z^c follows the mean soil height under four probe points
  (a planar vehicle: two front, two rear) through a critically damped spring-damper, the
  paper's "simple vehicle suspension". The blade's cut floor is what the chassis later
  drives over.
* The blade hangs on a "locked" lift joint: a spring-damper on the edge height relative to
  the chassis reference, tracking u_zr inside the reach [-0.3, +1.0] m, its force
  saturating at the 30 kN penetrative limit.
* Soil-tool force: the FEE failure force (Eq. 2-10, velocity-corrected, beta = beta*)
  along the Eq. 8 direction, reached through a stiff elastic contact: pushing the blade
  compresses the soil elastically (k_soil) until the FEE failure force is reached; then the
  soil shears and the force stays at the failure force (perfect plasticity). When the
  machine cannot supply the failure force it stalls against the elastic soil.
* The blade cuts the heightfield: cells the edge passes are lowered to the edge height.
* Soil along the path (optional ``EpisodeSpec.patches``): the soil in effect is the patch
  under the cutting edge (p_x^b at the start of each substep); every soil property switches
  when the edge crosses a boundary: phi, c, gamma, the penetration capacity, compaction
  (restarting from the new patch's I_d) and the published Θ_k / ground truth. delta and c_a
  are the world's, the same in every patch. What the blade already holds stays: the
  surcharge pile keeps its volume and weight, and the soil cut from then on mixes into it
  with the new soil's unit weight (a well-mixed pile: Q = V * mean gamma); the elastic
  pre-failure compression and the particles' grip are the contact's, not the soil's, and the
  new failure force bounds them at once; the heightfield is geometry.
* `default` world: the named effects of ``effects.Effects`` add to this; `fee` world has
  none (Q = 0).
* Measured force = lift-joint constraint force on the blade minus the blade's static weight
  (a tared load cell), averaged over the tick: blade-on-soil force + m_b * a_blade.

Engines
-------
This module, on NumPy, is the readable reference of the physics (``engine="reference"``).
By default (``engine="compiled"``) each episode's ticks run in ``kernel``, a Numba-compiled
second form of the same equations (outputs equal to the reference to 1e-9 relative, tested
in ``tests/soil_sim_node/test_kernel.py``), about a thousand times faster. User plugins are
plain Python: with plugins, each substep runs the kernel's soil half for the whole batch,
then the plugins on NumPy arrays (B,), then the kernel's machine half; slower than without
plugins (the interpreter is back in every substep) but still much faster than the reference.
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field, replace

import numpy as np

from soil_physics import fee
from soil_msgs_py.episode import MAX_EPISODE_S, MAX_SEED
from soil_msgs_py.patches import SoilPatch, check_patches, patch_under
from soil_msgs_py.values import finite_number, plain_zero, short_repr
from soil_msgs_py.params import (
    ADHESION_PA,
    DEG,
    GRAVITY_M_S2,
    GROUND_TRUTH_PARAMS,
    KNOWN_PARAMS,
    MACHINE,
    MAX_TARGET_DEPTH_M,
    MAX_TARGET_SPEED_M_S,
    MIN_TARGET_SPEED_M_S,
    SAMPLE_RATE_HZ,
    SOIL_TOOL_FRICTION_DEFAULT_RAD,
    SOIL_TOOL_FRICTION_FEE_RAD,
    VELOCITY_AVERAGE_SAMPLES,
    Machine,
    tick_stamp_ns,
)
from soil_physics.bearing import EDGE_WIDTH_M, penetration_capacity
from soil_physics.contact import BASE_FRICTION_V_REF_M_S, CONTACT_DAMPING_PA_S_M, base_friction_force, submerged_area_m2
from soil_physics.force_inputs import ForceInputs
from soil_physics.soils import SoilType, at_density, get_soil
from soil_physics.travel import soil_advance, soil_time_step

from . import kernel
from .effects import (
    FORCE_TERMS,
    Effects,
    ForcePlugin,
    check_effect_params,
    effects_for_mode,
    load_plugins,
)

ENGINES = ("compiled", "reference")


def check_engine(engine) -> None:
    """ValueError naming the value unless ``engine`` is one of ENGINES."""
    if engine not in ENGINES:
        raise ValueError(f"engine={engine!r} is not one of {ENGINES}")


@dataclass(frozen=True)
class EpisodeSpec:
    """One episode: soil, initial relative density, targets, seed, length, and optionally the
    soil along the path.

    ``patches``: ``soil_msgs_py.patches`` entries ordered by x (SoilPatch, ``'X:SOIL:ID'``
    strings or (x_start_m, soil, I_d) triples). With patches the soil under the cutting edge
    is the patch's, and ``soil`` / ``relative_density_pct`` are not used: ``resolve`` sets them
    to those of the patch under the edge at the start (what the metadata and the bag name show).
    """

    soil: str | SoilType
    relative_density_pct: float
    target_speed_m_s: float
    target_depth_m: float
    seed: int
    duration_s: float = 10.0
    patches: tuple = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "patches", tuple(self.patches or ()))
        for name in ("relative_density_pct", "target_speed_m_s", "target_depth_m", "duration_s"):
            object.__setattr__(self, name, plain_zero(getattr(self, name)))

    def soil_path(self, custom_soils: dict | None = None) -> tuple[tuple[float, SoilType, float], ...]:
        """The soil along x: ((x_start_m, SoilType, I_d [%]), ...) ordered by x; one entry
        (x_start_m = -inf) without patches. Errors name the patch, field and value."""
        if not self.patches:
            soil = self.soil if isinstance(self.soil, SoilType) else get_soil(self.soil, custom_soils)
            return ((-math.inf, soil, self.relative_density_pct),)
        path = []
        for i, patch in enumerate(check_patches(self.patches)):
            try:
                soil = get_soil(patch.soil, custom_soils)
            except ValueError as err:
                raise ValueError(f"patches[{i}]: {err}") from None
            path.append((patch.x_start_m, soil, patch.relative_density_pct))
        return tuple(path)

    def resolve(self, custom_soils: dict | None = None) -> tuple["EpisodeSpec", SoilType]:
        """Validate every field; return (the spec, the SoilType it starts in). Errors name the
        field and value. With patches the returned spec has the soil and I_d of the patch under
        the blade's edge at the start (the first patch, unless the next starts at or behind the
        edge: a patch never cut must not name and label the episode) and the patches as
        SoilPatch with the soils' catalogue names."""
        spec = self
        if self.patches:
            path = self.soil_path(custom_soils)
            patches = tuple(SoilPatch(x, soil.name, i_d) for x, soil, i_d in path)
            first = int(patch_under(patches, Dynamics.blade_offset_m))  # (SoilSimulator.patch_at's rule)
            spec = replace(self, soil=path[first][1].name, relative_density_pct=path[first][2], patches=patches)
        soil = spec.soil if isinstance(spec.soil, SoilType) else get_soil(spec.soil, custom_soils)
        checks = (
            ("relative_density_pct", spec.relative_density_pct, 0.0, 100.0, "%"),
            ("target_speed_m_s", spec.target_speed_m_s, MIN_TARGET_SPEED_M_S, MAX_TARGET_SPEED_M_S, "m/s"),
            ("target_depth_m", spec.target_depth_m, 0.0, MAX_TARGET_DEPTH_M, "m"),
            ("duration_s", spec.duration_s, 1.0 / SAMPLE_RATE_HZ, MAX_EPISODE_S, "s"),
        )
        for name, value, lo, hi, unit in checks:  # (not a bool; an integer too large for a float is refused, not raised)
            if not finite_number(value):
                raise ValueError(f"{name}={short_repr(value)} must be a number in [{lo:g}, {hi:g}] {unit}")
            if not lo <= value <= hi:
                raise ValueError(f"{name}={short_repr(value)} outside [{lo:g}, {hi:g}] {unit}")
        if isinstance(spec.seed, bool) or not isinstance(spec.seed, (int, np.integer)) or not 0 <= spec.seed <= MAX_SEED:
            raise ValueError(f"seed={spec.seed!r} must be an integer in [0, 2**63 - 1]")
        return spec, soil


@dataclass(frozen=True)
class Dynamics:
    """Constraint and contact constants (tuned for a stable 600 Hz explicit integration)."""

    substeps: int = 10  # physics steps per 60 Hz tick
    motor_gain_n_s_m: float = 5e5  # 1/loss of the velocity motor: 20 kN at 0.04 m/s error
    joint_stiffness_n_m: float = 2e6
    joint_damping_n_s_m: float = 4e4
    chassis_height_omega_rad_s: float = 12.0
    soil_stiffness_n_m: float = 2e6  # pre-failure contact stiffness
    soil_damping_n_s_m: float = 2e4
    blade_offset_m: float = 2.0  # cutting edge ahead of the chassis centre
    probe_offsets_m: tuple[float, ...] = (-1.2, -1.2, 1.2, 1.2)  # four points under the chassis
    terrain_cell_m: float = 0.01
    blade_edge_width_m: float = EDGE_WIDTH_M
    fee_velocity_gain_s_m: float = fee.FEE_VELOCITY_GAIN_S_M


@dataclass(frozen=True)
class SimConfig:
    world_mode: str = "default"
    effects: Effects | None = None  # None: the mode's defaults
    plugins: tuple = ()
    dynamics: Dynamics = field(default_factory=Dynamics)
    machine: Machine = MACHINE
    engine: str = "compiled"  # one of ENGINES

    def resolved_effects(self) -> Effects:
        mode_effects = effects_for_mode(self.world_mode)
        return mode_effects if self.effects is None else self.effects


@dataclass
class TickOutput:
    """What the simulator reports after a tick (arrays of shape (B,) or (B, k))."""

    stamp_ns: int
    positions: np.ndarray  # (B,3) p_x_b, p_z_b, p_z_c
    velocities: np.ndarray  # (B,3) v_z_b, v_x_c, v_z_c
    forces: np.ndarray  # (B,2) measured f_x_b, f_z_b
    known: np.ndarray  # (B,9) Θ_k
    truth: np.ndarray  # (B,13) pseudo-ground truth Θ
    extras: np.ndarray  # (B,2) p_x_c, v_x_b
    applied_u_zr: np.ndarray  # (B,) lift-joint target actually used (after reach clipping)


SURFACE_INCLINATION_RAD = 0.0  # α of the simulated soil surface [rad]: level ground


def soil_tool_friction_rad(world_mode: str) -> float:
    """δ [rad] of the world's blade (the fee world's and the default world's differ)."""
    return SOIL_TOOL_FRICTION_FEE_RAD if world_mode == "fee" else SOIL_TOOL_FRICTION_DEFAULT_RAD


def check_failure_wedges(config: "SimConfig", spec: "EpisodeSpec", custom_soils: dict | None = None) -> None:
    """ValueError naming the soil if the FEE (Eq. 1-7) has no failure wedge for a soil of ``spec``'s
    path at a steady cut with this blade, at its relative density or fully compacted (what
    compaction can reach): its force would be 0, a soil that resists nothing, and every tick of it
    silent garbage. φ = 0 (an undrained clay) is such a soil: N_γ and N_c have no minimum over β
    there; so is one whose φ + δ + ρ reaches 180°, where the wedge vanishes."""
    delta, rho = soil_tool_friction_rad(config.world_mode), config.machine.blade_angle_rad
    for _, soil, i_d in spec.soil_path(custom_soils):
        for label, phi in ((f"I_d {i_d:g} %", soil.at(i_d).phi), ("I_d 100 %", soil.dense.phi)):
            with np.errstate(all="ignore"):
                beta = float(fee.beta_star(phi, delta, rho, SURFACE_INCLINATION_RAD))
            if not math.isfinite(beta):
                raise ValueError(
                    f"soil {soil.name!r} at {label}: phi={phi / DEG:.3g}° gives the FEE no failure wedge with this "
                    f"blade (rho={rho / DEG:.3g}°, soil-tool friction delta={delta / DEG:.3g}°): the soil would resist "
                    f"nothing. The FEE needs 0° < phi < {180.0 - (rho + delta) / DEG:.3g}° (an undrained clay's "
                    "phi = 0 is outside it)")
        phi = soil.at(i_d).phi  # (compaction only raises it; the world's adhesion c_a acts in every soil)
        if phi < delta:
            warnings.warn(
                f"soil {soil.name!r} at I_d {i_d:g} %: phi={phi / DEG:.3g}° is below the soil-tool friction "
                f"delta={delta / DEG:.3g}°: while the blade rises (the friction reversed, Eq. 9-10) the FEE has no "
                "failure wedge, the simulated soil resists nothing there, and the recorded truth's FEE (beta = "
                "180° - rho) is not the measured force on those ticks", stacklevel=2)


def resolve_checked(config: "SimConfig", spec: "EpisodeSpec",
                    custom_soils: dict | None = None) -> tuple["EpisodeSpec", SoilType]:
    """``spec.resolve`` (every field in range, every soil known), then ``check_failure_wedges`` in
    ``config``'s world: what every place that accepts an episode runs before simulating it."""
    resolved = spec.resolve(custom_soils)
    check_failure_wedges(config, resolved[0], custom_soils)
    return resolved


class SoilSimulator:
    """B planar earthmoving episodes advanced together at 60 Hz (``substeps`` physics steps per tick)."""

    def __init__(self, config: SimConfig, specs: list[EpisodeSpec], custom_soils: dict | None = None):
        if not specs:
            raise ValueError("specs is empty: give at least one EpisodeSpec")
        self.config = config
        self.effects = config.resolved_effects()
        check_effect_params(self.effects)
        check_engine(config.engine)
        self.plugins: list[ForcePlugin] = load_plugins(config.plugins)
        self.engine = config.engine
        if self.engine == "compiled":
            from .warm_up import ready  # (it makes simulators itself)

            ready()
        resolved = [resolve_checked(config, s, custom_soils) for s in specs]
        self.specs = [r[0] for r in resolved]
        self.soils = [r[1] for r in resolved]
        self.batch = len(specs)
        self.dyn = config.dynamics
        if self.dyn.substeps < 1:
            raise ValueError(f"dynamics.substeps={self.dyn.substeps} must be >= 1")
        self.dt = 1.0 / (SAMPLE_RATE_HZ * self.dyn.substeps)
        m = config.machine
        self.m = m
        b = self.batch
        self._set_soil_paths([s.soil_path(custom_soils) for s in self.specs])
        self.delta = np.full(b, soil_tool_friction_rad(config.world_mode))
        self.c_a = np.full(b, ADHESION_PA)
        self.rho = m.blade_angle_rad
        self.alpha = SURFACE_INCLINATION_RAD
        self.w = m.blade_width_m
        # the heightfield holds wherever the machine can drive in the longest episode at the
        # fastest command ``step`` accepts (a teleop, or a controller at another speed than the
        # spec's), either way; whole cells behind -3 m, so a cell's edges stay where they were
        # (to the rounding of x_min: bit-identical on every episode compared) when it was sized from the spec's own speed (clamped reads beyond it were silently wrong:
        # an outside reviewer's 1 m/s in a 0.3 m/s episode lost a quarter of the cut volume)
        reach_m = MAX_TARGET_SPEED_M_S * max(s.duration_s for s in self.specs) + 3.0
        self.x_min = -3.0 - math.ceil(reach_m / self.dyn.terrain_cell_m) * self.dyn.terrain_cell_m
        x_max = self.dyn.blade_offset_m + reach_m + 3.0
        self.n_cells = int(math.ceil((x_max - self.x_min) / self.dyn.terrain_cell_m)) + 2
        self._params, self._probes = self._kernel_params()
        self._episode = self._kernel_episodes()
        self.reset()

    def _set_soil_paths(self, paths: list[tuple]) -> None:
        """Per episode and patch (B, P) arrays of the soil along x (``EpisodeSpec.soil_path``);
        an episode with fewer patches than the batch's most is padded with patches that start
        at +inf (never reached)."""
        b, n = self.batch, max(len(path) for path in paths)
        self.n_patches = np.array([len(path) for path in paths])
        self.patch_x = np.full((b, n), math.inf)  # start of each patch (edge x) [m]
        self.patch_i_d = np.zeros((b, n))  # relative density [%]
        self.patch_loose, self.patch_dense = np.zeros((b, n, 3)), np.zeros((b, n, 3))  # (phi, c, gamma) at 0 / 100 %
        for i, path in enumerate(paths):
            for j, (x, soil, i_d) in enumerate(path):
                self.patch_x[i, j], self.patch_i_d[i, j] = x, i_d
                self.patch_loose[i, j] = (soil.loose.phi, soil.loose.c, soil.loose.gamma)
                self.patch_dense[i, j] = (soil.dense.phi, soil.dense.c, soil.dense.gamma)
        # pseudo-ground truth (§3.1): each patch's soil at its own I_d, uncompacted
        self.patch_nominal = self._soil_at(self.patch_loose, self.patch_dense, self.patch_i_d)

    def _kernel_episodes(self) -> np.ndarray:
        """The per-episode constants the compiled kernel reads (``kernel.E_*``, then the
        ``kernel.K_*`` columns of each patch)."""
        k, n = kernel, self.patch_x.shape[1]
        episodes = np.zeros((self.batch, k.N_EPISODE + n * k.N_PATCH))
        episodes[:, k.E_DELTA], episodes[:, k.E_C_A], episodes[:, k.E_N_PATCHES] = self.delta, self.c_a, self.n_patches
        for j in range(n):
            o = k.N_EPISODE + j * k.N_PATCH
            episodes[:, o + k.K_X_START], episodes[:, o + k.K_I_D] = self.patch_x[:, j], self.patch_i_d[:, j]
            for q, (loose, dense, nominal) in enumerate(((k.K_PHI_LOOSE, k.K_PHI_DENSE, k.K_PHI0),
                                                         (k.K_C_LOOSE, k.K_C_DENSE, k.K_C0),
                                                         (k.K_GAMMA_LOOSE, k.K_GAMMA_DENSE, k.K_GAMMA0))):
                episodes[:, o + loose] = self.patch_loose[:, j, q]
                episodes[:, o + dense] = self.patch_dense[:, j, q]
                episodes[:, o + nominal] = self.patch_nominal[:, j, q]
        return episodes

    def _kernel_params(self) -> tuple[np.ndarray, np.ndarray]:
        """The shared constants the compiled kernel reads (``kernel.P_*`` layout) and the probe offsets."""
        dyn, m, e, k = self.dyn, self.m, self.effects, kernel
        p = np.zeros(k.N_PARAMS)
        values = {
            k.P_DT: self.dt, k.P_SUBSTEPS: dyn.substeps, k.P_MOTOR_GAIN: dyn.motor_gain_n_s_m,
            k.P_JOINT_K: dyn.joint_stiffness_n_m, k.P_JOINT_C: dyn.joint_damping_n_s_m,
            k.P_CHASSIS_OMEGA: dyn.chassis_height_omega_rad_s, k.P_SOIL_K: dyn.soil_stiffness_n_m,
            k.P_SOIL_C: dyn.soil_damping_n_s_m, k.P_BLADE_OFFSET: dyn.blade_offset_m, k.P_CELL_M: dyn.terrain_cell_m,
            k.P_X_MIN: self.x_min, k.P_N_CELLS: self.n_cells, k.P_EDGE_W: dyn.blade_edge_width_m,
            k.P_FEE_GAIN: dyn.fee_velocity_gain_s_m, k.P_RHO: self.rho, k.P_ALPHA: self.alpha, k.P_W: self.w,
            k.P_M_BLADE: m.blade_mass_kg, k.P_M_CHASSIS: m.chassis_mass_kg, k.P_LIMIT_X: m.horizontal_force_limit_n,
            k.P_LIMIT_Z: m.vertical_force_limit_n, k.P_MIN_REL: m.blade_min_rel_m, k.P_MAX_REL: m.blade_max_rel_m,
            k.P_MAX_SPEED: MAX_TARGET_SPEED_M_S, k.P_GRAVITY: GRAVITY_M_S2,
            k.P_SURCHARGE: e.surcharge, k.P_PENETRATION: e.penetration, k.P_CONTACT_DAMPING: e.contact_damping,
            k.P_BASE_FRICTION: e.base_friction, k.P_FORCE_SCALING: e.force_scaling, k.P_PARTICLES: e.particles,
            k.P_COMPACTION: e.compaction, k.P_NOISE: e.noise,
            k.P_SHED_TIME: e.surcharge_shed_time_s, k.P_PILE_CAPACITY: e.surcharge_capacity_m3,
            k.P_SURCHARGE_FEE_FACTOR: e.surcharge_fee_factor, k.P_FORCE_SCALE: e.force_scale,
            k.P_AREA_LIMIT: e.area_pressure_limit_pa, k.P_CHUNK: e.particle_chunk_m, k.P_LOSS_MAX: e.particle_loss_max,
            k.P_LOSS_TIME_LO: e.particle_loss_time_s[0], k.P_LOSS_TIME_HI: e.particle_loss_time_s[1],
            k.P_FULL_DEPTH: e.particle_full_depth_m, k.P_COMPACTION_GAIN: e.compaction_gain,
            k.P_COMPACTION_LENGTH: e.compaction_length_m, k.P_NOISE_X: e.noise_force_std_n[0],
            k.P_NOISE_Z: e.noise_force_std_n[1], k.P_DAMPING_PA_S_M: CONTACT_DAMPING_PA_S_M,
            k.P_FRICTION_V_REF: BASE_FRICTION_V_REF_M_S,
        }
        assert len(values) == k.N_PARAMS, "every kernel parameter is set"
        for index, value in values.items():
            p[index] = float(value)
        return p, np.array(dyn.probe_offsets_m, dtype=float)

    def kernel_arguments(self, i: int) -> tuple:
        """(state, episode, terrain, params, probes, rng) of episode ``i`` for ``kernel`` (views: the
        kernel advances this simulator)."""
        return self._state[i], self._episode[i], self.terrain[i], self._params, self._probes, self.rngs[i]

    # ------------------------------------------------------------------ state
    def reset(self) -> TickOutput:
        """Start every episode: vehicle at rest at x = 0, blade edge on the level surface."""
        b = self.batch
        z = lambda: np.zeros(b)  # noqa: E731
        self.tick = 0
        # every state variable is a column of one (B, N_STATE) array, the kernel's layout;
        # ``u_e`` is the elastic pre-failure compression of the soil [m], ``grip`` the
        # particle-conversion contact (1 = full contact)
        self._state = np.zeros((b, kernel.N_STATE))
        self.grip = np.ones(b)
        self.grip_tau = np.full(b, 0.05)
        self.terrain = np.zeros((b, self.n_cells))
        self.v_hist = np.zeros((VELOCITY_AVERAGE_SAMPLES, b, 2))  # newest first
        self.v_hist_count = 0
        self._v_hist_rows = np.zeros((b, VELOCITY_AVERAGE_SAMPLES, 2))  # the kernel's layout, newest first
        self.rngs = [np.random.default_rng(int(s.seed)) for s in self.specs]
        self.last_applied_u_zr = z()
        # time with the edge in the soil [s] (``travel.time_in_soil``, per substep): what force
        # terms see as ``ForceInputs.time_in_soil``; kept where they are evaluated (the reference
        # engine's substep, the compiled engine's with plugins)
        self.time_in_soil = z()
        # the blade starts in the patch under its edge, with an empty pile of that soil
        self.patch_index = self.patch_at(self.x_c + self.dyn.blade_offset_m)
        self.pile_gamma = self.patch_nominal[np.arange(b), self.patch_index.astype(np.int64), 2]
        self._push_velocity_history()
        return self._compiled_output(np.zeros((b, 2))) if self.engine == "compiled" else self._output(np.zeros((b, 2)))

    # ------------------------------------------------------------------ helpers
    def _state_column(j: int):  # noqa: N805 - a property factory used in the class body
        def get(self):
            return self._state[:, j].copy()

        def set_(self, value):
            self._state[:, j] = value

        return property(get, set_)

    x_c, vx_c = _state_column(kernel.S_X_C), _state_column(kernel.S_VX_C)
    z_c, vz_c = _state_column(kernel.S_Z_C), _state_column(kernel.S_VZ_C)
    z_rel, vz_rel = _state_column(kernel.S_Z_REL), _state_column(kernel.S_VZ_REL)
    u_e, grip, grip_tau = _state_column(kernel.S_U_E), _state_column(kernel.S_GRIP), _state_column(kernel.S_GRIP_TAU)
    pile_m3, distance_in_soil = _state_column(kernel.S_PILE), _state_column(kernel.S_DIST)
    # the patch the soil half last used, travel in soil when the edge entered it [m], the
    # pile's mean unit weight [N/m^3]
    patch_index, dist_entry = _state_column(kernel.S_PATCH), _state_column(kernel.S_DIST_ENTRY)
    pile_gamma = _state_column(kernel.S_PILE_GAMMA)
    del _state_column

    def _cell(self, x):
        i = np.floor((x - self.x_min) / self.dyn.terrain_cell_m).astype(np.int64)
        return np.clip(i, 0, self.n_cells - 2)

    def _height_at(self, x):
        return self.terrain[np.arange(self.batch), self._cell(x)]

    @staticmethod
    def _soil_at(loose, dense, i_d):
        """(..., 3) phi, c, gamma at relative density i_d [%] (...), by SoilType.at's rule."""
        return at_density(loose, dense, i_d[..., None])

    def patch_at(self, x):
        """Index (B,) of each episode's soil patch at edge x [m] (B,): the last whose start is
        <= x; the first patch also holds before the second's start."""
        return np.sum(np.asarray(x)[:, None] >= self.patch_x[:, 1:], axis=1)

    def _enter_patch(self, x_b):
        """The patch (B,) under the edge now; where the edge has crossed into another patch,
        its compaction starts from its own I_d (travel counted from here)."""
        j = self.patch_at(x_b)
        self.dist_entry = np.where(j != self.patch_index, self.distance_in_soil, self.dist_entry)
        self.patch_index = j
        return j

    def soil_in_effect(self, j=None):
        """(phi, c, gamma, I_d) now in patch ``j`` (B,) (default: the one the soil half last
        used): the catalogue at the patch's relative density compacted by the travel in it."""
        rows = np.arange(self.batch)
        j = self.patch_index.astype(np.int64) if j is None else j
        i_d = self.patch_i_d[rows, j]
        if self.effects.compaction:
            e = self.effects
            travel = self.distance_in_soil - self.dist_entry
            i_d = i_d + (100.0 - i_d) * e.compaction_gain * (1.0 - np.exp(-travel / e.compaction_length_m))
        props = self._soil_at(self.patch_loose[rows, j], self.patch_dense[rows, j], i_d)
        return props[:, 0], props[:, 1], props[:, 2], i_d

    def surcharge_n(self):
        """Weight of the surcharge pile Q [N]: its volume times its mean unit weight."""
        return self.pile_gamma * self.pile_m3 if self.effects.surcharge else np.zeros(self.batch)

    def depth(self):
        x_b = self.x_c + self.dyn.blade_offset_m
        surface_ahead = self.terrain[np.arange(self.batch), self._cell(x_b) + 1]
        return surface_ahead - (self.z_c + self.z_rel)

    # ------------------------------------------------------------------ stepping
    def step(self, u_zr, u_za, u_x) -> TickOutput:
        """Advance one 60 Hz tick under commands (arrays (B,) or scalars).

        u_zr: lift-joint target, edge height relative to the chassis reference [m] (clipped
        to the reach); u_za: the absolute target it came from (recorded only); u_x: chassis
        velocity command [m/s]. Non-finite commands raise ValueError (the ROS node sanitises
        its inputs before they get here).
        """
        b = self.batch
        cmds = {}
        for name, value in (("u_zr", u_zr), ("u_za", u_za), ("u_x", u_x)):
            a = np.broadcast_to(np.asarray(value, dtype=float), (b,))
            if not np.all(np.isfinite(a)):
                raise ValueError(f"command {name}={a[~np.isfinite(a)][0]} is not finite")
            cmds[name] = a
        u_zr = np.clip(cmds["u_zr"], self.m.blade_min_rel_m, self.m.blade_max_rel_m)
        u_x = np.clip(cmds["u_x"], -MAX_TARGET_SPEED_M_S, MAX_TARGET_SPEED_M_S)
        self.last_applied_u_zr = u_zr
        if self.engine == "compiled" and not self.plugins:
            forces = np.zeros((b, 2))
            for i in range(b):
                kernel.tick(*self.kernel_arguments(i), u_zr[i], u_x[i], forces[i])
            self.tick += 1
            self._push_velocity_history()
            return self._compiled_output(forces)
        substep = self._compiled_substep_with_plugins if self.engine == "compiled" else self._substep
        force_sum = np.zeros((b, 2))
        draws = [rng.random((self.dyn.substeps, 3)) for rng in self.rngs]
        uniforms = np.stack(draws, axis=1)  # (substeps, B, 3)
        for k in range(self.dyn.substeps):
            force_sum += substep(u_zr, u_x, uniforms[k])
        self.tick += 1
        forces = force_sum / self.dyn.substeps
        if self.effects.noise:
            std = np.asarray(self.effects.noise_force_std_n)
            forces = forces + np.stack([rng.standard_normal(2) for rng in self.rngs]) * std
        self._push_velocity_history()
        return self._compiled_output(forces) if self.engine == "compiled" else self._output(forces)

    def _compiled_substep_with_plugins(self, u_zr, u_x, uniform) -> np.ndarray:
        """A substep in the kernel's two halves with the user plugins' forces added between them,
        where ``_substep`` adds them."""
        k, b = kernel, self.batch
        f = np.empty((b, k.N_FORCE_INPUTS))
        k.substep_soil_batch(self._state, self._episode, self.terrain, self._params, np.ascontiguousarray(uniform), f)
        state = ForceInputs(
            t=np.full(b, self.tick / SAMPLE_RATE_HZ), dt=self.dt, x_b=f[:, k.F_X_B], z_b=f[:, k.F_Z_B],
            v_x=f[:, k.F_V_X], v_z=f[:, k.F_V_Z], d=f[:, k.F_D], q=f[:, k.F_Q], phi=f[:, k.F_PHI], c=f[:, k.F_C],
            gamma=f[:, k.F_GAMMA], delta=self.delta, c_a=self.c_a, rho=self.rho, alpha=self.alpha, w=self.w,
            blade_thickness=self.dyn.blade_edge_width_m, f_fee_x=f[:, k.F_FEE_X], f_fee_z=f[:, k.F_FEE_Z],
            distance_in_soil=self.distance_in_soil, relative_density_pct=f[:, k.F_I_D], time_in_soil=self.time_in_soil,
        )
        fx, fz = f[:, k.F_X].copy(), f[:, k.F_Z].copy()
        for plugin in self.plugins:
            tx, tz = plugin(state, b)
            fx, fz = fx + tx, fz + tz
        self.time_in_soil = self.time_in_soil + soil_time_step(f[:, k.F_D], self.dt)
        f[:, k.F_X], f[:, k.F_Z] = fx, fz
        measured = np.empty((b, 2))
        k.substep_machine_batch(self._state, self._episode, self.terrain, self._params, self._probes, u_zr, u_x, f,
                                measured)
        return measured

    def _substep(self, u_zr, u_x, uniform) -> np.ndarray:
        dyn, m, e, dt = self.dyn, self.m, self.effects, self.dt
        b = self.batch
        t = self.tick / SAMPLE_RATE_HZ
        x_b = self.x_c + dyn.blade_offset_m
        z_b = self.z_c + self.z_rel
        vz_b = self.vz_c + self.vz_rel
        vx = self.vx_c
        d = self.depth()
        in_soil = d > 0
        j = self._enter_patch(x_b)
        phi, c, gamma, i_d = self.soil_in_effect(j)
        q = self.surcharge_n()

        # --- FEE failure force (Eq. 2-10) and its direction (Eq. 8)
        delta_p, c_a_p = fee.velocity_corrected(self.delta, self.c_a, self.rho, self.alpha, vx, vz_b, dyn.fee_velocity_gain_s_m)
        beta = fee.beta_star(phi, delta_p, self.rho, self.alpha)
        q_fee = q * e.surcharge_fee_factor
        f_fail = fee.failure_force(phi, c, delta_p, c_a_p, gamma, self.rho, self.alpha, self.w, d, q_fee, beta)
        f_fail = np.where(np.isfinite(f_fail), np.maximum(f_fail, 0.0), 0.0)
        if e.force_scaling:
            area = submerged_area_m2(self.w, d, self.rho)
            f_fail = np.minimum(f_fail * e.force_scale, e.area_pressure_limit_pa * area)
        ex, ez = fee.force_xz(1.0, self.rho, delta_p, self.alpha)  # Eq. 8's direction of the failure force

        # --- elastic-perfectly-plastic soil contact along the failure-force direction
        v_n = vx * ex + vz_b * ez
        self.u_e = np.clip(self.u_e + v_n * dt, 0.0, f_fail / dyn.soil_stiffness_n_m)
        self.u_e = np.where(in_soil, self.u_e, 0.0)
        f_mag = np.clip(dyn.soil_stiffness_n_m * self.u_e + dyn.soil_damping_n_s_m * v_n, 0.0, f_fail)

        # --- particle conversion: failure events drop the grip, which recovers (default world)
        if e.particles:
            rate = np.maximum(vx, 0.0) / e.particle_chunk_m * in_soil
            event = uniform[:, 0] < rate * dt
            loss = e.particle_loss_max * uniform[:, 1] * np.clip(d / e.particle_full_depth_m, 0.0, 1.0)
            lo, hi = e.particle_loss_time_s
            self.grip = np.where(event, np.minimum(self.grip, 1.0 - loss), self.grip)
            self.grip_tau = np.where(event, lo + (hi - lo) * uniform[:, 2], self.grip_tau)
            self.grip = self.grip + (1.0 - self.grip) * np.minimum(dt / self.grip_tau, 1.0)
            f_mag = f_mag * self.grip
        fx, fz = f_mag * ex, f_mag * ez

        # --- other named effects and user plugins (force the blade exerts on the soil)
        state = ForceInputs(
            t=np.full(b, t), dt=dt, x_b=x_b, z_b=z_b, v_x=vx, v_z=vz_b, d=d, q=q, phi=phi, c=c,
            gamma=gamma, delta=self.delta, c_a=self.c_a, rho=self.rho, alpha=self.alpha, w=self.w,
            blade_thickness=dyn.blade_edge_width_m, f_fee_x=fx, f_fee_z=fz,
            distance_in_soil=self.distance_in_soil, relative_density_pct=self.patch_i_d[np.arange(b), j],
            time_in_soil=self.time_in_soil,
        )
        self.time_in_soil = self.time_in_soil + soil_time_step(d, dt)
        for name, term in FORCE_TERMS.items():
            if getattr(e, name):
                tx, tz = term(state)
                fx, fz = fx + tx, fz + tz
        for plugin in self.plugins:
            tx, tz = plugin(state, b)
            fx, fz = fx + tx, fz + tz

        # --- blade vertical: lift joint, then penetration as a one-sided rigid-plastic constraint
        f_joint = np.clip(
            dyn.joint_stiffness_n_m * (u_zr - self.z_rel) - dyn.joint_damping_n_s_m * self.vz_rel,
            -m.vertical_force_limit_n,
            m.vertical_force_limit_n,
        )
        weight = m.blade_mass_kg * GRAVITY_M_S2
        probes = np.mean([self._height_at(self.x_c + o) for o in dyn.probe_offsets_m], axis=0)
        w_c = dyn.chassis_height_omega_rad_s
        a_zc = w_c * w_c * (probes - self.z_c) - 2.0 * w_c * self.vz_c
        if e.penetration:
            sinking = vz_b + (f_joint - weight - fz) / m.blade_mass_kg * dt  # edge velocity without the soil's support
            need = np.maximum(-sinking, 0.0) * m.blade_mass_kg / dt
            reaction = np.minimum(need, penetration_capacity(state, dyn.blade_edge_width_m))
            fz = fz - reaction  # the edge pushes the soil down by what the soil holds up
            if e.base_friction:
                tx, _ = base_friction_force(state, normal_down_n=reaction + np.maximum(-state.f_fee_z, 0.0))
                fx = fx + tx
        elif e.base_friction:
            tx, _ = base_friction_force(state)
            fx = fx + tx
        a_zb = (f_joint - weight - fz) / m.blade_mass_kg

        # --- chassis + blade in x (semi-implicit Euler)
        f_motor = np.clip(dyn.motor_gain_n_s_m * (u_x - vx), -m.horizontal_force_limit_n, m.horizontal_force_limit_n)
        a_x = (f_motor - fx) / (m.chassis_mass_kg + m.blade_mass_kg)
        self.vx_c = self.vx_c + a_x * dt
        self.x_c = self.x_c + self.vx_c * dt
        self.vz_c = self.vz_c + a_zc * dt
        self.z_c = self.z_c + self.vz_c * dt
        self.vz_rel = self.vz_rel + (a_zb - a_zc) * dt
        self.z_rel = self.z_rel + self.vz_rel * dt

        # --- the edge cuts the heightfield; bookkeeping of pile and distance in soil
        new_x_b = self.x_c + dyn.blade_offset_m
        idx = (np.arange(b), self._cell(new_x_b))
        self.terrain[idx] = np.minimum(self.terrain[idx], self.z_c + self.z_rel)
        # ground-truth travel: the estimator's increment per substep at the chassis' own speed
        # (``soil_physics.travel`` says why the two sums exist)
        advance = soil_advance(self.vx_c, d, dt)
        self.distance_in_soil = self.distance_in_soil + advance
        if e.surcharge:
            inflow = self.w * np.maximum(d, 0.0) * advance * (1.0 - self.pile_m3 / e.surcharge_capacity_m3)
            kept = self.pile_m3 + inflow - self.pile_m3 * dt / e.surcharge_shed_time_s
            # the cut soil (this patch's, at its nominal gamma) mixes into the pile: the pile
            # keeps what it holds across a boundary and its weight changes only as it refills
            mixing = (inflow > 0.0) & (kept > 0.0)
            gamma_cut = self.patch_nominal[np.arange(b), j, 2]
            share = inflow / np.where(mixing, kept, 1.0)
            self.pile_gamma = np.where(mixing, self.pile_gamma + (gamma_cut - self.pile_gamma) * share, self.pile_gamma)
            self.pile_m3 = np.clip(kept, 0.0, e.surcharge_capacity_m3)

        # measured: lift/push constraint forces on the blade, static weight tared
        return np.stack([m.blade_mass_kg * a_x + fx, f_joint - weight], axis=1)

    # ------------------------------------------------------------------ outputs
    def _push_velocity_history(self):
        if self.engine == "compiled":
            count = self.v_hist_count
            for i in range(self.batch):
                count = kernel.push_velocity(self._state[i], self._v_hist_rows[i], self.v_hist_count)
            self.v_hist_count = count
            return
        vz_b = self.vz_c + self.vz_rel
        self.v_hist = np.roll(self.v_hist, 1, axis=0)
        self.v_hist[0] = np.stack([self.vx_c, vz_b], axis=1)
        self.v_hist_count = min(self.v_hist_count + 1, VELOCITY_AVERAGE_SAMPLES)

    def averaged_velocity(self):
        """§3.1: v_t = avg([v_x^c, v_z^b]) over the last 10 samples (fewer at the start)."""
        if self.engine == "compiled":
            v = self._v_hist_rows[:, : self.v_hist_count].mean(axis=1)
        else:
            v = self.v_hist[: self.v_hist_count].mean(axis=0)
        return v[:, 0], v[:, 1]

    def _compiled_output(self, forces: np.ndarray) -> TickOutput:
        """``_output`` computed by ``kernel.output_row``, row by row."""
        b = self.batch
        positions, velocities, extras = np.zeros((b, 3)), np.zeros((b, 3)), np.zeros((b, 2))
        known, truth = np.zeros((b, len(KNOWN_PARAMS))), np.zeros((b, len(GROUND_TRUTH_PARAMS)))
        for i in range(b):
            kernel.output_row(self._state[i], self._episode[i], self.terrain[i], self._params, self._v_hist_rows[i],
                              self.v_hist_count, positions[i], velocities[i], known[i], truth[i], extras[i])
        return TickOutput(stamp_ns=tick_stamp_ns(self.tick), positions=positions, velocities=velocities, forces=forces,
                          known=known, truth=truth, extras=extras, applied_u_zr=self.last_applied_u_zr.copy())

    def _output(self, forces: np.ndarray) -> TickOutput:
        b = self.batch
        x_b = self.x_c + self.dyn.blade_offset_m
        z_b = self.z_c + self.z_rel
        vz_b = self.vz_c + self.vz_rel
        d = self.depth()
        q = self.surcharge_n()
        v_x, v_z = self.averaged_velocity()
        nominal = self.patch_nominal[np.arange(b), self.patch_at(x_b)]  # the ground truth is the soil under the edge
        phi0, c0, gamma0 = nominal[:, 0], nominal[:, 1], nominal[:, 2]
        full = lambda v: np.full(b, float(v))  # noqa: E731
        known = dict(c_a=self.c_a, gamma=gamma0, rho=full(self.rho), alpha=full(self.alpha), w=full(self.w), d=d, q=q, v_x=v_x, v_z=v_z)
        truth = dict(known, phi=phi0, c=c0, delta=self.delta)
        delta_p, _ = fee.velocity_corrected(self.delta, self.c_a, self.rho, self.alpha, v_x, v_z, self.dyn.fee_velocity_gain_s_m)
        truth["beta"] = fee.recorded_beta_star(phi0, delta_p, self.rho, self.alpha)
        return TickOutput(
            stamp_ns=tick_stamp_ns(self.tick),
            positions=np.stack([x_b, z_b, self.z_c], axis=1),
            velocities=np.stack([vz_b, self.vx_c, self.vz_c], axis=1),
            forces=forces,
            known=np.stack([known[k] for k in KNOWN_PARAMS], axis=1),
            truth=np.stack([truth[k] for k in GROUND_TRUTH_PARAMS], axis=1),
            extras=np.stack([self.x_c, self.vx_c], axis=1),
            applied_u_zr=self.last_applied_u_zr.copy(),
        )
