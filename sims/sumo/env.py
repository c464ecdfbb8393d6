"""The paper's long composite-route study in SUMO, driven through libsumo (one simulation per process).

The ego drives one of two long composite routes through a hand-made network (``sims/sumo/data``):
unsignalised junctions, a roundabout, a signalised junction, an on-ramp merge, highway cruising and the off-ramp
whose end is the goal. Route 1 (phase C1) and route 2 (phase C2) differ in local geometry and traffic
composition; in C2 special vehicles (bus, fire truck, police car, ambulance) join the traffic.

Observation (29 values, all in [-1, 1]):
    6 sectors x 4: the nearest vehicle within ``perception_range`` in front, rear, left-front, left-rear,
        right-front, right-rear: relative distance (centre to centre, / range), relative heading (/ pi),
        relative speed (/ speed_scale) and direction of the relative velocity in the ego frame (/ pi);
        an empty sector reads (1, 0, 0, 0), "far away, nothing moving".
        Front and rear are SUMO's leader and follower along the ego's route (they follow curves and junctions);
        the four side sectors take the nearest other vehicle left/right of the ego's lane, ahead of or behind it.
    ego speed (/ speed_scale) and heading (/ pi, x east, counter-clockwise),
    distance to the next traffic light on the route (/ range, 1 if none in range) and its state for the ego's
        link (0 green or none, 0.5 yellow, 1 red),
    remaining route distance to the goal (/ route length).
Action: Box([-1], [1]), longitudinal acceleration; 0 holds the speed, +1 is ``a_max``, -1 is ``a_min``
    (piecewise linear, so the two halves keep their physical meaning). Lane changes are SUMO's: the ego keeps
    SUMO's lane-change model (strategic changes follow the route, e.g. leaving an acceleration lane).
    While the agent drives, SUMO's safety checks are off for the ego (speed mode 32): it can collide and it can
    run a red light, and both are detected from SUMO.
Reward (the paper's, read literally): ``v / 5 + r_goal - c_col - c_red`` with ``r_goal = 100`` on arrival at
    the off-ramp exit and otherwise the shaping ``-log(1 + d / d_max) - 1``, where d is the remaining route
    distance to the goal and d_max the route length. Read this way the shaping is a per-step time cost between
    -1 - log 2 (at the start) and -1 (at the goal): it never rewards standing still, shrinks as the ego gets
    closer, and with ``v / 5`` the step reward turns positive above about 6.5 m/s. (Reading the paper's
    Delta d as per-step progress instead would punish progress, so that reading is rejected.) The penalty
    weights are configurable; the defaults are the paper's (1 each).
Costs: ``info["cost"] = 1`` when the ego collided (SUMO's collision list, junctions included) or crossed a stop
    line on red (the state of the very link it crossed, read from its traffic light). ``info`` also carries
    ``violation``, ``collision``, ``red_light``, ``success``, ``speed``, ``route_progress``, ``expert_drove``
    and ``executed_action`` (the acceleration actually applied, normalised like the action).
The episode ends at the goal or a collision (terminated) or at ``max_steps`` (truncated). A SUMO failure
    (TraCIException, lost simulation) raises :class:`~sims.sumo.engine.SumoError` from ``step``; the next reset
    starts a fresh simulation.
Expert (:meth:`SumoEnv.expert_action`): SUMO's own driver model. When the executed action is the very array
    ``expert_action()`` just returned, the env hands the ego back to SUMO for that step with all safety checks on
    (speed mode 31, Krauss car following, junction right of way, red lights), so the expert's driving is exactly
    SUMO's. The returned action is SUMO's next acceleration predicted from its own API (``getFollowSpeed`` for the
    leader, ``getStopSpeed`` for a red or stoppable yellow light and for a closed link without priority, the
    speed limits ahead); the acceleration actually applied is reported in ``info["executed_action"]``.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from core.scene import Scene
from sims.sumo import engine
from sims.sumo import scene as drawing
from sims.sumo.engine import SumoError
from sims.sumo.network import DATA_DIR, NET_FILE

libsumo = engine.libsumo

EGO = "ego"
GOAL_EDGE = "exit"
ROUTES = {1: "ego_r1", 2: "ego_r2"}
"""Route number -> route id in ``common.rou.xml``."""
AGENT_SPEED_MODE = 32
"""All of SUMO's speed checks off: the agent's acceleration is applied as is (it may collide or run a red)."""
EXPERT_SPEED_MODE = 31
"""SUMO's default: safe speed, acceleration bounds, right of way and red lights all respected."""
EGO_LANE_CHANGE_MODE = 0b011001010101
"""SUMO's default lane-change mode (1621): strategic, cooperative, speed-gain and keep-right changes."""
SECTORS = ("front", "rear", "left_front", "left_rear", "right_front", "right_rear")
OBS_SIZE = 4 * len(SECTORS) + 5
EMPTY_SECTOR = (1.0, 0.0, 0.0, 0.0)
TLS_STATE_VALUE = {"G": 0.0, "g": 0.0, "s": 0.0, "y": 0.5, "Y": 0.5, "u": 0.5, "r": 1.0, "R": 1.0}
"""Light state -> observation value (how strongly it says stop); unknown or off reads 0."""
RED_STATES = frozenset("rR")
RED_STOP_GAP = 1.0
"""SUMO stops this far before the stop line of a red light (``DIST_TO_STOPLINE_EXPECT_PRIORITY``)."""
FOE_VISIBILITY = 4.5
"""netconvert's default foe visibility distance at a junction (m)."""
ROUNDABOUT_VISIBILITY = 9.0
"""netconvert's ``--roundabouts.visibility-distance`` default (m)."""


