"""Reference gatings for the operating curve: random, curiosity-only and privileged (InfoGate), each with the SAGE
gate's own hold (:class:`~core.sage.gate.TakeoverHold`). Fear at another operating point is no reference gating: it
is the SAGE gate itself with ``gate.tau_scale`` set (:func:`studies.calibrate.curve_point`)."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from core.loop import Gate, GateDecision, StepRecord
from core.sage.gate import TakeoverHold


class HoldGate:
    """Fires by its own rule (:meth:`rule`) and holds control as the SAGE gate does: the same
    :class:`~core.sage.gate.TakeoverHold`, for ``hold`` steps. ``inner`` (a SAGE gate) still computes fear, τ and
    curiosity for the records; its own firing is not used."""

    def __init__(self, inner: Gate, hold: int) -> None:
        self.inner, self.hold = inner, hold
        self.takeover_hold = TakeoverHold()
        self.last_curiosity = math.nan

    def reset(self) -> None:
        self.inner.reset()
        self.takeover_hold.reset()
        self.last_curiosity = math.nan

    def rule(self, decision: GateDecision) -> bool:
        """Whether to (re)start the hold at this step."""
        raise NotImplementedError

    def decide(self, obs: np.ndarray, a_rl: np.ndarray) -> GateDecision:
        decision = self.inner.decide(obs, a_rl)
        fired = self.takeover_hold.step(self.rule(decision), self.hold)
        return GateDecision(decision.fear, decision.threshold, fired)

    def observe(self, obs: np.ndarray, action: np.ndarray, next_obs: np.ndarray) -> float:
        self.last_curiosity = float(self.inner.observe(obs, action, next_obs))
        return self.last_curiosity


class RandomGate(HoldGate):
    """Fires with probability ``p`` at each step, whatever the state."""

    def __init__(self, inner: Gate, hold: int, p: float, seed: int = 0) -> None:
        super().__init__(inner, hold)
        self.p, self.rng = p, np.random.default_rng(seed)

    def rule(self, decision: GateDecision) -> bool:
        return bool(self.rng.random() < self.p)


class CuriosityGate(HoldGate):
    """Fires when the curiosity of the last transition exceeds ``level`` (curiosity alone, no fear); ``seen`` keeps
    every curiosity it observed (an infinite level makes it a pilot that never fires)."""

    def __init__(self, inner: Gate, hold: int, level: float) -> None:
        super().__init__(inner, hold)
        self.level = level
        self.seen: list[float] = []

    def rule(self, decision: GateDecision) -> bool:
        return math.isfinite(self.last_curiosity) and self.last_curiosity > self.level

    def observe(self, obs: np.ndarray, action: np.ndarray, next_obs: np.ndarray) -> float:
        curiosity = super().observe(obs, action, next_obs)
        if math.isfinite(curiosity):
            self.seen.append(curiosity)
        return curiosity


class InfoGate(HoldGate):
    """Fires when ``danger(info)`` holds for the info dict of the last step (a privileged reference gating: what the
    simulator knows and the policy's world model must infer, e.g. highway's true time to contact and gaps), with the
    SAGE gate's hold. Feed it the steps: :func:`run_gated`'s ``listeners`` (its :meth:`watch`)."""

    def __init__(self, inner: Gate, hold: int, danger: Callable[[Mapping[str, Any]], bool]) -> None:
        super().__init__(inner, hold)
        self.danger = danger
        self.info: Mapping[str, Any] = {}

    def reset(self) -> None:
        super().reset()
        self.info = {}  # an episode's first step has no last step: nothing to read yet

    def watch(self, record: StepRecord) -> None:
        self.info = record.info

    def rule(self, decision: GateDecision) -> bool:
        return bool(self.info) and bool(self.danger(self.info))


def firing_share(rate: float, hold: int) -> float:
    """The per-step firing probability p at which independent firing with a ``hold``-step hold takes over a share
    ``rate`` of the steps: rate = k p / (1 + (k - 1) p)."""
    return min(max(rate / max(hold - (hold - 1) * rate, 1e-9), 0.0), 1.0)


def level_for_share(curiosities: Sequence[float], share: float) -> float:
    """The curiosity level exceeded by a ``share`` of ``curiosities`` (above all of them for a share of 0)."""
    values = np.sort(np.asarray(curiosities, dtype=float))
    if len(values) == 0 or share <= 0.0:
        return math.inf
    index = int(np.clip(math.ceil((1.0 - share) * len(values)) - 1, 0, len(values) - 1))
    return float(values[index])
