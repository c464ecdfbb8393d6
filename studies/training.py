"""The composition root of a training run: :class:`TrainSpec` and :func:`run_training`.

``sage train`` is a thin adapter over them (its flags are the spec's fields, :mod:`app.cli.train`), and a
study sweep builds specs and calls :func:`run_training` in each Ray trial, with no shell in between. Every
default of a training run is written once, here.

The paper's driving studies are protocols around the one training loop:

- :mod:`studies.envs`: what a ``--scenario`` string means to each simulator.
- :mod:`studies.highway`: CAT-style closed-loop adversarial training (an episode hook) and the paper's
  normal / adversarial evaluation table (issue 6).
- :mod:`studies.route_shift`: the SUMO route-shift protocol (an episode hook) and its run folders (issue 7).
- :mod:`studies.route_shift_figures`: the route-shift figure panels (matplotlib).

:func:`prepare_training` turns a spec's protocol options into what :class:`core.train.Trainer` takes: the env
factory, the scenarios, the episode count and the episode hooks; :meth:`TrainingSetup.finish` writes the
study's outputs (``study.json``, figures) into the run folder.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import gymnasium as gym

from core.train import EpisodeHook, RunConfig, TrainResult
from studies.envs import default_scenario, env_factory, parse_env_overrides
from studies.spec import TrainSpec

__all__ = ["TrainOutcome", "TrainSpec", "TrainingSetup", "prepare_training", "run_training", "train_once"]

PROTOCOLS = ("none", "route-shift")
DEFAULT_EPISODES = 100
DEFAULT_ADVERSARIAL_RATIO = 0.5
"""Share of highway training episodes that are adversarial variants (the rest replay the logs)."""


@dataclass
class TrainingSetup:
    scenarios: list[str]
    make_env: Callable[[str], gym.Env[Any, Any]]
    episodes: int | None
    hooks: list[EpisodeHook] = field(default_factory=list)
    study: dict[str, Any] | None = None
    """Written to ``study.json`` in the run folder (protocol, phase lengths, experts)."""
    name: str | None = None
    """Short name for the default run folder (``route_shift``), else the scenarios."""

    def start(self, out: Path) -> None:
        """Before training: record the protocol in the run folder."""
        if self.study is not None:
            from studies.route_shift import write_study

            write_study(out, self.study)

    def finish(self, out: Path, window: int | None = None) -> list[str]:
        """After training: write the protocol's figures into the run folder; return what to print."""
        if self.study is None or self.study.get("protocol") != "route-shift":
            return []
        from studies.route_shift import RouteShift, phase_table, read_run, write_study
        from studies.route_shift_figures import write_figures

        for hook in self.hooks:
            if isinstance(hook, RouteShift) and hook.by_steps and self.study.get("switch_episode") is None:
                self.study.update(switch_episode=hook.switch_episode, c1_steps=hook.c1_steps)  # known now
                write_study(out, self.study)

        run = read_run(out)
        paths = write_figures([run], out, window)
        return [phase_table([run]), *(f"figure: {path}" for path in paths)]


@dataclass
class TrainOutcome:
    """What :func:`run_training` returns: the trainer's result, the run folder and the study's report lines."""

    result: TrainResult
    out: Path
    setup: TrainingSetup
    lines: list[str] = field(default_factory=list)
    """What the protocol has to say after training (a phase table, figure paths)."""


def default_out(spec: TrainSpec, setup: TrainingSetup) -> Path:
    stamp = time.strftime("%Y%m%d-%H%M%S")
    return Path("runs") / f"{spec.sim}-{setup.name or '_'.join(setup.scenarios)}-{spec.method}-s{spec.seed}-{stamp}"


