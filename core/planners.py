"""Planners and baselines that are not learners, by name: selectable as the policy or as the expert.

A planner is built for one environment (``factory(env) -> Policy``): it may read what the simulator exposes
through its protocol (the scripted expert reads the privileged scene; a local planner such as TEB reads only
what the robot senses). Wherever a run folder or checkpoint names a policy (``sage eval``, the dashboard's
policy picker) a planner name may stand instead, and ``sage train --expert NAME`` makes it the expert.

    register_planner("teb", TebPlanner, title="TEB local planner", sims=("ugv",))
    policy = make_planner("scripted", env)
    planner_names("ugv")                                   # those that can drive the UGV

``scripted`` (the simulator's own scripted expert, :class:`core.experts.ExpertPolicy`) is built in and
drives every simulator.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np

from core.experts import ExpertPolicy
from core.protocol import Actor, Policy

PlannerFactory = Callable[[gym.Env[Any, Any]], Policy]


@dataclass(frozen=True)
class PlannerEntry:
    name: str
    factory: PlannerFactory
    title: str
    """What the policy picker shows."""
    sims: tuple[str, ...] | None = None
    """The simulators it can drive (None: every one)."""

    def drives(self, sim: str | None) -> bool:
        return sim is None or self.sims is None or sim in self.sims


_PLANNERS: dict[str, PlannerEntry] = {
    "scripted": PlannerEntry("scripted", ExpertPolicy, "scripted expert (no gate)"),
}


def register_planner(
    name: str, factory: PlannerFactory, title: str = "", sims: tuple[str, ...] | None = None, replace: bool = False
) -> None:
    """Add planner ``name``; a taken name is an error unless ``replace``."""
    if not name or "/" in name or name.endswith(".pt"):
        raise ValueError(f"a planner name must be a plain word, not a path: {name!r}")
    if name in _PLANNERS and not replace:
        raise ValueError(f"planner {name!r} is already registered (pass replace=True to override it)")
    _PLANNERS[name] = PlannerEntry(name, factory, title or name, sims)


def unregister_planner(name: str) -> None:
    if name == "scripted":
        raise ValueError("the scripted expert is built in")
    _PLANNERS.pop(name, None)


def is_planner(name: str) -> bool:
    return str(name) in _PLANNERS


def planners(sim: str | None = None) -> list[PlannerEntry]:
    """The registered planners that can drive ``sim`` (all of them when None)."""
    return [entry for entry in _PLANNERS.values() if entry.drives(sim)]


def planner_names(sim: str | None = None) -> list[str]:
    return [entry.name for entry in planners(sim)]


def planner_entry(name: str) -> PlannerEntry:
    try:
        return _PLANNERS[str(name)]
    except KeyError:
        raise ValueError(f"unknown planner {name!r}; registered: {', '.join(_PLANNERS)}") from None


def make_planner(name: str, env: gym.Env[Any, Any], sim: str | None = None) -> Policy:
    """Planner ``name`` built for ``env`` (``sim``: refuse a planner that cannot drive that simulator)."""
    return checked_entry(name, sim).factory(env)


def checked_entry(name: str, sim: str | None) -> PlannerEntry:
    """Planner ``name``'s entry, refusing a planner that cannot drive ``sim``."""
    entry = planner_entry(name)
    if not entry.drives(sim):
        raise ValueError(f"planner {name!r} drives {', '.join(entry.sims or ())}, not {sim}")
    return entry


class PlannerExpert:
    """A planner as the expert (:class:`core.loop.Expert`): built for each env it is asked to drive."""

    def __init__(self, name: str, sim: str | None = None) -> None:
        planner_entry(name)  # fail early on an unknown name
        self.name, self.sim = name, sim
        self._built: dict[int, Policy] = {}

    def reset(self) -> None:
        pass

    def wants_control(self) -> bool:
        return False

    def act(self, env: gym.Env[Any, Any], obs: np.ndarray) -> tuple[np.ndarray, Actor]:
        policy = self._built.get(id(env))
        if policy is None:
            policy = self._built[id(env)] = make_planner(self.name, env, self.sim)
        return np.asarray(policy.act(obs, deterministic=True)), "expert"
