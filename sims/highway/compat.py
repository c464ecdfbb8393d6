"""highway-env's own environments, configured to run at a usable speed and with continuous actions
on every map: the one place where the two measured problems of highway-env 1.12 are handled.

1. Speed. ``highway-v0`` at its defaults steps at ~3 steps/s here: 50 vehicles whose neighbour search
   is quadratic in their number, 15 simulation steps per 1 Hz decision. ``FAST_CONFIG`` is what keeps
   it usable (fewer vehicles, 5 Hz decisions, 10 Hz simulation); sage/Highway-v0 itself avoids the
   problem by replaying traffic from arrays (traffic.py) and only logs with highway-env's vehicles,
   with a vectorised neighbour search (road.FastRoad).
2. Continuous actions. ``MergeEnv._rewards`` and ``RoundaboutEnv._rewards`` (and their ``-generic``
   and connected-lane variants) test ``action in [0, 2]`` for a lane-change penalty, which raises
   "truth value of an array is ambiguous" for a ``ContinuousAction`` array. The penalty means nothing
   for a continuous action, so those reward terms are given no action (``None in [0, 2]`` is False).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import highway_env  # noqa: F401 - registers highway-env's environments
import numpy as np
from highway_env.envs.merge_env import MergeEnv
from highway_env.envs.roundabout_env import RoundaboutEnv

FAST_CONFIG: dict[str, Any] = {
    "vehicles_count": 20,
    "policy_frequency": 5,
    "simulation_frequency": 10,
}
"""Applied where the env has the key (merge and roundabout have no ``vehicles_count``)."""
CONTINUOUS_ACTION: dict[str, Any] = {"type": "ContinuousAction", "longitudinal": True, "lateral": True}
DISCRETE_LANE_CHANGE_REWARDS = (MergeEnv, RoundaboutEnv)
"""Envs whose reward reads the action as a discrete meta-action index."""


def fix_continuous_rewards(env: gym.Env[Any, Any]) -> gym.Env[Any, Any]:
    """Make a merge/roundabout env's reward accept array actions (a no-op for other envs)."""
    inner = env.unwrapped
    if not isinstance(inner, DISCRETE_LANE_CHANGE_REWARDS) or getattr(inner, "_sage_reward_fix", False):
        return env
    discrete_rewards = inner._rewards

    def rewards(action: Any) -> dict[str, float]:
        return discrete_rewards(None if isinstance(action, np.ndarray | list | tuple) else action)

    inner._rewards = rewards
    inner._sage_reward_fix = True
    return env


def make_stock(env_id: str, *, continuous: bool = False, fast: bool = True, **config: Any) -> gym.Env[Any, Any]:
    """``gym.make(env_id)`` for a highway-env id with ``FAST_CONFIG`` (if ``fast``), a continuous
    [steer, acc] action (if ``continuous``) that works on every map, and ``config`` on top."""
    if env_id not in gym.registry:
        raise ValueError(f"{env_id!r} is not a registered highway-env environment")
    env = gym.make(env_id)
    defaults = env.unwrapped.config  # type: ignore[attr-defined]
    overrides: dict[str, Any] = {}
    if fast:
        overrides.update({k: v for k, v in FAST_CONFIG.items() if k in defaults})
    if continuous:
        overrides["action"] = dict(CONTINUOUS_ACTION)
    unknown = sorted(set(config) - set(defaults))
    if unknown:
        raise ValueError(f"unknown config key(s) for {env_id}: {', '.join(unknown)}")
    overrides.update(config)
    env.unwrapped.configure(overrides)  # type: ignore[attr-defined]
    if continuous:
        fix_continuous_rewards(env)
    return env
