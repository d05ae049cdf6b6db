"""Step 5 for the PINN: retrain it with the named effect and compare on held-out episodes.

Two PINNs are trained side by side on the same episodes with the same seed: one with the
model's physics before the workflow (F̂ = F_FEE + F_r, plus any accepted terms), one with the
named terms added (F̂ = F_FEE + Σ k·B + F_r, the k the workflow fitted, fixed).

Episodes. The PINN estimates the soil from kinematics alone (it never sees the force), so it
cannot extrapolate to a soil strength it was never trained on: scored on whole held-out soil
groups, its error is that extrapolation (about 3 kN on the full-size run, the same with or
without the term) and says nothing about the physics. So each held-out θ-group is split by
episode (seeded): a *calibration* half joins the PINN's training (as a user's recordings of the
site would) and the *scored* half is what both PINNs are compared on. The named term's k was
fitted on the selection groups only, so no scored episode has touched k or either PINN.
A θ-group with a single held-out episode (e.g. ``--group-by episode``) is scored only.

Three force predictions per PINN, each scored like the FEE model (``gap.compare_predictions``:
RMSE, per regime, paired test over episodes):

- ``force``: F̂, what the network outputs. Its free residual F_r and, more, its per-window soil
  estimates can absorb a missing effect, so F̂ barely moves with the term.
- ``physics``: F̂ − F_r, the physics part on the window's own estimates.
- ``soil``: the soil estimates pooled per θ-group (median φ̂, ĉ, δ̂ of the group's scored
  windows) through the same FEE (+ terms) model as the workflow's (``AugmentedFEE``), along the
  measured trajectory. This is the test that matters: a soil does not change with speed or
  depth, and a planner predicts the force at other depths and speeds from θ̂. A PINN that
  absorbed the missing effect into θ̂ (e.g. a higher φ̂ at high speed) fails it; one with the
  right physics passes.

The FEE model is scored on the same episodes for reference (θ fitted per group, as in step 5).
"""
from __future__ import annotations

import dataclasses
import functools
import pickle
import tempfile
from pathlib import Path

import numpy as np

from soil_msgs_py.params import WINDOW_SAMPLES
from soil_msgs_py.process_pool import map_in_processes
from soil_physics.augmented_fee import AugmentedFEE

from pinn_estimator.dataset import Dataset
from pinn_estimator.inference import WindowTensors, predict
from pinn_estimator.model import ModelConfig
from pinn_estimator.train import TrainConfig, train
from .candidates import limit_blas_threads
from .fee_fit import ThetaFit
from .frame import Frame
from .gap import compare_predictions, error_metrics, fee_gap

PREDICTIONS = ("force", "physics", "soil")
VAL_FRACTION = 0.2  # of the selection episodes: early stopping and model choice


def pinn_split(test_frame: Frame, selection: list[str], seed: int, val_fraction: float = VAL_FRACTION) -> dict[str, list[str]]:
    """Episode names: train (selection + calibration), val (selection), calibration, test (scored).

    Each held-out θ-group's episodes are shuffled (seeded) and the first half (rounded down)
    goes to calibration; the rest is scored."""
    rng = np.random.default_rng(seed)
    names = sorted(selection)
    rng.shuffle(names)
    n_val = max(1, int(round(val_fraction * len(names))))
    calibration, scored = [], []
    for g in test_frame.groups:
        eps = sorted(test_frame.episode_names([g]))
        rng.shuffle(eps)
        half = len(eps) // 2
        calibration += eps[:half]
        scored += eps[half:]
    return {"train": sorted(names[n_val:] + calibration), "val": sorted(names[:n_val]),
            "calibration": sorted(calibration), "test": sorted(scored)}


def pooled_theta(frame: Frame, thetas) -> ThetaFit:
    """Median (φ̂, ĉ, δ̂) per θ-group of per-tick estimates: one (N, ≥3) array [rad, Pa, rad] at
    ``frame``'s ticks or a list of them (an ensemble: the median over all members' ticks)."""
    thetas = [np.asarray(t, float) for t in (thetas if isinstance(thetas, (list, tuple)) else [thetas])]
    out = ThetaFit()
    group = frame.group
    for g in np.unique(group):
        rows = np.concatenate([t[group == g, :3] for t in thetas])
        rows = rows[np.isfinite(rows).all(1)]
        ok = len(rows) > 0
        out.theta[int(g)] = np.median(rows, 0) if ok else np.full(3, np.nan)
        out.success[int(g)] = bool(ok)
    return out


