"""The one step loop behind every face of the product.

    s_t -> policy -> a_rl -> gate (fear F_t vs threshold tau_t, held k steps) -> takeover?
        yes: a = expert(s_t)      no: a = a_rl (and a coaching expert's label for s_t, recorded, not executed)
    env.step(a) -> s_{t+1}, r_t, c_t -> gate.observe -> curiosity C_{t+1} -> StepRecord -> listeners

Headless training and evaluation run :meth:`Runner.step` as fast as they can with a scripted expert;
the live server runs the very same method at wall-clock rate with a person (or a fallback) as the
expert. Listeners (replay buffers, learners, the session store, the websocket stream) receive every
:class:`StepRecord` and every :class:`EpisodeSummary`; nothing about the step differs between faces.
"""

from __future__ import annotations

import logging
import math
import time
import traceback
from collections.abc import Callable
from typing import Any, Literal

import gymnasium as gym
import numpy as np

# The loop's records and protocols live in core.protocol (what core.sage implements needs no import of the loop);
# imported here for the loop and for callers that name them core.loop.X.
from core.protocol import (
    Actor,
    EpisodeProgress,
    EpisodeSummary,
    Expert,
    Gate,
    GateDecision,
    Policy,
    StepRecord,
    simulator,
)

log = logging.getLogger(__name__)


class NoGate:
    """Plain RL: never asks for help, computes no fear or curiosity."""

    def reset(self) -> None:
        pass

    def decide(self, obs: np.ndarray, a_rl: np.ndarray) -> GateDecision:
        return GateDecision(math.nan, math.nan, False)

    def observe(self, obs: np.ndarray, action: np.ndarray, next_obs: np.ndarray) -> float:
        return math.nan


TakeoverCause = Literal["fear", "hold", "hysteresis", "manoeuvre"]
TAKEOVER_CAUSES: tuple[TakeoverCause, ...] = ("fear", "hold", "hysteresis", "manoeuvre")
"""Why the expert drove a step (:func:`takeover_cause`)."""


def takeover_cause(record: StepRecord, gate: Gate) -> TakeoverCause | None:
    """Why the expert drove this step (None: it did not): ``fear`` over the step's τ (the gate fired), the
    ``hold`` counting down its k steps after that, ``hysteresis`` (fear under τ but over the gate's release level
    restarted the hold: ``GateConfig.release``, read from the gate's ``detail.level`` where it keeps one) or the
    expert's own ``manoeuvre``, kept past the gate's hold (:func:`core.protocol.expert_engaged`; at the dashboard, a
    person holding on). Read right after the step, before the gate decides the next."""
    if not record.takeover:
        return None
    if not record.gate_fired:
        return "manoeuvre"
    if record.fear > record.threshold:
        return "fear"
    level = getattr(getattr(gate, "detail", None), "level", math.nan)
    return "hysteresis" if record.fear > level else "hold"


StepListener = Callable[[StepRecord], None]
EpisodeListener = Callable[[EpisodeSummary], None]


