"""The scripted expert: IDM/MOBIL driving, checked every step by a short-horizon safety forecast that
falls back to graded emergency braking or an evasive lane change.

Privileged state: it reads every vehicle's true position, velocity (lateral velocity included, so a
cut-in is seen as it starts) and acceleration, not the LiDAR. It does not read the future of the log.

Each step:
1. IDM towards the leader of the ego's lane and, while changing lanes, of the target lane. A vehicle
   counts as a lane's occupant when it covers at least half a metre of it now or will be in it within
   a second at its current lateral velocity.
2. MOBIL, at most once per ``lane_change_interval``, for a discretionary lane change (incentive and
   safety for the new follower).
   Defensive driving: riding alongside a vehicle in a neighbouring lane that would stay beside the ego for more
   than ``alongside_time``, it aims to drive ``alongside_speed_gap`` slower than that vehicle (braking at most
   ``comfort_brake``) and so drops back; beside the ego, a cut-in leaves no gap that braking could open in time.
3. Forecast: the nominal command and alternatives (target lane ∈ current, left, right; acceleration ∈
   nominal, 0, -2, -4, -max brake, +max accel) are rolled over ``horizon`` against every vehicle moving
   at constant acceleration and lateral velocity. The nominal command is used when it stays clear;
   otherwise the alternative whose first conflict comes latest (none at all is best), preferring the
   current target lane and the mildest braking.
4. A cascaded lateral controller (lateral position -> heading -> yaw rate -> steering angle, as
   highway-env's ``ControlledVehicle``) steers to the target lane's centre.
"""

from __future__ import annotations

from typing import cast

import numpy as np

from sims.highway.config import HighwayConfig
from sims.highway.road import LANE_WIDTH
from sims.highway.sensing import half_extents
from sims.highway.world import World


