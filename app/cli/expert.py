"""``sage expert``: run a simulator's scripted expert headless and print the paper's metric table.

    sage expert --sim ugv --scenario 3 --episodes 50 --seed 0 --plot runs/ugv3.png

The expert drives through the one step loop (:class:`core.loop.Runner` with
:class:`core.experts.ExpertPolicy` as the policy). ``--plot`` draws the trajectories over the map
with the simulator's ``plot`` module (``sims.<sim>.plot.plot_episodes``), from recorded scenes.
"""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import Annotated, Any

import typer

from app.cli.options import NamedChoicesCommand, one_scenario

OUTCOMES = ("success", "collision", "timeout")


def _outcome(metrics: dict[str, Any], error: str | None) -> str:
    if error:
        return "error"
    for key in OUTCOMES:
        if metrics.get(key):
            return key
    return "other"


def run_expert(
    sim: str, scenario: str | None, episodes: int, seed: int, plot: Path | None, progress: bool = True
) -> tuple[list[dict[str, Any]], Path | None]:
    """Run the expert for ``episodes`` episodes; return the per-episode rows (and the plot's path)."""
    from tqdm import tqdm

    import sims
    from core.experts import ExpertPolicy
    from core.loop import EpisodeSummary, Runner, StepRecord
    from core.protocol import simulator

    env = sims.make(sim, scenario)  # a clear ValueError for an unknown simulator or scenario name
    plot_module = None
    if plot is not None:
        try:
            plot_module = importlib.import_module(f"sims.{sim}.plot")
        except ModuleNotFoundError:
            raise ValueError(f"simulator {sim!r} has no plot module (sims/{sim}/plot.py); drop --plot") from None
    runner = Runner(env, ExpertPolicy(env), seed=seed)
    summaries: list[EpisodeSummary] = []
    runner.episode_listeners.append(summaries.append)
    traces: list[Any] = []
    if plot_module is not None:
        runner.step_listeners.append(lambda record: traces[-1].record(simulator(env).scene()))
    rows: list[dict[str, Any]] = []
    name = f"{sim} scenario {scenario}" if scenario is not None else sim
    bar = tqdm(range(episodes), desc=name, unit="ep", disable=not progress, leave=False)
    try:
        for episode in bar:
            runner.reset()
            if plot_module is not None:
                trace = plot_module.EpisodeTrace(first_scene=simulator(env).scene())
                trace.record(trace.first_scene)
                traces.append(trace)
            record: StepRecord | None = None
            while len(summaries) <= episode:
                record = runner.step()
            summary = summaries[episode]
            outcome = _outcome(summary.metrics, summary.error)
            if plot_module is not None:
                traces[-1].outcome = outcome
            rows.append(summary.as_row())
            done = sum(r.get("success", 0) for r in rows)
            bar.set_postfix_str(f"success {done:.0f}/{len(rows)}")
            del record
    finally:
        bar.close()
        env.close()
    written = None
    if plot_module is not None and plot is not None:
        written = plot_module.plot_episodes(traces, plot, title=f"{name}: scripted expert, {episodes} episodes")
    return rows, written


def register(app: typer.Typer) -> None:
    """Add ``sage expert`` to ``app``."""

    @app.command("expert", cls=NamedChoicesCommand)
    def expert(
        sim: Annotated[str, typer.Option("--sim", help="Simulator: {SIMS}.")] = "ugv",
        scenario: Annotated[
            list[str] | None,
            typer.Option("--scenario", help="Scenario name or file (one; default: the simulator's own)."),
        ] = None,
        episodes: Annotated[int, typer.Option("--episodes", min=1, help="Number of episodes.")] = 20,
        seed: Annotated[int, typer.Option("--seed", help="Seed of the first episode (then seed + 1, ...).")] = 0,
        plot: Annotated[Path | None, typer.Option("--plot", help="Write a PNG of the trajectories.")] = None,
    ) -> None:
        """Run the scripted expert headless and print the paper's metric table."""
        from core.report import format_table

        name = one_scenario(scenario, "sage expert")
        try:
            rows, written = run_expert(sim, name, episodes, seed, plot)
        except (ValueError, FileNotFoundError) as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(2) from None
        errors = [r["error"] for r in rows if r.get("error")]
        metric_columns = [k for k in rows[0] if k not in ("episode", "steps", "return", "cost", "error")]
        metric_columns = [k for k in metric_columns if not k.startswith(("takeover", "mean_"))]
        columns = [*metric_columns, "return", "cost"]
        label = f"expert ({sim} {name})" if name is not None else f"expert ({sim})"
        typer.echo(format_table({label: rows}, columns))
        if errors:
            typer.echo(f"{len(errors)} episode(s) ended by a simulator error, first: {errors[0]}", err=True)
        if written is not None:
            typer.echo(f"trajectories: {written}")
