"""Messages a page may send over the dashboard websocket, validated by pydantic.

Every message is a JSON object with a ``type`` field; pydantic picks the model from it (a discriminated
union) and rejects unknown types, unknown fields, non-finite numbers and out-of-range values (every integer is
bounded to what the server can store and use, so 2**63 is a validation error, not an overflow inside it). A message
that fails validation gets an ``error`` reply naming the problem and never reaches the loop.

Messages that act on the loop (``input``, ``presence``, ``control``, ``configure``, ``version``...) carry the control
``token`` the server issued to the one operator; viewers have none and are refused. Replay messages change only
the sending page's view, so any page may send them.
"""

from __future__ import annotations

import json
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, ValidationError, model_validator

ExpertMode = Literal["person", "scripted", "person_fallback"]
"""Who answers a takeover: ``person`` (the operator; the scripted expert bridges only while the operator
is silent, hidden or gone, as ``fallback``), ``scripted`` (the scripted expert, person input ignored),
``person_fallback`` (the scripted expert answers the gate, the operator may take over at any time)."""

EXPERT_MODES: tuple[str, ...] = ("person", "scripted", "person_fallback")

MAX_MESSAGE_BYTES = 16_384
"""Anything longer is refused before JSON parsing (a page never needs more)."""
MAX_DEPTH = 8
"""Deepest nesting of JSON arrays and objects accepted (a page's messages are flat)."""
MAX_NUMBER_CHARS = 32
"""Longest number literal accepted (a 5,000-digit integer would otherwise reach Python's int limits)."""

MAX_INDEX = 2**31 - 1
"""Largest episode, step or version number accepted: far beyond any session, and within every integer column
the server stores it in (SQLite's are 64-bit; 2**63 raised OverflowError there)."""
MAX_SEQ = 2**53 - 1
"""Largest input sequence number: the page counts in JavaScript numbers, exact up to 2**53 - 1."""

Axis = Annotated[float, Field(ge=-1.0, le=1.0)]
Index = Annotated[int, Field(ge=0, le=MAX_INDEX)]


class _Message(BaseModel):
    # strict: "yes" is not a bool and "1" is not a number (a page that means them sends JSON true and 1)
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, frozen=True, strict=True)


class _Operator(_Message):
    token: str = Field(min_length=8, max_length=128)


class Claim(_Message):
    """Ask for the control token (granted when nobody else holds it)."""

    type: Literal["claim"]


class Release(_Operator):
    type: Literal["release"]


class Input(_Operator):
    """The operator's latest manual controls. Sent on every change and as a heartbeat while focused."""

    type: Literal["input"]
    seq: int = Field(ge=0, le=MAX_SEQ)
    ts: float = Field(ge=0, description="page clock when the input was read, ms since the epoch")
    held: bool = Field(description="takeover requested: Space held, sticky toggle on, or gamepad trigger")
    throttle: Axis = 0.0
    steer: Axis = 0.0
    source: Literal["keyboard", "gamepad"] = "keyboard"
    coach: bool = Field(
        default=False,
        description="coaching (key C): the person steers along while the agent drives; a label, not executed",
    )


class Presence(_Operator):
    type: Literal["presence"]
    focused: bool
    visible: bool


class Control(_Operator):
    type: Literal["control"]
    op: Literal["pause", "resume", "step", "new_episode"]


class Speed(_Operator):
    type: Literal["speed"]
    value: float = Field(ge=0.1, le=20.0)


class Configure(_Operator):
    """Switch simulator, scenario, policy or expert mode. Omitted fields keep their value."""

    type: Literal["configure"]
    sim: str | None = Field(default=None, max_length=64)
    scenario: str | None = Field(default=None, min_length=1, max_length=512)
    """A scenario name of the simulator (the picker lists them)."""
    policy: str | None = Field(default=None, max_length=512)
    expert_mode: ExpertMode | None = None


