"""``sage train``, ``sage eval``, ``sage compare``: headless training and evaluation of the learners.

    sage train --sim ugv --scenario 3 --method sage --episodes 60 --seed 0 --init policies/ugv-default --out runs/s3
    sage eval runs/s3 --episodes 20 --scenario 1,2,3,4
    sage compare runs/s3 runs/s3-sac --episodes 20 --scenario 3

``--sim`` is any simulator of :data:`sims.SIMULATORS`; ``--scenario`` passes through to it (a comma list
trains on several in turn). ``--set key=value`` edits the learner's config (``--set gate.tau_max=0.7``;
fields: :mod:`core.sage.config`). The tables are the paper's (:mod:`core.report`): one row per run and
scenario, the simulator's own metric columns, then return and cost.
"""

from __future__ import annotations

import importlib
import json
import time
from pathlib import Path
from typing import Annotated, Any

import typer

BASE_COLUMNS_AFTER = ("return", "cost")
GATED_COLUMNS = ("takeover_rate", "mean_fear")


def _scenarios(value: str) -> list[str]:
    items = [s.strip() for s in value.split(",") if s.strip()]
    if not items:
        raise typer.BadParameter("give at least one scenario, e.g. 3 or 1,2")
    return items


def _make_env_factory(sim: str, overrides: dict[str, Any] | None = None) -> Any:
    import sims

    if sim not in sims.SIMULATORS:
        raise typer.BadParameter(f"unknown simulator {sim!r}; choose one of {', '.join(sims.SIMULATORS)}")

    def make_env(scenario: str) -> Any:
        arg: int | str = int(scenario) if scenario.isdigit() else scenario
        return sims.make(sim, scenario=arg, **(overrides or {}))

    return make_env


def table_columns(sim: str, rows: list[dict[str, Any]], gated: bool = False) -> list[str]:
    """The simulator's metric columns (its package's METRIC_COLUMNS, else the keys its metrics() gave)."""
    columns: list[str] = []
    try:
        module = importlib.import_module(f"sims.{sim}")
        columns = list(getattr(module, "METRIC_COLUMNS", ()))
    except ModuleNotFoundError:
        pass
    if not columns:
        skip = {
            "episode",
            "steps",
            "takeovers",
            "takeover_events",
            "mean_curiosity",
            "scenario",
            "phase",
            "error",
            *BASE_COLUMNS_AFTER,
            *GATED_COLUMNS,
        }
        for row in rows:
            for key, value in row.items():
                if key not in skip and key not in columns and isinstance(value, int | float):
                    columns.append(key)
    columns += list(BASE_COLUMNS_AFTER)
    if gated:
        columns += list(GATED_COLUMNS)
    return columns


def _fail(message: str) -> None:
    typer.secho(f"error: {message}", fg=typer.colors.RED, err=True)
    raise typer.Exit(code=2)


