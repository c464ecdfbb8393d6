"""The UGV field-test table (the paper's Table tab:all_scenarios_results): every method on scenarios 1-4.

Protocol. Every method that can use it starts from the same pretraining, the committed ``policies/ugv-default``
(trained on the static scenarios 1-2; actor, critics and world model), and adapts for the same number of
environment steps (the study budget) on scenarios 1-4 in turn:

- ``sac``, ``td3``: plain RL from the warm start, no expert;
- ``hg-dagger``: aggregated imitation of the scripted expert's takeovers (asked by the same SAGE gate);
- ``multi-hug``: human-guided SAC (:mod:`core.sage.multi_hug`): the supervisor steps in on its own judgement (the
  stand-in: when the safety cost reaches 0.5), corrective imitation and intervention reward shaping;
- ``sage``: fear-regularised SAC with the gate, the scripted expert and value-weighted imitation;
- ``diffusion-bc``, ``diffusion-ql`` (:mod:`core.sage.diffusion`): offline learners, so the budget buys them the
  scripted expert's demonstrations on scenarios 1-4 (the same environment steps), then offline training; a
  denoiser cannot start from the warm start's actor;
- ``teb``: the Timed-Elastic-Band local planner (:mod:`sims.ugv.teb`, sensing only), no training;
- ``scripted``: the simulator's scripted expert (privileged: it reads the layout and the movers' scripts), no
  training: a reference row.

Each learned policy is then evaluated alone (deterministic, no gate, no expert) on ``trials`` episodes of each
scenario with seeds disjoint from training: success rate, average speed, travel distance, path curvature and
lateral acceleration (the paper's columns) and the collision rate. Collisions end the episode for every method.
The paper's numbers are real-robot field tests, ours are the pymunk re-creation.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from studies.registry import StudyDef

METHODS = ("sac", "td3", "hg-dagger", "multi-hug", "diffusion-bc", "diffusion-ql", "teb", "sage", "scripted")
PLANNERS = ("teb", "scripted")
"""Rows that are planners, not learners: evaluated as they are, on every seed's evaluation episodes."""
OFFLINE = ("diffusion-bc", "diffusion-ql")
"""Offline learners: the budget buys them expert demonstrations instead of interaction."""
OFFLINE_STEPS = 4000
"""Offline gradient steps of the diffusion policies (fewer when the budget's environment steps are fewer)."""
SCENARIOS = ("1", "2", "3", "4")
WARM_START = Path(__file__).resolve().parents[1] / "policies" / "ugv-default"
TRIALS = 20
"""Evaluation episodes per scenario and method (the paper's 20 trials), unless the budget gives more (the smoke
budget gives fewer: ``min_eval_episodes`` raises every budget to this)."""
METRICS = (
    "success_rate_pct",
    "collision_rate_pct",
    "avg_speed",
    "travel_distance",
    "path_curvature",
    "lateral_acc",
)


def trial(config: dict[str, Any]) -> dict[str, float]:
    """Adapt one method on one seed (or take the scripted expert), evaluate it on every scenario, return the
    metrics as ``"<scenario>/<metric>"`` (the registry unpacks them into rows). Resumable like the pedestrian
    study's trials: a finished run folder is evaluated again."""
    import functools

    from core.agents import load_agent
    from core.planners import make_planner
    from core.train import evaluate
    from studies.envs import env_factory
    from studies.spec import TrainSpec
    from studies.training import train_once

    method, seed = str(config["method"]), int(config["seed"])
    scenarios = list(config.get("scenarios", SCENARIOS))
    if method in PLANNERS:
        policy: Any = functools.partial(make_planner, method, sim="ugv")
    else:
        spec = TrainSpec(
            sim="ugv",
            scenario=",".join(scenarios),
            method=method,
            seed=seed,
            train_steps=int(config["train_steps"]),
            init=None if method in OFFLINE else str(config.get("init", WARM_START)),
            checkpoint_every=0,
            out=str(Path(config["runs_dir"]) / f"{method}-s{seed}"),
        )
        if method in OFFLINE:  # demonstrations until the budget is spent, then offline training only
            offline_steps = min(OFFLINE_STEPS, int(config["train_steps"]))
            spec = spec.replace(
                demo_episodes=1_000_000, episodes=0, overrides=[f"diffusion.offline_steps={offline_steps}"]
            )
        out = train_once(spec, config)
        policy = load_agent(out).policy
    episodes = int(config["eval_episodes"])  # the budget's, raised to min_eval_episodes by the registry
    rows = evaluate(policy, env_factory("ugv"), scenarios, episodes, seed, None, False, progress=False)
    result: dict[str, float] = {}
    for scenario, episode_rows in rows.items():

        def mean(key: str, rows: list[dict[str, Any]] = episode_rows) -> float:
            return float(np.mean([float(r[key]) for r in rows]))

        result[f"{scenario}/success_rate_pct"] = 100.0 * mean("success")
        result[f"{scenario}/collision_rate_pct"] = 100.0 * mean("collision")
        for key in ("avg_speed", "travel_distance", "path_curvature", "lateral_acc"):
            result[f"{scenario}/{key}"] = mean(key)
    return result


def figures(out: Path, settings: dict[str, Any]) -> list[Path]:
    """Training success and collision against environment steps, for the methods that learn by interacting."""
    from studies.learning_curves import write_learning_curves

    online = [m for m in settings.get("methods", METHODS) if m not in PLANNERS and m not in OFFLINE]
    return write_learning_curves(Path(settings["runs_dir"]), out, online, ("success", "collision"))


STUDY = StudyDef(
    name="ugv",
    methods=METHODS,
    trial=trial,
    metrics=METRICS,
    keys=("scenario", "method"),
    plot=("success_rate_pct", "collision_rate_pct"),
    notes=(
        "Every online learner starts from policies/ugv-default (the same pretraining: static scenarios 1-2) and "
        "adapts on scenarios 1-4 in turn for the same budget in environment steps; collisions end the episode for "
        "every method. sage and hg-dagger get the scripted expert through the SAGE gate; multi-hug gets it when the "
        "stand-in supervisor steps in (safety cost >= 0.5, held 5 steps) with a 10-point intervention penalty; sac "
        "and td3 have none.",
        "diffusion-bc and diffusion-ql learn offline: the same budget in environment steps buys them the scripted "
        "expert's demonstrations on scenarios 1-4, then offline training: 4000 gradient steps (fewer if the budget "
        "is smaller), a 10-level cosine schedule, 5 DDIM sampling steps. A denoiser cannot start from the warm "
        "start's actor.",
        "teb: the Timed-Elastic-Band planner on the robot's own sensing (lidar costmap, odometry, goal), no "
        "training. scripted: the simulator's privileged scripted expert, untrained; a reference row the paper "
        "does not have.",
        "Evaluation: each learned policy alone, deterministic, 20 episodes per scenario (seeds disjoint from "
        "training). The paper's numbers are real-robot field tests; ours are the pymunk re-creation.",
    ),
    settings={"scenarios": list(SCENARIOS), "min_eval_episodes": TRIALS},
    untrained=PLANNERS,
    figures=figures,
)
