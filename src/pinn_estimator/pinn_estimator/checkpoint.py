"""Checkpoints: weights + normalisation + config + dataset fingerprint + split + metrics.

Everything is plain Python containers and tensors so ``torch.load(..., weights_only=True)``
can read it: loading a checkpoint never executes code from the file. Table 1 ranges the
model was trained with are stored too: a model whose output units no longer match the code's
Table 1 is refused rather than silently mis-scaled.
"""
from __future__ import annotations

from pathlib import Path

import torch

from soil_msgs_py.episode import WORLD_MODES
from soil_msgs_py.params import KNOWN_PARAMS, OBSERVATION_FIELDS, TABLE1, UNKNOWN_PARAMS
from soil_msgs_py.cli_paths import replace_atomically
from soil_msgs_py.values import short_repr

from .model import FORCE_SCALE_N, EstimatorNet, ModelConfig
from .shipped import DEFAULT_WORLD, shipped_checkpoint

FORMAT = "insitu-soil-estimator"
FORMAT_VERSION = 1
DEFAULT_CHECKPOINT = shipped_checkpoint(DEFAULT_WORLD)


def interface() -> dict:
    """What a checkpoint's inputs and outputs mean; must match the code to be loadable."""
    return {
        "observation_fields": list(OBSERVATION_FIELDS),
        "known_params": list(KNOWN_PARAMS),
        "unknown_params": list(UNKNOWN_PARAMS),
        "force_scale_n": list(FORCE_SCALE_N),
        "table1_norm": {n: list(TABLE1[n].norm) for n in (*KNOWN_PARAMS, *UNKNOWN_PARAMS)},
    }


def save_checkpoint(path, model: EstimatorNet, *, train_config: dict, dataset: dict, split: dict, metrics: dict, history: dict) -> Path:
    """Write atomically (``.tmp`` then rename) so a killed trainer never leaves half a model."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "model_config": model.cfg.to_dict(),
        "interface": interface(),
        "state_dict": {k: v.detach().cpu().clone() for k, v in model.state_dict().items()},
        "train_config": train_config,
        "dataset": dataset,
        "split": split,
        "metrics": metrics,
        "history": history,
        "torch_version": str(torch.__version__),
    }
    return replace_atomically(path, lambda tmp: torch.save(payload, tmp))


# The dict sections of a checkpoint (save_checkpoint) that its readers look into.
CHECKPOINT_SECTIONS = ("model_config", "state_dict", "train_config", "dataset", "split", "metrics", "history")


def is_checkpoint_file(path) -> bool:
    """Whether ``path`` is a file pinn_train wrote (any format version: an old model may be
    replaced), read without running code; what ``pinn_train --overwrite`` may replace."""
    try:
        ckpt = torch.load(Path(path), map_location="cpu", weights_only=True)
    except Exception:  # noqa: BLE001 - not a torch file, damaged, or a pickle of objects
        return False
    return isinstance(ckpt, dict) and ckpt.get("format") == FORMAT


def read_checkpoint(path) -> dict:
    """The checkpoint's dict, validated; ValueError names what is wrong."""
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"checkpoint {path} is a directory, not a checkpoint file (the .pt pinn_train writes)")
    if not path.is_file():
        raise FileNotFoundError(f"checkpoint {path} does not exist")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # noqa: BLE001 - torch raises many types for a foreign/corrupt file
        if "unsupported global" in str(err).lower():  # a pickled object: not torch's advice to unpickle it anyway (runs its code)
            raise ValueError(f"checkpoint {path} holds Python objects beyond tensors and plain containers, which are "
                             "never unpickled here (unpickling runs code from the file): not a file pinn_train "
                             "writes") from None
        # torch's own words, without its advice to load the file with weights_only=False (that runs its code)
        text = str(err)
        if "WeightsUnpickler error:" in text:  # (a damaged file: torch's lines before it are about the weights_only default)
            text = text.split("WeightsUnpickler error:", 1)[1]
            text = " ".join(line.strip() for line in text.split("Check the documentation")[0].splitlines() if line.strip())
        said = text.split("Re-running")[0].strip().splitlines()[0] if text.strip() else ""
        raise ValueError(f"checkpoint {path} is not a readable torch checkpoint (a file pinn_train writes; damaged or "
                         f"another format?): {type(err).__name__}: {said[:200]}") from None
    if not isinstance(ckpt, dict) or ckpt.get("format") != FORMAT:
        raise ValueError(f"checkpoint {path} is not an insitu-soil estimator checkpoint (format {FORMAT!r} missing)")
    if ckpt.get("format_version") != FORMAT_VERSION:
        raise ValueError(f"checkpoint {path} has format_version={ckpt.get('format_version')!r}; this code reads {FORMAT_VERSION}")
    if ckpt.get("interface") != interface():
        theirs, ours = ckpt.get("interface"), interface()
        if not isinstance(theirs, dict):
            raise ValueError(f"checkpoint {path} has interface={short_repr(theirs)}, not the inputs/outputs pinn_train "
                             "records; retrain it")
        changed = sorted(k for k in ours if k in theirs and theirs[k] != ours[k])
        said = ([f"{', '.join(changed)} differ"] if changed else []) + [
            f"{', '.join(repr(k) for k in sorted(keys, key=str))} {what}" for keys, what in (
                ([k for k in ours if k not in theirs], "missing"),
                ([k for k in theirs if k not in ours], "not inputs or outputs this code knows")) if keys]
        raise ValueError(f"checkpoint {path} was trained with different inputs/outputs ({'; '.join(said)}); retrain it")
    missing = [k for k in CHECKPOINT_SECTIONS if not isinstance(ckpt.get(k), dict)]
    if missing:
        raise ValueError(f"checkpoint {path} lacks its section(s) {', '.join(missing)} (a file pinn_train writes has them)")
    return ckpt