def run_training(spec: TrainSpec, progress: bool = False) -> TrainOutcome:
    """Train as ``spec`` says and write its run folder; a ValueError names the option that does not fit.

    The learner's configuration is the method's preset (on a warm start: the hyperparameters of the run it
    starts from; a world-model-only refit: that run's own configuration) with ``spec.overrides`` applied.
    """
    import sims
    from core.agents import load_checkpoint
    from core.learners import preset
    from core.sage.config import apply_overrides, from_dict
    from core.train import Trainer

    base = from_dict(load_checkpoint(spec.init)["agent_config"]) if spec.init else None
    # a world-model-only refit keeps the policy's own config (its method, switches and schedule: a method preset
    # would turn off what the policy was trained with, e.g. imitation of takeovers when fine-tuned); only the
    # model is refitted, with the --set overrides
    if spec.world_model_only and base is not None:
        method, start = base.method, base
    else:
        method, start = spec.method, preset(spec.method, base=base)
    # the gate's hold may be given in seconds (gate.hold_seconds): the run records the step it is counted in; and
    # where its simulator's observation shows contact, the floors fear's imagined contact reads
    descriptor = sims.descriptor(spec.sim)
    start.gate = replace(start.gate, step_seconds=descriptor.dt, contact_floors=list(descriptor.contact_floors) or None)
    agent_cfg = apply_overrides(start, list(spec.overrides))
    env = parse_env_overrides(list(spec.env))
    setup = prepare_training(
        spec.sim,
        scenario=spec.scenario,
        protocol=spec.protocol,
        episodes=spec.episodes,
        seed=spec.seed,
        method=method,
        expert=spec.expert,
        expert_c2=spec.expert_c2,
        c1=spec.c1,
        c2=spec.c2,
        c1_share=spec.c1_share,
        adversarial_ratio=spec.adversarial_ratio,
        bounded_by_steps=spec.train_steps is not None,
        env=env,
    )
    out = Path(spec.out) if spec.out else default_out(spec, setup)
    if (out / "checkpoint.pt").exists():
        raise ValueError(f"{out} already holds a finished run; choose another out folder")
    run_cfg = RunConfig(
        sim=spec.sim,
        scenarios=setup.scenarios,
        episodes=setup.episodes,
        seed=spec.seed,
        init=spec.init,
        demo_episodes=spec.demo_episodes,
        demo_steps=spec.demo_steps,
        demo_noise=spec.demo_noise,
        checkpoint_every=spec.checkpoint_every,
        checkpoint_dtype=spec.checkpoint_dtype,
        max_episode_steps=spec.max_episode_steps,
        expert=spec.expert,
        demo_expert=spec.demo_expert,
        train_steps=spec.train_steps,
        datasets=list(spec.dataset),
        world_model_only=spec.world_model_only,
        refit_gated_share=spec.refit_gated_share,
        device=spec.device,
        env=env,
    )
    trainer = Trainer(run_cfg, agent_cfg, setup.make_env, out, progress, setup.hooks)
    notes: list[str] = []
    inherited = base is not None and base.world_model
    if inherited and trainer.learner.world_model is not None and "world_model" not in trainer.init_parts:
        # e.g. a refit that adds an input (--set world_model_config.approach_*) or learns over an ego step (ego_*):
        # the old weights cannot be read
        notes.append(
            f"note: the world model of --init {spec.init} does not fit this run's world_model_config (another input "
            "layout, size or ego step); this run fitted a new one on its own data"
        )
    try:
        setup.start(out)
        result = trainer.train()
    finally:
        trainer.close()
    return TrainOutcome(result, out, setup, notes + setup.finish(out))


STUDY_DEVICE = "device"
"""The study setting that carries ``sage study --device`` to every trial (resolved: ``cpu`` or ``cuda``)."""
LEARNER_OVERRIDES = "learner_overrides"
"""The study setting that carries ``sage study --set learner.KEY=VALUE`` to every trial: learner ``key=value``
overrides."""


def with_study_overrides(spec: TrainSpec, config: Mapping[str, Any]) -> TrainSpec:
    """``spec`` with the study's learner overrides (``sage study --set learner.KEY=VALUE``) after its own: an
    ablation of every method of a study at the same budgets, seeds and evaluation."""
    extra = [str(pair) for pair in config.get(LEARNER_OVERRIDES, ())]
    if extra:
        spec = spec.replace(overrides=[*spec.overrides, *extra])
    if STUDY_DEVICE in config:  # sage study --device: every trial's updates there
        spec = spec.replace(device=str(config[STUDY_DEVICE]))
    return spec


def check_learner_overrides(pairs: Sequence[str]) -> list[str]:
    """``pairs`` as ``key=value`` learner overrides, each checked on a default configuration (a ValueError names
    the one that does not fit), before any trial starts."""
    from core.sage.config import AgentConfig, apply_overrides

    checked = []
    for pair in pairs:
        try:
            apply_overrides(AgentConfig(), [pair])
        except (ValueError, TypeError, KeyError, AttributeError) as exc:
            raise ValueError(f"--set learner.{pair.strip()}: {exc}") from None
        checked.append(pair.strip())
    return checked


