"""The gate's operating point: the target of the gate table (GateTarget) and ``sage gate choose-scale``'s choice of
``gate.tau_scale`` on the training scenarios (choose_tau_scale)."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal, TypedDict

import gymnasium as gym

from core.agents import load_agent
from core.loop import TAKEOVER_CAUSES
from core.metrics import wilson_interval
from studies.calibrate._gated_runs import run_gated


@dataclass(frozen=True)
class GateTarget:
    """Issue #11's target for the gate with the scripted expert on a scenario: a violation in at most
    ``violation_share`` of the episodes (1 of 20), at a takeover rate of at most ``takeover_rate``."""

    violation_share: float = 0.05
    takeover_rate: float = 0.35

    def met(self, violations: int, episodes: int, takeover_rate: float) -> bool:
        """Whether a measured row meets the target as read (its point estimates)."""
        if episodes <= 0:
            raise ValueError("a gate row needs at least one episode")
        return violations <= self.violation_share * episodes and takeover_rate <= self.takeover_rate

    def decided(self, violations: int, episodes: int) -> Literal["under", "over", "undecided"]:
        """What the row's episodes can tell about its violation share: ``"under"`` (the 95% Wilson interval lies
        at or under the target's share), ``"over"`` (wholly above it) or ``"undecided"`` (it straddles it: more
        episodes would be needed to say)."""
        low, high = wilson_interval(violations, episodes)
        if high <= self.violation_share:
            return "under"
        if low > self.violation_share:
            return "over"
        return "undecided"


DEFAULT_SCALES: tuple[float, ...] = (1.0, 0.7, 0.5, 0.35, 0.25)
"""Candidate values of ``gate.tau_scale`` for :func:`choose_tau_scale`, about equal ratios apart: none above 1, so that
the choice only ever lowers τ from the bounds the fear of familiar states set (asks for help earlier). A higher τ
buys less takeover with safety, judged on a few hundred training episodes that may not hold the danger met later:
that trade is the user's, who may pass larger scales."""


@dataclass
class ScaleChoice:
    """What :func:`choose_tau_scale` measured and chose."""

    run: str
    sim: str
    scenarios: list[str]
    episodes: int
    target: GateTarget
    rows: list[dict[str, Any]]
    """One per (scale, scenario) driven: ``scale``, ``scenario``, ``violations`` (episodes with one),
    ``episodes``, ``takeover_rate`` and its parts by why the expert drove (``takeover_<cause>``), ``met``."""
    scale: float
    """The chosen ``gate.tau_scale``: where none met the target, the run's own, unchanged."""
    met: bool
    """Whether the chosen scale met the target on every scenario (False: none did, and the run's scale stays)."""
    gate_settings: dict[str, Any] = field(default_factory=dict)
    """The gate settings every row ran with over the run's own (``tau_scale`` apart): a choice holds with them
    only, so deploying it sets them too (:meth:`deploy_settings`)."""

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    def deploy_settings(self) -> dict[str, Any]:
        """The gate settings to deploy the choice with: those the rows ran with, and the chosen scale."""
        return {**self.gate_settings, "tau_scale": self.scale}

    def summary(self) -> str:
        t = self.target
        lines = [
            f"{self.run} on {self.sim} {', '.join(self.scenarios)}: gate + scripted expert, {self.episodes} episodes "
            f"per scenario and scale; target: a violation in at most {t.violation_share:.0%} of the episodes at "
            f"most {t.takeover_rate:.0%} takeover, on every scenario"
            + ("; gate " + ", ".join(f"{k}={v}" for k, v in self.gate_settings.items()) if self.gate_settings else ""),
            "",
            "| tau_scale | scenario | episodes with a violation (95% interval) | takeover rate "
            "| why the expert drove: fear over τ · hold · hysteresis · manoeuvre (% of steps) | target |",
            "|---|---|---|---|---|---|",
        ]
        for r in self.rows:
            low, high = wilson_interval(int(r["violations"]), int(r["episodes"]))
            # rows saved before the parts were measured have none
            parts = " · ".join(
                f"{100 * r[f'takeover_{c}']:.0f}" if f"takeover_{c}" in r else "–" for c in TAKEOVER_CAUSES
            )
            lines.append(
                f"| {r['scale']:g} | {r['scenario']} | {r['violations']}/{r['episodes']} ({low:.0%}-{high:.0%}) | "
                f"{r['takeover_rate']:.1%} | {parts} | {'met' if r['met'] else 'missed'} |"
            )
        lines.append("")
        if self.met:
            lines.append(
                f"chosen: gate.tau_scale={self.scale:g}, the largest scale that met the target on every scenario"
            )
        else:
            lines.append(
                f"no scale met the target on every scenario: the run's own gate.tau_scale={self.scale:g} stays (the "
                "rows say what each would give)"
            )
        return "\n".join(lines)


class _ScaledGateCall(TypedDict):
    """The keyword arguments of one :func:`scaled_gate_row` call."""

    run: str | Path
    scenario: str
    make_env: Callable[[], gym.Env[Any, Any]]
    episodes: int
    gate_kwargs: dict[str, Any]
    target: GateTarget
    max_steps: int | None


