"""`pinn_train`: train the PINN (or its physics-free twin) from a directory of episode bags.

Reads bags with ``rosbags`` (cached by content fingerprint), splits by episode, normalises
observations with training-set statistics (stored in the model), Adam with plateau LR decay,
early stopping on the validation loss, a wall-clock budget, seeded. Writes the checkpoint and
a training-curve PNG beside it.

``--extra-term NAME=K`` (repeatable) trains the PINN with catalogue effects added to its
physics (F_phys = F_FEE + Σ k·B, ``soil_physics.force_terms``); the checkpoint's
model config records them, so every loader runs the same physics.

Under ``torchrun`` (``pinn_estimator.distributed``) every process trains on its share of each
global batch (--batch-size) with DistributedDataParallel; validation is shared out and its loss
agreed on, so every rank takes the same LR and stopping decisions; rank 0 reads the bags (and
writes the cache) before the others, and alone writes the checkpoint, curve and JSON.
``--ray [ADDRESS]`` reads the bags as Ray tasks.
"""
from __future__ import annotations

import argparse
import copy
import json
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np
import torch
import torch.distributed as dist

from soil_msgs_py.interrupts import (StopRequest, interrupt_exit_code, interrupt_for, interrupt_name, interrupts_deferred,
                                     stop_requests, terminate_as_interrupt)
from soil_msgs_py import cli_numbers
from soil_msgs_py.episode import world_modes
from soil_msgs_py.cli_paths import input_text, output_file, refuse_directories, save_figure_atomically
from soil_physics.force_terms import CATALOGUE, parse_terms

from soil_sim_node.ray_cluster import add_ray_option, parse_ray_options

from .checkpoint import is_checkpoint_file, save_checkpoint
from .dataset import (MAX_WINDOW_STRIDE, Dataset, add_skip_bad_bags_option, describe, identical_episodes, load_dataset,
                      split_episodes)
from .distributed import Ranks, agreed_max, gather, process_group, ranks_from_env, share, stop_when_orphaned
from .inference import WindowTensors, force_errors
from .loss import LossWeights, consistency_loss, force_loss, pinn_loss
from .model import EstimatorNet, ModelConfig, parameter_count

# ModelConfig fields that are not a plain ``--name`` option (fixed by the data, or --kind/--extra-term)
MODEL_FIELDS_NOT_OPTIONS = ("kind", "window", "n_obs", "n_known", "extra_terms")


LR_SCHEDULES = ("plateau", "cosine")
MAX_LR = 10.0  # the largest learning rate taken: far beyond any that trains (2e-3 does), short of overflowing
# A best validation force error beyond this share of the measured force [%] is a training that has
# not learnt: a model saying 0 N is off by 100 %. Said when the model is saved (--lr 1 gave 103 389 %
# and was saved without a word; an outside tester's).
NOT_LEARNT_PCT = 100.0


@dataclass
class TrainConfig:
    """Optimisation settings; every field is a ``pinn_train`` option of the same name."""

    seed: int = 0
    epochs: int = 40
    batch_size: int = 512
    lr: float = 2e-3
    stride: int = 2  # samples between the ends of consecutive training windows
    eval_stride: int = 10  # same, for validation
    patience: int = 8  # epochs without validation improvement before stopping
    max_minutes: float = 14.0  # wall-clock budget; the best model so far is kept
    val_fraction: float = 0.15
    test_fraction: float = 0.15
    threads: int = 2
    consistency: float = 0.0  # weight of the same-episode agreement term (ours; 0 = paper's Eq. 13 only)
    # "plateau": halve lr when validation stalls; "cosine": anneal lr to lr/200 over ``epochs``
    # (a fixed budget ends on a converged model: validation loss at lr 2e-3 jumps ±30 % epoch to
    # epoch, so comparing two models' best epochs under "plateau" compares their luck)
    lr_schedule: str = "plateau"

    def __post_init__(self):
        for name in ("epochs", "batch_size", "stride", "eval_stride", "patience", "threads"):
            v = getattr(self, name)
            if not isinstance(v, int) or v < 1:
                raise ValueError(f"{name}={v!r} must be a positive integer")
        for name in ("stride", "eval_stride"):
            if getattr(self, name) > MAX_WINDOW_STRIDE:
                raise ValueError(f"{name}={getattr(self, name)!r} must be at most {MAX_WINDOW_STRIDE} samples "
                                 "(10 s of samples): beyond it one window per episode")
        cli_numbers.check_local_count("threads", self.threads)
        if not (isinstance(self.consistency, (int, float)) and np.isfinite(self.consistency) and self.consistency >= 0):
            raise ValueError(f"consistency={self.consistency!r} must be a number >= 0")
        if self.lr_schedule not in LR_SCHEDULES:
            raise ValueError(f"lr_schedule={self.lr_schedule!r} must be one of {LR_SCHEDULES}")
        for name in ("lr", "max_minutes"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise ValueError(f"{name}={v!r} must be a positive number")
        if self.lr > MAX_LR:  # (1e300 ended in torch's "cannot be converted to type float without overflow")
            raise ValueError(f"lr={self.lr!r} must be at most {MAX_LR:g} (Adam's steps are about lr in each weight)")
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) or not 0 <= self.seed <= cli_numbers.MAX_NUMPY_SEED:
            raise ValueError(f"seed={self.seed!r} must be an integer in [0, 2**32 - 1] (numpy's seeding)")


