"""What the simulator knows of the robot's encounters with movers and the world model must infer: the true time to
contact and the nearest gap (privileged; the reference gates of ``experiments/oracle_gate.py`` read them, and the
near-miss flag ``info["conflict"]`` can join the world model's violation label, as on highway).

Time to contact: holding its last command (v, w) (the unicycle's constant motion, as the traffic literature's time
to contact holds the speeds), when the footprint's three circles (the expert's, :mod:`sims.ugv.expert`) would first
touch a mover's own box or circle on its scripted future path. Movers only: the static obstacles are what the policy
was trained among, and a constant arc meets a corridor's wall soon on every bend of a passage it drives through.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from sims.ugv.config import RobotConfig
from sims.ugv.expert import footprint_centres, footprint_radius, mover_distances, unicycle_poses
from sims.ugv.scenario import MoverPlan


def interaction_stats(
    pose: tuple[float, float, float],
    command: tuple[float, float],
    mover_poses: np.ndarray,
    movers: Sequence[MoverPlan],
    robot: RobotConfig,
    dt: float,
) -> tuple[float, float]:
    """(time to contact [s], nearest gap [m]) of the robot at ``pose`` holding ``command`` (v m/s, w rad/s) among
    ``movers`` whose poses from now on are ``mover_poses`` ((M, 1 + T, 3): now, then after each step). inf where
    no mover is touched within the T steps, or there is none; the gap is 0 in contact."""
    if not movers:
        return math.inf, math.inf
    x, y, yaw = pose
    steps = mover_poses.shape[1] - 1
    v, w = np.full((1, steps), command[0]), np.full((1, steps), command[1])
    px, py, heading = unicycle_poses(x, y, yaw, v, w, dt)  # (1, T) poses after each step
    px = np.concatenate([[[x]], px], axis=1)
    py = np.concatenate([[[y]], py], axis=1)
    heading = np.concatenate([[[yaw]], heading], axis=1)
    cx, cy = footprint_centres(px, py, heading, robot)  # (1, 1 + T, 3)
    gaps = mover_distances(cx, cy, mover_poses, movers)[0].min(axis=(0, 2)) - footprint_radius(robot)  # (1 + T,)
    touching = np.flatnonzero(gaps <= 0.0)
    ttc = float(touching[0]) * dt if len(touching) else math.inf
    return ttc, max(float(gaps[0]), 0.0)
