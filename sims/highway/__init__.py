"""Highway driving on logged scenarios, replayed or adversarially resampled: the paper's Waymo study on highway-env.

``import sims.highway`` registers ``sage/Highway-v0``; build it with ``sims.make("highway", split="test",
mode="adversarial")``. See env.py for observation, action, reward and cost, scenarios.py for the pool
of 500 logged scenarios, adversary.py for the CAT-style resampling, expert.py for the scripted expert;
the paper's evaluation protocol is studies/highway_evaluate.py.
"""

from __future__ import annotations

from gymnasium.envs.registration import register, registry

from sims.highway.config import HighwayConfig
from sims.highway.descriptor import DESCRIPTOR
from sims.highway.env import HighwayEnv
from sims.highway.scenarios import load_log, scenario_ids, scenario_spec, warm_cache

ENV_ID = "sage/Highway-v0"

if ENV_ID not in registry:
    register(id=ENV_ID, entry_point="sims.highway.env:HighwayEnv")

__all__ = [
    "DESCRIPTOR",
    "ENV_ID",
    "HighwayConfig",
    "HighwayEnv",
    "load_log",
    "scenario_ids",
    "scenario_spec",
    "warm_cache",
]
