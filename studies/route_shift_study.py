"""The route-shift study (the paper's Fig. sumo_1): ``sage study route-shift``.

Protocol, the same for every method on every training seed (:class:`studies.route_shift.RouteShift` by steps):

- **Budget**: ``train_steps`` environment steps, demonstrations included; phase C1 (route 1, ordinary traffic) takes
  the first ``C1_SHARE`` of the interaction steps (the budget left after the demonstrations), phase C2 (route 2 with
  special vehicles) the rest, C1's last episode cut where its steps end, so that every method gets the same steps
  in each phase (the paper: 1,000 + 500 episodes, the same 2:1 ratio).
- **Demonstrations**: ``demo_episodes`` expert episodes on route 1 (the same for every method on a seed), at most
  ``DEMO_SHARE`` of the budget, cloned before interaction by every method.
- **Terminal rule**: every violation (collision, red light) is terminal for learning (the buffer cuts the return
  there), for every method; a collision also ends the episode, a red-light run does not (the car drives on).
- **Methods**: ``sac`` (the paper's standard RL), ``fni-rl`` (fear-regularised, no expert) and ``sage`` (the gate
  hands control to the expert), the paper's three.
- **Experts** (setting ``expert``, :mod:`studies.experts`): ``sumo``, SUMO's own driver model on both routes (the
  stated stand-in; the executed action is the label); ``hg-dagger``, one policy per route trained by HG-DAgger from
  SUMO's driver; or an RL learner's name (``sac``, ``sage``, ...), one policy per route trained by reinforcement
  learning for the budget's ``expert_steps``, as the paper's separately trained per-route policies. Route 1's
  supervises C1, route 2's C2; learned experts are trained once per results folder and cached in
  ``<results>/experts/<expert>/route1`` and ``route2``. Each expert's own success and collision rates on its route
  are measured and printed under the table.

The table reports, per method, mean ± 95% interval over seeds: success, collision and red-light rates of the last
third of C1 (stable?), the first third of C2 (the drop) and the last third of C2 (recovered?), the expert's share of
steps in C2 (overall, in its first and last third, and their per-seed change: falling as the policy adapts?), the
change in collisions from C2's first to its last third, and the final policy alone on each route (``eval_episodes``
each); :func:`studies.route_shift.shift_metrics` computes the training ones. The paper shows this study as curves,
so no numbers stand beside; ``learning_curves.png`` draws ours.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from studies.registry import StudyDef

METHODS = ("sac", "fni-rl", "sage")
C1_SHARE = 2 / 3
DEMO_EPISODES = 5
DEMO_SHARE = 0.5
"""The demonstrations take at most this share of the step budget (the last one cut there), so that a small
budget still leaves C1 and C2 to learn in; at the small budget the 5 demonstrations take about a third."""
EXPERT_DEMOS = 10
EXPERT_EPISODES = 20
PHASE_KEYS = ("success", "collision", "red_light")
METRICS = (
    *(f"c1_late_{k}" for k in PHASE_KEYS),
    *(f"c2_early_{k}" for k in PHASE_KEYS),
    *(f"c2_late_{k}" for k in PHASE_KEYS),
    "c2_takeover_rate",
    "c2_takeover_early",
    "c2_takeover_late",
    "c2_takeover_change",
    "c2_collision_change",
    "eval_route1_success",
    "eval_route2_success",
    "eval_route2_collision",
)


def trial(config: dict[str, Any]) -> dict[str, float]:
    """Train one method on one seed through the route shift (resumable), then evaluate it alone on both routes."""
    from core.agents import load_agent
    from core.train import evaluate
    from studies.envs import env_factory
    from studies.route_shift import read_run, shift_metrics
    from studies.spec import TrainSpec
    from studies.training import train_once

    method, seed = str(config["method"]), int(config["seed"])
    budget = int(config["train_steps"])
    demos = int(config.get("demo_episodes", DEMO_EPISODES))
    out = train_once(
        TrainSpec(
            sim="sumo",
            protocol="route-shift",
            method=method,
            seed=seed,
            train_steps=budget,
            c1_share=C1_SHARE,
            demo_episodes=demos,
            demo_steps=max(1, int(DEMO_SHARE * budget)),
            expert=config.get("expert_c1"),
            expert_c2=config.get("expert_c2"),
            checkpoint_every=0,
            out=str(Path(config["runs_dir"]) / f"{method}-s{seed}"),
        ),
        config,
    )
    run = read_run(out)
    result: dict[str, float] = {
        "train_episodes": float(len(run.rows)),
        "c2_episodes": float(len(run.rows) - run.switch),
    }
    result.update(shift_metrics(run))
    policy = load_agent(out).policy
    episodes = int(config["eval_episodes"])
    evaluated = evaluate(policy, env_factory("sumo"), ["c1", "c2"], episodes, seed, None, False, progress=False)
    result["eval_route1_success"] = float(np.mean([float(r["success"]) for r in evaluated["c1"]]))
    result["eval_route2_success"] = float(np.mean([float(r["success"]) for r in evaluated["c2"]]))
    result["eval_route2_collision"] = float(np.mean([float(r["collision"]) for r in evaluated["c2"]]))
    return result


def prepare(out: Path, settings: dict[str, Any]) -> dict[str, Any]:
    """The experts of phases C1 and C2 (:mod:`studies.experts`): SUMO's driver, or one learned policy per route
    (trained once, cached), each measured alone on its route for the note under the table. The two routes' experts
    train and are measured at once, as Ray tasks (each in its own process: libsumo runs one simulation per
    process)."""
    from studies.experts import study_expert
    from studies.registry import PREPARED_NOTES
    from studies.sweep import run_tasks

    choice = str(settings.get("expert", "sumo"))
    routes = (("route1", "c1"), ("route2", "c2"))
    calls = [
        {
            "choice": choice,
            "out": out,
            "sim": "sumo",
            "scenario": scenario,
            "name": route,
            "evaluate_on": [scenario],
            "episodes": int(settings["eval_episodes"]),
            "scripted_label": "SUMO's driver",
            "demo_episodes": EXPERT_DEMOS,
            "expert_steps": int(settings.get("expert_steps", 0)),
            "imitation_episodes": EXPERT_EPISODES,
            "aliases": ("sumo",),
        }
        for route, scenario in routes
    ]
    results = run_tasks(study_expert, calls, labels=[f"{choice} expert on {route}" for route, _ in routes])
    experts = {f"expert_{scenario}": run for (_, scenario), (run, _) in zip(routes, results, strict=True)}
    return {**experts, PREPARED_NOTES: [note for _, note in results]}


def figures(out: Path, settings: dict[str, Any]) -> list[Path]:
    from studies.learning_curves import write_learning_curves

    methods = settings.get("methods", METHODS)
    return write_learning_curves(Path(settings["runs_dir"]), out, methods, ("success", "collision", "red_light"))


STUDY = StudyDef(
    name="route-shift",
    methods=METHODS,
    trial=trial,
    metrics=METRICS,
    plot=("c2_early_success", "c2_late_collision", "eval_route2_success"),
    notes=(
        f"Every method: the same budget in environment steps, the same {DEMO_EPISODES} expert demonstrations on "
        f"route 1 per seed (counted, at most {DEMO_SHARE:.0%} of the budget) cloned before interaction; C1 (route 1) "
        f"takes the first {C1_SHARE:.0%} of the interaction steps, C2 (route 2 with special vehicles) the rest. "
        "Every violation (collision, red light) is terminal for learning for every method; a collision ends the "
        "episode, a red-light run does not.",
        "sage gets the expert through the SAGE gate; sac and fni-rl have none after the demonstrations. The expert "
        "is the setting expert: sumo (default: SUMO's driver model, its executed action the label), hg-dagger "
        f"(one policy per route, {EXPERT_DEMOS} demonstrations + {EXPERT_EPISODES} episodes each) or an RL learner's "
        f"name, e.g. sac (one policy per route, {EXPERT_DEMOS} demonstrations cloned, then the budget's "
        "expert_steps); learned experts are cached in experts/<expert>/route1 and route2, route 1's supervises C1, "
        "route 2's C2.",
        "c1_late / c2_early / c2_late: the last third of C1's episodes, the first and the last third of C2's. "
        "c2_takeover_early / c2_takeover_late: the expert's share of the steps of C2's first and last third of "
        "episodes; c2_takeover_change and c2_collision_change: late minus early, per seed, so that their ± is the "
        "95% interval of a paired difference (negative: falling over C2). –: does not apply (a method that never "
        "hands over has no takeover share; no C2 episodes, or fewer than two for a change). eval_*: the final "
        "policy alone, deterministic, eval_episodes per route. The paper shows this study as curves (Fig. "
        "sumo_1), so no paper numbers stand beside; learning_curves.png draws ours over environment steps.",
    ),
    settings={"expert": "sumo", "demo_episodes": DEMO_EPISODES},
    prepare=prepare,
    figures=figures,
)
