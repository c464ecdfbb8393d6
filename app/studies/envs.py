"""What a ``--scenario`` string means to each simulator, for the headless commands (train, eval, compare).

Each simulator names its variants differently: the UGV takes ``scenario=1..4`` (or a YAML file), highway a
``split`` of its logged pool (or one ``scenario_id``), SUMO a ``route`` and whether special vehicles drive.
This module turns the command line's scenario string into ``sims.make`` keyword arguments, so a run records
the string (``RunConfig.scenarios``) and evaluation rebuilds the same env from it.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import gymnasium as gym

DEFAULT_SCENARIO: dict[str, str] = {"ugv": "1", "highway": "train", "sumo": "c1"}
"""The scenario a command uses when none is given: UGV field test 1, the highway train split, SUMO phase C1."""

SUMO_SCENARIOS: dict[str, dict[str, Any]] = {
    "c1": {"route": 1, "special_vehicles": False},
    "c2": {"route": 2, "special_vehicles": True},
    "1": {"route": 1, "special_vehicles": False},
    "2": {"route": 2, "special_vehicles": False},
}
"""SUMO scenario names: the route-shift phases (c1: route 1; c2: route 2 with special vehicles) or a bare route."""

HIGHWAY_SPLITS = ("train", "test", "all")


def default_scenario(sim: str) -> str:
    return DEFAULT_SCENARIO.get(sim, "1")


def scenario_kwargs(sim: str, scenario: str) -> dict[str, Any]:
    """``sims.make(sim, **scenario_kwargs(sim, scenario))`` builds that scenario; a clear error for a bad name."""
    name = scenario.strip()
    if sim == "highway":
        if name in HIGHWAY_SPLITS:
            return {"split": name}
        if name.isdigit():
            return {"scenario_id": int(name)}
        splits = ", ".join(HIGHWAY_SPLITS)
        raise ValueError(f"highway scenario {scenario!r}: give a split ({splits}) or a pool id 0-499")
    if sim == "sumo":
        if name.lower() in SUMO_SCENARIOS:
            return dict(SUMO_SCENARIOS[name.lower()])
        raise ValueError(
            f"sumo scenario {scenario!r}: choose {', '.join(SUMO_SCENARIOS)} "
            "(c1: route 1; c2: route 2 with special vehicles; 1 / 2: the bare route)"
        )
    return {"scenario": int(name) if name.isdigit() else name}


def env_factory(sim: str, **fixed: Any) -> Callable[[str], gym.Env[Any, Any]]:
    """``make_env(scenario)`` for :class:`core.train.Trainer` and :func:`core.train.evaluate`.

    ``fixed``: more keyword arguments for every env (e.g. ``mode="adversarial"``).
    """
    import sims

    if sim not in sims.SIMULATORS:
        raise ValueError(f"unknown simulator {sim!r}; choose one of {', '.join(sims.SIMULATORS)}")

    def make_env(scenario: str) -> gym.Env[Any, Any]:
        kwargs = {**scenario_kwargs(sim, scenario), **fixed}
        try:
            return sims.make(sim, **kwargs)
        except TypeError as exc:  # the simulator's constructor does not take what was given
            raise ValueError(f"cannot build simulator {sim!r} with {kwargs}: {exc}") from None

    return make_env