def load_model(path) -> tuple[EstimatorNet, dict]:
    """(model in eval mode, checkpoint dict). Refuses another architecture with a clear message."""
    ckpt = read_checkpoint(path)
    try:
        cfg = ModelConfig.from_dict(ckpt["model_config"])
    except (TypeError, ValueError) as err:
        raise ValueError(f"checkpoint {path}: {err}") from None
    state = ckpt.get("state_dict")
    if not isinstance(state, dict) or "backbone.obs_mean" not in state or "backbone.obs_std" not in state:
        raise ValueError(f"checkpoint {path} has no observation normalisation (backbone.obs_mean/obs_std) in its weights")
    model = EstimatorNet(cfg, state["backbone.obs_mean"], state["backbone.obs_std"])
    try:
        model.load_state_dict(state, strict=True)
    except RuntimeError as err:
        first = str(err).splitlines()[0:3]
        raise ValueError(f"checkpoint {path} does not fit model config {cfg}: {' '.join(first)}") from None
    bad = next((k for k, v in state.items() if torch.is_floating_point(v) and not torch.isfinite(v).all()), None)
    if bad is not None:  # a training that diverged: every estimate would be NaN
        raise ValueError(f"checkpoint {path}: its weights {bad} are not finite (NaN or inf); retrain it")
    if not bool((model.backbone.obs_std > 0.0).all()):  # observations are divided by it: 0 gave inf inputs, NaN estimates
        raise ValueError(f"checkpoint {path}: its observation scales backbone.obs_std hold values <= 0 "
                         f"({model.backbone.obs_std.min().item():g}); pinn_train writes positive ones, retrain it")
    model.eval()
    return model, ckpt


def trained_worlds(ckpt: dict | None) -> list[str]:
    """The simulator worlds a checkpoint's training data came from, sorted ([]: not recorded)."""
    return sorted(set(((ckpt or {}).get("dataset") or {}).get("world_modes") or ()))


def world_mismatch(checkpoint, ckpt: dict, world: str, use: str) -> str:
    """The sentence saying ``checkpoint`` was trained in another world than ``world``, where it is
    used as ``use`` says ("" if its training worlds include ``world``, are not recorded, or ``world``
    is no simulator world): one check for every tool that takes a --checkpoint and a world
    (``pinn_eval``'s report, ``soil_cut_report``), which an outside tester's fee checkpoint in the
    default world had passed in silence."""
    trained = trained_worlds(ckpt)
    if not trained or world not in WORLD_MODES or world in trained:
        return ""
    return (f"{Path(checkpoint).name} was trained on {', '.join(trained)}-world data; {use}: give the {world} world's "
            "checkpoint (--checkpoint) unless the mismatch is what you want to measure")


def world_mismatch_lines(text: str) -> list[str]:
    """Markdown lines of a report for ``world_mismatch``'s sentence (none if it is "")."""
    return ["", f"**Another world's checkpoint**: {text}."] if text else []