class HighwayExpert:
    def __init__(self, cfg: HighwayConfig) -> None:
        self.cfg = cfg
        self.reset()

    def reset(self) -> None:
        self.target_lane: int | None = None
        self.last_choice = "idle"
        """What the last action was: ``nominal`` (IDM/MOBIL), or the safety check's ``brake``, ``escape``
        (speeding up away from a threat) or ``evasive`` (a lane change)."""
        self.last_step = -10
        self.last_lane_decision = -1e9
        self.evasive_until = -1e9
        self.last_emergency: tuple[int, float] | None = None

    # -- helpers ------------------------------------------------------------------------------
    def _idm(self, v: float, v0: float, gap: float, v_lead: float) -> float:
        e = self.cfg.expert
        free = 1.0 - (max(v, 0.0) / max(v0, 0.1)) ** e.delta
        if not np.isfinite(gap):
            return e.comfort_accel * free
        desired = (
            e.min_gap + max(v, 0.0) * e.time_gap + v * (v - v_lead) / (2 * np.sqrt(e.comfort_accel * e.comfort_brake))
        )
        desired = max(desired, e.min_gap)
        return e.comfort_accel * (free - (desired / max(gap, 0.1)) ** 2)

    @staticmethod
    def _occupies(world: World, lane: int, vy: np.ndarray) -> np.ndarray:
        tr = world.traffic
        yl = float(world.layout.lane_y(lane))
        _, half_y = half_extents(tr.length, tr.width, tr.heading)
        now = np.abs(tr.y - yl) < LANE_WIDTH / 2 + half_y - 0.5
        soon = np.abs(tr.y + vy * 1.0 - yl) < LANE_WIDTH / 2
        return now | soon

    def _neighbours(self, world: World, lane: int, vy: np.ndarray) -> tuple[int | None, int | None]:
        """Indices of the leader and follower of the ego in ``lane`` (None when there is none)."""
        tr = world.traffic
        ex = world.ego.position[0]
        occ = self._occupies(world, lane, vy)
        dx = tr.x - ex
        ahead = np.flatnonzero(occ & (dx > 0))
        behind = np.flatnonzero(occ & (dx <= 0))
        lead = int(ahead[np.argmin(dx[ahead])]) if ahead.size else None
        follow = int(behind[np.argmax(dx[behind])]) if behind.size else None
        return lead, follow

    def _lane_accel(self, world: World, lane: int, vy: np.ndarray) -> float:
        tr = world.traffic
        lead, _ = self._neighbours(world, lane, vy)
        v = world.ego.speed
        v0 = world.layout.speed_limit
        if lead is None:
            return self._idm(v, v0, np.inf, v)
        gap = tr.x[lead] - world.ego.position[0] - (tr.length[lead] + self.cfg.ego.length) / 2
        return self._idm(v, v0, gap, tr.speed[lead] * np.cos(tr.heading[lead]))

    def _alongside_accel(self, world: World, current: int, vy: np.ndarray) -> float:
        """The acceleration that drops the ego back from the vehicles riding alongside it in a neighbouring lane
        for longer than ``alongside_time`` (inf where there is none)."""
        e = self.cfg.expert
        if e.alongside_time <= 0:
            return np.inf
        tr = world.traffic
        ex, v = world.ego.position[0], world.ego.speed
        dx = tr.x - ex
        zone = (tr.length + self.cfg.ego.length) / 2 + e.margin_long
        v_other = tr.speed * np.cos(tr.heading)
        closing = v_other - v
        with np.errstate(divide="ignore", invalid="ignore"):
            # how long each one stays within the zone beside the ego at the present speeds
            stays = np.where(
                closing > 0.1, (zone - dx) / closing, np.where(closing < -0.1, (dx + zone) / -closing, np.inf)
            )
        neighbouring = np.zeros(dx.shape, dtype=bool)
        for lane in (current - 1, current + 1):
            if 0 <= lane < world.layout.lanes:
                neighbouring |= self._occupies(world, lane, vy)
        beside = neighbouring & (np.abs(dx) < zone) & (stays > e.alongside_time)
        if not beside.any():
            return np.inf
        target = float(v_other[beside].min()) - e.alongside_speed_gap  # the slowest of them sets the pace
        return max((target - v) / e.alongside_time, -e.comfort_brake)

    def _mobil(self, world: World, current: int, vy: np.ndarray) -> int:
        e = self.cfg.expert
        tr = world.traffic
        ex = world.ego.position[0]
        v = world.ego.speed
        a_here = self._lane_accel(world, current, vy)
        best, best_gain = current, e.lane_change_gain
        for lane in (current - 1, current + 1):
            if not 0 <= lane < world.layout.lanes:
                continue
            lead, follow = self._neighbours(world, lane, vy)
            if follow is not None:
                gap_f = ex - tr.x[follow] - (tr.length[follow] + self.cfg.ego.length) / 2
                if gap_f < 2.0:
                    continue
                vf = tr.speed[follow]
                a_follow_after = self._idm(vf, max(vf, 1.0), gap_f, v)
                if a_follow_after < -e.lane_change_safe_brake:
                    continue
            if lead is not None:
                gap_l = tr.x[lead] - ex - (tr.length[lead] + self.cfg.ego.length) / 2
                if gap_l < 2.0 + 0.5 * v:
                    continue
            gain = self._lane_accel(world, lane, vy) - a_here
            if follow is not None:
                gain -= e.politeness * max(0.0, -self._idm(tr.speed[follow], max(tr.speed[follow], 1.0), gap_f, v))
            if gain > best_gain:
                best, best_gain = lane, gain
        return best

    # -- forecast -----------------------------------------------------------------------------
    def _conflict_times(
        self, world: World, lanes: np.ndarray, accels: np.ndarray, evasive: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """First time each candidate (lane, accel) touches another vehicle (hard) or its safety margin (soft).

        inf when it never does within the horizon.
        """
        e = self.cfg.expert
        tr = world.traffic
        ex, ey, _, ev = world.ego_state
        t = np.arange(1, round(e.horizon / e.forecast_dt) + 1) * e.forecast_dt  # (K,)
        lim = self.cfg.ego
        none = np.full(len(accels), np.inf)
        v_c = np.clip(ev + accels[:, None] * t[None, :], 0.0, lim.max_speed)  # (C, K)
        v_start = np.concatenate([np.full((len(accels), 1), ev), v_c[:, :-1]], axis=1)
        x_c = ex + np.cumsum(0.5 * (v_start + v_c) * e.forecast_dt, axis=1)
        y_target = world.layout.lane_y(lanes)[:, None]
        tau = np.where(evasive, e.evasive_lateral_time, e.lateral_time)[:, None] + 0.3
        y_c = y_target + (ey - y_target) * np.exp(-t[None, :] / tau)
        near = np.abs(tr.x - ex) < 120.0
        if not near.any():
            return none, none.copy()
        # others: constant acceleration along their heading (no reversing), lateral drift capped at one lane
        c, s = np.cos(tr.heading[near]), np.sin(tr.heading[near])
        v_o = np.maximum(tr.speed[near][:, None] + tr.accel[near][:, None] * t[None, :], 0.0)  # (N, K)
        v_prev = np.concatenate([tr.speed[near][:, None], v_o[:, :-1]], axis=1)
        along = np.cumsum(0.5 * (v_prev + v_o) * e.forecast_dt, axis=1)
        x_o = tr.x[near][:, None] + along * c[:, None]
        y_o = tr.y[near][:, None] + np.clip(along * s[:, None], -LANE_WIDTH, LANE_WIDTH)
        hx, hy = half_extents(tr.length[near], tr.width[near], tr.heading[near])
        half_long = (hx + lim.length / 2)[None, :, None]
        half_lat = (hy + lim.width / 2)[None, :, None]
        dx = np.abs(x_o[None] - x_c[:, None, :])  # (C, N, K)
        dy = np.abs(y_o[None] - y_c[:, None, :])
        hard = (dx < half_long + 0.3) & (dy < half_lat + 0.1)
        soft = (dx < half_long + e.margin_long) & (dy < half_lat + e.margin_lat)
        if self.cfg.traffic.reactive_followers:
            # followers right behind in the ego's own lane yield to it (traffic.py), as long as it stays there
            follower = ((tr.x[near] - ex) < -half_long[0, :, 0]) & (np.abs(tr.y[near] - ey) < half_lat[0, :, 0] + 0.3)
            stays = (lanes == int(world.layout.lane_of(ey)))[:, None, None]
            hard &= ~(stays & follower[None, :, None])
            soft &= ~(stays & follower[None, :, None])

        def first(hit: np.ndarray) -> np.ndarray:
            # numpy's stub types any(axis=...) as a scalar or an array; of a (C, N, K) array it is an array
            any_k = cast(np.ndarray, hit.any(axis=1))  # (C, K)
            return np.where(any_k.any(axis=1), t[np.argmax(any_k, axis=1)], np.inf)

        return first(hard), first(soft)

    # -- the action ---------------------------------------------------------------------------
    def act(self, world: World) -> np.ndarray:
        """Normalised [steer, acc] for the world's current state."""
        cfg, e = self.cfg, self.cfg.expert
        lay = world.layout
        _ex, ey, _eh, _ev = world.ego_state
        current = int(lay.lane_of(ey))
        if self.target_lane is None or world.steps != self.last_step + 1:
            self.reset()  # not called last step (someone else drove): start from the present lane
            self.target_lane = current
        self.last_step = world.steps
        tr = world.traffic
        vy = tr.speed * np.sin(tr.heading)
        target = int(np.clip(self.target_lane, 0, lay.lanes - 1))
        changing = abs(ey - float(lay.lane_y(target))) > 0.6
        if (
            not changing
            and world.t - self.last_lane_decision >= e.lane_change_interval
            and world.t >= self.evasive_until
        ):
            self.last_lane_decision = world.t
            target = self._mobil(world, current, vy)
        a_nom = self._lane_accel(world, current, vy)
        if target != current:
            a_nom = min(a_nom, self._lane_accel(world, target, vy))
        a_nom = min(a_nom, self._alongside_accel(world, current, vy))
        lim = cfg.ego
        a_nom = float(np.clip(a_nom, -lim.max_brake, lim.max_accel))

        lanes = [target] + [
            lane for lane in (current - 1, current, current + 1) if 0 <= lane < lay.lanes and lane != target
        ]
        accels = sorted({a_nom, 0.0, -2.0, -4.0, -lim.max_brake, lim.max_accel})
        cand_l = np.array([lane for lane in lanes for _ in accels])
        cand_a = np.array([a for _ in lanes for a in accels])
        evasive = cand_l != target
        t_hard, t_soft = self._conflict_times(world, cand_l, cand_a, evasive)
        nominal = int(np.flatnonzero((cand_l == target) & (cand_a == a_nom))[0])
        if np.isinf(t_soft[nominal]):
            lane, acc = target, a_nom
            self.last_choice = "nominal"
        else:
            # lexicographic: latest touch, then latest margin violation, then the mildest change
            cap = e.horizon + 1.0
            score = 1000.0 * np.minimum(t_hard, cap) + 10.0 * np.minimum(t_soft, cap)
            score -= 1.0 * (cand_l != target) + 0.1 * np.abs(cand_a - a_nom)
            if self.last_emergency is not None:
                same = (cand_l == self.last_emergency[0]) & (np.abs(cand_a - self.last_emergency[1]) < 1e-6)
                score += 0.5 * same  # hold a manoeuvre rather than dither between equals
            best = int(np.argmax(score))
            lane, acc = int(cand_l[best]), float(cand_a[best])
            if lane != target:
                self.evasive_until = world.t + 1.5
            self.last_choice = "evasive" if lane != target else ("brake" if acc < a_nom else "escape")
        self.last_emergency = None if self.last_choice == "nominal" else (lane, acc)
        self.target_lane = lane
        steer = self._steer(world, lane, evasive=world.t < self.evasive_until)
        acc_norm = acc / lim.max_accel if acc >= 0 else acc / lim.max_brake
        return np.array([steer, np.clip(acc_norm, -1.0, 1.0)], dtype=np.float32)

    def _steer(self, world: World, lane: int, evasive: bool) -> float:
        e, lim = self.cfg.expert, self.cfg.ego
        _, ey, eh, ev = world.ego_state
        v = max(ev, 1.0)
        err = ey - float(world.layout.lane_y(lane))
        lat_time = e.evasive_lateral_time if evasive else e.lateral_time
        max_heading = e.evasive_max_heading if evasive else e.max_heading
        heading_ref = np.clip(np.arcsin(np.clip(-err / lat_time / v, -1.0, 1.0)), -max_heading, max_heading)
        yaw_rate = (heading_ref - eh) / e.heading_time
        slip = np.arcsin(np.clip(lim.length / 2 / v * yaw_rate, -1.0, 1.0))
        steer = np.arctan(2 * np.tan(slip))
        return float(np.clip(steer / lim.max_steer, -1.0, 1.0))
