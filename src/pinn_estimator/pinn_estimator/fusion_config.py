"""What the soil posterior assumes (``fusion.SoilPosterior``): its settings, checked, and their JSON file.

The error laws in it are calibrated on episodes (``fusion_calibration``, ``pinn_fusion_calibrate``;
the planner's bound law by ``soil_planner_calibrate``) and shipped beside each model; a file
edited by hand or written before a field existed is checked as a whole, every error naming the
field and value.
"""
from __future__ import annotations

import json
import math
import warnings
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

from soil_msgs_py.cli_paths import write_text_atomically
from soil_msgs_py.episode import MAX_SEED, WORLD_MODES
from soil_msgs_py.values import finite_number, short_repr
from soil_physics import force_terms
from soil_physics.augmented_fee import AugmentedFEE
from soil_physics.soils import soil_from_dict, soil_to_dict

PAIR_FIELDS = ("abs_std_n", "rel_std", "forecast_rel_std", "forecast_abs_std_n", "forecast_limit_std", "shape_abs_std_n",
               "shape_rel_std")  # (x, z) each
BOUND_FIELDS = ("bound_abs_std_n", "bound_rel_std")  # (x, z) each, or both None


# The integer fields' bounds. Above: more than an offline check of the quantiles needs (a forecast
# runs components × forecast_samples models; a 400-digit count asked numpy for more memory than
# exists) and a stretch longer than a minute, which could not follow a soil change along the path.
# What a config records of the episodes that calibrated it, not a law: set by pinn_fusion_calibrate's
# --world, --plugin and --soil-file/--soils, never by --set, and absent from configs written before
PROVENANCE_FIELDS = ("world", "calibration_plugins", "calibration_soils")
# Fields whose default is the law a config written before them had (none of the forecast law's part
# near the F_x limit): a config without one is what it was, not a default taken unseen (no warning).
OLD_LAW_DEFAULTS = ("forecast_limit_std",)
INT_FIELD_RANGES = {"forecast_samples": (16, 100_000), "update_ticks": (1, 3600), "model_points": (1, 3600),
                    "components": (1, 64), "seed": (0, MAX_SEED)}  # (numpy's generator: a seed >= 0)
# The standard deviations' upper bounds: beyond what the calibration tries (shares up to 2, floors up
# to 3 kN: fusion_calibration's grids), below where their squares overflow (1e300 gave an
# OverflowError or an inf variance and a posterior of NaN): a model error of ten times the force,
# a floor of a meganewton.
STD_FIELD_MAX = {"prior_std": 10.0, "rel_std": 10.0, "forecast_rel_std": 10.0, "shape_rel_std": 10.0, "bound_rel_std": 10.0,
                 "forecast_limit_std": 10.0,
                 "abs_std_n": 1e6, "forecast_abs_std_n": 1e6, "shape_abs_std_n": 1e6, "bound_abs_std_n": 1e6}


