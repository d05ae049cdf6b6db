"""Force plugins used by the tests and the hidden-effect tables of docs/finding_missing_physics.md (loaded as ``tests.sim_plugins:<name>``,
e.g. ``soil_sim_batch ... --plugin "tests.sim_plugins:clay_entry_drag k=2"`` from the repository root).

tests/ is a package and pytest puts the repository root on sys.path, so the simulator's plugin
loader (importlib.import_module) finds this module by that name; tests/ itself must never be on
sys.path, where its package-named folders would shadow the project's packages.
"""
from __future__ import annotations

import numpy as np


def constant_force(state, f_x: float = 1000.0, f_z: float = 0.0):
    """A constant extra resistance [N] (blade on soil), whether or not the blade is in the soil."""
    return np.full_like(state.d, float(f_x)), np.full_like(state.d, float(f_z))


def nan_force(state):
    """Returns NaN in x: the simulator must refuse it, naming the plugin and the field."""
    return np.full_like(state.d, np.nan), np.zeros_like(state.d)


def matrix_force(state):
    """Returns a (B, 2) array for f_x: wrong shape."""
    return np.zeros((len(state.d), 2)), 0.0


def too_long_force(state):
    """Returns a 1-D f_x of length B + 2: wrong shape."""
    return np.zeros(len(state.d) + 2), 0.0


SEEN_DENSITY: list[tuple[np.ndarray, np.ndarray]] = []


def record_density(state):
    """No force; appends (x_b, relative_density_pct) of every substep to SEEN_DENSITY, so a test
    sees what the simulator hands its plugins."""
    SEEN_DENSITY.append((np.array(state.x_b, dtype=float), np.array(state.relative_density_pct, dtype=float)))
    return 0.0, 0.0


SEEN_TIME: list = []


def record_time_in_soil(state):
    """No force; appends (d, time_in_soil, dt) of every substep to SEEN_TIME."""
    SEEN_TIME.append((np.array(state.d, dtype=float), np.array(state.time_in_soil, dtype=float), float(state.dt)))
    return 0.0, 0.0


def sinking_resistance(state, k: float = 3.0, v0: float = 0.01, axis: str = "z"):
    """Hidden effect whose form is not in the catalogue: while the edge sinks, the soil resists,
    k γ w d² · min(max(−v_z, 0)/v0, 1) [N], pressing down (axis 'z') or dragging (axis 'x');
    nothing while the edge holds its depth or rises. The gate ramps on over the first ``v0``
    [m/s] of sinking speed (not the form library's hard gate)."""
    d = np.maximum(np.asarray(state.d, dtype=float), 0.0)
    gate = np.clip(-np.asarray(state.v_z, dtype=float) / float(v0), 0.0, 1.0)
    force = float(k) * state.gamma * state.w * d**2 * gate
    return (force, np.zeros_like(d)) if axis == "x" else (np.zeros_like(d), -force)


def entry_resistance(state, k: float = 2.0, s0: float = 1.0):
    """Hidden effect whose form is not in the catalogue: undisturbed soil at the start of a cut
    resists more, and the extra drag fades as the blade travels, F_x = k γ w d² · exp(−s/s0) [N]
    (s the blade's travel in soil, ``s0`` [m] between the form library's decay lengths)."""
    d = np.maximum(np.asarray(state.d, dtype=float), 0.0)
    fade = np.exp(-np.asarray(state.distance_in_soil, dtype=float) / float(s0))
    return float(k) * state.gamma * state.w * d**2 * fade, np.zeros_like(d)


def saturating_drag(state, k: float = 1.0, v0: float = 0.3, p_pa: float = 10e3):
    """Hidden effect whose form is not in the catalogue: a drag that grows with speed and saturates,
    F_x = k w d p · tanh(v_x / v0) [N] (the catalogue's rate-dependent strength is linear in v_x)."""
    d = np.maximum(np.asarray(state.d, dtype=float), 0.0)
    v = np.maximum(np.asarray(state.v_x, dtype=float), 0.0)
    return float(k) * state.w * d * float(p_pa) * np.tanh(v / float(v0)), np.zeros_like(d)


