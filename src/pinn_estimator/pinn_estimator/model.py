"""The physics-infused network of paper §2.2.1 (Fig. 4) and its physics-free twin.

    o_[t-59..t] (60 x 9, normalised) --Conv1d--> l x N --transformer encoder--> l x N
        --flatten ++ Θ_k (min-max, Table 1)--> integration net (2 x 20) --linear-->
        [Θ_u = φ, c, δ, β, Δd (Table 1 min-max units) | F_r (units of 10 % of the force scale)]
    Θ = [Θ_k, Θ_u] clipped to Table 1 limits, d' = d + Δd --FEE (soil_physics.fee)--> F_FEE
    F̂ = F_FEE + F_r

Augmented physics: ``ModelConfig.extra_terms`` = ((name, k), ...) of catalogue terms
(``soil_physics.force_terms``), each ΔF = k·B evaluated on the same Θ, d' and F_FEE, so

    F_phys = F_FEE + Σ k·B        F̂ = F_phys + F_r

with k fixed (not trained). ``force_fee`` stays the pure FEE part, ``force_extra`` is Σ k·B.
A term that looks at the blade's travel in soil (``DISTANCE_TERMS``) needs the ``distance``
input: ``soil_physics.travel.distance_in_soil`` over the episode, at the window's newest sample;
one that looks at its time in soil (a discovered form) the ``time_in_soil`` input likewise
(``soil_physics.travel.time_in_soil``).

The physics-free twin has the same backbone and size but its head predicts F directly: it is
the baseline that tells whether the physics costs force accuracy.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

import torch
from torch import nn

from soil_physics import force_terms as X
from soil_physics import fee
from soil_physics.force_inputs import ForceInputs
from soil_msgs_py.params import FORCE_LIMITS_N, KNOWN_PARAMS, OBSERVATION_FIELDS, TABLE1, UNKNOWN_PARAMS, WINDOW_SAMPLES

MODEL_KINDS = ("pinn", "physics_free")
# Forces are normalised by the machine's limits (20 kN tractive, 30 kN lift): fixed, physical,
# independent of the dataset, so a model's normalised error reads as "% of machine limit".
FORCE_SCALE_N = FORCE_LIMITS_N
# §2.2.2: "Values for the residual force are normalized F_r to 10% of the value of F".
RESIDUAL_FORCE_FRACTION = 0.1
# Catalogue terms whose basis depends on ForceInputs.distance_in_soil: a model using one needs
# the ``distance`` input (tests check no other catalogue term looks at it).
DISTANCE_TERMS = X.DISTANCE_TERMS  # catalogue terms; forms on the travel s too (X.uses_distance)


@dataclass(frozen=True)
class ModelConfig:
    """Architecture hyperparameters (l = number of conv output steps, N = d_model)."""

    kind: str = "pinn"
    window: int = WINDOW_SAMPLES
    n_obs: int = len(OBSERVATION_FIELDS)
    n_known: int = len(KNOWN_PARAMS)
    conv_kernel: int = 6
    conv_stride: int = 6
    d_model: int = 32
    n_heads: int = 4
    n_layers: int = 2
    ff_dim: int = 64
    dropout: float = 0.1
    hidden: int = 20
    # Catalogue terms added to the FEE force with a fixed k: ((name, k), ...), e.g.
    # (("soil_inertia", 2.0),). Empty = the paper's PINN.
    extra_terms: tuple[tuple[str, float], ...] = ()

    def __post_init__(self):
        if self.kind not in MODEL_KINDS:
            raise ValueError(f"model kind={self.kind!r} is not one of {MODEL_KINDS}")
        if isinstance(self.extra_terms, (str, bytes)):
            raise ValueError(f"model extra_terms={self.extra_terms!r} must be a sequence of 'name=k' or (name, k), not one string")
        terms = X.parse_terms(self.extra_terms)  # ValueError naming the bad term
        X.refuse_repeats(terms, "model extra_terms")
        names = [n for n, _ in terms]
        if terms and self.kind != "pinn":
            raise ValueError(f"model extra_terms={list(names)} need kind='pinn' (the {self.kind} model has no physics to add them to)")
        object.__setattr__(self, "extra_terms", terms)
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name not in ("kind", "dropout", "extra_terms") and (not isinstance(v, int) or isinstance(v, bool) or v < 1):
                raise ValueError(f"model {f.name}={v!r} must be a positive integer")
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"model dropout={self.dropout!r} must be in [0, 1)")
        if self.d_model % self.n_heads:
            raise ValueError(f"model d_model={self.d_model} must be divisible by n_heads={self.n_heads}")
        if self.conv_kernel > self.window:
            raise ValueError(f"model conv_kernel={self.conv_kernel} is longer than the window={self.window}")

    @property
    def n_tokens(self) -> int:  # l
        return (self.window - self.conv_kernel) // self.conv_stride + 1

    @property
    def needs_distance(self) -> bool:
        """True if a configured extra term needs the ``distance`` (travel in soil) input."""
        return any(X.uses_distance(name) for name, _ in self.extra_terms)

    @property
    def needs_time(self) -> bool:
        """True if a configured extra term needs the ``time_in_soil`` input."""
        return any(X.uses_time(name) for name, _ in self.extra_terms)

    @classmethod
    def from_dict(cls, data: dict) -> "ModelConfig":
        names = {f.name for f in fields(cls)}
        unknown = set(data) - names
        if unknown:
            raise ValueError(f"model config has unknown keys {sorted(unknown)} (a checkpoint of another architecture?)")
        return cls(**data)

    def to_dict(self) -> dict:
        """Plain containers (checkpoints load with weights_only=True); extra_terms as [[name, k], ...]."""
        out = asdict(self)
        out["extra_terms"] = [[name, float(k)] for name, k in self.extra_terms]
        return out


def _spans(names):
    lo = torch.tensor([TABLE1[n].norm[0] for n in names], dtype=torch.float32)
    span = torch.tensor([(TABLE1[n].norm[1] - TABLE1[n].norm[0]) or 1.0 for n in names], dtype=torch.float32)
    return lo, span


def _limits(names):
    lo = torch.tensor([TABLE1[n].limits[0] for n in names], dtype=torch.float32)
    hi = torch.tensor([min(TABLE1[n].limits[1], 1e9) for n in names], dtype=torch.float32)
    return lo, hi


class Backbone(nn.Module):
    """Temporal convolution -> transformer encoder (Zerveas et al. 2021) -> integration net."""

    def __init__(self, cfg: ModelConfig, obs_mean, obs_std):
        super().__init__()
        self.cfg = cfg
        self.register_buffer("obs_mean", torch.as_tensor(obs_mean, dtype=torch.float32).reshape(cfg.n_obs))
        self.register_buffer("obs_std", torch.as_tensor(obs_std, dtype=torch.float32).reshape(cfg.n_obs))
        known_lo, known_span = _spans(KNOWN_PARAMS)
        self.register_buffer("known_lo", known_lo)
        self.register_buffer("known_span", known_span)
        self.conv = nn.Conv1d(cfg.n_obs, cfg.d_model, cfg.conv_kernel, stride=cfg.conv_stride)
        # Zerveas et al.: learnable positional encoding added to the projected sequence.
        self.position = nn.Parameter(torch.zeros(1, cfg.n_tokens, cfg.d_model))
        nn.init.uniform_(self.position, -0.02, 0.02)
        layer = nn.TransformerEncoderLayer(
            cfg.d_model, cfg.n_heads, cfg.ff_dim, cfg.dropout, activation="gelu", batch_first=True
        )
        self.encoder = nn.TransformerEncoder(layer, cfg.n_layers, enable_nested_tensor=False)
        self.integration = nn.Sequential(
            nn.Linear(cfg.n_tokens * cfg.d_model + cfg.n_known, cfg.hidden),
            nn.GELU(),
            nn.Linear(cfg.hidden, cfg.hidden),
            nn.GELU(),
        )

    def forward(self, obs: torch.Tensor, known: torch.Tensor) -> torch.Tensor:
        """obs (B, T, 9) SI, known (B, 9) SI at the newest sample -> latent (B, hidden)."""
        x = (obs - self.obs_mean) / self.obs_std
        x = self.conv(x.transpose(1, 2)).transpose(1, 2) * math.sqrt(self.cfg.d_model)
        x = self.encoder(x + self.position)
        k = (known - self.known_lo) / self.known_span
        return self.integration(torch.cat([x.flatten(1), k], dim=1))


class EstimatorNet(nn.Module):
    """PINN (``kind='pinn'``) or physics-free baseline (``kind='physics_free'``).

    ``forward`` returns a dict of SI tensors: ``force`` (B, 2) = F̂ [N] always; for the PINN
    also ``theta_raw`` (B, 5) Θ_u before clipping (what the ReLU limits act on), ``theta``
    (B, 5) clipped, ``d_prime``, ``force_fee`` (the pure FEE part), ``force_extra`` (Σ k·B of
    ``cfg.extra_terms``, zeros without), ``force_residual`` (B, 2) [N], so that
    force = force_fee + force_extra + force_residual; ``delta_eff`` (velocity-corrected
    clipped δ, Eq. 10) and ``eta`` (δ' + ρ + φ + β of the unclipped outputs).
    """

    def __init__(self, cfg: ModelConfig, obs_mean, obs_std):
        super().__init__()
        self.cfg = cfg
        self.backbone = Backbone(cfg, obs_mean, obs_std)
        n_out = len(UNKNOWN_PARAMS) + 2 if cfg.kind == "pinn" else 2
        self.head = nn.Linear(cfg.hidden, n_out)
        self.register_buffer("force_scale", torch.tensor(FORCE_SCALE_N, dtype=torch.float32))
        theta_lo, theta_span = _spans(UNKNOWN_PARAMS)
        self.register_buffer("theta_lo", theta_lo)
        self.register_buffer("theta_span", theta_span)
        lim_lo, lim_hi = _limits(UNKNOWN_PARAMS)
        self.register_buffer("limit_lo", lim_lo)
        self.register_buffer("limit_hi", lim_hi)
        with torch.no_grad():  # start Θ_u mid-range and F_r at zero: a sane FEE from step one
            self.head.weight.mul_(0.1)
            self.head.bias.zero_()
            if cfg.kind == "pinn":
                self.head.bias[: len(UNKNOWN_PARAMS)] = 0.5

    @property
    def needs_distance(self) -> bool:
        return self.cfg.needs_distance

    @property
    def needs_time(self) -> bool:
        return self.cfg.needs_time

    def forward(self, obs: torch.Tensor, known: torch.Tensor, distance: torch.Tensor | None = None,
                time_in_soil: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        """obs (B, T, 9), known (B, 9) SI at the newest sample; ``distance`` (B,) [m] the blade's
        travel in soil since the episode start at the newest sample (``Dataset.distance_in_soil``),
        required only if ``needs_distance`` (ValueError otherwise), ignored else; ``time_in_soil``
        (B,) [s] likewise (``Dataset.time_in_soil``, required if ``needs_time``)."""
        # float64 callers (NumPy-born tensors) get the model's float32, not a dtype error
        obs, known = obs.to(self.force_scale.dtype), known.to(self.force_scale.dtype)
        out = self.head(self.backbone(obs, known))
        if self.cfg.kind == "physics_free":
            return {"force": out * self.force_scale}
        n = len(UNKNOWN_PARAMS)
        theta_raw = out[:, :n] * self.theta_span + self.theta_lo
        theta = torch.maximum(torch.minimum(theta_raw, self.limit_hi), self.limit_lo)
        residual = out[:, n:] * (RESIDUAL_FORCE_FRACTION * self.force_scale)
        k = {name: known[:, j] for j, name in enumerate(KNOWN_PARAMS)}
        phi, c, delta, beta, delta_d = theta.unbind(1)
        d_lo, d_hi = TABLE1["d"].limits
        d_prime = torch.clamp(k["d"] + delta_d, d_lo, d_hi)
        fx, fz, _ = fee.fee_xz({**k, "phi": phi, "c": c, "delta": delta, "d": d_prime}, beta=beta)
        delta_eff, _ = fee.velocity_corrected(delta, k["c_a"], k["rho"], k["alpha"], k["v_x"], k["v_z"])
        raw = theta_raw.unbind(1)  # eta of the unclipped outputs: the ReLU limit must see the excursion
        delta_eff_raw, _ = fee.velocity_corrected(raw[2], k["c_a"], k["rho"], k["alpha"], k["v_x"], k["v_z"])
        force_fee = torch.stack([fx, fz], dim=1)
        if self.cfg.extra_terms:
            force_extra = self._extra_force(k, theta, d_prime, fx, fz, distance, time_in_soil)
            force_phys = force_fee + force_extra
        else:  # the paper's PINN: exactly the original arithmetic (shipped checkpoints unchanged)
            force_extra = torch.zeros_like(force_fee)
            force_phys = force_fee
        return {
            "force": force_phys + residual,
            "force_fee": force_fee,
            "force_extra": force_extra,
            "force_residual": residual,
            "theta_raw": theta_raw,
            "theta": theta,
            "d_prime": k["d"] + theta_raw[:, 4],
            "delta_eff": delta_eff,
            "eta": delta_eff_raw + k["rho"] + raw[0] + raw[3],
        }

    def _path_input(self, value, name: str, uses, what: str, source: str, like: torch.Tensor):
        """The per-window ``value`` (B,) of a path input (travel or time in soil) as ``like``'s
        dtype; zeros when absent and no term uses it; ValueError naming the terms otherwise."""
        if value is None:
            used = sorted(term for term, _ in self.cfg.extra_terms if uses(term))
            if used:
                raise ValueError(
                    f"extra term(s) {used} need the blade's {what}: call model(obs, known, {name}=...) "
                    f"with {source} of the episode at each window's newest sample"
                )
            return torch.zeros_like(like)
        value = torch.as_tensor(value).to(like.dtype).reshape(-1)
        if len(value) != len(like):
            raise ValueError(f"{name} has {len(value)} values for a batch of {len(like)} windows")
        return value

    def _extra_force(self, k, theta, d_prime, fx, fz, distance, time_in_soil=None) -> torch.Tensor:
        """Σ k·B of the configured terms on the model's own Θ (clipped), d' and F_FEE -> (B, 2) [N]."""
        distance = self._path_input(distance, "distance", X.uses_distance, "travel in soil",
                                    "Dataset.distance_in_soil", fx)
        time_in_soil = self._path_input(time_in_soil, "time_in_soil", X.uses_time, "time in soil",
                                        "Dataset.time_in_soil", fx)
        g = _FiniteGrad.apply  # the estimated inputs: a term's singularity must not poison Θ_u's gradient
        inputs = ForceInputs.from_known(
            k, phi=g(theta[:, 0]), c=g(theta[:, 1]), delta=g(theta[:, 2]), distance_in_soil=distance,
            f_fee_x=g(fx), f_fee_z=g(fz), d=g(d_prime), time_in_soil=time_in_soil,
        )
        ex = ez = torch.zeros_like(fx)
        for name, coef in self.cfg.extra_terms:  # X.apply, with a non-finite basis value counted as 0
            bx, bz = X.get_term(name).basis(inputs)
            ex = ex + coef * torch.where(torch.isfinite(bx), bx, 0.0)
            ez = ez + coef * torch.where(torch.isfinite(bz), bz, 0.0)
        return torch.stack([ex, ez], dim=1)


class _FiniteGrad(torch.autograd.Function):
    """Identity whose backward zeroes non-finite gradient elements.

    Some catalogue formulas are singular at the edges of Θ's limits or off their domain:
    tip_penetration's N_c = (N_q − 1)/tan φ is 0/0 at φ = 0 (clipped), its e^{π tan φ}
    overflows float32 above φ ≈ 87°, and side_wall_shear masks an invalid β* with ``where``,
    whose backward still multiplies 0 by the masked branch's inf/NaN derivative. There the term
    counts as 0 (forward) and that sample's estimates get no gradient from the extra terms,
    instead of turning the loss (and, through clip_grad_norm_, every weight) into NaN.
    Finite elements pass exactly.
    """

    @staticmethod
    def forward(ctx, x):
        return x.view_as(x)

    @staticmethod
    def backward(ctx, grad):
        return torch.where(torch.isfinite(grad), grad, torch.zeros_like(grad))


def parameter_count(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())
