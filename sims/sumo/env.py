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
from dataclasses import dataclass, field, replace
from typing import Any

import gymnasium as gym
import numpy as np

from core.dotted import replaced
from core.scene import Scene
from sims.sumo import engine, variation
from sims.sumo import scene as drawing
from sims.sumo.config import (
    AGENT_SPEED_MODE,
    CONFIG_FIELDS,
    EGO,
    EGO_LANE_CHANGE_MODE,
    EXPERT_SPEED_MODE,
    GOAL_EDGE,
    RED_STATES,
    ROUTES,
    SumoConfig,
    check_xml_file,
)
from sims.sumo.engine import SumoError
from sims.sumo.expert import predict_sumo_speed
from sims.sumo.reward import step_reward
from sims.sumo.sensing import OBS_SIZE, heading_from_sumo, observe

libsumo = engine.libsumo
_FAILURES: tuple[type[Exception], ...] = (SumoError, *engine.SUMO_ERRORS)
"""Ours and libsumo's: what ends an episode (a starred tuple in ``except`` itself is beyond mypy)."""

__all__ = ["CONFIG_FIELDS", "EGO", "OBS_SIZE", "SumoConfig", "SumoEnv", "libsumo"]


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
        self.config = replaced(config or SumoConfig(), overrides, "SUMO")
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
        check_xml_file(config.network_path(), "net", "network file")
        for path in config.route_paths():
            check_xml_file(path, "routes", "route file")

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
        except _FAILURES as exc:
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
        except _FAILURES as exc:
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
        routes = cfg.route_paths()
        if cfg.random_specials > 0:
            routes.append(variation.specials_file(cfg.route, cfg.random_specials, seed))
        scale = variation.traffic_scale(seed) if cfg.random_density else cfg.traffic_scale
        return [
            "--net-file", str(cfg.network_path()),
            "--route-files", ",".join(str(p) for p in routes),
            "--step-length", repr(cfg.step_length),
            "--seed", str(seed),
            "--scale", repr(scale),
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

        reward = step_reward(
            cfg,
            speed=speed,
            arrived=arrived,
            remaining=ep.remaining,
            route_length=ep.route_length,
            collision=collision,
            red_light=red_light,
        )

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
        heading = heading_from_sumo(angle)
        half = 0.5 * self._ego_length
        self._last_position = (x - half * math.cos(heading), y - half * math.sin(heading))  # front bumper -> centre
        self._last_heading = heading
        self._speed = libsumo.vehicle.getSpeed(EGO)

    def _remaining_distance(self) -> float:
        d = libsumo.vehicle.getDrivingDistance(EGO, GOAL_EDGE, self._goal_pos)
        # SUMO answers a huge negative number when the goal is unreachable (it never is on the ego's route)
        return float(d) if d >= 0.0 else self._episode.remaining

    def _observe(self) -> np.ndarray:
        ep = self._episode
        return observe(
            self.config, self._last_position, self._last_heading, self._speed, ep.remaining / ep.route_length
        )

    def _predict_sumo_speed(self) -> float:
        """SUMO's next speed as its own API computes it (see :func:`sims.sumo.expert.predict_sumo_speed`)."""
        return predict_sumo_speed(
            self.config, self._speed, self._ego_accel, self._ego_decel, self._ego_max_speed, self._roundabout_entries
        )