def scaled_gate_row(
    run: str | Path,
    scenario: str,
    make_env: Callable[[], gym.Env[Any, Any]],
    episodes: int,
    gate_kwargs: Mapping[str, Any],
    target: GateTarget,
    max_steps: int | None = None,
) -> dict[str, Any]:
    """One row of :func:`choose_tau_scale`: the policy with its gate (``gate_kwargs``, ``tau_scale`` among them)
    and the scripted expert on ``scenario``; a Ray task of its own where the rows run at once."""
    agent = load_agent(run)
    point = run_gated(agent, make_env, agent.make_gate(**gate_kwargs), episodes, max_steps)
    violations = round(point["violation_rate"] * episodes)
    return {
        "scale": float(gate_kwargs["tau_scale"]),
        "scenario": scenario,
        "violations": violations,
        "episodes": episodes,
        "takeover_rate": point["takeover_rate"],
        **{f"takeover_{cause}": point[f"takeover_{cause}"] for cause in TAKEOVER_CAUSES},
        "met": target.met(violations, episodes, point["takeover_rate"]),
    }


def choose_tau_scale(
    run: str | Path,
    make_envs: Mapping[str, Callable[[], gym.Env[Any, Any]]],
    episodes: int,
    scales: Sequence[float] = DEFAULT_SCALES,
    target: GateTarget = GateTarget(),
    *,
    sim: str = "",
    max_steps: int | None = None,
    gate_settings: Mapping[str, Any] | None = None,
    on_row: Callable[[dict[str, Any]], None] | None = None,
    cpus: int | None = None,
    address: str | None = None,
) -> ScaleChoice:
    """The gate's operating point for a risk target, chosen on the given scenarios (those the policy was trained
    on: the choice is then judged on others): ``gate.tau_scale`` multiplies τ's bounds, and this drives the policy
    with its own gate at each candidate scale and the scripted expert, as the product runs, ``episodes`` per
    scenario on the evaluation seeds.

    The largest scale (the least takeover) that meets ``target`` as read on every scenario is chosen. Where none
    does, nothing is chosen: the run's own scale stays (``met`` False), since a trade between violations and
    takeover beyond the target is the user's to make, from the rows. Scales are absolute values of ``tau_scale``,
    replacing the run's own.

    In this process the scales are driven largest first and the sweep stops at the first that meets the target;
    ``on_row`` sees each row as it is measured (a sweep of a few hundred episodes takes minutes). With ``cpus`` or
    ``address`` every (scale, scenario) row runs at once as a Ray task (:func:`studies.sweep.run_tasks`, local Ray
    on ``cpus`` cores or the cluster at ``address``) and the same rule reads them all; ``on_row`` then sees them at
    the end.
    """
    if episodes < 1:
        raise ValueError("choosing a scale needs at least one episode per scenario")
    if not make_envs:
        raise ValueError("choosing a scale needs at least one scenario")
    candidates = sorted({float(s) for s in scales}, reverse=True)
    if not candidates or any(not (math.isfinite(s) and s > 0.0) for s in candidates):
        raise ValueError(f"scales must be finite numbers > 0, got {list(scales)}")
    agent = load_agent(run)
    settings = {k: v for k, v in (gate_settings or {}).items() if k != "tau_scale"}
    own_scale = agent.gate_config(**settings).tau_scale  # a setting the gate refuses stops here, before any episode
    calls: list[_ScaledGateCall] = [
        {
            "run": str(run),
            "scenario": scenario,
            "make_env": make_env,
            "episodes": episodes,
            "gate_kwargs": {**settings, "tau_scale": scale},
            "target": target,
            "max_steps": max_steps,
        }
        for scale in candidates
        for scenario, make_env in make_envs.items()
    ]
    rows: list[dict[str, Any]] = []
    if cpus is not None or address is not None:
        from studies.sweep import run_tasks

        labels = [f"tau_scale {c['gate_kwargs']['tau_scale']:g} on {c['scenario']}" for c in calls]
        rows = run_tasks(scaled_gate_row, calls, labels, address=address, cpus=cpus)
        for row in rows:
            if on_row is not None:
                on_row(row)
    else:
        for call in calls:
            rows.append(scaled_gate_row(**call))
            if on_row is not None:
                on_row(rows[-1])
            scale = rows[-1]["scale"]
            done = [r for r in rows if r["scale"] == scale]
            if len(done) == len(make_envs) and all(r["met"] for r in done):
                break  # the choice is the largest scale that meets the target: none below it can be chosen
    meeting = [s for s in candidates if _meets_everywhere(rows, s, len(make_envs))]
    chosen = meeting[0] if meeting else own_scale
    return ScaleChoice(str(run), sim, list(make_envs), episodes, target, rows, chosen, bool(meeting), dict(settings))


def _meets_everywhere(rows: Sequence[Mapping[str, Any]], scale: float, scenarios: int) -> bool:
    at = [r for r in rows if r["scale"] == scale]
    return len(at) == scenarios and all(r["met"] for r in at)