class VersionControl(_Operator):
    """Choose the fine-tuned policy version that drives (taken at the next episode boundary).

    ``pin``: run ``version`` and keep it whatever the worker publishes; ``follow``: run the newest version and
    each new one as it appears; ``rollback``: run ``version`` again and continue fine-tuning from it."""

    type: Literal["version"]
    op: Literal["pin", "follow", "rollback"]
    version: int | None = Field(default=None, ge=0, le=1_000_000)

    @model_validator(mode="after")
    def _version_given(self) -> VersionControl:
        if self.op in ("pin", "rollback") and self.version is None:
            raise ValueError(f"{self.op} needs a version number")
        return self


class View(_Operator):
    """The 3D view: follow the ego, or show the whole area (one shared scene, so the operator chooses)."""

    type: Literal["view"]
    mode: Literal["follow", "overview"]


class _Viewer(_Message):
    """Any page may send it: it changes only that page's view. A token is accepted and not needed."""

    token: str | None = Field(default=None, min_length=8, max_length=128)


class ReplayOpen(_Viewer):
    type: Literal["replay_open"]
    session: str = Field(min_length=1, max_length=128)
    episode: Index


class ReplaySeek(_Viewer):
    type: Literal["replay_seek"]
    t: Index


class ReplayClose(_Viewer):
    type: Literal["replay_close"]


class Ping(_Message):
    type: Literal["ping"]
    ts: float = 0.0


ClientMessage = Annotated[
    Claim
    | Release
    | Input
    | Presence
    | Control
    | Speed
    | Configure
    | VersionControl
    | View
    | ReplayOpen
    | ReplaySeek
    | ReplayClose
    | Ping,
    Field(discriminator="type"),
]
_adapter: TypeAdapter[ClientMessage] = TypeAdapter(ClientMessage)


class MessageError(ValueError):
    """A message that cannot be accepted; ``str()`` is a short, human-readable reason."""


def _depth(text: str) -> int:
    """The deepest nesting of brackets outside strings (a cheap bound checked before parsing)."""
    depth = deepest = 0
    in_string = escaped = False
    for char in text:
        if in_string:
            if escaped:
                escaped = False
            elif char == "\\":
                escaped = True
            elif char == '"':
                in_string = False
        elif char == '"':
            in_string = True
        elif char in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif char in "]}":
            depth -= 1
    return deepest


def _number(kind: type) -> Any:
    def parse(literal: str) -> Any:
        if len(literal) > MAX_NUMBER_CHARS:
            raise MessageError(f"number too long ({len(literal)} characters > {MAX_NUMBER_CHARS})")
        return kind(literal)

    return parse


def parse_message(raw: str | bytes) -> ClientMessage:
    """Parse and validate one websocket frame; :class:`MessageError` says what is wrong."""
    if len(raw) > MAX_MESSAGE_BYTES:
        raise MessageError(f"message too long ({len(raw)} bytes > {MAX_MESSAGE_BYTES})")
    text = raw.decode("utf-8", errors="replace") if isinstance(raw, bytes) else raw
    if _depth(text) > MAX_DEPTH:
        raise MessageError(f"message nested deeper than {MAX_DEPTH} levels")
    try:
        data: Any = json.loads(text, parse_int=_number(int), parse_float=_number(float))
    except MessageError:
        raise
    except (ValueError, RecursionError) as exc:  # JSONDecodeError is a ValueError
        raise MessageError(f"not JSON: {str(exc)[:120]}") from None
    if not isinstance(data, dict):
        raise MessageError(f"expected a JSON object with a 'type' field, got {type(data).__name__}")
    try:
        return _adapter.validate_python(data)
    except ValidationError as exc:
        problems = "; ".join(
            f"{'.'.join(str(p) for p in err['loc']) or 'message'}: {err['msg']}" for err in exc.errors()[:3]
        )
        raise MessageError(f"invalid {data.get('type', 'message')!r}: {problems}") from None
