"""``sage train``, ``sage eval``, ``sage compare``: headless training and evaluation of the learners.

    sage train --sim ugv --scenario 3 --method sage --episodes 60 --seed 0 --init policies/ugv-default --out runs/s3
    sage eval runs/s3 --episodes 20 --scenario 1,2,3,4
    sage compare runs/s3 runs/s3-sac --episodes 20 --scenario 3
    sage train --sim highway --method sage --episodes 150            # closed-loop adversarial (CAT-style)
    sage eval runs/hw --sim highway --split test --mode normal,adversarial --episodes 50 --seeds 0,1,2,3,4
    sage train --sim sumo --protocol route-shift --method sage --c1 40 --c2 20   # + figures in the run folder

``sage train``'s options are the fields of :class:`studies.training.TrainSpec` (the composition root: each
default and help text is written there once, and a study sweep builds the same spec without a shell).
``--sim`` is any simulator of :data:`sims.SIMULATORS`; ``--scenario`` names its variant (a comma list
trains on several in turn; :mod:`studies.envs`: UGV 1-4, highway train/test, SUMO c1/c2). The study
protocols (highway closed-loop adversaries, SUMO route shift) live in :mod:`studies`. In ``sage train``,
``--set key=value`` edits the learner's config (``--set gate.tau_max=0.7``; fields: :mod:`core.sage.config`);
in ``sage eval`` / ``compare`` on highway, ``--split`` is the logged split (train or test), as in the paper.
The tables are the paper's (:mod:`core.report`): one row per run and scenario, the simulator's own
metric columns, then return and cost.
"""

from __future__ import annotations

import contextlib
import inspect
import json
from pathlib import Path
from typing import Annotated, Any

import typer

from app.cli.spec_command import spec_command
from studies.spec import TrainSpec

BASE_COLUMNS_AFTER = ("return", "cost")
SplitOption = Annotated[str, typer.Option("--split", help="highway: logged split(s), train and/or test (comma list).")]
ModeOption = Annotated[str, typer.Option(help="highway: normal and/or adversarial (comma list).")]
SeedsOption = Annotated[str | None, typer.Option(help="Evaluation seeds, pooled (comma list; overrides --seed).")]
GATED_COLUMNS = ("takeover_rate", "mean_fear")


def _scenarios(value: str) -> list[str]:
    items = [s.strip() for s in value.split(",") if s.strip()]
    if not items:
        raise typer.BadParameter("give at least one scenario, e.g. 3 or 1,2")
    return items


def _make_env_factory(sim: str, overrides: dict[str, Any] | None = None) -> Any:
    from studies.envs import env_factory

    try:
        return env_factory(sim, **(overrides or {}))
    except ValueError as exc:
        raise typer.BadParameter(str(exc)) from None


def _ints(value: str) -> list[int]:
    try:
        return [int(s) for s in value.split(",") if s.strip()]
    except ValueError:
        raise typer.BadParameter(f"{value!r} is not a comma list of integers, e.g. 0,1,2") from None


