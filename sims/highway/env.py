"""``sage/Highway-v0``: logged highway scenarios, replayed or adversarially resampled (the paper's Waymo study).

Observation (83 numbers in [-1, 1], as the paper's Waymo setup):
  [0:5]   ego kinematics: speed / 40, sin and cos of the heading (the main road runs along +x),
          steering state (last steering angle / max), last acceleration command (/ max accel or brake)
  [5:11]  route guidance: for the next two checkpoints (every 40 m on the ego's current lane along the
          route, the last one at the route end): distance / 80 m (clipped), sin and cos of its bearing
          relative to the ego's heading
  [11:83] 72 LiDAR-style beams over 360° (first straight ahead, counter-clockwise), 50 m range,
          normalised distance to the nearest vehicle box or road edge (1: nothing)
Action: [steer, acc] in [-1, 1]²: steering angle ±0.25 rad, acceleration +3 / -7 m/s².
Reward: progress along the route (d_t - d_{t-1}, metres) - 1 on a crash - 10 on leaving the road.
Cost: 1 on a crash or leaving the road (both end the episode), else 0; ``violation`` the same as a bool.
The episode also ends on reaching the route end (success) and is truncated at the scenario's time limit.
"""

from __future__ import annotations

import dataclasses
import hashlib
from collections.abc import Callable
from typing import Any, Literal, Protocol

import gymnasium as gym
import numpy as np

from core.dotted import replaced
from core.loop import Policy
from core.scene import Scene
from sims.highway.adversary import Event, resample
from sims.highway.config import DEFAULT, HighwayConfig
from sims.highway.drawing import build_scene
from sims.highway.expert import HighwayExpert
from sims.highway.scenarios import N_SCENARIOS, ScenarioSpec, Split, TrafficLog, load_log, scenario_ids
from sims.highway.traffic import Paths
from sims.highway.world import StepResult, World

Mode = Literal["normal", "adversarial"]
EgoPredictor = Policy | Callable[[np.ndarray], np.ndarray] | Literal["expert"]
"""What the CAT step rolls to predict the ego's path: a ``Policy`` (``act(obs, deterministic)``), a
plain ``obs -> action`` function, or ``"expert"`` for the scripted expert."""

OBS_SIZE = 5 + 6 + DEFAULT.sensor.beams


def approach_layout() -> dict[str, int]:
    """``world_model_config`` fields for a world model that also reads each LiDAR beam's approach rate (its
    inverse time to contact, :func:`core.motion.approach_rate`): the beams are the observation's last channels,
    ranges over the sensor's reach."""
    return {"approach_start": OBS_SIZE - DEFAULT.sensor.beams, "approach_stop": OBS_SIZE}


def observe(world: World) -> np.ndarray:
    """The observation of ``world`` (see the module docstring)."""
    cfg = world.cfg
    ex, ey, eh, ev = world.ego_state
    lim, sen = cfg.ego, cfg.sensor
    acc_scale = lim.max_accel if world.accel_cmd >= 0 else lim.max_brake
    kin = [ev / sen.speed_scale, np.sin(eh), np.cos(eh), world.steer / lim.max_steer, world.accel_cmd / acc_scale]
    lane_y = float(world.layout.lane_y(int(world.layout.lane_of(ey))))
    spacing = sen.checkpoint_spacing
    done = ex - world.route_start
    first = (np.floor(max(done, 0.0) / spacing) + 1) * spacing
    guide: list[float] = []
    for s in (first, first + spacing):
        cx = world.route_start + min(s, world.route_length)
        dx, dy = cx - ex, lane_y - ey
        bearing = np.arctan2(dy, dx) - eh
        guide += [min(np.hypot(dx, dy) / (2 * spacing), 1.0), np.sin(bearing), np.cos(bearing)]
    obs = np.concatenate([kin, guide, world.lidar]).astype(np.float32)
    return np.clip(obs, -1.0, 1.0)