@dataclass(frozen=True)
class FusionConfig:
    """What the posterior assumes; ``rel_std`` and ``forecast_rel_std`` come from calibration
    (``fusion_calibration``)."""

    prior_std: float = 0.3  # prior standard deviation, share of the prior box (a uniform box has 0.29)
    components: int = 9  # Gaussians side by side along φ: one depth leaves a curved φ-c ridge
    seed: int = 0  # of the fixed normal draws the forecast pushes through the model
    forecast_samples: int = 128  # posterior samples per component, forecast and summary
    update_ticks: int = 30  # samples averaged into one stretch of evidence (0.5 s at 60 Hz)
    model_points: int = 10  # sub-means of Θ_k (and, with shape_evidence, of the force) per stretch (divides update_ticks)
    abs_std_n: tuple[float, float] = (20.0, 20.0)  # model-error floor (x, z) [N]: the force sensor's noise
    rel_std: tuple[float, float] = (0.02, 0.02)  # model error per unit of model force (x, z): how hard each stretch teaches
    # Model error a forecast adds to the posterior's spread (x, z), per unit of the force it
    # extrapolates from the newest stretch (``forecast``). Separate
    # from rel_std: the posterior is an approximation (a Gaussian sum on a curved φ-c ridge) and
    # the model may miss physics, so what makes intervals hold is calibrated on forecasts
    # themselves, while rel_std stays what lets stretches at two depths pin φ and c down.
    forecast_rel_std: tuple[float, float] = (0.05, 0.05)
    forecast_abs_std_n: tuple[float, float] = (20.0, 20.0)  # its floor (x, z) [N]: a force near 0 is not known to 0
    # What the forecast's model error adds (x, z) as a sample's forecast F_x goes from the planner's
    # margin to the F_x limit, a share of the axis's force limit (``predictive.near_limit_error_std``):
    # there the anti-stall controller's lift sets the force as much as the soil does. 0: nothing
    # (configs written before it had none; the fee world's calibration keeps 0).
    forecast_limit_std: tuple[float, float] = (0.0, 0.0)
    unsteady_gain: float = 1.0  # model error per unit of the force's spread within the stretch (transients)
    evidence_weight: float = 1.0  # κ: tempering of each stretch's log-likelihood
    drift_per_sqrt_m: float = 0.01  # soil drift within a patch: share of the prior box per √m of travel
    # Mean length of a soil patch along the path [m] (0: the soil never jumps). Between
    # stretches the soil is a new one with probability 1 − exp(−travel / patch_length_m): the
    # posterior keeps that hypothesis beside the current one (``fusion.SoilPosterior.update``).
    patch_length_m: float = 5.0
    change_nis: float = 30.0  # normalised innovation (χ², 2 dof) beyond which a stretch is a new soil
    # Shape evidence: each stretch is observed as its ``model_points`` sub-means of force, not its
    # mean alone. The sub-means share the stretch's model error (the σ law above: their mean
    # teaches what the stretch mean did) and each carries its own error in how it departs from the
    # others, σ_dev = abs + rel·|the model's departure|, widened by ``shape_noise_gain`` × the
    # force's tick noise over the sub-mean (``tick_noise_n``). Why: the force's change along the
    # entry ramp or a slow lift is what tells φ from c at one target depth (γd²wN_γ against
    # c·d·w·N_c), and a stretch mean, widened by that very change as if it were noise, threw it
    # away (fee world: φ after 5 s 4.2° off). Only quasi-static sub-means count (``fusion.quasi_static``).
    shape_evidence: bool = False
    shape_abs_std_n: tuple[float, float] = (20.0, 20.0)  # floor of a sub-mean's departure error (x, z) [N]
    shape_rel_std: tuple[float, float] = (0.05, 0.05)  # per unit of the model's departure (x, z)
    # per unit of the sub-mean's noise and of its timing error (``fusion.SAMPLE_TIMING_TICKS``)
    shape_noise_gain: float = 1.0
    # Prior probability that the soil is cohesionless (clean sands and gravels: c = 0, a state of
    # its own, not the edge of a range): the prior holds a second row of components at c = 0
    # beside the broad one (``fusion.SoilPosterior._prior``). Why: c = 0 is at the end of the softplus
    # coordinate, where the broad prior has little mass and the data no say (a few tens of Pa
    # of c trade against a fraction of a degree of φ), so a sand's posterior sat at c ≈ 0.1-0.2
    # kPa and φ 1-2° low, 2-6 % off at another depth. At c ≈ 7 Pa instead of 0 the row still
    # biased every sand's φ by −0.6 to −0.8 of its standard deviation (c 13 ± 18 Pa).
    cohesionless_prior: float = 0.5
    # Prior probability that the soil is stiff beyond Table 1's cohesions (a third row of components
    # at c = 30 ± 6 kPa, ``fusion.STIFF_U``; c reaches 60 kPa). Why: a hardpan of 32 kPa at φ 10° lay 4-5
    # prior standard deviations out and its posterior sat on the broad row's bound at 20 kPa, φ
    # 24° off with intervals holding neither (fee world); with the row it is found (c 30-34 kPa,
    # φ within its interval). 0.02: the Table 1 soils' posteriors do not move (their data rule the
    # row out); at 0.1 the default world's dense clays, whose effective soil is stiffer than their
    # own, took some of it (F_x at another depth 4.1 → 5.4 % in clay), at 0.02 and 0.05 none.
    stiff_prior: float = 0.02
    terms: tuple[tuple[str, float], ...] = ()  # catalogue terms of the physics model (AugmentedFEE)
    # The error law (x, z) of the bound a planner keeps within the limits (``soil_planner``: the
    # posterior's upper force quantile, anchored to the force measured now and scaled by each
    # sample's depth ratio), floor [N] and share of the extrapolated force; None: the forecast law
    # above. Why a law of its own: the anchored bound is another forecast than the posterior's
    # own (its centre is the force now, not the posterior's force), so the law that makes the
    # posterior's intervals hold does not make the bound hold (default world: a law calibrated for
    # the intervals let the 95 % bound be exceeded in 28 % of the calibration pairs going deeper).
    # ``soil_planner_calibrate`` (soil_planner/bound_calibration.py) calibrates it, after
    # ``fusion_calibration``; ``planner_bound_law`` is what the planner gets. An unanchored plan
    # keeps the forecast law: its bound is the posterior's own forecast.
    bound_abs_std_n: tuple[float, float] | None = None
    bound_rel_std: tuple[float, float] | None = None
    # The world whose episodes calibrated the laws above ("": not recorded, as in configs made
    # before it was). Why: the laws are one world's, and a config of one world recalibrated on
    # another's episodes (a copy of the default world's, given to ``soil_planner_calibrate
    # --world fee``) took a bound law 200× tighter without a word; the estimator says when its
    # episodes are of another world.
    world: str = ""
    # The force plugins switched on in those episodes (``pinn_fusion_calibrate --plugin``, specs as
    # ``soil_sim_batch --plugin`` takes them): an effect the world lacks, found in a machine's
    # bags. Recorded so that what calibrates or judges this config again simulates the same world
    # (the planner's bound law had been calibrated on episodes without the force; a reviewer's).
    # None: not recorded (a config written before it was, or made in code), () none.
    calibration_plugins: tuple[str, ...] | None = None
    # The soils of those episodes, each as a soils YAML's entry (``soils.soil_to_dict``): the
    # catalogue's or a site's (``pinn_fusion_calibrate --soil-file/--soils``). Recorded so that what
    # calibrates more of this config simulates them again (the planner's bound law of a site's config
    # had been calibrated on the catalogue's soils when --soil-file was not given again).
    # None: not recorded (a config written before it was, or made in code).
    calibration_soils: tuple[dict, ...] | None = field(default=None, hash=False)  # (dicts: not hashable)

    def __post_init__(self):
        for name, (lo, hi) in INT_FIELD_RANGES.items():
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or not lo <= v <= hi:
                raise ValueError(f"fusion {name}={short_repr(v)} must be an integer in [{lo}, {hi}]")
        if self.update_ticks % self.model_points:
            raise ValueError(f"fusion model_points={self.model_points} must divide update_ticks={self.update_ticks}")
        if (self.bound_abs_std_n is None) != (self.bound_rel_std is None):
            raise ValueError(f"fusion bound_abs_std_n={short_repr(self.bound_abs_std_n)} and bound_rel_std="
                             f"{short_repr(self.bound_rel_std)}: give both (the bound's law) or neither (the forecast law)")
        for name in PAIR_FIELDS + (BOUND_FIELDS if self.bound_abs_std_n is not None else ()):
            try:
                v = tuple(float(x) for x in getattr(self, name))
            except (TypeError, ValueError):
                raise ValueError(f"fusion {name}={short_repr(getattr(self, name))} must be two numbers (x, z)") from None
            except OverflowError:  # an integer of hundreds of digits (JSON has no bound): not finite
                v = (math.inf, math.inf)
            if len(v) != 2 or not all(math.isfinite(x) and x >= 0 for x in v) or (name.endswith("abs_std_n") and min(v) <= 0):
                raise ValueError(f"fusion {name}={short_repr(getattr(self, name))} must be two finite values >= 0 (abs > 0) for x, z")
            if max(v) > STD_FIELD_MAX[name]:
                raise ValueError(f"fusion {name}={short_repr(getattr(self, name))} must be at most {STD_FIELD_MAX[name]:g} for x, z")
            object.__setattr__(self, name, v)
        for name in ("unsteady_gain", "shape_noise_gain"):
            v = getattr(self, name)
            if not (finite_number(v) and v >= 0):
                raise ValueError(f"fusion {name}={short_repr(v)} must be finite and >= 0")
        if not isinstance(self.shape_evidence, bool):
            raise ValueError(f"fusion shape_evidence={self.shape_evidence!r} must be true or false")
        if not (finite_number(self.evidence_weight) and 0 < self.evidence_weight <= 1):
            raise ValueError(f"fusion evidence_weight={short_repr(self.evidence_weight)} must be in (0, 1]")
        for name in ("drift_per_sqrt_m", "patch_length_m", "cohesionless_prior", "stiff_prior"):
            v = getattr(self, name)
            if not (finite_number(v) and v >= 0):
                raise ValueError(f"fusion {name}={short_repr(v)} must be finite and >= 0")
        for name in ("cohesionless_prior", "stiff_prior"):
            if getattr(self, name) > 1:
                raise ValueError(f"fusion {name}={getattr(self, name)!r} must be a probability in [0, 1]")
        if self.cohesionless_prior + self.stiff_prior > 1:
            raise ValueError(f"fusion cohesionless_prior={self.cohesionless_prior!r} and stiff_prior={self.stiff_prior!r} "
                             "are shares of one prior: their sum must be at most 1")
        for name in ("prior_std", "change_nis"):
            v = getattr(self, name)
            if not (finite_number(v) and v > 0):
                raise ValueError(f"fusion {name}={short_repr(v)} must be a positive number")
        if self.prior_std > STD_FIELD_MAX["prior_std"]:
            raise ValueError(f"fusion prior_std={short_repr(self.prior_std)} must be at most {STD_FIELD_MAX['prior_std']:g} "
                             "(a share of the prior box)")
        if self.world not in ("", *WORLD_MODES):
            raise ValueError(f"fusion world={short_repr(self.world)} must be one of {WORLD_MODES} or \"\" (not recorded)")
        plugins = self.calibration_plugins
        if plugins is not None:
            if isinstance(plugins, (str, bytes)) or not isinstance(plugins, (list, tuple)) \
                    or not all(isinstance(p, str) and p.strip() for p in plugins):
                raise ValueError(f"fusion calibration_plugins={short_repr(plugins)} must be a list of plugin specs "
                                 "('package.module:function key=value ...') or null (not recorded)")
            object.__setattr__(self, "calibration_plugins", tuple(plugins))
        soils = self.calibration_soils
        if soils is not None:
            if isinstance(soils, (str, bytes, dict)) or not isinstance(soils, (list, tuple)) or not soils:
                raise ValueError(f"fusion calibration_soils={short_repr(soils)} must be a non-empty list of soils (a "
                                 "soils YAML's entries) or null (not recorded)")
            records = []
            for i, soil in enumerate(soils):
                try:
                    records.append(soil_to_dict(soil_from_dict(soil)))
                except ValueError as err:
                    raise ValueError(f"fusion calibration_soils[{i}]: {err}") from None
            object.__setattr__(self, "calibration_soils", tuple(records))
        terms = AugmentedFEE(self.terms).terms
        force_terms.refuse_repeats(terms, "fusion terms")  # a model sums them: twice would be k1 + k2
        object.__setattr__(self, "terms", terms)

    def to_dict(self) -> dict:
        out = asdict(self)
        out["terms"] = [[n, float(k)] for n, k in self.terms]
        return out

    @classmethod
    def from_dict(cls, data: dict) -> "FusionConfig":
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"fusion config: unknown field {unknown[0]!r}")
        data = dict(data)
        for name in PAIR_FIELDS + BOUND_FIELDS:
            if name in data and not (name in BOUND_FIELDS and data[name] is None):
                if isinstance(data[name], (str, bytes, dict)):
                    raise ValueError(f"fusion {name}={data[name]!r} must be two numbers (x, z)")
                try:
                    data[name] = tuple(data[name])
                except TypeError:
                    raise ValueError(f"fusion {name}={data[name]!r} must be two numbers (x, z)") from None
        if "terms" in data:
            terms = data["terms"]
            if not isinstance(terms, (list, tuple)) or not all(
                    isinstance(t, str) or (isinstance(t, (list, tuple)) and len(t) == 2 and isinstance(t[0], str))
                    for t in terms):
                raise ValueError(f"fusion terms={terms!r} must be a list of [name, k] pairs (or 'name=k' texts)")
            data["terms"] = tuple(t if isinstance(t, str) else tuple(t) for t in terms)
        try:
            return cls(**data)
        except TypeError as err:  # a value of the wrong type, e.g. text where a number is expected
            raise ValueError(f"fusion config: {err}") from None

    def planner_bound_law(self) -> tuple[float, float, float, float] | None:
        """The bound law as the planner's ``bound_law`` takes it, (abs_x [N], abs_z [N], rel_x, rel_z);
        None where the config has none (the planner then takes the published forecast law)."""
        if self.bound_abs_std_n is None:
            return None
        return (*map(float, self.bound_abs_std_n), *map(float, self.bound_rel_std))

    def with_fields(self, overrides: dict) -> "FusionConfig":
        """This config with some fields set (validated as a whole; errors name the field and value)."""
        return FusionConfig.from_dict({**self.to_dict(), **overrides})

    @staticmethod
    def parse_field(text: str) -> tuple[str, object]:
        """FIELD=VALUE (VALUE as JSON, e.g. ``drift_per_sqrt_m=0.005`` or ``rel_std=[0.01,0.02]``) of a
        command line that sets a field; ValueError naming what is wrong."""
        field, sep, value = text.partition("=")
        known = sorted(f.name for f in fields(FusionConfig))
        if not sep or field not in known:
            raise ValueError(f"{text!r}: expected FIELD=VALUE with FIELD one of {known}")
        try:
            return field, json.loads(value)
        except json.JSONDecodeError:
            raise ValueError(f"{text!r}: VALUE {value!r} is not JSON (a number or [x, z])") from None

    def save(self, path) -> None:
        write_text_atomically(path, json.dumps(self.to_dict(), indent=2) + "\n")

    @classmethod
    def load(cls, path) -> "FusionConfig":
        if Path(path).is_dir():  # (it was "[Errno 21] Is a directory")
            raise ValueError(f"fusion config {path} is a directory, not a config file (a .json pinn_fusion_calibrate writes)")
        try:
            data = json.loads(Path(path).read_text())
        except json.JSONDecodeError as err:
            raise ValueError(f"fusion config {path}: not JSON ({err})") from None
        if not isinstance(data, dict):
            raise ValueError(f"fusion config {path}: expected an object, got {type(data).__name__}")
        cfg = cls.from_dict(data)
        # (a config written before a field existed, or edited by hand: its default was taken unseen)
        # (nor the world, the plugins or the soils, not recorded before they were: their defaults are no law)
        if missing := sorted({f.name for f in fields(cls)} - set(data) - set(PROVENANCE_FIELDS) - set(OLD_LAW_DEFAULTS)):
            warnings.warn(f"fusion config {path} lacks {missing}: their defaults are used, not calibrated values",
                          stacklevel=2)
        return cfg
