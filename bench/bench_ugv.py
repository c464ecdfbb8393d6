"""UGV env throughput on one core: numpy lidar vs a lidar built on pymunk segment queries.

    python bench/bench_ugv.py [--steps 20000] [--scenario 3]

Steps the env built by ``sims.make("ugv", ...)`` (gymnasium wrappers included) with seeded random
actions, resetting when episodes end, and prints steps/s for both lidar backends measured in the
same run, their ratio, and the scripted expert's rate for reference. Target: >= 10,000 steps/s.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

import sims

TARGET = 10_000


def steps_per_second(scenario: int, steps: int, backend: str, expert: bool = False, repeats: int = 3) -> float:
    """Best of ``repeats`` timed runs (the machine is shared; the best run is the least disturbed)."""
    env = sims.make("ugv", scenario=scenario, **{"lidar.backend": backend})
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (steps, 2)).astype(np.float32)
    unwrapped = env.unwrapped
    best = 0.0
    for repeat in range(repeats):
        env.reset(seed=repeat)
        start = time.perf_counter()
        for i in range(steps):
            action = unwrapped.expert_action() if expert else actions[i]
            _, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                env.reset()
        elapsed = time.perf_counter() - start
        best = max(best, steps / elapsed)
    env.close()
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=20_000)
    parser.add_argument("--scenario", type=int, default=3)
    args = parser.parse_args()
    with contextlib.suppress(AttributeError, OSError):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})  # one core

    print(f"UGV env, scenario {args.scenario}, {args.steps} steps per run, random actions, one core")
    rows = []
    for backend in ("numpy", "pymunk"):
        steps = args.steps if backend == "numpy" else max(1000, args.steps // 4)
        rate = steps_per_second(args.scenario, steps, backend)
        rows.append((backend, rate))
        print(f"  lidar={backend:<7} {rate:>9,.0f} steps/s  ({1e6 / rate:6.1f} µs/step)")
    numpy_rate, pymunk_rate = rows[0][1], rows[1][1]
    print(f"  speed-up of the numpy lidar env over the pymunk-query lidar env: {numpy_rate / pymunk_rate:.2f}x")
    print(f"  target >= {TARGET:,} steps/s: {'met' if numpy_rate >= TARGET else 'NOT met'}")
    for scenario in (1, 2, 3, 4):
        rate = steps_per_second(scenario, 3000, "numpy", expert=True, repeats=1)
        print(f"  scenario {scenario}, scripted expert actions (planner included): {rate:>7,.0f} steps/s")


if __name__ == "__main__":
    main()