class Runner:
    """Owns an env, a policy, a gate and an expert, and steps them as one loop.

    ``step()`` never raises because of the simulator: an exception inside ``env.step`` ends the
    episode with ``EpisodeSummary.error`` set, and the next call starts a new episode.
    """

    def __init__(
        self,
        env: gym.Env[Any, Any],
        policy: Policy,
        gate: Gate | None = None,
        expert: Expert | None = None,
        *,
        seed: int = 0,
        deterministic: bool = False,
    ) -> None:
        simulator(env)  # fail early and clearly if the env is not one of ours
        self.env = env
        self.policy = policy
        self.gate: Gate = gate or NoGate()
        self.expert = expert
        self.seed = seed
        self.deterministic = deterministic
        self.step_listeners: list[StepListener] = []
        self.episode_listeners: list[EpisodeListener] = []
        self.agent_action_filter: Callable[[np.ndarray], np.ndarray] | None = None
        """What the policy's action passes through before it is executed when nobody takes over (the dashboard's
        bumpless hand-back from a person to the policy); the record keeps the policy's own proposal as ``a_rl``."""
        self.episode = -1
        self.t = 0
        self.obs: np.ndarray | None = None
        self._pending_policy: Policy | None = None
        self._pending_gate: Gate | None = None
        self._next_reset_options: dict[str, Any] | None = None
        self._acc: dict[str, Any] = {}

    # -- configuration -------------------------------------------------------------------------
    def set_policy_at_boundary(self, policy: Policy, gate: Gate | None = None) -> None:
        """Swap the policy (and the gate that watches it) when the next episode starts (never mid-episode)."""
        self._pending_policy = policy
        self._pending_gate = gate

    def set_next_reset_options(self, options: dict[str, Any] | None) -> None:
        """gymnasium ``reset(options=...)`` of the next episode (a scenario change, a mode): the env itself
        applies them, nobody sets its fields behind gymnasium's back."""
        self._next_reset_options = dict(options) if options else None

    def reseed(self, seed: int) -> None:
        """Episode seeds from now on: the next episode's is ``seed + its index``."""
        self.seed = seed

    def set_expert(self, expert: Expert | None) -> None:
        self.expert = expert

    # -- the loop ------------------------------------------------------------------------------
    def reset(self, seed: int | None = None) -> np.ndarray:
        if self._pending_policy is not None:
            self.policy, self._pending_policy = self._pending_policy, None
        if self._pending_gate is not None:
            self.gate, self._pending_gate = self._pending_gate, None
        self.episode += 1
        self.t = 0
        episode_seed = self.seed + self.episode if seed is None else seed
        options, self._next_reset_options = self._next_reset_options, None
        self.obs, _ = (
            self.env.reset(seed=episode_seed, options=options) if options else self.env.reset(seed=episode_seed)
        )
        self.gate.reset()
        started = getattr(self.policy, "episode_started", None)
        if started is not None:  # a policy that watches its own steps (core.familiar.BaseFirstPolicy)
            started()
        if self.expert is not None:
            self.expert.reset()
        self._acc = {
            "ret": 0.0,
            "cost": 0.0,
            "takeovers": 0,
            "coached": 0,
            "events": 0,
            "violations": 0,
            "fear": [],
            "curiosity": [],
            "prev": False,
            "prev_violation": False,
        }
        return self.obs

    def progress(self) -> EpisodeProgress:
        """Tallies of the current (or the just-ended) episode; zeros before the first step."""
        acc = self._acc
        return EpisodeProgress(
            self.episode,
            self.t,
            float(acc.get("ret", 0.0)),
            float(acc.get("cost", 0.0)),
            int(acc.get("takeovers", 0)),
            int(acc.get("events", 0)),
            int(acc.get("violations", 0)),
        )

    def step(self) -> StepRecord | None:
        """One step of the loop. Returns None when the step failed (the episode was ended with the error)."""
        if self.obs is None:
            self.reset()
        obs = self.obs
        assert obs is not None
        expert = self.expert
        a_expert: np.ndarray | None = None
        actor: Actor = "agent"
        try:
            # Policies and gates may query the simulator too (the scripted expert as a policy does), so a
            # dead simulator can surface anywhere in the step: any failure ends the episode, never the loop.
            a_rl = np.asarray(self.policy.act(obs, deterministic=self.deterministic))
            decision = self.gate.decide(obs, a_rl)
            takeover = expert is not None and (decision.fired or expert.wants_control())
            action = a_rl
            coached = False
            if takeover:
                assert expert is not None
                a_expert, actor = expert.act(self.env, obs)
                a_expert = np.asarray(a_expert)
                action = a_expert
            else:
                coach = getattr(expert, "coach", None)
                if coach is not None:  # asked before the step: the label is for the state the agent acts in
                    label = coach(self.env, obs)
                    if label is not None:
                        a_expert, coached = np.asarray(label), True
                if self.agent_action_filter is not None:
                    action = np.asarray(self.agent_action_filter(a_rl))
            next_obs, reward, terminated, truncated, info = self.env.step(action)
            executed = info.get("executed_action") if takeover else None
            if executed is not None:
                # a simulator whose own driver took the wheel (SUMO's) reports what it really did: that is the
                # expert's label and the transition's action, not the prediction made before the step
                action = np.asarray(executed, dtype=np.asarray(action).dtype).reshape(np.shape(action))
                a_expert = action
            curiosity = float(self.gate.observe(obs, action, next_obs))
            stepped = getattr(self.policy, "stepped", None)
            if stepped is not None:  # what was executed, whoever chose it
                stepped(obs, action, next_obs)
        except Exception as exc:
            self.end_episode(error=f"{type(exc).__name__}: {exc}", reason="error")
            log.warning("step failed in episode %d: %s", self.episode, traceback.format_exc())
            return None
        record = StepRecord(
            episode=self.episode,
            t=self.t,
            obs=obs,
            a_rl=a_rl,
            a_expert=a_expert,
            action=np.asarray(action),
            takeover=takeover,
            gate_fired=decision.fired,
            actor=actor,
            fear=decision.fear,
            threshold=decision.threshold,
            curiosity=curiosity,
            reward=float(reward),
            cost=float(info.get("cost", 0.0)),
            violation=bool(info.get("violation", False)),
            terminated=bool(terminated),
            truncated=bool(truncated),
            next_obs=next_obs,
            wall_time=time.time(),
            info=info,
            coached=coached,
        )
        acc = self._acc
        acc["ret"] += record.reward
        acc["cost"] += record.cost
        acc["takeovers"] += int(takeover)
        acc["coached"] += int(coached)
        acc["events"] += int(takeover and not acc["prev"])
        acc["prev"] = takeover
        acc["violations"] += int(record.violation and not acc["prev_violation"])
        acc["prev_violation"] = record.violation
        if math.isfinite(record.fear):
            acc["fear"].append(record.fear)
        if math.isfinite(curiosity):
            acc["curiosity"].append(curiosity)
        self.t += 1
        self.obs = next_obs
        for listener in self.step_listeners:
            listener(record)
        if record.done:
            self.end_episode(reason="terminated" if record.terminated else "truncated")
        return record

    def run_episode(self, max_steps: int | None = None) -> EpisodeSummary:
        """Run one whole episode and return its summary."""
        summaries: list[EpisodeSummary] = []
        self.episode_listeners.append(summaries.append)
        try:
            self.reset()
            steps = 0
            while not summaries:
                self.step()
                steps += 1
                if max_steps is not None and steps >= max_steps and not summaries:
                    self.end_episode(reason="step limit")
        finally:
            self.episode_listeners.remove(summaries.append)
        return summaries[0]

    def end_episode(self, error: str | None = None, reason: str | None = None) -> None:
        """End the current episode now (an operator's "new episode", a step budget, a simulator error):
        episode listeners get its summary and the next ``step()`` starts a new episode. No-op between
        episodes."""
        if self.obs is None:
            return
        acc = self._acc
        try:
            metrics = dict(simulator(self.env).metrics())
        except Exception as exc:
            metrics = {}
            error = error or f"metrics failed: {exc}"
        summary = EpisodeSummary(
            episode=self.episode,
            steps=self.t,
            ret=acc.get("ret", 0.0),
            cost=acc.get("cost", 0.0),
            takeovers=acc.get("takeovers", 0),
            takeover_events=acc.get("events", 0),
            mean_fear=float(np.mean(acc["fear"])) if acc.get("fear") else math.nan,
            mean_curiosity=float(np.mean(acc["curiosity"])) if acc.get("curiosity") else math.nan,
            metrics=metrics,
            error=error,
            reason=reason or ("error" if error else "ended"),
            coached=acc.get("coached", 0),
        )
        self.obs = None  # the next step() starts a new episode
        for listener in self.episode_listeners:
            listener(summary)
