"""The physics-infused network of paper §2.2.1 (Fig. 4) and its physics-free twin.

    o_[t-59..t] (60 x 9, normalised) --Conv1d--> l x N --transformer encoder--> l x N
        --flatten ++ Θ_k (min-max, Table 1)--> integration net (2 x 20) --linear-->
        [Θ_u = φ, c, δ, β, Δd (Table 1 min-max units) | F_r (units of 10 % of the force scale)]
    Θ = [Θ_k, Θ_u] clipped to Table 1 limits, d' = d + Δd --FEE (soil_msgs_py.fee)--> F_FEE
    F̂ = F_FEE + F_r

The physics-free twin has the same backbone and size but its head predicts F directly: it is
the baseline that tells whether the physics costs force accuracy.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

import torch
from torch import nn

from soil_msgs_py import fee
from soil_msgs_py.params import FORCE_LIMITS_N, KNOWN_PARAMS, OBSERVATION_FIELDS, TABLE1, UNKNOWN_PARAMS, WINDOW_SAMPLES

MODEL_KINDS = ("pinn", "physics_free")
# Forces are normalised by the machine's limits (20 kN tractive, 30 kN lift): fixed, physical,
# independent of the dataset, so a model's normalised error reads as "% of machine limit".
FORCE_SCALE_N = FORCE_LIMITS_N
# §2.2.2: "Values for the residual force are normalized F_r to 10% of the value of F".
RESIDUAL_FORCE_FRACTION = 0.1


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

    def __post_init__(self):
        if self.kind not in MODEL_KINDS:
            raise ValueError(f"model kind={self.kind!r} is not one of {MODEL_KINDS}")
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name not in ("kind", "dropout") and (not isinstance(v, int) or isinstance(v, bool) or v < 1):
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

    @classmethod
    def from_dict(cls, data: dict) -> "ModelConfig":
        names = {f.name for f in fields(cls)}
        unknown = set(data) - names
        if unknown:
            raise ValueError(f"model config has unknown keys {sorted(unknown)} (a checkpoint of another architecture?)")
        return cls(**data)

    def to_dict(self) -> dict:
        return asdict(self)


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
    (B, 5) clipped, ``d_prime``, ``force_fee``, ``force_residual`` (B, 2) [N], ``delta_eff``
    (velocity-corrected clipped δ, Eq. 10) and ``eta`` (δ' + ρ + φ + β of the unclipped outputs).
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

    def forward(self, obs: torch.Tensor, known: torch.Tensor) -> dict[str, torch.Tensor]:
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
        return {
            "force": force_fee + residual,
            "force_fee": force_fee,
            "force_residual": residual,
            "theta_raw": theta_raw,
            "theta": theta,
            "d_prime": k["d"] + theta_raw[:, 4],
            "delta_eff": delta_eff,
            "eta": delta_eff_raw + k["rho"] + raw[0] + raw[3],
        }


def parameter_count(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())
