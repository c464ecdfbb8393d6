"""UGV env throughput on one core: numpy lidar vs a lidar built on pymunk segment queries.

    python bench/bench_ugv.py [--steps 20000] [--scenario 3]

Steps the env built by ``sims.make("ugv", ...)`` (gymnasium wrappers included) with seeded random
actions, resetting when episodes end, and prints steps/s for both lidar backends measured in the
same run, their ratio, and the scripted expert's rate for reference. Target: >= 10,000 steps/s.

Rates are steps per second of the process's own CPU time (one core, pinned), next to wall-clock
rates: on a machine shared with other jobs the wall clock also counts time spent waiting for the CPU.
Each figure is the best of a few runs.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import time
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

import sims
from core.protocol import simulator

TARGET = 10_000


def steps_per_second(
    scenario: int, steps: int, backend: str, expert: bool = False, repeats: int = 3
) -> tuple[float, float]:
    """(CPU-time rate, wall-clock rate), each the best of ``repeats`` runs."""
    overrides: dict[str, Any] = {"lidar.backend": backend}  # a dotted key: no keyword argument spells it
    env = sims.make("ugv", scenario=scenario, **overrides)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (steps, 2)).astype(np.float32)
    unwrapped = simulator(env)
    best_cpu = best_wall = 0.0
    for repeat in range(repeats):
        env.reset(seed=repeat)
        start_cpu, start_wall = time.process_time(), time.perf_counter()
        for i in range(steps):
            action = unwrapped.expert_action() if expert else actions[i]
            _, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                env.reset()
        cpu, wall = time.process_time() - start_cpu, time.perf_counter() - start_wall
        best_cpu, best_wall = max(best_cpu, steps / cpu), max(best_wall, steps / wall)
    env.close()
    return best_cpu, best_wall


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=20_000)
    parser.add_argument("--scenario", type=int, default=3)
    args = parser.parse_args()
    with contextlib.suppress(AttributeError, OSError):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})  # one core

    print(f"UGV env, scenario {args.scenario}, {args.steps} steps per run, random actions, one core")
    print(f"  load average now: {', '.join(f'{x:.1f}' for x in os.getloadavg())}")
    rates = {}
    for backend in ("numpy", "pymunk"):
        steps = args.steps if backend == "numpy" else max(1000, args.steps // 4)
        cpu, wall = rates[backend] = steps_per_second(args.scenario, steps, backend)
        print(
            f"  lidar={backend:<7} {cpu:>9,.0f} steps/s CPU time ({1e6 / cpu:6.1f} µs/step), {wall:>9,.0f} wall clock"
        )
    ratio, wall_ratio = (rates["numpy"][i] / rates["pymunk"][i] for i in (0, 1))
    print(f"  numpy lidar env / pymunk-query lidar env: {ratio:.2f}x (wall clock {wall_ratio:.2f}x)")
    print(f"  target >= {TARGET:,} steps/s: {'met' if rates['numpy'][0] >= TARGET else 'NOT met'}")
    for scenario in (1, 2, 3, 4):
        cpu, _ = steps_per_second(scenario, 3000, "numpy", expert=True, repeats=1)
        print(f"  scenario {scenario}, scripted expert actions (planning included): {cpu:>7,.0f} steps/s CPU time")


if __name__ == "__main__":
    main()
