"""Measure a run's τ bounds again for another fear, and choose fear's β from data (``sage gate refit-bounds``).

A world model's τ bounds are quantiles of the fear of familiar states under the policy, measured at its fit
(:func:`core.sage.calibration.calibrate`). Fear is β ĉ + (1-β) σ̂, so a gate that weighs the parts otherwise (or looks
further ahead, or aggregates otherwise) needs the bounds measured again on its own fear: a gate loaded with such
a setting over the run's own is refused (:data:`core.agents.FEAR_SHAPE`). This module drives the run's policy
with no expert on the scenarios it was trained on, keeps the states as a fit keeps its buffer's
(:func:`core.sage.model_trainer.calibration_sample`: the familiar ones are those with no violation within all that fear
looks at), and sets κ and the τ bounds on them for the new settings. The world model's weights stay as they are.

β. The paper leaves β open ("controls the relative contribution of predicted cost and uncertainty"). With
``choose_beta`` the same drives choose it: each step's ĉ and σ̂ are recorded with the run's own gate watching, each
step is labelled "a violation within ``horizon_s``", and β is the candidate whose fear ranks those steps best
(the mean AUROC over the scenarios where the policy met a violation), ties to the candidate nearest the run's own.
The drives are on the training scenarios, where ĉ learned from violations, so the choice leans towards ĉ; σ̂ is
the part that speaks on ground the model never saw, which no training scenario shows. docs/calibration.md
measures the choice on scenarios and layouts it did not see.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch

from core.agents import (
    FEAR_SHAPE,
    FINAL_CHECKPOINT,
    load_agent,
    load_checkpoint,
    resolve_checkpoint,
    save_with_world_model,
)
from core.loop import NoGate, Runner, StepRecord
from core.metrics import auroc
from core.replay import ReplayBuffer
from core.sage.calibration import CALIBRATION_FILE
from core.sage.config import GateConfig
from core.sage.model_trainer import calibration_sample
from core.sage.world_model import EnsembleWorldModel
from studies.calibrate import labels_within

RECALIBRATION_FILE = "recalibration.json"
"""What a recalibrated folder was made from (run, scenarios, episodes, settings, bounds, β's scores)."""

BETA_CANDIDATES = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0)
"""The β that ``choose_beta`` scores."""

RECALIBRATION_SEED = 5_000_000
"""Episode seeds of the drives (seed + episode index per scenario block): apart from the evaluation's
(:data:`studies.calibrate.EVAL_SEED`), so that the states the bounds are set on are not the episodes that judge
them."""


def fitted_reference(world_model: EnsembleWorldModel, cfg: GateConfig) -> float | None:
    """The fixed curiosity reference a gate of ``cfg`` reads on this calibrated model; None for a moving average."""
    if cfg.curiosity_reference != "fitted":
        return None
    if cfg.curiosity_signal == "disagreement":
        return float(world_model.disagreement_ref)
    if cfg.curiosity_signal == "novelty":
        return float(world_model.novelty_ref)
    return float(world_model.curiosity_ref)


@dataclass
class Recalibration:
    """What :func:`recalibrate_run` measured and wrote."""

    run: str
    out: str
    scenarios: list[str]
    episodes: int
    steps: int
    violation_episodes: dict[str, int]
    """Per scenario, the episodes in which the policy met a violation."""
    calibration_states: int
    familiar_states: int
    settings: dict[str, Any]
    """The gate settings over the run's own (β among them when chosen)."""
    beta_before: float
    beta: float
    bounds_before: tuple[float, float]
    bounds: tuple[float, float]
    beta_auroc: dict[str, dict[str, float]] = field(default_factory=dict)
    """With ``choose_beta``: per scenario with a violation, fear's AUROC at each candidate β (keys as text)."""
    label_s: float = 1.0
    novelty_scenarios: list[str] = field(default_factory=list)
    """Scenarios driven only for the state novelty's reference set (beside ``scenarios``), not for the τ bounds."""
    kept_bounds: bool = False
    """κ and the τ bounds are the run's own (``keep_bounds``); only the curiosity's references were measured."""
    curiosity_reference: float | None = None
    """The fixed reference curiosity is read against (``gate.curiosity_reference=fitted``) as measured on these drives:
    the disagreement's or the state novelty's mean on the calibration states; None for the paper's moving average."""

    def as_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def summary(self) -> str:
        lines = [
            f"{self.run} -> {self.out}: {self.episodes} episodes a scenario on {', '.join(self.scenarios)} "
            f"({self.steps} steps; episodes with a violation: "
            + ", ".join(f"{s} {n}" for s, n in self.violation_episodes.items())
            + ")",
        ]
        if self.beta_auroc:
            lines.append(f"fear's AUROC for a violation within {self.label_s:g} s, by β:")
            for scenario, scores in self.beta_auroc.items():
                lines.append(f"  {scenario:>28}: " + " ".join(f"{b}:{v:.3f}" for b, v in scores.items()))
            mean = mean_auroc(self.beta_auroc)
            lines.append(f"  {'mean':>28}: " + " ".join(f"{b}:{v:.3f}" for b, v in mean.items()))
        lines.append(
            f"β {self.beta_before:g} -> {self.beta:g}; τ bounds {self.bounds_before[0]:.3f}-{self.bounds_before[1]:.3f}"
            f" -> {self.bounds[0]:.3f}-{self.bounds[1]:.3f} on {self.familiar_states} familiar of "
            f"{self.calibration_states} states"
        )
        if self.curiosity_reference is not None:
            signal = self.settings.get("curiosity_signal", "its")
            lines.append(f"curiosity ({signal}) read against its mean on these states: {self.curiosity_reference:.4f}")
        if self.kept_bounds:
            lines.append(
                "κ and the τ bounds kept as the run's own (fear unchanged): only curiosity's references measured"
            )
        if self.novelty_scenarios:
            lines.append(f"the novelty's reference set also holds the drives of {', '.join(self.novelty_scenarios)}")
        return "\n".join(lines)