def observation_statistics(ds: Dataset, episodes) -> tuple[np.ndarray, np.ndarray]:
    """Mean and std of o over the training episodes' rows (§2.2.2); constant features get std 1."""
    rows = np.concatenate([np.arange(ds.offsets[e], ds.offsets[e + 1]) for e in episodes])
    obs = ds.observations[rows]
    std = obs.std(0)
    return obs.mean(0), np.where(std > 1e-9, std, 1.0)


def _loss(model, out, force, known, weights):
    if model.cfg.kind == "pinn":
        return pinn_loss(out, force, known, weights)
    return force_loss(out, force, weights)


@torch.no_grad()
def _validate(model, tensors, ends, weights, batch_size=4096) -> tuple[float, np.ndarray]:
    """Mean validation loss and the predicted forces [N], from one pass over the windows (each
    with its newest row's travel and time in soil, ``WindowTensors``)."""
    model.eval()
    total, forces = 0.0, []
    for i in range(0, len(ends), batch_size):
        part = ends[i : i + batch_size]
        obs, known, force = tensors.batch(part)
        out = model(obs, known, tensors.distance[part], tensors.time_in_soil[part])
        loss, _ = _loss(model, out, force, known, weights)
        total += float(loss) * len(obs)
        forces.append(out["force"].double().numpy())
    return total / max(len(ends), 1), (np.concatenate(forces) if forces else np.zeros((0, 2)))


class JobFailed(RuntimeError):
    """Another process of the torchrun job failed mid-training; ``result`` is what ``train``
    returns, with the best model validated before it (rank 0 writes it)."""

    def __init__(self, message: str, result: tuple):
        super().__init__(message)
        self.result = result


