"""``sage gate evaluate``'s measurement: the policy drives with its gate and no expert, and fear, its parts and
curiosity are scored against "a violation within H" (CalibrationReport, calibrate_run)."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from core.agents import load_agent
from core.loop import Runner, StepRecord
from core.metrics import auroc, average_precision, reliability
from studies.calibrate._curve import CURVE_SCALES, operating_curve
from studies.calibrate._gated_runs import EVAL_SEED
from studies.calibrate._metrics import SignalScore, compare_curves, early_warning, labels_within


@dataclass
class CalibrationReport:
    """What :func:`calibrate_run` measured."""

    run: str
    sim: str
    scenario: str
    episodes: int
    steps: int
    horizon_s: float
    horizon_steps: int
    violations: int
    """Episodes that ended in (or contained) a violation."""
    positives: int
    """Steps labelled "violation within H"."""
    scores: dict[str, SignalScore]
    """fear, cost (ĉ), sigma (σ̂), curiosity."""
    fire_rate_before_violation: float
    fire_rate_elsewhere: float
    violations_warned: float
    """Share of violations with a gate firing within H before them."""
    mean_lead_time_s: float
    """Mean time from the first firing in that window to the violation (warned violations only)."""
    reliability: list[tuple[float, float, int]] = field(default_factory=list)
    curve: dict[str, list[dict[str, float]]] = field(default_factory=dict)
    early_warning: list[dict[str, float]] = field(default_factory=list)
    """How early fear warns, whatever τ: per firing share (:func:`early_warning`), the share of violations it warned of
    :data:`EARLY_LEAD_S` to twice that ahead at a threshold crossed on that share of the steps far from any."""

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    def summary(self) -> str:
        lines = [
            f"{self.run} on {self.sim} {self.scenario}: {self.episodes} episodes, {self.steps} steps, "
            f"{self.violations} with a violation; label: violation within {self.horizon_s:g} s "
            f"({self.horizon_steps} steps), {self.positives} positive steps",
            "",
            "| signal | AUROC | average precision |",
            "|---|---|---|",
        ]
        for name, score in self.scores.items():
            lines.append(f"| {name} | {_fmt(score.auroc)} | {_fmt(score.average_precision)} |")
        lines += [
            "",
            f"gate firing rate: {_pct(self.fire_rate_before_violation)} of pre-violation steps, "
            f"{_pct(self.fire_rate_elsewhere)} of the others",
            f"violations preceded by a firing within {self.horizon_s:g} s: {_pct(self.violations_warned)}, "
            f"mean lead time {_fmt(self.mean_lead_time_s)} s",
        ]
        if self.early_warning:
            lead = self.early_warning[0]["lead_s"]
            pairs = ", ".join(f"{w['firing']:.0%} → {_pct(w['warned'])}" for w in self.early_warning)
            lines.append(
                f"violations fear warned of {lead:g}-{2 * lead:g} s ahead at equal firing (share of the steps more "
                f"than {2 * lead:g} s from a violation over the threshold → violations warned): {pairs}"
            )
        for name, points in self.curve.items():
            pairs = ", ".join(f"{p['takeover_rate']:.0%}→{p['violation_rate']:.0%}" for p in points)
            lines.append(f"operating curve {name} (takeover → episodes with a violation): {pairs}")
        for against in ("random", "curiosity only"):
            if self.curve.get(against):
                v = compare_curves(self.curve, against)
                lines.append(
                    f"fear against {against} at equal takeover (95% interval of the difference): {v['better']} better, "
                    f"{v['tied']} tied, {v['worse']} worse, {v['unmatched']} without a point within 5 points"
                )
        return "\n".join(lines)


def _fmt(value: float) -> str:
    return "–" if value is None or not math.isfinite(value) else f"{value:.3f}"


def _pct(value: float) -> str:
    return "–" if not math.isfinite(value) else f"{value:.0%}"


@dataclass
class _Step:
    episode: int
    fear: float
    cost: float
    sigma: float
    curiosity_in: float
    fired: bool
    violation: bool


def collect(
    make_env: Callable[[], gym.Env[Any, Any]],
    run: str | Path,
    episodes: int,
    max_steps: int | None = None,
    gate_settings: Mapping[str, Any] | None = None,
) -> tuple[list[_Step], Any]:
    """Run the policy with its gate (``gate_settings`` over its own) and no expert; record every step's signals."""
    agent = load_agent(run)
    gate = agent.make_gate(**(gate_settings or {}))
    env = make_env()
    steps: list[_Step] = []
    previous_curiosity = [math.nan]
    try:
        runner = Runner(env, agent.policy, gate, None, seed=EVAL_SEED, deterministic=True)

        def record(r: StepRecord) -> None:
            d = gate.detail
            steps.append(
                _Step(r.episode, r.fear, d.cost, d.sigma, previous_curiosity[0], r.gate_fired, bool(r.violation))
            )
            previous_curiosity[0] = r.curiosity if not r.done else math.nan

        runner.step_listeners.append(record)
        for _ in range(episodes):
            previous_curiosity[0] = math.nan
            runner.run_episode(max_steps=max_steps)
    finally:
        env.close()
    return steps, agent


