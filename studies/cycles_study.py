"""The continual-adaptation study (the paper's field test, Fig. field_test_1): ``sage study cycles``.

Deploy → takeover → fine-tune cycles (:func:`studies.cycles.run_cycles`, the live server's own fine-tuning round)
against a control that deploys the same starting policy through the same situations with the same gate and
expert but never fine-tunes:

- ``sage``: after every cycle the policy is fine-tuned on what the session recorded (takeover segments through
  value-weighted imitation, its own transitions through the fear-regularised critic) and the next cycle deploys
  the new version;
- ``frozen``: the control, no fine-tuning.

Both start from ``policy`` (default ``policies/ugv-default``) on ``scenario`` (default UGV 3, the crossing, where the
starting policy alone collides), ``episodes_per_cycle`` episodes per cycle; the training seed picks the situations
(episode seeds) and the fine-tuning's randomness. The budget sets the number of cycles: one per 600 environment
steps of the budget, 2 to 9 (the paper's field test ran 9). The table reports, per method, mean ± 95% interval over
seeds: the takeover rate, collision and success rates of the first and the last cycle, and the change in takeover
rate. The paper shows this study as curves, so no numbers stand beside.
"""

from __future__ import annotations

import shutil
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from studies.budgets import Budget
from studies.registry import StudyDef

METHODS = ("frozen", "sage")
STEPS_PER_CYCLE = 600
DEFAULT_POLICY = Path(__file__).resolve().parents[1] / "policies" / "ugv-default"
METRICS = (
    "takeover_first",
    "takeover_last",
    "takeover_change",
    "collision_first",
    "collision_last",
    "success_first",
    "success_last",
)


def cycles_for(train_steps: int) -> int:
    return max(2, min(9, train_steps // STEPS_PER_CYCLE))


def budget_text(budget: Budget, settings: Mapping[str, Any]) -> str:
    """What a budget runs here: cycles of episodes, not training steps and evaluation episodes."""
    cycles = cycles_for(budget.train_steps)
    episodes = int(settings.get("episodes_per_cycle", 3))
    return (
        f"{cycles} cycles of {episodes} episodes per method and seed: one cycle per {STEPS_PER_CYCLE} of its "
        f"{budget.train_steps} environment steps, 2 to 9; no separate evaluation episodes"
    )


def trial(config: dict[str, Any]) -> dict[str, float]:
    """One method on one seed: the cycles (resumable: a finished folder is read back), first and last cycle."""
    from studies.cycles import CyclesConfig, read_cycles, run_cycles
    from studies.envs import env_factory

    method, seed = str(config["method"]), int(config["seed"])
    sim = str(config.get("sim", "ugv"))
    out = Path(config["runs_dir"]) / f"{method}-s{seed}"
    if not (out / "cycles.json").is_file():
        shutil.rmtree(out, ignore_errors=True)
        cfg = CyclesConfig(
            sim=sim,
            scenario=str(config.get("scenario", "3")),
            policy=str(config.get("policy", DEFAULT_POLICY)),
            cycles=cycles_for(int(config["train_steps"])),
            episodes_per_cycle=int(config.get("episodes_per_cycle", 3)),
            seed=1000 * seed,
            fine_tune=method != "frozen",
        )
        run_cycles(cfg, out, env_factory(sim))
    rows = read_cycles(out)["cycles"]
    first, last = rows[0], rows[-1]

    def value(row: dict[str, Any], key: str) -> float:
        return float(row[key] or 0.0)

    return {
        "takeover_first": value(first, "takeover_rate"),
        "takeover_last": value(last, "takeover_rate"),
        "takeover_change": value(last, "takeover_rate") - value(first, "takeover_rate"),
        "collision_first": value(first, "collision"),
        "collision_last": value(last, "collision"),
        "success_first": value(first, "success"),
        "success_last": value(last, "success"),
        "cycles": float(len(rows)),
    }


STUDY = StudyDef(
    name="cycles",
    methods=METHODS,
    trial=trial,
    metrics=METRICS,
    plot=("takeover_last", "collision_last"),
    notes=(
        "Both methods deploy the same starting policy with its SAGE gate and the scripted expert through the same "
        "situations each cycle; sage fine-tunes between cycles on what was recorded (the live server's round), "
        f"frozen never does. Cycles: one per {STEPS_PER_CYCLE} environment steps of the budget, 2 to 9.",
        "first / last: the first and the last cycle (the first is the same policy for both methods). Collisions end "
        "the episode. The paper shows this study as curves (Fig. field_test_1), so no paper numbers stand beside.",
    ),
    settings={"sim": "ugv", "scenario": "3", "policy": str(DEFAULT_POLICY), "episodes_per_cycle": 3},
    learner_overrides=False,
    budget_text=budget_text,
)
