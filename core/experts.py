"""Experts behind the :class:`core.loop.Expert` protocol that need no web or simulator imports.

A person at the dashboard is another implementation, in ``app``.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from core.protocol import Actor, Expert, Policy, StepRecord, expert_engaged, simulator


class ScriptedExpert:
    """The simulator's own scripted controller (``env.unwrapped.expert_action()``).

    Once it has the wheel it keeps it while the simulator says it is engaged in a manoeuvre
    (:func:`core.protocol.expert_engaged`, e.g. the UGV evading a mover), as a person keeps holding the takeover
    key: a gate that releases on schedule would otherwise hand a half-finished evasion to the policy.
    ``finish_manoeuvres=False`` hands back whenever the gate releases."""

    def __init__(self, finish_manoeuvres: bool = True) -> None:
        self.finish_manoeuvres = finish_manoeuvres
        self._engaged = False

    def reset(self) -> None:
        self._engaged = False

    def wants_control(self) -> bool:
        # refreshed at every act(), and a True here always leads to one, so it never outlives the manoeuvre
        return self._engaged

    def act(self, env: gym.Env[Any, Any], obs: np.ndarray) -> tuple[np.ndarray, Actor]:
        action = np.asarray(simulator(env).expert_action())
        self._engaged = self.finish_manoeuvres and expert_engaged(env)
        return action, "expert"


class CoachingExpert:
    """An expert that also coaches (:class:`core.protocol.Coach`): on each step the agent drives, with probability
    ``share``, the simulator's scripted expert gives its action at that state as a label, recorded and imitated by
    the fine-tuning rounds, never executed: the headless stand-in for a person steering along at the dashboard
    part of the time. Takeovers are the wrapped expert's, unchanged.

    Why: takeovers label only the states after the gate fired, none of the approach the agent chose itself; coaching
    labels some of those too (DAgger's coverage). Measured on the crossing at a quarter of the steps it did not lift
    the versions alone and raised their takeover (docs/notes/forgetting_anatomy.md, arm C). Its own random stream
    (``seed``): the rest of the loop draws what it drew without a coach."""

    def __init__(self, expert: Expert, share: float, seed: int = 0) -> None:
        if not 0.0 <= share <= 1.0:
            raise ValueError(f"coaching share must be in [0, 1], got {share}")
        self.expert, self.share = expert, float(share)
        self.rng = np.random.default_rng(seed)

    def reset(self) -> None:
        self.expert.reset()

    def wants_control(self) -> bool:
        return self.expert.wants_control()

    def act(self, env: gym.Env[Any, Any], obs: np.ndarray) -> tuple[np.ndarray, Actor]:
        return self.expert.act(env, obs)

    def coach(self, env: gym.Env[Any, Any], obs: np.ndarray) -> np.ndarray | None:
        if self.share <= 0.0 or self.rng.random() >= self.share:
            return None
        return np.asarray(simulator(env).expert_action())


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


class CostSupervisor:
    """A supervisor who steps in on their own judgement (human-guided RL), headless: ``expert`` takes over for
    ``hold_steps`` steps whenever a step's safety cost reaches ``threshold`` or a violation happens.

    Attach :meth:`observe` to the runner's step listeners; :meth:`wants_control` then says whether it holds the
    wheel for the next step. Stands in for the person, who at the dashboard takes over whenever they choose."""

    def __init__(self, expert: Expert, threshold: float, hold_steps: int) -> None:
        if hold_steps < 1:
            raise ValueError(f"hold_steps must be >= 1, got {hold_steps}")
        self.expert, self.threshold, self.hold_steps = expert, threshold, hold_steps
        self._hold = 0

    def reset(self) -> None:
        self._hold = 0
        self.expert.reset()

    def observe(self, record: StepRecord) -> None:
        if record.violation or record.cost >= self.threshold:
            self._hold = self.hold_steps
        elif self._hold > 0:
            self._hold -= 1

    def wants_control(self) -> bool:
        return self._hold > 0 or self.expert.wants_control()

    def act(self, env: gym.Env[Any, Any], obs: np.ndarray) -> tuple[np.ndarray, Actor]:
        return self.expert.act(env, obs)