def calibrate_run(
    run: str | Path,
    make_env: Callable[[], gym.Env[Any, Any]],
    dt: float,
    *,
    sim: str = "",
    scenario: str = "",
    episodes: int = 20,
    horizon_s: float = 1.0,
    max_steps: int | None = None,
    curve_episodes: int = 0,
    curve_scales: Sequence[float] = CURVE_SCALES,
    gate_settings: Mapping[str, Any] | None = None,
    curve_cpus: int | None = None,
    curve_address: str | None = None,
) -> CalibrationReport:
    """Measure how well fear predicts "violation within ``horizon_s``" (see the module docstring); the gate is
    the run's own, with ``gate_settings`` (:class:`~core.sage.config.GateConfig` fields) over it; the operating curve's
    points run as Ray tasks with ``curve_cpus`` or ``curve_address`` (:func:`operating_curve`)."""
    steps, agent = collect(make_env, run, episodes, max_steps, gate_settings)
    if not steps:
        raise ValueError("no steps were recorded: every episode failed (see the log)")
    h = max(1, round(horizon_s / dt))
    episode = np.array([s.episode for s in steps])
    violation = np.array([s.violation for s in steps])
    label = labels_within(violation, episode, h)
    fired = np.array([s.fired for s in steps])
    signals = {
        "fear": np.array([s.fear for s in steps]),
        "cost": np.array([s.cost for s in steps]),
        "sigma": np.array([s.sigma for s in steps]),
        "curiosity": np.array([s.curiosity_in for s in steps]),
    }
    scores = {k: SignalScore(auroc(v, label), average_precision(v, label)) for k, v in signals.items()}
    warned, leads = 0, []
    violation_idx = np.flatnonzero(violation)
    for i in violation_idx:
        window = [j for j in range(max(0, int(i) - h + 1), i + 1) if episode[j] == episode[i]]
        firing = [j for j in window if fired[j]]
        if firing:
            warned += 1
            leads.append((i - firing[0]) * dt)
    model_steps = agent.config.world_model_config.violation_steps
    model_label = labels_within(violation, episode, model_steps)
    report = CalibrationReport(
        run=str(run),
        sim=sim,
        scenario=scenario,
        episodes=episodes,
        steps=len(steps),
        horizon_s=horizon_s,
        horizon_steps=h,
        violations=len(set(episode[violation_idx].tolist())),
        positives=int(label.sum()),
        scores=scores,
        fire_rate_before_violation=float(fired[label].mean()) if label.any() else math.nan,
        fire_rate_elsewhere=float(fired[~label].mean()) if (~label).any() else math.nan,
        violations_warned=warned / len(violation_idx) if len(violation_idx) else math.nan,
        mean_lead_time_s=float(np.mean(leads)) if leads else math.nan,
        reliability=reliability(signals["cost"], model_label),
        early_warning=early_warning(signals["fear"], violation, episode, dt),
    )
    if curve_episodes > 0:
        report.curve = operating_curve(
            run,
            make_env,
            curve_episodes,
            curve_scales,
            max_steps,
            gate_settings,
            cpus=curve_cpus,
            address=curve_address,
        )
    return report