def train(ds: Dataset, cfg: TrainConfig, model_cfg: ModelConfig, *, split=None, weights: LossWeights = LossWeights(),
          progress: bool = True, log=print, ranks: Ranks = Ranks(), stop: StopRequest | None = None,
          on_best: Callable[[EstimatorNet, dict, dict, dict], None] | None = None):
    """Train on ``ds``; returns (best model, split, history, metrics).

    ``ranks``: this process's place in a torchrun job (inside ``distributed.process_group``);
    every rank returns the same model. Each rank trains on its share of every global batch, its
    loss weighted by its share of the windows, so DDP's averaged gradient is the batch mean's
    (exactly for the plain means; the masked means of the force and residual terms are weighted
    by windows, not by masked windows).

    Stopping early keeps the best validated model, as the time budget does: a Ctrl-C or SIGTERM
    raised in one process, or, in a job, noted on ``stop`` (``interrupts.stop_requests``) by
    any rank, which every rank then acts on at the same step. A job whose other process failed
    (its collective broke) raises JobFailed carrying the best model. Before a first validated
    epoch either is raised as it came. ``on_best(model, split, history, metrics)``: called at each
    new best validation with that model (a copy) and provisional metrics (``stop_reason`` says so),
    for rank 0 to write it at once: a job whose rank 0 is killed, or whose stalled peer holds a
    collective until torchrun kills it, keeps its best model so far (an outside tester's lost five
    epochs either way)."""
    torch.manual_seed(cfg.seed)
    np.random.seed(cfg.seed)
    torch.set_num_threads(max(1, cfg.threads // ranks.local_world))  # the machine's --threads, shared
    given = split is not None
    split = split or split_episodes(ds, seed=cfg.seed, val_fraction=cfg.val_fraction, test_fraction=cfg.test_fraction)
    # all parts at once: a missing episode of any part is counted (the first part's alone were)
    ds.index([n for s in split for n in split[s]], fix="--split-from needs the bags its checkpoint was trained on")
    idx = {s: ds.index(split[s]) for s in split}
    if copies := identical_episodes(ds):
        shown = "; ".join(" = ".join(names) for names in copies[:3]) + ("; ..." if len(copies) > 3 else "")
        log(f"warning: {sum(len(c) - 1 for c in copies)} episodes are copies of others (the same samples under another "
            "name, or their first samples: two recorders, a replay recorded again or cut short, the seeds of one "
            f"noise-free fee-world episode): {shown}; each "
            "group kept in one split, where every copy weighs as one more episode")
    if given and (left := len(ds.names) - len({i for v in idx.values() for i in v})):
        log(f"{left} of the {len(ds.names)} episodes are in none of the given split's parts: left out (the split "
            "is the model's whose split was reused; train without it to use them)")
    if not idx["val"]:
        why = ("val_fraction is 0" if cfg.val_fraction <= 0 and not given else
               f"{len(ds.names)} episode(s) are too few to set any aside" if not given else "the given split has none")
        raise ValueError(f"the validation split is empty ({why}): early stopping needs validation episodes")
    if not idx["test"] and (given or cfg.test_fraction > 0):
        log(f"warning: the test split is empty ({len(ds.names)} episodes): pinn_eval will have nothing to score; "
            "use more episodes")
    mean, std = observation_statistics(ds, idx["train"])
    model = EstimatorNet(model_cfg, mean, std)
    net = model
    if ranks.active:
        net = torch.nn.parallel.DistributedDataParallel(model, forward_sync_buffers=False)
    # with the travel and time in soil since the episode start at every row (a window takes its
    # newest row's): only extra terms such as compaction_hardening look at them
    tensors = WindowTensors(ds)
    train_ends = torch.as_tensor(ds.window_ends(idx["train"], cfg.stride))
    # first and last possible window end of each training window's episode (partner draws)
    episode = torch.as_tensor(ds.episode_of_rows(train_ends.numpy()))
    first_end = torch.as_tensor(ds.offsets)[episode] + (model_cfg.window - 1)
    n_ends = torch.as_tensor(ds.offsets)[episode + 1] - first_end
    pairs = cfg.consistency > 0 and model_cfg.kind == "pinn"
    val_ends = torch.as_tensor(ds.window_ends(idx["val"], cfg.eval_stride))
    physics = "".join(f" + {k:g}·{name}" for name, k in model_cfg.extra_terms)
    n_eps = sum(len(v) for v in idx.values())
    log(f"{model_cfg.kind}{' (F_FEE' + physics + ')' if physics else ''}: {parameter_count(model)} parameters; "
        f"{len(train_ends)} training windows ({len(idx['train'])} episodes), {len(val_ends)} validation windows "
        f"({len(idx['val'])} episodes); episodes train / val / test "
        + " / ".join(f"{len(idx[s])} ({100 * len(idx[s]) / max(n_eps, 1):.0f} %)" for s in ("train", "val", "test"))
        + (" as the given split has them (--split-from)" if given else
           f" for val_fraction {cfg.val_fraction:g}, test_fraction {cfg.test_fraction:g} (by episode, stratified by "
           "world, soil and I_d: a cell of 3 or 4 episodes gives one to each)"))
    if len(train_ends) == 0:  # (an epoch divided by its window count: a ZeroDivisionError, an outside tester's)
        raise ValueError(f"no training window: none of its {len(idx['train'])} episodes holds {model_cfg.window} ticks "
                         "in a row without a gap (a window of one second at 60 Hz): give longer or more episodes")
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    if cfg.lr_schedule == "cosine":
        sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=cfg.epochs, eta_min=cfg.lr / 200)
    else:
        sched = torch.optim.lr_scheduler.ReduceLROnPlateau(opt, factor=0.5, patience=max(1, cfg.patience // 3))
    gen = torch.Generator().manual_seed(cfg.seed)
    history = {"epoch": [], "train_loss": [], "val_loss": [], "val_force_mae_n": [], "lr": [], "seconds": []}
    best = (float("inf"), None, 0, None)  # (val loss, weights, epoch, val forces)
    failed: BaseException | None = None  # a collective that broke: another process of the job failed
    interrupted = 0  # the exit code of the Ctrl-C or SIGTERM that stopped it (0: none did)
    start = time.monotonic()
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=cfg.epochs, desc=f"training {model_cfg.kind}", unit="epoch")
    stop_reason = "epochs"
    epoch_windows = 0

    def metrics_of(best, stop_reason: str, interrupted: int) -> dict:
        """The run's figures for the ``best`` (val loss, weights, epoch, val forces) model."""
        return {
            "processes": ranks.world,
            "train_windows_per_epoch": count,  # summed over the processes, partner windows included
            "best_epoch": best[2],
            "epochs_run": len(history["epoch"]),
            "stop_reason": stop_reason,
            "train_seconds": history["seconds"][-1] if history["seconds"] else 0.0,
            "val_loss": best[0],
            # the best epoch's validation, agreed by every rank (no pass alone over all of it)
            "val_force": force_errors(ds.forces[val_ends.numpy()], best[3]),
            "parameters": parameter_count(model),
            "interrupted_exit_code": interrupted,  # 130 / 143: the model is kept, but the run did not end by itself
        }

    try:
        for epoch in range(1, cfg.epochs + 1):
            net.train()
            perm = torch.randperm(len(train_ends), generator=gen)
            running, count = 0.0, 0
            step = cfg.batch_size // 2 if pairs else cfg.batch_size
            for i in range(0, len(perm), step):
                if stop is not None and ranks.active and (signum := agreed_max(stop.signum or 0, ranks)):
                    raise interrupt_for(signum)  # every rank, at this step
                pick = perm[i : i + step]
                if pairs:  # a partner window from the same episode for each window (drawn for the global batch)
                    partner = first_end[pick] + (torch.rand(len(pick), generator=gen) * n_ends[pick]).long()
                mine = share(len(pick), ranks)
                weight = (mine.stop - mine.start) * ranks.world / len(pick)
                if weight == 0:  # fewer windows than ranks: join the gradient all-reduce with weight 0
                    mine = slice(0, 1)
                ends = train_ends[pick[mine]]
                if pairs:
                    ends = torch.cat([ends, partner[mine]])
                n_pick = len(pick[mine])
                obs, known, force = tensors.batch(ends)
                out = net(obs, known, tensors.distance[ends], tensors.time_in_soil[ends])
                loss, _ = _loss(model, out, force, known, weights)
                if pairs:
                    loss = loss + cfg.consistency * consistency_loss(out["theta"][:n_pick], out["theta"][n_pick:])
                if not torch.isfinite(loss):
                    raise FloatingPointError(f"training loss became {float(loss)} at epoch {epoch}; lower --lr "
                                             "(or the k of an --extra-term)")
                opt.zero_grad(set_to_none=True)
                (loss * weight).backward()
                torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
                opt.step()
                if weight:
                    running += float(loss.detach()) * len(obs)
                    count += len(obs)
            val_loss, val_force, running, count, elapsed = _agree(model, tensors, val_ends, weights, ranks,
                                                                  running, count, start)
            val_mae = force_errors(ds.forces[val_ends.numpy()], val_force)["mae_mag_n"]
            if cfg.lr_schedule == "cosine":
                sched.step()
            else:
                sched.step(val_loss)
            epoch_windows = count
            for key, value in zip(history, (epoch, running / count, val_loss, val_mae, opt.param_groups[0]["lr"], elapsed)):
                history[key].append(value)
            if val_loss < best[0]:
                best = (val_loss, {k: v.clone() for k, v in model.state_dict().items()}, epoch, val_force)
                if on_best is not None:
                    kept = copy.deepcopy(model).eval()
                    kept.load_state_dict(best[1])
                    on_best(kept, split, {k: list(v) for k, v in history.items()},
                            metrics_of(best, f"in progress: the best model so far (epoch {epoch} of {cfg.epochs}), "
                                             "written at each improvement; a run that ends writes its own", 0))
            if bar is not None:
                bar.set_postfix(train=f"{running / count:.4f}", val=f"{val_loss:.4f}", val_mae=f"{val_mae:.0f}N")
                bar.update(1)
            if epoch - best[2] >= cfg.patience:
                stop_reason = f"early stop: no validation improvement for {cfg.patience} epochs"
                break
            if elapsed > 60 * cfg.max_minutes:
                stop_reason = f"time budget of {cfg.max_minutes} min reached"
                break
    except KeyboardInterrupt as exc:  # Ctrl-C or SIGTERM: keep the best model so far
        if best[1] is None or (ranks.active and stop is None):  # (raised in one rank alone: its peers are elsewhere)
            raise
        stop_reason = f"interrupted ({interrupt_name(exc)}) in epoch {epoch}"
        interrupted = interrupt_exit_code(exc)
    except (RuntimeError, dist.DistError) as exc:
        if not ranks.active or best[1] is None or not _broken_collective(exc):
            raise
        failed = exc
        stop_reason = f"another process of the job failed in epoch {epoch} ({_first_line(exc)})"
    if interrupted or failed is not None:  # stopped inside an epoch: its history may be half written
        rows = min(len(v) for v in history.values())  # an epoch whose history was half written
        for values in history.values():
            del values[rows:]
        count = epoch_windows  # the last whole epoch's
    if bar is not None:
        bar.close()
    if best[1] is None:  # every epoch's validation loss NaN or inf: there is no model to keep (--lr 1e4 did this)
        raise FloatingPointError(f"the validation loss was never finite in {len(history['epoch'])} epoch(s); lower --lr "
                                 "(or the k of an --extra-term)")
    model.load_state_dict(best[1])
    model.eval()
    metrics = metrics_of(best, stop_reason, interrupted)
    said = f"all {cfg.epochs} epochs run" if stop_reason == "epochs" else stop_reason
    log(f"{model_cfg.kind}: {said}; best epoch {best[2]}, val |F-F̂| = {metrics['val_force']['mae_mag_n']:.0f} N "
        f"({metrics['val_force']['mae_mag_pct_measured']:.1f} % of measured) in {metrics['train_seconds']:.0f} s")
    if (pct := metrics['val_force']['mae_mag_pct_measured']) > NOT_LEARNT_PCT:
        log(f"warning: the best epoch's force is off by {pct:.0f} % of the measured force on the validation episodes, "
            f"worse than a model that says 0 N ({NOT_LEARNT_PCT:g} %): this training has not learnt (too few epochs, now "
            f"{len(history['epoch'])}, or diverged: lower --lr, now {cfg.lr:g}); do not run it live (the estimator "
            "refuses only an F̂ beyond ten times the force limits, not one merely wrong)")
    if failed is not None:
        raise JobFailed(stop_reason, (model, split, history, metrics))
    return model, split, history, metrics


def _broken_collective(exc: BaseException) -> bool:
    """A collective that failed, not this process's own computation: gloo raises a plain
    RuntimeError naming its transport ("…/gloo/transport/tcp/pair.cc: Read error …: Connection
    reset by peer" when another rank was killed)."""
    return isinstance(exc, dist.DistError) or "gloo" in str(exc).lower()


def _first_line(exc: BaseException) -> str:
    return (str(exc).strip().splitlines() or [type(exc).__name__])[0][:200]


def _agree(model, tensors, val_ends, weights, ranks: Ranks, running: float, count: int, start: float):
    """(validation loss, predicted validation forces, training loss sum, its window count,
    elapsed s) of the epoch, the same on every rank: each validates its share of the windows and
    every rank combines all shares in rank order; the clock is rank 0's, so the time budget
    stops every rank at the same epoch."""
    if not ranks.active:
        val_loss, val_force = _validate(model, tensors, val_ends, weights)
        return val_loss, val_force, running, count, time.monotonic() - start
    mine = val_ends[share(len(val_ends), ranks)]
    loss, force = _validate(model, tensors, mine, weights)
    elapsed = time.monotonic() - start
    parts = gather((loss * len(mine), len(mine), force, running, count, elapsed), ranks)
    return (sum(p[0] for p in parts) / max(1, sum(p[1] for p in parts)), np.concatenate([p[2] for p in parts]),
            sum(p[3] for p in parts), sum(p[4] for p in parts), parts[0][5])


def plot_curve(history: dict, path: Path, title: str) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.6))
    a.plot(history["epoch"], history["train_loss"], label="train")
    a.plot(history["epoch"], history["val_loss"], label="validation")
    a.set_yscale("log")
    a.set_xlabel("epoch")
    a.set_ylabel("loss (Eq. 13, normalised)")
    a.legend()
    b.plot(history["epoch"], history["val_force_mae_n"], color="C2")
    b.set_xlabel("epoch")
    b.set_ylabel("validation mean |F - F̂| [N]")
    fig.suptitle(title)
    fig.tight_layout()
    save_figure_atomically(fig, path, dpi=90)
    plt.close(fig)
    return path


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="pinn_train", description=__doc__.splitlines()[0])
    p.add_argument("--data", required=True, type=input_text, help="directory of episode bags (searched recursively)")
    p.add_argument("--out", type=output_file, required=True, help="checkpoint path to write (.pt); the curve PNG goes beside it")
    p.add_argument("--overwrite", action="store_true",
                   help="replace a checkpoint already at --out (default: refused, as soil_sim_batch refuses an "
                        "existing dataset: a trained model costs minutes to hours)")
    p.add_argument("--kind", choices=("pinn", "physics_free"), default="pinn", help="model (default: pinn)")
    p.add_argument("--split-from", type=input_text, help="reuse the train/val/test split of this checkpoint (same bags)")
    p.add_argument("--workers", type=cli_numbers.workers, default=2, help="processes reading bags on the first run (with --ray alone: CPUs of the local Ray instance; 0: one per core)")
    p.add_argument("--no-cache", action="store_true", help="do not read or write the dataset cache")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_skip_bad_bags_option(p)
    add_ray_option(p, "read the bags as Ray tasks (rank 0 only under torchrun)")
    for f in fields(TrainConfig):
        kind = cli_numbers.seed if f.name == "seed" else type(f.default)
        choices = {"choices": LR_SCHEDULES} if f.name == "lr_schedule" else {}
        p.add_argument(f"--{f.name.replace('_', '-')}", type=kind, default=f.default, help=f"(default: {f.default})",
                       **choices)
    p.add_argument("--extra-term", action="append", default=[], metavar="NAME=K",
                   help="add the force term NAME with coefficient K to the PINN's physics "
                        "(F_FEE + Σ K·B_NAME; repeatable): a catalogue effect, one of: " + ", ".join(sorted(CATALOGUE))
                        + ", or a form form:<scale>*<factor> that soil_discrepancy discovered")
    for f in fields(ModelConfig):
        if f.name in MODEL_FIELDS_NOT_OPTIONS:
            continue
        p.add_argument(f"--{f.name.replace('_', '-')}", type=type(f.default), default=f.default, help=f"model (default: {f.default})")
    return p


