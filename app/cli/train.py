"""``sage train`` and ``sage eval``: headless training and evaluation of the learners.

    sage train --sim ugv --scenario 3 --method sage --episodes 60 --seed 0 --init policies/ugv-default --out runs/s3
    sage eval runs/s3 --episodes 20 --scenario 1,2,3,4
    sage eval runs/s3 runs/s3-sac --episodes 20 --scenario 3          # several runs: side by side
    sage train --sim highway --method sage --episodes 150            # closed-loop adversarial (CAT-style)
    sage eval runs/hw --split test --mode normal,adversarial --episodes 50 --seeds 0,1,2,3,4
    sage train --sim sumo --protocol route-shift --method sage --c1 40 --c2 20   # + figures in the run folder

``sage train``'s options are the fields of :class:`studies.training.TrainSpec` (the composition root: each
default and help text is written there once, and a study sweep builds the same spec without a shell), with the
options every command shares (:mod:`app.cli.options`): ``--sim`` is any simulator of :data:`sims.SIMULATORS`
(a run's own where one is given); ``--scenario`` names its variants (repeatable, comma lists; :mod:`studies.envs`:
UGV 1-4, highway train/test, SUMO c1/c2), trained on in turn; ``--set`` edits the learner's config
(``--set gate.tau_max=0.7``, ``--set hidden=64``; fields: :mod:`core.sage.config`) and the simulator's
(``--set env.expert.horizon=0.5``). The study protocols (highway closed-loop adversaries, SUMO route shift) live in
:mod:`studies`. In ``sage eval`` on highway, ``--split`` is the logged split (train or test), as in the paper.
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

from app.cli.options import (
    ENV_SECTIONS,
    GATE_SET_HELP,
    LEARNER_SECTIONS,
    LEARNER_SET_HELP,
    EnvRetired,
    GateSetRetired,
    NamedChoicesCommand,
    checked_device,
    describe_device,
    fail,
    gate_pairs,
    refuse_retired,
    routed_settings,
    runs_sim,
    scenario_list,
)
from app.cli.spec_command import spec_command
from studies.spec import TrainSpec

BASE_COLUMNS_AFTER = ("return", "cost")
SplitOption = Annotated[str, typer.Option("--split", help="highway: logged split(s), train and/or test (comma list).")]
ModeOption = Annotated[str, typer.Option(help="highway: normal and/or adversarial (comma list).")]
SeedsOption = Annotated[str | None, typer.Option(help="Evaluation seeds, pooled (comma list; overrides --seed).")]
GATED_COLUMNS = ("takeover_rate", "mean_fear")


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


def register(app: typer.Typer) -> None:
    """Add ``train`` and ``eval``."""

    def train(
        spec: TrainSpec,
        sim: str | None = None,
        scenario: list[str] | None = None,
        set_: list[str] | None = None,
        env: list[str] | None = None,
        quiet: bool = False,
    ) -> None:
        """Train a learner on a simulator with the one step loop; write a run folder."""
        import torch

        from core.report import format_table
        from studies.training import run_training

        refuse_retired(env=env)
        settings = routed_settings(set_, ENV_SECTIONS | LEARNER_SECTIONS, other="learner")
        if spec.init is not None and Path(spec.init).exists():
            sim = runs_sim([spec.init], sim)  # a warm start drives the simulator its run was trained on
        names = scenario_list(scenario)
        spec = spec.replace(
            device=checked_device(spec.device),
            sim=sim or TrainSpec.sim,
            scenario=",".join(names) if names else None,
            env=settings.get("env", []),
            overrides=settings.get("learner", []),
        )
        torch.set_num_threads(1)
        try:
            outcome = run_training(spec, progress=not quiet)
        except (ValueError, FileNotFoundError, TypeError) as exc:
            fail(str(exc))
        result, rows = outcome.result, outcome.result.rows
        tail = rows[-max(1, len(rows) // 4) :] if rows else []
        method, scenarios = result.learner.cfg.method, ",".join(outcome.setup.scenarios)
        typer.echo(
            f"trained {method} on {spec.sim} {scenarios}: {len(rows)} episodes, "
            f"{result.learner.env_steps} steps, {result.learner.updates} updates in {result.seconds:.0f} s "
            f"(updates on {describe_device(result.learner.device)})"
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

    def option(name: str, annotation: Any, default: Any = None) -> inspect.Parameter:
        return inspect.Parameter(name, inspect.Parameter.KEYWORD_ONLY, default=default, annotation=annotation)

    extra = [
        option(
            "sim",
            Annotated[
                str | None,
                typer.Option(help="Simulator: {SIMS}. Default: that of the --init run, else ugv (must match the run)."),
            ],
        ),
        option(
            "scenario",
            Annotated[
                list[str] | None,
                typer.Option(
                    help="Scenario(s) by the simulator's names (ugv 1-4, highway train|test, sumo c1|c2, pedestrian "
                    "crossing|rare); repeatable or a comma list: trains on each in turn. Default: the simulator's."
                ),
            ],
        ),
        option(
            "set_",
            Annotated[
                list[str] | None,
                typer.Option(
                    "--set",
                    help=f"A setting, section.key=value (repeatable): {LEARNER_SET_HELP}; env.KEY=VALUE: the "
                    "simulator's config for every env of the run, e.g. env.expert.yield_to_movers=false on ugv (a "
                    "value is read as JSON where it parses: false, 0.3).",
                ),
            ],
        ),
        option("env", EnvRetired),
        option("quiet", Annotated[bool, typer.Option(help="No progress bar.")], False),
    ]
    more_help = {
        "method": " One of: {METHODS}.",
        "expert": " Planners: {PLANNERS}.",
        "demo_expert": " Planners: {PLANNERS}.",
    }
    command = spec_command(TrainSpec, train, extra, skip=("sim", "scenario", "env", "overrides"), more_help=more_help)
    app.command("train", cls=NamedChoicesCommand)(command)

    @app.command("eval", cls=NamedChoicesCommand)
    def eval_(
        runs: Annotated[
            list[Path],
            typer.Argument(
                metavar="RUN",
                help="Run folder(s) or checkpoint(s), or a planner's name ({PLANNERS}) with --sim. Several: the "
                "same episodes for every run, side by side.",
                show_default=False,
            ),
        ],
        episodes: Annotated[int, typer.Option(help="Episodes per run and scenario.")] = 20,
        scenario: Annotated[
            list[str] | None,
            typer.Option(help="Scenario(s), repeatable or a comma list; default: each run's own."),
        ] = None,
        seed: Annotated[int, typer.Option(help="Evaluation seed (the same episodes for every run).")] = 0,
        gate: Annotated[
            bool, typer.Option(help="Run the SAGE gate (records fear; with --expert it takes over).")
        ] = False,
        expert: Annotated[bool, typer.Option(help="Let the gate hand over to the scripted expert.")] = False,
        set_: Annotated[list[str] | None, typer.Option("--set", help=f"With --gate: {GATE_SET_HELP}")] = None,
        save: Annotated[Path | None, typer.Option(help="Also write the rows to this JSON-lines file.")] = None,
        quiet: Annotated[bool, typer.Option(help="No progress bar.")] = False,
        sim: Annotated[
            str | None,
            typer.Option(
                help="Simulator: {SIMS}. Default: the runs' own (must match them); needed for planners alone."
            ),
        ] = None,
        split: SplitOption = "test",
        mode: ModeOption = "normal,adversarial",
        seeds: SeedsOption = None,
        gate_set: GateSetRetired = None,
    ) -> None:
        """Run learned policies with no expert and print the paper's table per scenario (several runs: side by side).

        On highway: the first --episodes scenarios of each --split, in each --mode
        (adversaries aimed at the evaluated policy), pooled over --seeds, with the
        paper's columns: success and collision rates, speed and acceleration; with --scenario, --gate or
        --expert, the per-scenario table instead (on highway: test, test-adversarial, train, ...)."""
        refuse_retired(gate_set=gate_set)
        seed_list = _ints(seeds) if seeds else [seed]
        gate_settings = gate_pairs(set_)
        run_sim = runs_sim(runs, sim, planners=True)
        if gate_settings and not gate:
            fail("--set gate.… needs --gate (it sets the gate the run drives with)")
        names = scenario_list(scenario)
        generic = bool(names) or gate or expert  # the protocol table runs the policy alone, on its sets
        table = None if generic else _protocol_table(run_sim, runs, episodes, split, mode, seed_list, save, quiet)
        if table is not None:
            typer.echo(table)
            return
        typer.echo(
            _evaluate_and_format(
                run_sim, runs, episodes, names, seed_list, gate, expert, save, quiet, gate_set=gate_settings
            )
        )


def _label(run: Path) -> str:
    if run.is_dir() or not run.parent.name:  # a run folder, or a planner's name
        return run.name
    return f"{run.parent.name}/{run.stem}"


def run_labels(runs: list[Path]) -> list[str]:
    """A table label per run, distinct even where runs share a name (the v0008 of several cycles runs): such runs
    are named by as many of their parent folders as it takes, else numbered. Rows are keyed by label, so two runs
    under one label would show as one."""
    labels = [_label(run) for run in runs]
    for depth in range(1, max((len(run.parts) for run in runs), default=0)):
        repeated = {label for label in labels if labels.count(label) > 1}
        if not repeated:
            return labels
        labels = [
            "/".join([*run.parts[-depth - 1 : -1], label.rsplit("/", 1)[-1]]) if label in repeated else label
            for run, label in zip(runs, labels, strict=True)
        ]
    seen: dict[str, int] = {}
    numbered = []
    for label in labels:
        seen[label] = seen.get(label, 0) + 1
        numbered.append(label if labels.count(label) == 1 else f"{label} #{seen[label]}")
    return numbered


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
        fail(str(exc))
    if save is not None:
        _write_rows(save, rows)
    return text


def _evaluate_and_format(
    sim_given: str,
    runs: list[Path],
    episodes: int,
    scenario: list[str],
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
        fail("--expert needs --gate (the gate decides when the expert takes over)")
    try:
        parse_gate_settings(gate_set or [])  # an unreadable setting stops here, before any run loads
    except ValueError as exc:
        fail(f"--set gate.…: {exc}")
    named: dict[str, list[dict[str, Any]]] = {}
    sims_seen: list[str] = []
    all_rows: list[dict[str, Any]] = []
    for run, label in zip(runs, run_labels(runs), strict=True):
        if is_planner(str(run)):  # a planner that is not a learner: no checkpoint, no gate
            if gate:
                fail(f"{run} is a planner: it has no world model, so no SAGE gate (drop --gate)")
            sim = sim_given
            try:
                default = sims.descriptor(sim).default_scenario
            except ValueError as exc:
                fail(str(exc))
            scenarios = scenario or [default]
            policy: Any = functools.partial(make_planner, str(run), sim=sim)
            gate_factory = None
        else:
            try:
                agent = load_agent(run)
            except (FileNotFoundError, ValueError) as exc:
                fail(str(exc))
            sim = agent.meta.sim
            scenarios = scenario or list(agent.meta.scenarios)
            if gate and not agent.has_world_model:
                fail(f"{run} has no world model: no SAGE gate to run (drop --gate)")
            try:
                # the run's simulator's contact floors, should the settings switch imagined contact on
                run_settings = parse_gate_settings(gate_set or [], sims.descriptor(sim).contact_floors)
                agent.gate_config(**run_settings)
            except ValueError as exc:
                fail(f"--set gate.…: {exc}")
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
                fail(str(exc))
            for s, rows in by_scenario.items():
                results.setdefault(s, []).extend(dict(r, seed=seed) for r in rows)
        for s, rows in results.items():
            named[f"{label} ({sim} {s})"] = rows
            all_rows += [dict(r, run=str(run)) for r in rows]
    if save is not None:
        _write_rows(save, all_rows)
    columns = table_columns(sims_seen[0], all_rows, gated=gate)
    return format_table(named, columns)
