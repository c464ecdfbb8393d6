"""Simulators, one package each, registered with gymnasium under the ``sage/`` namespace.

Each package provides a gymnasium ``Env`` whose ``unwrapped`` implements :class:`core.protocol.SimulatorEnv`
(``expert_action``, ``scene``, ``metrics``) and exports ``DESCRIPTOR`` (:class:`core.descriptor.SimDescriptor`):
env id, scenarios by name, control period, key mapping, metric columns, safe action, live options. Every other
layer reads the descriptor, so adding a simulator is one package plus one line in :data:`SIMULATORS`.

    env = sims.make("ugv", scenario="3")                 # a named scenario
    env = sims.make("sumo", scenario="c2", live=True)     # with the descriptor's live options
    sims.descriptor("highway").dt
"""

from __future__ import annotations

import importlib
from typing import Any

import gymnasium as gym

from core.descriptor import ScenarioNameError, SimDescriptor

SIMULATORS: dict[str, str] = {
    "ugv": "sims.ugv",
    "highway": "sims.highway",
    "sumo": "sims.sumo",
    "pedestrian": "sims.pedestrian",
}
"""Short name -> the package that exports its ``DESCRIPTOR`` (and registers its env on import)."""

PLANNERS: dict[str, tuple[str, str, tuple[str, ...]]] = {
    "teb": ("sims.ugv.teb:TebPlanner", "TEB local planner (sensing only)", ("ugv",)),
    "blind-movers": ("sims.ugv.expert:BlindExpertPolicy", "scripted expert blind to movers (no gate)", ("ugv",)),
}
"""Planners the simulators bring (:mod:`core.planners`): name -> (``module:factory``, title, simulators). Registered
when ``sims`` is imported; the module is imported only when one is built."""

_EXTRA: dict[str, SimDescriptor] = {}


def _lazy_factory(target: str) -> Any:
    def build(env: gym.Env[Any, Any]) -> Any:
        module, _, attr = target.partition(":")
        return getattr(importlib.import_module(module), attr)(env)

    build.__name__ = target
    return build


def _register_planners() -> None:
    from core.planners import is_planner, register_planner

    for name, (target, title, drives) in PLANNERS.items():
        if not is_planner(name):
            register_planner(name, _lazy_factory(target), title=title, sims=drives)


_register_planners()


class UnknownSimulatorError(ValueError):
    """A simulator name that is not registered; the message lists those that are."""


def register(descriptor: SimDescriptor) -> None:
    """Add a simulator at run time (a plug-in, or a test's toy simulator) by its descriptor alone."""
    _EXTRA[descriptor.name] = descriptor


def unregister(name: str) -> None:
    """Remove a simulator added with :func:`register` (no-op for the built-in ones)."""
    _EXTRA.pop(name, None)


def names() -> list[str]:
    return [*SIMULATORS, *(n for n in _EXTRA if n not in SIMULATORS)]


def descriptor(name: str) -> SimDescriptor:
    """The descriptor of ``name`` (imports its package). Raises :class:`UnknownSimulatorError`."""
    if name in _EXTRA:
        return _EXTRA[name]
    if name not in SIMULATORS:
        raise UnknownSimulatorError(f"unknown simulator {name!r}; choose one of {', '.join(names())}")
    module = importlib.import_module(SIMULATORS[name])
    found = getattr(module, "DESCRIPTOR", None)
    if not isinstance(found, SimDescriptor):
        raise TypeError(f"{SIMULATORS[name]} exports no DESCRIPTOR")
    return found


def descriptors() -> dict[str, SimDescriptor]:
    """Every simulator that imports cleanly (a broken package is left out, not fatal)."""
    out: dict[str, SimDescriptor] = {}
    for name in names():
        try:
            out[name] = descriptor(name)
        except Exception:
            continue
    return out


def make(name: str, scenario: str | int | None = None, *, live: bool = False, **overrides: Any) -> gym.Env[Any, Any]:
    """Build simulator ``name`` on a named ``scenario`` (None: its default); ``overrides`` are more
    ``make()`` keyword arguments and win over the scenario's."""
    return descriptor(name).make(None if scenario is None else str(scenario), live=live, **overrides)


__all__ = [
    "SIMULATORS",
    "ScenarioNameError",
    "UnknownSimulatorError",
    "descriptor",
    "descriptors",
    "make",
    "names",
    "register",
    "unregister",
]
