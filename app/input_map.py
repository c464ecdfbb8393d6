"""From the operator's two manual axes to a simulator's action (the mapping is the simulator descriptor's).

The page always sends the same two normalised axes, whatever the simulator:
``throttle`` in [-1, 1] (up arrow / W / left stick up = +1) and ``steer`` in [-1, 1] (left arrow / A /
stick left = +1, i.e. counter-clockwise, matching a positive yaw rate in the x-east, y-north scene).
Each simulator's descriptor says which action component each axis drives and with which sign; a ``Box``
action is then scaled from [-1, 1] to its bounds. An unregistered env gets a mapping from its action space
alone: two components mean (throttle/speed, steer/yaw), one means accelerate/brake.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from core.descriptor import InputMapping

__all__ = ["InputMapping", "mapping_for", "to_action"]


def mapping_for(sim: str, action_space: gym.Space[Any]) -> InputMapping:
    """The simulator's own mapping (its descriptor), or one derived from the action space's shape."""
    import sims

    try:
        return sims.descriptor(sim).input_mapping
    except ValueError:  # not a registered simulator (a test's toy env): go by the action space
        pass
    if isinstance(action_space, gym.spaces.Box) and int(np.prod(action_space.shape)) >= 2:
        return InputMapping(throttle_index=0, steer_index=1)
    return InputMapping(throttle_index=0, steer_index=None)


def to_action(
    mapping: InputMapping,
    action_space: gym.Space[Any],
    throttle: float,
    steer: float,
    safe: np.ndarray | None = None,
) -> np.ndarray:
    """The action the operator's axes ask for, inside ``action_space``.

    ``safe``: the simulator's safe action (its descriptor's: stop or brake). With it, the throttle axis is
    anchored there: no throttle input is the safe action's throttle component (a person holding control without
    pressing forward stops or brakes; never cruises), +1 the component's maximum, -1 its minimum.
    ``Discrete(n)`` spaces (e.g. keep / slow down / speed up) get the throttle axis split into ``n``
    equal bins, so full brake is action 0 and full throttle action ``n - 1``.
    """
    throttle = float(np.clip(throttle, -1.0, 1.0)) * mapping.throttle_sign
    steer = float(np.clip(steer, -1.0, 1.0)) * mapping.steer_sign
    if isinstance(action_space, gym.spaces.Discrete):
        if mapping.discrete is not None:
            return np.asarray(int(mapping.discrete(throttle, steer)), dtype=np.int64)
        n = int(action_space.n)
        return np.asarray(int(action_space.start) + min(n - 1, int((throttle + 1.0) / 2.0 * n)), dtype=np.int64)
    if not isinstance(action_space, gym.spaces.Box):
        raise TypeError(f"manual control supports Box and Discrete action spaces, not {type(action_space).__name__}")
    unit = np.zeros(action_space.shape, dtype=np.float64).reshape(-1)
    if mapping.throttle_index is not None and mapping.throttle_index < unit.size:
        unit[mapping.throttle_index] = throttle
    if mapping.steer_index is not None and mapping.steer_index < unit.size:
        unit[mapping.steer_index] = steer
    low = np.broadcast_to(action_space.low, action_space.shape).reshape(-1).astype(np.float64)
    high = np.broadcast_to(action_space.high, action_space.shape).reshape(-1).astype(np.float64)
    bounded = np.isfinite(low) & np.isfinite(high)
    scaled = np.where(bounded, low + (unit + 1.0) / 2.0 * (high - low), unit)
    index = mapping.throttle_index
    if safe is not None and index is not None and index < unit.size and bounded[index]:
        anchor = float(np.asarray(safe, np.float64).reshape(-1)[index])
        scaled[index] = anchor + throttle * ((high[index] - anchor) if throttle >= 0 else (anchor - low[index]))
    return scaled.reshape(action_space.shape).astype(action_space.dtype)
