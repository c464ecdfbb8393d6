"""The ``sage`` command line. Each command group lives in its own module with a ``register(app)``; the options every
command reads the same way (``--set``, ``--scenario``, ``--sim``) live in :mod:`app.cli.options`."""

from __future__ import annotations

import importlib

import typer

COMMAND_MODULES = (
    "app.cli.serve",  # sage serve
    "app.cli.train",  # sage train / eval
    "app.cli.expert",  # sage expert
    "app.cli.gate",  # sage gate evaluate / choose-scale / refit-bounds / merge
    "app.cli.study",  # sage study
    "app.cli.cycles",  # sage cycles
    "app.cli.export",  # sage export
    "app.cli.figures",  # sage figure
)

RENAMED: dict[str, str] = {
    "calibrate": "gate evaluate",
    "choose-scale": "gate choose-scale",
    "recalibrate": "gate refit-bounds",
    "merge": "gate merge",
    "compare": "eval",
}
"""Retired command -> its new spelling; the old one prints the new and exits 2 (it runs nothing)."""

app = typer.Typer(
    name="sage",
    help="SAGE: self-aware guided exploration. Train, evaluate and supervise driving agents that ask for help.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

for _name in COMMAND_MODULES:
    importlib.import_module(_name).register(app)


def _register_renamed(old: str, new: str) -> None:
    def renamed() -> None:
        typer.secho(f"`sage {old}` is now `sage {new}`", fg=typer.colors.RED, err=True)
        raise typer.Exit(code=2)

    settings = {"allow_extra_args": True, "ignore_unknown_options": True, "help_option_names": []}
    app.command(old, hidden=True, add_help_option=False, context_settings=settings)(renamed)


for _old, _new in RENAMED.items():
    _register_renamed(_old, _new)


def main() -> None:
    app()
