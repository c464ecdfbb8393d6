"""Hostile websocket messages get a validation error, never an internal error, and the loop keeps stepping."""

from __future__ import annotations

import json
import random
import time

from app.messages import MessageError, parse_message
from tests.app.conftest import LiveServer
from tests.app.test_server import claim, until, ws

TOKEN = "abcdefghijklmnop"


def hostile(rng: random.Random, n: int) -> list[str]:
    """Malformed, oversized, deeply nested, mistyped and random messages of every kind the page may send."""
    shapes = [
        lambda: "[" * rng.randint(9, 20_000) + "]" * rng.randint(0, 50),
        lambda: '{"type": "ping", "ts": ' + "9" * rng.randint(33, 6000) + "}",
        lambda: json.dumps({"type": "input", "token": TOKEN, "seq": 1, "ts": 1.0, "held": rng.choice(["yes", "1", 1])}),
        lambda: json.dumps({"type": "input", "token": TOKEN, "seq": -1, "ts": 1.0, "held": True}),
        lambda: json.dumps({"type": "input", "token": TOKEN, "seq": 1, "ts": 1.0, "held": True, "throttle": 7}),
        lambda: '{"type": "ping", "ts": ' + rng.choice(["NaN", "Infinity", "-Infinity"]) + "}",
        lambda: json.dumps({"type": rng.choice(["", "eval", "__class__", "claim2", None, 3])}),
        lambda: json.dumps({"type": "configure", "token": TOKEN, "scenario": {"$gt": ""}, "extra": 1}),
        lambda: json.dumps({"type": "speed", "token": TOKEN, "value": rng.choice([0, 1e308, "fast", [1]])}),
        lambda: json.dumps([{"type": "claim"}] * rng.randint(1, 5)),
        lambda: "".join(chr(rng.randint(0, 0x2FFF)) for _ in range(rng.randint(0, 200))),
        lambda: '{"type": "input", "a": ' + '{"b": ' * 30 + "1" + "}" * 30 + "}",
        lambda: json.dumps({"type": "replay_seek", "token": TOKEN, "t": 10**40}),
        lambda: json.dumps({"type": "replay_open", "session": "s", "episode": rng.choice([2**63, 2**31, -1])}),
        lambda: '"' + "x" * 20_000 + '"',
        lambda: '{"type": "control", "token": "' + TOKEN + '", "op": "pause"' + ', "op": "step"' * 3 + "}",
    ]
    return [rng.choice(shapes)() for _ in range(n)]


def test_every_hostile_message_is_a_validation_error() -> None:
    rng = random.Random(0)
    refused = 0
    for raw in hostile(rng, 1000):
        try:
            parse_message(raw)  # anything but a MessageError fails the test
        except MessageError:
            refused += 1
    # only the duplicated-key control message (JSON keeps the last value) is a real, valid message
    assert refused >= 1000 * (1 - 1 / 16) - 40


def test_the_server_answers_hostile_messages_with_errors_and_keeps_stepping(live_server: LiveServer) -> None:
    rng = random.Random(1)
    messages = hostile(rng, 300)
    with ws(live_server) as conn:
        claim(conn)
        internal = replies = 0
        for raw in messages:
            conn.send(raw)
        deadline = time.monotonic() + 30
        while replies < len(messages) and time.monotonic() < deadline:
            msg = json.loads(conn.recv(timeout=10))
            if msg.get("type") == "error":
                replies += 1
                internal += int("internal" in str(msg.get("error", "")))
            elif msg.get("type") in ("ack", "control", "pong"):
                replies += 1
        assert internal == 0
        assert replies >= len(messages) - 10
        until(conn, lambda m: m["type"] == "step")  # the loop still streams


def test_integers_beyond_what_the_server_can_use_are_validation_errors(live_server: LiveServer) -> None:
    """A replay of episode 2**63 of the live session (any page may send it, no token) once reached SQLite and came
    back as "internal error: OverflowError"; every integer field is bounded in the schema instead."""
    with ws(live_server) as conn:
        welcome = until(conn, lambda m: m["type"] == "welcome")
        session = welcome["state"]["session"]
        assert session
        token = claim(conn)
        hostile_integers = [
            {"type": "replay_open", "session": session, "episode": 2**63},
            {"type": "replay_open", "session": session, "episode": 2**64 + 5},
            {"type": "replay_seek", "t": 2**63},
            {"type": "input", "token": token, "seq": 2**63, "ts": 1.0, "held": False},
            {"type": "version", "token": token, "op": "pin", "version": 2**63},
        ]
        for message in hostile_integers:
            conn.send(json.dumps(message))
            reply = until(conn, lambda m: m["type"] == "error")
            assert "internal" not in reply["error"] and "less than or equal" in reply["error"], (message, reply)