def pinn_gap(ds: Dataset, test_frame: Frame, selection: list[str], model_before: AugmentedFEE,
             model_after: AugmentedFEE, *, epochs: int = 12, seed: int = 0, seeds: int = 1, stride: int = 4,
             eval_stride: int = 5, threads: int = 1, max_minutes: float = 5.0, edges: dict | None = None,
             workers: int = 1, log=print) -> dict:
    """Held-out comparison of the PINN trained with ``model_before``'s terms and with ``model_after``'s.

    ``test_frame``: the workflow's held-out ticks; ``selection``: the episode names the workflow
    selected terms on; ``seed``: the split and the first training seed; ``seeds``: PINNs per
    physics, trained with seeds seed, seed+1, ... on the same split and scored as an ensemble
    (F̂ averaged, θ̂ pooled over all members): one PINN's figures move by up to 1 kN from seed to
    seed. Returns {"split", "terms", "epochs", "seeds", "train": {before, after} (per seed),
    "theta": {before, after} (pooled per group), "comparisons": {force, physics, soil, FEE},
    "per_seed": {"soil_rmse_before": [...], "soil_rmse_after": [...]} (each member alone)}.
    ``threads``: torch threads of each PINN; a PINN's figures depend on it (float sums in another
    order), not on ``workers``. ``workers`` > 1: the 2 × ``seeds`` PINNs train in that many
    spawned processes at once (one small network per core trains ~2x faster than one network on
    two torch threads), each giving what it gives alone; their per-epoch log lines stay in the
    children. ``log``: a print-like function, or None for silence."""
    log = log or (lambda *_: None)
    if len(selection) < 2:
        raise ValueError(f"{len(selection)} selection episode(s): the PINN needs at least 2 (train + validation)")
    if len(test_frame) == 0:
        raise ValueError("no held-out episodes to compare the PINNs on")
    if not isinstance(seeds, int) or seeds < 1:
        raise ValueError(f"seeds={seeds!r} must be a positive integer (PINNs per physics)")
    if not isinstance(workers, int) or isinstance(workers, bool) or workers < 1:
        raise ValueError(f"workers={workers!r} must be a positive integer (processes training PINNs)")
    split = pinn_split(test_frame, selection, seed)
    index = {name: i for i, name in enumerate(test_frame.names)}
    scored = test_frame.select(episodes=[index[n] for n in split["test"]])
    out: dict = {"split": split, "terms": [list(t) for t in model_after.terms],
                 "terms_before": [list(t) for t in model_before.terms], "epochs": epochs, "seed": seed, "seeds": seeds,
                 "window_samples": WINDOW_SAMPLES, "ticks": int(len(scored)), "threads_per_pinn": threads,
                 "train": {}, "theta": {}, "per_seed": {}}
    models = {"before": model_before, "after": model_after}
    jobs = [(label, member) for label in models for member in range(seeds)]
    workers = min(workers, len(jobs))
    for label, fee_model in models.items():
        physics = "F_FEE" + "".join(f" + {k:g}·{n}" for n, k in fee_model.terms)
        log(f"PINN {label}: {seeds} trained with {physics} + F_r ({workers} at a time)")
    # the same fixed budget for both, annealed to convergence (no early stop): validation
    # loss jumps epoch to epoch at a constant lr, and comparing best epochs compares luck
    # (TrainConfig validates threads and the other training settings)
    tasks = [(TrainConfig(seed=seed + member, epochs=epochs, stride=stride, eval_stride=eval_stride, patience=epochs,
                          threads=threads, max_minutes=max_minutes, lr_schedule="cosine"),
              models[label].terms, split, scored.rows) for label, member in jobs]
    if workers > 1:
        # spawn, not fork: a forked child of a process whose torch threads already ran can hang;
        # the dataset goes once to each worker, without the ground truth (training never reads
        # it, and a blind dataset has none), through a file: given as the workers' start argument, it
        # went down each worker's start pipe, and a worker that died while it started (a script without
        # `if __name__ == "__main__":`, run again in it) left this process writing into that pipe for ever.
        # The project's pool: a dead worker is WorkerDied; the workers ignore Ctrl-C (the terminal sends it to
        # them too: each printed its traceback) and an interrupt or error stops them (SIGTERM), not after the
        # minutes of training they hold
        payload = dataclasses.replace(ds, truth=np.zeros((len(ds.observations), 0)))
        with tempfile.TemporaryDirectory(prefix="pinn_gap_") as tmp:
            path = Path(tmp) / "dataset.pickle"
            with path.open("wb") as f:
                pickle.dump(payload, f, protocol=pickle.HIGHEST_PROTOCOL)
            results = list(map_in_processes(_train_member, tasks, workers, what="training PINNs", start_method="spawn",
                                            initializer=functools.partial(_worker_start, str(path)), stop_workers=True))
    else:
        results = [_train_member(task, log, ds) for task in tasks]
    preds: dict[str, dict[str, np.ndarray]] = {}
    for label, fee_model in models.items():
        members = [pred for (lab, _), (pred, _) in zip(jobs, results) if lab == label]
        out["train"][label] = [metrics for (lab, _), (_, metrics) in zip(jobs, results) if lab == label]
        soil = [_soil_force(scored, fee_model, pooled_theta(scored, m["theta"])) for m in members]
        out["per_seed"][f"soil_rmse_{label}"] = [error_metrics(scored.forces - f)["rmse"] for f in soil]
        theta = pooled_theta(scored, [m["theta"] for m in members])
        # F̂ estimates the measured force (the PINN is trained on it): less the blade's inertia it
        # is its estimate of the soil's, which the frame holds
        preds[label] = {"force": np.mean([m["force"] for m in members], 0) - scored.inertia,
                        "physics": np.mean([m["force"] - m["force_residual"] for m in members], 0),
                        "soil": _soil_force(scored, fee_model, theta)}
        out["theta"][label] = theta.table(scored)
    out["comparisons"] = {
        key: compare_predictions(scored, preds["before"][key], preds["after"][key], label=f"PINN {key}", edges=edges)
        for key in PREDICTIONS
    }
    out["comparisons"]["FEE"], _ = fee_gap(scored, model_before, model_after, edges=edges)
    return out