def mean_auroc(per_scenario: Mapping[str, Mapping[str, float]]) -> dict[str, float]:
    """Each candidate's mean AUROC over the scenarios."""
    keys = next(iter(per_scenario.values())).keys()
    return {k: float(np.mean([scores[k] for scores in per_scenario.values()])) for k in keys}


def choose_beta(per_scenario: Mapping[str, Mapping[str, float]], current: float) -> float:
    """The candidate with the best mean AUROC (to 3 decimals: finer differences are sampling noise at any budget
    this runs at), ties to the one nearest ``current``."""
    mean = mean_auroc(per_scenario)
    best = max(round(v, 3) for v in mean.values())
    tied = [float(k) for k, v in mean.items() if round(v, 3) == best]
    return min(tied, key=lambda b: (abs(b - current), b))


def recalibrate_run(
    run: str | Path,
    make_env: Callable[[str], gym.Env[Any, Any]],
    scenarios: Sequence[str],
    episodes: int,
    out: str | Path,
    dt: float,
    *,
    gate_settings: Mapping[str, Any] | None = None,
    choose: bool = False,
    label_s: float = 1.0,
    max_steps: int | None = None,
    seed: int = RECALIBRATION_SEED,
    dtype: str = "float32",
    novelty_scenarios: Sequence[str] = (),
    keep_bounds: bool = False,
) -> Recalibration:
    """Write ``out``: ``run`` with its world model's κ and τ bounds measured again on ``episodes`` drives of the
    policy alone per scenario, for the gate with ``gate_settings`` over the run's own (and β chosen, with
    ``choose``). ``novelty_scenarios``: for a gate whose curiosity is state novelty, more scenarios driven the same
    way whose states join the novelty's reference set (familiar ground) but not the τ bounds (the drives of
    ``scenarios`` are in the set too). ``keep_bounds``: κ and the τ bounds stay the run's own (for settings that do
    not change fear, such as the curiosity signal: only its references are measured). Raises ValueError for a run
    without a world model, an ``out`` that holds a checkpoint, β both given and chosen, novelty scenarios for
    another curiosity, bounds kept for a setting that changes fear, or drives with too few familiar states."""
    settings = dict(gate_settings or {})
    if choose and "beta" in settings:
        raise ValueError("give β (--set gate.beta=...) or choose it (--choose-beta), not both")
    reshaped = sorted(set(settings) & set(FEAR_SHAPE))
    if keep_bounds and reshaped:
        raise ValueError(f"{', '.join(reshaped)} change fear itself: its κ and τ bounds must be measured again")
    if choose and reshaped:
        # β is scored on the parts of the run's own fear, which these settings change
        raise ValueError(
            f"--choose-beta scores β on the run's own fear, and {', '.join(reshaped)} change it: measure the bounds "
            "for them first (sage gate refit-bounds --set gate.…), then choose β on that run"
        )
    if episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}")
    if not scenarios:
        raise ValueError("name at least one scenario to drive (those the policy was trained on)")
    out = Path(out)
    file = resolve_checkpoint(run)
    if (out / FINAL_CHECKPOINT).exists():
        raise ValueError(f"{out} already holds a checkpoint; choose another out folder")
    agent = load_agent(file)
    if agent.world_model is None or not agent.has_world_model:
        raise ValueError(f"{run} has no trained world model: nothing to recalibrate")
    learner, world_model = agent.learner, agent.world_model
    before = agent.config.gate
    bounds_before = (float(world_model.tau_bounds[0]), float(world_model.tau_bounds[1]))
    records: list[StepRecord] = []
    label_steps = max(1, round(label_s / dt))
    scores: dict[str, dict[str, float]] = {}
    violation_episodes: dict[str, int] = {}
    extra = [s for s in novelty_scenarios if s not in scenarios]
    if extra and agent.gate_config(**settings).curiosity_signal != "novelty":
        raise ValueError("novelty scenarios set the state novelty's reference: give gate.curiosity_signal=novelty")
    bounds_records = 0
    for scenario in [*scenarios, *extra]:
        if extra and scenario == extra[0]:
            bounds_records = len(records)  # the drives from here on set only the novelty's reference
        env = make_env(scenario)
        # the run's own gate watches only to record ĉ and σ̂ (no expert: it changes no action)
        gate = agent.make_gate() if choose else NoGate()
        parts: list[tuple[int, float, float, bool]] = []

        def record(r: StepRecord, gate: Any = gate, parts: list[tuple[int, float, float, bool]] = parts) -> None:
            records.append(learner.encoded(r))
            detail = getattr(gate, "detail", None)
            cost, sigma = (detail.cost, detail.sigma) if detail is not None else (math.nan, math.nan)
            parts.append((r.episode, cost, sigma, bool(r.violation)))

        try:
            runner = Runner(env, agent.policy, gate, None, seed=seed, deterministic=True)
            runner.step_listeners.append(record)
            for _ in range(episodes):
                runner.run_episode(max_steps=max_steps)
        finally:
            env.close()
        violation_episodes[scenario] = len({e for e, _, _, v in parts if v})
        episode = np.array([p[0] for p in parts])
        violation = np.array([p[3] for p in parts])
        label = labels_within(violation, episode, label_steps)
        if choose and scenario not in extra and label.any() and not label.all():
            cost, sigma = np.array([p[1] for p in parts]), np.array([p[2] for p in parts])
            scores[scenario] = {str(b): auroc(b * cost + (1 - b) * sigma, label) for b in BETA_CANDIDATES}
    if choose:
        if not scores:
            raise ValueError(
                "the policy met no violation on these scenarios: no steps to rank, so no β to choose "
                "(drive more episodes, or scenarios where it meets danger)"
            )
        settings["beta"] = choose_beta(scores, before.beta)
    gate_cfg = agent.gate_config(**settings)
    reference_records = records
    records = records[:bounds_records] if extra else records
    buffer = ReplayBuffer(agent.meta.obs_dim, learner.model_action_dim, max(1, len(records)))
    for r in records:
        buffer.add_record(r)
    sample = calibration_sample(buffer, world_model, gate_cfg, np.random.default_rng(0))
    if int(sample.familiar.sum()) < 20:
        raise ValueError(f"the drives gave {int(sample.familiar.sum())} familiar states, too few to set the τ bounds")
    kept = (world_model.sigma_scale.clone(), world_model.tau_bounds.clone())
    sample.calibrate(world_model, learner.rollout_policy, gate_cfg)
    if keep_bounds:  # fear is unchanged: only the curiosity's references were wanted from these drives
        world_model.sigma_scale.copy_(kept[0])
        world_model.tau_bounds.copy_(kept[1])
        world_model.touch()
    bounds = (float(world_model.tau_bounds[0]), float(world_model.tau_bounds[1]))
    if not all(math.isfinite(b) for b in bounds):
        raise ValueError("the τ bounds came out undefined: too few familiar states")
    if extra:
        wide = ReplayBuffer(agent.meta.obs_dim, learner.model_action_dim, len(reference_records))
        for r in reference_records:
            wide.add_record(r)
        reference = calibration_sample(wide, world_model, gate_cfg, np.random.default_rng(0))
        motion = None if reference.motion is None else torch.from_numpy(reference.motion)
        world_model.set_novelty_reference(torch.from_numpy(reference.obs), motion)
    payload = load_checkpoint(file)
    agent_config = json.loads(json.dumps(payload["agent_config"]))
    agent_config["gate"] = json.loads(json.dumps(dataclasses.asdict(gate_cfg)))
    result = Recalibration(
        curiosity_reference=fitted_reference(world_model, gate_cfg),
        run=str(run),
        out=str(out),
        scenarios=list(scenarios),
        novelty_scenarios=extra,
        kept_bounds=keep_bounds,
        episodes=episodes,
        steps=len(buffer),
        violation_episodes=violation_episodes,
        calibration_states=len(sample),
        familiar_states=int(sample.familiar.sum()),
        settings=settings,
        beta_before=before.beta,
        beta=gate_cfg.beta,
        bounds_before=bounds_before,
        bounds=bounds,
        beta_auroc=scores,
        label_s=label_s,
    )
    provenance = {
        "recalibrated_from": str(run),
        "recalibration": {"scenarios": list(scenarios), **settings} | ({"novelty_scenarios": extra} if extra else {}),
    }
    save_with_world_model(payload, out, world_model, agent_config, provenance, dtype)
    sample.save(out / CALIBRATION_FILE)
    (out / RECALIBRATION_FILE).write_text(json.dumps(result.as_dict(), indent=2) + "\n")
    return result
