"""The one small protocol through which a simulator meets the rest of the product.

A simulator is a gymnasium ``Env`` whose ``unwrapped`` also offers the three methods of
:class:`SimulatorEnv`. ``core`` never imports a simulator; it only relies on this protocol.
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import gymnasium as gym
import numpy as np

from core.scene import Scene


@runtime_checkable
class SimulatorEnv(Protocol):
    """What ``env.unwrapped`` offers beyond gymnasium's ``reset`` and ``step``."""

    def expert_action(self) -> np.ndarray:
        """The scripted expert's action for the current state (privileged state allowed)."""
        ...

    def scene(self) -> Scene:
        """Plain data describing what to draw now (see :mod:`core.scene`). The sim never draws."""
        ...

    # Optional: ``expert_engaged() -> bool``, True while the scripted expert is in the middle of a manoeuvre that
    # handing control back would cut short (the UGV's evasion of a mover). The scripted expert then keeps the
    # wheel past the gate's hold, as a person keeps holding the takeover key; see :func:`expert_engaged`.

    # ``step``'s info may carry ``executed_action``: the action the simulator really executed when its own driver
    # model acted for the expert (SUMO); the loop then records it as the expert's action (the imitation label).

    def metrics(self) -> dict[str, float]:
        """Metrics of the current (or just finished) episode, computed from the executed trajectory."""
        ...


def simulator(env: gym.Env[Any, Any]) -> SimulatorEnv:
    """The protocol side of ``env``; a clear error when the env does not offer it."""
    inner = env.unwrapped
    missing = [name for name in ("expert_action", "scene", "metrics") if not callable(getattr(inner, name, None))]
    if missing:
        raise TypeError(
            f"{type(inner).__name__} does not implement the simulator protocol: missing {', '.join(missing)}"
        )
    return inner  # type: ignore[return-value]


def expert_engaged(env: gym.Env[Any, Any]) -> bool:
    """Whether the simulator's scripted expert, at its last action, was in the middle of a manoeuvre it should
    finish (the optional ``expert_engaged`` of the protocol; False for a simulator without it)."""
    engaged = getattr(env.unwrapped, "expert_engaged", None)
    return bool(engaged()) if callable(engaged) else False


def is_discrete(env: gym.Env[Any, Any]) -> bool:
    """True when the action space is ``Discrete`` (D3QN-style learners), False for a ``Box``."""
    return isinstance(env.action_space, gym.spaces.Discrete)
