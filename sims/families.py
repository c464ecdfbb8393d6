"""Names of a generalisation family whose splits differ by settings, not by seed: ``FAMILY:train`` / ``FAMILY:test``."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any


def split_kwargs(name: str, family: str, splits: Mapping[str, Mapping[str, Any]]) -> dict[str, Any] | None:
    """The ``make`` keyword arguments of ``family:SPLIT``; None for a name outside the family; a ``ValueError`` for
    one of it that does not parse."""
    parts = name.strip().lower().split(":")
    if parts[0] != family:
        return None
    if len(parts) != 2 or parts[1] not in splits:
        raise ValueError(f"{name!r} is not a {family} name; give " + " or ".join(f"{family}:{s}" for s in splits))
    return dict(splits[parts[1]])
