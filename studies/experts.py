"""The studies' experts in one home: which expert supervises a study's takeovers and drives its demonstrations,
how a learned one is trained and cached, and how well each drives on its own.

A study's ``expert`` setting chooses:

- ``scripted`` (route shift also says ``sumo``): the simulator's scripted expert, the stated stand-in;
- ``hg-dagger``: an imitation policy trained by HG-DAgger from the scripted expert's labels (the study names its
  recipe: demonstrations and interaction episodes; ``hg-dagger-discrete`` on a discrete-action simulator);
- the name of any other registered learner (``sac``, ``td3``, ``sage``, ``fni-rl``, ``d3qn``, ...): the paper's kind of
  expert, a policy trained by reinforcement learning, which first clones the study's expert demonstrations and
  then interacts for the budget's ``expert_steps`` environment steps;
- the path of a trained run folder or checkpoint, used as it is.

A learned expert is trained once per results folder, in ``<results>/experts/<choice>[/<name>]`` (one per route on
the route-shift study), and reused by every rerun (:func:`studies.training.train_once`). Whatever the choice, the
study measures the expert alone (deterministic, no gate, ``episodes`` per scenario, cached beside it in
``quality-<scenarios>.json``) and states it under its table: a study's takeovers are only as safe as its expert,
and an RL expert trained at a small budget is far weaker than a scripted one.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

SCRIPTED = ("scripted",)
"""The choices that mean the simulator's scripted expert."""
IMITATION = "hg-dagger"
"""The choice that means an imitation expert trained with the study's own HG-DAgger recipe."""
QUALITY_KEYS = ("success", "collision", "red_light", "violation")
"""Episode columns reported for an expert alone, where the simulator has them."""
SEED = 0
"""Training seed of every learned expert (an expert is one fixed policy per results folder, not a sweep)."""


def expert_kind(choice: str, aliases: Sequence[str] = ()) -> str:
    """``scripted``, ``imitation``, ``learner`` or ``run`` (a learner's name wins over a same-named folder); a clear
    error for an ``expert`` setting that is none of them."""
    from core.learners import learner_names

    if choice in SCRIPTED or choice in aliases:
        return "scripted"
    if choice == IMITATION:
        return "imitation"
    if choice in learner_names():
        return "learner"
    if Path(choice).exists():
        return "run"
    names = ", ".join([*SCRIPTED, *aliases, IMITATION, *(n for n in learner_names() if n != IMITATION)])
    raise ValueError(f"expert={choice}: give one of {names}, or the path of a trained run")


def check_choice(choice: str, aliases: Sequence[str] = ()) -> None:
    """A clear error for an ``expert`` setting that is neither scripted, a learner nor an existing run."""
    expert_kind(choice, aliases)


def expert_run(
    choice: str,
    out: Path,
    sim: str,
    scenario: str,
    *,
    name: str | None = None,
    demo_episodes: int,
    expert_steps: int,
    imitation_method: str = "hg-dagger",
    imitation_episodes: int = 20,
    aliases: Sequence[str] = (),
) -> str | None:
    """The expert run folder for ``choice`` trained on ``scenario`` (None: the scripted expert), trained now unless
    ``out/experts/<choice>[/<name>]`` already holds it.

    ``imitation_*``: the study's HG-DAgger recipe (``demo_episodes`` demonstrations, then that many episodes);
    any other learner gets ``demo_episodes`` demonstrations and ``expert_steps`` environment steps in all."""
    kind = expert_kind(choice, aliases)
    if kind == "scripted":
        return None
    if kind == "run":
        return str(Path(choice).resolve())
    from studies.spec import TrainSpec
    from studies.training import train_once

    if kind == "imitation":
        budget: dict[str, Any] = {"method": imitation_method, "episodes": imitation_episodes}
    else:
        if expert_steps <= 0:
            raise ValueError(f"expert={choice} is trained for the budget's expert_steps, which is {expert_steps}")
        budget = {"method": choice, "train_steps": expert_steps}
    spec = TrainSpec(
        sim=sim,
        scenario=scenario,
        demo_episodes=demo_episodes,
        seed=SEED,
        checkpoint_every=0,
        out=str(_folder(out, choice, name, aliases).resolve()),
        **budget,
    )
    return str(train_once(spec))