_WORKER_DATASET: Dataset | None = None  # a pinn_gap worker's dataset (``_worker_start``)


def _worker_start(dataset_path: str) -> None:
    """A spawned pinn_gap worker: the dataset, once (a pickle ``pinn_gap`` wrote); one BLAS thread
    (torch's are set per PINN)."""
    global _WORKER_DATASET
    with open(dataset_path, "rb") as f:
        _WORKER_DATASET = pickle.load(f)
    limit_blas_threads()


def _train_member(task, log=None, ds: Dataset | None = None) -> tuple[dict[str, np.ndarray], dict]:
    """One PINN of ``pinn_gap`` (a process-pool task when ``workers`` > 1, on the worker's
    dataset): train it on the split, then its outputs on the scored rows and its training figures."""
    cfg, terms, split, rows = task
    ds = _WORKER_DATASET if ds is None else ds
    model, _, _, metrics = train(ds, cfg, ModelConfig(extra_terms=terms), split=split, progress=False,
                                  log=log or (lambda *_: None))
    return predict(model, WindowTensors(ds), rows), {k: metrics[k] for k in ("train_seconds", "best_epoch", "epochs_run",
                                                                           "stop_reason")}


def _soil_force(frame: Frame, fee_model: AugmentedFEE, theta: ThetaFit) -> np.ndarray:
    """(N, 2) [N]: the model's force along ``frame``'s measured trajectory with θ per group."""
    fx, fz = fee_model.force(theta.per_tick(frame), frame.known, frame.distance, time_in_soil=frame.time_in_soil)
    return np.stack((fx, fz), -1)
