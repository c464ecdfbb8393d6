"""The protocols and records the parts of the product meet through.

A simulator is a gymnasium ``Env`` whose ``unwrapped`` also offers the three methods of
:class:`SimulatorEnv`. ``core`` never imports a simulator; it only relies on this protocol.

The step loop (:mod:`core.loop`) meets a :class:`Policy`, a :class:`Gate` and an :class:`Expert`, and hands its
listeners a :class:`StepRecord` per step and an :class:`EpisodeSummary` per episode. They live here, below the loop,
so that what implements or consumes them (the learners and the SAGE gate in :mod:`core.sage`, the replay buffer,
the session store) needs no import of the loop; :mod:`core.loop` imports them back for its callers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Literal, Protocol, runtime_checkable

import gymnasium as gym
import numpy as np

from core.scene import Scene

Actor = Literal["agent", "expert", "person", "fallback"]
"""Who produced the executed action: the learned policy, a scripted expert, a person at the
dashboard, or the scripted expert standing in for a person who did not answer in time."""


class Policy(Protocol):
    """Maps an observation to an action in the env's action space."""

    def act(self, obs: np.ndarray, deterministic: bool = False) -> np.ndarray: ...


@dataclass(frozen=True)
class GateDecision:
    fear: float
    """Short-horizon fear F_t^m (NaN when the gate computes none)."""
    threshold: float
    """Curiosity-modulated threshold tau_t (NaN when the gate computes none)."""
    fired: bool
    """True when the gate asks for the expert: F_t > tau_t now, or still holding a recent firing."""


class Gate(Protocol):
    """Decides when the agent is out of its depth. ``core.sage`` implements the SAGE gate."""

    def reset(self) -> None:
        """Start of an episode: clear the hold counter (curiosity statistics may persist)."""
        ...

    def decide(self, obs: np.ndarray, a_rl: np.ndarray) -> GateDecision: ...

    def observe(self, obs: np.ndarray, action: np.ndarray, next_obs: np.ndarray) -> float:
        """After the env step: update curiosity statistics and return C_{t+1}."""
        ...


class Expert(Protocol):
    """Who acts when the gate fires: a scripted controller, a trained policy, or a person."""

    def reset(self) -> None: ...

    def wants_control(self) -> bool:
        """True while the expert takes control on its own (a person holding the takeover key)."""
        ...

    def act(self, env: gym.Env[Any, Any], obs: np.ndarray) -> tuple[np.ndarray, Actor]:
        """The expert's action for the current state and who actually produced it."""
        ...


class Coach(Protocol):
    """An expert that can also *coach*: give its action as a label on a step the agent drives, without taking the
    wheel (a person steering along at the dashboard; headless, :class:`core.experts.CoachingExpert`). The loop asks
    on every step nobody takes over; the label is recorded (``StepRecord.a_expert`` with ``coached``) and imitated
    by the fine-tuning rounds like a takeover's, never executed."""

    def coach(self, env: gym.Env[Any, Any], obs: np.ndarray) -> np.ndarray | None:
        """The label for this agent-driven step, or None (no coaching on this step)."""
        ...


@dataclass
class StepRecord:
    """Everything one step produced; the unit that is streamed, stored and learned from."""

    episode: int
    t: int
    obs: np.ndarray
    a_rl: np.ndarray
    a_expert: np.ndarray | None
    action: np.ndarray
    takeover: bool
    gate_fired: bool
    actor: Actor
    fear: float
    threshold: float
    curiosity: float
    reward: float
    cost: float
    violation: bool
    terminated: bool
    truncated: bool
    next_obs: np.ndarray
    wall_time: float
    info: dict[str, Any] = field(default_factory=dict)
    coached: bool = False
    """The agent drove and the expert coached: ``a_expert`` is its label for this state, not what was executed."""

    @property
    def done(self) -> bool:
        return self.terminated or self.truncated

    def to_message(self) -> dict[str, Any]:
        """A small JSON-ready dict (no observations) for streaming to a page."""

        def num(x: float) -> float | None:
            return None if x is None or not math.isfinite(x) else float(x)

        return {
            "episode": self.episode,
            "t": self.t,
            "fear": num(self.fear),
            "threshold": num(self.threshold),
            "curiosity": num(self.curiosity),
            "takeover": self.takeover,
            "gate_fired": self.gate_fired,
            "actor": self.actor,
            "coached": self.coached,
            "a_rl": np.asarray(self.a_rl, dtype=float).reshape(-1).tolist(),
            "a_expert": None if self.a_expert is None else np.asarray(self.a_expert, dtype=float).reshape(-1).tolist(),
            "action": np.asarray(self.action, dtype=float).reshape(-1).tolist(),
            "reward": num(self.reward),
            "cost": num(self.cost),
            "violation": self.violation,
            "done": self.done,
            "wall_time": self.wall_time,
        }


