"""Episode metrics of the paper's UGV table, as pure functions of the executed trajectory.

A trajectory is the robot's positions ``xy`` (n, 2) sampled every ``dt`` seconds (the control
period), first sample at the start pose. Curvature and lateral acceleration are taken at interior
samples from the circle through three consecutive positions (its Menger curvature), so a path
sampled from a circle of radius r gives exactly 1/r and, at constant speed, exactly v^2 / r.
Samples where the robot stands still (either neighbouring displacement under ``min_step``) have no
defined path curvature and are left out of both means.
"""

from __future__ import annotations

import numpy as np

METRIC_COLUMNS: tuple[str, ...] = (
    "success",
    "collision",
    "timeout",
    "avg_speed",
    "travel_distance",
    "path_curvature",
    "lateral_acc",
)
"""Keys of :func:`episode_metrics`, in the order of the paper's table (outcomes first)."""

MIN_STEP = 1e-3
"""Displacements shorter than this (m) count as standing still."""


def travel_distance(xy: np.ndarray) -> float:
    """Length of the polyline through the positions (m)."""
    xy = np.asarray(xy, dtype=float)
    if len(xy) < 2:
        return 0.0
    return float(np.hypot(*np.diff(xy, axis=0).T).sum())


def average_speed(xy: np.ndarray, dt: float) -> float:
    """Travel distance over elapsed time (m/s); 0 for fewer than two samples."""
    elapsed = dt * (len(xy) - 1)
    return travel_distance(xy) / elapsed if elapsed > 0 else 0.0


def curvature_profile(xy: np.ndarray, dt: float, min_step: float = MIN_STEP) -> tuple[np.ndarray, np.ndarray]:
    """Per moving interior sample: (unsigned curvature 1/m, speed m/s along the three-point circle)."""
    xy = np.asarray(xy, dtype=float)
    if len(xy) < 3:
        return np.zeros(0), np.zeros(0)
    p0, p1, p2 = xy[:-2], xy[1:-1], xy[2:]
    a = np.hypot(*(p1 - p0).T)
    b = np.hypot(*(p2 - p1).T)
    c = np.hypot(*(p2 - p0).T)
    moving = (a >= min_step) & (b >= min_step)
    a, b, c = a[moving], b[moving], c[moving]
    u, w = (p1 - p0)[moving], (p2 - p1)[moving]
    cross = np.abs(u[:, 0] * w[:, 1] - u[:, 1] * w[:, 0])  # twice the triangle's area
    kappa = 2.0 * cross / (a * b * c)
    # arc length from p0 to p2 on that circle (chord c subtends angle 2 asin(c kappa / 2))
    half_angle = np.arcsin(np.clip(c * kappa / 2.0, 0.0, 1.0))
    safe_kappa = np.where(kappa > 1e-12, kappa, 1.0)
    arc = np.where(kappa > 1e-12, 2.0 * half_angle / safe_kappa, c)
    speed = arc / (2.0 * dt)
    return kappa, speed


def mean_path_curvature(xy: np.ndarray, dt: float = 0.1, min_step: float = MIN_STEP) -> float:
    """Mean unsigned path curvature over moving samples (1/m); 0 when the robot never moved."""
    kappa, _ = curvature_profile(xy, dt, min_step)
    return float(kappa.mean()) if len(kappa) else 0.0


def mean_lateral_acceleration(xy: np.ndarray, dt: float, min_step: float = MIN_STEP) -> float:
    """Mean |v^2 kappa| over moving samples (m/s^2); 0 when the robot never moved."""
    kappa, speed = curvature_profile(xy, dt, min_step)
    return float((speed**2 * kappa).mean()) if len(kappa) else 0.0


def episode_metrics(xy: np.ndarray, dt: float, *, success: bool, collision: bool, timeout: bool) -> dict[str, float]:
    """The row of the paper's table for one episode (keys: :data:`METRIC_COLUMNS`)."""
    return {
        "success": float(success),
        "collision": float(collision),
        "timeout": float(timeout),
        "avg_speed": average_speed(xy, dt),
        "travel_distance": travel_distance(xy),
        "path_curvature": mean_path_curvature(xy, dt),
        "lateral_acc": mean_lateral_acceleration(xy, dt),
    }
