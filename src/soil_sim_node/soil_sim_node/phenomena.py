"""Measure the paper's simulator phenomena and report them as plain numbers (no ROS, no plots).

Wagner et al. describe what their Vortex set-up does (§2.1.2, §3.1-3.2); this module runs small
vectorised batches of episodes of our simulator and returns, for each phenomenon, plain
dataclasses of numbers that ``tests/soil_sim_node/test_simulator.py`` asserts on and ``format_report``
prints (``soil_sim_report`` console script, ``soil_sim_node.report``):

a. ``depth_vs_density``   deep targets in dense Clay/Loam hit the 20 kN tractive limit, the
                          anti-stall controller raises the blade, mean cut depth falls with I_d.
b. ``surcharge_growth``   the surcharge Q grows through a default-world episode; Q = 0 in fee.
c. ``fee_force_match``    in the fee world the measured force is the FEE force of the published
                          ground-truth Θ up to the joint dynamics (inertia removed exactly from
                          the recorded velocities: m_b dv/dt).
d. ``open_loop_comparison`` the same command sequence (recorded in a fee episode) replayed into
                          both worlds (``replay_commands``): default forces exceed fee forces.
e. ``force_oscillations`` detrended force oscillations in dense default-world soils vs loose
                          soils and the fee world (paper: ~5 kN in x, ~10 kN in z).

Conventions: forces are the measured blade forces (x forward, z up, blade on soil, N); "tail"
is the last ``tail_s`` seconds of an episode; Episode row k is the state after k ticks, the
force measured over the tick that ended there and the command answered to it (rollout.py).
"""
from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field
from typing import Callable, Iterable, Mapping, Sequence

import numpy as np

from soil_physics import fee
from soil_physics.blade_inertia import inertia_force_rows
from soil_msgs_py.episode import WORLD_MODES, Episode
from soil_msgs_py.strict_json import json_safe
from soil_msgs_py.params import COMMAND_FIELDS, GROUND_TRUTH_PARAMS, MACHINE, SAMPLE_RATE_HZ, ticks_in
from soil_physics.soils import CATALOGUE, COHESIVE_SOILS, ID_LIMIT_PCT

from .batch import DEFAULT_RELATIVE_DENSITIES
from .batch import grid_specs as factorial_specs
from .rollout import run_episodes
from .simulator import EpisodeSpec, SimConfig, SoilSimulator

SOILS: tuple[str, ...] = tuple(CATALOGUE)
DENSITIES: tuple[float, ...] = DEFAULT_RELATIVE_DENSITIES
WORLDS: tuple[str, ...] = WORLD_MODES
LIMIT_FRACTION = 0.95  # |F_x| >= 0.95 * 20 kN counts as "at the tractive limit"
PAPER_OSCILLATION_N = (5e3, 10e3)  # §2.1.2: "on the order of 5 kN and 10 kN in the x and z forces"


@dataclass(frozen=True)
class Settings:
    """What the report runs. Defaults follow the paper's dataset ranges (§3.1)."""

    duration_s: float = 10.0
    seed: int = 0
    speed_m_s: float = 0.5  # v̄_x, inside [0.3, 1.0] m/s
    deep_depth_m: float = 0.25  # d̄_z for a, b, c, e (deep end of [0.05, 0.3] m)
    shallow_depth_m: float = 0.06  # d̄_z for the open-loop comparison d (no saturation)
    tail_s: float = 5.0
    soils: tuple[str, ...] = SOILS
    densities: tuple[float, ...] = DENSITIES
    replay_densities: tuple[float, ...] = (0.0, 50.0, 100.0)
    dense_min_pct: float = 80.0  # "dense" for e
    loose_max_pct: float = 20.0  # "loose" for e

    def __post_init__(self):
        if not (math.isfinite(self.duration_s) and self.duration_s > 0):
            raise ValueError(f"duration_s={self.duration_s!r} must be a finite number > 0 s")
        if not (math.isfinite(self.tail_s) and 0 < self.tail_s):
            raise ValueError(f"tail_s={self.tail_s!r} must be a finite number > 0 s")
        if int(self.seed) != self.seed or self.seed < 0:
            raise ValueError(f"seed={self.seed!r} must be a non-negative integer")

    @property
    def tail_ticks(self) -> int:
        n = ticks_in(self.duration_s)
        return max(1, min(n - 1, ticks_in(self.tail_s)))


def _truth(ep: Episode, name: str) -> np.ndarray:
    return ep.truth[:, GROUND_TRUTH_PARAMS.index(name)]


def _tail(x: np.ndarray, settings: Settings) -> np.ndarray:
    return x[-settings.tail_ticks:]


def _limit_n() -> float:
    return MACHINE.horizontal_force_limit_n


# --------------------------------------------------------------------------- running
GridKey = tuple  # (soil, I_d)


def grid_specs(settings: Settings, target_depth_m: float, densities: Sequence[float] | None = None) -> list[EpisodeSpec]:
    """One spec per soil x I_d; episode i gets seed ``settings.seed + i`` (stable order)."""
    densities = settings.densities if densities is None else densities
    return factorial_specs(settings.soils, densities, [settings.speed_m_s], [target_depth_m], 1, settings.seed,
                           settings.duration_s)


def run_grid(world: str, settings: Settings, target_depth_m: float | None = None,
             densities: Sequence[float] | None = None, config: SimConfig | None = None) -> dict[GridKey, Episode]:
    """Closed-loop episodes for every soil x I_d in one vectorised batch -> {(soil, I_d): Episode}."""
    depth = settings.deep_depth_m if target_depth_m is None else target_depth_m
    specs = grid_specs(settings, depth, densities)
    eps = run_episodes(config or SimConfig(world_mode=world), specs)
    return {(s.soil, s.relative_density_pct): ep for s, ep in zip(specs, eps)}


def _grid(world: str, settings: Settings, episodes: Mapping[str, Mapping[GridKey, Episode]] | None):
    if episodes is not None and world in episodes:
        return episodes[world]
    return run_grid(world, settings)


