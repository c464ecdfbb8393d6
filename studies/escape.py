"""Could the expert have avoided it from there? The violations that come with the expert driving, replayed.

The gate + expert table (:func:`studies.calibrate.gate_with_expert`) counts the violations that happen while the
expert drives: the gate warned, the expert took the wheel and still could not avoid it. That is either the expert's
failure (a better driver would have escaped) or the warning's (nothing could be done from there). :func:`escape_check`
tells the two apart with the simulator itself: each such episode is replayed from its seed with the actions that
were executed, up to the step where the expert took over (or a given time before the violation), and from there every
steady manoeuvre of a grid over the action space (each action held) is driven for a few seconds. A violation that
some manoeuvre avoids was within reach from there, for a driver who knew what the others would do (the manoeuvres
meet the true future of the other traffic, which the expert only predicts). One that none avoids may still have been
avoidable by a manoeuvre that changes course on the way (a steady grid is a small set): "no escape" is evidence that
the warning came too late, not a proof.

The replay is exact only where the simulator is deterministic given the seed and the actions; each replay is checked
against the recorded observations up to its start, and an episode whose replay drifts (SUMO, whose own driver steers
when its expert drives) is counted apart and left out.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from core.agents import load_agent
from core.experts import ScriptedExpert
from core.loop import Runner, StepRecord
from studies.calibrate import EVAL_SEED, _episode


@dataclass
class EscapeReport:
    """What :func:`escape_check` measured."""

    episodes: int
    violations: int
    """Episodes with a violation (gate + scripted expert, the evaluation seeds)."""
    drifted: int
    """Of them, those whose replay did not reproduce the episode (left out of everything below)."""
    manoeuvres: int
    """Steady manoeuvres tried from each start."""
    hold_s: float
    """How long each manoeuvre is held (or up to the episode's end)."""
    warned: int = 0
    """Replayed violations with a takeover in the ``window_s`` before them: the expert driving at the violation, or
    handed back."""
    under_expert: int = 0
    """Of the warned, those with the expert driving at the violation."""
    from_takeover: int = 0
    """Of the warned, those that some manoeuvre avoided from the first step of the last takeover."""
    before_s: list[float] = field(default_factory=list)
    escapable_before: list[int] = field(default_factory=list)
    """Per ``before_s``: of all replayed violations, those that some manoeuvre avoided from that long before."""

    @property
    def replayed(self) -> int:
        return self.violations - self.drifted

    def summary(self) -> str:
        drifted = f" ({self.drifted} replays drifted, left out)" if self.drifted else ""
        before = ", ".join(f"{s:g} s before: {n}" for s, n in zip(self.before_s, self.escapable_before, strict=True))
        return (
            f"{self.violations} of {self.episodes} episodes with a violation{drifted}; {self.warned} of the "
            f"{self.replayed} replayed had a takeover before it ({self.under_expert} with the expert driving), "
            f"{self.from_takeover} of them avoidable from that takeover by a steady manoeuvre ({self.manoeuvres}, held "
            f"{self.hold_s:g} s); avoidable from {before or '–'}"
        )


def steady_actions(space: gym.Space[Any], levels: int = 5) -> list[np.ndarray]:
    """Every action of a discrete space, or a grid of ``levels`` evenly spaced values per dimension of a box."""
    if isinstance(space, gym.spaces.Discrete):
        return [np.asarray(space.start + i, dtype=np.int64) for i in range(int(space.n))]
    if isinstance(space, gym.spaces.Box):
        if levels < 2:
            raise ValueError(f"levels must be >= 2, got {levels}")
        axes = [np.linspace(lo, hi, levels) for lo, hi in zip(space.low.ravel(), space.high.ravel(), strict=True)]
        return [np.asarray(point, dtype=space.dtype).reshape(space.shape) for point in itertools.product(*axes)]
    raise ValueError(f"no steady manoeuvres for a {type(space).__name__} action space")


def _replay_to(env: gym.Env[Any, Any], seed: int, records: Sequence[StepRecord], start: int) -> bool:
    """Reset ``env`` with ``seed`` and execute the recorded actions before step ``start``; whether every observation
    on the way matched the recording (the replay is the same episode)."""
    obs, _ = env.reset(seed=seed)
    for record in records[:start]:
        if not np.allclose(np.asarray(obs, dtype=np.float64), np.asarray(record.obs, dtype=np.float64), atol=1e-5):
            return False
        obs, *_ = env.step(record.action)
    return start >= len(records) or bool(
        np.allclose(np.asarray(obs, dtype=np.float64), np.asarray(records[start].obs, dtype=np.float64), atol=1e-5)
    )


def _avoids(env: gym.Env[Any, Any], action: np.ndarray, steps: int) -> bool:
    for _ in range(steps):
        _, _, terminated, truncated, info = env.step(action)
        if info.get("violation"):
            return False
        if terminated or truncated:
            return True
    return True


def escape_check(
    run: str | Path,
    make_env: Callable[[], gym.Env[Any, Any]],
    dt: float,
    episodes: int = 100,
    before_s: Sequence[float] = (1.0, 2.0),
    hold_s: float = 3.0,
    levels: int = 5,
    window_s: float = 3.0,
    max_steps: int | None = None,
    **gate_overrides: Any,
) -> EscapeReport:
    """The policy with its own gate and the scripted expert on the evaluation seeds (as
    :func:`studies.calibrate.gate_with_expert`); each episode with a violation is replayed, and every steady
    manoeuvre (:func:`steady_actions`) is held for ``hold_s`` seconds from the start of the last takeover within
    ``window_s`` before the violation (where there was one) and from each of ``before_s`` seconds before it: does
    any avoid the violation?"""
    agent = load_agent(run)
    env = make_env()
    manoeuvres = steady_actions(env.action_space, levels)
    hold = max(1, round(hold_s / dt))
    window = max(1, round(window_s / dt))
    report = EscapeReport(episodes, 0, 0, len(manoeuvres), hold_s, before_s=[float(s) for s in before_s])
    report.escapable_before = [0] * len(before_s)
    try:
        gate = agent.make_gate(**gate_overrides)
        runner = Runner(env, agent.policy, gate, ScriptedExpert(), seed=EVAL_SEED, deterministic=True)
        failures: list[tuple[int, list[StepRecord], int]] = []  # (episode, records, step of the first violation)
        for episode in range(episodes):
            records = _episode(runner, max_steps)
            step = next((i for i, r in enumerate(records) if r.violation), None)
            if step is not None:
                failures.append((episode, records, step))
        report.violations = len(failures)

        def escapes(seed: int, records: list[StepRecord], begin: int) -> bool:
            for action in manoeuvres:
                _replay_to(env, seed, records, begin)
                if _avoids(env, action, hold):
                    return True
            return False

        for episode, records, step in failures:
            seed = EVAL_SEED + episode
            if not _replay_to(env, seed, records, step):
                report.drifted += 1
                continue
            taken = [i for i in range(max(0, step - window), step + 1) if records[i].takeover]
            if taken:
                report.warned += 1
                report.under_expert += int(records[step].takeover)
                begin = taken[-1]
                while begin > 0 and records[begin - 1].takeover:
                    begin -= 1
                report.from_takeover += int(escapes(seed, records, begin))
            for i, s in enumerate(before_s):
                report.escapable_before[i] += int(escapes(seed, records, max(0, step - round(s / dt))))
    finally:
        env.close()
    return report
