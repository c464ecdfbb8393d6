"""The GPU check of issue 63, prepared for a machine with CUDA: one SAGE-SAC update (and one SAGE-D3QN update) on one
CPU thread, on the GPU eagerly, and on the GPU replayed as a CUDA graph (``learner.cuda_graph``), at batch 256, 1024
and 4096, side by side with the ratios to the CPU. It first checks that the graph's update agrees with the eager one
on the GPU (same start, same sampled batches, a few updates), then prints the card, the processor and the numbers.

    .venv/bin/python bench/gpu_check.py [--batches 256 1024 4096] [--seconds 3] [--methods sage sage-d3qn]

Targets (issue 63): SAGE-SAC update ≥ 30x one CPU thread at batch 256, ≥ 100x at 1024. Without CUDA it prints one
line and exits 2. Sized for a few minutes on an H200 machine with 16 cores: the CPU's large batches are timed on a
few updates only (``--seconds`` bounds each measurement).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's core, not an installed one

from bench.bench_sac import OBS_DIM, ours
from core.device import cuda_available, device_name, processor_name
from core.learners import make_learner
from core.sage.config import for_method
from core.sage.learner import BaseLearner

N_ACTIONS = 5


def discrete(rng: np.random.Generator, batch: int, device: str, **overrides: object) -> BaseLearner:
    """SAGE-D3QN with the bench's sizes (58 observations, 5 actions), a filled buffer and a fitted world model."""
    cfg = for_method("sage", hidden=128, batch_size=batch, **overrides)
    cfg.method = "sage-d3qn"
    cfg.world_model_config.max_updates_per_fit = 200
    learner = make_learner(
        "sage-d3qn", cfg, OBS_DIM, 1, np.array([0.0]), np.array([N_ACTIONS - 1.0]), seed=0, device=device
    )
    obs = rng.random((20_001, OBS_DIM)).astype(np.float32)
    for i in range(20_000):
        takeover = i % 10 == 0
        action = learner.encode_action(np.array([i % N_ACTIONS], np.float32))
        learner.buffer.add(
            obs[i], action, float(rng.normal()), obs[i + 1], False, cost=float(rng.random()),
            violation=bool(rng.random() < 0.01), takeover=takeover, a_rl=action, a_expert=action if takeover else None,
        )  # fmt: skip
    learner.warm = True
    learner.fit_world_model()
    return learner


def build(method: str, batch: int, device: str, graph: bool = False) -> BaseLearner:
    rng = np.random.default_rng(0)
    extra = {"cuda_graph": True} if graph else {}
    if method == "sage-d3qn":
        return discrete(rng, batch, device, **extra)
    return ours(method, rng, batch=batch, device=device, **extra)


def per_update(fn: Callable[[], object], seconds: float, cuda: bool) -> float:
    """Median seconds per update over rounds of ~``seconds`` / 3 each (at least 2 updates a round)."""
    sync = torch.cuda.synchronize if cuda else (lambda: None)
    fn()
    sync()
    start = time.perf_counter()
    fn()
    sync()
    once = max(time.perf_counter() - start, 1e-6)
    n = max(2, int(seconds / 3 / once))
    times = []
    for _ in range(3):
        sync()
        start = time.perf_counter()
        for _ in range(n):
            fn()
        sync()
        times.append((time.perf_counter() - start) / n)
    return statistics.median(times)


def agreement(method: str, batch: int) -> float:
    """Largest relative gap between the eager and the graph update's statistics over 8 updates from one start (the
    same seed before each: a gap near float32 rounding says the graph computes the eager update; a large one, that
    its inputs or its random draws differ, to be looked into before trusting its timings)."""
    eager, graphed = build(method, batch, "cuda"), build(method, batch, "cuda", graph=True)  # the same start
    worst = 0.0
    for _ in range(8):  # past the warm-up: the last updates replay the captured graph
        torch.manual_seed(1)
        expected = eager.update()
        torch.manual_seed(1)
        got = graphed.update()
        for key, value in expected.items():
            worst = max(worst, abs(got[key] - value) / max(1e-3, abs(value)))
    return worst


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--batches", type=int, nargs="+", default=[256, 1024, 4096])
    parser.add_argument("--seconds", type=float, default=3.0, help="time spent measuring each cell")
    parser.add_argument("--methods", nargs="+", default=["sage", "sage-d3qn"], choices=["sage", "sac", "sage-d3qn"])
    args = parser.parse_args()
    if not cuda_available():
        print(f"gpu_check: no CUDA device (torch {torch.__version__}); nothing to measure here", file=sys.stderr)
        raise SystemExit(2)
    torch.set_num_threads(1)
    cuda = torch.device("cuda")
    print(f"card: {device_name(cuda)}; processor: {processor_name()} (CPU: one thread); torch {torch.__version__}")
    for method in args.methods:
        gap = agreement(method, 256)
        print(f"{method}: graph vs eager on the GPU, largest relative gap of the statistics: {gap:.2e}")
    header = ("cpu ms", "cuda ms", "graph ms", "cuda/cpu", "graph/cpu")
    print(f"{'method':10s} {'batch':>6s} " + " ".join(f"{h:>9s}" for h in header))
    for method in args.methods:
        for batch in args.batches:
            cpu = per_update(build(method, batch, "cpu").update, args.seconds, cuda=False)
            eager = per_update(build(method, batch, "cuda").update, args.seconds, cuda=True)
            graph_learner = build(method, batch, "cuda", graph=True)
            for _ in range(5):  # warm-up and capture
                graph_learner.update()
            graph = per_update(graph_learner.update, args.seconds, cuda=True)
            print(
                f"{method:10s} {batch:6d} {cpu * 1e3:9.2f} {eager * 1e3:9.2f} {graph * 1e3:9.2f} "
                f"{cpu / eager:8.1f}x {cpu / graph:8.1f}x"
            )
    print("targets: SAGE-SAC graph/cpu >= 30x at batch 256, >= 100x at 1024")


if __name__ == "__main__":
    main()