def _folder(out: Path, choice: str, name: str | None, aliases: Sequence[str] = ()) -> Path:
    """``out/experts/<choice>[/<name>]`` (``run`` for a run's path): where a learned expert and its numbers live."""
    folder = out / "experts" / ("run" if expert_kind(choice, aliases) == "run" else choice)
    return folder if name is None else folder / name


def study_expert(
    choice: str,
    out: Path,
    sim: str,
    scenario: str,
    *,
    evaluate_on: Sequence[str],
    episodes: int,
    scripted_label: str,
    name: str | None = None,
    **recipe: Any,
) -> tuple[str | None, str]:
    """What a study's ``prepare`` needs: the expert (:func:`expert_run`, ``recipe`` its keyword arguments) and the
    sentence for under the table saying how it drives alone on ``evaluate_on`` (:func:`expert_quality`)."""
    run = expert_run(choice, out, sim, scenario, name=name, **recipe)
    cache = quality_cache(out, choice, name, evaluate_on, recipe.get("aliases", ()))
    quality = expert_quality(run, sim, evaluate_on, episodes, cache)
    label = scripted_label if run is None else (choice if name is None else f"{choice}, trained on {name}")
    return run, quality_note(label, quality, episodes)


def expert_quality(
    expert: str | None,
    sim: str,
    scenarios: Sequence[str],
    episodes: int,
    cache: Path,
    **env_options: Any,
) -> dict[str, dict[str, float]]:
    """Per scenario, the expert alone (deterministic, no gate): the mean of each of :data:`QUALITY_KEYS` the
    simulator reports, over ``episodes`` evaluation episodes. Cached in ``cache`` (a json file) for the same
    expert, scenarios and episodes; ``env_options`` go to every env (e.g. ``mode="adversarial"``)."""
    key = {"expert": expert or "scripted", "scenarios": list(scenarios), "episodes": episodes, "env": env_options}
    if cache.is_file():
        try:
            stored = json.loads(cache.read_text())
            if stored.get("key") == key:
                return {s: {k: float(v) for k, v in m.items()} for s, m in stored["quality"].items()}
        except (OSError, ValueError, KeyError, AttributeError):
            pass  # an unreadable cache is measured again
    from core.planners import make_planner
    from core.train import evaluate, evaluate_run
    from studies.envs import env_factory

    make_env = env_factory(sim, **env_options)
    if expert is None:
        rows = evaluate(lambda env: make_planner("scripted", env, sim), make_env, scenarios, episodes, progress=False)
    else:
        rows = evaluate_run(expert, make_env, scenarios, episodes, progress=False)
    quality = {
        scenario: {k: sum(float(r[k]) for r in got) / len(got) for k in QUALITY_KEYS if got and k in got[0]}
        for scenario, got in rows.items()
    }
    cache.parent.mkdir(parents=True, exist_ok=True)
    cache.write_text(json.dumps({"key": key, "quality": quality}, indent=1))
    return quality


def quality_cache(
    out: Path, choice: str, name: str | None, scenarios: Sequence[str], aliases: Sequence[str] = ()
) -> Path:
    """Where :func:`expert_quality` keeps its numbers for this expert (beside it)."""
    return _folder(out, choice, name, aliases) / f"quality-{'-'.join(scenarios)}.json"


def quality_note(label: str, quality: dict[str, dict[str, float]], episodes: int) -> str:
    """One sentence for under a table: how the expert drives alone on each scenario."""
    parts = []
    for scenario, metrics in quality.items():
        values = ", ".join(f"{k.replace('_', ' ')} {100 * v:.0f}%" for k, v in metrics.items())
        parts.append(f"{scenario}: {values}")
    return f"The expert ({label}) alone, deterministic, {episodes} episodes per scenario: " + "; ".join(parts) + "."