def deep_drag(state, k: float = 3.0, d0: float = 0.2):
    """Hidden effect in neither the catalogue nor the form library: extra drag only below a depth,
    F_x = k γ w d² · [d > ``d0``] [N] (a harder layer the blade reaches only in deep cuts)."""
    d = np.maximum(np.asarray(state.d, dtype=float), 0.0)
    return float(k) * state.gamma * state.w * d**2 * (d > float(d0)), np.zeros_like(d)


def clay_entry_drag(state, k: float = 2.0, s0: float = 1.0, phi_max_rad: float = 0.45):
    """Hidden effect in one soil only: ``entry_resistance`` where φ < ``phi_max_rad`` (of the
    catalogue's soils at I_d 0-100 %, only clay)."""
    fx, fz = entry_resistance(state, k, s0)
    return fx * (np.asarray(state.phi, dtype=float) < float(phi_max_rad)), fz


def cohesive_speed_drag(state, k: float = 1.0, v0: float = 1.0, c_min_pa: float = 500.0):
    """Hidden effect in cohesive soils only: ``saturating_drag`` with ``v0`` where c > ``c_min_pa``."""
    fx, fz = saturating_drag(state, k, v0)
    return fx * (np.asarray(state.c, dtype=float) > float(c_min_pa)), fz


def speed_suction(state, k: float = 1.0, v0: float = 0.3, p_pa: float = 10e3):
    """Hidden effect: the ``saturating_drag`` form pulling the blade down, F_z = −k w d p tanh(v_x / v0) [N]."""
    fx, _ = saturating_drag(state, k, v0, p_pa)
    return np.zeros_like(fx), -fx


def rising_press(state, k: float = 2.0, v0: float = 0.01):
    """Hidden effect: while the edge rises the soil presses it down, F_z = −k γ w d² min(max(v_z, 0)/v0, 1) [N]."""
    d = np.maximum(np.asarray(state.d, dtype=float), 0.0)
    gate = np.clip(np.asarray(state.v_z, dtype=float) / float(v0), 0.0, 1.0)
    return np.zeros_like(d), -float(k) * state.gamma * state.w * d**2 * gate


def in_soil_constant_drag(state, f_x: float = 1500.0):
    """Hidden effect: a constant drag [N] while the edge is in the soil (no form of the library is a constant)."""
    d = np.asarray(state.d, dtype=float)
    return float(f_x) * (d > 0), np.zeros_like(d)


def speed_squared_drag(state, k: float = 1.0, p_pa: float = 10e3):
    """Hidden effect: F_x = k w d p v_x² [N] (soil inertia's column without its γ)."""
    d = np.maximum(np.asarray(state.d, dtype=float), 0.0)
    return float(k) * state.w * d * float(p_pa) * np.asarray(state.v_x, dtype=float) ** 2, np.zeros_like(d)


def chatter(state, k: float = 0.5, f_hz: float = 29.9, p_pa: float = 10e3):
    """A zero-mean blade chatter, F_x = k w d p · sin(2π f t) [N], the same phase in every episode:
    near a multiple of 60 Hz / stride, one analysed tick in ``stride`` sees it as a slow signal (an
    outside reader's)."""
    d = np.maximum(np.asarray(state.d, dtype=float), 0.0)
    wave = np.sin(2.0 * np.pi * float(f_hz) * np.asarray(state.t, dtype=float)) * np.ones_like(d)
    return float(k) * state.w * d * float(p_pa) * wave, np.zeros_like(d)