@dataclass
class SumoConfig:
    """Every default of the SUMO study in one place. Any field can be given to ``SumoEnv(...)`` or ``gym.make``."""

    route: int = 1
    """Which composite route the ego drives: 1 (phase C1) or 2 (phase C2)."""
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
            files.append(DATA_DIR / "special.rou.xml")
        return files

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


CONFIG_FIELDS = frozenset(f.name for f in fields(SumoConfig))


def _check_xml_file(path: Path, root_tag: str, what: str) -> None:
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


def _wrap(angle: float) -> float:
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


def _heading(sumo_angle_deg: float) -> float:
    """SUMO's angle (degrees, 0 = north, clockwise) -> heading (radians, 0 = east, counter-clockwise)."""
    return _wrap(math.radians(90.0 - sumo_angle_deg))


@dataclass
class _Episode:
    """Per-episode bookkeeping (the trajectory the metrics are computed from)."""

    route_length: float = 1.0
    remaining: float = 1.0
    steps: int = 0
    speeds: list[float] = field(default_factory=list)
    success: bool = False
    collision: bool = False
    red_light_runs: int = 0
    truncated: bool = False
    teleported: bool = False
    done: bool = False
    expert_steps: int = 0


class SumoEnv(gym.Env[np.ndarray, np.ndarray]):
    """The ego on a composite route, in an in-process libsumo simulation (see the module docstring).

    The simulation starts at ``reset`` (construction only checks the input files), so building an env is cheap
    and safe while another one runs. Only one in-process env can run at a time: starting a second one takes the
    simulation over and the first one's next step raises :class:`SumoError`. Use
    :class:`~sims.sumo.process.SumoProcessEnv` (or ``process=True`` in ``gym.make``) for parallel runs or to keep
    a thread's event loop free while SUMO steps.
    """

    metadata: dict[str, Any] = {"render_modes": []}  # noqa: RUF012 - gymnasium's class attribute

    def __init__(self, config: SumoConfig | None = None, **overrides: Any) -> None:
        super().__init__()
        unknown = set(overrides) - CONFIG_FIELDS
        if unknown:
            raise TypeError(f"unknown SumoEnv option(s): {', '.join(sorted(unknown))}")
        self.config = replace(config or SumoConfig(), **overrides)
        self._check_inputs(self.config)
        self.observation_space = gym.spaces.Box(-1.0, 1.0, (OBS_SIZE,), np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
        self._pending: SumoConfig | None = None
        self._episode = _Episode()
        self._obs = np.zeros(OBS_SIZE, np.float32)
        self._speed = 0.0
        self._speed_mode = -1
        self._expert_action: np.ndarray | None = None
        self._ego_decel = 4.5
        self._ego_accel = 3.0
        self._ego_max_speed = 33.33
        self._goal_pos = 0.0
        self._last_position = (0.0, 0.0)
        self._last_heading = 0.0
        self._ego_length = 4.5
        self._ego_width = 1.8
        self._sim_time = 0.0
        self._roundabout_entries: frozenset[str] = frozenset()

    # -- configuration -------------------------------------------------------------------------
    @staticmethod
    def _check_inputs(config: SumoConfig) -> None:
        _check_xml_file(config.network_path(), "net", "network file")
        for path in config.route_paths():
            _check_xml_file(path, "routes", "route file")

    def set_scenario(self, route: int | None = None, special_vehicles: bool | None = None) -> None:
        """Switch route and/or special vehicles from the next ``reset`` on (the route-shift study's phase switch)."""
        changes: dict[str, Any] = {}
        if route is not None:
            changes["route"] = int(route)
        if special_vehicles is not None:
            changes["special_vehicles"] = bool(special_vehicles)
        pending = replace(self._pending or self.config, **changes)
        self._check_inputs(pending)
        self._pending = pending

    @property
    def running(self) -> bool:
        return engine.owns(self)

    @property
    def pending_expert_action(self) -> np.ndarray | None:
        """The array the last ``expert_action()`` returned, until the next step (what ``step`` recognises)."""
        return self._expert_action

    # -- gymnasium -----------------------------------------------------------------------------
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        if options:
            unknown = set(options) - CONFIG_FIELDS
            if unknown:
                raise ValueError(f"unknown reset option(s): {', '.join(sorted(unknown))}")
            self._pending = replace(self._pending or self.config, **options)
            self._check_inputs(self._pending)
        if self._pending is not None:
            self.config, self._pending = self._pending, None
        sumo_seed = int(self.np_random.integers(0, 2**31 - 1))
        self._episode = _Episode()
        self._expert_action = None
        self._speed_mode = -1
        engine.start(self, self.sumo_args(sumo_seed))
        try:
            self._prepare_episode()
            self._obs = self._observe()
        except (SumoError, *engine.SUMO_ERRORS) as exc:
            self._episode.done = True
            engine.close(self)
            if isinstance(exc, SumoError):
                raise
            raise SumoError(f"SUMO failed while starting the episode: {exc}") from exc
        return self._obs.copy(), self._info(collision=False, red_light=False, executed=0.0, expert=False)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._episode.done:
            raise RuntimeError("the episode has ended: call reset() before step()")
        if not engine.owns(self):
            self._episode.done = True
            raise SumoError(
                "this SumoEnv's simulation is gone: it was closed, or another SumoEnv started in this process "
                "(libsumo runs one simulation per process; use SumoProcessEnv for parallel runs)"
            )
        act = np.asarray(action, dtype=np.float32).reshape(-1)
        if act.shape != (1,) or not np.isfinite(act).all():
            raise ValueError(f"action must be one finite number in [-1, 1], got {action!r}")
        act = np.clip(act, -1.0, 1.0)
        # identity, not equality: a policy that happens to output the same number still drives itself
        expert = self._expert_action is not None and action is self._expert_action
        self._expert_action = None
        try:
            return self._step(act, expert)
        except (SumoError, *engine.SUMO_ERRORS) as exc:
            # the episode is over and its simulation unusable; the next reset starts a fresh one
            self._episode.done = True
            engine.close(self)
            if isinstance(exc, SumoError):
                raise
            raise SumoError(f"SUMO failed during step {self._episode.steps}: {exc}") from exc

    def close(self) -> None:
        engine.close(self)
        self._episode.done = True

    # -- the simulator protocol ----------------------------------------------------------------
    def expert_action(self) -> np.ndarray:
        """SUMO's own driver model for this step.

        Passing the very array returned here to ``step`` (as ``core.loop.Runner`` does on a takeover) lets SUMO
        drive the ego for that step; any other array, equal or not, is applied as the agent's acceleration.
        """
        if self._episode.done or not engine.owns(self):
            return np.zeros(1, np.float32)
        try:
            target = self._predict_sumo_speed()
        except engine.SUMO_ERRORS as exc:
            raise SumoError(f"SUMO failed while computing the expert action: {exc}") from exc
        action = np.array([self._normalize((target - self._speed) / self.config.step_length)], np.float32)
        self._expert_action = action
        return action

    def scene(self) -> Scene:
        cfg = self.config
        net = cfg.network_path()
        key, static = drawing.static_shapes(str(net))
        ego_box = drawing.box(
            self._last_position, self._last_heading, self._ego_length, self._ego_width, drawing.EGO_COLOR, "ego"
        )
        movers: list[Any] = []
        if engine.owns(self):
            try:
                movers = drawing.vehicle_boxes(exclude=EGO) + drawing.signal_circles()
            except engine.SUMO_ERRORS:
                movers = []
        half = 110.0
        x, y = self._last_position
        ep = self._episode
        return Scene(
            sim="sumo",
            bounds=[x - half, y - half, x + half, y + half],
            static_key=key,
            static=static,
            movers=movers,
            ego=ego_box,
            goal=drawing.goal_marker(str(net), GOAL_EDGE),
            labels={
                "route": str(cfg.route),
                "phase": cfg.phase,
                "speed": f"{self._speed:.1f} m/s",
                "progress": f"{100.0 * self._progress():.0f}%",
                "time": f"{self._sim_time:.1f} s",
                "status": "goal" if ep.success else "collision" if ep.collision else "driving",
            },
        )

    def metrics(self) -> dict[str, float]:
        ep = self._episode
        timeout = ep.truncated and not (ep.success or ep.collision)
        return {
            "success": float(ep.success),
            "collision": float(ep.collision),
            "red_light": float(ep.red_light_runs > 0),
            "timeout": float(timeout),
            "route_progress": self._progress(),
            "speed_mean": float(np.mean(ep.speeds)) if ep.speeds else 0.0,
            "red_light_runs": float(ep.red_light_runs),
            "steps": float(ep.steps),
            "route": float(self.config.route),
            "special_vehicles": float(self.config.special_vehicles),
        }

    def sumo_args(self, seed: int) -> list[str]:
        """SUMO's command line (without the binary) for an episode of this config with this SUMO seed."""
        cfg = self.config
        return [
            "--net-file", str(cfg.network_path()),
            "--route-files", ",".join(str(p) for p in cfg.route_paths()),
            "--step-length", repr(cfg.step_length),
            "--seed", str(seed),
            "--scale", repr(cfg.traffic_scale),
            "--collision.action", "remove",
            "--collision.check-junctions", "true",
            "--collision.mingap-factor", "0",
            "--time-to-teleport", repr(cfg.teleport_time),
            "--no-step-log", "true",
            "--no-warnings", "true",
            "--duration-log.disable", "true",
            "--xml-validation", "never",
            *cfg.extra_args,
        ]  # fmt: skip

    # -- internals -----------------------------------------------------------------------------
    def _prepare_episode(self) -> None:
        cfg = self.config
        dt = cfg.step_length
        if cfg.randomize_signals:
            for tls in libsumo.trafficlight.getIDList():
                phases = libsumo.trafficlight.getAllProgramLogics(tls)[0].phases
                index = int(self.np_random.integers(len(phases)))
                libsumo.trafficlight.setPhase(tls, index)
                libsumo.trafficlight.setPhaseDuration(tls, float(self.np_random.uniform(dt, phases[index].duration)))
        for _ in range(round(cfg.warmup / dt)):
            libsumo.simulationStep()
        libsumo.vehicle.add(EGO, ROUTES[cfg.route], typeID="ego", depart="now", departLane="best", departSpeed="0")
        for _ in range(round(60.0 / dt)):
            libsumo.simulationStep()
            if EGO in libsumo.simulation.getDepartedIDList():
                break
        else:
            raise SumoError("the ego could not enter the network within 60 s (its start lane stayed blocked)")
        libsumo.vehicle.setLaneChangeMode(EGO, EGO_LANE_CHANGE_MODE)
        self._set_speed_mode(AGENT_SPEED_MODE)
        ego_type = libsumo.vehicle.getTypeID(EGO)
        self._ego_accel = libsumo.vehicletype.getAccel(ego_type)
        self._ego_decel = libsumo.vehicletype.getDecel(ego_type)
        self._ego_max_speed = libsumo.vehicletype.getMaxSpeed(ego_type)
        self._ego_length = libsumo.vehicletype.getLength(ego_type)
        self._ego_width = libsumo.vehicletype.getWidth(ego_type)
        self._goal_pos = libsumo.lane.getLength(f"{GOAL_EDGE}_0")
        self._roundabout_entries = drawing.roundabout_entry_lanes(str(cfg.network_path()))
        libsumo.vehicle.subscribeContext(
            EGO,
            libsumo.CMD_GET_VEHICLE_VARIABLE,
            cfg.perception_range,
            [libsumo.VAR_POSITION, libsumo.VAR_ANGLE, libsumo.VAR_SPEED, libsumo.VAR_LANE_ID, libsumo.VAR_LENGTH],
        )
        libsumo.simulationStep()  # fills the context subscription; the ego starts rolling from rest
        ep = self._episode
        ep.route_length = max(self._remaining_distance(), 1.0)
        ep.remaining = ep.route_length
        self._read_ego()

    def _set_speed_mode(self, mode: int) -> None:
        if mode != self._speed_mode:
            libsumo.vehicle.setSpeedMode(EGO, mode)
            self._speed_mode = mode

    def _step(self, act: np.ndarray, expert: bool) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        cfg = self.config
        ep = self._episode
        dt = cfg.step_length
        v0 = self._speed
        tls_ahead = libsumo.vehicle.getNextTLS(EGO)
        odometer = libsumo.vehicle.getDistance(EGO)
        if expert:
            self._set_speed_mode(EXPERT_SPEED_MODE)
            libsumo.vehicle.setSpeed(EGO, -1.0)  # hand the ego back to SUMO's own model for this step
            ep.expert_steps += 1
        else:
            self._set_speed_mode(AGENT_SPEED_MODE)
            target = min(max(v0 + self._acceleration(float(act[0])) * dt, 0.0), self._ego_max_speed)
            libsumo.vehicle.setSpeed(EGO, target)
        libsumo.simulationStep()
        ep.steps += 1
        self._sim_time = libsumo.simulation.getTime()

        collision = any(EGO in (c.collider, c.victim) for c in libsumo.simulation.getCollisions())
        present = not collision and EGO in libsumo.vehicle.getIDList()
        arrived = not collision and not present and EGO in libsumo.simulation.getArrivedIDList()
        teleported = present and EGO in libsumo.simulation.getStartingTeleportIDList()
        if not (collision or present or arrived):
            raise SumoError("the ego vanished from the simulation without arriving or colliding")
        if present:
            travelled = libsumo.vehicle.getDistance(EGO) - odometer
            self._read_ego()
            ep.remaining = self._remaining_distance()
        else:
            travelled = max(v0, self._speed) * dt + 1.0  # the ego is gone: it got at least this far
            if arrived:
                ep.remaining = 0.0
        # the state of the link the ego crossed, in force during this step's move (SUMO switches lights first)
        red_light = any(
            dist < travelled and libsumo.trafficlight.getRedYellowGreenState(tls)[index] in RED_STATES
            for tls, index, dist, _state in tls_ahead
        )
        executed = self._normalize((self._speed - v0) / dt) if present else float(act[0])
        ep.red_light_runs += int(red_light)
        ep.collision = collision
        ep.success = arrived
        speed = self._speed
        ep.speeds.append(speed)

        reward = speed / cfg.speed_reward_divisor
        if arrived:
            reward += cfg.goal_reward
        else:
            reward += -math.log1p(ep.remaining / ep.route_length) - 1.0
        reward -= cfg.collision_penalty * float(collision) + cfg.red_light_penalty * float(red_light)

        terminated = collision or arrived
        truncated = not terminated and (ep.steps >= cfg.max_steps or teleported)
        ep.teleported = teleported
        ep.truncated = truncated
        ep.done = terminated or truncated
        if present and not ep.done:
            self._obs = self._observe()
        info = self._info(collision=collision, red_light=red_light, executed=executed, expert=expert)
        if teleported:
            info["teleported"] = True
        return self._obs.copy(), float(reward), terminated, truncated, info

    def _info(self, *, collision: bool, red_light: bool, executed: float, expert: bool) -> dict[str, Any]:
        cost = float(collision or red_light)
        return {
            "cost": cost,
            "violation": bool(cost),
            "collision": bool(collision),
            "red_light": bool(red_light),
            "success": bool(self._episode.success),
            "speed": float(self._speed),
            "route_progress": self._progress(),
            "distance_to_goal": float(self._episode.remaining),
            "expert_drove": bool(expert),
            "executed_action": float(executed),
            "route": self.config.route,
            "phase": self.config.phase,
        }

    def _progress(self) -> float:
        ep = self._episode
        if ep.success:
            return 1.0
        return float(min(max(1.0 - ep.remaining / ep.route_length, 0.0), 1.0))

    def _acceleration(self, a: float) -> float:
        return a * self.config.a_max if a >= 0.0 else -a * self.config.a_min

    def _normalize(self, accel: float) -> float:
        a = accel / self.config.a_max if accel >= 0.0 else -accel / self.config.a_min
        return float(min(max(a, -1.0), 1.0))

    def _read_ego(self) -> None:
        angle = libsumo.vehicle.getAngle(EGO)
        x, y = libsumo.vehicle.getPosition(EGO)
        heading = _heading(angle)
        half = 0.5 * self._ego_length
        self._last_position = (x - half * math.cos(heading), y - half * math.sin(heading))  # front bumper -> centre
        self._last_heading = heading
        self._speed = libsumo.vehicle.getSpeed(EGO)

    def _remaining_distance(self) -> float:
        d = libsumo.vehicle.getDrivingDistance(EGO, GOAL_EDGE, self._goal_pos)
        # SUMO answers a huge negative number when the goal is unreachable (it never is on the ego's route)
        return float(d) if d >= 0.0 else self._episode.remaining

    def _observe(self) -> np.ndarray:
        cfg = self.config
        rng = cfg.perception_range
        vs = cfg.speed_scale
        ego_x, ego_y = self._last_position
        he = self._last_heading
        ve = self._speed
        cos_e, sin_e = math.cos(he), math.sin(he)
        ego_lane = libsumo.vehicle.getLaneID(EGO)
        others = libsumo.vehicle.getContextSubscriptionResults(EGO) or {}
        leader = libsumo.vehicle.getLeader(EGO, rng)
        follower = libsumo.vehicle.getFollower(EGO, rng)
        leader_id = leader[0] if leader else ""
        follower_id = follower[0] if follower else ""

        best: dict[str, tuple[float, tuple[float, float, float, float]]] = {}
        for vid, var in others.items():
            if vid == EGO:
                continue
            h = _heading(var[libsumo.VAR_ANGLE])
            fx, fy = var[libsumo.VAR_POSITION]
            half = 0.5 * var[libsumo.VAR_LENGTH]
            dx = fx - half * math.cos(h) - ego_x
            dy = fy - half * math.sin(h) - ego_y
            dist = math.hypot(dx, dy)
            if dist > rng:
                continue
            along = dx * cos_e + dy * sin_e
            across = -dx * sin_e + dy * cos_e
            if vid == leader_id:
                sector = "front"
            elif vid == follower_id:
                sector = "rear"
            elif var[libsumo.VAR_LANE_ID] == ego_lane:
                continue  # further along the ego's own lane: hidden behind the leader or follower
            elif across >= 0.0:
                sector = "left_front" if along >= 0.0 else "left_rear"
            else:
                sector = "right_front" if along >= 0.0 else "right_rear"
            if sector in best and best[sector][0] <= dist:
                continue
            v = var[libsumo.VAR_SPEED]
            rel_vx = v * math.cos(h) - ve * cos_e
            rel_vy = v * math.sin(h) - ve * sin_e
            rel_along = rel_vx * cos_e + rel_vy * sin_e
            rel_across = -rel_vx * sin_e + rel_vy * cos_e
            direction = math.atan2(rel_across, rel_along) if math.hypot(rel_vx, rel_vy) > 1e-3 else 0.0
            best[sector] = (
                dist,
                (dist / rng, _wrap(h - he) / math.pi, (v - ve) / vs, direction / math.pi),
            )
        obs: list[float] = []
        for sector in SECTORS:
            obs.extend(best[sector][1] if sector in best else EMPTY_SECTOR)
        obs.append(ve / vs)
        obs.append(he / math.pi)
        tls = libsumo.vehicle.getNextTLS(EGO)
        if tls and tls[0][2] <= rng:
            obs.append(tls[0][2] / rng)
            obs.append(TLS_STATE_VALUE.get(tls[0][3], 0.0))
        else:
            obs.extend((1.0, 0.0))
        obs.append(self._episode.remaining / self._episode.route_length)
        return np.clip(np.asarray(obs, dtype=np.float32), -1.0, 1.0)

    def _predict_sumo_speed(self) -> float:
        """SUMO's speed for the next step as its own API computes it (the label of the expert's action).

        The bounds mirror what SUMO's vehicle applies (``MSVehicle::planMove``): acceleration and speed limits,
        the Krauss follow speed behind the leader, stopping 1 m before a red light or a yellow one it can still
        stop for, arriving at a link without priority slowly enough to stop within the foe visibility distance,
        stopping at it while it is closed, and slowing down in time for lower speed limits ahead.
        """
        v = self._speed
        dt = self.config.step_length
        decel = self._ego_decel
        bounds = [v + self._ego_accel * dt, self._ego_max_speed, libsumo.vehicle.getAllowedSpeed(EGO)]

        def reach(target: float, dist: float) -> float:
            # highest speed from which `target` is reached within `dist` (one step of reaction on an Euler grid)
            return math.sqrt(target * target + 2.0 * decel * max(dist - v * dt, 0.0))

        leader = libsumo.vehicle.getLeader(EGO, self.config.perception_range)
        if leader and leader[0]:
            lid, gap = leader
            leader_speed = libsumo.vehicle.getSpeed(lid)
            leader_decel = libsumo.vehicle.getDecel(lid)
            bounds.append(libsumo.vehicle.getFollowSpeed(EGO, v, max(gap, 0.0), leader_speed, leader_decel, lid))
        tls = libsumo.vehicle.getNextTLS(EGO)
        if tls:
            _tls_id, _index, dist, state = tls[0]
            can_stop = dist > v * v / (2.0 * decel)
            if state in RED_STATES or (state in "yY" and can_stop):
                bounds.append(libsumo.vehicle.getStopSpeed(EGO, v, max(dist - RED_STOP_GAP, 0.0)))
        lane = libsumo.vehicle.getLaneID(EGO)
        if not lane.startswith(":"):
            dist = libsumo.lane.getLength(lane) - libsumo.vehicle.getLanePosition(EGO)
            links = libsumo.vehicle.getNextLinks(EGO)
            if links:
                next_lane, has_prio, is_open, has_foe, via, state, _direction, _length = links[0]
                if not has_prio and state not in RED_STATES:
                    if not is_open or has_foe:
                        bounds.append(libsumo.vehicle.getStopSpeed(EGO, v, max(dist, 0.0)))
                    visibility = ROUNDABOUT_VISIBILITY if via in self._roundabout_entries else FOE_VISIBILITY
                    bounds.append(reach(math.sqrt(2.0 * decel * visibility), dist))
                for ahead in (via, next_lane):
                    if ahead:
                        bounds.append(reach(libsumo.lane.getMaxSpeed(ahead), dist))
        return max(0.0, min(bounds))