def register(app: typer.Typer) -> None:
    """Add ``train``, ``eval`` and ``compare``."""

    @app.command()
    def train(
        sim: Annotated[str, typer.Option(help="Simulator: ugv, highway, sumo.")] = "ugv",
        scenario: Annotated[
            str, typer.Option(help="Scenario(s) passed to the simulator; a comma list alternates.")
        ] = "1",
        method: Annotated[str, typer.Option(help="sage | sac | td3 | hg-dagger | fni-rl")] = "sage",
        episodes: Annotated[int, typer.Option(help="Training episodes.")] = 100,
        seed: Annotated[int, typer.Option(help="Seed of torch, numpy and the episodes.")] = 0,
        init: Annotated[
            str | None,
            typer.Option(help="Warm-start from this run folder or checkpoint (and take its hyperparameters)."),
        ] = None,
        out: Annotated[
            Path | None, typer.Option(help="Run folder (default runs/<sim>-<scenario>-<method>-s<seed>-<time>).")
        ] = None,
        demo_episodes: Annotated[int, typer.Option(help="Expert episodes recorded and cloned before training.")] = 0,
        demo_noise: Annotated[float, typer.Option(help="Std of noise on demonstrated expert actions.")] = 0.0,
        checkpoint_every: Annotated[
            int, typer.Option(help="Episodes between checkpoint versions (0: final only).")
        ] = 25,
        checkpoint_dtype: Annotated[
            str, typer.Option(help="float32, or float16 for small committed policies.")
        ] = "float32",
        max_episode_steps: Annotated[int | None, typer.Option(help="Cut episodes at this many steps.")] = None,
        set_: Annotated[
            list[str] | None, typer.Option("--set", help="Learner config override key=value (repeatable).")
        ] = None,
        quiet: Annotated[bool, typer.Option(help="No progress bar.")] = False,
    ) -> None:
        """Train a learner on a simulator with the one step loop; write a run folder."""
        import torch

        from core.agents import load_checkpoint
        from core.report import format_table
        from core.sage.config import apply_overrides, for_method, from_dict
        from core.train import RunConfig, Trainer

        torch.set_num_threads(1)
        try:
            # a warm start keeps the hyperparameters of the run it starts from; the method sets the switches
            base = from_dict(load_checkpoint(init)["agent_config"]) if init else None
            agent_cfg = apply_overrides(for_method(method, base=base), list(set_ or []))
        except (ValueError, FileNotFoundError) as exc:
            _fail(str(exc))
        scenarios = _scenarios(scenario)
        if out is None:
            stamp = time.strftime("%Y%m%d-%H%M%S")
            out = Path("runs") / f"{sim}-{'_'.join(scenarios)}-{method}-s{seed}-{stamp}"
        if (out / "checkpoint.pt").exists():
            _fail(f"{out} already holds a finished run; choose another --out")
        run_cfg = RunConfig(
            sim=sim,
            scenarios=scenarios,
            episodes=episodes,
            seed=seed,
            init=init,
            demo_episodes=demo_episodes,
            checkpoint_every=checkpoint_every,
            checkpoint_dtype=checkpoint_dtype,
            max_episode_steps=max_episode_steps,
        )
        try:
            trainer = Trainer(run_cfg, agent_cfg, _make_env_factory(sim), out, progress=not quiet)
            result = trainer.train()
        except (ValueError, FileNotFoundError, TypeError) as exc:
            _fail(str(exc))
        rows = result.rows
        tail = rows[-max(1, len(rows) // 4) :] if rows else []
        typer.echo(
            f"trained {method} on {sim} {','.join(scenarios)}: {len(rows)} episodes, "
            f"{result.learner.env_steps} steps, {result.learner.updates} updates in {result.seconds:.0f} s"
        )
        if tail:
            named = {f"last {len(tail)} episodes": tail}
            typer.echo(format_table(named, table_columns(sim, tail, gated=True)))
        typer.echo(f"run folder: {out}")

    @app.command("eval")
    def eval_(
        run: Annotated[Path, typer.Argument(help="Run folder or checkpoint file.")],
        episodes: Annotated[int, typer.Option(help="Episodes per scenario.")] = 20,
        scenario: Annotated[str | None, typer.Option(help="Scenario(s); default: the run's own.")] = None,
        seed: Annotated[int, typer.Option(help="Evaluation seed.")] = 0,
        gate: Annotated[
            bool, typer.Option(help="Run the SAGE gate (records fear; with --expert it takes over).")
        ] = False,
        expert: Annotated[bool, typer.Option(help="Let the gate hand over to the scripted expert.")] = False,
        save: Annotated[Path | None, typer.Option(help="Also write the rows to this JSON-lines file.")] = None,
        quiet: Annotated[bool, typer.Option(help="No progress bar.")] = False,
    ) -> None:
        """Run a learned policy with no expert and print the paper's table per scenario."""
        typer.echo(_evaluate_and_format([run], episodes, scenario, seed, gate, expert, save, quiet))

    @app.command()
    def compare(
        runs: Annotated[list[Path], typer.Argument(help="Run folders or checkpoints.")],
        episodes: Annotated[int, typer.Option(help="Episodes per run and scenario.")] = 20,
        scenario: Annotated[str | None, typer.Option(help="Scenario(s); default: each run's own.")] = None,
        seed: Annotated[int, typer.Option(help="Evaluation seed (the same episodes for every run).")] = 0,
        save: Annotated[Path | None, typer.Option(help="Also write the rows to this JSON-lines file.")] = None,
        quiet: Annotated[bool, typer.Option(help="No progress bar.")] = False,
    ) -> None:
        """Evaluate several runs on the same episodes and print them side by side."""
        typer.echo(_evaluate_and_format(runs, episodes, scenario, seed, False, False, save, quiet))


def _evaluate_and_format(
    runs: list[Path],
    episodes: int,
    scenario: str | None,
    seed: int,
    gate: bool,
    expert: bool,
    save: Path | None,
    quiet: bool,
) -> str:
    import torch

    from core.agents import load_agent
    from core.report import format_table
    from core.train import evaluate

    torch.set_num_threads(1)
    if expert and not gate:
        _fail("--expert needs --gate (the gate decides when the expert takes over)")
    named: dict[str, list[dict[str, Any]]] = {}
    sims_seen: list[str] = []
    all_rows: list[dict[str, Any]] = []
    for run in runs:
        try:
            agent = load_agent(run)
        except (FileNotFoundError, ValueError) as exc:
            _fail(str(exc))
        sim = agent.meta.sim
        sims_seen.append(sim)
        scenarios = _scenarios(scenario) if scenario else list(agent.meta.scenarios)
        if gate and not agent.has_world_model:
            _fail(f"{run} has no world model: no SAGE gate to run (drop --gate)")
        gate_factory = agent.make_gate if gate else None
        results = evaluate(
            agent.policy, _make_env_factory(sim), scenarios, episodes, seed, gate_factory, expert, progress=not quiet
        )
        label = run.name if run.is_dir() else f"{run.parent.name}/{run.stem}"
        for s, rows in results.items():
            named[f"{label} ({sim} {s})"] = rows
            all_rows += [dict(r, run=str(run)) for r in rows]
    if save is not None:
        save.parent.mkdir(parents=True, exist_ok=True)
        with save.open("w") as f:
            for row in all_rows:
                f.write(json.dumps(row, default=str) + "\n")
    columns = table_columns(sims_seen[0], all_rows, gated=gate)
    return format_table(named, columns)