def curve_path(out: Path) -> Path:
    """The training curve's figure beside the checkpoint ``out``."""
    return out.with_name(out.stem + "_curve.png")


def main(argv=None) -> int:
    args = parse_ray_options(_parser(), argv)
    try:
        ranks = ranks_from_env()
        cfg = TrainConfig(**{f.name: getattr(args, f.name) for f in fields(TrainConfig)})
        model_cfg = ModelConfig(kind=args.kind, extra_terms=parse_terms(args.extra_term),
                                **{f.name: getattr(args, f.name) for f in fields(ModelConfig) if f.name not in MODEL_FIELDS_NOT_OPTIONS})
        refuse_directories([curve_path(Path(args.out))])
    except ValueError as err:
        print(f"pinn_train: error: {err}", file=sys.stderr)
        return 2
    # every rank alike, before any joins a process group (a torchrun job on one machine, or on
    # several that share the output's filesystem, as rank 0's checkpoint is read back); said once
    if Path(args.out).exists() and not is_checkpoint_file(args.out):
        # (a bag's .mcap or metadata.yaml given as --out was replaced by a checkpoint, an outside tester's)
        if ranks.main:
            print(f"pinn_train: error: --out {args.out} exists and is not a checkpoint pinn_train wrote: --overwrite "
                  "replaces only a checkpoint; give another path (or remove the file yourself)", file=sys.stderr)
        return 2
    if Path(args.out).exists() and not args.overwrite:
        if ranks.main:
            print(f"pinn_train: error: --out {args.out} exists (a trained model): give --overwrite to replace it, or "
                  "another path", file=sys.stderr)
        return 2
    with stop_when_orphaned(ranks), process_group(ranks):
        return _run(args, cfg, model_cfg, ranks)