def train_once(spec: TrainSpec, study: Mapping[str, Any] | None = None) -> Path:
    """``spec``'s run folder, trained unless it already holds a finished run (a study's trial resumes, an expert is
    cached): a half-written folder (a crash) is cleared and trained afresh. ``study``: a trial's settings, whose
    learner overrides (:func:`with_study_overrides`) the run takes after ``spec``'s own."""
    if study is not None:
        spec = with_study_overrides(spec, study)
    if spec.out is None:
        raise ValueError("train_once needs spec.out, the folder to reuse")
    out = Path(spec.out)
    if not (out / "checkpoint.pt").is_file():
        import shutil

        shutil.rmtree(out, ignore_errors=True)
        run_training(spec)
    return out


def prepare_training(
    sim: str,
    *,
    scenario: str | None = None,
    protocol: str | None = None,
    episodes: int | None = None,
    seed: int = 0,
    method: str = "sage",
    expert: str | None = None,
    expert_c2: str | None = None,
    c1: int | None = None,
    c2: int | None = None,
    c1_share: float | None = None,
    adversarial_ratio: float | None = None,
    bounded_by_steps: bool = False,
    env: dict[str, Any] | None = None,
) -> TrainingSetup:
    """What a :class:`TrainSpec` runs for these options; a ValueError naming the option that does not fit.

    ``bounded_by_steps``: the run has an environment-step budget, so no episode count means "until the
    budget is spent" rather than the default count. ``env``: keyword arguments for every env's ``make()``
    (``--set env.KEY=VALUE``)."""
    protocol = protocol or "none"
    if protocol not in PROTOCOLS:
        raise ValueError(f"unknown protocol {protocol!r}; choose one of {', '.join(PROTOCOLS)}")
    if adversarial_ratio is not None and sim != "highway":
        raise ValueError("--adversarial-ratio is for --sim highway (closed-loop adversarial training)")
    if protocol != "route-shift" and (c1 is not None or c2 is not None or expert_c2 is not None or c1_share):
        raise ValueError("--c1, --c2, --c1-share and --expert-c2 belong to --protocol route-shift")
    make_env = env_factory(sim, **(env or {}))
    if protocol == "route-shift":
        from studies.route_shift import DEFAULT_C1, DEFAULT_C2, RouteShift, policy_expert

        if sim != "sumo":
            raise ValueError(f"--protocol route-shift is the SUMO study; got --sim {sim}")
        if scenario is not None and scenario.strip().lower() != "c1":
            raise ValueError("--protocol route-shift sets the scenario itself (C1 then C2); drop --scenario")
        if c1_share is not None:
            if c1 is not None or c2 is not None:
                raise ValueError("--c1-share switches by environment steps: drop --c1 and --c2")
            if not bounded_by_steps or not 0.0 < c1_share < 1.0:
                raise ValueError("--c1-share needs --train-steps (the whole run's budget) and must be in (0, 1)")
        shift = RouteShift(
            DEFAULT_C1 if c1 is None else c1,
            DEFAULT_C2 if c2 is None else c2,
            policy_expert(expert_c2) if expert_c2 else None,
            c1_share=c1_share,
        )
        if episodes is not None and shift.episodes is not None and episodes != shift.episodes:
            raise ValueError(f"--protocol route-shift runs --c1 + --c2 = {shift.episodes} episodes; drop --episodes")
        return TrainingSetup(
            ["c1"], make_env, shift.episodes, [shift], shift.describe(method, expert, expert_c2), "route_shift"
        )
    scenarios = [s.strip() for s in (scenario or default_scenario(sim)).split(",") if s.strip()]
    if not scenarios:
        raise ValueError("give at least one scenario, e.g. 3 or 1,2")
    hooks: list[EpisodeHook] = []
    study = None
    if sim == "highway":
        from studies.highway import ClosedLoopAdversary

        ratio = DEFAULT_ADVERSARIAL_RATIO if adversarial_ratio is None else adversarial_ratio
        hooks.append(ClosedLoopAdversary(ratio, seed))
        study = {"protocol": "closed-loop-adversarial", "adversarial_ratio": ratio, "predictor": "policy"}
    if episodes is None and not bounded_by_steps:
        episodes = DEFAULT_EPISODES
    return TrainingSetup(scenarios, make_env, episodes, hooks, study)
