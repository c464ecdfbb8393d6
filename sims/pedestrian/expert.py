"""The scripted cautious expert (privileged: it knows whether a pedestrian waits, where, and its script).

Lane keeping: of the three steering choices, the one whose two-step rollout brings the ego closest to the
lane centre with the smallest heading. Speed: the fastest of brake/maintain/accelerate whose next state can
still stop, at the ``brake`` deceleration, ``MARGIN`` metres before the pedestrian's crossing line while the
pedestrian has not yet cleared the ego lane.
"""

from __future__ import annotations

from sims.pedestrian.config import PedestrianConfig
from sims.pedestrian.world import STEER, Ego, Pedestrian, bicycle_step, ego_front, encode

MARGIN = 2.5
"""Metres the expert keeps between its front and the pedestrian's crossing line."""


def _stopping_distance(v: float, brake: float, dt: float) -> float:
    # one more control period at v before the brake acts, then uniform deceleration
    return v * dt + v * v / (2 * brake)


def expert_action(config: PedestrianConfig, ego: Ego, ped: Pedestrian | None, pedestrian_cleared: bool) -> int:
    """The expert's action index; ``pedestrian_cleared``: the pedestrian has walked past the ego lane."""
    lane_y = config.lane_width / 2

    def lane_cost(steer: int) -> float:
        state = ego
        for _ in range(2):
            state = bicycle_step(state, 0.0, steer * config.steer, config.dt, config)
        return (state.y - lane_y) ** 2 + 8.0 * state.yaw**2

    steer = min(STEER, key=lambda s: (lane_cost(s), abs(s)))
    throttle = 1
    if ped is not None and not pedestrian_cleared:
        for candidate in (1, 0, -1):
            throttle = candidate
            accel = config.accel if candidate > 0 else (-config.brake if candidate < 0 else 0.0)
            nxt = bicycle_step(ego, accel, 0.0, config.dt, config)
            gap = ped.x - ped.radius - ego_front(nxt, config) - MARGIN
            if ego_front(ego, config) > ped.x + ped.radius or _stopping_distance(nxt.v, config.brake, config.dt) <= gap:
                break
    return encode(throttle, steer)
