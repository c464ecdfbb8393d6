"""Dotted-name overrides of a simulator's frozen config dataclass: ``--env expert.horizon=0.5`` on the command
line, ``make(..., **{"lidar.backend": "pymunk"})`` in code. One home for every simulator's keyword overrides."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import fields, is_dataclass, replace
from typing import Any, TypeVar

C = TypeVar("C")


def replaced(config: C, overrides: Mapping[str, Any], what: str) -> C:
    """``config`` with each ``name: value`` of ``overrides`` put in its place, a nested dataclass's field by its
    dotted path (``"expert.horizon"``). A list given for a tuple field becomes a tuple (JSON, which ``--env``
    reads, has none). An unknown name is a ValueError that says which part is unknown and what ``what``'s config
    has there, so a typo is never silently ignored."""
    for key, value in overrides.items():
        config = _replace(config, key, key.split("."), value, what)
    return config


def _replace(obj: Any, key: str, path: list[str], value: Any, what: str) -> Any:
    names = {f.name for f in fields(obj)}
    head = path[0]
    if head not in names:
        raise ValueError(f"unknown {what} config field {key!r}: no {head!r} among {', '.join(sorted(names))}")
    current = getattr(obj, head)
    if len(path) == 1:
        if isinstance(current, tuple) and isinstance(value, list):
            value = tuple(value)
        return replace(obj, **{head: value})
    if not is_dataclass(current) or isinstance(current, type):
        raise ValueError(f"unknown {what} config field {key!r}: {head!r} is a value, not a section")
    return replace(obj, **{head: _replace(current, key, path[1:], value, what)})


__all__ = ["replaced"]
