"""UGV navigation among static and moving obstacles: the paper's field tests in a pymunk world.

Build it with ``sims.make("ugv", scenario=3)`` or ``gymnasium.make("sage/UGV-v0", scenario=...)``,
where ``scenario`` is 1..4 (the paper's four field tests, ``sims/ugv/scenarios/*.yaml``) or the path
of any scenario YAML file (schema and randomisation: :mod:`sims.ugv.scenario`). Keyword overrides
change the :class:`~sims.ugv.config.UGVConfig` (dotted names, e.g. ``time_limit=30`` or
``**{"lidar.backend": "pymunk"}``). Observation, action, reward and cost: :mod:`sims.ugv.env`.

Stable interface for the rest of the project (``env.unwrapped``):

``step`` info
    ``cost`` (float, the paper's dense cost), ``violation`` (bool, = collision), ``collision``,
    ``success``, ``timeout`` (bools), ``d_goal`` (m).

``expert_action() -> np.ndarray``
    The scripted expert's normalised action (float32, shape (2,)) for the current state: grid planner
    around static obstacles, pure pursuit, and yielding/stopping for movers, whose scripted future it
    knows (privileged). Callable at any step, so takeovers may start mid-episode.

``scene() -> core.scene.Scene``
    Plain data, metres and radians, rebuilt cheaply every call (~tens of µs):
    ``sim="ugv"``; ``bounds`` = the map's [xmin, ymin, xmax, ymax]; ``static`` = walls (polylines),
    boxes and round obstacles, the same list object for the whole episode, with ``static_key`` =
    ``"<scenario name>:<episode index>"`` changing at every reset; ``movers`` = boxes (or circles)
    of the moving obstacles now; ``ego`` = the robot's box; ``goal`` = the goal circle; ``rays`` =
    lidar origin (the robot's centre), one end point per ray (its hit point, or max range when
    ``hit`` is false) and hit flags: 108 rays by default, index j * 54 + s being ray j of sector s,
    at -135° + (s + j / 2) * 5° from the heading; ``labels`` = scenario, time, cost.

``metrics() -> dict[str, float]``
    The paper's table row for the current or just finished episode (:mod:`sims.ugv.metrics`):
    ``success``, ``collision``, ``timeout`` (0/1), ``avg_speed`` (m/s), ``travel_distance`` (m),
    ``path_curvature`` (1/m, mean over moving samples), ``lateral_acc`` (m/s², mean v²·κ). Column
    order: :data:`sims.ugv.metrics.METRIC_COLUMNS`.
"""

from __future__ import annotations

import gymnasium as gym

from sims.ugv.config import UGVConfig
from sims.ugv.descriptor import DESCRIPTOR
from sims.ugv.metrics import METRIC_COLUMNS
from sims.ugv.scenario import BUILTIN_SCENARIOS, Scenario, ScenarioError, load_scenario

ENV_ID = "sage/UGV-v0"

if ENV_ID not in gym.registry:
    gym.register(id=ENV_ID, entry_point="sims.ugv.env:UGVEnv")

__all__ = [
    "BUILTIN_SCENARIOS",
    "DESCRIPTOR",
    "ENV_ID",
    "METRIC_COLUMNS",
    "Scenario",
    "ScenarioError",
    "UGVConfig",
    "load_scenario",
]