def time_drag(state, k: float = 1.0, t0: float = 10.0, p_pa: float = 10e3):
    """Hidden effect on a variable no model input carries: F_x = k w d p · min(t / t0, 1) [N], a
    drag that grows with time in the episode (t the simulation time [s]), not with travel."""
    if not float(t0) > 0:
        raise ValueError(f"time_drag t0={t0!r} must be > 0 [s]")
    d = np.maximum(np.asarray(state.d, dtype=float), 0.0)
    ramp = np.minimum(np.asarray(state.t, dtype=float) * np.ones_like(d) / float(t0), 1.0)
    return float(k) * state.w * d * float(p_pa) * ramp, np.zeros_like(d)


def layer_drag(state, k: float = 3.0, d0: float = 0.15, p_pa: float = 10e3):
    """Hidden effect: a harder layer below ``d0`` [m], F_x = k w (d − d0)+ p [N] (the face area in
    the layer times a pressure; the library's ``wd_x*below…`` form, not a catalogue term)."""
    d = np.maximum(np.asarray(state.d, dtype=float), 0.0)
    return float(k) * state.w * np.maximum(d - float(d0), 0.0) * float(p_pa), np.zeros_like(d)


def clay_viscous_drag(state, k: float = 1.0, p_pa: float = 20e3, c_min_pa: float = 1.5e3, phi_max_rad: float = 0.48):
    """Hidden effect in clay only (of the catalogue's soils, c > ``c_min_pa`` and φ < ``phi_max_rad``
    hold for clay at every I_d and nothing else): a viscous drag F_x = k w d p (v_x / 1 m/s) [N]."""
    d = np.maximum(np.asarray(state.d, dtype=float), 0.0)
    clay = (np.asarray(state.c, dtype=float) > float(c_min_pa)) & (np.asarray(state.phi, dtype=float) < float(phi_max_rad))
    return float(k) * state.w * d * float(p_pa) * np.maximum(np.asarray(state.v_x, dtype=float), 0.0) * clay, np.zeros_like(d)


def _fading(state, v0_m_s: float):
    """exp(−max(v_x, 0) / v0): 1 at rest, fading with forward speed over ``v0_m_s`` [m/s]."""
    return np.exp(-np.maximum(np.asarray(state.v_x, dtype=float), 0.0) / float(v0_m_s))


def speed_weakening(state, k: float = 2.0, v0: float = 0.3):
    """Hidden effect: a strength the moving blade loses, F_x = k γ w d² exp(−v_x / v0) [N], v0 [m/s]
    (rate weakening: the most at rest, fading with speed; the library's ``gd2w_x*fadevx…`` forms)."""
    d = np.maximum(np.asarray(state.d, dtype=float), 0.0)
    return float(k) * state.gamma * state.w * d**2 * _fading(state, v0), np.zeros_like(d)


def dense_only_drag(state, k: float = 1.0, p_pa: float = 10e3, gamma_min_n_m3: float = 19.0e3):
    """Hidden effect in the dense soils only: F_x = k w d p where γ > ``gamma_min_n_m3`` (a drag
    with cohesion's depth profile, which those soils' θ can absorb)."""
    d = np.maximum(np.asarray(state.d, dtype=float), 0.0)
    dense = np.asarray(state.gamma, dtype=float) > float(gamma_min_n_m3)
    return float(k) * state.w * d * float(p_pa) * dense, np.zeros_like(d)


def sqrt_depth_drag(state, k: float = 1.0, p_pa: float = 10e3, d_ref_m: float = 0.1):
    """Hidden effect concave in depth (no form of the library): F_x = k w p √(d d_ref) [N]."""
    d = np.maximum(np.asarray(state.d, dtype=float), 0.0)
    return float(k) * state.w * float(p_pa) * np.sqrt(d * float(d_ref_m)) * (d > 0), np.zeros_like(d)


