"""Training and inference figures for the PINN on this CPU (prints, never asserts).

* Training throughput (windows/s) of the PINN and of the physics-free network, measured side
  by side in one run on the same synthetic batches, and the implied epoch time for the
  D_default-like dataset at the shipped stride.
* Model step latency at batch 1 (p50/p99), what the online node pays per estimate.
* The wall time each shipped checkpoint actually took to train (recorded by pinn_train),
  against the issue's 15-minute budget.

Usage: .venv/bin/python benchmarks/bench_train.py
"""
from __future__ import annotations

import time

import numpy as np
import torch

from pinn_estimator.checkpoint import read_checkpoint
from pinn_estimator.loss import force_loss, pinn_loss
from pinn_estimator.model import EstimatorNet, ModelConfig, parameter_count
from pinn_estimator.shipped import MODELS_DIR
from soil_msgs_py.params import KNOWN_PARAMS

WINDOWS_PER_EPOCH_DEFAULT = 402 * (600 - 59) // 4  # ~70 % of 576 episodes, stride 4


def _batch(b: int):
    g = torch.Generator().manual_seed(0)
    obs = torch.randn(b, 60, 9, generator=g)
    known = torch.tensor([200.0, 18e3, np.radians(80), 0.0, 3.164, 0.15, 1e3, 0.5, 0.0]).repeat(b, 1)
    known[:, KNOWN_PARAMS.index("d")] = torch.rand(b, generator=g) * 0.3
    force = torch.stack([torch.rand(b, generator=g) * 2e4, torch.randn(b, generator=g) * 3e3], 1)
    return obs, known, force


def throughput(kind: str, steps: int = 30, b: int = 512) -> float:
    torch.manual_seed(0)
    model = EstimatorNet(ModelConfig(kind=kind), np.zeros(9), np.ones(9))
    opt = torch.optim.Adam(model.parameters(), 1e-3)
    obs, known, force = _batch(b)
    loss_fn = (lambda o: pinn_loss(o, force, known)[0]) if kind == "pinn" else (lambda o: force_loss(o, force)[0])
    for i in range(steps + 5):
        if i == 5:
            t0 = time.perf_counter()
        loss = loss_fn(model(obs, known))
        opt.zero_grad()
        loss.backward()
        opt.step()
    return steps * b / (time.perf_counter() - t0)


def latency(n: int = 500) -> tuple[float, float]:
    model = EstimatorNet(ModelConfig(), np.zeros(9), np.ones(9)).eval()
    obs, known, _ = _batch(1)
    times = []
    with torch.inference_mode():
        for _ in range(n + 20):
            t0 = time.perf_counter()
            model(obs, known)
            times.append(time.perf_counter() - t0)
    t = np.array(times[20:]) * 1e3
    return float(np.percentile(t, 50)), float(np.percentile(t, 99))


def main() -> None:
    torch.set_num_threads(2)
    print(f"parameters: PINN {parameter_count(EstimatorNet(ModelConfig(), np.zeros(9), np.ones(9)))}, "
          f"physics-free {parameter_count(EstimatorNet(ModelConfig(kind='physics_free'), np.zeros(9), np.ones(9)))}")
    rates = {kind: throughput(kind) for kind in ("pinn", "physics_free")}
    for kind, r in rates.items():
        print(f"training throughput {kind:13s}: {r:8.0f} windows/s  -> {WINDOWS_PER_EPOCH_DEFAULT / r:5.1f} s per D_default epoch (stride 4)")
    print(f"PINN / physics-free time per step: {rates['physics_free'] / rates['pinn']:.2f}x")
    torch.set_num_threads(1)
    p50, p99 = latency()
    print(f"model step latency, batch 1, 1 thread: p50 {p50:.2f} ms, p99 {p99:.2f} ms")
    for path in sorted(MODELS_DIR.glob("*.pt")):
        m = read_checkpoint(path)["metrics"]
        print(f"shipped {path.name}: trained in {m['train_seconds'] / 60:.1f} min ({m['epochs_run']} epochs; stop: {m['stop_reason']}); budget 15 min")


if __name__ == "__main__":
    import argparse

    # no options: --help prints what the benchmark measures instead of starting its run
    argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter).parse_args()
    main()
