"""World modes and the named effects that make the `default` world differ from the FEE.

The paper's D_default (§2.1.1, §3.1) comes from Vortex with its heuristics on: a surcharge
pile built from particles, penetration forces, extra friction/elastic/damping contact
forces between heightfield and tool, FEE force scaling and area limiting, particle-
conversion contact losses, compaction, and noisy measurements. Each of these is one named,
documented, switchable term below; `fee` mode switches all of them off (and Q = 0).

Force convention for every term: the force the blade exerts ON the soil [N], x forward,
z up (same as the FEE, paper Eq. 8). The measured force is this plus blade inertia.

User plugins (no simulator edit needed)
---------------------------------------
``SimConfig(plugins=["my_pkg.my_mod:my_force"])`` or, with parameters,
``plugins=[{"target": "my_pkg.my_mod:my_force", "params": {"k": 1200.0}}]``.
The function is called once per physics substep as ``fn(state, **params)`` with a
``soil_physics.force_inputs.ForceInputs`` (arrays of shape (B,) for a batch of B episodes,
SI units; the simulator fills every field, its own soil in effect and FEE force; its ``t`` is the
tick's time, the same for every substep of a tick, and starts at 0 with each episode) and
must return ``(f_x, f_z)``: arrays (or floats) broadcastable to (B,), the extra force the
blade exerts on the soil [N]. A plugin that does not import, is not callable, returns the
wrong shape, a non-finite value or a force beyond ``params.MAX_PLAUSIBLE_FORCE_N`` (the blade would
be flung kilometres away) stops the simulation with a ``PluginError`` naming the
plugin, the field and the value. See ``soil_sim_node/plugins_example.py``.
"""
from __future__ import annotations

import importlib
import inspect
import math
from dataclasses import dataclass, field, fields, replace

import numpy as np

from soil_physics.contact import contact_damping_force
from soil_msgs_py.episode import WORLD_MODES
from soil_msgs_py.params import MAX_PLAUSIBLE_FORCE_N
from soil_physics.force_inputs import ForceInputs


# Named effects that are one force term on ``ForceInputs`` (the physics lives in soil_physics;
# the simulator applies penetration and base friction itself, they interact with the edge).
FORCE_TERMS = {"contact_damping": contact_damping_force}