def travel_wave(state, f_n: float = 1000.0, wavelength_m: float = 0.7):
    """Hidden effect with zero mean (stick-slip with travel): F_x = f_n sin(2π s / λ) [N] in soil, a
    force no mean over an episode shows, only its structure along the travel s."""
    d = np.asarray(state.d, dtype=float)
    s = np.asarray(state.distance_in_soil, dtype=float)
    return float(f_n) * np.sin(2.0 * np.pi * s / float(wavelength_m)) * (d > 0), np.zeros_like(d)


def speed_squared_press(state, k: float = 2.0):
    """Hidden effect in z: F_z = −k γ w d² (v_x / 1 m/s)² [N], pressing the blade down harder the
    faster the cut (the soil's momentum turned down the blade face: a z force no catalogue term has)."""
    d = np.maximum(np.asarray(state.d, dtype=float), 0.0)
    v = np.asarray(state.v_x, dtype=float)
    return np.zeros_like(d), -float(k) * state.gamma * state.w * d**2 * v**2


def fading_lift(state, k: float = 1.0, v0: float = 0.3, p_pa: float = 10e3):
    """Hidden effect in z: F_z = +k w d p exp(−v_x / v0) [N], v0 [m/s] (the blade's force on the soil,
    z up): the soil holds the blade down most when it barely moves, the sign opposite the library's
    z scales, so the search must find it as a relief."""
    d = np.maximum(np.asarray(state.d, dtype=float), 0.0)
    return np.zeros_like(d), float(k) * state.w * d * float(p_pa) * _fading(state, v0)


def clay_press(state, k: float = 2.0, phi_max_rad: float = 0.45):
    """Hidden effect in z in the weakest soils only: F_z = −k γ w d² where φ < ``phi_max_rad``
    (of the catalogue's soils: clay, and loam at I_d 0 %)."""
    d = np.maximum(np.asarray(state.d, dtype=float), 0.0)
    weak = np.asarray(state.phi, dtype=float) < float(phi_max_rad)
    return np.zeros_like(d), -float(k) * state.gamma * state.w * d**2 * weak


def surface_crust(state, k: float = 1.0, p_pa: float = 20e3, crust_m: float = 0.05):
    """Hidden effect: a crust in the top ``crust_m`` [m], F_x = k w p min(d, crust) [N] (growing
    with depth through the crust, constant below it: at the grid's depths, a constant drag)."""
    d = np.maximum(np.asarray(state.d, dtype=float), 0.0)
    return float(k) * state.w * float(p_pa) * np.minimum(d, float(crust_m)), np.zeros_like(d)


def slow_stick(state, k: float = 2.0, v_max: float = 0.5):
    """Hidden effect with a hard speed gate: F_x = k γ w d² while 0 < v_x < ``v_max`` [m/s] (soil
    that sticks to a slow blade), nothing faster."""
    d = np.maximum(np.asarray(state.d, dtype=float), 0.0)
    v = np.asarray(state.v_x, dtype=float)
    return float(k) * state.gamma * state.w * d**2 * ((v > 0) & (v < float(v_max))), np.zeros_like(d)


def fee_tilt(state, k: float = 0.3):
    """Hidden effect: the soil's resultant tilted down, F_z = −k F_x^FEE [N] (a z force in
    proportion to the FEE's own drag, which δ can absorb)."""
    fx = np.asarray(state.f_fee_x, dtype=float)
    return np.zeros_like(fx), -float(k) * fx


def dense_rate_drag(state, k: float = 1.0, p_pa: float = 20e3):
    """Hidden effect: a viscous drag that grows with density, F_x = k w d p (v_x / 1 m/s)(I_d / 100) [N]."""
    d = np.maximum(np.asarray(state.d, dtype=float), 0.0)
    v = np.maximum(np.asarray(state.v_x, dtype=float), 0.0)
    i_d = np.asarray(state.relative_density_pct, dtype=float)
    return float(k) * state.w * d * float(p_pa) * v * i_d / 100.0, np.zeros_like(d)


