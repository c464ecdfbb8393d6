"""Experts behind the :class:`core.loop.Expert` protocol that need no web or simulator imports.

A person at the dashboard is another implementation, in ``app``.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from core.loop import Actor, Policy
from core.protocol import simulator


class ScriptedExpert:
    """The simulator's own scripted controller (``env.unwrapped.expert_action()``)."""

    def reset(self) -> None:
        pass

    def wants_control(self) -> bool:
        return False

    def act(self, env: gym.Env[Any, Any], obs: np.ndarray) -> tuple[np.ndarray, Actor]:
        return np.asarray(simulator(env).expert_action()), "expert"


class PolicyExpert:
    """A separately trained policy serving as the expert, as in the paper's driving studies."""

    def __init__(self, policy: Policy) -> None:
        self.policy = policy

    def reset(self) -> None:
        pass

    def wants_control(self) -> bool:
        return False

    def act(self, env: gym.Env[Any, Any], obs: np.ndarray) -> tuple[np.ndarray, Actor]:
        return np.asarray(self.policy.act(obs, deterministic=True)), "expert"


class ExpertPolicy:
    """The scripted expert seen as a policy (to run the expert alone, or collect demonstrations)."""

    def __init__(self, env: gym.Env[Any, Any]) -> None:
        self.env = env

    def act(self, obs: np.ndarray, deterministic: bool = False) -> np.ndarray:
        return np.asarray(simulator(self.env).expert_action())
