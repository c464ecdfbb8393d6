"""What a ``--scenario`` string means to each simulator: its descriptor's scenario names.

The naming lives in each simulator's descriptor (``sims/<name>/descriptor.py``), so the CLI, the dashboard and
the studies mean the same env by the same name; a run records the name (``RunConfig.scenarios``) and evaluation
rebuilds the same env from it.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any

import gymnasium as gym


def default_scenario(sim: str) -> str:
    import sims

    return sims.descriptor(sim).default_scenario


def scenario_kwargs(sim: str, scenario: str) -> dict[str, Any]:
    """``make()`` keyword arguments of a scenario name; a clear error for a bad name."""
    import sims

    return sims.descriptor(sim).scenario_kwargs(scenario)


def parse_env_overrides(pairs: list[str]) -> dict[str, Any]:
    """``key=value`` strings (``sage train --set env.KEY=VALUE``) as keyword arguments of the simulator's
    ``make()``: a value is read as JSON where it parses (``false``, ``0.3``, ``[1, 2]``; ``True``/``False`` too),
    else kept as text."""
    out: dict[str, Any] = {}
    for pair in pairs:
        key, sep, text = pair.partition("=")
        if not sep or not key.strip():
            raise ValueError(f"--set env.{pair}: not of the form env.key=value")
        text = text.strip()
        try:
            value: Any = json.loads(text.lower() if text in ("True", "False") else text)
        except json.JSONDecodeError:
            value = text
        out[key.strip()] = value
    return out


def env_factory(sim: str, **fixed: Any) -> Callable[[str], gym.Env[Any, Any]]:
    """``make_env(scenario)`` for :class:`core.train.Trainer` and :func:`core.train.evaluate`.

    ``fixed``: more keyword arguments for every env (e.g. ``mode="adversarial"``), winning over the scenario's.
    """
    import sims

    descriptor = sims.descriptor(sim)  # a clear error for an unknown simulator, before any training

    def make_env(scenario: str) -> gym.Env[Any, Any]:
        try:
            return descriptor.make(scenario, **fixed)
        except TypeError as exc:  # the simulator's constructor does not take what was given
            raise ValueError(f"cannot build simulator {sim!r} scenario {scenario!r} with {fixed}: {exc}") from None

    return make_env