def _run(args, cfg: TrainConfig, model_cfg: ModelConfig, ranks: Ranks) -> int:
    """Load, train, and (rank 0) write; an error is printed once, by rank 0."""
    best_so_far = None
    noted = None  # a job's stop request (``stop_requests``) once training began
    written = False  # the finished run's checkpoint, curve and summary
    try:
        with terminate_as_interrupt():  # SIGTERM while the bags are read (no collective under way) as Ctrl-C: it had
            ds = _load(args, ranks)  # killed the run in silence (timeout's, a scheduler's, torchrun's stopping a job)
        worlds = world_modes(ds.metas)
        if len(worlds) > 1 and ranks.main:  # allowed (one model for both), but rarely meant: said
            print(f"pinn_train: warning: the bags under {args.data} mix worlds {worlds} (bag metadata world_mode): one "
                  "model for both, where the shipped ones are one per world; pinn_eval scores its test split across "
                  "both but judges the force at another depth in one world (--forecast-world, one world's "
                  "--forecast-data), and soil_discrepancy takes one world's bags", file=sys.stderr)
        split = None
        if args.split_from:
            from .checkpoint import read_checkpoint

            split = read_checkpoint(args.split_from)["split"]
        # SIGTERM (timeout, a scheduler) as Ctrl-C: the best model so far is kept. A torchrun job's
        # ranks note either signal and stop at one step, and rank 0 writes unhindered by the second
        # Ctrl-C every rank gets (the terminal's, then torchrun's)
        best_so_far = _best_so_far(args, cfg, ds) if ranks.main else None
        with stop_requests() if ranks.active else terminate_as_interrupt() as stop:
            noted = stop
            failed = None
            try:
                model, split, history, metrics = train(ds, cfg, model_cfg, split=split,
                                                       progress=not args.quiet and ranks.main,
                                                       log=_say if ranks.main else _silent, ranks=ranks, stop=stop,
                                                       on_best=best_so_far)
            except JobFailed as err:
                failed = err
                model, split, history, metrics = err.result
            if ranks.main:
                # a stop while they are written waits for them (a second or so): cut short, the checkpoint
                # was the finished one but the curve and the summary were missing, and the line said less
                with interrupts_deferred():  # (leaving it raises a signal that came meanwhile)
                    _write(args, cfg, ds, model, split, history, metrics)
                    written = True
    except (ValueError, FileNotFoundError, FloatingPointError, RuntimeError) as err:
        if isinstance(err, RuntimeError) and noted is not None and noted.signum:
            # a collective that failed after this job was told to stop: a peer that stopped first (torchrun ends
            # the ranks it stops), not a fault; said as the interrupt it is (it read "Connection closed by peer")
            return _said_interrupted(args, ranks, best_so_far, interrupt_for(noted.signum))
        if ranks.main:
            print(f"pinn_train: error: {err}", file=sys.stderr)
        return 1 if isinstance(err, RuntimeError) else 2  # a run that broke (a worker died) / the input's fault
    except KeyboardInterrupt as exc:  # before a first epoch was validated, or a second Ctrl-C (a first keeps the best)
        if written:  # a signal while the results were written, which waited for them
            if metrics["interrupted_exit_code"]:  # the training had already stopped on a first one: said as that
                return _said_stopped(args, ranks, metrics)
            print(f"pinn_train: interrupted ({interrupt_name(exc)}) as its results were written; they are complete: "
                  f"{args.out}, its curve and the summary", file=sys.stderr)
            return interrupt_exit_code(exc)
        return _said_interrupted(args, ranks, best_so_far, exc)
    if failed is not None:
        if ranks.main:
            print(f"pinn_train: error: {failed}; the best model validated before it is written to {args.out}",
                  file=sys.stderr)
        return 1
    if metrics["interrupted_exit_code"]:  # kept, and said; a script can still tell it from a finished run
        return _said_stopped(args, ranks, metrics)
    return 0


