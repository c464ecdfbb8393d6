"""The ``sage`` command line. Each command group lives in its own module with a ``register(app)``."""

from __future__ import annotations

import importlib

import typer

COMMAND_MODULES = (
    "app.cli.expert",  # sage expert
    "app.cli.train",  # sage train / eval / compare
    "app.cli.serve",  # sage serve
    "app.cli.export",  # sage export
    "app.cli.figures",  # sage figure
    "app.cli.cycles",  # sage cycles
    "app.cli.calibrate",  # sage calibrate
    "app.cli.merge",  # sage merge
    "app.cli.study",  # sage study
)

app = typer.Typer(
    name="sage",
    help="SAGE: self-aware guided exploration. Train, evaluate and supervise driving agents that ask for help.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

for _name in COMMAND_MODULES:
    importlib.import_module(_name).register(app)


def main() -> None:
    app()