# --------------------------------------------------------------------------- open loop
def _command_array(commands, n_batch: int | None = None) -> np.ndarray:
    """Episode | {u_zr, u_za, u_x} | array (N, 3) [or (N, B, 3)] -> float array (N, B, 3)."""
    if isinstance(commands, Episode):
        arr = np.stack([commands.column(name) for name in COMMAND_FIELDS], axis=1)
    elif isinstance(commands, Mapping):
        missing = [n for n in COMMAND_FIELDS if n not in commands]
        if missing:
            raise ValueError(f"commands is missing {missing}; need {list(COMMAND_FIELDS)}")
        arr = np.stack([np.asarray(commands[n], dtype=float) for n in COMMAND_FIELDS], axis=-1)
    else:
        arr = np.asarray(commands, dtype=float)
    if arr.ndim == 2:
        arr = arr[:, None, :]
    if arr.ndim != 3 or arr.shape[2] != 3 or arr.shape[0] < 1:
        raise ValueError(f"commands has shape {arr.shape}; expected (N, 3) columns {list(COMMAND_FIELDS)}")
    if n_batch is not None and arr.shape[1] != n_batch:
        raise ValueError(f"commands has {arr.shape[1]} episodes, specs has {n_batch}")
    return arr


def replay_commands_batch(config: SimConfig, specs: Sequence[EpisodeSpec], commands,
                          custom_soils: dict | None = None) -> dict[str, np.ndarray]:
    """Open loop: drive B episodes with given commands (N, B, 3) = (u_zr, u_za, u_x) per tick.

    Rows follow the Episode convention: row k is the simulator output after k ticks (row 0 =
    ``reset()``) and command row k is applied to go from row k to row k + 1. So replaying
    the commands of a closed-loop Episode in the same world and seed reproduces it.
    Returns arrays of shape (N, B, ...): positions (p_x_b, p_z_b, p_z_c), velocities
    (v_z_b, v_x_c, v_z_c), forces (f_x_b, f_z_b), known, truth, extras, applied_u_zr,
    commands, and ``time_s`` (N,).
    """
    cmds = _command_array(commands, len(specs))
    if not np.all(np.isfinite(cmds)):
        bad = np.argwhere(~np.isfinite(cmds))[0]
        raise ValueError(f"command {COMMAND_FIELDS[bad[2]]}={cmds[tuple(bad)]} at tick {bad[0]} is not finite")
    sim = SoilSimulator(config, list(specs), custom_soils)
    n = cmds.shape[0]
    out = sim.reset()
    keys = ("positions", "velocities", "forces", "known", "truth", "extras", "applied_u_zr")
    rec = {k: [] for k in keys}
    for k in range(n):
        for key in keys:
            rec[key].append(np.array(getattr(out, key), copy=True))
        out = sim.step(cmds[k, :, 0], cmds[k, :, 1], cmds[k, :, 2])
    result = {key: np.stack(v) for key, v in rec.items()}
    result["commands"] = cmds.copy()
    result["time_s"] = np.arange(n) / SAMPLE_RATE_HZ
    return result


def replay_commands(config: SimConfig, spec: EpisodeSpec, commands, custom_soils: dict | None = None) -> dict[str, np.ndarray]:
    """Open-loop replay of one episode: ``commands`` is an Episode (its u_zr, u_za, u_x
    columns), a mapping with those keys, or an (N, 3) array. Returns arrays of shape (N, ...)
    (see ``replay_commands_batch``); ``forces[:, 0]`` is F_x, ``forces[:, 1]`` F_z."""
    out = replay_commands_batch(config, [spec], _command_array(commands), custom_soils)
    return {k: (v if k == "time_s" else v[:, 0]) for k, v in out.items()}


# --------------------------------------------------------------------------- a. depth vs I_d
@dataclass
class DepthRow:
    world: str
    soil: str
    relative_density_pct: float
    target_depth_m: float
    mean_depth_tail_m: float  # mean cut depth d over the tail
    frac_at_limit: float  # fraction of ticks (whole episode) with |F_x| >= 0.95 * 20 kN
    frac_at_limit_tail: float
    max_offset_m: float  # max controller depth offset Δd̄ = u_za + d̄_z
    mean_offset_tail_m: float
    mean_vx_tail_m_s: float
    mean_fx_tail_n: float


def depth_vs_density(settings: Settings | None = None, episodes=None) -> list[DepthRow]:
    """Phenomenon a, both worlds: per soil x I_d, tail cut depth, time at the limit, offset."""
    settings = settings or Settings()
    rows = []
    lim = LIMIT_FRACTION * _limit_n()
    for world in WORLDS:
        for (soil, i_d), ep in _grid(world, settings, episodes).items():
            target = ep.meta.target_depth_m
            offset = ep.column("u_za") + target
            fx = ep.column("f_x_b")
            rows.append(DepthRow(
                world=world, soil=soil, relative_density_pct=i_d, target_depth_m=target,
                mean_depth_tail_m=float(_tail(_truth(ep, "d"), settings).mean()),
                frac_at_limit=float(np.mean(np.abs(fx[1:]) >= lim)),
                frac_at_limit_tail=float(np.mean(np.abs(_tail(fx, settings)) >= lim)),
                max_offset_m=float(offset.max()),
                mean_offset_tail_m=float(_tail(offset, settings).mean()),
                mean_vx_tail_m_s=float(_tail(ep.column("v_x_c"), settings).mean()),
                mean_fx_tail_n=float(_tail(fx, settings).mean()),
            ))
    return rows


def depth_trend(rows: Iterable[DepthRow], world: str, soil: str) -> tuple[np.ndarray, np.ndarray]:
    """(I_d, mean tail depth) of one world and soil, sorted by I_d."""
    sel = sorted((r.relative_density_pct, r.mean_depth_tail_m) for r in rows if r.world == world and r.soil == soil)
    return np.array([s[0] for s in sel]), np.array([s[1] for s in sel])


