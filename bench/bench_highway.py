"""sage/Highway-v0 against highway-env's highway-v0 at its defaults, at equal traffic, in the same run.

    python bench/bench_highway.py [--steps 3000] [--stock-steps 20] [--evaluate 0]

highway-v0 at its defaults drives 50 vehicles (plus the ego) with highway-env's IDM/MOBIL models,
15 simulation steps per 1 Hz decision. sage/Highway-v0 replays a 50-vehicle logged scenario (plus the
ego) at 10 Hz: numpy replay, 72-beam LiDAR, collision and interaction statistics every step. Printed:
steps/s of both and their ratio (target: >= 5x), the same in simulated seconds per second (one
highway-v0 step is 1 s of driving, one of ours 0.1 s), highway-v0 with ``compat.FAST_CONFIG`` for
reference, the scripted expert's rate, and the one-off costs (recording a log, an adversarial reset).

Rates are per second of the process's own CPU time (pinned to one core), next to wall-clock rates: on
a machine shared with other jobs the wall clock also counts time spent waiting for the CPU.

``--evaluate N`` also runs the scripted expert and a constant-speed lane keeper on the first N test
scenarios, in log replay and adversarial mode, and prints the paper's table with interaction stats.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import time
from collections.abc import Callable
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import gymnasium as gym
import numpy as np
from highway_env.envs.common.abstract import AbstractEnv

import sims
from core.protocol import simulator
from sims.highway.compat import make_stock
from sims.highway.env import HighwayEnv
from sims.highway.road import RoadLayout, make_road
from sims.highway.scenarios import ScenarioSpec, custom_spec, load_log, spawn_traffic

TARGET = 5.0
VEHICLES = 50


def equal_traffic_spec(vehicles: int = VEHICLES) -> ScenarioSpec:
    """A 4-lane highway scenario whose log holds exactly ``vehicles`` surrounding vehicles."""
    layout = RoadLayout(kind="highway", lanes=4, speed_limit=30.0)
    for seed in range(200):
        for spacing in np.arange(20.0, 30.0, 0.5):
            spec = custom_spec(layout, spacing=float(spacing), ego_lane=1, seed=seed)
            rng = np.random.default_rng(spec.seed)
            _, others, _ = spawn_traffic(spec, make_road(layout, rng), rng)
            if len(others) == vehicles:
                return spec
    raise RuntimeError(f"no spacing gives {vehicles} vehicles")


def timed(fn: Callable[[], int]) -> tuple[float, float, int]:
    """(CPU seconds, wall seconds, steps) of ``fn``, which returns how many steps it ran."""
    cpu0, wall0 = time.process_time(), time.perf_counter()
    steps = fn()
    return time.process_time() - cpu0, time.perf_counter() - wall0, steps


def stock_rate(steps: int, fast: bool) -> tuple[float, float, int]:
    env = make_stock("highway-v0", fast=fast) if fast else gym.make("highway-v0")
    stock = env.unwrapped
    assert isinstance(stock, AbstractEnv)  # a highway-env environment: its config holds the traffic
    vehicles = int(stock.config["vehicles_count"])
    idle = 1  # DiscreteMetaAction IDLE

    def run() -> int:
        env.reset(seed=0)
        for _ in range(steps):
            _, _, terminated, truncated, _ = env.step(idle)
            if terminated or truncated:
                env.reset()
        return steps

    cpu, wall, n = timed(run)
    env.close()
    return n / cpu, n / wall, vehicles


def sage_rate(spec: ScenarioSpec, steps: int, expert: bool, repeats: int = 3) -> tuple[float, float]:
    env = sims.make("highway", custom_spec=spec)
    inner = simulator(env)
    keep_lane = np.array([0.0, 0.0], np.float32)
    best_cpu = best_wall = 0.0
    for repeat in range(repeats):

        def run(repeat: int = repeat) -> int:
            env.reset(seed=repeat)
            for _ in range(steps):
                action = inner.expert_action() if expert else keep_lane
                _, _, terminated, truncated, _ = env.step(action)
                if terminated or truncated:
                    env.reset()
            return steps

        cpu, wall, n = timed(run)
        best_cpu, best_wall = max(best_cpu, n / cpu), max(best_wall, n / wall)
    env.close()
    return best_cpu, best_wall


def evaluate_table(episodes: int) -> None:
    from studies.highway import interaction_table, paper_table
    from studies.highway_evaluate import evaluate

    class LaneKeeper:
        def act(self, obs: np.ndarray, deterministic: bool = False) -> np.ndarray:
            return np.array([np.clip(3.0 * obs[6] - 2.0 * obs[1], -1.0, 1.0), 0.0], np.float32)

    results: dict[str, dict[tuple[str, str], list[dict[str, Any]]]] = {}
    for name, policy in (("expert", "expert"), ("lane keeper", LaneKeeper())):
        for mode in ("normal", "adversarial"):
            start = time.perf_counter()
            rows = evaluate(policy, "test", mode, episodes=episodes)  # type: ignore[arg-type]
            results.setdefault(name, {})[("test", mode)] = rows
            print(f"  evaluated {name} / {mode}: {episodes} episodes in {time.perf_counter() - start:.0f} s")
    print(paper_table(results))
    print(interaction_table(results))
    rows = results["expert"][("test", "adversarial")]
    reference = evaluate("expert", "test", "adversarial", episodes=episodes, predictor="reference")
    print(
        f"expert, adversaries aimed at itself: {sum(r['collision'] for r in rows):.0f}/{len(rows)} collisions; "
        f"aimed at the log's IDM reference driver: {sum(r['collision'] for r in reference):.0f}/{len(reference)}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument("--stock-steps", type=int, default=20)
    parser.add_argument("--evaluate", type=int, default=0, help="also evaluate on the first N test scenarios")
    args = parser.parse_args()
    with contextlib.suppress(AttributeError, OSError):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})  # one core

    spec = equal_traffic_spec()
    cpu, _, _ = timed(lambda: load_log(spec, cache=False).frames)
    log = load_log(spec)
    print(
        f"logged scenario: {log.vehicles} vehicles, {log.frames} frames at {log.dt} s; recording took {cpu:.1f} s CPU"
    )

    stock_cpu, stock_wall, stock_vehicles = stock_rate(args.stock_steps, fast=False)
    fast_cpu, fast_wall, fast_vehicles = stock_rate(args.stock_steps * 5, fast=True)
    ours_cpu, ours_wall = sage_rate(spec, args.steps, expert=False)
    expert_cpu, expert_wall = sage_rate(spec, max(args.steps // 3, 100), expert=True, repeats=1)

    env = sims.make("highway", custom_spec=spec, mode="adversarial")
    env.reset(seed=0)
    cpu_adv, wall_adv, _ = timed(lambda: len(env.reset(seed=1)[1]["adversary_events"]))
    adversarial = env.unwrapped
    assert isinstance(adversarial, HighwayEnv)
    adversarial.set_ego_predictor("expert")
    cpu_adv_expert, _, _ = timed(lambda: len(env.reset(seed=1)[1]["adversary_events"]))

    rows = [
        (f"highway-v0 defaults ({stock_vehicles} vehicles)", stock_cpu, stock_wall, 1.0),
        (f"highway-v0 FAST_CONFIG ({fast_vehicles} veh.)", fast_cpu, fast_wall, 0.2),
        (f"sage/Highway-v0 ({log.vehicles} vehicles)", ours_cpu, ours_wall, 0.1),
        ("  + scripted expert every step", expert_cpu, expert_wall, 0.1),
    ]
    print(f"{'':36s}{'steps/s (CPU)':>15s}{'steps/s (wall)':>16s}{'sim s / s':>11s}")
    for name, rate_cpu, rate_wall, step_seconds in rows:
        print(f"{name:36s}{rate_cpu:15.1f}{rate_wall:16.1f}{rate_cpu * step_seconds:11.1f}")
    ratio, sim_ratio = ours_cpu / stock_cpu, ours_cpu * 0.1 / stock_cpu
    verdict = "meets" if ratio >= TARGET else "MISSES"
    print(f"ratio at equal traffic: {ratio:.0f}x steps/s, {sim_ratio:.0f}x simulated time", end=" ")
    print(f"({verdict} the {TARGET:.0f}x target)")
    print(f"adversarial reset (CAT resampling, IDM reference prediction): {cpu_adv * 1e3:.0f} ms CPU", end=" ")
    print(f"({wall_adv * 1e3:.0f} ms wall)")
    print(f"adversarial reset with the expert rolled as the ego predictor: {cpu_adv_expert * 1e3:.0f} ms CPU")
    if args.evaluate:
        evaluate_table(args.evaluate)


if __name__ == "__main__":
    main()
