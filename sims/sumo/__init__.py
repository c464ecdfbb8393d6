"""SUMO (libsumo): the paper's long composite-route study, registered as ``sage/Sumo-v0``.

``sims.make("sumo", route=2, special_vehicles=True)`` builds the in-process env; ``process=True`` builds the
process-backed one (its own libsumo in a spawned worker: parallel runs, and SUMO steps that never hold the
caller's GIL).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym

from sims.sumo.descriptor import DESCRIPTOR
from sims.sumo.engine import SumoError
from sims.sumo.env import SumoConfig, SumoEnv

ENV_ID = "sage/Sumo-v0"


def make_sumo_env(process: bool = False, **kwargs: Any) -> gym.Env[Any, Any]:
    """gymnasium's entry point: the in-process :class:`SumoEnv`, or :class:`SumoProcessEnv` with ``process=True``."""
    if process:
        from sims.sumo.process import SumoProcessEnv

        return SumoProcessEnv(**kwargs)
    return SumoEnv(**kwargs)


if ENV_ID not in gym.registry:
    gym.register(id=ENV_ID, entry_point=make_sumo_env, disable_env_checker=False)

__all__ = [
    "DESCRIPTOR",
    "ENV_ID",
    "SumoConfig",
    "SumoEnv",
    "SumoError",
    "make_sumo_env",
]
