"""The adversarial-traffic study (the paper's Waymo table ``tab:test_results``): ``sage study highway``.

Protocol, the same for every method on every training seed:

- **Budget**: ``train_steps`` environment steps, demonstrations included (an episode that would pass it is cut).
- **Demonstrations and pretraining**: ``demo_episodes`` expert-driven episodes on the training split (the same
  episodes for every method on a seed), cloned into the actor and regressed into the critics before interaction.
  SAC and TD3 get them too: what sets the methods apart is only what they do afterwards.
- **Training**: closed-loop adversarial (CAT-style, :class:`studies.highway.ClosedLoopAdversary`): half of the
  training episodes resample opponents towards risk around the path the current policy drives.
- **Terminal rule**: every violation (a collision, leaving the road) ends the episode and is terminal for learning,
  for every method.
- **Methods**: ``sac``, ``td3``, ``fni-rl`` (fear-regularised, no expert) and ``sage`` (the gate hands control to the
  expert; value-weighted imitation), the paper's four rows.
- **Expert** (setting ``expert``, :mod:`studies.experts`): ``scripted``, the simulator's rule-based driver (the
  stated stand-in); ``hg-dagger``, a policy trained by HG-DAgger from the scripted driver's labels; an RL learner's
  name (``sac``, ...: the paper's kind, trained by reinforcement learning for the budget's ``expert_steps``), each
  trained once per results folder and cached in ``<results>/experts/<expert>``; or the path of any trained run (a
  converged RL policy trained with ``sage train`` at the scale it needs). The expert also drives the
  demonstrations; its own success and collision rates alone are printed under the table.
- **Evaluation**: the policy alone, deterministic, on the first ``eval_episodes`` scenarios of the training and the
  held-out test split, each in the normal (logged) and adversarial (opponents aimed at this policy) condition.

The table has the paper's rows (split × method × condition) with its numbers beside ours; ``learning_curves.png``
shows success and collision over training against environment steps for every method (is SAC competent yet?).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from studies.registry import StudyDef

METHODS = ("sac", "td3", "fni-rl", "sage")
METRICS = ("success_rate_pct", "collision_rate_pct", "speed_mps", "acceleration_mps2")
DEMO_EPISODES = 10
EXPERT_DEMOS = 20
EXPERT_EPISODES = 30


def trial(config: dict[str, Any]) -> dict[str, float]:
    """Train one method on one seed (resumable), evaluate it on both splits and conditions."""
    from core.agents import load_agent
    from studies.highway import evaluate_policy
    from studies.spec import TrainSpec
    from studies.training import train_once

    method, seed = str(config["method"]), int(config["seed"])
    out = train_once(
        TrainSpec(
            sim="highway",
            scenario="train",
            method=method,
            seed=seed,
            train_steps=int(config["train_steps"]),
            demo_episodes=int(config.get("demo_episodes", DEMO_EPISODES)),
            expert=config.get("expert_run"),
            checkpoint_every=0,
            out=str(Path(config["runs_dir"]) / f"{method}-s{seed}"),
        ),
        config,
    )
    policy = load_agent(out).policy
    results = evaluate_policy(
        policy, ("train", "test"), ("normal", "adversarial"), int(config["eval_episodes"]), (seed,)
    )
    metrics: dict[str, float] = {}
    for (split, condition), rows in results.items():

        def mean(key: str, rows: list[dict[str, Any]] = rows) -> float:
            return float(np.mean([float(r[key]) for r in rows]))

        prefix = f"{split}/{condition}/"
        metrics[prefix + "success_rate_pct"] = 100.0 * mean("success")
        metrics[prefix + "collision_rate_pct"] = 100.0 * mean("collision")
        metrics[prefix + "speed_mps"] = mean("speed_mean")
        metrics[prefix + "acceleration_mps2"] = mean("acc_mean")
    return metrics


def prepare(out: Path, settings: dict[str, Any]) -> dict[str, Any]:
    """The expert of takeovers and demonstrations (:mod:`studies.experts`): scripted, HG-DAgger or an RL learner
    (trained once and cached), or a run; measured alone on both splits for the note under the table."""
    from studies.experts import study_expert
    from studies.registry import PREPARED_NOTES

    run, note = study_expert(
        str(settings.get("expert", "scripted")),
        out,
        "highway",
        "train",
        evaluate_on=["train", "test"],
        episodes=int(settings["eval_episodes"]),
        scripted_label="the scripted driver",
        demo_episodes=EXPERT_DEMOS,
        expert_steps=int(settings.get("expert_steps", 0)),
        imitation_episodes=EXPERT_EPISODES,
    )
    return {"expert_run": run, PREPARED_NOTES: [note]}


def figures(out: Path, settings: dict[str, Any]) -> list[Path]:
    from studies.learning_curves import write_learning_curves

    return write_learning_curves(
        Path(settings["runs_dir"]), out, settings.get("methods", METHODS), ("success", "collision")
    )


STUDY = StudyDef(
    name="highway",
    methods=METHODS,
    trial=trial,
    metrics=METRICS,
    keys=("split", "method", "condition"),
    plot=("success_rate_pct", "collision_rate_pct"),
    notes=(
        f"Every method: the same budget in environment steps, the same {DEMO_EPISODES} expert demonstrations per "
        "seed (counted in the budget) cloned before interaction, closed-loop adversarial training (half the "
        "episodes). Every violation (collision, off road) ends the episode and is terminal for every method.",
        "sage gets the expert through the SAGE gate; sac, td3 and fni-rl have no expert after the demonstrations. "
        "The expert is the setting expert: scripted (default, the rule-based driver), hg-dagger (trained from it "
        f"with {EXPERT_DEMOS} demonstrations and {EXPERT_EPISODES} episodes), an RL learner's name, e.g. sac "
        f"(the paper's kind: {EXPERT_DEMOS} demonstrations cloned, then the budget's expert_steps), cached in "
        "experts/<expert>, or a trained run's path.",
        "Evaluation: the policy alone, deterministic, on the first eval_episodes scenarios of each split; "
        "adversarial opponents are aimed at the evaluated policy. learning_curves.png: training success and "
        "collision against environment steps.",
        "The paper's numbers are Waymo log replays with CAT adversaries over 400/100 scenarios; ours are the "
        "highway-env re-creation (sims/highway).",
    ),
    settings={"expert": "scripted", "demo_episodes": DEMO_EPISODES},
    prepare=prepare,
    figures=figures,
)