def layer_lift(state, k: float = 3.0, d0: float = 0.15, p_pa: float = 10e3):
    """Hidden effect in z: a hard layer below ``d0`` [m] pushing the blade up, F_z = +k w (d − d0)+ p
    [N] (on the soil, z up)."""
    d = np.maximum(np.asarray(state.d, dtype=float), 0.0)
    return np.zeros_like(d), float(k) * state.w * np.maximum(d - float(d0), 0.0) * float(p_pa)


def rising_relief(state, k: float = 2.0, v0: float = 0.01):
    """Hidden effect: the drag drops while the edge rises, F_x = −k γ w d² min(max(v_z, 0)/v0, 1) [N]
    (ramping on over the first ``v0`` [m/s] of rising speed)."""
    d = np.maximum(np.asarray(state.d, dtype=float), 0.0)
    gate = np.clip(np.asarray(state.v_z, dtype=float) / float(v0), 0.0, 1.0)
    return -float(k) * state.gamma * state.w * d**2 * gate, np.zeros_like(d)


def load_cell_gain(state, k: float = 0.15):
    """Hidden effect on the measurement, not the soil: the force sensor reads (1 + k) times the soil's
    force, F = k F^FEE on both axes (a load cell's gain error)."""
    return float(k) * np.asarray(state.f_fee_x, dtype=float), float(k) * np.asarray(state.f_fee_z, dtype=float)


def hard_spot(state, k: float = 1.0, p_pa: float = 20e3, x0_m: float = 4.0, x1_m: float = 6.0):
    """Hidden effect at one place along the path: a buried hard spot between blade edge x = ``x0_m``
    and ``x1_m`` [m], F_x = k w d p there (a root or a boulder bed; no soil or motion variable has it)."""
    d = np.maximum(np.asarray(state.d, dtype=float), 0.0)
    x = np.asarray(state.x_b, dtype=float)
    inside = (x >= float(x0_m)) & (x <= float(x1_m))
    return float(k) * state.w * d * float(p_pa) * inside, np.zeros_like(d)


def log_rate_drag(state, k: float = 1.0, p_pa: float = 5e3, v0: float = 0.05):
    """Hidden effect: a strength that grows with the logarithm of the shear rate (the usual
    rate law of clays), F_x = k w d p ln(1 + v_x / v0) [N], v0 [m/s]: no form of the library."""
    d = np.maximum(np.asarray(state.d, dtype=float), 0.0)
    v = np.maximum(np.asarray(state.v_x, dtype=float), 0.0)
    return float(k) * state.w * d * float(p_pa) * np.log1p(v / float(v0)), np.zeros_like(d)


def remoulding_drag(state, k: float = 1.0, p_pa: float = 20e3, tau0_s: float = 2.0):
    """Hidden effect: a strength the soil loses as the blade remoulds it, F_x = k w d p exp(−τ / τ0)
    [N], τ the time in soil [s] (the library's decays are 1 and 3 s)."""
    d = np.maximum(np.asarray(state.d, dtype=float), 0.0)
    tau = np.asarray(state.time_in_soil, dtype=float)
    return float(k) * state.w * d * float(p_pa) * np.exp(-tau / float(tau0_s)), np.zeros_like(d)


def pile_lift(state, k: float = 0.5, v0: float = 0.5):
    """Hidden effect in z: the pile in front of the blade lifts it more the faster it rolls,
    F_z = +k Q tanh(v_x / v0) [N] (on the soil, z up; Q the surcharge weight)."""
    v = np.maximum(np.asarray(state.v_x, dtype=float), 0.0)
    q = np.asarray(state.q, dtype=float)
    return np.zeros_like(q), float(k) * q * np.tanh(v / float(v0))


def adhesion_pull(state, k: float = 0.5):
    """Hidden effect in z: adhesion pulling the blade down in proportion to the soil's cohesion,
    F_z = −k c w d [N] (on the soil, z up), only where c > 0."""
    d = np.maximum(np.asarray(state.d, dtype=float), 0.0)
    c = np.maximum(np.asarray(state.c, dtype=float), 0.0)
    return np.zeros_like(d), -float(k) * c * state.w * d