@dataclass(frozen=True)
class EpisodeProgress:
    """The running episode's tallies so far (what :class:`EpisodeSummary` will say when it ends)."""

    episode: int
    steps: int
    ret: float
    cost: float
    takeovers: int
    takeover_events: int
    violations: int
    """Violation onsets (a violation lasting several steps counts once)."""


@dataclass
class EpisodeSummary:
    episode: int
    steps: int
    ret: float
    cost: float
    takeovers: int
    """Number of steps under expert control."""
    takeover_events: int
    """Number of distinct takeover segments."""
    mean_fear: float
    mean_curiosity: float
    metrics: dict[str, float]
    """The simulator's own episode metrics (success, collision, speed, ...)."""
    error: str | None = None
    """Set when the episode ended because the simulator raised."""
    reason: str = "ended"
    """Why it ended: ``terminated`` / ``truncated`` by the simulator, ``error``, or what the caller said
    (``step limit``, ``new episode``, ``simulator switched``, ``server stopped``...)."""
    coached: int = 0
    """Steps the agent drove with a coach's label (:class:`Coach`)."""

    @property
    def takeover_rate(self) -> float:
        return self.takeovers / max(self.steps, 1)

    def as_row(self) -> dict[str, Any]:
        row: dict[str, Any] = {
            "episode": self.episode,
            "steps": self.steps,
            "return": self.ret,
            "cost": self.cost,
            "takeovers": self.takeovers,
            "takeover_events": self.takeover_events,
            "takeover_rate": self.takeover_rate,
            "mean_fear": self.mean_fear,
            "mean_curiosity": self.mean_curiosity,
        }
        row.update(self.metrics)
        if self.coached:  # only where a coach was on: the rows of every study without one stay as they were
            row["coached"] = self.coached
        if self.error:
            row["error"] = self.error
        return row


@runtime_checkable
class SimulatorEnv(Protocol):
    """What ``env.unwrapped`` offers beyond gymnasium's ``reset`` and ``step``."""

    def expert_action(self) -> np.ndarray:
        """The scripted expert's action for the current state (privileged state allowed)."""
        ...

    def scene(self) -> Scene:
        """Plain data describing what to draw now (see :mod:`core.scene`). The sim never draws."""
        ...

    # Optional: ``expert_engaged() -> bool``, True while the scripted expert is in the middle of a manoeuvre that
    # handing control back would cut short (the UGV's evasion of a mover). The scripted expert then keeps the
    # wheel past the gate's hold, as a person keeps holding the takeover key; see :func:`expert_engaged`.

    # ``step``'s info may carry ``executed_action``: the action the simulator really executed when its own driver
    # model acted for the expert (SUMO); the loop then records it as the expert's action (the imitation label).

    def metrics(self) -> dict[str, float]:
        """Metrics of the current (or just finished) episode, computed from the executed trajectory."""
        ...


def simulator(env: gym.Env[Any, Any]) -> SimulatorEnv:
    """The protocol side of ``env``; a clear error when the env does not offer it."""
    inner = env.unwrapped
    missing = [name for name in ("expert_action", "scene", "metrics") if not callable(getattr(inner, name, None))]
    if missing:
        raise TypeError(
            f"{type(inner).__name__} does not implement the simulator protocol: missing {', '.join(missing)}"
        )
    return inner  # type: ignore[return-value]


def expert_engaged(env: gym.Env[Any, Any]) -> bool:
    """Whether the simulator's scripted expert, at its last action, was in the middle of a manoeuvre it should
    finish (the optional ``expert_engaged`` of the protocol; False for a simulator without it)."""
    engaged = getattr(env.unwrapped, "expert_engaged", None)
    return bool(engaged()) if callable(engaged) else False


def is_discrete(env: gym.Env[Any, Any]) -> bool:
    """True when the action space is ``Discrete`` (D3QN-style learners), False for a ``Box``."""
    return isinstance(env.action_space, gym.spaces.Discrete)
