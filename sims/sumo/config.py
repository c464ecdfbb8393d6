"""The SUMO study's configuration: every default in :class:`SumoConfig`, the ego's ids and SUMO modes, input checks."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

from sims.sumo.engine import SumoError
from sims.sumo.network import DATA_DIR, NET_FILE

EGO = "ego"
GOAL_EDGE = "exit"
ROUTES = {1: "ego_r1", 2: "ego_r2", 3: "ego_r3"}
"""Route number -> route id in ``common.rou.xml`` (3: the ``sumo-shift`` family's unseen route)."""
SPECIAL_FILES = {3: "special3.rou.xml"}
"""The special vehicles of a route, where not C2's ``special.rou.xml``."""
AGENT_SPEED_MODE = 32
"""All of SUMO's speed checks off: the agent's acceleration is applied as is (it may collide or run a red)."""
EXPERT_SPEED_MODE = 31
"""SUMO's default: safe speed, acceleration bounds, right of way and red lights all respected."""
EGO_LANE_CHANGE_MODE = 0b011001010101
"""SUMO's default lane-change mode (1621): strategic, cooperative, speed-gain and keep-right changes."""
RED_STATES = frozenset("rR")
"""Light states that mean stop (SUMO's red and red-with-priority)."""


@dataclass
class SumoConfig:
    """Every default of the SUMO study in one place. Any field can be given to ``SumoEnv(...)`` or ``gym.make``."""

    route: int = 1
    """Which composite route the ego drives: 1 (phase C1), 2 (phase C2) or 3 (the ``sumo-shift`` family's unseen
    route, :mod:`sims.sumo.families`)."""
    special_vehicles: bool = False
    """Add the special vehicles (bus, fire truck, police car, ambulance) to the traffic, as in phase C2."""
    step_length: float = 0.5
    """Seconds of simulated time per env step (SUMO's step length)."""
    max_steps: int = 800
    """Step limit of an episode (truncation): 400 s at the default step length, about twice the expert's mean."""
    warmup: float = 60.0
    """Seconds of background traffic simulated before the ego departs, so the roads are not empty."""
    a_min: float = -4.5
    """Strongest deceleration (m/s^2) at action -1 (the ego type's comfortable maximum, ``decel``)."""
    a_max: float = 3.0
    """Strongest acceleration (m/s^2) at action +1 (the ego type's ``accel``)."""
    perception_range: float = 200.0
    """Neighbour and traffic-light perception range (m); also the distance normaliser."""
    speed_scale: float = 30.0
    """Speed normaliser (m/s) for the ego speed and the relative speeds."""
    speed_reward_divisor: float = 5.0
    """The reward's speed term is ``v / speed_reward_divisor``."""
    goal_reward: float = 100.0
    """Reward on arrival at the off-ramp exit."""
    collision_penalty: float = 1.0
    """Subtracted from the reward on a collision (the paper's binary c_col)."""
    red_light_penalty: float = 1.0
    """Subtracted from the reward on a red-light violation (the paper's binary c_red)."""
    traffic_scale: float = 1.0
    """Multiplies every background flow (SUMO's ``--scale``)."""
    random_specials: int = 0
    """Special-vehicle flows of random type added to each episode, drawn from its SUMO seed on the route's own flows'
    edges (:mod:`sims.sumo.variation`; the ``sumo-shift`` family's varied training splits). 0: none."""
    random_density: bool = False
    """Draw each episode's background scale from :data:`sims.sumo.variation.TRAFFIC_SCALES` by its SUMO seed, in
    place of ``traffic_scale``."""
    randomize_signals: bool = True
    """Start each traffic light in a seeded random phase, so that the ego meets every signal state."""
    teleport_time: float = 120.0
    """SUMO's ``--time-to-teleport`` for jammed vehicles (s); an ego teleport ends the episode (truncated). Longer
    than any wait of the expert at a signal or a busy yield junction."""
    net_file: str | None = None
    """Network file; None is the committed composite network."""
    route_files: tuple[str, ...] | None = None
    """Route files (vehicle types, the ego routes ``ego_r1``/``ego_r2``, flows); None picks the scenario's."""
    extra_args: tuple[str, ...] = ()
    """More SUMO command-line options, appended as given."""

    def __post_init__(self) -> None:
        if self.route not in ROUTES:
            raise ValueError(f"route must be one of {sorted(ROUTES)}, got {self.route!r}")
        if not self.step_length > 0:
            raise ValueError(f"step_length must be positive, got {self.step_length}")
        if not self.a_min < 0 < self.a_max:
            raise ValueError(f"need a_min < 0 < a_max, got a_min={self.a_min}, a_max={self.a_max}")
        if self.max_steps < 1:
            raise ValueError(f"max_steps must be at least 1, got {self.max_steps}")
        count = self.random_specials
        if isinstance(count, bool) or not isinstance(count, int) or count < 0:
            raise ValueError(f"random_specials must be a whole number >= 0, got {self.random_specials!r}")
        self.random_density = bool(self.random_density)
        self.special_vehicles = bool(self.special_vehicles)
        if self.route_files is not None:
            self.route_files = tuple(str(f) for f in self.route_files)
        self.extra_args = tuple(str(a) for a in self.extra_args)

    @property
    def phase(self) -> str:
        """The paper's phase: "C1" (route 1, ordinary traffic), "C2" (route 2 with special vehicles), else a name."""
        if (self.route, self.special_vehicles) == (1, False):
            return "C1"
        if (self.route, self.special_vehicles) == (2, True):
            return "C2"
        return f"route {self.route}" + (" + special vehicles" if self.special_vehicles else "")

    def network_path(self) -> Path:
        return Path(self.net_file) if self.net_file is not None else NET_FILE

    def route_paths(self) -> list[Path]:
        if self.route_files is not None:
            return [Path(f) for f in self.route_files]
        files = [DATA_DIR / "common.rou.xml", DATA_DIR / f"route{self.route}.rou.xml"]
        if self.special_vehicles:
            files.append(DATA_DIR / SPECIAL_FILES.get(self.route, "special.rou.xml"))
        return files

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


CONFIG_FIELDS = frozenset(f.name for f in fields(SumoConfig))


def check_xml_file(path: Path, root_tag: str, what: str) -> None:
    """A clear error naming the file when it is missing or is not a SUMO ``<root_tag>`` XML file."""
    if not path.is_file():
        raise FileNotFoundError(f"SUMO {what} not found: {path}")
    root: str | None = None
    try:
        for event, element in ET.iterparse(path, events=("start", "end")):
            if root is None:
                root = element.tag
                if root != root_tag:
                    raise SumoError(f"SUMO {what} {path} is not a <{root_tag}> file (its root is <{root}>)")
            elif event == "end":
                element.clear()  # read to the end (so truncated files are caught) without keeping the tree
    except ET.ParseError as exc:
        raise SumoError(f"SUMO {what} {path} is not valid XML: {exc}") from exc
    if root is None:
        raise SumoError(f"SUMO {what} {path} is empty")