# --------------------------------------------------------------------------- b. surcharge
@dataclass
class SurchargeRow:
    world: str
    soil: str
    relative_density_pct: float
    q_first_third_n: float  # mean Q over the first third of the episode
    q_middle_third_n: float
    q_last_third_n: float
    q_final_n: float
    q_max_abs_n: float
    frac_rising_seconds: float  # fraction of consecutive 1 s means of Q that do not fall
    spearman_time: float  # rank correlation of Q with time, ties averaged (1 = strictly rising)
    t_plateau_s: float  # first time Q >= 99 % of its episode maximum (nan if Q is 0 throughout)
    target_depth_m: float = float("nan")


def _ranks(x: np.ndarray) -> np.ndarray:
    """Ranks with ties averaged (so a plateau does not count as rising)."""
    x = np.asarray(x, dtype=float)
    order = np.argsort(x, kind="stable")
    ranks = np.empty(len(x))
    ranks[order] = np.arange(len(x), dtype=float)
    _, inverse, counts = np.unique(x, return_inverse=True, return_counts=True)
    sums = np.bincount(inverse, weights=ranks)
    return sums[inverse] / counts[inverse]


def _spearman(x: np.ndarray, y: np.ndarray) -> float:
    rx, ry = _ranks(x), _ranks(y)
    if rx.std() == 0 or ry.std() == 0:
        return float("nan")
    return float(np.corrcoef(rx, ry)[0, 1])


