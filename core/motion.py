"""The world model's motion input: the last change of state, with a range scan seen from the current heading.

One lidar frame carries no motion, so the world model also reads s_t - s_{t-1}. For a robot that turns, that
difference of two ego-centric scans is mostly the robot's own rotation: every range slides sideways by the
turn, and a mover's approach (millimetres of range per step) drowns in it. Measured on the UGV: while the
scripted expert turned on the spot, the fear of the policy's plan fell to 0.001-0.01 with a mover 0.6-0.8 m
away and closing, and the collisions on the crossing scenario came 0.1-1.3 s after such a turn.

:class:`ScanAlignment` removes the rotation: before differencing, the previous scan is resampled at the
bearings the current scan's sectors had then (linear interpolation between neighbouring sectors; a sector
that has turned in from outside the field of view takes the nearest edge sector's range), so a static
obstacle gives no motion under a pure turn and a mover gives its own. The turn over the step comes from the
current observation itself (the UGV observes its last yaw-rate command), so the same alignment serves the real
history, the replay buffer's training inputs and the imagined steps of a fear rollout (where the next state is
the model's prediction). The policy's observation is unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor


@dataclass(frozen=True)
class ScanAlignment:
    """Where the scan and the turn are in the observation (``WorldModelConfig.scan_*``)."""

    sectors: int
    """Channels [0, sectors) are ranges over evenly spaced sectors, in order of increasing bearing (the UGV's:
    rightmost first)."""
    turn_channel: int
    """The channel holding the turn over the step that led to this observation (a yaw rate, any units)."""
    sectors_per_unit: float
    """Sectors the heading turns by over one step per unit of ``turn_channel`` (positive: bearings increase
    with the turn channel, so a static obstacle slides to lower sectors)."""

    @classmethod
    def of(cls, sectors: int, turn_channel: int, sectors_per_unit: float, obs_dim: int) -> ScanAlignment | None:
        """The alignment a world model config describes (None for ``sectors`` 0); a ValueError names what does
        not fit an observation of ``obs_dim`` channels."""
        if sectors == 0:
            return None
        if not 2 <= sectors <= obs_dim:
            raise ValueError(f"world_model_config.scan_sectors must be 0 or in [2, {obs_dim}], got {sectors}")
        if not sectors <= turn_channel < obs_dim:
            raise ValueError(
                f"world_model_config.scan_turn_channel must be a channel after the scan, in [{sectors}, {obs_dim}), "
                f"got {turn_channel}"
            )
        if not np.isfinite(sectors_per_unit) or sectors_per_unit == 0:
            raise ValueError(f"world_model_config.scan_turn_sectors must be finite, non-zero; got {sectors_per_unit}")
        return cls(int(sectors), int(turn_channel), float(sectors_per_unit))

    def motion(self, previous: Tensor, current: Tensor) -> Tensor:
        """current - previous with ``previous``'s scan resampled at the bearings of ``current``'s sectors: the
        change of state with the robot's own turn taken out of the scan (any leading shape, (..., D))."""
        s = self.sectors
        shift = current[..., self.turn_channel : self.turn_channel + 1] * self.sectors_per_unit
        position = torch.add(_sector_index(s, previous.dtype), shift).clamp_(0.0, s - 1.0)
        low = position.floor()
        index = low.long()
        frac = position.sub_(low)
        scan = previous[..., :s]
        below = torch.gather(scan, -1, index)
        above = torch.gather(scan, -1, (index + 1).clamp_max_(s - 1))
        out = current - previous
        out[..., :s] = current[..., :s] - below.lerp_(above, frac)
        return out


_INDEX: dict[tuple[int, torch.dtype], Tensor] = {}


def _sector_index(sectors: int, dtype: torch.dtype) -> Tensor:
    """0, 1, ..., sectors - 1 (cached: the gate aligns a scan at every imagined step)."""
    key = (sectors, dtype)
    if key not in _INDEX:
        with torch.inference_mode(False):  # a normal tensor, whichever mode asks first: autograd reads it too
            _INDEX[key] = torch.arange(sectors, dtype=dtype)
    return _INDEX[key]


def motion_between(previous: np.ndarray, current: np.ndarray, scan: ScanAlignment | None) -> np.ndarray:
    """Rows of (current - previous), scan-aligned when ``scan`` is given (numpy in, float32 numpy out)."""
    cur = np.asarray(current, dtype=np.float32)
    prev = np.asarray(previous, dtype=np.float32)
    if scan is None:
        return cur - prev
    with torch.no_grad():
        return scan.motion(torch.from_numpy(prev), torch.from_numpy(cur)).numpy()


APPROACH_RANGE_FLOOR = 0.02
"""Smallest range the approach rate divides by, in the observation's units (2% of a scan normalised to its reach):
a beam already touching something reads the largest rate, not a division by zero."""


def approach_rate(state: Tensor, motion: Tensor, start: int, stop: int) -> Tensor:
    """Per range channel in [start, stop) of ``state``: how fast it closes relative to its length,
    max(0, -Δrange) / range per step, capped at 1 (contact within a step), from the motion input's Δ.

    This is the inverse of a beam's time to contact. A small network reads ranges and their changes on their own
    scales, where a 4 m/s approach at 7 m and a 4 m/s approach at 40 m differ by nothing in the change; the ratio is
    what tells them apart, and it is a division, which a few SiLU layers learn poorly from rare violations. On
    highway the gate's rows did not improve beyond the spread of refits (README, "Calibration of fear"), so it is an
    option, off by default. Any leading shape, (..., D) -> (..., stop - start)."""
    closing = motion[..., start:stop].neg().clamp_min(0.0)
    return closing.div(state[..., start:stop].clamp_min(APPROACH_RANGE_FLOOR)).clamp_max(1.0)