def _driver(predictor: EgoPredictor, cfg: HighwayConfig) -> Callable[[World], np.ndarray]:
    """``predictor`` as a function of the world (the expert reads it; policies read the observation)."""
    if isinstance(predictor, str):
        if predictor != "expert":
            raise ValueError(f"unknown ego_predictor {predictor!r}; use 'expert', a Policy or a callable")
        expert = HighwayExpert(cfg)
        return expert.act
    act = getattr(predictor, "act", None)
    if callable(act):
        return lambda world: act(observe(world), deterministic=True)
    if callable(predictor):
        return lambda world: predictor(observe(world))
    raise TypeError(
        "ego_predictor must be 'expert', a Policy (with act) or a callable obs -> action, "
        f"got {type(predictor).__name__}"
    )


def predict_ego_path(
    log: TrafficLog, paths: Paths, cfg: HighwayConfig, predictor: EgoPredictor | None
) -> tuple[np.ndarray, Paths]:
    """The predicted ego path ((F, 4) x, y, heading, speed on the log's frames) and the traffic as it
    moved around that ego (``Paths``; the log itself unless followers yielded to the predicted ego).

    None: the log's reference ego (an IDM/MOBIL driver recorded with the traffic). Otherwise the
    predictor (a policy, or ``"expert"``) is rolled in the log-replay version of the scenario, as CAT
    rolls the current policy; once it stops (crash, off-road, route end) the ego coasts straight on.
    A deterministic ego driven by the same predictor follows this path exactly up to the first
    resampled event, because until then the traffic is the log.
    """
    if predictor is None:
        return log.ego_ref.astype(np.float64), paths
    drive = _driver(predictor, cfg)
    sense = predictor != "expert"  # the expert reads privileged state, not the LiDAR
    world = World(log, paths, cfg)
    every = max(1, round(log.dt / cfg.dt))
    plan = np.zeros((log.frames, 4))
    observed = np.zeros_like(paths.state)
    tr = world.traffic
    plan[0], observed[0] = world.ego_state, np.stack([tr.x, tr.y, tr.heading, tr.speed], axis=-1)
    coast = np.zeros(2)
    stopped = False
    for step in range(1, (log.frames - 1) * every + 1):
        action = coast if stopped else np.asarray(drive(world), dtype=np.float64)
        res = world.step(action, sense=sense and not stopped)
        stopped = stopped or res.crashed or res.offroad or res.success
        if step % every == 0:
            f = step // every
            plan[f] = world.ego_state
            observed[f] = np.stack([tr.x, tr.y, tr.heading, tr.speed], axis=-1)
    return plan, Paths(paths.dt, observed, paths.length, paths.width)


class SpecSource(Protocol):
    """A family of scenario specs, one drawn at each reset (e.g. :class:`sims.highway.families.SpecSelection`)."""

    def draw(self, rng: np.random.Generator) -> tuple[int, ScenarioSpec]:
        """The episode's spec and its index in the family, drawn from the env's seeded generator."""
        ...


