"""The continual-adaptation study (the paper's field test, Fig. field_test_1): ``sage study cycles``.

Deploy → takeover → fine-tune cycles (:func:`studies.cycles.run_cycles`, the live server's own fine-tuning round)
against a control that deploys the same starting policy through the same situations with the same gate and
expert but never fine-tunes:

- ``sage``: after every cycle the policy is fine-tuned on what the session recorded (as fear-regularised SAGE
  whatever the base was trained as: takeover segments through value-weighted imitation, its own transitions and the
  base policy's own drives through the fear-regularised critic) and the next cycle deploys the new version;
- ``frozen``: the control, a policy never fine-tuned, evaluated the same way.

Both start from ``policy`` (default ``policies/ugv-default``) on ``scenario`` (default UGV 3, the crossing, where the
starting policy alone collides). The budget is stated in environment steps and is the same for both methods: its
``train_steps`` are the deployment steps of a seed, split into ``cycles_for(train_steps)`` cycles (one per
:data:`STEPS_PER_CYCLE` steps, 2 to 9; the paper's field test ran 9) of exactly ``train_steps // cycles`` steps each
(the last episode of a cycle cut at it). Its ``eval_episodes`` are the policy-alone episodes of every cycle, on the
scenario and on an unseen one of the same kind (UGV 4 for 3). The training seed picks the situations (episode
seeds) and the fine-tuning's randomness.

The table reports, per method, mean ± 95% interval over seeds: the policy ALONE (no gate, no expert) in the first
and the last cycle, on the cycle's scenario and on the unseen one; takeover rate and collisions under supervision in
the first and the last cycle; the change in takeover rate; the number of cycles with more supervised collisions
than the first; and forgetting: the first and the last cycle's version (the frozen control's is the starting policy
in both) alone on the static scenarios (``static_scenarios``; UGV 1 and 2, no movers, which the starting policy
solves; none for a simulator without them), the same ``eval_episodes`` and seeds as the other alone evaluations,
success averaged over the static scenarios (per scenario in the run folder's ``static.json``). The paper shows this
study as curves, so no numbers stand beside; the figure ``cycles_improvement.png`` draws alone success and takeover
over the cycles.
"""

from __future__ import annotations

import dataclasses
import json
import math
import shutil
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from studies.budgets import Budget
from studies.registry import StudyDef

METHODS = ("frozen", "sage")
STEPS_PER_CYCLE = 600
DEFAULT_POLICY = Path(__file__).resolve().parents[1] / "policies" / "ugv-default"
METRICS = (
    "alone_success_first",
    "alone_success_last",
    "unseen_success_first",
    "unseen_success_last",
    "takeover_first",
    "takeover_last",
    "takeover_change",
    "collision_first",
    "collision_last",
    "collision_cycles_above_first",
    "static_success_first",
    "static_success_last",
    "static_success_change",
)
#: The static scenarios of each simulator (no movers; the starting policy solves them): the policy alone there after
#: the cycles says whether fine-tuning on the crossing forgot them. A simulator not named here has none.
STATIC_SCENARIOS: dict[str, tuple[str, ...]] = {"ugv": ("1", "2")}
STATIC_FILE = "static.json"


def static_scenarios_of(settings: Mapping[str, Any]) -> tuple[str, ...]:
    """The static scenarios a trial measures: ``static_scenarios`` (comma-separated names), "" for the simulator's
    own (:data:`STATIC_SCENARIOS`: UGV 1 and 2), "none" for none."""
    given = settings.get("static_scenarios", "") or ""
    names = [str(n) for n in given] if isinstance(given, list | tuple) else str(given).split(",")
    names = [n.strip() for n in names if n.strip()]
    if [n.lower() for n in names] == ["none"]:
        return ()
    return tuple(names) if names else STATIC_SCENARIOS.get(str(settings.get("sim", "ugv")), ())


