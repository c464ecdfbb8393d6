"""Lean replay of surrounding vehicles along recorded (or adversarially resampled) paths.

Vehicles are not highway-env objects at run time: all of them are numpy arrays, stepped together.
Each vehicle follows its path exactly in time (log replay, non-reactive) except, when
``reactive_followers`` is on, in the two situations where a logged driver would drive into an ego that
is not where the log's reference ego was:

- **rear-end**: the ego is right ahead of it in its path. It slows down by IDM (the ego as its leader)
  while staying on its own logged path, and from then on moves along that path at its own speed
  (never faster than the log at the same place): it may lag behind the log, never leaves its path.
- **side-swipe**: it is alongside the ego and its logged lane change would close the lateral gap to
  under a metre. It holds its lateral position until the ego is clear, then resumes its logged
  lateral position at a lane-change pace.

Resampled (adversarial) opponents never yield sideways: their cut-in is the point of the scenario.
"""

from __future__ import annotations

import numpy as np

from sims.highway.config import TrafficConfig
from sims.highway.scenarios import TrafficLog
from sims.highway.sensing import half_extents


class Paths:
    """What the surrounding vehicles will do: their poses on a regular time grid.

    ``x``, ``y``, ``heading``, ``speed`` are (F, N) views into one (F, N, 4) array, so that
    interpolating all four is one operation; writing into a view writes the path.
    """

    def __init__(
        self,
        dt: float,
        state: np.ndarray,
        length: np.ndarray,
        width: np.ndarray,
        adversarial: np.ndarray | None = None,
    ) -> None:
        self.dt = float(dt)
        self.state = np.ascontiguousarray(state, dtype=np.float64)
        self.length = np.asarray(length, dtype=np.float64)
        self.width = np.asarray(width, dtype=np.float64)
        self.adversarial = np.zeros(self.length.shape, dtype=bool) if adversarial is None else adversarial
        """(N,) True for opponents whose behaviour was resampled."""

    x = property(lambda self: self.state[:, :, 0])
    y = property(lambda self: self.state[:, :, 1])
    heading = property(lambda self: self.state[:, :, 2])
    speed = property(lambda self: self.state[:, :, 3])

    @staticmethod
    def from_log(log: TrafficLog) -> Paths:
        return Paths(log.dt, np.stack([log.x, log.y, log.heading, log.speed], axis=-1), log.length, log.width)

    def copy(self) -> Paths:
        return Paths(self.dt, self.state.copy(), self.length.copy(), self.width.copy(), self.adversarial.copy())

    @property
    def frames(self) -> int:
        return int(self.x.shape[0])

    @property
    def count(self) -> int:
        return int(self.x.shape[1])

    def arc_length(self) -> np.ndarray:
        """(F, N) distance travelled along each path since frame 0."""
        step = np.hypot(np.diff(self.x, axis=0), np.diff(self.y, axis=0))
        return np.vstack([np.zeros((1, self.count)), np.cumsum(step, axis=0)])

    def at(self, t: np.ndarray | float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """x, y, heading, speed of every vehicle at path time(s) ``t`` (one per vehicle, or one for all).

        Linear interpolation between frames; beyond the last frame a vehicle keeps its last velocity.
        """
        last = self.frames - 1
        if np.ndim(t) == 0:  # everybody in sync with the log: plain slices
            pos = float(t) / self.dt
            f0 = min(max(int(np.floor(pos)), 0), last)
            p0, p1 = self.state[f0], self.state[min(f0 + 1, last)]
            a: np.ndarray | float = min(max(pos - f0, 0.0), 1.0)
            beyond: np.ndarray | float = max(pos - last, 0.0) * self.dt
        else:
            positions = np.asarray(t, dtype=np.float64) / self.dt
            f0 = np.clip(np.floor(positions).astype(int), 0, last)
            cols = np.arange(self.count)
            p0, p1 = self.state[f0, cols], self.state[np.minimum(f0 + 1, last), cols]
            a = np.clip(positions - f0, 0.0, 1.0)[:, None]
            beyond = np.maximum(positions - last, 0.0) * self.dt
        d = p1 - p0
        d[:, 2] = (d[:, 2] + np.pi) % (2 * np.pi) - np.pi
        p = p0 + a * d
        x, y, h, v = p[:, 0], p[:, 1], p[:, 2], p[:, 3]
        if np.any(beyond):
            x = x + beyond * v * np.cos(h)
            y = y + beyond * v * np.sin(h)
        return x, y, h, v


class Traffic:
    """Surrounding vehicles during one episode. ``step`` advances them by ``dt`` given the ego's pose."""

    def __init__(self, paths: Paths, cfg: TrafficConfig, dt: float, ego_length: float, ego_width: float) -> None:
        self.paths = paths
        self.cfg = cfg
        self.dt = dt
        self.ego_length, self.ego_width = ego_length, ego_width
        self.arc = paths.arc_length()
        self.times = np.arange(paths.frames) * paths.dt
        n = paths.count
        self.t = 0.0
        self.tau = np.zeros(n)
        """Each vehicle's own path time (equal to ``t`` while it is in sync with the log)."""
        self.lagging = np.zeros(n, dtype=bool)
        self.sigma = np.zeros(n)
        """Distance travelled along the path (kept for lagging vehicles)."""
        self.x, self.y, self.heading, self.speed = (a.copy() for a in paths.at(0.0))
        self.accel = np.zeros(n)
        self.yielding = np.zeros(n, dtype=bool)
        """Vehicles that deviated from their log this step to spare the ego (for drawing and tests)."""
        self.lateral_offset = np.zeros(n)
        """Lateral deviation from the logged path of vehicles that held back a lane change [m]."""

    @property
    def length(self) -> np.ndarray:
        return self.paths.length

    @property
    def width(self) -> np.ndarray:
        return self.paths.width

    def velocity(self) -> tuple[np.ndarray, np.ndarray]:
        return self.speed * np.cos(self.heading), self.speed * np.sin(self.heading)

    def _follower_accel(self, ego: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """IDM acceleration of each vehicle towards the ego as its leader, and who has it as a leader."""
        ex, ey, eh, ev = ego
        c, s = np.cos(self.heading), np.sin(self.heading)
        rx, ry = ex - self.x, ey - self.y
        dx = rx * c + ry * s
        dy = -rx * s + ry * c
        gap = dx - (self.length + self.ego_length) / 2
        overlap = np.abs(dy) < (self.width + self.ego_width) / 2 + 0.3
        behind_ego = overlap & (dx > 0) & (gap < 60.0)
        if not behind_ego.any():
            return np.zeros_like(dx), behind_ego
        cfg = self.cfg
        v = self.speed
        ego_along = ev * np.cos(eh - self.heading)
        comfort, brake = 2.0, 3.0
        desired = (
            cfg.follower_min_gap + v * cfg.follower_time_gap + v * (v - ego_along) / (2 * np.sqrt(comfort * brake))
        )
        desired = np.maximum(desired, cfg.follower_min_gap)
        acc = -comfort * (desired / np.maximum(gap, 0.1)) ** 2
        return acc, behind_ego

    def step(self, ego: np.ndarray) -> None:
        """Advance by ``dt``; ``ego`` is (x, y, heading, speed) of the ego after its own step."""
        dt = self.dt
        t_next = self.t + dt
        in_sync = ~self.lagging
        tau_next = np.where(in_sync, t_next, self.tau)
        pose = self.paths.at(tau_next if self.lagging.any() else t_next)
        v_log_next = pose[3]
        new_speed = np.where(in_sync, v_log_next, self.speed)
        yielding = np.zeros(self.paths.count, dtype=bool)
        if self.cfg.reactive_followers:
            acc, behind = self._follower_accel(ego)
            # a vehicle yields when IDM asks it to brake noticeably for the ego and its log would not slow
            # down as much; a distant ego ahead leaves the replay untouched
            wants = self.speed + np.maximum(acc, -self.cfg.follower_max_brake) * dt
            yielding = behind & (acc < -1.0) & (wants < np.where(in_sync, v_log_next, self.speed))
            new_speed = np.where(yielding, np.maximum(wants, 0.0), new_speed)
        start_lag = yielding & in_sync
        if start_lag.any():
            self.lagging |= start_lag
            idx = np.flatnonzero(start_lag)
            self.sigma[idx] = [np.interp(self.tau[i], self.times, self.arc[:, i]) for i in idx]
        lag = np.flatnonzero(self.lagging)
        for i in lag:
            # a lagging vehicle drives its path at its own speed, never faster than the log at that place
            v_here = np.interp(self.tau[i], self.times, self.paths.speed[:, i])
            v = new_speed[i] if yielding[i] else min(v_here, self.speed[i] + 2.0 * dt)
            v = max(v, 0.0)
            self.sigma[i] += 0.5 * (self.speed[i] + v) * dt
            log_sigma = np.interp(t_next, self.times, self.arc[:, i], right=np.inf)
            if self.sigma[i] >= log_sigma - 1e-6 and not yielding[i]:
                self.lagging[i] = False  # caught up with the log (the logged vehicle stopped)
                tau_next[i] = t_next
                continue
            tau_next[i] = (
                np.interp(self.sigma[i], self.arc[:, i], self.times)
                if self.sigma[i] <= self.arc[-1, i]
                else (self.times[-1] + (self.sigma[i] - self.arc[-1, i]) / max(v, 0.1))
            )
            new_speed[i] = v
        x, y, h, v_path = self.paths.at(tau_next) if lag.size else pose
        speed = np.where(self.lagging, new_speed, v_path)
        if self.cfg.reactive_followers:
            y, h, held = self._hold_lane_changes(ego, x, y, h)
            yielding |= held
        self.accel = (speed - self.speed) / dt
        self.x, self.y, self.heading, self.speed = x, y, h, speed
        self.tau = tau_next
        self.t = t_next
        self.yielding = yielding

    def _hold_lane_changes(
        self, ego: np.ndarray, x: np.ndarray, y_log: np.ndarray, h_log: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Lateral positions and headings after non-adversarial vehicles spared the ego's side."""
        ex, ey = ego[0], ego[1]
        recover = 1.0 * self.dt  # lateral pace when resuming the logged lane position [m/step]
        offset = np.sign(self.lateral_offset) * np.maximum(np.abs(self.lateral_offset) - recover, 0.0)
        y = y_log + offset
        half_x, half_y = half_extents(self.length, self.width, h_log)
        alongside = np.abs(x - ex) < half_x + self.ego_length / 2 + 3.0
        toward = (y - self.y) * np.sign(ey - self.y) > 1e-3
        close = np.abs(y - ey) - half_y - self.ego_width / 2 < 1.0
        held = alongside & toward & close & ~self.paths.adversarial
        y = np.where(held, self.y, y)
        self.lateral_offset = y - y_log
        moved = np.hypot(x - self.x, y - self.y) > 0.05
        deviating = (np.abs(self.lateral_offset) > 1e-6) & moved
        h = np.where(deviating, np.arctan2(y - self.y, np.maximum(x - self.x, 1e-3)), h_log)
        return y, h, held
