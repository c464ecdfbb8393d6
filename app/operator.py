"""A person at the dashboard as the loop's expert, the fail-safe around them, and the control token.

:class:`OperatorConsole` holds the operator's latest input as the websocket delivers it (asyncio side)
and is read by :class:`PersonExpert` in the loop's thread; a lock keeps the two consistent. The clock
is injected so the fail-safe timing is tested without sleeping.

Fail-safe: the person counts as *answering* only while their page is connected, focused and visible
and their last input is at most ``timeout`` (200 ms) old. The page sends input on every change and as a
20 Hz heartbeat. Whenever a takeover is due and the person is not answering, the scripted expert acts
with actor ``"fallback"``; the loop never waits. A person who vanishes while holding the takeover key
leaves the scripted expert in charge (latched) until they are back or the episode ends, rather than
handing control back to the agent they were stopping.

:class:`ControlDesk` issues the one control token: one operator at a time, any number of viewers.
"""

from __future__ import annotations

import secrets
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np

from app.input_map import InputMapping, to_action
from app.messages import ExpertMode
from core.experts import ScriptedExpert
from core.loop import Actor, Expert

Clock = Callable[[], float]

DEFAULT_TIMEOUT = 0.2
"""Seconds without operator input after which the scripted expert stands in."""


@dataclass(frozen=True)
class OperatorSnapshot:
    held: bool
    throttle: float
    steer: float
    answering: bool
    """Connected, focused, visible and heard from within the timeout."""
    seq: int
    ts: float
    """The page's timestamp (ms since the epoch) of the input in effect."""
    source: str


class OperatorConsole:
    """The latest input of whoever holds the control token; written by the server, read by the loop."""

    def __init__(self, clock: Clock = time.monotonic, timeout: float = DEFAULT_TIMEOUT) -> None:
        self.clock = clock
        self.timeout = timeout
        self._lock = threading.Lock()
        self._connected = False
        self._focused = True
        self._visible = True
        self._held = False
        self._throttle = 0.0
        self._steer = 0.0
        self._last_input_at = -float("inf")
        self._last_ts = -float("inf")
        self._seq = -1
        self._source = "keyboard"
        self.on_takeover_onset: Callable[[], None] | None = None
        """Called (outside the lock) when the operator starts holding the takeover: the loop steps at once."""

    def connect(self) -> None:
        """A new operator took the token: start from a clean slate (nothing held, no input yet)."""
        with self._lock:
            self._connected, self._focused, self._visible = True, True, True
            self._held, self._throttle, self._steer = False, 0.0, 0.0
            self._last_input_at, self._last_ts, self._seq = -float("inf"), -float("inf"), -1

    def disconnect(self) -> None:
        with self._lock:
            self._connected = False

    def set_presence(self, focused: bool, visible: bool) -> None:
        with self._lock:
            self._focused, self._visible = focused, visible

    def accept_input(self, *, seq: int, ts: float, held: bool, throttle: float, steer: float, source: str) -> bool:
        """Store an input unless an input read later on the page already arrived (latest input wins)."""
        onset = False
        with self._lock:
            if not self._connected or ts < self._last_ts or (ts == self._last_ts and seq <= self._seq):
                return False
            onset = held and not self._held
            self._held, self._throttle, self._steer = held, throttle, steer
            self._last_ts, self._seq, self._source = ts, seq, source
            self._last_input_at = self.clock()
        if onset and self.on_takeover_onset is not None:
            self.on_takeover_onset()
        return True

    def snapshot(self) -> OperatorSnapshot:
        with self._lock:
            answering = (
                self._connected
                and self._focused
                and self._visible
                and self.clock() - self._last_input_at <= self.timeout
            )
            return OperatorSnapshot(
                held=self._held,
                throttle=self._throttle,
                steer=self._steer,
                answering=answering,
                seq=self._seq,
                ts=self._last_ts,
                source=self._source,
            )

    @property
    def connected(self) -> bool:
        return self._connected


class PersonExpert:
    """:class:`core.loop.Expert` for a person at the dashboard, with the scripted expert as fallback."""

    def __init__(
        self,
        console: OperatorConsole,
        mapping: InputMapping,
        action_space: gym.Space[Any],
        mode: ExpertMode = "person",
        scripted: Expert | None = None,
    ) -> None:
        self.console = console
        self.mapping = mapping
        self.action_space = action_space
        self.mode: ExpertMode = mode
        self.scripted: Expert = scripted or ScriptedExpert()
        self.latched = False
        """The person left mid-takeover: the scripted expert keeps control until they are back."""
        self._holding = False
        self.last_input: OperatorSnapshot | None = None
        """The operator input behind the latest person action (for latency accounting)."""

    def reset(self) -> None:
        self.latched = False
        self._holding = False
        self.scripted.reset()

    def _look(self) -> OperatorSnapshot:
        snap = self.console.snapshot()
        if snap.answering:
            self.latched = False
            self._holding = snap.held
        elif self._holding:  # they were holding the takeover when they went silent, hid or left
            self.latched = True
            self._holding = False
        return snap

    def wants_control(self) -> bool:
        if self.mode == "scripted":
            return False
        snap = self._look()
        return (snap.answering and snap.held) or self.latched

    def act(self, env: gym.Env[Any, Any], obs: np.ndarray) -> tuple[np.ndarray, Actor]:
        self.last_input = None
        if self.mode == "scripted":
            action, _ = self.scripted.act(env, obs)
            return action, "expert"
        snap = self._look()
        if snap.answering and (self.mode == "person" or snap.held):
            self.last_input = snap
            return to_action(self.mapping, self.action_space, snap.throttle, snap.steer), "person"
        action, _ = self.scripted.act(env, obs)
        if self.mode == "person_fallback" and not self.latched:
            return action, "expert"  # the scripted expert answering the gate is this mode's normal case
        return action, "fallback"


class ControlDesk:
    """Issues the single control token and checks it on every operator message."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._token: str | None = None
        self._holder: Any = None

    def claim(self, holder: Any) -> str | None:
        """A token for ``holder`` when nobody (else) holds control, otherwise None."""
        with self._lock:
            if self._token is not None and self._holder is not holder:
                return None
            if self._token is None:
                self._token, self._holder = secrets.token_urlsafe(24), holder
            return self._token

    def check(self, holder: Any, token: str) -> bool:
        with self._lock:
            return self._token is not None and self._holder is holder and secrets.compare_digest(self._token, token)

    def release(self, holder: Any) -> bool:
        """Give control back (page closed or released). True when ``holder`` was the operator."""
        with self._lock:
            if self._holder is holder and self._token is not None:
                self._token, self._holder = None, None
                return True
            return False

    def holder(self) -> Any:
        return self._holder
