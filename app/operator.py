"""A person at the dashboard as the loop's expert, the fail-safe around them, and the control token.

:class:`OperatorConsole` holds the operator's latest input as the websocket delivers it (asyncio side)
and is read by :class:`PersonExpert` in the loop's thread; a lock keeps the two consistent. The clock
is injected so the fail-safe timing is tested without sleeping.

Fail-safe: the person counts as *answering* only while their page is connected, focused and visible
and their last input is at most ``timeout`` (200 ms) old. The page sends input on every change and as a
20 Hz heartbeat, but a heartbeat is presence, not action: a person *drives* only while they actively hold
control (the takeover key or trigger, or sticky mode) and are answering. When the gate asks for help and
the person is not holding, the page alerts them and the scripted expert drives (``"fallback"``) until they
take hold: never a neutral action, and the loop never waits. A person who vanishes while holding is
latched out for at least ``rejoin_after`` (so late heartbeats under load do not flip control step to step)
and the scripted expert stays in charge rather than handing control back to the agent they were stopping.

Coaching: while the person has coaching on (key C) and answers, their controls on a step the agent drives are
recorded as a label for it (:meth:`PersonExpert.coach`), never executed: the rounds imitate them as they imitate a
takeover, on states the agent reached itself. Holding the takeover still takes the wheel.

Handover is bumpless: for a ``Box`` action the person's (or fallback's) first actions after a handover, and the
policy's first ones when control returns to it (:meth:`PersonExpert.hand_back`), move from the executed action
towards the target by at most ``max_jump`` of the action range per step, and every handover's action jump and the
handover latency (gate request -> the person taking hold) are measured.

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
REJOIN_AFTER = 0.5
"""Seconds a person who went silent while holding stays latched out before their input drives again."""
MAX_JUMP = 0.25
"""Largest change of each action component per step at a handover, as a share of its range."""


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
    coach: bool = False
    """Coaching on (key C): while the agent drives, the person's controls are a label, not an action."""


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
        self._coach = False
        self.on_takeover_onset: Callable[[], None] | None = None
        """Called (outside the lock) when the operator starts holding the takeover: the loop steps at once."""

    def connect(self) -> None:
        """A new operator took the token: start from a clean slate (nothing held, no input yet)."""
        with self._lock:
            self._connected, self._focused, self._visible = True, True, True
            self._held, self._throttle, self._steer, self._coach = False, 0.0, 0.0, False
            self._last_input_at, self._last_ts, self._seq = -float("inf"), -float("inf"), -1

    def disconnect(self) -> None:
        with self._lock:
            self._connected = False

    def set_presence(self, focused: bool, visible: bool) -> None:
        with self._lock:
            self._focused, self._visible = focused, visible

    def accept_input(
        self, *, seq: int, ts: float, held: bool, throttle: float, steer: float, source: str, coach: bool = False
    ) -> bool:
        """Store an input unless an input read later on the page already arrived (latest input wins)."""
        onset = False
        with self._lock:
            if not self._connected or ts < self._last_ts or (ts == self._last_ts and seq <= self._seq):
                return False
            onset = held and not self._held
            self._held, self._throttle, self._steer = held, throttle, steer
            self._last_ts, self._seq, self._source, self._coach = ts, seq, source, coach
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
                coach=self._coach,
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
        *,
        rejoin_after: float = REJOIN_AFTER,
        max_jump: float = MAX_JUMP,
        safe: np.ndarray | None = None,
    ) -> None:
        """``safe``: the simulator's safe action (stop or brake), where the person's throttle axis rests."""
        self.console = console
        self.mapping = mapping
        self.action_space = action_space
        self.mode: ExpertMode = mode
        self.scripted: Expert = scripted or ScriptedExpert()
        self.rejoin_after = rejoin_after
        self.max_jump = max_jump
        self.safe = safe
        self.latched = False
        """The person left mid-takeover: the scripted expert keeps control until they are back."""
        self._latched_at = -float("inf")
        self._holding = False
        self._scripted_drove = False
        """The scripted expert (or fallback) produced the last action, not the person."""
        self.last_input: OperatorSnapshot | None = None
        """The operator input behind the latest person action (for latency accounting)."""
        self._previous: np.ndarray | None = None
        self._previous_actor: str | None = None
        self._ramping = False
        self._request_at: float | None = None
        self.latencies: list[float] = []
        """Seconds from a gate request to the person taking hold, per handover to the person."""
        self.jumps: list[float] = []
        """Largest action-component change (share of its range) at each handover between actors."""

    def reset(self) -> None:
        self.latched = False
        self._holding = False
        self._scripted_drove = False
        self._previous = None
        self._previous_actor = None
        self._ramping = False
        self._request_at = None
        self.scripted.reset()

    def _look(self) -> OperatorSnapshot:
        snap = self.console.snapshot()
        now = self.console.clock()
        # back and released: control returns at once; back and holding: only after ``rejoin_after`` (late
        # heartbeats under load must not flip control between the person and the fallback step to step)
        if snap.answering and (not self.latched or not snap.held or now - self._latched_at >= self.rejoin_after):
            self.latched = False
            self._holding = snap.held
        elif self._holding and not snap.answering:  # they were holding when they went silent, hid or left
            self.latched = True
            self._latched_at = now
            self._holding = False
        return snap

    def acting(self, snap: OperatorSnapshot) -> bool:
        """The person drives only while answering and actively holding control (key, trigger or sticky)."""
        return snap.answering and snap.held and not self.latched

    def wants_control(self) -> bool:
        # the scripted expert, when it drove last, keeps the wheel while it is mid-manoeuvre (``ScriptedExpert``:
        # the simulator's ``expert_engaged``), as the person would by holding the key; the person can still take it
        scripted_engaged = self._scripted_drove and self.scripted.wants_control()
        if self.mode == "scripted":
            return scripted_engaged
        snap = self._look()
        return self.acting(snap) or self.latched or scripted_engaged

    def act(self, env: gym.Env[Any, Any], obs: np.ndarray) -> tuple[np.ndarray, Actor]:
        self.last_input = None
        if self.mode == "scripted":
            action, _ = self.scripted.act(env, obs)
            self._scripted_drove = True
            return action, "expert"
        snap = self._look()
        if self.acting(snap):
            self._scripted_drove = False
            if self._request_at is not None:
                self.latencies.append(self.console.clock() - self._request_at)
                self._request_at = None
            self.last_input = snap
            target = to_action(self.mapping, self.action_space, snap.throttle, snap.steer, self.safe)
            return self._bumpless(target, "person"), "person"
        if self._request_at is None and self.mode == "person" and not self.latched:
            self._request_at = self.console.clock()  # the gate asked, nobody holds: the page alerts the person
        action, _ = self.scripted.act(env, obs)
        self._scripted_drove = True
        actor: Actor = "expert" if self.mode == "person_fallback" and not self.latched else "fallback"
        return self._bumpless(np.asarray(action), actor), actor

    def coach(self, env: gym.Env[Any, Any], obs: np.ndarray) -> np.ndarray | None:
        """:class:`core.protocol.Coach`: the person's controls as a label for the step the agent drives, while they
        coach (key C) and answer; never executed. Not while they hold the takeover (then they drive) or are latched
        out, and never from the scripted expert: a label is a person's judgement or nothing."""
        if self.mode == "scripted":
            return None
        snap = self._look()
        if not (snap.coach and snap.answering) or snap.held or self.latched:
            return None
        return to_action(self.mapping, self.action_space, snap.throttle, snap.steer, self.safe)

    def hand_back(self, a_rl: np.ndarray) -> np.ndarray:
        """The policy's action as executed when nobody takes over (:attr:`core.loop.Runner.agent_action_filter`):
        right after a person, the fallback or the scripted expert drove, it moves from their last executed action
        towards the policy's by at most ``max_jump`` of the range per step, as every other handover does."""
        return self._bumpless(np.asarray(a_rl), "agent")

    def _bumpless(self, target: np.ndarray, actor: str) -> np.ndarray:
        """Move from the last executed action towards ``target`` by at most ``max_jump`` of the range per
        step while a handover is under way (Box actions; discrete actions switch at once)."""
        space = self.action_space
        previous = self._previous
        if previous is None or not isinstance(space, gym.spaces.Box):
            return target
        if actor != self._previous_actor:
            self._ramping = True
        if not self._ramping:
            return target
        low = np.broadcast_to(space.low, space.shape).astype(np.float64)
        high = np.broadcast_to(space.high, space.shape).astype(np.float64)
        span = np.where(np.isfinite(high - low), high - low, 2.0)
        step = self.max_jump * span
        goal = np.asarray(target, np.float64).reshape(space.shape)
        limited = previous.reshape(space.shape) + np.clip(goal - previous.reshape(space.shape), -step, step)
        if np.allclose(limited, goal):
            self._ramping = False
        return limited.astype(space.dtype)

    def note_executed(self, action: np.ndarray, actor: str, takeover: bool) -> None:
        """A step listener's report of what was executed: the reference of the next bumpless handover and the
        measured jump at each change of actor. A ramp ends once the executed action reached its target."""
        a = np.asarray(action, np.float64).reshape(-1)
        space = self.action_space
        handover = self._previous is not None and self._previous_actor not in (None, actor)
        if handover and isinstance(space, gym.spaces.Box) and self._previous is not None:
            low = np.broadcast_to(space.low, space.shape).reshape(-1).astype(np.float64)
            high = np.broadcast_to(space.high, space.shape).reshape(-1).astype(np.float64)
            span = np.where(np.isfinite(high - low), high - low, 2.0)
            self.jumps.append(float(np.max(np.abs(a - self._previous.reshape(-1)) / span)))
        if not takeover:
            self._request_at = None
        self._previous = a.reshape(np.shape(action)) if np.ndim(action) else a
        self._previous_actor = actor

    def handover_stats(self) -> dict[str, float | None]:
        """The measured handover latency (s) and action jump (share of range), last and worst."""
        return {
            "handover_latency_last": self.latencies[-1] if self.latencies else None,
            "handover_latency_median": float(np.median(self.latencies)) if self.latencies else None,
            "handover_jump_last": self.jumps[-1] if self.jumps else None,
            "handover_jump_max": max(self.jumps) if self.jumps else None,
            "handovers": len(self.jumps),
        }


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
