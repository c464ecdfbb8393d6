"""The SUMO observation encoder (29 values in [-1, 1], described in :mod:`sims.sumo.env`), read from libsumo."""

from __future__ import annotations

import math

import numpy as np

from sims.sumo import engine
from sims.sumo.config import EGO, SumoConfig

libsumo = engine.libsumo

SECTORS = ("front", "rear", "left_front", "left_rear", "right_front", "right_rear")
OBS_SIZE = 4 * len(SECTORS) + 5
EMPTY_SECTOR = (1.0, 0.0, 0.0, 0.0)
TLS_STATE_VALUE = {"G": 0.0, "g": 0.0, "s": 0.0, "y": 0.5, "Y": 0.5, "u": 0.5, "r": 1.0, "R": 1.0}
"""Light state -> observation value (how strongly it says stop); unknown or off reads 0."""


def wrap(angle: float) -> float:
    """An angle wrapped to [-pi, pi)."""
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


def heading_from_sumo(sumo_angle_deg: float) -> float:
    """SUMO's angle (degrees, 0 = north, clockwise) -> heading (radians, 0 = east, counter-clockwise)."""
    return wrap(math.radians(90.0 - sumo_angle_deg))


def observe(
    cfg: SumoConfig, position: tuple[float, float], heading: float, speed: float, remaining_fraction: float
) -> np.ndarray:
    """The ego's observation now: six neighbour sectors, its speed and heading, the next light, route left.

    ``position`` is the ego's centre, ``heading`` in radians (x east, counter-clockwise), ``remaining_fraction``
    the remaining route distance over the route length.
    """
    rng = cfg.perception_range
    vs = cfg.speed_scale
    ego_x, ego_y = position
    he = heading
    ve = speed
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
        h = heading_from_sumo(var[libsumo.VAR_ANGLE])
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
            (dist / rng, wrap(h - he) / math.pi, (v - ve) / vs, direction / math.pi),
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
    obs.append(remaining_fraction)
    return np.clip(np.asarray(obs, dtype=np.float32), -1.0, 1.0)
