"""Every message from a page is validated; a bad one gets a reason, never a crash."""

from __future__ import annotations

import json

import pytest

from app import messages as m

TOKEN = "t" * 32


def test_valid_messages_parse_into_their_models() -> None:
    msg = m.parse_message(
        json.dumps(
            {"type": "input", "token": TOKEN, "seq": 3, "ts": 1.5e12, "held": True, "throttle": -1, "steer": 0.5}
        )
    )
    assert isinstance(msg, m.Input) and msg.held and msg.throttle == -1.0 and msg.source == "keyboard"
    assert not msg.coach  # a page that knows nothing of coaching sends none
    coached = m.parse_message(
        json.dumps({"type": "input", "token": TOKEN, "seq": 4, "ts": 2, "held": False, "coach": True})
    )
    assert isinstance(coached, m.Input) and coached.coach
    assert isinstance(m.parse_message(b'{"type": "claim"}'), m.Claim)
    configure = m.parse_message(json.dumps({"type": "configure", "token": TOKEN, "expert_mode": "scripted"}))
    assert isinstance(configure, m.Configure) and configure.sim is None and configure.expert_mode == "scripted"


@pytest.mark.parametrize(
    ("raw", "reason"),
    [
        ("not json", "not JSON"),
        ("[1, 2]", "JSON object"),
        ('{"no": "type"}', "type"),
        ('{"type": "launch_missiles"}', "launch_missiles"),
        (json.dumps({"type": "claim", "extra": 1}), "extra"),
        (json.dumps({"type": "input", "token": TOKEN, "seq": 1, "ts": 1, "held": True, "throttle": 2}), "throttle"),
        ('{"type": "input", "token": "' + TOKEN + '", "seq": 1, "ts": 1, "held": true, "steer": NaN}', "steer"),
        (json.dumps({"type": "speed", "token": TOKEN, "value": 1000}), "value"),
        (json.dumps({"type": "control", "token": TOKEN, "op": "explode"}), "op"),
        (json.dumps({"type": "input", "seq": 1, "ts": 1, "held": True}), "token"),
        (json.dumps({"type": "input", "token": TOKEN, "seq": 1, "ts": 1, "held": False, "coach": "yes"}), "coach"),
        (json.dumps({"type": "configure", "token": TOKEN, "expert_mode": "robot"}), "expert_mode"),
        ("x" * (m.MAX_MESSAGE_BYTES + 1), "too long"),
        (b"\xff\xfe", "not JSON"),
    ],
)
def test_malformed_messages_are_refused_with_a_reason(raw: str | bytes, reason: str) -> None:
    with pytest.raises(m.MessageError, match=reason):
        m.parse_message(raw)
