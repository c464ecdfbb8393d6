"""A small simulator and gate that follow the product's protocols, so the dashboard is tested without
depending on how fast or how finished the real simulators are.

``ToyRobotEnv``: a unicycle in a walled room with two moving discs, a goal and a 24-ray scan;
action Box [-1, 1]^2 = (speed, yaw rate) like the UGV; cost when it touches a disc.
``WaveGate``: fear and threshold as smooth waves; fires on a fixed part of every 40 steps.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np

from app.policies import LoadedPolicy
from core.experts import ExpertPolicy
from core.loop import GateDecision, NoGate

ROOM = 5.0
RAYS = 24


class ToyRobotEnv(gym.Env[np.ndarray, np.ndarray]):
    observation_space = gym.spaces.Box(-np.inf, np.inf, (5 + RAYS,), np.float32)
    action_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
    metadata: ClassVar[dict[str, Any]] = {"render_modes": [], "render_fps": 10}  # drawn by the server, not render()

    def __init__(self, scenario: int | str | None = 1, horizon: int = 200) -> None:
        self.scenario = int(scenario or 1)
        self.horizon = horizon
        self.dt = 0.1
        self.state = np.zeros(3)
        self.t = 0
        self.collided = False
        self.goal = np.array([3.5, 3.5])
        self.rng = np.random.default_rng(0)

    def _discs(self) -> np.ndarray:
        phase = 0.15 * self.t
        return np.array([[1.5 * math.cos(phase), 1.5 * math.sin(phase)], [-2.0, 2.0 * math.sin(0.5 * phase)]])

    def _scan(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        x, y, yaw = self.state
        angles = yaw + np.linspace(-0.75 * math.pi, 0.75 * math.pi, RAYS)
        dirs = np.stack([np.cos(angles), np.sin(angles)], axis=1)
        dist = np.full(RAYS, 4.0)
        for cx, cy in self._discs():
            oc = np.array([x - cx, y - cy])
            b = dirs @ oc
            c = oc @ oc - 0.5**2
            disc = b * b - c
            hit = (disc >= 0) & (-b - np.sqrt(np.maximum(disc, 0)) > 0)
            dist = np.where(hit, np.minimum(dist, -b - np.sqrt(np.maximum(disc, 0))), dist)
        with np.errstate(divide="ignore", invalid="ignore"):
            for axis, pos in ((0, x), (1, y)):
                for wall in (-ROOM, ROOM):
                    d = (wall - pos) / dirs[:, axis]
                    dist = np.where((d > 0) & (d < dist), d, dist)
        ends = np.stack([x + dist * dirs[:, 0], y + dist * dirs[:, 1]], axis=1)
        return dist, ends, dist < 4.0

    def _obs(self) -> np.ndarray:
        dist, _, _ = self._scan()
        x, y, yaw = self.state
        return np.array([x, y, math.cos(yaw), math.sin(yaw), self.t / self.horizon, *dist], np.float32)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        self.state = np.array([-3.5, -3.5, 0.6])
        self.t = 0
        self.collided = False
        return self._obs(), {}

    def step(self, action: np.ndarray):
        a = np.clip(np.asarray(action, dtype=float).reshape(2), -1, 1)
        x, y, yaw = self.state
        yaw += 1.5 * a[1] * self.dt
        x = float(np.clip(x + 0.8 * a[0] * math.cos(yaw) * self.dt, -ROOM + 0.2, ROOM - 0.2))
        y = float(np.clip(y + 0.8 * a[0] * math.sin(yaw) * self.dt, -ROOM + 0.2, ROOM - 0.2))
        self.state = np.array([x, y, yaw])
        self.t += 1
        touching = bool(np.any(np.hypot(*(self._discs() - self.state[:2]).T) < 0.7))
        self.collided |= touching
        reached = bool(np.hypot(*(self.goal - self.state[:2])) < 0.4)
        reward = 1.0 if reached else -0.01
        return self._obs(), reward, reached, self.t >= self.horizon, {"cost": float(touching), "violation": touching}

    def expert_action(self) -> np.ndarray:
        x, y, yaw = self.state
        bearing = math.atan2(self.goal[1] - y, self.goal[0] - x)
        err = (bearing - yaw + math.pi) % (2 * math.pi) - math.pi
        return np.array([0.8, np.clip(2.0 * err, -1, 1)], np.float32)

    def scene(self) -> dict[str, Any]:
        x, y, yaw = self.state
        _, ends, hit = self._scan()
        walls = [
            {"kind": "box", "x": 0.0, "y": ROOM, "yaw": 0.0, "length": 2 * ROOM, "width": 0.15, "color": "#5a6b7d"},
            {"kind": "box", "x": 0.0, "y": -ROOM, "yaw": 0.0, "length": 2 * ROOM, "width": 0.15, "color": "#5a6b7d"},
            {
                "kind": "box",
                "x": ROOM,
                "y": 0.0,
                "yaw": math.pi / 2,
                "length": 2 * ROOM,
                "width": 0.15,
                "color": "#5a6b7d",
            },
            {
                "kind": "box",
                "x": -ROOM,
                "y": 0.0,
                "yaw": math.pi / 2,
                "length": 2 * ROOM,
                "width": 0.15,
                "color": "#5a6b7d",
            },
            {"kind": "polygon", "points": [[-1, -4], [1, -4], [0.5, -3], [-0.5, -3]], "color": "#233040"},
            {"kind": "polyline", "points": [[-4, 0], [-3, 0.5], [-2, 0]], "width": 0.05, "color": "#3f7fbf"},
        ]
        movers = [
            {"kind": "circle", "x": float(cx), "y": float(cy), "radius": 0.5, "color": "#e0703a"}
            for cx, cy in self._discs()
        ]
        return {
            "sim": "toy",
            "bounds": [-ROOM, -ROOM, ROOM, ROOM],
            "static_key": f"toy-{self.scenario}",
            "static": walls,
            "movers": movers,
            "ego": {
                "kind": "box",
                "x": float(x),
                "y": float(y),
                "yaw": float(yaw),
                "length": 0.5,
                "width": 0.4,
                "color": "#3ddc84",
            },
            "goal": {
                "kind": "circle",
                "x": float(self.goal[0]),
                "y": float(self.goal[1]),
                "radius": 0.4,
                "color": "#ffd24a",
            },
            "rays": {"origin": [float(x), float(y)], "ends": ends.tolist(), "hit": hit.tolist()},
            "labels": {"scenario": str(self.scenario)},
        }

    def metrics(self) -> dict[str, float]:
        return {"collision": float(self.collided), "success": float(np.hypot(*(self.goal - self.state[:2])) < 0.4)}


class WaveGate:
    """Fear rises and falls; it crosses the threshold for steps 20..29 of every 40."""

    def __init__(self, period: int = 40, fire_from: int = 20, fire_to: int = 30) -> None:
        self.period, self.fire_from, self.fire_to = period, fire_from, fire_to
        self.t = 0

    def reset(self) -> None:
        self.t = 0

    def decide(self, obs: np.ndarray, a_rl: np.ndarray) -> GateDecision:
        phase = self.t % self.period
        self.t += 1
        fired = self.fire_from <= phase < self.fire_to
        fear = 0.3 + 0.25 * math.sin(2 * math.pi * phase / self.period - math.pi / 2) + (0.3 if fired else 0.0)
        return GateDecision(fear=fear, threshold=0.6 + 0.05 * math.cos(0.1 * self.t), fired=fired)

    def observe(self, obs: np.ndarray, action: np.ndarray, next_obs: np.ndarray) -> float:
        return 0.2 + 0.1 * math.sin(0.23 * self.t)


class Wander:
    """A policy that drives forward and turns slowly."""

    def act(self, obs: np.ndarray, deterministic: bool = False) -> np.ndarray:
        return np.array([0.6, 0.3 * math.sin(8 * float(obs[4]))], np.float32)


def toy_env_factory(sim: str, scenario: str | None) -> gym.Env[Any, Any]:
    if sim not in ("toy", "ugv"):
        raise ValueError(f"unknown simulator {sim!r}")
    return ToyRobotEnv(scenario)


def toy_policy_loader(choice: str, env: gym.Env[Any, Any], gate: Any = None) -> LoadedPolicy:
    if choice == "scripted":
        return LoadedPolicy(ExpertPolicy(env), NoGate(), "scripted expert (no gate)", {})
    if choice == "wave":
        return LoadedPolicy(Wander(), gate or WaveGate(), "wander + wave gate", {})
    if choice == "calm":  # a gate that never fires: every takeover is the person's own
        return LoadedPolicy(Wander(), gate or WaveGate(fire_from=0, fire_to=0), "wander + calm gate", {})
    raise FileNotFoundError(f"no policy at {choice!r}")


def toy_catalogue() -> dict[str, dict[str, Any]]:
    return {
        "toy": {
            "name": "toy",
            "env_id": "toy",
            "available": True,
            "scenarios": [{"id": "1", "label": "1"}, {"id": "2", "label": "2"}],
            "default_scenario": "1",
        },
        "sumo": {"name": "sumo", "env_id": "sage/Sumo-v0", "available": False, "scenarios": []},
    }