def cycles_for(train_steps: int) -> int:
    """Cycles a budget of ``train_steps`` deployment steps buys: one per :data:`STEPS_PER_CYCLE`, 2 to 9."""
    return max(2, min(9, train_steps // STEPS_PER_CYCLE))


def steps_per_cycle(train_steps: int) -> int:
    """Deployment steps of every cycle: the budget split evenly over :func:`cycles_for` cycles."""
    return max(1, train_steps // cycles_for(train_steps))


def cycles_above_first(rows: list[dict[str, Any]], key: str) -> int:
    """How many cycles after the first have a higher ``key`` than the first (e.g. supervised collisions: the
    issue's "no cycle with more supervised collisions than the first", which first and last alone do not show)."""
    if not rows:
        return 0
    first = float(rows[0].get(key) or 0.0)
    return sum(float(row.get(key) or 0.0) > first for row in rows[1:])


def budget_text(budget: Budget, settings: Mapping[str, Any]) -> str:
    """What a budget runs here: cycles of deployment steps, and the versions alone on the evaluation episodes."""
    from studies.cycles import unseen_of

    cycles = cycles_for(budget.train_steps)
    sim, scenario = str(settings.get("sim", "ugv")), str(settings.get("scenario", "3"))
    unseen = str(settings.get("unseen_scenario", "")) or unseen_of(sim, scenario) or "none"
    static = static_scenarios_of(settings)
    statics = (
        f"; the first and the last cycle's version alone on {budget.eval_episodes} episodes of each static scenario "
        f"({', '.join(static)})"
        if static
        else ""
    )
    return (
        f"{cycles} cycles of {steps_per_cycle(budget.train_steps)} deployment steps per method and seed "
        f"({budget.train_steps} environment steps) on {sim} scenario {scenario}; each cycle's version alone on "
        f"{budget.eval_episodes} evaluation episodes of the scenario and of an unseen one ({unseen}){statics}"
    )


def trial(config: dict[str, Any]) -> dict[str, float]:
    """One method on one seed: the cycles (resumable: a finished folder is read back), first and last cycle."""
    from core.finetune import FinetuneConfig
    from studies.cycles import CyclesConfig, read_cycles, run_cycles
    from studies.envs import env_factory
    from studies.training import LEARNER_OVERRIDES

    method, seed = str(config["method"]), int(config["seed"])
    sim = str(config.get("sim", "ugv"))
    out = Path(config["runs_dir"]) / f"{method}-s{seed}"
    if not (out / "cycles.json").is_file():
        shutil.rmtree(out, ignore_errors=True)
        budget = int(config["train_steps"])
        cfg = CyclesConfig(
            sim=sim,
            scenario=str(config.get("scenario", "3")),
            unseen_scenario=str(config.get("unseen_scenario", "")) or None,
            policy=str(config.get("policy", DEFAULT_POLICY)),
            cycles=cycles_for(budget),
            steps_per_cycle=steps_per_cycle(budget),
            alone_episodes=int(config["eval_episodes"]),
            seed=1000 * seed,
            fine_tune=method != "frozen",
            # the training seed seeds the rounds' sampling too (it was 0 for every seed: on a field whose episodes do
            # not vary with the episode seed, five seeds were one run five times); finetune.seed still wins
            # sage study cycles --set learner.KEY=VALUE: edits of every round's learner configuration, after SAGE's
            # switches (FinetuneConfig.overrides), the same for every seed
            finetune=dataclasses.replace(
                FinetuneConfig(min_steps=1, min_takeover_samples=0, seed=seed).with_settings(
                    config.get("finetune", ())
                ),
                overrides=tuple(str(pair) for pair in config.get(LEARNER_OVERRIDES, ())),
            ),
            max_episode_steps=config.get("max_episode_steps"),
            promotion=promotion_of(config),
            coach_share=float(config.get("coach_share", 0.0)),
            expert=str(config.get("expert", "scripted")),
        )
        run_cycles(cfg, out, env_factory(sim))
    run = read_cycles(out)
    rows = run["cycles"]
    first, last = rows[0], rows[-1]
    static = static_alone(
        out,
        [int(first["version"]), int(last["version"])],
        static_scenarios_of(config),
        env_factory(sim),
        episodes=int(config["eval_episodes"]),
        seed=int(run["config"].get("alone_seed", 9_000_000)),
        max_steps=config.get("max_episode_steps"),
    )

    def value(row: dict[str, Any], key: str) -> float:
        return float(row.get(key) or 0.0)

    return {
        "alone_success_first": value(first, "alone_success"),
        "alone_success_last": value(last, "alone_success"),
        "unseen_success_first": value(first, "unseen_success"),
        "unseen_success_last": value(last, "unseen_success"),
        "takeover_first": value(first, "takeover_rate"),
        "takeover_last": value(last, "takeover_rate"),
        "takeover_change": value(last, "takeover_rate") - value(first, "takeover_rate"),
        "collision_first": value(first, "collision"),
        "collision_last": value(last, "collision"),
        "collision_cycles_above_first": float(cycles_above_first(rows, "collision")),
        "static_success_first": static_success(static, int(first["version"])),
        "static_success_last": static_success(static, int(last["version"])),
        "static_success_change": static_success(static, int(last["version"]))
        - static_success(static, int(first["version"])),
        "cycles": float(len(rows)),
        "steps": float(sum(int(row["steps"]) for row in rows)),
    }


def static_alone(
    out: Path,
    versions: list[int],
    scenarios: tuple[str, ...],
    make_env: Callable[[str], Any],
    episodes: int,
    seed: int,
    max_steps: int | None,
) -> list[dict[str, Any]]:
    """The run folder's ``versions`` alone (deterministic, no gate, no expert) on each static scenario, ``episodes``
    seeds from ``seed`` (the alone evaluations' seeds, apart from deployment): one row per version and scenario,
    each pair measured once and kept in ``out/static.json`` (a finished trial reads it back)."""
    from core.versions import VersionStore
    from studies.cycles import drive_alone_rates

    path = Path(out) / STATIC_FILE
    kept: list[dict[str, Any]] = []
    if path.is_file():
        loaded = json.loads(path.read_text())
        if loaded.get("episodes") == episodes and loaded.get("seed") == seed and loaded.get("max_steps") == max_steps:
            kept = list(loaded.get("rows", []))
    done = {(int(r["version"]), str(r["scenario"])) for r in kept}
    store = VersionStore(Path(out) / "versions")
    for version in dict.fromkeys(versions):
        for scenario in scenarios:
            if (version, scenario) in done:
                continue
            rates = drive_alone_rates(store.get(version).path, make_env, scenario, episodes, seed, max_steps)
            kept.append({"version": version, "scenario": scenario, **rates})
            done.add((version, scenario))
    payload = {"episodes": episodes, "seed": seed, "max_steps": max_steps, "rows": kept}
    path.write_text(json.dumps(payload, indent=2) + "\n")
    return [r for r in kept if int(r["version"]) in versions and str(r["scenario"]) in scenarios]


def static_success(rows: list[dict[str, Any]], version: int) -> float:
    """A version's alone success averaged over the static scenarios (NaN without any: not measured)."""
    values = [float(r["success"]) for r in rows if int(r["version"]) == version]
    return sum(values) / len(values) if values else math.nan


def promotion_of(settings: Mapping[str, Any]) -> Any:
    """The promotion a trial's versions must pass before they drive (:class:`core.promotion.PromotionConfig`), or
    None (the default: every version drives). ``promotion``: the live worker's supervised tests beside the version
    in control; ``regression_scenarios``: the regression test, each version alone on those scenarios no worse than
    ``v0000`` (``regression_against="control"``: than the version in control); either one switches promotion on,
    and a rejected version is not deployed."""
    from core.promotion import PromotionConfig

    supervised = bool(settings.get("promotion", False))
    regression = tuple(str(s) for s in settings.get("regression_scenarios", ()) or ())
    if not supervised and not regression:
        return None
    max_steps = settings.get("max_episode_steps") or PromotionConfig().max_steps
    return PromotionConfig(
        supervised=supervised,
        regression_scenarios=regression,
        max_steps=max_steps,
        regression_against=str(settings.get("regression_against", "base")),  # type: ignore[arg-type]
    )


def check_settings(settings: Mapping[str, Any]) -> None:
    """The scenario and the unseen one must be names the simulator knows, and differ (a procedural field such as
    ``ugv-fields:test:7`` is a scenario like UGV 3; it has no built-in unseen one, so the study is given one with
    ``unseen_scenario``); a ValueError of one line otherwise, before any trial."""
    from studies.cycles import expert_problem, unseen_of
    from studies.envs import scenario_kwargs

    sim = str(settings.get("sim", "ugv"))
    scenario = str(settings.get("scenario", "3"))
    unseen = str(settings.get("unseen_scenario", "")) or unseen_of(sim, scenario)
    regression = [("regression_scenarios", str(name)) for name in settings.get("regression_scenarios", ()) or ()]
    static = [("static_scenarios", name) for name in static_scenarios_of(settings)]
    for key, name in (("scenario", scenario), ("unseen_scenario", unseen), *regression, *static):
        if not name:
            continue
        try:
            scenario_kwargs(sim, name)
        except (ValueError, OSError) as error:  # the descriptor's own message, as one line
            raise ValueError(f"--set study.{key}={name}: {str(error).splitlines()[0]}") from None
    if unseen == scenario:
        raise ValueError(f"--set study.unseen_scenario={unseen}: the unseen scenario must differ from the scenario")
    share = float(settings.get("coach_share", 0.0))
    if not 0.0 <= share <= 1.0:
        raise ValueError(f"--set study.coach_share={share}: a share of the agent's steps, from 0 to 1")
    expert = str(settings.get("expert", "scripted"))
    problem = expert_problem(sim, expert, share)
    if problem is not None:
        raise ValueError(f"--set study.expert={expert}: {problem}")
    from core.promotion import REGRESSION_REFERENCES

    against = str(settings.get("regression_against", "base"))
    if against not in REGRESSION_REFERENCES:
        raise ValueError(f"--set study.regression_against={against}: base (v0000) or control (the version in control)")
    from core.agents import resolve_checkpoint

    policy = str(settings.get("policy", DEFAULT_POLICY))
    try:
        resolve_checkpoint(policy)
    except (FileNotFoundError, ValueError) as error:
        raise ValueError(f"--set study.policy={policy}: {str(error).splitlines()[0]}") from None


def prepare(out: Path, settings: dict[str, Any]) -> dict[str, Any]:
    """The starting policy as an absolute path: the trials run in their own folders (Ray's working directory), where
    a path given relative to where the study was started would name nothing."""
    return {"policy": str(Path(str(settings.get("policy", DEFAULT_POLICY))).resolve())}


def figures(out: Path, settings: dict[str, Any]) -> list[Path]:
    """Alone success (the scenario and the unseen one) and takeover over the cycles, mean over seeds per method."""
    from studies.cycles import read_cycles
    from studies.cycles_figures import improvement, save

    runs: dict[str, list[dict[str, Any]]] = {}
    for folder in sorted(Path(settings["runs_dir"]).glob("*-s*")):
        if (folder / "cycles.json").is_file():
            method = folder.name.rsplit("-s", 1)[0]
            runs.setdefault(method, []).append(read_cycles(folder))
    if not runs:
        return []
    return [save(improvement(runs), Path(out) / "cycles_improvement.png")]


STUDY = StudyDef(
    name="cycles",
    methods=METHODS,
    trial=trial,
    metrics=METRICS,
    plot=("alone_success_last", "takeover_last"),
    notes=(
        "Both methods deploy the same starting policy with its SAGE gate and the scripted expert through the same "
        "situations each cycle; sage fine-tunes between cycles on what was recorded (the live server's round, "
        "fear-regularised SAGE whatever the base was trained as), frozen never does. The budget's environment "
        f"steps are the deployment steps of a seed: one cycle per {STEPS_PER_CYCLE} of them (2 to 9), each cycle "
        "exactly budget / cycles steps, the same for both methods.",
        "alone: the cycle's version with no gate and no expert, deterministic, on the budget's evaluation episodes "
        "of the cycle's scenario (seeds apart from deployment) and of an unseen scenario of the same kind (UGV 4 for "
        "UGV 3). takeover and collision: under supervision, over the cycle's deployment steps. first / last: the first "
        "and the last cycle (the first is the same policy for both methods). collision_cycles_above_first: the cycles "
        "after the first whose supervised collision rate is above the first's. Collisions end the episode. The paper "
        "shows this study as curves (Fig. field_test_1), so no paper numbers stand beside.",
        "static: forgetting, the first and the last cycle's version alone (no gate, no expert, deterministic) on the "
        "static scenarios (UGV 1 and 2 by default, no movers; study setting static_scenarios), the budget's "
        "evaluation episodes of each on the alone evaluations' seeds; success averaged over the static scenarios "
        "(each in the run folder's static.json); static_success_change = last - first (the first is the starting "
        "policy; frozen's last is too).",
        "coach_share (study setting, default 0: takeovers only, the paper's protocol): on that share of the steps "
        "the agent drives, the scripted expert's action is recorded as a coaching label and imitated by the rounds, "
        "never executed (core.experts.CoachingExpert; a person steering along at the dashboard); the frozen control "
        "gets the same coach, which it never learns from. takeover counts the expert's driving only.",
        "expert (study setting, default scripted: the simulator's privileged expert, which knows where the movers will "
        "go): who takes over when the gate fires, for both methods; a planner's name (teb on the UGV) takes over from "
        "the robot's own sensing, as a person must.",
    ),
    settings={
        "sim": "ugv",
        "scenario": "3",
        "unseen_scenario": "",
        "policy": str(DEFAULT_POLICY),
        "finetune": (),
        "promotion": False,
        "regression_scenarios": (),
        "regression_against": "base",
        "static_scenarios": "",
        "coach_share": 0.0,
        "expert": "scripted",
    },
    check_settings=check_settings,
    prepare=prepare,
    learner_overrides=True,
    budget_text=budget_text,
    figures=figures,
)
