"""Data-parallel training under ``torchrun``: ranks, the process group, shares of a batch.

torchrun sets WORLD_SIZE, RANK, LOCAL_WORLD_SIZE (and MASTER_ADDR/PORT) in every process it
starts; without them training is one process and nothing here talks to anyone. Every rank
draws the same split, permutation and partner windows from the same seed and trains on its
contiguous share of each global batch; DistributedDataParallel averages the gradients, so one
and N processes take the same optimisation steps. The backend is gloo: the trainer keeps its
tensors on the CPU (nccl only moves CUDA tensors).
"""
from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import timedelta

import torch
import torch.distributed as dist

from soil_msgs_py.cli_numbers import check_local_count

# How long a rank waits in a collective: rank 0 reads the bags (possibly a fleet's worth) while
# the others wait at a barrier, so the default 30 min could be too short. A rank that dies
# does not make the others wait this long: torchrun stops the whole group.
GROUP_TIMEOUT = timedelta(hours=4)
ORPHAN_POLL_S = 1.0  # how often a rank looks whether torchrun, its parent, is still there [s]


@dataclass(frozen=True)
class Ranks:
    """This process's place in the job (one process: rank 0 of 1)."""

    rank: int = 0
    world: int = 1
    local_world: int = 1  # processes on this machine (they share its cores)

    @property
    def main(self) -> bool:
        """Rank 0 reads the bags first, logs, and writes the checkpoint."""
        return self.rank == 0

    @property
    def active(self) -> bool:
        return self.world > 1


def ranks_from_env(env=os.environ) -> Ranks:
    """The Ranks torchrun announced; ValueError names a malformed variable."""
    values = {}
    for name, default in (("RANK", 0), ("WORLD_SIZE", 1), ("LOCAL_WORLD_SIZE", None)):
        text = env.get(name)
        try:
            values[name] = default if text is None else int(text)
        except ValueError:
            raise ValueError(f"environment variable {name}={text!r} must be an integer (torchrun sets it)") from None
    world, rank = values["WORLD_SIZE"], values["RANK"]
    local = values["LOCAL_WORLD_SIZE"] or world
    if world < 1 or not 0 <= rank < world or not 1 <= local <= world:
        raise ValueError(f"RANK={rank}, WORLD_SIZE={world}, LOCAL_WORLD_SIZE={local} are inconsistent")
    # processes on this machine, bounded like every tool's --workers (17 ranks on 2 cores ran, exit 0)
    check_local_count("LOCAL_WORLD_SIZE (torchrun --nproc-per-node)", local)
    return Ranks(rank, world, local)


@contextmanager
def process_group(ranks: Ranks):
    """The default process group for the job's lifetime (nothing for one process); always destroyed."""
    if not ranks.active:
        yield
        return
    dist.init_process_group(backend="gloo", timeout=GROUP_TIMEOUT)
    try:
        yield
    finally:
        dist.destroy_process_group()


@contextmanager
def stop_when_orphaned(ranks: Ranks, poll_s: float = ORPHAN_POLL_S):
    """Within: a rank whose parent (torchrun) goes away sends itself SIGTERM, so the job stops as on
    torchrun's own stop, rank 0 keeping the best model. torchrun starts each rank in a session of
    its own, and killed outright (kill -9, the OOM killer) it left its ranks training on to the
    end, hours under a cluster's --max-minutes (an outside tester's). On under torchrun only (it sets
    TORCHELASTIC_RUN_ID in every worker, one process of one too); nothing otherwise, where the
    parent may be a shell that ends while the job goes on. A wrapper between torchrun and the
    trainer must exec into it: the parent watched is the trainer's own."""
    if "TORCHELASTIC_RUN_ID" not in os.environ:
        yield
        return
    parent, done = os.getppid(), threading.Event()

    def watch() -> None:
        while not done.wait(poll_s):
            if os.getppid() != parent:
                os.kill(os.getpid(), signal.SIGTERM)  # first: a stderr gone with torchrun must not keep it training
                with contextlib.suppress(OSError):
                    print(f"pinn_train: rank {ranks.rank}: its torchrun (pid {parent}) is gone; stopping as on SIGTERM",
                          file=sys.stderr, flush=True)
                return

    threading.Thread(target=watch, name="torchrun-watch", daemon=True).start()
    try:
        yield
    finally:
        done.set()


def share(n: int, ranks: Ranks) -> slice:
    """This rank's contiguous share of ``n`` items (sizes differ by at most one; all of them for one process)."""
    return slice(n * ranks.rank // ranks.world, n * (ranks.rank + 1) // ranks.world)


def gather(obj, ranks: Ranks) -> list:
    """``obj`` of every rank, in rank order, on every rank (``[obj]`` for one process)."""
    if not ranks.active:
        return [obj]
    out = [None] * ranks.world
    dist.all_gather_object(out, obj)
    return out


def agreed_max(value: int, ranks: Ranks) -> int:
    """The largest of every rank's ``value`` (``value`` for one process): a decision every rank
    takes at the same step."""
    if not ranks.active:
        return value
    t = torch.tensor([value], dtype=torch.int64)
    dist.all_reduce(t, op=dist.ReduceOp.MAX)
    return int(t)
