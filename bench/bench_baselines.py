"""Action latency of the UGV baselines against the 10 Hz control budget (100 ms per action), one core.

Measured side by side in one run, on the same recorded UGV states (the scripted expert driving scenarios 1-4):
the SAGE actor (the reference), Diffusion-BC at 1, 2, 5 and 10 sampling steps, Diffusion-QL (5 steps, best of 10
candidates by Q) and the TEB planner (which also updates its costmap and global path, so it is timed in closed
loop on its own episodes). Denoiser weights do not change the cost, so the diffusion policies are untrained.

    .venv/bin/python bench/bench_baselines.py [--states 300] [--teb-episodes 2]
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import numpy as np
import torch

import sims
from core.learners import make_learner, preset
from core.sage.learner import ActorPolicy
from core.sage.networks import Actor
from sims.ugv.teb import TebPlanner

BUDGET_MS = 100.0


def states(n: int) -> list[np.ndarray]:
    out: list[np.ndarray] = []
    for scenario in ("1", "2", "3", "4"):
        env = sims.make("ugv", scenario=scenario)
        obs, _ = env.reset(seed=7)
        for _ in range(n // 4):
            out.append(obs)
            obs, _, terminated, truncated, _ = env.step(env.unwrapped.expert_action())
            if terminated or truncated:
                obs, _ = env.reset()
    return out


def timed(act: Callable[[np.ndarray], object], observations: list[np.ndarray]) -> list[float]:
    times = []
    for obs in observations:
        start = time.perf_counter()
        act(obs)
        times.append(1e3 * (time.perf_counter() - start))
    return times


def teb_times(episodes: int) -> list[float]:
    times: list[float] = []
    for scenario in ("1", "2", "3", "4"):
        env = sims.make("ugv", scenario=scenario)
        planner = TebPlanner(env)
        for seed in range(episodes):
            obs, _ = env.reset(seed=seed)
            while True:
                start = time.perf_counter()
                action = planner.act(obs)
                times.append(1e3 * (time.perf_counter() - start))
                obs, _, terminated, truncated, _ = env.step(action)
                if terminated or truncated:
                    break
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--states", type=int, default=300)
    parser.add_argument("--teb-episodes", type=int, default=2)
    args = parser.parse_args()
    torch.set_num_threads(1)
    observations = states(args.states)
    low, high = -np.ones(2), np.ones(2)
    cfg = preset("sage")
    actor = ActorPolicy(Actor(58, 2, cfg.hidden, cfg.layers, torch.as_tensor(low), torch.as_tensor(high)))
    policies: dict[str, Callable[[np.ndarray], object]] = {"SAGE actor (reference)": lambda o: actor.act(o, True)}
    for steps in (1, 2, 5, 10):
        bc = make_learner(
            "diffusion-bc", preset("diffusion-bc", **{"diffusion.sampling_steps": steps}), 58, 2, low, high
        )
        policies[f"Diffusion-BC, {steps} sampling steps"] = lambda o, bc=bc: bc.act(o, True)
    ql = make_learner("diffusion-ql", preset("diffusion-ql"), 58, 2, low, high)
    policies["Diffusion-QL, 5 steps, best of 10"] = lambda o: ql.act(o, True)
    results: dict[str, list[float]] = {name: [] for name in policies}
    for _ in range(3):  # interleaved rounds, so a busy moment hits every policy alike
        for name, act in policies.items():
            results[name] += timed(act, observations)
    results["TEB planner (closed loop)"] = teb_times(args.teb_episodes)
    reference = statistics.median(results["SAGE actor (reference)"])
    print(f"| policy | median ms | p95 ms | max ms | × SAGE actor | within {BUDGET_MS:.0f} ms |")
    print("|---|---|---|---|---|---|")
    for name, times in results.items():
        median, p95 = statistics.median(times), float(np.percentile(times, 95))
        ok = "yes" if max(times) < BUDGET_MS else f"no ({np.mean(np.array(times) >= BUDGET_MS):.1%} over)"
        print(f"| {name} | {median:.2f} | {p95:.2f} | {max(times):.1f} | {median / reference:.0f}× | {ok} |")


if __name__ == "__main__":
    main()
