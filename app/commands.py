"""The live loop's commands, as typed values, and a registry that dispatches them by class.

A command changes the loop (pause, one step, speed, what drives, which fine-tuned version) and is applied in
the loop's own thread between two steps (:meth:`app.live.LiveLoop.submit`). The page's websocket messages
(:mod:`app.messages`) are the wire format; the server turns each operator message into one of these. Tests,
benches and other callers build them directly: ``loop.submit(SetSpeed(2.0)).result()``.

Handlers are registered by command class (as viser registers its message handlers), so adding a command is a
class here and one decorated method on the loop, never another branch of a string switch.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TypeVar

from app.messages import ExpertMode


@dataclass(frozen=True)
class Pause:
    """Stop stepping (the episode stays where it is)."""


@dataclass(frozen=True)
class Resume:
    """Step at the configured rate again."""


@dataclass(frozen=True)
class StepOnce:
    """Pause, then take exactly one step."""


@dataclass(frozen=True)
class NewEpisode:
    """End the running episode now (recorded with its summary); the next step starts a new one."""


@dataclass(frozen=True)
class SetSpeed:
    value: float
    """Multiple of real time (the control rate is speed / dt)."""


@dataclass(frozen=True)
class Configure:
    """Switch simulator, scenario, policy or expert mode; None keeps the current value."""

    sim: str | None = None
    scenario: str | None = None
    policy: str | None = None
    expert_mode: ExpertMode | None = None
    default_policy: str | None = None
    """The policy to drive a newly picked simulator when ``policy`` is not given (the server finds it)."""


@dataclass(frozen=True)
class ChooseVersion:
    """Pin a fine-tuned version, follow the newest, or roll back to one (taken at the next episode boundary)."""

    action: str
    number: int | None = None


@dataclass(frozen=True)
class Stop:
    """End the loop thread."""


Command = Pause | Resume | StepOnce | NewEpisode | SetSpeed | Configure | ChooseVersion | Stop

C = TypeVar("C")


class CommandError(RuntimeError):
    """A command the loop refused (unknown simulator, policy that does not load, ...)."""


class CommandRegistry:
    """Handlers by command class: ``@registry.handles(SetSpeed)`` on a method taking ``(self, command)``."""

    def __init__(self) -> None:
        self._handlers: dict[type, Callable[[Any, Any], Any]] = {}

    def handles(self, kind: type[C]) -> Callable[[Callable[[Any, C], Any]], Callable[[Any, C], Any]]:
        def register(function: Callable[[Any, C], Any]) -> Callable[[Any, C], Any]:
            if kind in self._handlers:
                raise ValueError(f"{kind.__name__} already has a handler")
            self._handlers[kind] = function
            return function

        return register

    def dispatch(self, owner: Any, command: object) -> Any:
        handler = self._handlers.get(type(command))
        if handler is None:
            raise CommandError(f"unknown command {type(command).__name__}")
        return handler(owner, command)

    def kinds(self) -> set[type]:
        return set(self._handlers)
