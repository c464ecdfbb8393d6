"""The paper's driving studies as protocols around the one training loop, and their figures and tables.

- :mod:`studies.envs`: what a ``--scenario`` string means to each simulator.
- :mod:`studies.highway`: CAT-style closed-loop adversarial training (an episode hook) and the paper's
  normal / adversarial evaluation table (issue 6).
- :mod:`studies.route_shift`: the SUMO route-shift protocol (an episode hook) and its run folders (issue 7).
- :mod:`studies.route_shift_figures`: the route-shift figure panels (matplotlib).

:func:`prepare_training` turns the ``sage train`` options into what :class:`core.train.Trainer` takes: the env
factory, the scenarios, the episode count and the episode hooks; :meth:`TrainingSetup.finish` writes the
study's outputs (``study.json``, figures) into the run folder.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym

from core.train import EpisodeHook
from studies.envs import default_scenario, env_factory

PROTOCOLS = ("none", "route-shift")
DEFAULT_EPISODES = 100
DEFAULT_ADVERSARIAL_RATIO = 0.5
"""Share of highway training episodes that are adversarial variants (the rest replay the logs)."""


@dataclass
class TrainingSetup:
    scenarios: list[str]
    make_env: Callable[[str], gym.Env[Any, Any]]
    episodes: int
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
        from studies.route_shift import phase_table, read_run
        from studies.route_shift_figures import write_figures

        run = read_run(out)
        paths = write_figures([run], out, window)
        return [phase_table([run]), *(f"figure: {path}" for path in paths)]


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
    adversarial_ratio: float | None = None,
) -> TrainingSetup:
    """What ``sage train`` runs for these options; a ValueError naming the option that does not fit."""
    protocol = protocol or "none"
    if protocol not in PROTOCOLS:
        raise ValueError(f"unknown protocol {protocol!r}; choose one of {', '.join(PROTOCOLS)}")
    if adversarial_ratio is not None and sim != "highway":
        raise ValueError("--adversarial-ratio is for --sim highway (closed-loop adversarial training)")
    if protocol != "route-shift" and (c1 is not None or c2 is not None or expert_c2 is not None):
        raise ValueError("--c1, --c2 and --expert-c2 belong to --protocol route-shift")
    make_env = env_factory(sim)
    if protocol == "route-shift":
        from studies.route_shift import DEFAULT_C1, DEFAULT_C2, RouteShift, policy_expert

        if sim != "sumo":
            raise ValueError(f"--protocol route-shift is the SUMO study; got --sim {sim}")
        if scenario is not None and scenario.strip().lower() != "c1":
            raise ValueError("--protocol route-shift sets the scenario itself (C1 then C2); drop --scenario")
        shift = RouteShift(
            DEFAULT_C1 if c1 is None else c1,
            DEFAULT_C2 if c2 is None else c2,
            policy_expert(expert_c2) if expert_c2 else None,
        )
        if episodes is not None and episodes != shift.episodes:
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
    return TrainingSetup(scenarios, make_env, DEFAULT_EPISODES if episodes is None else episodes, hooks, study)
