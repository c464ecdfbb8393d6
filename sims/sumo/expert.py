"""The SUMO expert: SUMO's own driver model, and its next speed predicted from SUMO's API (the expert's label).

On a takeover the env hands the ego back to SUMO (speed mode 31) for the step, so the expert's driving is exactly
SUMO's; :func:`predict_sumo_speed` gives the action that driving corresponds to before the step is taken.
"""

from __future__ import annotations

import math

from sims.sumo import engine
from sims.sumo.config import EGO, RED_STATES, SumoConfig

libsumo = engine.libsumo

RED_STOP_GAP = 1.0
"""SUMO stops this far before the stop line of a red light (``DIST_TO_STOPLINE_EXPECT_PRIORITY``)."""
FOE_VISIBILITY = 4.5
"""netconvert's default foe visibility distance at a junction (m)."""
ROUNDABOUT_VISIBILITY = 9.0
"""netconvert's ``--roundabouts.visibility-distance`` default (m)."""


def predict_sumo_speed(
    cfg: SumoConfig,
    speed: float,
    accel: float,
    decel_limit: float,
    max_speed: float,
    roundabout_entries: frozenset[str],
) -> float:
    """SUMO's speed for the next step as its own API computes it (the label of the expert's action).

    The bounds mirror what SUMO's vehicle applies (``MSVehicle::planMove``): acceleration and speed limits,
    the Krauss follow speed behind the leader, stopping 1 m before a red light or a yellow one it can still
    stop for, arriving at a link without priority slowly enough to stop within the foe visibility distance,
    stopping at it while it is closed, and slowing down in time for lower speed limits ahead.
    """
    v = speed
    dt = cfg.step_length
    decel = decel_limit
    bounds = [v + accel * dt, max_speed, libsumo.vehicle.getAllowedSpeed(EGO)]

    def reach(target: float, dist: float) -> float:
        # highest speed from which `target` is reached within `dist` (one step of reaction on an Euler grid)
        return math.sqrt(target * target + 2.0 * decel * max(dist - v * dt, 0.0))

    leader = libsumo.vehicle.getLeader(EGO, cfg.perception_range)
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
                visibility = ROUNDABOUT_VISIBILITY if via in roundabout_entries else FOE_VISIBILITY
                bounds.append(reach(math.sqrt(2.0 * decel * visibility), dist))
            for ahead in (via, next_lane):
                if ahead:
                    bounds.append(reach(libsumo.lane.getMaxSpeed(ahead), dist))
    return max(0.0, min(bounds))
