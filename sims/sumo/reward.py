"""The SUMO study's reward (the paper's, read literally; the reading is argued in :mod:`sims.sumo.env`)."""

from __future__ import annotations

import math

from sims.sumo.config import SumoConfig


def step_reward(
    cfg: SumoConfig,
    *,
    speed: float,
    arrived: bool,
    remaining: float,
    route_length: float,
    collision: bool,
    red_light: bool,
) -> float:
    """``v / divisor + r_goal - c_col - c_red``; before the goal ``r_goal`` is ``-log(1 + d / d_max) - 1``."""
    reward = speed / cfg.speed_reward_divisor
    if arrived:
        reward += cfg.goal_reward
    else:
        reward += -math.log1p(remaining / route_length) - 1.0
    reward -= cfg.collision_penalty * float(collision) + cfg.red_light_penalty * float(red_light)
    return float(reward)