def vertical_damping(state, k: float = 2.0, p_pa: float = 10e3, v0: float = 0.05):
    """Hidden effect in z against the edge's vertical motion: on the soil F_z = +k w d p_pa
    clip(v_z / v0, −1, 1) [N] (sinking presses the soil down harder, rising pulls it up)."""
    d = np.maximum(np.asarray(state.d, dtype=float), 0.0)
    g = np.clip(np.asarray(state.v_z, dtype=float) / float(v0), -1.0, 1.0)
    return np.zeros_like(d), float(k) * state.w * d * float(p_pa) * g


def density_drag(state, k: float = 2.0):
    """Hidden effect: a drag growing with relative density only, F_x = k (I_d / 100) γ w d² [N]."""
    d = np.maximum(np.asarray(state.d, dtype=float), 0.0)
    i_d = np.asarray(state.relative_density_pct, dtype=float)
    return float(k) * i_d / 100.0 * state.gamma * state.w * d**2, np.zeros_like(d)


def pile_travel_drag(state, k: float = 1.0, s0: float = 2.0):
    """Hidden effect: a drag in proportion to the surcharge pile that builds up with travel,
    F_x = k Q (1 − exp(−s / s0)) [N] in soil (s the travel in soil)."""
    q = np.asarray(state.q, dtype=float)
    s = np.asarray(state.distance_in_soil, dtype=float)
    d = np.asarray(state.d, dtype=float)
    return float(k) * q * (1.0 - np.exp(-s / float(s0))) * (d > 0), np.zeros_like(q)


def cubic_depth_drag(state, k: float = 1.0, d_ref_m: float = 0.1):
    """Hidden effect steeper in depth than any FEE term: F_x = k γ w d³ / d_ref [N] (a drag that
    grows as the failure wedge's volume times its depth; the library has d² forms times d)."""
    d = np.maximum(np.asarray(state.d, dtype=float), 0.0)
    return float(k) * state.gamma * state.w * d**3 / float(d_ref_m), np.zeros_like(d)


def time_oscillation(state, f_n: float = 1500.0, period_s: float = 1.3):
    """Hidden effect with zero mean in time (a machine vibration): F_x = f_n sin(2π t / T) [N] while
    in the soil, t the time in soil; no soil property and no mean force: never a named mechanism."""
    d = np.asarray(state.d, dtype=float)
    t = np.asarray(state.time_in_soil, dtype=float)
    return float(f_n) * np.sin(2.0 * np.pi * t / float(period_s)) * (d > 0), np.zeros_like(d)


def soft_floor_lift(state, k: float = 1.0, p_pa: float = 20e3, d_s_m: float = 0.05):
    """Hidden effect in z saturating with depth: F_z = +k w p d_s tanh(d / d_s) [N] (z up: a floor
    that pushes the blade up by the same amount once the edge is a few cm in; no form of the library
    saturates in depth)."""
    d = np.maximum(np.asarray(state.d, dtype=float), 0.0)
    return np.zeros_like(d), float(k) * state.w * float(p_pa) * float(d_s_m) * np.tanh(d / float(d_s_m))


def speed_depth_drag(state, k: float = 1.0):
    """Hidden effect linear in speed: F_x = k γ w d² (v_x / 1 m/s) [N] (a viscous drag on the wedge)."""
    d = np.maximum(np.asarray(state.d, dtype=float), 0.0)
    return float(k) * state.gamma * state.w * d**2 * np.maximum(np.asarray(state.v_x, dtype=float), 0.0), np.zeros_like(d)