def surcharge_row(world: str, ep: Episode) -> SurchargeRow:
    q = _truth(ep, "q")
    thirds = np.array_split(q, 3)
    per_s = [chunk.mean() for chunk in np.array_split(q, max(2, len(q) // SAMPLE_RATE_HZ))]
    q_max = float(q.max())
    t_plateau = float(np.argmax(q >= 0.99 * q_max) / SAMPLE_RATE_HZ) if q_max > 0 else float("nan")
    return SurchargeRow(
        world=world, soil=ep.meta.soil, relative_density_pct=ep.meta.relative_density_pct,
        q_first_third_n=float(thirds[0].mean()), q_middle_third_n=float(thirds[1].mean()),
        q_last_third_n=float(thirds[2].mean()), q_final_n=float(q[-1]),
        q_max_abs_n=float(np.abs(q).max()),
        frac_rising_seconds=float(np.mean(np.diff(per_s) >= 0)),
        spearman_time=_spearman(np.arange(len(q)), q),
        t_plateau_s=t_plateau, target_depth_m=ep.meta.target_depth_m,
    )


def surcharge_growth(settings: Settings | None = None, episodes=None) -> list[SurchargeRow]:
    """Phenomenon b: Q per third of each episode, its monotonicity; both worlds."""
    settings = settings or Settings()
    return [surcharge_row(world, ep) for world in WORLDS for ep in _grid(world, settings, episodes).values()]


SURCHARGE_DEPTHS_M = (0.05, 0.1, 0.15, 0.2, 0.25, 0.3)


def surcharge_vs_depth(settings: Settings | None = None, soil: str = "Loam", relative_density_pct: float = 60.0,
                       depths_m: Sequence[float] = SURCHARGE_DEPTHS_M) -> list[SurchargeRow]:
    """Phenomenon b across the paper's target-depth range (§3.1: d̄_z in [0.05, 0.3] m), default
    world, paper Fig. 3's soil (Loam, I_d = 60 %): when does Q stop growing (t_plateau_s)?"""
    settings = settings or Settings()
    specs = [EpisodeSpec(soil, relative_density_pct, settings.speed_m_s, d, settings.seed + i, settings.duration_s)
             for i, d in enumerate(depths_m)]
    return [surcharge_row("default", ep) for ep in run_episodes(SimConfig(world_mode="default"), specs)]


# --------------------------------------------------------------------------- c. fee == FEE
def fee_of_truth(ep_truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """FEE (F_x, F_z) of ground-truth rows (N, 13), with the published (truth) beta."""
    fx, fz = fee.fee_xz_of_truth(ep_truth)
    return np.asarray(fx), np.asarray(fz)


@dataclass
class FeeMatchRow:
    soil: str
    relative_density_pct: float
    mean_abs_f_n: float  # mean |F| (magnitude) over rows >= 1
    mae_x_n: float  # mean |F_x - F_x^FEE|, rows >= 1 (whole episode after reset)
    mae_z_n: float
    mae_x_pct: float  # of mean |F|
    mae_z_pct: float
    mae_x_no_inertia_n: float  # after removing m_b dv/dt
    mae_z_no_inertia_n: float
    mae_x_no_inertia_pct: float
    mae_z_no_inertia_pct: float
    tail_mae_x_no_inertia_n: float  # same, tail only
    tail_mae_z_no_inertia_n: float
    median_abs_x_no_inertia_n: float  # typical tick (rows >= 1)
    median_abs_z_no_inertia_n: float
    frac_ticks_within_1pct: float  # |F - m a - F^FEE| <= 1 % of mean |F| in both x and z


def fee_force_match(settings: Settings | None = None, episodes=None) -> list[FeeMatchRow]:
    """Phenomenon c (fee world): measured F vs FEE(Θ_truth), raw and with inertia removed."""
    settings = settings or Settings()
    rows = []
    for (soil, i_d), ep in _grid("fee", settings, episodes).items():
        fx_fee, fz_fee = fee_of_truth(ep.truth)
        fx, fz = ep.column("f_x_b"), ep.column("f_z_b")
        ix, iz = inertia_force_rows(ep.column("v_x_c"), ep.column("v_z_b"))
        s = slice(1, None)
        mag = float(np.hypot(fx, fz)[s].mean())
        ex, ez = np.abs(fx - fx_fee), np.abs(fz - fz_fee)
        nx, nz = np.abs(fx - ix - fx_fee), np.abs(fz - iz - fz_fee)
        pct = lambda v: 100.0 * v / mag if mag > 0 else float("nan")  # noqa: E731
        rows.append(FeeMatchRow(
            soil=soil, relative_density_pct=i_d, mean_abs_f_n=mag,
            mae_x_n=float(ex[s].mean()), mae_z_n=float(ez[s].mean()),
            mae_x_pct=pct(float(ex[s].mean())), mae_z_pct=pct(float(ez[s].mean())),
            mae_x_no_inertia_n=float(nx[s].mean()), mae_z_no_inertia_n=float(nz[s].mean()),
            mae_x_no_inertia_pct=pct(float(nx[s].mean())), mae_z_no_inertia_pct=pct(float(nz[s].mean())),
            tail_mae_x_no_inertia_n=float(_tail(nx, settings).mean()),
            tail_mae_z_no_inertia_n=float(_tail(nz, settings).mean()),
            median_abs_x_no_inertia_n=float(np.median(nx[s])),
            median_abs_z_no_inertia_n=float(np.median(nz[s])),
            frac_ticks_within_1pct=float(np.mean((nx[s] <= 0.01 * mag) & (nz[s] <= 0.01 * mag))),
        ))
    return rows


# --------------------------------------------------------------------------- d. open loop
@dataclass
class OpenLoopRow:
    soil: str
    relative_density_pct: float
    target_depth_m: float
    fee_mean_abs_f_n: float  # mean |F| over the tail, fee world
    default_mean_abs_f_n: float
    fee_mean_fx_n: float
    default_mean_fx_n: float
    fee_mean_fz_n: float
    default_mean_fz_n: float
    fee_mean_abs_fz_n: float
    default_mean_abs_fz_n: float
    fee_mean_depth_m: float
    default_mean_depth_m: float
    fee_frac_at_limit: float  # |F_x| >= 0.95 * 20 kN, whole episode
    default_frac_at_limit: float
    fee_min_vx_tail_m_s: float
    default_min_vx_tail_m_s: float
    replay_reproduces_fee_episode: bool  # fee replay == the closed-loop fee episode, bitwise

    @property
    def ratio_abs_f(self) -> float:
        return self.default_mean_abs_f_n / self.fee_mean_abs_f_n if self.fee_mean_abs_f_n else float("nan")

    @property
    def saturated(self) -> bool:
        return max(self.fee_frac_at_limit, self.default_frac_at_limit) > 0.0


def open_loop_comparison(settings: Settings | None = None, fee_episodes: Mapping[GridKey, Episode] | None = None) -> list[OpenLoopRow]:
    """Phenomenon d: record commands in closed-loop fee episodes at the shallow target, replay
    them open-loop into the fee and the default world (same seeds), compare the forces."""
    settings = settings or Settings()
    if fee_episodes is None:
        fee_episodes = run_grid("fee", settings, settings.shallow_depth_m, settings.replay_densities)
    keys = list(fee_episodes)
    eps = [fee_episodes[k] for k in keys]
    specs = [EpisodeSpec(e.meta.soil, e.meta.relative_density_pct, e.meta.target_speed_m_s,
                         e.meta.target_depth_m, e.meta.seed, e.meta.duration_s) for e in eps]
    cmds = np.stack([_command_array(e)[:, 0] for e in eps], axis=1)
    replays = {w: replay_commands_batch(SimConfig(world_mode=w), specs, cmds) for w in WORLDS}
    lim = LIMIT_FRACTION * _limit_n()
    rows = []
    for i, ((soil, i_d), ep) in enumerate(zip(keys, eps)):
        stats = {}
        for w, rep in replays.items():
            f = rep["forces"][:, i]
            ft = _tail(f, settings)
            stats[w] = dict(
                abs_f=float(np.hypot(ft[:, 0], ft[:, 1]).mean()), fx=float(ft[:, 0].mean()),
                fz=float(ft[:, 1].mean()), abs_fz=float(np.abs(ft[:, 1]).mean()),
                depth=float(_tail(rep["truth"][:, i, GROUND_TRUTH_PARAMS.index("d")], settings).mean()),
                at_limit=float(np.mean(np.abs(f[1:, 0]) >= lim)),
                min_vx=float(_tail(rep["velocities"][:, i, 1], settings).min()),
            )
        same = bool(np.array_equal(replays["fee"]["forces"][:, i], ep.forces)
                    and np.array_equal(replays["fee"]["positions"][:, i], ep.observations[:, 0:3]))
        rows.append(OpenLoopRow(
            soil=soil, relative_density_pct=i_d, target_depth_m=ep.meta.target_depth_m,
            fee_mean_abs_f_n=stats["fee"]["abs_f"], default_mean_abs_f_n=stats["default"]["abs_f"],
            fee_mean_fx_n=stats["fee"]["fx"], default_mean_fx_n=stats["default"]["fx"],
            fee_mean_fz_n=stats["fee"]["fz"], default_mean_fz_n=stats["default"]["fz"],
            fee_mean_abs_fz_n=stats["fee"]["abs_fz"], default_mean_abs_fz_n=stats["default"]["abs_fz"],
            fee_mean_depth_m=stats["fee"]["depth"], default_mean_depth_m=stats["default"]["depth"],
            fee_frac_at_limit=stats["fee"]["at_limit"], default_frac_at_limit=stats["default"]["at_limit"],
            fee_min_vx_tail_m_s=stats["fee"]["min_vx"], default_min_vx_tail_m_s=stats["default"]["min_vx"],
            replay_reproduces_fee_episode=same,
        ))
    return rows


@dataclass
class ForceLevelRow:
    """Closed-loop, dataset-level (the paper's D_FEE vs D_default comparison, §3.2): tail means
    over all soils of one I_d group; commands differ between worlds (the controller reacts)."""

    world: str
    group: str
    n: int
    mean_abs_f_n: float
    mean_fx_n: float
    mean_fz_n: float
    mean_abs_fz_n: float


def closed_loop_force_levels(settings: Settings | None = None, episodes=None) -> list[ForceLevelRow]:
    settings = settings or Settings()
    groups = (("all I_d", lambda i: True),
              (f"I_d <= {ID_LIMIT_PCT:g}", lambda i: i <= ID_LIMIT_PCT),
              (f"I_d >= {settings.dense_min_pct:g}", lambda i: i >= settings.dense_min_pct))
    rows = []
    for world in WORLDS:
        grid = _grid(world, settings, episodes)
        for label, pred in groups:
            sel = [ep for (soil, i_d), ep in grid.items() if pred(i_d)]
            if not sel:
                continue
            f = np.concatenate([_tail(ep.forces, settings) for ep in sel])
            rows.append(ForceLevelRow(world, label, len(sel), float(np.hypot(f[:, 0], f[:, 1]).mean()),
                                      float(f[:, 0].mean()), float(f[:, 1].mean()), float(np.abs(f[:, 1]).mean())))
    return rows


# --------------------------------------------------------------------------- e. oscillations
def detrend(x: np.ndarray, window_s: float = 1.0) -> np.ndarray:
    """x minus its centred moving average over ``window_s``; only samples with a full window
    (the first and last window/2 samples are dropped)."""
    w = ticks_in(window_s) | 1  # odd, centred
    if len(x) < w:
        raise ValueError(f"series of {len(x)} samples is shorter than the {w}-sample detrend window")
    ma = np.convolve(x, np.ones(w) / w, mode="valid")
    h = w // 2
    return x[h:len(x) - h] - ma


@dataclass
class OscillationRow:
    world: str
    soil: str
    relative_density_pct: float
    std_fx_n: float  # of the detrended force over the tail
    std_fz_n: float
    p95_p5_fx_n: float
    p95_p5_fz_n: float
    mean_fx_n: float
    mean_fz_n: float


def _oscillation(x: np.ndarray, settings: Settings) -> tuple[float, float]:
    r = detrend(x)
    r = r[-min(len(r), settings.tail_ticks):]
    p5, p95 = np.percentile(r, [5, 95])
    return float(r.std()), float(p95 - p5)


def force_oscillations(settings: Settings | None = None, episodes=None) -> list[OscillationRow]:
    """Phenomenon e: std and p95 - p5 of F_x, F_z over the tail, detrended by a 1 s moving average."""
    settings = settings or Settings()
    rows = []
    for world in WORLDS:
        for (soil, i_d), ep in _grid(world, settings, episodes).items():
            fx, fz = ep.column("f_x_b"), ep.column("f_z_b")
            sx, px = _oscillation(fx, settings)
            sz, pz = _oscillation(fz, settings)
            rows.append(OscillationRow(world, soil, i_d, sx, sz, px, pz,
                                       float(_tail(fx, settings).mean()), float(_tail(fz, settings).mean())))
    return rows


@dataclass
class OscillationGroup:
    label: str
    n: int
    std_fx_n: float
    std_fz_n: float
    p95_p5_fx_n: float
    p95_p5_fz_n: float


def oscillation_groups(rows: Sequence[OscillationRow], settings: Settings | None = None) -> list[OscillationGroup]:
    """Means over: dense default (I_d >= dense_min), loose default (I_d <= loose_max), dense fee, all fee."""
    settings = settings or Settings()
    groups = (
        (f"default, I_d >= {settings.dense_min_pct:g}", lambda r: r.world == "default" and r.relative_density_pct >= settings.dense_min_pct),
        (f"default, I_d <= {settings.loose_max_pct:g}", lambda r: r.world == "default" and r.relative_density_pct <= settings.loose_max_pct),
        (f"fee, I_d >= {settings.dense_min_pct:g}", lambda r: r.world == "fee" and r.relative_density_pct >= settings.dense_min_pct),
        ("fee, all", lambda r: r.world == "fee"),
    )
    out = []
    for label, pred in groups:
        sel = [r for r in rows if pred(r)]
        if not sel:
            continue
        m = lambda attr: float(np.mean([getattr(r, attr) for r in sel]))  # noqa: E731
        out.append(OscillationGroup(label, len(sel), m("std_fx_n"), m("std_fz_n"), m("p95_p5_fx_n"), m("p95_p5_fz_n")))
    return out


# --------------------------------------------------------------------------- everything
@dataclass
class PhenomenaReport:
    settings: Settings
    depth: list[DepthRow] = field(default_factory=list)
    surcharge: list[SurchargeRow] = field(default_factory=list)
    surcharge_depths: list[SurchargeRow] = field(default_factory=list)
    fee_match: list[FeeMatchRow] = field(default_factory=list)
    open_loop: list[OpenLoopRow] = field(default_factory=list)
    force_levels: list[ForceLevelRow] = field(default_factory=list)
    oscillations: list[OscillationRow] = field(default_factory=list)
    oscillation_summary: list[OscillationGroup] = field(default_factory=list)
    runtime_s: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """JSON-ready (plain numbers, lists and strings)."""
        out = {"settings": asdict(self.settings), "runtime_s": dict(self.runtime_s)}
        for name in ("depth", "surcharge", "surcharge_depths", "fee_match", "force_levels", "oscillations",
                     "oscillation_summary"):
            out[name] = [asdict(r) for r in getattr(self, name)]
        out["open_loop"] = [dict(asdict(r), ratio_abs_f=r.ratio_abs_f, saturated=r.saturated) for r in self.open_loop]
        out["summary"] = [dict(claim=c, holds=ok, numbers=n) for c, ok, n in summarize(self)]
        return json_safe(out)


def run_all(settings: Settings | None = None, progress: Callable[[str], None] | None = None) -> PhenomenaReport:
    """Run every phenomenon (closed-loop grids of both worlds shared by a, b, c, e)."""
    settings = settings or Settings()
    say = progress or (lambda msg: None)
    report = PhenomenaReport(settings)
    grids = {}
    for world in WORLDS:
        t0 = time.perf_counter()
        say(f"closed-loop {world} grid: {len(settings.soils)} soils x {len(settings.densities)} I_d, "
            f"d = {settings.deep_depth_m} m, {settings.duration_s:g} s")
        grids[world] = run_grid(world, settings)
        report.runtime_s[f"grid_{world}"] = time.perf_counter() - t0
    report.depth = depth_vs_density(settings, grids)
    report.surcharge = surcharge_growth(settings, grids)
    t0 = time.perf_counter()
    say("surcharge across target depths (default, Loam, I_d = 60 %)")
    report.surcharge_depths = surcharge_vs_depth(settings)
    report.runtime_s["surcharge_depths"] = time.perf_counter() - t0
    report.force_levels = closed_loop_force_levels(settings, grids)
    report.fee_match = fee_force_match(settings, grids)
    report.oscillations = force_oscillations(settings, grids)
    report.oscillation_summary = oscillation_groups(report.oscillations, settings)
    t0 = time.perf_counter()
    say(f"open-loop replay: fee commands at d = {settings.shallow_depth_m} m into both worlds")
    report.open_loop = open_loop_comparison(settings)
    report.runtime_s["open_loop"] = time.perf_counter() - t0
    return report


# --------------------------------------------------------------------------- text report
def _table(headers: Sequence[str], rows: Sequence[Sequence], fmts: Sequence[str]) -> str:
    cells = [[(f.format(v) if not isinstance(v, str) else v) for f, v in zip(fmts, row)] for row in rows]
    widths = [max(len(h), *(len(c[i]) for c in cells)) if cells else len(h) for i, h in enumerate(headers)]
    line = lambda vals: "  ".join(v.rjust(w) for v, w in zip(vals, widths))  # noqa: E731
    return "\n".join([line(headers), line(["-" * w for w in widths])] + [line(c) for c in cells])


def _verdict(ok: bool) -> str:
    return "HOLDS" if ok else "DOES NOT HOLD"


def summarize(report: PhenomenaReport) -> list[tuple[str, bool, str]]:
    """(claim, holds, numbers) per phenomenon claim: what the tests assert, in short."""
    s = report.settings
    out = []
    if report.depth:
        for world in WORLDS:
            parts, ok = [], True
            for soil in COHESIVE_SOILS:
                ids, d = depth_trend(report.depth, world, soil)
                if len(ids) < 2:
                    continue
                ok &= bool(d[-1] < d[0] - 0.05 and np.all(np.diff(d) <= 0.01))
                parts.append(f"{soil} {d[0]:.3f} -> {d[-1]:.3f} m")
            lim = [r.frac_at_limit for r in report.depth if r.world == world and r.soil in COHESIVE_SOILS
                   and r.relative_density_pct >= s.dense_min_pct]
            if parts and lim:
                ok &= min(lim) > 0.3
                out.append((f"a: {world}: Clay/Loam mean depth falls as I_d rises, dense ones at the "
                            f"{MACHINE.horizontal_force_limit_n / 1e3:g} kN limit", ok,
                            "; ".join(parts) + f"; dense at-limit fraction >= {min(lim):.2f}"))
            nc = [r for r in report.depth if r.world == world and r.soil not in COHESIVE_SOILS
                  and r.relative_density_pct >= s.dense_min_pct]
            if nc:
                out.append((f"a': {world}: dense Sand/Gravel also lose depth (paper §3.2: depth ~0 at I_d = 80, "
                            "'particularly for the non-cohesive soil')",
                            all(r.mean_depth_tail_m < 0.5 * r.target_depth_m for r in nc),
                            "tail depths " + ", ".join(f"{r.soil} {r.relative_density_pct:.0f}: {r.mean_depth_tail_m:.3f} m"
                                                        for r in nc)))
    if report.surcharge:
        d = [r for r in report.surcharge if r.world == "default"]
        f = [r for r in report.surcharge if r.world == "fee"]
        out.append(("b: default: Q grows through the episode (rank correlation with time >= 0.5, last third > first); fee: Q == 0 exactly",
                    all(r.spearman_time >= 0.5 and r.q_last_third_n > r.q_first_third_n for r in d)
                    and all(r.q_max_abs_n == 0.0 for r in f),
                    f"Q_3rd / Q_1st in [{min(r.q_last_third_n / r.q_first_third_n for r in d):.2f}, "
                    f"{max(r.q_last_third_n / r.q_first_third_n for r in d):.2f}], max |Q| fee = "
                    f"{max(r.q_max_abs_n for r in f):g} N"))
        rows = report.surcharge_depths or d
        out.append(("b': Q still grows in the last third of the episode (paper Fig. 3: 'the surcharge grows with time')",
                    all(r.q_last_third_n > 1.02 * r.q_middle_third_n for r in rows),
                    "Q reaches 99 % of its episode maximum (the pile capacity, unless still rising) after " + ", ".join(
                        f"{r.t_plateau_s:.1f} s (d̄ {r.target_depth_m:.2f} m)" for r in rows)))
    if report.fee_match:
        worst_x = max(r.mae_x_no_inertia_pct for r in report.fee_match)
        worst_z = max(r.mae_z_no_inertia_pct for r in report.fee_match)
        out.append(("c: fee: measured F == FEE(truth) up to joint dynamics (inertia removed, mean error < 5 % of |F|)",
                    worst_x < 5 and worst_z < 5,
                    f"worst mean error x {worst_x:.1f} %, z {worst_z:.1f} % (with inertia z up to "
                    f"{max(r.mae_z_pct for r in report.fee_match):.1f} %); median tick error "
                    f"<= {max(r.median_abs_x_no_inertia_n for r in report.fee_match):.0f} N"))
    if report.open_loop:
        ok = [r for r in report.open_loop if not r.saturated]
        if ok:
            out.append(("d: same commands (open loop, unsaturated): default mean |F| > fee mean |F|",
                        all(r.default_mean_abs_f_n > r.fee_mean_abs_f_n for r in ok),
                        f"ratio default/fee in [{min(r.ratio_abs_f for r in ok):.2f}, {max(r.ratio_abs_f for r in ok):.2f}] "
                        f"over {len(ok)} cases"))
            bigger = [r for r in ok if r.default_mean_abs_fz_n > r.fee_mean_abs_fz_n]
            out.append(("d': same commands: default mean |F_z| > fee mean |F_z| (paper §3.2: 'F_z is much larger')",
                        len(bigger) == len(ok),
                        f"{len(bigger)}/{len(ok)} cases; exceptions: " + (", ".join(
                            f"{r.soil} {r.relative_density_pct:.0f} ({r.default_mean_abs_fz_n:.0f} vs {r.fee_mean_abs_fz_n:.0f} N)"
                            for r in ok if r not in bigger) or "none")))
    if report.force_levels:
        lv = {(r.world, r.group): r for r in report.force_levels}
        a, b = lv.get(("default", "all I_d")), lv.get(("fee", "all I_d"))
        if a and b:
            out.append(("d'': closed loop, dataset level: default mean |F| and |F_z| > fee",
                        a.mean_abs_f_n > b.mean_abs_f_n and a.mean_abs_fz_n > b.mean_abs_fz_n,
                        f"|F| {a.mean_abs_f_n:.0f} vs {b.mean_abs_f_n:.0f} N, |F_z| {a.mean_abs_fz_n:.0f} vs "
                        f"{b.mean_abs_fz_n:.0f} N"))
    if report.oscillation_summary:
        g = report.oscillation_summary
        dense, loose = g[0], g[1] if len(g) > 1 else None
        fees = [x for x in g if x.label.startswith("fee")]
        if loose is not None:
            out.append(("e: dense default oscillations of the paper's order (p95-p5 >= half of 5 kN x / 10 kN z), "
                        "larger than loose default and fee",
                        dense.p95_p5_fx_n >= 0.5 * PAPER_OSCILLATION_N[0] and dense.p95_p5_fz_n >= 0.5 * PAPER_OSCILLATION_N[1]
                        and dense.p95_p5_fx_n > loose.p95_p5_fx_n and dense.p95_p5_fz_n > loose.p95_p5_fz_n
                        and all(dense.p95_p5_fx_n > x.p95_p5_fx_n and dense.p95_p5_fz_n > x.p95_p5_fz_n for x in fees),
                        f"p95-p5 x/z: dense default {dense.p95_p5_fx_n / 1e3:.1f}/{dense.p95_p5_fz_n / 1e3:.1f} kN, "
                        f"loose default {loose.p95_p5_fx_n / 1e3:.1f}/{loose.p95_p5_fz_n / 1e3:.1f} kN, "
                        + ", ".join(f"{x.label} {x.p95_p5_fx_n / 1e3:.1f}/{x.p95_p5_fz_n / 1e3:.1f} kN" for x in fees)))
    return out


def format_report(report: PhenomenaReport) -> str:
    """A readable text report of every phenomenon."""
    s = report.settings
    out = [
        "insitu-soil simulator phenomena (Wagner et al. §2.1.2, §3.1-3.2)",
        f"episodes: {s.duration_s:g} s at 60 Hz, v̄_x = {s.speed_m_s} m/s, seed base {s.seed}; "
        f"tail = last {s.tail_s:g} s; forces blade-on-soil, x forward, z up [N]",
        "",
    ]
    if report.depth:
        out.append(f"a. Cut depth vs relative density, closed loop, d̄_z = {s.deep_depth_m} m "
                   f"(limit = |F_x| >= {LIMIT_FRACTION:g} x {_limit_n() / 1e3:g} kN; offset Δd̄ = u_za + d̄_z)")
        rows = [(r.world, r.soil, r.relative_density_pct, r.mean_depth_tail_m, r.frac_at_limit, r.frac_at_limit_tail,
                 r.max_offset_m, r.mean_offset_tail_m, r.mean_vx_tail_m_s, r.mean_fx_tail_n) for r in report.depth]
        out.append(_table(["world", "soil", "I_d%", "depth_tail_m", "at_limit", "at_limit_tail", "max_off_m",
                           "off_tail_m", "vx_tail", "Fx_tail_N"], rows,
                          ["{}", "{}", "{:.0f}", "{:.3f}", "{:.2f}", "{:.2f}", "{:.3f}", "{:.3f}", "{:.2f}", "{:.0f}"]))
        out.append("")
    sur_headers = ["world", "soil", "I_d%", "d̄_z", "Q_1st_N", "Q_2nd_N", "Q_3rd_N", "Q_final_N", "max|Q|_N",
                   "rising", "rank_corr", "t_plateau"]
    sur_fmts = ["{}", "{}", "{:.0f}", "{:.2f}", "{:.0f}", "{:.0f}", "{:.0f}", "{:.0f}", "{:.0f}", "{:.2f}", "{:.3f}", "{:.1f}"]
    sur_row = lambda r: (r.world, r.soil, r.relative_density_pct, r.target_depth_m, r.q_first_third_n,  # noqa: E731
                         r.q_middle_third_n, r.q_last_third_n, r.q_final_n, r.q_max_abs_n, r.frac_rising_seconds,
                         r.spearman_time, r.t_plateau_s)
    if report.surcharge:
        out.append("b. Surcharge Q through the episode (mean per third; rising = share of consecutive 1 s means that "
                   "do not fall;\n   rank_corr = Spearman of Q vs time, ties averaged; t_plateau = first time Q >= 99 % of its max) [s]")
        out.append(_table(sur_headers, [sur_row(r) for r in report.surcharge], sur_fmts))
        out.append("")
    if report.surcharge_depths:
        out.append("b'. Surcharge across the paper's target-depth range (default world, Loam, I_d = 60 %, paper Fig. 3)")
        out.append(_table(sur_headers, [sur_row(r) for r in report.surcharge_depths], sur_fmts))
        out.append("")
    if report.fee_match:
        out.append("c. fee world: measured F vs FEE(ground-truth Θ, truth β), rows >= 1 (whole episode after reset);")
        out.append("   'ni' = no inertia: F - m_b dv/dt from the recorded velocities; med = median tick; "
                   "ticks<1% = share of ticks within 1 % of mean |F| in x and z (ni)")
        rows = [(r.soil, r.relative_density_pct, r.mean_abs_f_n, r.mae_x_n, r.mae_x_pct, r.mae_z_n, r.mae_z_pct,
                 r.mae_x_no_inertia_n, r.mae_x_no_inertia_pct, r.mae_z_no_inertia_n, r.mae_z_no_inertia_pct,
                 r.median_abs_x_no_inertia_n, r.median_abs_z_no_inertia_n, r.frac_ticks_within_1pct)
                for r in report.fee_match]
        out.append(_table(["soil", "I_d%", "mean|F|", "|dFx|", "%", "|dFz|", "%", "|dFx|ni", "%", "|dFz|ni", "%",
                           "med_x_ni", "med_z_ni", "ticks<1%"], rows,
                          ["{}", "{:.0f}", "{:.0f}", "{:.0f}", "{:.1f}", "{:.0f}", "{:.1f}", "{:.0f}", "{:.1f}",
                           "{:.0f}", "{:.1f}", "{:.1f}", "{:.1f}", "{:.2f}"]))
        out.append("")
    if report.open_loop:
        out.append(f"d. Open loop, same commands: fee-world closed-loop commands (d̄_z = {s.shallow_depth_m} m) replayed "
                   "into both worlds (same seeds); tail means [N], depth [m]")
        rows = [(r.soil, r.relative_density_pct, r.fee_mean_abs_f_n, r.default_mean_abs_f_n, r.ratio_abs_f,
                 r.fee_mean_fx_n, r.default_mean_fx_n, r.fee_mean_fz_n, r.default_mean_fz_n, r.fee_mean_abs_fz_n,
                 r.default_mean_abs_fz_n, r.fee_mean_depth_m, r.default_mean_depth_m,
                 "yes" if r.saturated else "no", "yes" if r.replay_reproduces_fee_episode else "NO")
                for r in report.open_loop]
        out.append(_table(["soil", "I_d%", "|F|fee", "|F|def", "ratio", "Fx_fee", "Fx_def", "Fz_fee", "Fz_def",
                           "|Fz|fee", "|Fz|def", "d_fee", "d_def", "saturated", "replay==ep"], rows,
                          ["{}", "{:.0f}", "{:.0f}", "{:.0f}", "{:.2f}", "{:.0f}", "{:.0f}", "{:.0f}", "{:.0f}", "{:.0f}",
                           "{:.0f}", "{:.3f}", "{:.3f}", "{}", "{}"]))
        out.append("")
    if report.force_levels:
        out.append(f"d''. Closed loop, dataset level (d̄_z = {s.deep_depth_m} m grid, all soils; commands differ "
                   "between worlds): tail means [N]")
        rows = [(r.world, r.group, r.n, r.mean_abs_f_n, r.mean_fx_n, r.mean_fz_n, r.mean_abs_fz_n) for r in report.force_levels]
        out.append(_table(["world", "group", "n", "mean|F|", "mean_Fx", "mean_Fz", "mean|Fz|"], rows,
                          ["{}", "{}", "{}", "{:.0f}", "{:.0f}", "{:.0f}", "{:.0f}"]))
        out.append("")
    if report.oscillations:
        out.append(f"e. Force oscillations over the tail, detrended with a 1 s moving average, closed loop d̄_z = "
                   f"{s.deep_depth_m} m (paper: ~{PAPER_OSCILLATION_N[0] / 1e3:g} kN in x, ~{PAPER_OSCILLATION_N[1] / 1e3:g} kN in z) [N]")
        rows = [(r.world, r.soil, r.relative_density_pct, r.std_fx_n, r.std_fz_n, r.p95_p5_fx_n, r.p95_p5_fz_n,
                 r.mean_fx_n, r.mean_fz_n) for r in report.oscillations]
        out.append(_table(["world", "soil", "I_d%", "std_Fx", "std_Fz", "p95-p5_Fx", "p95-p5_Fz", "mean_Fx", "mean_Fz"],
                          rows, ["{}", "{}", "{:.0f}", "{:.0f}", "{:.0f}", "{:.0f}", "{:.0f}", "{:.0f}", "{:.0f}"]))
        out.append("")
        out.append(_table(["group", "n", "std_Fx", "std_Fz", "p95-p5_Fx", "p95-p5_Fz"],
                          [(g.label, g.n, g.std_fx_n, g.std_fz_n, g.p95_p5_fx_n, g.p95_p5_fz_n) for g in report.oscillation_summary],
                          ["{}", "{}", "{:.0f}", "{:.0f}", "{:.0f}", "{:.0f}"]))
        out.append("")
    verdicts = summarize(report)
    if verdicts:
        out.append("Summary")
        for claim, ok, numbers in verdicts:
            out.append(f"  [{_verdict(ok)}] {claim}")
            out.append(f"      {numbers}")
    if report.runtime_s:
        out.append("runtime: " + ", ".join(f"{k} {v:.1f} s" for k, v in report.runtime_s.items()))
    return "\n".join(out)


__all__ = [
    "Settings", "run_grid", "grid_specs", "replay_commands", "replay_commands_batch",
    "DepthRow", "depth_vs_density", "depth_trend", "SurchargeRow", "surcharge_row", "surcharge_growth",
    "surcharge_vs_depth", "FeeMatchRow", "fee_force_match", "fee_of_truth", "OpenLoopRow",
    "open_loop_comparison", "ForceLevelRow", "closed_loop_force_levels", "OscillationRow", "force_oscillations",
    "detrend", "OscillationGroup", "oscillation_groups", "PhenomenaReport", "run_all", "summarize", "format_report",
]