def table_columns(sim: str, rows: list[dict[str, Any]], gated: bool = False) -> list[str]:
    """The simulator's metric columns (its descriptor's, else the keys its metrics() gave)."""
    import sims

    columns: list[str] = []
    with contextlib.suppress(ValueError):  # an unregistered simulator: the keys its metrics() gave
        columns = list(sims.descriptor(sim).metric_columns)
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
            "seed",
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

    def train(spec: TrainSpec, quiet: bool = False) -> None:
        """Train a learner on a simulator with the one step loop; write a run folder."""
        import torch

        from core.report import format_table
        from studies.training import run_training

        torch.set_num_threads(1)
        try:
            outcome = run_training(spec, progress=not quiet)
        except (ValueError, FileNotFoundError, TypeError) as exc:
            _fail(str(exc))
        result, rows = outcome.result, outcome.result.rows
        tail = rows[-max(1, len(rows) // 4) :] if rows else []
        method, scenarios = result.learner.cfg.method, ",".join(outcome.setup.scenarios)
        typer.echo(
            f"trained {method} on {spec.sim} {scenarios}: {len(rows)} episodes, "
            f"{result.learner.env_steps} steps, {result.learner.updates} updates in {result.seconds:.0f} s"
        )
        if tail:
            named = {f"last {len(tail)} episodes": tail}
            typer.echo(format_table(named, table_columns(spec.sim, tail, gated=True)))
        fear_term = result.learner.describe_fear_term()
        if fear_term is not None:
            typer.echo(fear_term)
        for line in outcome.lines:
            typer.echo(line)
        typer.echo(f"run folder: {outcome.out}")

    quiet = inspect.Parameter(
        "quiet",
        inspect.Parameter.KEYWORD_ONLY,
        default=False,
        annotation=Annotated[bool, typer.Option(help="No progress bar.")],
    )
    app.command("train")(spec_command(TrainSpec, train, [quiet]))

    @app.command("eval")
    def eval_(
        run: Annotated[
            Path, typer.Argument(help="Run folder or checkpoint file, or a planner's name (core.planners), with --sim.")
        ],
        episodes: Annotated[int, typer.Option(help="Episodes per scenario.")] = 20,
        scenario: Annotated[str | None, typer.Option(help="Scenario(s); default: the run's own.")] = None,
        seed: Annotated[int, typer.Option(help="Evaluation seed.")] = 0,
        gate: Annotated[
            bool, typer.Option(help="Run the SAGE gate (records fear; with --expert it takes over).")
        ] = False,
        expert: Annotated[bool, typer.Option(help="Let the gate hand over to the scripted expert.")] = False,
        gate_set: Annotated[
            list[str] | None,
            typer.Option(
                "--gate-set",
                help="A setting of the gate over the run's own, KEY=VALUE (repeatable; with --gate), e.g. "
                "hold_seconds=2 or release=0: any field of core.sage.config.GateConfig.",
            ),
        ] = None,
        save: Annotated[Path | None, typer.Option(help="Also write the rows to this JSON-lines file.")] = None,
        quiet: Annotated[bool, typer.Option(help="No progress bar.")] = False,
        sim: Annotated[str | None, typer.Option(help="Simulator (default: the run's own; must match it).")] = None,
        split: SplitOption = "test",
        mode: ModeOption = "normal,adversarial",
        seeds: SeedsOption = None,
    ) -> None:
        """Run a learned policy with no expert and print the paper's table per scenario.

        On highway: the first --episodes scenarios of each --set, in each --mode
        (adversaries aimed at the evaluated policy), pooled over --seeds, with the
        paper's columns: success and collision rates, speed and acceleration; with --scenario, --gate or
        --expert, the per-scenario table instead (on highway: test, test-adversarial, train, ...)."""
        seed_list = _ints(seeds) if seeds else [seed]
        run_sim = _run_sim([run], sim)
        if gate_set and not gate:
            _fail("--gate-set needs --gate (it sets the gate the run drives with)")
        generic = scenario is not None or gate or expert  # the protocol table runs the policy alone, on its sets
        table = None if generic else _protocol_table(run_sim, [run], episodes, split, mode, seed_list, save, quiet)
        if table is not None:
            typer.echo(table)
            return
        typer.echo(
            _evaluate_and_format(
                run_sim, [run], episodes, scenario, seed_list, gate, expert, save, quiet, gate_set=gate_set or []
            )
        )

    @app.command()
    def compare(
        runs: Annotated[
            list[Path], typer.Argument(help="Run folders or checkpoints, or planner names (core.planners).")
        ],
        episodes: Annotated[int, typer.Option(help="Episodes per run and scenario.")] = 20,
        scenario: Annotated[str | None, typer.Option(help="Scenario(s); default: each run's own.")] = None,
        seed: Annotated[int, typer.Option(help="Evaluation seed (the same episodes for every run).")] = 0,
        save: Annotated[Path | None, typer.Option(help="Also write the rows to this JSON-lines file.")] = None,
        quiet: Annotated[bool, typer.Option(help="No progress bar.")] = False,
        split: SplitOption = "test",
        mode: ModeOption = "normal,adversarial",
        seeds: SeedsOption = None,
        sim: Annotated[str | None, typer.Option(help="Simulator (needed when only planners are compared).")] = None,
    ) -> None:
        """Evaluate several runs on the same episodes and print them side by side."""
        seed_list = _ints(seeds) if seeds else [seed]
        run_sim = _run_sim(runs, sim)
        table = _protocol_table(run_sim, runs, episodes, split, mode, seed_list, save, quiet)
        if table is not None:
            typer.echo(table)
            return
        typer.echo(_evaluate_and_format(run_sim, runs, episodes, scenario, seed_list, False, False, save, quiet))


def _label(run: Path) -> str:
    if run.is_dir() or not run.parent.name:  # a run folder, or a planner's name
        return run.name
    return f"{run.parent.name}/{run.stem}"


def _run_sim(runs: list[Path], sim: str | None) -> str:
    """The simulator the runs were trained on (all the same, and ``sim`` when given). A planner's name
    (:mod:`core.planners`) stands for a policy too; it drives the ``--sim`` it is given."""
    import sims  # noqa: F401 (registers the simulators' planners)
    from core.agents import load_checkpoint, meta_of
    from core.planners import is_planner

    seen = []
    for run in runs:
        if is_planner(str(run)):
            continue
        try:
            seen.append(meta_of(load_checkpoint(run)).sim)
        except (FileNotFoundError, ValueError) as exc:
            _fail(str(exc))
    if sim is not None and any(s != sim for s in seen):
        _fail(f"--sim {sim}: the run was trained on {', '.join(sorted(set(seen)))}")
    if not seen and sim is None:
        _fail(f"{runs[0]} is a planner: say which simulator it drives with --sim")
    return sim if sim is not None else seen[0]


def _write_rows(save: Path, rows: list[dict[str, Any]]) -> None:
    save.parent.mkdir(parents=True, exist_ok=True)
    with save.open("w") as f:
        for row in rows:
            f.write(json.dumps(row, default=str) + "\n")


def _protocol_table(
    sim: str, runs: list[Path], episodes: int, split: str, mode: str, seeds: list[int], save: Path | None, quiet: bool
) -> str | None:
    """The simulator's own evaluation protocol (:mod:`studies.evaluation`), or None where it has none."""
    import torch

    from studies.evaluation import protocol_for

    protocol = protocol_for(sim)
    if protocol is None:
        return None
    torch.set_num_threads(1)
    try:
        text, rows = protocol([str(r) for r in runs], episodes, split, mode, seeds, not quiet)
    except (ValueError, FileNotFoundError) as exc:
        _fail(str(exc))
    if save is not None:
        _write_rows(save, rows)
    return text


def _evaluate_and_format(
    sim_given: str,
    runs: list[Path],
    episodes: int,
    scenario: str | None,
    seeds: list[int],
    gate: bool,
    expert: bool,
    save: Path | None,
    quiet: bool,
    gate_set: list[str] | None = None,
) -> str:
    import functools

    import torch

    import sims
    from core.agents import load_agent
    from core.planners import is_planner, make_planner
    from core.report import format_table
    from core.sage.config import parse_gate_settings
    from core.train import evaluate

    torch.set_num_threads(1)
    if expert and not gate:
        _fail("--expert needs --gate (the gate decides when the expert takes over)")
    try:
        parse_gate_settings(gate_set or [])  # an unreadable setting stops here, before any run loads
    except ValueError as exc:
        _fail(f"--gate-set: {exc}")
    named: dict[str, list[dict[str, Any]]] = {}
    sims_seen: list[str] = []
    all_rows: list[dict[str, Any]] = []
    for run in runs:
        if is_planner(str(run)):  # a planner that is not a learner: no checkpoint, no gate
            if gate:
                _fail(f"{run} is a planner: it has no world model, so no SAGE gate (drop --gate)")
            sim = sim_given
            try:
                default = sims.descriptor(sim).default_scenario
            except ValueError as exc:
                _fail(str(exc))
            scenarios = _scenarios(scenario) if scenario else [default]
            policy: Any = functools.partial(make_planner, str(run), sim=sim)
            gate_factory = None
        else:
            try:
                agent = load_agent(run)
            except (FileNotFoundError, ValueError) as exc:
                _fail(str(exc))
            sim = agent.meta.sim
            scenarios = _scenarios(scenario) if scenario else list(agent.meta.scenarios)
            if gate and not agent.has_world_model:
                _fail(f"{run} has no world model: no SAGE gate to run (drop --gate)")
            try:
                # the run's simulator's contact floors, should the settings switch imagined contact on
                run_settings = parse_gate_settings(gate_set or [], sims.descriptor(sim).contact_floors)
                agent.gate_config(**run_settings)
            except ValueError as exc:
                _fail(f"--gate-set: {exc}")
            policy = agent.policy
            gate_factory = functools.partial(agent.make_gate, **run_settings) if gate else None
        sims_seen.append(sim)
        results: dict[str, list[dict[str, Any]]] = {}
        for seed in seeds:
            try:
                by_scenario = evaluate(
                    policy, _make_env_factory(sim), scenarios, episodes, seed, gate_factory, expert, not quiet
                )
            except ValueError as exc:
                _fail(str(exc))
            for s, rows in by_scenario.items():
                results.setdefault(s, []).extend(dict(r, seed=seed) for r in rows)
        label = _label(run)
        for s, rows in results.items():
            named[f"{label} ({sim} {s})"] = rows
            all_rows += [dict(r, run=str(run)) for r in rows]
    if save is not None:
        _write_rows(save, all_rows)
    columns = table_columns(sims_seen[0], all_rows, gated=gate)
    return format_table(named, columns)
