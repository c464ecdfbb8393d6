"""A gating driving with the scripted expert on the evaluation seeds, and where its episodes' violations came from."""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from core.agents import load_agent
from core.experts import ScriptedExpert
from core.loop import TAKEOVER_CAUSES, Gate, Runner, StepRecord, takeover_cause

EVAL_SEED = 3_000_000
"""Calibration episodes use seeds apart from training (episode i: EVAL_SEED + i)."""


def _tau_min(gate: Gate) -> float:
    """The lowest threshold the SAGE gate inside ``gate`` can reach (its τ_min), NaN for other gates."""
    inner = getattr(gate, "inner", gate)
    threshold = getattr(inner, "threshold", None)
    return float(getattr(threshold, "tau_min", math.nan))


def run_gated(
    agent: Any,
    make_env: Callable[[], gym.Env[Any, Any]],
    gate: Gate,
    episodes: int,
    max_steps: int | None,
    warn_steps: int = 10,
    listeners: Sequence[Callable[[StepRecord], None]] = (),
    first_seed: int = EVAL_SEED,
) -> dict[str, float]:
    """The policy with ``gate`` and the scripted expert over ``episodes`` (the evaluation seeds, from ``first_seed``):
    see :func:`gate_with_expert` for what it returns; ``listeners`` also see every step (e.g.
    :meth:`InfoGate.watch`)."""
    env = make_env()
    tau_min = _tau_min(gate)
    try:
        runner = Runner(env, agent.policy, gate, ScriptedExpert(), seed=first_seed, deterministic=True)
        # per episode: the first violation's (expert driving?, steps the expert had been driving up to it, and the
        # last ``warn_steps`` steps' (fear, gate fired) up to it)
        first: list[tuple[bool, int, list[tuple[float, bool]]] | None] = [None]
        streak = [0]
        recent: deque[tuple[float, bool]] = deque(maxlen=max(1, warn_steps))
        expert_steps = dict.fromkeys(TAKEOVER_CAUSES, 0)
        # fear over the threshold the gate compares it with (τ_t, gate.tau_scale already in it) over the last
        # 2 · warn_steps steps, and its peak over those before the expert's present streak began
        ratios: deque[float] = deque(maxlen=2 * max(1, warn_steps))
        peak_before_streak = [math.nan]
        peaks: list[float] = []

        def watch(r: StepRecord) -> None:
            streak[0] = streak[0] + 1 if r.takeover else 0
            if streak[0] == 1:
                peak_before_streak[0] = max((v for v in ratios if math.isfinite(v)), default=math.nan)
            level = r.threshold
            ratios.append(r.fear / level if math.isfinite(r.fear) and math.isfinite(level) and level > 0 else math.nan)
            recent.append((r.fear, bool(r.gate_fired or r.takeover)))
            if r.violation and first[0] is None:
                first[0] = (bool(r.takeover), streak[0], list(recent))
                if r.takeover:
                    peaks.append(peak_before_streak[0])
            cause = takeover_cause(r, gate)
            if cause is not None:
                expert_steps[cause] += 1

        runner.step_listeners.append(watch)
        runner.step_listeners.extend(listeners)
        takeovers = steps = 0
        violations: list[tuple[bool, int, list[tuple[float, bool]]]] = []
        for _ in range(episodes):
            first[0], streak[0] = None, 0
            recent.clear()
            ratios.clear()
            summary = runner.run_episode(max_steps=max_steps)
            if first[0] is not None:
                violations.append(first[0])
            takeovers += summary.takeovers
            steps += summary.steps
    finally:
        env.close()
    under_expert = [n for expert, n, _ in violations if expert]
    # the others, with the policy driving: had the gate fired in the last warn_steps (and handed back), did fear
    # at least reach τ_min (a threshold within the gate's own range would have fired), or was the danger unforeseen
    handed_back = under_threshold = unforeseen = 0
    for expert, _, window in violations:
        if expert:
            continue
        peak = max((f for f, _ in window if math.isfinite(f)), default=math.nan)
        if any(fired for _, fired in window):
            handed_back += 1
        elif math.isfinite(peak) and math.isfinite(tau_min) and peak >= tau_min:
            under_threshold += 1
        else:
            unforeseen += 1
    return {
        "takeover_rate": takeovers / max(steps, 1),
        **{f"takeover_{cause}": n / max(steps, 1) for cause, n in expert_steps.items()},
        "violation_rate": len(violations) / episodes,
        "episodes": float(episodes),
        "steps": float(steps),
        "violations_under_expert": float(len(under_expert)),
        "expert_steps_before_violation": float(np.mean(under_expert)) if under_expert else float("nan"),
        "fear_before_handoff": float(np.nanmedian(peaks)) if any(math.isfinite(p) for p in peaks) else float("nan"),
        "violations_handed_back": float(handed_back),
        "violations_under_threshold": float(under_threshold),
        "violations_unforeseen": float(unforeseen),
    }


def gate_with_expert(
    run: str | Path,
    make_env: Callable[[], gym.Env[Any, Any]],
    episodes: int,
    max_steps: int | None = None,
    warn_steps: int = 10,
    **gate_overrides: Any,
) -> dict[str, float]:
    """The product as it runs: the policy with its own SAGE gate (its τ, unscaled; ``gate_overrides``: any
    :class:`~core.sage.config.GateConfig` field, e.g. ``release=1.0``) and the scripted expert.
    Returns the share of episodes with a violation and the takeover rate, on the evaluation seeds, the takeover
    rate's parts by why the expert drove (``takeover_<cause>``: :func:`core.loop.takeover_cause`), and where each
    episode's first violation comes from:

    - ``violations_under_expert``: the expert was driving (the gate warned; the expert could not avoid it from
      there), and for how many steps it had been driving by then (``expert_steps_before_violation``, their mean);
      ``fear_before_handoff``: over those, the median of fear's peak over the threshold it was compared with (τ_t, at
      the gate's ``tau_scale``) in the ``2 · warn_steps`` steps before the expert's last takeover
      began. Well under 1: fear rose suddenly, and a lower threshold would have handed over little earlier; near 1:
      it hovered just under the threshold, which a lower one would have caught sooner;
    - with the policy driving, judged on the last ``warn_steps`` steps up to the violation (1 s by default at
      10 Hz): ``violations_handed_back`` (the gate had fired and its hold ran out), ``violations_under_threshold``
      (it had not, but fear reached τ_min, the lowest threshold curiosity can set: the threshold's place was the
      lever) and ``violations_unforeseen`` (fear stayed below τ_min throughout: the world model did not see it
      coming, and no threshold in the gate's range would have fired).
    """
    agent = load_agent(run)
    return run_gated(agent, make_env, agent.make_gate(**gate_overrides), episodes, max_steps, warn_steps)
