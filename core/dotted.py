"""Dotted-name settings: the one reading of ``--set section.key=value`` and the overrides of a config dataclass.

:func:`route_settings` splits the command line's ``--set`` pairs by their first name (``gate.``, ``env.``,
``study.``, the learner's sections) for every command; :func:`replaced` puts a simulator's overrides into its frozen
config (``--set env.expert.horizon=0.5`` on the command line, ``make(..., **{"lidar.backend": "pymunk"})`` in code).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, fields, is_dataclass, replace
from typing import Any, TypeVar

C = TypeVar("C")


def replaced(config: C, overrides: Mapping[str, Any], what: str) -> C:
    """``config`` with each ``name: value`` of ``overrides`` put in its place, a nested dataclass's field by its
    dotted path (``"expert.horizon"``). A list given for a tuple field becomes a tuple (JSON, which ``--set env.``
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


@dataclass(frozen=True)
class Section:
    """Where the ``--set`` pairs of one section go: ``route`` (a name the command reads them under), the key after
    the section's name with ``prefix`` put before it (``world_model.x`` -> the learner's ``world_model_config.x``)."""

    route: str
    prefix: str = ""


def split_setting(pair: str) -> tuple[str, str]:
    """``"a.b=value"`` -> ``("a.b", "value")``; a pair without a name or an ``=`` is a ValueError."""
    key, sep, value = pair.partition("=")
    key = key.strip()
    if not sep or not key or key.startswith(".") or key.endswith(".") or ".." in key:
        raise ValueError(f"{pair!r} is not of the form section.key=value")
    return key, value.strip()


def route_settings(
    pairs: Iterable[str], sections: Mapping[str, Section], other: str | None = None
) -> dict[str, list[str]]:
    """``section.key=value`` pairs sorted by section: ``{route: ["key=value", ...]}``, in the order given. A pair
    whose first name is no section goes, whole, to the route ``other`` (the learner's own field paths, such as
    ``hidden=16`` or ``gate.tau_max=0.7``, where a command trains), or is a ValueError that names the sections.
    The values stay text: each route's reader gives them their field's type."""
    routed: dict[str, list[str]] = {}
    for pair in pairs:
        key, value = split_setting(pair)
        head, dot, rest = key.partition(".")
        section = sections.get(head) if dot else None
        if section is not None:
            routed.setdefault(section.route, []).append(f"{section.prefix}{rest}={value}")
        elif other is not None:
            routed.setdefault(other, []).append(f"{key}={value}")
        else:
            names = ", ".join(f"{name}.KEY=VALUE" for name in sections)
            raise ValueError(f"{pair!r} names no section this command takes: {names}")
    return routed


__all__ = ["Section", "replaced", "route_settings", "split_setting"]
