"""Steps per second of ``sage/Pedestrian-v0`` under the scripted expert (the numpy lidar is most of a step).

PYTHONPATH=. python bench/bench_pedestrian.py [episodes]
"""

from __future__ import annotations

import sys
import time

from sims.pedestrian.env import PedestrianEnv


def main(episodes: int = 100) -> None:
    env = PedestrianEnv()
    steps, collisions, start = 0, 0, time.perf_counter()
    for seed in range(episodes):
        env.reset(seed=seed)
        done = False
        while not done:
            _, _, terminated, truncated, info = env.step(env.expert_action())
            steps += 1
            done = terminated or truncated
        collisions += int(info["collision"])
    elapsed = time.perf_counter() - start
    print(f"{episodes} episodes, {steps} steps, {steps / elapsed:.0f} steps/s, expert collisions {collisions}")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 100)