@dataclass(frozen=True)
class Effects:
    """Switches and parameters of every default-world effect. ``Effects.fee()`` = all off.

    surcharge        soil cut ahead of the blade becomes a pile whose weight Q (the "soil
                     mass sensor", published as Θ_k's Q) enters the FEE as
                     ``surcharge_fee_factor`` * Q N_Q. The factor 0.1 is Haeri et al.'s
                     (2020) Vortex modification cited in paper §2.1.1 ("reduces the
                     contribution of the surcharge by a factor of 10 in equation 2"), so a
                     model that uses the full Q N_Q over-predicts: a real model gap. The
                     pile fills at the cut rate w d v_x, less what spills over the top as it
                     fills (inflow * V / capacity), and sheds over the blade ends with time
                     constant ``surcharge_shed_time_s``.
    penetration      ``soil_physics.bearing.penetration_capacity`` (a one-sided constraint on
                     the edge: it holds an edge pressed onto the floor as well as a sinking
                     one, so the floor carries the lift's push, up to the capacity).
    contact_damping  ``soil_physics.contact.contact_damping_force``.
    base_friction    ``soil_physics.contact.base_friction_force`` on the penetration reaction.
    force_scaling    the FEE force is multiplied by ``force_scale`` and limited to
                     ``area_pressure_limit_pa`` times the submerged face area.
    particles        heightfield-to-particle conversion: failure events at a rate
                     proportional to the cut volume rate, each dropping the soil's grip on
                     the blade for a few ms to ~0.1 s (contact loss); these are the step
                     disturbances that make the force oscillate (paper §2.1.2, Fig. 3).
    compaction       the soil ahead is densified as the blade pushes: the relative density
                     in effect rises towards 100 % with distance in soil,
                     I_d' = I_d + (100 - I_d) k (1 - exp(-s / s_c)), s the travel in soil
                     since the edge entered its soil patch (the whole episode without
                     patches); phi, c, gamma follow the catalogue. The published
                     pseudo-ground truth keeps the nominal I_d's values, like Vortex (§3.1).
    noise            white Gaussian noise on the measured force (x, z) [N].
    """

    surcharge: bool = True
    surcharge_shed_time_s: float = 6.0
    # Pile capacity: with gamma <= 22 kN/m^3 this keeps Q <= ~10 kN, the top of paper
    # Table 1's Q range (what the authors saw Vortex's soil mass sensor report).
    surcharge_capacity_m3: float = 0.45
    surcharge_fee_factor: float = 0.1
    penetration: bool = True
    contact_damping: bool = True
    base_friction: bool = True
    force_scaling: bool = True
    force_scale: float = 1.15
    area_pressure_limit_pa: float = 150e3
    particles: bool = True
    particle_chunk_m: float = 0.04  # blade travel per failure event at full depth [m]
    particle_loss_max: float = 0.9  # largest fraction of grip lost in an event
    particle_loss_time_s: tuple[float, float] = (0.01, 0.08)
    particle_full_depth_m: float = 0.1  # an event's grip loss grows with d up to this depth [m]
    compaction: bool = True
    compaction_gain: float = 0.3
    compaction_length_m: float = 6.0
    noise: bool = True
    noise_force_std_n: tuple[float, float] = (300.0, 500.0)

    @classmethod
    def fee(cls) -> "Effects":
        return cls(**{name: False for name in cls.names()})

    @classmethod
    def names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls) if f.type in ("bool", bool))

    def enabled(self) -> list[str]:
        return [n for n in self.names() if getattr(self, n)]

    def with_switches(self, **switches: bool) -> "Effects":
        unknown = set(switches) - set(self.names())
        if unknown:
            raise ValueError(f"unknown effect(s) {sorted(unknown)}; known: {list(self.names())}")
        return replace(self, **switches)


def effects_for_mode(mode: str, force_noise: bool = False) -> Effects:
    """The world's effects; ``force_noise``: with the measured force's noise on whatever the world
    (the fee world with a noisy sensor: the FEE exact and the truth known, the noise a machine's)."""
    if mode not in WORLD_MODES:
        raise ValueError(f"world_mode={mode!r} is not one of {WORLD_MODES}")
    effects = Effects.fee() if mode == "fee" else Effects()
    return effects.with_switches(noise=True) if force_noise else effects


class PluginError(ValueError):
    """A user force plugin could not be loaded or returned something unusable."""