def _said_stopped(args, ranks: Ranks, metrics: dict) -> int:
    """Rank 0 says how the training stopped early and where its best model is; the exit code of
    that stop."""
    if ranks.main:
        print(f"pinn_train: {metrics['stop_reason']}; the best model (epoch {metrics['best_epoch']}) is written to "
              f"{args.out}", file=sys.stderr)
    return metrics["interrupted_exit_code"]


def _write(args, cfg: TrainConfig, ds: Dataset, model, split, history, metrics) -> None:
    """The checkpoint, its training curve, and the run's summary on stdout (rank 0)."""
    out = Path(args.out)
    save_checkpoint(out, model, train_config=asdict(cfg), dataset=describe(ds), split=split, metrics=metrics, history=history)
    curve = plot_curve(history, curve_path(out), f"{args.kind} on {Path(args.data).name}")
    print(json.dumps({"checkpoint": str(out), "curve": str(curve), **{k: metrics[k] for k in ("best_epoch", "epochs_run", "stop_reason", "train_seconds")}, "val_force": metrics["val_force"]}, indent=1))


def _best_so_far(args, cfg: TrainConfig, ds: Dataset):
    """``train``'s ``on_best`` for rank 0: each new best model written to ``--out`` at once
    (atomically; the finished run's checkpoint, curve and summary replace it). Its ``written``
    says the epoch of the last one (0: none yet)."""
    def write(model, split, history, metrics) -> None:
        try:
            save_checkpoint(Path(args.out), model, train_config=asdict(cfg), dataset=describe(ds), split=split,
                            metrics=metrics, history=history)
        except OSError as err:  # (a disk full for a moment must not end the training; the final write says its own)
            if not write.failed:
                print(f"pinn_train: warning: the best model so far could not be written to {args.out} ({err}); "
                      "training goes on", file=sys.stderr)
            write.failed = True
            return
        write.written = metrics["best_epoch"]
    write.written, write.failed = 0, False
    return write


