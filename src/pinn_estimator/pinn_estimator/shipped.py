"""Where the shipped models and their calibrations live, by world (no torch: a launcher asks).

One home for the paths every tool builds from a world's name: the launcher giving the
estimator its world's model, the cut trial, the node's warnings, the benchmarks.
"""
from __future__ import annotations

from pathlib import Path

MODELS_DIR = Path(__file__).resolve().parent / "models"
DEFAULT_WORLD = "default"  # the shipped estimator's world (pinn_default.pt): the node's and replay's config


def shipped_checkpoint(world: str) -> Path:
    """The shipped PINN checkpoint trained in ``world`` (it may not exist for a world of one's own)."""
    return MODELS_DIR / f"pinn_{world}.pt"


def config_path(world: str) -> Path:
    """Where the calibrated fusion config of a world lives (next to the shipped checkpoints)."""
    return MODELS_DIR / f"fusion_{world}.json"

