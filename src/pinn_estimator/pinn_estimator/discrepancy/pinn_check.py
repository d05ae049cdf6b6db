"""Step 5 for the PINN: retrain it with the named effect and compare on held-out episodes.

Two PINNs are trained side by side on the same episodes (the workflow's selection part,
split into training and validation by episode) with the same seed: one with the paper's
physics (F̂ = F_FEE + F_r), one with the added term (F̂ = F_FEE + k·B + F_r, the k the
workflow fitted, fixed). Both are scored on the held-out episodes the workflow never used:
the force error of F̂, and of the physics part alone (F̂ − F_r), which is what the added
term must improve: a PINN's free residual F_r can absorb a missing effect in F̂, but then
the physics (and so the estimated soil parameters) carries the error.
"""
from __future__ import annotations

import numpy as np

from soil_msgs_py.params import WINDOW_SAMPLES

from ..data import Dataset
from ..inference import WindowTensors, force_errors, predict
from ..model import ModelConfig
from ..train import TrainConfig, train


def _split(selection: list[str], heldout: list[str], seed: int, val_fraction: float = 0.2) -> dict[str, list[str]]:
    rng = np.random.default_rng(seed)
    names = sorted(selection)
    rng.shuffle(names)
    n_val = max(1, int(round(val_fraction * len(names))))
    return {"train": sorted(names[n_val:]), "val": sorted(names[:n_val]), "test": sorted(heldout)}


def pinn_gap(ds: Dataset, selection: list[str], heldout: list[str], terms, *, epochs: int = 12, seed: int = 0,
             stride: int = 4, eval_stride: int = 5, threads: int = 2, max_minutes: float = 5.0,
             log=print) -> dict:
    """Held-out force errors of the PINN without and with ``terms`` ((name, k), ...).

    Returns {"split": ..., "before": {"force": .., "physics": ..}, "after": {...}, "train": {...}}
    with ``inference.force_errors`` figures (x, z, magnitude; N and %)."""
    if len(selection) < 2:
        raise ValueError(f"{len(selection)} selection episode(s): the PINN needs at least 2 (train + validation)")
    if not heldout:
        raise ValueError("no held-out episodes to compare the PINNs on")
    split = _split(selection, heldout, seed)
    cfg = TrainConfig(seed=seed, epochs=epochs, stride=stride, eval_stride=eval_stride, patience=max(3, epochs // 3),
                      threads=threads, max_minutes=max_minutes)
    tensors = WindowTensors(ds)
    ends = ds.window_ends(ds.index(split["test"]), eval_stride)
    measured = ds.forces[ends]
    out: dict = {"split": split, "terms": [list(t) for t in terms], "epochs": epochs}
    for label, extra in (("before", ()), ("after", tuple(terms))):
        log(f"PINN {label}: training with {'F_FEE' + ''.join(f' + {k:g}·{n}' for n, k in extra)} + F_r")
        model, _, _, metrics = train(ds, cfg, ModelConfig(extra_terms=extra), split=split, progress=False, log=log)
        pred = predict(model, tensors, ends)
        physics = pred["force"] - pred["force_residual"]
        out[label] = {"force": force_errors(measured, pred["force"]), "physics": force_errors(measured, physics),
                      "train_seconds": metrics["train_seconds"], "best_epoch": metrics["best_epoch"]}
    out["windows"] = int(len(ends))
    out["window_samples"] = WINDOW_SAMPLES
    return out
