"""``sage figure``: the paper's figures from finished run folders.

    sage figure route-shift runs/sumo-route_shift-sage-s0 runs/sumo-route_shift-sac-s0 --out docs/figures

``route-shift`` overlays the success, collision and red-light rates of several route-shift runs (one line per
run, the switch marked) and draws the SAGE signals (takeover frequency, mean fear, mean curiosity) of every
run that recorded fear. Figures are PNG files; the drawing is :mod:`studies.route_shift_figures`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer


def _fail(message: str) -> None:
    typer.secho(f"error: {message}", fg=typer.colors.RED, err=True)
    raise typer.Exit(code=2)


def register(app: typer.Typer) -> None:
    """Add the ``figure`` command group."""
    group = typer.Typer(help="Draw the paper's figures from run folders.", no_args_is_help=True)
    app.add_typer(group, name="figure")

    @group.command("route-shift")
    def route_shift(
        runs: Annotated[list[Path], typer.Argument(help="Run folders of sage train --protocol route-shift.")],
        out: Annotated[Path, typer.Option(help="Folder the PNG files go to.")] = Path("figures"),
        label: Annotated[
            str | None, typer.Option(help="Comma list of legend labels, one per run (default: the method).")
        ] = None,
        window: Annotated[
            int | None, typer.Option(help="Moving-average window in episodes (default: a tenth of the run, 3-50).")
        ] = None,
        prefix: Annotated[str, typer.Option(help="File name prefix.")] = "route_shift",
    ) -> None:
        """Success / collision / red-light rates over episodes with the route switch marked, and SAGE's signals."""
        from studies.route_shift import phase_table, read_run
        from studies.route_shift_figures import write_figures

        labels = [s.strip() for s in label.split(",")] if label else []
        if labels and len(labels) != len(runs):
            _fail(f"--label gives {len(labels)} labels for {len(runs)} runs")
        if window is not None and window < 1:
            _fail("--window must be at least 1")
        try:
            studies = [read_run(run, labels[k] if labels else None) for k, run in enumerate(runs)]
        except (FileNotFoundError, ValueError) as exc:
            _fail(str(exc))
        typer.echo(phase_table(studies))
        for path in write_figures(studies, out, window, prefix):
            typer.echo(f"figure: {path}")
