"""How much warning the expert needs: each of the policy's violations replayed with the scripted expert taking over a
given time before it, beside how long before it the gate first fired (expert_lead)."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from core.agents import load_agent
from core.experts import ScriptedExpert
from core.loop import GateDecision, Runner, StepRecord
from studies.calibrate._gated_runs import EVAL_SEED


@dataclass
class LeadReport:
    """What :func:`expert_lead` measured: the policy's violations, how early the gate saw each coming, and how many
    the expert still could not avoid when it took over a given time before them."""

    episodes: int
    violations: int
    """Episodes in which the policy alone had a violation (the gate watching, no expert)."""
    gate_warning_s: list[float]
    """Per such episode: time from the gate's first firing in the ``max(leads_s)`` before the violation to it (0:
    no firing in that window)."""
    leads_s: list[float]
    left: list[int]
    """Per lead: of those episodes, how many still had a violation with the expert driving from that long before
    the policy's violation to the end of the episode."""

    def summary(self) -> str:
        warning = f"{np.median(self.gate_warning_s):.1f} s" if self.gate_warning_s else "–"
        left = ", ".join(f"{lead:g} s: {n}" for lead, n in zip(self.leads_s, self.left, strict=True))
        needed = self.needed_s()
        return "\n".join(
            [
                f"the policy alone had a violation in {self.violations} of {self.episodes} episodes; the gate first "
                f"fired a median {warning} before it (within {max(self.leads_s, default=0.0):g} s)",
                f"the scripted expert taking over that long before each, violations left: {left or '–'}",
                "warning the expert needs: "
                + ("nothing to avoid" if self.violations == 0 else f"{needed:g} s" if math.isfinite(needed) else "more")
                + " (the shortest of those leads at which it avoided every one)",
            ]
        )

    def needed_s(self) -> float:
        """The shortest lead at which the expert avoided every one of them (NaN: none of the leads was enough; 0:
        there was nothing to avoid)."""
        if self.violations == 0:
            return 0.0
        return next((lead for lead, left in zip(self.leads_s, self.left, strict=True) if left == 0), math.nan)


class _ExpertFrom:
    """Fires from step ``start`` of the episode on (the expert drives from there to the end)."""

    def __init__(self) -> None:
        self.start, self.t = 0, 0

    def reset(self) -> None:
        self.t = 0

    def decide(self, obs: np.ndarray, a_rl: np.ndarray) -> GateDecision:
        fired = self.t >= self.start
        self.t += 1
        return GateDecision(math.nan, math.nan, fired)

    def observe(self, obs: np.ndarray, action: np.ndarray, next_obs: np.ndarray) -> float:
        return math.nan


def _episode(runner: Runner, max_steps: int | None) -> list[StepRecord]:
    """The step records of one whole episode of ``runner`` (:meth:`Runner.run_episode`)."""
    records: list[StepRecord] = []
    runner.step_listeners.append(records.append)
    try:
        runner.run_episode(max_steps=max_steps)
    finally:
        runner.step_listeners.remove(records.append)
    return records


def expert_lead(
    run: str | Path,
    make_env: Callable[[], gym.Env[Any, Any]],
    dt: float,
    episodes: int = 20,
    leads_s: Sequence[float] = (0.5, 1.0, 1.5, 2.0, 3.0),
    max_steps: int | None = None,
    gate_settings: Mapping[str, Any] | None = None,
) -> LeadReport:
    """The policy drives alone with its gate watching (as in :func:`calibrate_run`) on the evaluation seeds; each
    episode with a violation is then replayed from the same seed with the scripted expert taking over ``lead``
    seconds before the policy's first violation and driving to the end. Policy and simulator are deterministic
    given the seed, so the replay is the same episode up to the takeover; the fewest seconds at which the expert
    avoids every violation is the warning the gate has to give."""
    agent = load_agent(run)
    env = make_env()
    try:
        gate = agent.make_gate(**(gate_settings or {}))
        watching = Runner(env, agent.policy, gate, None, seed=EVAL_SEED, deterministic=True)
        window = max(1, round(max(leads_s, default=0.0) / dt))
        first: list[tuple[int, int]] = []  # (episode, step of its first violation)
        warnings: list[float] = []
        for episode in range(episodes):
            records = _episode(watching, max_steps)  # seed EVAL_SEED + episode
            step = next((i for i, r in enumerate(records) if r.violation), None)
            if step is None:
                continue
            first.append((episode, step))
            fired = [i for i in range(max(0, step - window), step + 1) if records[i].gate_fired]
            warnings.append((step - fired[0]) * dt if fired else 0.0)
        takeover = _ExpertFrom()
        left = []
        for lead in leads_s:
            count = 0
            for episode, step in first:
                takeover.start = max(0, step - round(lead / dt))
                # a runner's first episode has its seed: the same episode as the watched one up to the takeover
                replay = Runner(
                    env, agent.policy, takeover, ScriptedExpert(), seed=EVAL_SEED + episode, deterministic=True
                )
                count += any(r.violation for r in _episode(replay, max_steps))
            left.append(count)
    finally:
        env.close()
    return LeadReport(episodes, len(first), warnings, [float(lead) for lead in leads_s], left)
