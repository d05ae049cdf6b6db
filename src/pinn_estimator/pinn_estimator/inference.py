"""Running a model on windows of a dataset, and the force-error figures of paper §3.2.

Shared by the trainer (validation), the evaluation report and the tests, so every number
is computed one way.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch

from soil_bag_tools.bag_io import read_episode
from soil_msgs_py.params import FORCE_LIMITS_N as FORCE_LIMITS, WINDOW_SAMPLES

from .dataset import Dataset, load_dataset
from .model import EstimatorNet
from .fusion import fused_track
from .fusion_config import FusionConfig
from .online import FUSED, estimate_values

FORCE_LIMITS_N = np.array(FORCE_LIMITS)
# §3.2 normalises the magnitude error by the machine limits: 730 N ~ 2 % -> |(20, 30) kN| = 36 kN.
FORCE_LIMIT_MAGNITUDE_N = float(math.hypot(*FORCE_LIMITS_N))
WINDOW_OFFSETS = torch.arange(-(WINDOW_SAMPLES - 1), 1)


class WindowTensors:
    """The dataset's rows as float32 tensors, gathered into (B, T, 9) windows by end row."""

    def __init__(self, ds: Dataset):
        self.obs = torch.as_tensor(ds.observations, dtype=torch.float32)
        self.known = torch.as_tensor(ds.known, dtype=torch.float32)
        self.force = torch.as_tensor(ds.forces, dtype=torch.float32)
        self.distance = torch.as_tensor(ds.distance_in_soil(), dtype=torch.float32)  # for distance terms
        self.time_in_soil = torch.as_tensor(ds.time_in_soil(), dtype=torch.float32)  # for time terms

    def batch(self, ends: torch.Tensor):
        return self.obs[ends[:, None] + WINDOW_OFFSETS], self.known[ends], self.force[ends]


@torch.no_grad()
def predict(model: EstimatorNet, tensors: WindowTensors, ends: np.ndarray, batch_size: int = 2048) -> dict[str, np.ndarray]:
    """Model outputs (SI, float64 NumPy) for the windows ending at global rows ``ends``."""
    model.eval()
    parts: dict[str, list] = {}
    ends_t = torch.as_tensor(ends, dtype=torch.int64)
    for i in range(0, len(ends_t), batch_size):
        part = ends_t[i : i + batch_size]
        obs, known, _ = tensors.batch(part)
        for key, value in model(obs, known, tensors.distance[part], tensors.time_in_soil[part]).items():
            parts.setdefault(key, []).append(value.double().numpy())
    return {k: np.concatenate(v) for k, v in parts.items()}


def force_errors(measured: np.ndarray, predicted: np.ndarray) -> dict[str, float]:
    """§3.2 figures: mean |F - F̂| [N] per axis and of the vector magnitude, as % of the mean
    measured |F| (ratio of means: robust where F passes through 0) and as % of machine limits."""
    err = np.abs(predicted - measured)
    mag_err = np.hypot(*(predicted - measured).T)
    mag = np.hypot(*measured.T)
    out = {"windows": int(len(measured))}
    for j, axis in enumerate(("x", "z")):
        out[f"mae_{axis}_n"] = float(err[:, j].mean())
        out[f"mae_{axis}_pct_measured"] = float(100 * err[:, j].mean() / max(np.abs(measured[:, j]).mean(), 1e-9))
        out[f"mae_{axis}_pct_limit"] = float(100 * err[:, j].mean() / FORCE_LIMITS_N[j])
    out["mae_mag_n"] = float(mag_err.mean())
    out["mae_mag_pct_measured"] = float(100 * mag_err.mean() / max(mag.mean(), 1e-9))
    out["mae_mag_pct_limit"] = float(100 * mag_err.mean() / FORCE_LIMIT_MAGNITUDE_N)
    return out


def episode_estimates(model: EstimatorNet, bag, fusion: FusionConfig | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The offline pipeline on one recorded episode bag: (stamps of the newest sample of every
    full window, ``/soil/estimate`` values of each, batched, with the fused fields of the
    episode's posterior at each; ``fusion`` None: the shipped default world's config, the node's for the shipped model). What the online
    estimator must publish for the same episode (up to float32 rounding of batch 1 vs batched)."""
    from .fusion_calibration import config_for_model

    bag = Path(bag)
    ds = load_dataset(bag.parent, cache=False)
    (e,) = ds.index([bag.name])
    ends = ds.window_ends([e])
    out = predict(model, WindowTensors(ds), ends)
    values = estimate_values({k: torch.as_tensor(v) for k, v in out.items()})
    cfg = config_for_model(fusion, model)
    rows = ds.episode_rows(e)
    track = fused_track(cfg, ds.forces[rows], ds.known[rows], ds.distance_in_soil()[rows],
                        ds.observations[rows], ds.gap_before[rows])
    values[:, FUSED] = track[ends - ds.offsets[e]]
    stamps = read_episode(bag).stamps_ns[ends - ds.offsets[e]]
    return stamps, values