# Eight more hidden effects no earlier run had tried (2026-12-02; docs/finding_missing_physics.md's table)
def fast_gate_drag(state, k: float = 2.0, v_min: float = 0.6):
    """Hidden effect with a hard speed gate: F_x = k γ w d² only while v_x > v_min [m/s]."""
    d = np.maximum(np.asarray(state.d, dtype=float), 0.0)
    return float(k) * state.gamma * state.w * d**2 * (np.asarray(state.v_x, dtype=float) > float(v_min)), np.zeros_like(d)


def fee_time_drag(state, k: float = 0.3, tau0_s: float = 5.0):
    """Hidden effect growing with time in soil on the FEE's own scale: F_x = k F_FEE,x (1 − exp(−τ / τ0))
    (τ0 between the library's 3 and 10 s)."""
    d = np.maximum(np.asarray(state.d, dtype=float), 0.0)
    tau = np.asarray(state.time_in_soil, dtype=float)
    return float(k) * np.asarray(state.f_fee_x, dtype=float) * (1.0 - np.exp(-tau / float(tau0_s))) * (d > 0), np.zeros_like(d)


def sqrt_speed_drag(state, k: float = 1.5, p_pa: float = 10e3):
    """Hidden effect with a power law in speed the library lacks: F_x = k w d p · sqrt(v_x / 1 m/s)."""
    d = np.maximum(np.asarray(state.d, dtype=float), 0.0)
    return float(k) * state.w * d * float(p_pa) * np.sqrt(np.maximum(np.asarray(state.v_x, dtype=float), 0.0)), np.zeros_like(d)


def speed_tilt(state, k: float = 0.3):
    """Hidden effect tilting the resultant down more the faster the cut: F_z = −k F_FEE,x (v_x / 1 m/s)."""
    d = np.maximum(np.asarray(state.d, dtype=float), 0.0)
    v = np.maximum(np.asarray(state.v_x, dtype=float), 0.0)
    return np.zeros_like(d), -float(k) * np.asarray(state.f_fee_x, dtype=float) * v * (d > 0)


def capped_travel_drag(state, k: float = 1.5, p_pa: float = 10e3, s_cap_m: float = 3.0):
    """Hidden effect growing linearly with travel and capped: F_x = k w d p · min(s / s_cap, 1)."""
    d = np.maximum(np.asarray(state.d, dtype=float), 0.0)
    s = np.asarray(state.distance_in_soil, dtype=float)
    return float(k) * state.w * d * float(p_pa) * np.minimum(s / float(s_cap_m), 1.0) * (d > 0), np.zeros_like(d)


def phi_drag(state, k: float = 3.0):
    """Hidden effect on the soil's own friction angle: F_x = k γ w d² sin φ."""
    d = np.maximum(np.asarray(state.d, dtype=float), 0.0)
    return float(k) * state.gamma * state.w * d**2 * np.sin(np.asarray(state.phi, dtype=float)), np.zeros_like(d)


def cohesive_suction(state, k: float = 1.0, v0: float = 1.0):
    """Hidden effect in z in proportion to cohesion, growing with speed: F_z = +k c w d tanh(v_x / v0)
    (on the soil, z up: the soil holding the blade down)."""
    d = np.maximum(np.asarray(state.d, dtype=float), 0.0)
    v = np.maximum(np.asarray(state.v_x, dtype=float), 0.0)
    return np.zeros_like(d), float(k) * state.c * state.w * d * np.tanh(v / float(v0))


def log_time_drag(state, k: float = 1.5, p_pa: float = 10e3, t0_s: float = 1.0):
    """Hidden effect growing with the logarithm of time in soil, without saturating (creep-like):
    F_x = k w d p · ln(1 + τ / t0) / ln 11."""
    d = np.maximum(np.asarray(state.d, dtype=float), 0.0)
    tau = np.asarray(state.time_in_soil, dtype=float)
    return float(k) * state.w * d * float(p_pa) * np.log1p(tau / float(t0_s)) / np.log(11.0) * (d > 0), np.zeros_like(d)
