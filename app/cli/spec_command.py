"""A typer command whose options are a dataclass's fields: each default and each help text is written once.

The help of an option is the docstring under its field (:func:`core.field_docs.field_docs`); the flag is the
field's name with dashes (``demo_episodes`` -> ``--demo-episodes``) unless its metadata says ``flag``. A list
field is a repeatable option. The command's body receives the filled-in dataclass.
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
import typing
from collections.abc import Callable, Mapping
from typing import Annotated, Any

import typer

from core.field_docs import field_docs


def _default(field: dataclasses.Field[Any]) -> Any:
    if field.default is not dataclasses.MISSING:
        return field.default
    if field.default_factory is not dataclasses.MISSING:
        value = field.default_factory()
        return None if value == [] else value  # typer spells "not given" for a repeatable option as None
    raise TypeError(f"field {field.name} needs a default to be an option")


def spec_parameters(
    cls: type, skip: tuple[str, ...] = (), more_help: Mapping[str, str] | None = None
) -> list[inspect.Parameter]:
    """One keyword parameter per field of ``cls`` but those in ``skip``, annotated as a typer option; ``more_help``
    adds text after a field's docstring (the command's own, e.g. the list of choices)."""
    hints = typing.get_type_hints(cls)
    docs = field_docs(cls)
    params: list[inspect.Parameter] = []
    for field in dataclasses.fields(cls):
        if field.name in skip:
            continue
        kind = hints[field.name]
        default = _default(field)
        if typing.get_origin(kind) is list:
            kind = kind | None
        flag = field.metadata.get("flag", "--" + field.name.replace("_", "-"))
        option = typer.Option(flag, help=docs.get(field.name, "") + (more_help or {}).get(field.name, ""))
        params.append(
            inspect.Parameter(
                field.name, inspect.Parameter.KEYWORD_ONLY, default=default, annotation=Annotated[kind, option]
            )
        )
    return params


def spec_command(
    cls: type,
    body: Callable[..., None],
    extra: list[inspect.Parameter] | None = None,
    skip: tuple[str, ...] = (),
    more_help: Mapping[str, str] | None = None,
) -> Callable[..., None]:
    """A function typer can register: its options are ``cls``'s fields (but ``skip``, which keep their defaults and
    which ``body`` fills from its own options) plus ``extra``; it calls ``body(spec, **extra_values)`` with the spec
    built from the given options."""
    names = {f.name for f in dataclasses.fields(cls)} - set(skip)
    params = spec_parameters(cls, skip, more_help) + list(extra or [])

    @functools.wraps(body)
    def command(**values: Any) -> None:
        fields = {k: v for k, v in values.items() if k in names}
        for field in dataclasses.fields(cls):
            if (
                field.name in names
                and fields.get(field.name) is None
                and field.default_factory is not dataclasses.MISSING
            ):
                fields[field.name] = field.default_factory()
        body(cls(**fields), **{k: v for k, v in values.items() if k not in names})

    del command.__wrapped__  # typer must read the signature below, not the body's
    command.__signature__ = inspect.Signature(params)  # type: ignore[attr-defined]
    command.__annotations__ = {p.name: p.annotation for p in params} | {"return": None}
    return command
