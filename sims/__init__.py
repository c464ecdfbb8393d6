"""Simulators, one package each, registered with gymnasium under the ``sage/`` namespace.

Each package provides a gymnasium ``Env`` whose ``unwrapped`` implements
:class:`core.protocol.SimulatorEnv` (``expert_action``, ``scene``, ``metrics``), its scenarios and
its scripted expert. :func:`make` builds one by its short name.
"""

from __future__ import annotations

import importlib
from typing import Any

import gymnasium as gym

SIMULATORS: dict[str, tuple[str, str]] = {
    "ugv": ("sims.ugv", "sage/UGV-v0"),
    "highway": ("sims.highway", "sage/Highway-v0"),
    "sumo": ("sims.sumo", "sage/Sumo-v0"),
}
"""Short name -> (package that registers it on import, gymnasium id)."""


def make(sim: str, **kwargs: Any) -> gym.Env[Any, Any]:
    """``make("ugv", scenario=3)``: import the simulator's package (which registers it) and build it."""
    if sim not in SIMULATORS:
        raise ValueError(f"unknown simulator {sim!r}; choose one of {', '.join(SIMULATORS)}")
    package, env_id = SIMULATORS[sim]
    importlib.import_module(package)
    return gym.make(env_id, **kwargs)
