"""``sage figure``: the paper's figures from finished run folders.

    sage figure route-shift runs/sumo-route_shift-sage-s0 runs/sumo-route_shift-sac-s0 --out docs/figures

``route-shift`` overlays the success, collision and red-light rates of several route-shift runs (one line per
run, the switch marked) and draws the SAGE signals (takeover frequency, mean fear, mean curiosity) of every
run that recorded fear. Figures are PNG files; the drawing is :mod:`studies.route_shift_figures`.

    sage figure learning-curves runs/highway-40k --methods sac,sage --out runs/highway-40k

``learning-curves`` draws training metrics over environment steps from run folders named ``<method>-s<seed>``
(mean over seeds, 95% band), as every study does for its own trials (:mod:`studies.learning_curves`).
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
        try:
            paths = write_figures(studies, out, window, prefix)
        except ValueError as exc:  # e.g. runs whose switch came after different numbers of episodes (by steps)
            _fail(str(exc))
        for path in paths:
            typer.echo(f"figure: {path}")

    @group.command("learning-curves")
    def learning_curves(
        runs_dir: Annotated[Path, typer.Argument(help="Folder of run folders named <method>-s<seed>.")],
        methods: Annotated[str, typer.Option(help="Comma list of methods (the run folders' prefixes).")],
        metrics: Annotated[str, typer.Option(help="Comma list of per-episode training metrics.")] = "success,collision",
        out: Annotated[Path, typer.Option(help="Folder the PNG file goes to.")] = Path("figures"),
        name: Annotated[str, typer.Option(help="File name.")] = "learning_curves.png",
    ) -> None:
        """Training metrics over environment steps, mean over seeds with a 95% band (what the studies draw)."""
        from studies.learning_curves import write_learning_curves

        names = [m.strip() for m in methods.split(",") if m.strip()]
        keys = [k.strip() for k in metrics.split(",") if k.strip()]
        if not names or not keys:
            _fail("give at least one method and one metric")
        missing = [m for m in names if not any(runs_dir.glob(f"{m}-s*"))]
        if missing:
            _fail(f"{runs_dir} holds no run folder <method>-s<seed> for {', '.join(missing)}")
        out.mkdir(parents=True, exist_ok=True)
        paths = write_learning_curves(runs_dir, out, names, keys, name)
        if not paths:
            _fail(f"no training episodes with {', '.join(keys)} in those runs")
        for path in paths:
            typer.echo(f"figure: {path}")
