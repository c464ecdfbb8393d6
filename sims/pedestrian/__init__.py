"""Long-tail study: an occluded pedestrian steps out from in front of a parked truck (paper, Long-Tail
Safety-Critical Experiments). ``sims.make("pedestrian", scenario="crossing")`` or
``gymnasium.make("sage/Pedestrian-v0")``; observation, actions, reward and cost: :mod:`sims.pedestrian.env`.

``step`` info: ``cost`` (0/1 collision flag), ``violation``, ``collision``, ``success``, ``pedestrian`` (one
exists this episode), ``pedestrian_visible`` (a lidar ray's nearest hit is the pedestrian), ``ttc`` (s).
``expert_action()``: the cautious scripted expert's action index (privileged). ``metrics()``: the columns
:data:`METRIC_COLUMNS`. Scenarios: ``crossing`` (always a pedestrian), ``clear``, ``parked`` (no pedestrian),
``rare`` (the training mix, a pedestrian in 20% of episodes); per-seed randomisation of the truck position,
walking speed, where the pedestrian waits and when it steps out.
"""

from __future__ import annotations

import gymnasium as gym

from sims.pedestrian.config import PedestrianConfig, default_config
from sims.pedestrian.descriptor import DESCRIPTOR
from sims.pedestrian.metrics import METRIC_COLUMNS

ENV_ID = "sage/Pedestrian-v0"

if ENV_ID not in gym.registry:
    gym.register(id=ENV_ID, entry_point="sims.pedestrian.env:PedestrianEnv")

__all__ = ["DESCRIPTOR", "ENV_ID", "METRIC_COLUMNS", "PedestrianConfig", "default_config"]
