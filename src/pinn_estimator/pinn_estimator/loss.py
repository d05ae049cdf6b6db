"""The physics-infused loss, paper Eq. 13-16, on normalised values (§2.2.2).

    L = λ_F  L_MAE^F(F, F̂; w_xz)            averaged over samples whose η and β are inside limits
      + λ_Fr L_MAE^Fr(F_r, 0; w_xz)          averaged over samples with d' = d + Δd > 0
      + Σ_χ λ_χ L_ReLU^χ(χ; Table 1 limits)  χ ∈ [φ, c, δ, β, η, ζ, Δd, d'], λ_η = λ_β = 10
      + λ_Δd (Δd̄ - Δd)^2                     Δd̄ = 0: the FEE depth is trusted unless the force says otherwise
      + λ_∂ L_MAE(∂N_γ/∂β, 0)                gradient reaches β only

Normalisation: F and F_r by the force scale (F_r by 10 % of it, §2.2.2), Table 1 parameters
by their min-max span, ∂N_γ/∂β by the span of its Table 1 range (20). The ReLU penalty of a
parameter is measured in units of its normalisation span so that degrees and pascals weigh alike.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import torch

from soil_physics import fee
from soil_msgs_py.params import KNOWN_PARAMS, TABLE1

from .model import FORCE_SCALE_N, RESIDUAL_FORCE_FRACTION

@dataclass(frozen=True)
class LossWeights:
    """λ of Eq. 13 as printed in §2.2.2 (λ_χ = 1, λ_η = λ_β = 10)."""

    force: float = 0.5
    residual: float = 3e-2
    delta_d_mse: float = 5e-3
    dn_gamma_dbeta: float = 0.2
    limits: float = 1.0
    limits_eta_beta: float = 10.0
    w_x: float = 1.0  # w_xz of Eq. 14
    w_z: float = 1.0

    def to_dict(self) -> dict:
        return asdict(self)


# χ in X of Eq. 13 and where each comes from in the model output.
LIMITED = ("phi", "c", "delta", "beta", "eta", "zeta", "delta_d", "d")


def _span(name: str) -> float:
    lo, hi = TABLE1[name].norm
    return (hi - lo) or 1.0


def relu_limit(x: torch.Tensor, name: str) -> torch.Tensor:
    """Eq. 16 in units of the parameter's normalisation span; open ("-") bounds never bite."""
    lo, hi = TABLE1[name].limits
    span = _span(name)
    out = torch.zeros_like(x)
    if lo > -float("inf"):
        out = out + torch.relu((lo - x) / span)
    if hi < float("inf"):
        out = out + torch.relu((x - hi) / span)
    return out


def limited_values(out: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """The unclipped χ of Eq. 13 from a PINN output (d is d' = d + Δd)."""
    phi, c, delta, beta, delta_d = out["theta_raw"].unbind(1)
    return {
        "phi": phi, "c": c, "delta": delta, "beta": beta, "eta": out["eta"],
        "zeta": phi - delta, "delta_d": delta_d, "d": out["d_prime"],
    }


def dn_gamma_dbeta_beta_only(out: dict[str, torch.Tensor], known: torch.Tensor) -> torch.Tensor:
    """∂N_γ/∂β at the estimated parameters with every input but β detached (§2.2.2)."""
    phi = out["theta"][:, 0].detach()
    delta_eff = out["delta_eff"].detach()
    beta = out["theta"][:, 3]
    rho = known[:, KNOWN_PARAMS.index("rho")]
    alpha = known[:, KNOWN_PARAMS.index("alpha")]
    return fee.dn_gamma_dbeta(phi, delta_eff, rho, alpha, beta)


def _masked_mean(x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    m = mask.to(x.dtype)
    return (x * m).sum() / m.sum().clamp(min=1.0)


def pinn_loss(out: dict[str, torch.Tensor], force: torch.Tensor, known: torch.Tensor, weights: LossWeights = LossWeights()):
    """Eq. 13 -> (total, dict of its weighted terms)."""
    w_xz = torch.tensor([weights.w_x, weights.w_z], dtype=force.dtype)
    force_scale = _force_scale(force)
    chi = limited_values(out)
    relu = {name: relu_limit(chi[name], name) for name in LIMITED}
    inside = (relu["eta"] == 0) & (relu["beta"] == 0)
    err_f = ((out["force"] - force).abs() / force_scale * w_xz).sum(1)
    err_r = (out["force_residual"].abs() / (RESIDUAL_FORCE_FRACTION * force_scale) * w_xz).sum(1)
    limits = sum(
        (weights.limits_eta_beta if n in ("eta", "beta") else weights.limits) * relu[n].mean() for n in LIMITED
    )
    delta_d = chi["delta_d"] / _span("delta_d")
    dng = dn_gamma_dbeta_beta_only(out, known) / _span("dn_gamma_dbeta")
    terms = {
        "force": weights.force * _masked_mean(err_f, inside),
        "residual": weights.residual * _masked_mean(err_r, chi["d"] > 0),
        "limits": limits,
        "delta_d": weights.delta_d_mse * (delta_d**2).mean(),
        "dn_gamma_dbeta": weights.dn_gamma_dbeta * dng.abs().mean(),
    }
    return sum(terms.values()), terms


# Θ_u entries expected to hold steady along one cut (β follows δ' and so the blade velocity).
CONSISTENT_PARAMS = ("phi", "c", "delta", "delta_d")


def consistency_loss(theta_a: torch.Tensor, theta_b: torch.Tensor) -> torch.Tensor:
    """Ours, not in the paper: mean |Θ̂_a - Θ̂_b| (normalised) of φ, c, δ, Δd over pairs of
    windows from the same episode.

    Why: per window the FEE gives one force magnitude and one direction; the direction pins δ
    but φ and c trade off freely (a sand fitted as a cohesive soil fits as well). Soil does not
    change along one cut, and one cut spans several depths, so asking the estimates of one
    episode to agree makes φ and c identifiable from the depth dependence of the force
    (γ d² N_γ vs c d N_c); Δd is included so a per-window depth offset cannot absorb that
    dependence. It needs no ground truth, only which windows share a cut. Off by default: on
    the validation split it lowered φ error but collapsed φ to a constant.
    """
    from soil_msgs_py.params import UNKNOWN_PARAMS

    cols = [UNKNOWN_PARAMS.index(n) for n in CONSISTENT_PARAMS]
    span = torch.tensor([_span(n) for n in CONSISTENT_PARAMS], dtype=theta_a.dtype)
    return ((theta_a[:, cols] - theta_b[:, cols]).abs() / span).sum(1).mean()


def force_loss(out: dict[str, torch.Tensor], force: torch.Tensor, weights: LossWeights = LossWeights()):
    """The physics-free baseline's loss: λ_F L_MAE^F alone, same normalisation."""
    w_xz = torch.tensor([weights.w_x, weights.w_z], dtype=force.dtype)
    err = ((out["force"] - force).abs() / _force_scale(force) * w_xz).sum(1).mean()
    return weights.force * err, {"force": weights.force * err}


def _force_scale(force: torch.Tensor) -> torch.Tensor:
    return torch.tensor(FORCE_SCALE_N, dtype=force.dtype, device=force.device)
