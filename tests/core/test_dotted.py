"""Dotted-name overrides of frozen config dataclasses (``core.dotted``), the one home of every simulator's."""

from __future__ import annotations

from dataclasses import dataclass, field

import pytest

from core.dotted import replaced


@dataclass(frozen=True)
class Inner:
    gain: float = 1.0
    span: tuple[float, float] = (0.0, 1.0)


@dataclass(frozen=True)
class Outer:
    dt: float = 0.1
    inner: Inner = field(default_factory=Inner)


def test_dotted_names_replace_nested_fields_and_leave_the_original_alone() -> None:
    base = Outer()
    out = replaced(base, {"dt": 0.5, "inner.gain": 2.0, "inner.span": [1.0, 3.0]}, "toy")
    assert out == Outer(dt=0.5, inner=Inner(gain=2.0, span=(1.0, 3.0)))
    assert isinstance(out.inner.span, tuple)  # JSON lists become the field's tuple
    assert base == Outer()


@pytest.mark.parametrize(
    ("key", "message"),
    [
        ("inner.gian", r"unknown toy config field 'inner\.gian': no 'gian' among gain, span"),
        ("dtt", r"unknown toy config field 'dtt': no 'dtt' among dt, inner"),
        ("dt.x", r"unknown toy config field 'dt\.x': 'dt' is a value, not a section"),
    ],
)
def test_an_unknown_name_is_a_clear_error(key: str, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        replaced(Outer(), {key: 1.0}, "toy")