class HighwayEnv(gym.Env[np.ndarray, np.ndarray]):
    """Logged highway scenario replay (``mode="normal"``) or CAT-style adversarial variants.

    Keyword overrides change the :class:`~sims.highway.config.HighwayConfig` with dotted names, e.g.
    ``HighwayEnv(split="train", **{"expert.horizon": 1.0})`` (``sage train --set env.expert.horizon=1.0``).
    """

    metadata: dict[str, Any] = {"render_modes": []}  # noqa: RUF012 - gymnasium's convention

    def __init__(
        self,
        scenario_id: int | None = None,
        split: Split = "train",
        mode: Mode = "normal",
        ego_predictor: EgoPredictor | None = None,
        config: HighwayConfig | None = None,
        custom_spec: ScenarioSpec | None = None,
        spec_source: SpecSource | None = None,
        scene_rays: bool | None = None,
        render_mode: str | None = None,
        **overrides: Any,
    ) -> None:
        if mode not in ("normal", "adversarial"):
            raise ValueError(f"unknown mode {mode!r}; choose normal or adversarial")
        if scenario_id is not None and not 0 <= int(scenario_id) < N_SCENARIOS:
            raise ValueError(f"scenario_id {scenario_id} is outside the pool 0..{N_SCENARIOS - 1}")
        if render_mode is not None:
            raise ValueError("the highway sim does not render; draw scene() instead")
        self.ids = scenario_ids(split)  # validates split
        self.split, self.mode = split, mode
        self.scenario_id = None if scenario_id is None else int(scenario_id)
        self.custom_spec = custom_spec
        """A scenario outside the pool (``scenarios.custom_spec``), used instead of the split when given."""
        self.spec_source = spec_source
        """A family of specs (``highway-shift``: :mod:`sims.highway.families`), one drawn at each reset, used instead of
        the split when given."""
        self.source_index: int | None = None
        """The source's index of the current episode's spec (None without a source)."""
        self.cfg = replaced(config or DEFAULT, overrides, "highway")
        if scene_rays is not None:
            self.cfg = dataclasses.replace(self.cfg, scene_rays=scene_rays)
        self.ego_predictor = ego_predictor
        self.render_mode = render_mode
        self.observation_space = gym.spaces.Box(-1.0, 1.0, (OBS_SIZE,), np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
        self.expert = HighwayExpert(self.cfg)
        self.world: World | None = None
        self.log: TrafficLog | None = None
        self.events: list[Event] = []
        self.current_id: int = -1
        self.current_mode: Mode = mode
        self._reset_stats()

    def set_ego_predictor(self, predictor: EgoPredictor | None) -> None:
        """Use ``predictor`` (e.g. the current policy) in the CAT step from the next adversarial reset on."""
        self.ego_predictor = predictor

    # -- gymnasium ------------------------------------------------------------------------------
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        options = options or {}
        mode = options.get("mode", self.mode)
        if mode not in ("normal", "adversarial"):
            raise ValueError(f"unknown mode {mode!r}; choose normal or adversarial")
        if self.spec_source is not None and "scenario_id" not in options:
            self.source_index, spec = self.spec_source.draw(self.np_random)
            log = load_log(spec)
            self.current_id = spec.scenario_id
        elif self.custom_spec is not None and "scenario_id" not in options:
            log = load_log(self.custom_spec)
            self.current_id = self.custom_spec.scenario_id
        else:
            sid = options.get("scenario_id", self.scenario_id)
            if sid is None:
                sid = self.ids[int(self.np_random.integers(len(self.ids)))]
            if not 0 <= int(sid) < N_SCENARIOS:
                raise ValueError(f"scenario_id {sid} is outside the pool 0..{N_SCENARIOS - 1}")
            self.current_id = int(sid)
            log = load_log(self.current_id)
        self.log = log
        self.current_mode = mode
        paths = Paths.from_log(log)
        self.events = []
        if mode == "adversarial":
            # candidates perturb the opponents as they drove around the predicted ego (CAT); only the
            # resampled opponents get a new path, everybody else replays the log
            plan, observed = predict_ego_path(log, paths, self.cfg, self.ego_predictor)
            resampled, self.events = resample(observed, plan, log.spec.layout, self.cfg, self.np_random)
            for event in self.events:
                paths.state[:, event.vehicle] = resampled.state[:, event.vehicle]
                paths.adversarial[event.vehicle] = True
        self.world = World(log, paths, self.cfg)
        self.expert.reset()
        self._reset_stats()
        return observe(self.world), self._info(None)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self.world is None:
            raise RuntimeError("call reset() before step()")
        res = self.world.step(action)
        rw = self.cfg.reward
        reward = rw.progress_weight * res.progress + rw.crash_reward * res.crashed + rw.offroad_reward * res.offroad
        terminated = res.crashed or res.offroad or res.success
        self._record(res)
        return observe(self.world), float(reward), bool(terminated), bool(res.timeout), self._info(res)

    # -- simulator protocol ---------------------------------------------------------------------
    def expert_action(self) -> np.ndarray:
        if self.world is None:
            raise RuntimeError("call reset() before expert_action()")
        return self.expert.act(self.world)

    def scene(self) -> Scene:
        if self.world is None:
            raise RuntimeError("call reset() before scene()")
        assert self.log is not None
        w = self.world
        labels = {
            "scenario": f"{self.current_id} ({self.log.spec.layout.kind}, {self.log.spec.layout.lanes} lanes)",
            "mode": self.current_mode,
            "t": f"{w.t:.1f}/{w.time_limit:.1f} s",
            "progress": f"{w.progress:.0f}/{w.route_length:.0f} m",
            "speed": f"{w.ego.speed:.1f} m/s",
        }
        key = f"highway/{self.current_id}/{hashlib.sha1(repr(self.log.spec.layout).encode()).hexdigest()[:8]}"
        return build_scene(w, key, labels, self.cfg.scene_rays, self.log.behaviour)

    def metrics(self) -> dict[str, float]:
        st = self._stats
        speeds = np.asarray(st["speed"]) if st["speed"] else np.zeros(1)
        accs = np.asarray(st["acc"]) if st["acc"] else np.zeros(1)
        return {
            "success": float(st["success"]),
            "collision": float(st["crashed"]),
            "off_road": float(st["offroad"]),
            "timeout": float(st["timeout"]),
            "speed_mean": float(speeds.mean()),
            "speed_std": float(speeds.std()),
            "acc_mean": float(accs.mean()),
            "acc_std": float(accs.std()),
            "min_ttc": float(min(st["ttc"])) if st["ttc"] else self.cfg.sensor.ttc_cap,
            "mean_gap": float(np.mean(st["gap"])) if st["gap"] else self.cfg.sensor.gap_cap,
            "mean_nearest_gap": float(np.mean(st["nearest_gap"])) if st["nearest_gap"] else self.cfg.sensor.gap_cap,
            "progress": float(self.world.progress / max(self.world.route_length, 1e-6)) if self.world else 0.0,
            "scenario_id": float(self.current_id),
            "adversarial": float(self.current_mode == "adversarial"),
            "adversary_events": float(len(self.events)),
        }

    # -- internals ------------------------------------------------------------------------------
    def _reset_stats(self) -> None:
        self._stats: dict[str, Any] = {
            "speed": [],
            "acc": [],
            "ttc": [],
            "gap": [],
            "nearest_gap": [],
            "success": False,
            "crashed": False,
            "offroad": False,
            "timeout": False,
        }

    def _record(self, res: StepResult) -> None:
        st = self._stats
        if st["success"] or st["crashed"] or st["offroad"] or st["timeout"]:
            return  # stepping past the end changes nothing in the episode's metrics
        assert self.world is not None
        st["speed"].append(float(self.world.ego.speed))
        st["acc"].append(abs(res.accel))
        st["ttc"].append(res.ttc)
        st["gap"].append(res.lead_gap)
        st["nearest_gap"].append(res.gap)
        st["success"] |= res.success
        st["crashed"] |= res.crashed
        st["offroad"] |= res.offroad
        st["timeout"] |= res.timeout

    def _info(self, res: StepResult | None) -> dict[str, Any]:
        assert self.world is not None
        violation = bool(res is not None and (res.crashed or res.offroad))
        info: dict[str, Any] = {
            "cost": float(violation),
            "violation": violation,
            "crashed": bool(res.crashed) if res else False,
            "offroad": bool(res.offroad) if res else False,
            "success": bool(res.success) if res else False,
            "ttc": res.ttc if res else self.cfg.sensor.ttc_cap,
            "gap": res.lead_gap if res else self.cfg.sensor.gap_cap,
            "nearest_gap": res.gap if res else self.cfg.sensor.gap_cap,
            "conflict": bool(
                res is not None and (res.ttc < self.cfg.reward.conflict_ttc or res.gap < self.cfg.reward.conflict_gap)
            ),
            "progress": self.world.progress,
            "scenario_id": self.current_id,
            "mode": self.current_mode,
        }
        if res is None:
            info["adversary_events"] = [e.__dict__ for e in self.events]
        return info