def _said_interrupted(args, ranks: Ranks, best_so_far, exc: KeyboardInterrupt) -> int:
    """Rank 0 says what an interrupt before the end left (the best model written while training, or
    nothing); the exit code of the signal."""
    if ranks.main:
        kept = best_so_far.written if best_so_far is not None else 0
        print(f"pinn_train: interrupted ({interrupt_name(exc)}); "
              + (f"the best model so far (epoch {kept}) is in {args.out}, as written while training (no curve)"
                 if kept else "nothing written"), file=sys.stderr)
    return interrupt_exit_code(exc)


def _say(message: str) -> None:
    """``log`` of rank 0: progress on stderr, so that stdout holds the run's summary alone (JSON, as
    docs/cluster.md says; the progress lines before it made ``pinn_train ... > run.json`` unreadable, an
    outside tester's)."""
    print(message, file=sys.stderr, flush=True)


def _silent(*_args, **_kwargs) -> None:
    """``log`` of the ranks other than 0: rank 0 speaks for the job."""


def _load(args, ranks: Ranks) -> Dataset:
    """The dataset. Rank 0 reads the bags first (over Ray with --ray) and writes the cache;
    then the other ranks read that cache (or the bags, where there is none: --no-cache, skipped
    bad bags, a read-only directory), so no two processes write the cache at once."""
    options = dict(cache=not args.no_cache, workers=args.workers, skip_bad_bags=args.skip_bad_bags)
    ds, problem = None, None
    if ranks.main:
        try:
            ds = load_dataset(args.data, progress=not args.quiet, ray_address=args.ray,
                              ray_give_up_after_s=args.ray_give_up_after, **options)
        except (ValueError, FileNotFoundError, RuntimeError) as err:
            problem = err
    first = gather(None if problem is None else f"{type(problem).__name__}: {problem}", ranks)[0]
    if problem is not None:
        raise problem
    if first is not None:  # rank 0 failed and says why
        raise ValueError(first)
    if not ranks.main:
        ds = load_dataset(args.data, log=_silent, **options)
    return ds


if __name__ == "__main__":
    sys.exit(main())
