"""The long-tail study (the paper's Fig. carla_1, issue #12): D3QN against SAGE-D3QN on the occluded pedestrian.

Protocol. Each method learns from scratch on the crossing scenario (a pedestrian steps out from in front of a
parked truck, hidden from the lidar until late; ``sims.pedestrian``), for the same number of environment steps
(the study budget), on each training seed:

- ``d3qn``: double Q-learning with a dueling network, ε-greedy exploration, no expert;
- ``sage-d3qn``: the same network and budget, with the world model on one-hot actions, fear over the horizon
  under the greedy policy, the curiosity threshold and the gate handing control to the expert, fear-regularised
  targets with -c* on collisions, and ω-weighted margin imitation of takeover actions.

The expert is the simulator's scripted cautious driver (it sees the pedestrian and never collides). The paper's
was trained by HG-DAgger; ``sage study pedestrian --set expert=hg-dagger`` trains one (``hg-dagger-discrete``) from
the scripted driver's demonstrations and corrections, once per results folder, caches it in
``<results>/experts/hg-dagger`` (:func:`prepare`) and takes over through it. Measured at the small budget
(results/pedestrian-small-hgdagger), that learned expert drives the crossing almost always safely on its own but
not as a takeover expert, handed control mid-episode: SAGE-D3QN then collided more than D3QN while learning. So it
is not the default.
Every collision is terminal for every method (the simulator ends the episode).

Evaluation: the learned policy alone (greedy, no gate, no expert) on ``eval_episodes`` crossing episodes with
seeds disjoint from training. The table reports, per method, mean ± 95% interval over seeds: the collision rate
during training (the paper's claim: SAGE's is lower), its early and late thirds, the expert's share of training
steps, and the evaluation's success, collision, time-to-collision, speed and acceleration variability. The
figures are the paper's panels: (b) training reward over episodes, (c) trajectory snapshots early, middle and late
in training, (d) time-to-collision, speed, acceleration variability and collisions over training episodes.
The paper reports these as curves only, so there are no paper numbers beside the table.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from studies.pedestrian_figures import read_rows, write_figures
from studies.registry import StudyDef

__all__ = ["METHODS", "METRICS", "STUDY", "figures", "read_rows", "trial"]

METHODS = ("d3qn", "sage-d3qn")
TRAIN_SCENARIO = "crossing"
CHECKPOINT_EVERY = 10
"""Training episodes between the checkpoints that the trajectory snapshots (panel c) replay."""
METRICS = (
    "train_collision_rate",
    "train_collision_early",
    "train_collision_late",
    "train_takeover_rate",
    "eval_success",
    "eval_collision",
    "eval_min_ttc",
    "eval_avg_speed",
    "eval_acc_std",
)


def run_folder(config: dict[str, Any]) -> Path:
    return Path(config["runs_dir"]) / f"{config['method']}-s{int(config['seed'])}"


def trial(config: dict[str, Any]) -> dict[str, float]:
    """Train one method on one seed within the budget, evaluate it alone, return the table's metrics.

    Resumable: a run folder that already holds a finished run is evaluated again, not retrained; a half-written
    one (a crash) is cleared and trained afresh."""
    from core.agents import load_agent
    from core.train import evaluate
    from studies.envs import env_factory
    from studies.spec import TrainSpec
    from studies.training import train_once

    out = train_once(
        TrainSpec(
            sim="pedestrian",
            scenario=str(config.get("scenario", TRAIN_SCENARIO)),
            method=str(config["method"]),
            seed=int(config["seed"]),
            train_steps=int(config["train_steps"]),
            checkpoint_every=int(config.get("checkpoint_every", CHECKPOINT_EVERY)),
            overrides=list(config.get("overrides", [])),
            expert=config.get("expert_run") if str(config["method"]).startswith("sage") else None,
            out=str(run_folder(config)),
        ),
        config,
    )
    rows = read_rows(out)
    if not rows:
        raise RuntimeError(f"{out}: no training episode within {config['train_steps']} steps")
    collisions = np.array([float(r.get("collision", 0.0)) for r in rows])
    third = max(1, len(rows) // 3)
    steps = sum(int(r["steps"]) for r in rows)
    result: dict[str, float] = {
        "train_collision_rate": float(collisions.mean()),
        "train_collision_early": float(collisions[:third].mean()),
        "train_collision_late": float(collisions[-third:].mean()),
        "train_takeover_rate": sum(int(r.get("takeovers", 0)) for r in rows) / max(steps, 1),
        "train_episodes": float(len(rows)),
    }
    agent = load_agent(out)
    episodes = int(config["eval_episodes"])
    scenario = str(config.get("scenario", TRAIN_SCENARIO))
    evaluated = evaluate(agent.policy, env_factory("pedestrian"), [scenario], episodes, int(config["seed"]), None,
                         False, progress=False)[scenario]  # fmt: skip
    for key in ("success", "collision", "min_ttc", "avg_speed", "acc_std"):
        result[f"eval_{key}"] = float(np.mean([float(r[key]) for r in evaluated]))
    return result


EXPERT_DEMOS = 20
EXPERT_EPISODES = 60


def prepare(out: Path, settings: dict[str, Any]) -> dict[str, Any]:
    """The study's expert (:mod:`studies.experts`): the scripted driver, an HG-DAgger policy (``hg-dagger``, trained
    as ``hg-dagger-discrete``) or a discrete RL learner (``d3qn``), trained on the study's scenario once and cached
    in ``out/experts/<expert>``; measured alone on that scenario for the note under the table."""
    from studies.experts import study_expert
    from studies.registry import PREPARED_NOTES

    scenario = str(settings.get("scenario", TRAIN_SCENARIO))
    run, note = study_expert(
        str(settings.get("expert", "scripted")),
        out,
        "pedestrian",
        scenario,
        evaluate_on=[scenario],
        episodes=int(settings["eval_episodes"]),
        scripted_label="the scripted cautious driver",
        demo_episodes=EXPERT_DEMOS,
        expert_steps=int(settings.get("expert_steps", 0)),
        imitation_method="hg-dagger-discrete",
        imitation_episodes=EXPERT_EPISODES,
    )
    return {"expert_run": run, PREPARED_NOTES: [note]}


def figures(out: Path, settings: dict[str, Any]) -> list[Path]:
    """The paper's panels (b)-(d) from the run folders under ``out/runs``."""
    return write_figures(
        Path(settings["runs_dir"]), out, settings.get("methods", METHODS), str(settings.get("scenario", TRAIN_SCENARIO))
    )


STUDY = StudyDef(
    name="pedestrian",
    methods=METHODS,
    trial=trial,
    metrics=METRICS,
    plot=("train_collision_rate", "eval_collision", "eval_min_ttc"),
    notes=(
        f"Both methods learn from scratch on the {TRAIN_SCENARIO} scenario with the same budget in environment "
        "steps (expert-driven steps count); every collision ends the episode for every method.",
        "SAGE-D3QN's expert: the scripted cautious driver by default (expert=scripted); with expert=hg-dagger a "
        f"policy trained by HG-DAgger from its labels ({EXPERT_DEMOS} demonstrations, {EXPERT_EPISODES} episodes), "
        "cached in experts/hg-dagger, as the paper's. D3QN has no expert.",
        "Evaluation: the learned policy alone, greedy, on crossing episodes with seeds disjoint from training.",
        "The paper reports this study as curves (Fig. carla_1), so no paper numbers stand beside the table.",
    ),
    settings={"scenario": TRAIN_SCENARIO, "checkpoint_every": CHECKPOINT_EVERY, "expert": "scripted"},
    prepare=prepare,
    figures=figures,
)
