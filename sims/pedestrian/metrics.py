"""Episode metrics of the pedestrian study: success, collision, time-to-collision, speed, acceleration
variability."""

from __future__ import annotations

import math

import numpy as np

from sims.pedestrian.config import PedestrianConfig
from sims.pedestrian.world import Ego, ego_front

METRIC_COLUMNS = ("success", "collision", "min_ttc", "avg_speed", "acc_std")
TTC_CAP = 10.0
"""Time-to-collision is capped here (s): no conflict counts as this."""


def time_to_collision(ego: Ego, pedestrian: tuple[float, float] | None, config: PedestrianConfig) -> float:
    """Gap to the pedestrian / ego speed while the pedestrian is laterally within the ego's footprint
    (plus its radius), else ``TTC_CAP``."""
    if pedestrian is None or ego.v <= 1e-6:
        return TTC_CAP
    px, py = pedestrian
    gap = px - config.pedestrian_radius - ego_front(ego, config)
    if gap < 0 or abs(py - ego.y) > config.ego_width / 2 + config.pedestrian_radius:
        return TTC_CAP
    return min(gap / ego.v, TTC_CAP)


def episode_metrics(trace: np.ndarray, ttc: np.ndarray, *, success: bool, collision: bool) -> dict[str, float]:
    """``trace``: rows (t, x, y, v) at each control step. ``acc_std``: std of the per-step acceleration (m/s²)."""
    speeds = trace[:, 3] if len(trace) else np.zeros(1)
    if len(trace) >= 3:
        acc = np.diff(speeds) / np.maximum(np.diff(trace[:, 0]), 1e-9)
        acc_std = float(np.std(acc))
    else:
        acc_std = 0.0
    return {
        "success": float(success),
        "collision": float(collision),
        "min_ttc": float(np.min(ttc)) if len(ttc) else TTC_CAP,
        "avg_speed": float(np.mean(speeds)),
        "acc_std": acc_std if math.isfinite(acc_std) else 0.0,
    }
