"""SUMO study speed: raw libsumo steps vs env steps (in-process and process-backed), and event-loop blocking.

    python bench/bench_sumo.py [--steps 2000]

Measured side by side in one run:
  raw        libsumo.simulationStep() on the study's network and traffic (no ego, no Python per step)
  in-process SumoEnv.step (ego control, collision/red-light checks, 29-value observation)
  expert     SumoEnv.expert_action() + step (SUMO drives the ego, the action label is predicted)
  process    SumoProcessEnv.step (the same env in a spawned worker, one pipe round trip per step)
  loop lag   how late a 1 ms asyncio timer fires while another thread steps the env: in-process libsumo holds
             the GIL during simulationStep, the process-backed env waits on a pipe without it
"""

from __future__ import annotations

import argparse
import asyncio
import threading
import time
from typing import Any

import numpy as np

from sims.sumo import SumoEnv, engine
from sims.sumo.env import SumoConfig
from sims.sumo.process import SumoProcessEnv


def raw_steps_per_second(route: int, special: bool, steps: int) -> tuple[float, float]:
    """(simulation steps/s, mean vehicle count) of plain libsumo on a scenario's network and flows."""
    cfg = SumoConfig(route=route, special_vehicles=special)
    owner = object()
    args = SumoEnv(cfg).sumo_args(seed=1)
    engine.start(owner, args)
    try:
        lib = engine.libsumo
        for _ in range(240):  # let traffic fill the roads (120 s)
            lib.simulationStep()
        counts = []
        t0 = time.perf_counter()
        for k in range(steps):
            lib.simulationStep()
            if k % 50 == 0:
                counts.append(lib.vehicle.getIDCount())
        elapsed = time.perf_counter() - t0
    finally:
        engine.close(owner)
    return steps / elapsed, float(np.mean(counts))


def _hold_speed(obs: np.ndarray, target: float = 12.0) -> np.ndarray:
    speed = float(obs[24]) * 30.0
    return np.array([np.clip((target - speed) / 3.0, -1.0, 1.0)], np.float32)


def env_steps_per_second(env: Any, steps: int, expert: bool = False) -> float:
    """Env steps/s over ``steps`` steps, resets excluded (a new episode starts whenever one ends)."""
    obs, _ = env.reset(seed=0)
    done_steps, elapsed, seed = 0, 0.0, 0
    while done_steps < steps:
        t0 = time.perf_counter()
        action = env.expert_action() if expert else _hold_speed(obs)
        obs, _, terminated, truncated, _ = env.step(action)
        elapsed += time.perf_counter() - t0
        done_steps += 1
        if terminated or truncated:
            seed += 1
            obs, _ = env.reset(seed=seed)
    return steps / elapsed


def loop_lag_while_stepping(env: Any, seconds: float = 2.0) -> tuple[float, float]:
    """(p99, max) lateness in ms of a 1 ms asyncio timer while a background thread steps ``env``."""
    env.reset(seed=0)
    stop = threading.Event()

    def drive() -> None:
        obs, _ = env.reset(seed=0)
        seed = 0
        while not stop.is_set():
            obs, _, terminated, truncated, _ = env.step(_hold_speed(obs))
            if terminated or truncated:
                seed += 1
                obs, _ = env.reset(seed=seed)

    async def ticker() -> list[float]:
        lags = []
        end = time.perf_counter() + seconds
        while time.perf_counter() < end:
            t0 = time.perf_counter()
            await asyncio.sleep(0.001)
            lags.append((time.perf_counter() - t0 - 0.001) * 1e3)
        return lags

    worker = threading.Thread(target=drive, daemon=True)
    worker.start()
    try:
        lags = asyncio.run(ticker())
    finally:
        stop.set()
        worker.join(10.0)
    return float(np.percentile(lags, 99)), float(np.max(lags))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=2000, help="steps per measurement")
    args = parser.parse_args()
    n = args.steps

    print(f"SUMO study benchmark, {n} steps per measurement (step length 0.5 s)\n")
    raw1, veh1 = raw_steps_per_second(1, False, n)
    raw2, veh2 = raw_steps_per_second(2, True, n)
    print(f"raw libsumo simulationStep   route 1 (C1): {raw1:8.0f} steps/s  ({veh1:.0f} vehicles)")
    print(f"raw libsumo simulationStep   route 2 (C2): {raw2:8.0f} steps/s  ({veh2:.0f} vehicles)")

    env = SumoEnv(route=1)
    try:
        agent = env_steps_per_second(env, n)
        expert = env_steps_per_second(env, n, expert=True)
        t0 = time.perf_counter()
        for seed in range(5):
            env.reset(seed=seed)
        reset_ms = (time.perf_counter() - t0) / 5 * 1e3
        lag_in = loop_lag_while_stepping(env)
    finally:
        env.close()
    proc = SumoProcessEnv(route=1)
    try:
        t0 = time.perf_counter()
        proc.reset(seed=0)
        spawn_s = time.perf_counter() - t0
        process = env_steps_per_second(proc, n)
        lag_proc = loop_lag_while_stepping(proc)
    finally:
        proc.close()

    rows = [
        ("in-process SumoEnv.step       route 1 (C1)", agent),
        ("in-process expert_action+step route 1 (C1)", expert),
        ("process-backed step           route 1 (C1)", process),
    ]
    for name, rate in rows:
        print(f"{name}: {rate:8.0f} steps/s  ({1e6 / rate:6.0f} us/step)")
    print(f"reset (start SUMO, 60 s warm-up, ego enters): {reset_ms:.1f} ms")
    print(f"first process-backed reset, spawn included  : {spawn_s:.2f} s")
    print()
    python_us = 1e6 / agent - 1e6 / raw1
    pipe_us = 1e6 / process - 1e6 / agent
    print(f"ratio in-process env / raw sim     : {agent / raw1:5.2f}  (Python per step {python_us:.0f} us)")
    print(f"ratio process env / in-process env : {process / agent:5.2f}  (pipe per step {pipe_us:.0f} us)")
    print(f"ratio expert step / agent step     : {expert / agent:5.2f}")
    print("1 ms asyncio timer lateness while another thread steps the env:")
    print(f"  in-process     p99 {lag_in[0]:6.2f} ms  max {lag_in[1]:6.2f} ms")
    print(f"  process-backed p99 {lag_proc[0]:6.2f} ms  max {lag_proc[1]:6.2f} ms")
    episode_steps = 360
    print(f"a {episode_steps}-step expert episode: about {episode_steps / expert + reset_ms / 1e3:.2f} s of wall time")


if __name__ == "__main__":
    main()
