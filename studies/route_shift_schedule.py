"""The paper's route-shift study as data: the phase schedule and the per-episode curves it is judged by.

Phase C1 drives route 1 until the policy is stable; phase C2 switches to route 2 and adds special vehicles.
The training CLI builds one env, and before each episode passes that episode's scenario as gymnasium reset
options (``Runner.set_next_reset_options``: ``route``, ``special_vehicles``); every ``EpisodeSummary.metrics``
then carries ``success``, ``collision``, ``red_light``, ``timeout``,
``route_progress``, ``speed_mean``, ``route`` and ``special_vehicles``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

PAPER_C1_EPISODES = 1000
"""The paper's phase C1 length (episodes 1-1000 on route 1)."""
PAPER_C2_EPISODES = 500
"""The paper's phase C2 length (episodes 1001-1500 on route 2 with special vehicles)."""
DEFAULT_C1 = 40
"""C1 episodes by default (the paper: 1,000). With 10 demonstrations and ``updates_per_step=0.5``, C1 + C2 took
2 minutes of wall time for SAC (6.5k steps) and ~24 minutes for SAGE / FNI-RL (10-13k steps, world-model fits)
on this 2-core machine while other jobs kept its load at 5-17 (docs/figures/README.md)."""
DEFAULT_C2 = 20
"""C2 episodes by default (the paper: 500; the same 2:1 ratio of C1 to C2)."""
CURVE_KEYS = ("success", "collision", "red_light")
"""The paper's Fig. (b) curves: success, collision and red-light violation rates over training."""


@dataclass(frozen=True)
class RouteShiftEpisode:
    episode: int
    """0-based episode index over the whole study."""
    phase: str
    """"C1" or "C2"."""
    route: int
    special_vehicles: bool

    def env_kwargs(self) -> dict[str, Any]:
        return {"route": self.route, "special_vehicles": self.special_vehicles}


def route_shift_schedule(c1_episodes: int = DEFAULT_C1, c2_episodes: int = DEFAULT_C2) -> list[RouteShiftEpisode]:
    """One entry per episode: C1 (route 1, ordinary traffic) then C2 (route 2, special vehicles added)."""
    if c1_episodes < 0 or c2_episodes < 0:
        raise ValueError(f"episode counts must be >= 0, got c1={c1_episodes}, c2={c2_episodes}")
    c1 = [RouteShiftEpisode(i, "C1", 1, False) for i in range(c1_episodes)]
    c2 = [RouteShiftEpisode(c1_episodes + i, "C2", 2, True) for i in range(c2_episodes)]
    return c1 + c2


def route_shift_phases(c1_episodes: int = DEFAULT_C1, c2_episodes: int = DEFAULT_C2) -> list[dict[str, Any]]:
    """The env kwargs (``route``, ``special_vehicles``) of every episode of the study, in order."""
    return [episode.env_kwargs() for episode in route_shift_schedule(c1_episodes, c2_episodes)]


def rolling_rates(
    rows: Sequence[Mapping[str, Any]], keys: Sequence[str] = CURVE_KEYS, window: int = 50
) -> dict[str, np.ndarray]:
    """Trailing moving averages of per-episode 0/1 metrics (the curves of the paper's route-shift figure).

    Entry i averages episodes max(0, i - window + 1) .. i; an episode without the key (it errored) is skipped.
    """
    if window < 1:
        raise ValueError(f"window must be >= 1, got {window}")
    out: dict[str, np.ndarray] = {}
    for key in keys:
        values = np.array([float(r[key]) if r.get(key) is not None else np.nan for r in rows], dtype=float)
        valid = ~np.isnan(values)
        sums = np.concatenate([[0.0], np.cumsum(np.where(valid, values, 0.0))])
        counts = np.concatenate([[0], np.cumsum(valid)])
        idx = np.arange(len(values))
        lo = np.maximum(idx - window + 1, 0)
        n = counts[idx + 1] - counts[lo]
        with np.errstate(invalid="ignore", divide="ignore"):
            out[key] = np.where(n > 0, (sums[idx + 1] - sums[lo]) / np.maximum(n, 1), np.nan)
    return out
