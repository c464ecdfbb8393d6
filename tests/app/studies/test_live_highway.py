"""The operator's keys on the highway sim: throttle accelerates and 'left' steers to the left of the road."""

from __future__ import annotations

import numpy as np

import sims
from app.input_map import mapping_for, to_action


def drive(throttle: float, steer: float, steps: int = 8) -> tuple[np.ndarray, np.ndarray]:
    env = sims.make("highway", split="test")
    try:
        env.reset(seed=0)
        world = env.unwrapped.world
        start = np.array(world.ego_state)
        action = to_action(mapping_for("highway", env.action_space), env.action_space, throttle, steer)
        for _ in range(steps):
            env.step(action)
        return start, np.array(world.ego_state)
    finally:
        env.close()


def test_throttle_speeds_up_and_brake_slows_down_without_steering() -> None:
    start, end = drive(1.0, 0.0)
    assert end[3] > start[3] + 1.5 and abs(end[1] - start[1]) < 1e-6  # state: x, y, heading, speed
    start, end = drive(-1.0, 0.0)
    assert end[3] < start[3] - 3.0 and abs(end[1] - start[1]) < 1e-6


def test_left_steers_towards_positive_y_which_is_the_drivers_left() -> None:
    start, end = drive(0.0, 1.0)  # steer axis +1 is 'left' (A / left arrow / stick left)
    assert end[1] > start[1] + 0.3 and end[2] > 0.05 and abs(end[3] - start[3]) < 1e-6
    start, end = drive(0.0, -1.0)
    assert end[1] < start[1] - 0.3 and end[2] < -0.05