@dataclass
class ForcePlugin:
    """A loaded ``package.module:function`` force term with its keyword parameters."""

    target: str
    params: dict = field(default_factory=dict)
    fn: object = None
    # the largest |f_x| or |f_z| [N] it has returned: 0 after a whole run says it never acted there
    # (surcharge_drag in the fee world, where no pile stands before the blade), which a batch says
    peak_n: float = 0.0

    @classmethod
    def load(cls, spec) -> "ForcePlugin":
        if isinstance(spec, dict):
            target, params = spec.get("target"), dict(spec.get("params") or {})
        elif isinstance(spec, str) and " " in spec.strip():
            target, params = _parse_spec(spec)
        else:
            target, params = spec, {}
        if not isinstance(target, str) or target.count(":") != 1:
            raise PluginError(f"plugin={target!r} must look like 'package.module:function'")
        module_name, func_name = target.split(":")
        try:
            module = importlib.import_module(module_name)
        except Exception as exc:  # any import-time failure is the plugin's, name it
            raise PluginError(f"plugin={target!r}: cannot import module {module_name!r}: {exc}") from exc
        fn = getattr(module, func_name, None)
        if not callable(fn):
            raise PluginError(f"plugin={target!r}: {module_name!r} has no callable {func_name!r}")
        try:  # a parameter the function does not take: refused here, before a batch makes its folder
            inspect.signature(fn).bind(None, **params)
        except TypeError as exc:
            raise PluginError(f"plugin={target!r} cannot be called with the parameters {sorted(params)}: {exc}") from None
        except ValueError:  # no signature to read (a builtin): its call says what is wrong
            pass
        return cls(target, params, fn)

    def __call__(self, state: ForceInputs, batch: int) -> tuple[np.ndarray, np.ndarray]:
        try:
            out = self.fn(state, **self.params)
            fx, fz = out
        except PluginError:
            raise
        except Exception as exc:
            # with its parameters: a bad one (k0='abc') failed inside NumPy's words, naming neither
            given = f" with {', '.join(f'{k}={v!r}' for k, v in self.params.items())}" if self.params else ""
            raise PluginError(f"plugin={self.target!r}{given} raised {type(exc).__name__}: {exc}") from exc
        result = []
        for name, value in (("f_x", fx), ("f_z", fz)):
            shape = np.shape(value)
            if len(shape) > 1 or (len(shape) == 1 and shape[0] not in (1, batch)):
                raise PluginError(f"plugin={self.target!r} returned {name} of shape {shape}, expected ({batch},)")
            arr = np.asarray(value, dtype=float)
            if arr.shape != (batch,):
                arr = np.broadcast_to(arr, (batch,))
            magnitude = np.abs(arr)
            if not (magnitude <= MAX_PLAUSIBLE_FORCE_N).all():  # one check per substep; NaN fails it too
                if not np.all(np.isfinite(arr)):
                    bad = arr[~np.isfinite(arr)][0]
                    raise PluginError(f"plugin={self.target!r} returned {name}={bad} (not finite)")
                bad = arr[magnitude > MAX_PLAUSIBLE_FORCE_N][0]
                raise PluginError(f"plugin={self.target!r} returned {name}={bad:.3g} N, beyond ±{MAX_PLAUSIBLE_FORCE_N:.3g} N "
                                  "(300 times the machine's force limit: a plugin's unit or sign error?)")
            self.peak_n = max(self.peak_n, float(magnitude.max(initial=0.0)))
            result.append(arr)
        return result[0], result[1]


def _parse_spec(spec: str) -> tuple[str, dict]:
    """'package.module:function key=value ...' (what fits in a ROS string parameter or a CLI
    flag) -> (target, params); numbers become floats."""
    target, *pairs = spec.split()
    params: dict = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key.isidentifier():
            raise PluginError(f"plugin={spec!r}: parameter {pair!r} must look like key=value")
        if key in params:  # ('k=1 k=2' took the last, and the bag recorded both)
            raise PluginError(f"plugin={spec!r}: parameter {key!r} is given twice")
        try:
            params[key] = float(value)
        except ValueError:
            params[key] = value
    return target, params


def load_plugins(specs) -> list[ForcePlugin]:
    return [ForcePlugin.load(s) for s in (specs or [])]


def plugin_name(spec) -> str:
    return spec["target"] if isinstance(spec, dict) else str(spec)


def check_effect_params(effects: Effects) -> None:
    """Raise ValueError naming any effect parameter outside its meaningful range."""
    positive = ("surcharge_shed_time_s", "surcharge_capacity_m3", "force_scale", "area_pressure_limit_pa",
                "particle_chunk_m", "particle_full_depth_m", "compaction_length_m")
    for name in positive:
        value = getattr(effects, name)
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            raise ValueError(f"effects.{name}={value!r} must be a finite number > 0")
    if not 0.0 <= effects.particle_loss_max <= 1.0:
        raise ValueError(f"effects.particle_loss_max={effects.particle_loss_max} outside [0, 1]")
    if not 0.0 <= effects.surcharge_fee_factor <= 1.0:
        raise ValueError(f"effects.surcharge_fee_factor={effects.surcharge_fee_factor} outside [0, 1]")
    if not 0.0 <= effects.compaction_gain <= 1.0:
        raise ValueError(f"effects.compaction_gain={effects.compaction_gain} outside [0, 1]")
    lo, hi = effects.particle_loss_time_s
    if not 0.0 < lo <= hi:
        raise ValueError(f"effects.particle_loss_time_s={effects.particle_loss_time_s} must satisfy 0 < lo <= hi")
    if any(s < 0 or not math.isfinite(s) for s in effects.noise_force_std_n):
        raise ValueError(f"effects.noise_force_std_n={effects.noise_force_std_n} must be finite and >= 0")
