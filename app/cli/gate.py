"""``sage gate``: measure and set a trained run's SAGE gate (:mod:`studies.calibrate`, :mod:`studies.recalibrate`,
:mod:`core.merge`). The simulator is the run's own (``--sim``, when given, must be it).

``sage gate evaluate``: does the policy's fear predict danger? The policy drives with its gate and no expert:

    sage gate evaluate policies/ugv-default --scenario 3 --episodes 20 --curve-episodes 20 --out calib/ugv3
    sage gate evaluate policies/ugv-default --scenario 3 --episodes 150 --curve-episodes 300 --cpus 16
    sage gate evaluate policies/ugv-default --scenario 4 --episodes 20 --expert-lead
    sage gate evaluate policies/ugv-default --scenario 3 --episodes 20 --escape
    sage gate evaluate policies/ugv-default --scenario 3 --episodes 20 --curve-episodes 20 --set gate.hold_seconds=2

``sage gate choose-scale``: the gate's operating point for a risk target, chosen on the training scenarios
(:func:`studies.calibrate.choose_tau_scale`); deploy it with ``--set gate.tau_scale=X`` (a 0-episode run):

    sage gate choose-scale policies/highway-default --scenario train,train-adversarial --episodes 100

``sage gate refit-bounds``: the τ bounds measured again for other fear settings, or for β chosen on the training
scenarios' drives (:mod:`studies.recalibrate`); a new run folder, the world model's weights unchanged:

    sage gate refit-bounds policies/ugv-default --scenario 1,2 --set gate.beta=0.8 --out runs/ugv-beta08
    sage gate refit-bounds policies/pedestrian-default --scenario crossing,rare --choose-beta --out runs/ped-beta

``sage gate merge``: one ensemble from the world models of several refits of a policy (:mod:`core.merge`):

    for seed in 0 1 2 3 4; do sage train ... --world-model-only --init POLICY --seed $seed --out runs/wm-$seed; done
    sage gate merge runs/wm-0 runs/wm-1 runs/wm-2 runs/wm-3 runs/wm-4 --out runs/wm-bag
"""

from __future__ import annotations

import functools
import json
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Annotated, Any

import typer

from app.cli.options import (
    GATE_SET_HELP,
    GateSetRetired,
    NamedChoicesCommand,
    checked_device,
    fail,
    gate_pairs,
    one_scenario,
    refuse_retired,
    runs_sim,
    scenario_list,
)

RunArgument = Annotated[str, typer.Argument(help="Run folder or checkpoint with a world model.", show_default=False)]
SimOption = Annotated[str | None, typer.Option(help="Simulator: {SIMS} (default: the run's own; must match it).")]
SetOption = Annotated[list[str] | None, typer.Option("--set", help=GATE_SET_HELP)]
MaxStepsOption = Annotated[int | None, typer.Option(help="Cut episodes at this many steps.")]
CpusOption = Annotated[
    int | None, typer.Option(min=1, help="Drive the rows or curve points at once as Ray tasks on this many cores.")
]
GateDeviceOption = Annotated[
    str,
    typer.Option(
        "--device",
        help="auto, cpu or cuda, checked here (cuda without CUDA: an error). The gate reads one state per step, where "
        "a GPU only adds transfers: its rollouts, the policy and the world model run on the CPU whatever this says.",
    ),
]
AddressOption = Annotated[str | None, typer.Option(help="... or on the Ray cluster at this address (HOST:PORT).")]
ERRORS: tuple[type[Exception], ...] = (ValueError, FileNotFoundError, LookupError)
"""What a bad run, scenario or setting raises, each reported as one line."""


@dataclass(frozen=True)
class GateSetup:
    """A run, its simulator and the gate settings it is driven with, checked before any episode."""

    run: str
    sim: str
    descriptor: Any
    """The simulator's :class:`core.descriptor.SimDescriptor`."""
    settings: dict[str, Any]
    """The gate's settings over the run's own (``--set gate.KEY=VALUE``)."""


def gate_setup(run: str, sim: str | None, scenarios: list[str], set_: list[str] | None, gate_set: Any) -> GateSetup:
    """The run's simulator (``sim`` must be it), its scenarios checked by name and the gate settings parsed for it."""
    import sims
    from core.sage.config import parse_gate_settings

    refuse_retired(gate_set=gate_set)
    pairs = gate_pairs(set_)
    run_sim = runs_sim([run], sim)
    try:
        descriptor = sims.descriptor(run_sim)
        for name in scenarios:
            descriptor.scenario_kwargs(name)
        settings = parse_gate_settings(pairs, descriptor.contact_floors)
    except ERRORS as exc:
        fail(str(exc))
    return GateSetup(run, run_sim, descriptor, settings)


def single_threaded() -> None:
    """Batch-1 inference gains nothing from a second thread and loses much when another job holds a core (UGV 4 with
    a short curve beside a busy core: 35 s wall with torch's default threads, 12.5 s with one)."""
    import torch

    torch.set_num_threads(1)


@dataclass(frozen=True)
class Evaluation:
    """What ``sage gate evaluate`` measured: the report, and the replays it was asked for."""

    report: Any
    """:class:`studies.calibrate.CalibrationReport`."""
    lead: Any | None
    """The expert's lead replay (``--expert-lead``)."""
    escaped: Any | None
    """The escape check (``--escape``)."""


def evaluate_gate(
    setup: GateSetup,
    scenario: str,
    episodes: int,
    max_steps: int | None,
    horizon: float,
    curve_episodes: int,
    expert_lead: bool,
    escape: bool,
    cpus: int | None,
    address: str | None,
) -> Evaluation:
    """Drive the run with its gate and no expert on ``scenario`` and measure fear (and the replays asked for)."""
    from core.agents import load_agent
    from studies.calibrate import calibrate_run
    from studies.calibrate import expert_lead as measure_lead
    from studies.escape import escape_check

    load_agent(setup.run).gate_config(**setup.settings)  # a setting the run's gate refuses stops here

    def make_env() -> Any:
        return setup.descriptor.make(scenario)

    common: dict[str, Any] = {"episodes": episodes, "max_steps": max_steps}
    dt, settings = setup.descriptor.dt, setup.settings
    report = calibrate_run(
        setup.run,
        make_env,
        dt,
        sim=setup.sim,
        scenario=scenario,
        horizon_s=horizon,
        curve_episodes=curve_episodes,
        gate_settings=settings,
        curve_cpus=cpus,
        curve_address=address,
        **common,
    )
    lead = measure_lead(setup.run, make_env, dt, gate_settings=settings, **common) if expert_lead else None
    escaped = escape_check(setup.run, make_env, dt, **common, **settings) if escape else None
    return Evaluation(report, lead, escaped)


def write_evaluation(evaluation: Evaluation, out: Path) -> list[Path]:
    """``report.json`` and the figures, and the replays' JSON files, into ``out``."""
    from studies.calibrate import write_figures

    written = list(write_figures(evaluation.report, out))
    lead, escaped = evaluation.lead, evaluation.escaped
    if lead is not None:
        path = out / "expert_lead.json"
        path.write_text(json.dumps(asdict(lead) | {"needed_s": lead.needed_s()}, indent=2) + "\n")
        written.append(path)
    if escaped is not None:
        path = out / "escape.json"
        path.write_text(json.dumps(asdict(escaped) | {"replayed": escaped.replayed}, indent=2) + "\n")
        written.append(path)
    return written


def deploy_command(setup: GateSetup, scenario: str, deploy_settings: dict[str, Any]) -> str:
    """The ``sage train`` line that writes a run with the chosen operating point (0 episodes: nothing learns)."""
    settings = " ".join(
        f"--set gate.{key}={value:g}" if isinstance(value, float) else f"--set gate.{key}={value}"
        for key, value in deploy_settings.items()
    )
    return (
        f"sage train --sim {setup.sim} --scenario {scenario} --init {setup.run} --world-model-only --episodes 0 "
        f"--demo-episodes 0 {settings} --checkpoint-every 0 --out RUN"
    )


def print_scale_row(row: dict[str, Any]) -> None:
    typer.echo(
        f"tau_scale {row['scale']:g} on {row['scenario']}: {row['violations']}/{row['episodes']} episodes with a "
        f"violation, takeover {row['takeover_rate']:.1%}",
        err=True,
    )


def _one_line(errors: tuple[type[Exception], ...], action: Callable[[], Any]) -> Any:
    """``action()``, with any of ``errors`` reported as one line (exit 2)."""
    try:
        return action()
    except errors as exc:
        fail(str(exc))


def register(app: typer.Typer) -> None:
    """Add the ``sage gate`` group: evaluate, choose-scale, refit-bounds, merge."""
    group = typer.Typer(
        help="Measure and set a run's SAGE gate: evaluate fear, choose its operating point, refit τ's bounds, merge "
        "world models.",
        no_args_is_help=True,
    )
    app.add_typer(group, name="gate")

    @group.command("evaluate", cls=NamedChoicesCommand)
    def evaluate(
        run: RunArgument,
        sim: SimOption = None,
        scenario: Annotated[
            list[str] | None, typer.Option(help="The scenario driven (one; default: the simulator's).")
        ] = None,
        episodes: Annotated[int, typer.Option(min=1, help="Episodes driven by the policy alone (no expert).")] = 20,
        horizon: Annotated[float, typer.Option(help="Label: a violation within this many seconds.")] = 1.0,
        curve_episodes: Annotated[
            int, typer.Option(min=0, help="Episodes per point of the operating curve (0: no curve).")
        ] = 0,
        max_steps: MaxStepsOption = None,
        expert_lead: Annotated[
            bool,
            typer.Option(
                "--expert-lead",
                help="Also replay each of the policy's violations with the scripted expert taking over 0.5-3 s "
                "before it: the warning the expert needs, beside the gate's.",
            ),
        ] = False,
        escape: Annotated[
            bool,
            typer.Option(
                "--escape",
                help="Also drive the episodes with the gate and the scripted expert and replay each violation: did "
                "any steady manoeuvre avoid it from the takeover, or from 1 or 2 s before? (studies/escape.py)",
            ),
        ] = False,
        set_: SetOption = None,
        out: Annotated[Path | None, typer.Option(help="Folder for report.json and the PNG figures.")] = None,
        cpus: CpusOption = None,
        address: AddressOption = None,
        device: GateDeviceOption = "auto",
        gate_set: GateSetRetired = None,
    ) -> None:
        """Run the policy with its gate and no expert; report how well fear ranks the steps before a
        violation (AUROC, average precision), the gate's firing, a reliability diagram and the operating curve."""
        from studies.sweep import SweepError

        chosen = one_scenario(scenario, "sage gate evaluate")
        checked_device(device)
        setup = gate_setup(run, sim, [chosen] if chosen else [], set_, gate_set)
        name = chosen or setup.descriptor.default_scenario
        single_threaded()
        evaluation = _one_line(
            (*ERRORS, SweepError),
            lambda: evaluate_gate(
                setup, name, episodes, max_steps, horizon, curve_episodes, expert_lead, escape, cpus, address
            ),
        )
        typer.echo(evaluation.report.summary())
        for replay in (evaluation.lead, evaluation.escaped):
            if replay is not None:
                typer.echo(replay.summary())
        if out is not None:
            for path in write_evaluation(evaluation, out):
                typer.echo(f"wrote {path}")

    @group.command("choose-scale", cls=NamedChoicesCommand)
    def choose_scale(
        run: RunArgument,
        sim: SimOption = None,
        scenario: Annotated[
            list[str] | None,
            typer.Option(help="Scenario(s) to choose on, repeatable or a comma list: those the policy was trained on."),
        ] = None,
        episodes: Annotated[int, typer.Option(min=1, help="Episodes per scenario and scale.")] = 100,
        scale: Annotated[
            list[float] | None,
            typer.Option(
                help="A candidate gate.tau_scale (repeatable; default 1, 0.7, 0.5, 0.35, 0.25: only lowers τ)."
            ),
        ] = None,
        violation_share: Annotated[
            float, typer.Option(min=0.0, max=1.0, help="Target: at most this share of episodes with a violation.")
        ] = 0.05,
        takeover: Annotated[float, typer.Option(min=0.0, max=1.0, help="Target: at most this takeover rate.")] = 0.35,
        max_steps: MaxStepsOption = None,
        set_: SetOption = None,
        out: Annotated[Path | None, typer.Option(help="Write the measured rows and the choice here (JSON).")] = None,
        cpus: CpusOption = None,
        address: AddressOption = None,
        device: GateDeviceOption = "auto",
        gate_set: GateSetRetired = None,
    ) -> None:
        """Choose gate.tau_scale, the gate's operating point: the largest scale at which the gate with the scripted
        expert meets the target (violations, takeover) on every given scenario."""
        from studies.calibrate import DEFAULT_SCALES, GateTarget, choose_tau_scale
        from studies.sweep import SweepError

        names = scenario_list(scenario)
        if not names:
            fail("give the scenarios to choose on with --scenario (those the policy was trained on)")
        checked_device(device)
        setup = gate_setup(run, sim, names, set_, gate_set)
        single_threaded()
        choice = _one_line(
            (*ERRORS, SweepError),
            lambda: choose_tau_scale(
                run,
                {name: functools.partial(setup.descriptor.make, name) for name in names},
                episodes,
                scale or DEFAULT_SCALES,
                GateTarget(violation_share, takeover),
                sim=setup.sim,
                max_steps=max_steps,
                gate_settings=setup.settings,
                on_row=print_scale_row,
                cpus=cpus,
                address=address,
            ),
        )
        typer.echo(choice.summary())
        if choice.met:
            typer.echo("deploy: " + deploy_command(setup, names[0], choice.deploy_settings()))
        if out is not None:
            out.parent.mkdir(parents=True, exist_ok=True)
            out.write_text(json.dumps(choice.as_dict(), indent=2) + "\n")
            typer.echo(f"wrote {out}")

    @group.command("refit-bounds", cls=NamedChoicesCommand)
    def refit_bounds(
        run: RunArgument,
        sim: SimOption = None,
        scenario: Annotated[
            list[str] | None,
            typer.Option(help="Scenario(s) to drive, repeatable or a comma list: those the policy was trained on."),
        ] = None,
        episodes: Annotated[int, typer.Option(min=1, help="Episodes of the policy alone per scenario.")] = 100,
        set_: Annotated[
            list[str] | None,
            typer.Option(
                "--set", help="A gate setting to measure the bounds for, gate.KEY=VALUE (repeatable): gate.beta=0.8."
            ),
        ] = None,
        choose_beta: Annotated[
            bool,
            typer.Option(
                "--choose-beta",
                help="Choose β from the same drives: the candidate (0, 0.1, ..., 1) whose fear ranks the steps "
                "before a violation best (mean AUROC over the scenarios).",
            ),
        ] = False,
        horizon: Annotated[float, typer.Option(help="--choose-beta's label: a violation within this many s.")] = 1.0,
        novelty_scenario: Annotated[
            list[str] | None,
            typer.Option(
                help="With gate.curiosity_signal=novelty: more scenarios (repeatable or a comma list) driven the "
                "same way whose states join the novelty's reference set, familiar ground, but not the τ bounds."
            ),
        ] = None,
        keep_bounds: Annotated[
            bool,
            typer.Option(
                "--keep-bounds",
                help="Keep the run's κ and τ bounds (for settings that leave fear as it is, such as "
                "gate.curiosity_signal): only the curiosity's references are measured on the drives.",
            ),
        ] = False,
        max_steps: MaxStepsOption = None,
        checkpoint_dtype: Annotated[str, typer.Option(help="float32, or float16 (half the file).")] = "float32",
        out: Annotated[Path | None, typer.Option(help="The new run folder.")] = None,
        device: GateDeviceOption = "auto",
        gate_set: GateSetRetired = None,
    ) -> None:
        """Measure the gate's τ bounds (and κ) again, for other fear settings or a chosen β: the run with its world
        model's weights unchanged, written to a new folder."""
        from studies.recalibrate import recalibrate_run

        names = scenario_list(scenario)
        if not names:
            fail("give the scenarios to drive with --scenario (those the policy was trained on)")
        if out is None:
            fail("give the new run folder with --out")
        checked_device(device)
        setup = gate_setup(run, sim, names, set_, gate_set)
        single_threaded()
        result = _one_line(
            ERRORS,
            lambda: recalibrate_run(
                run,
                setup.descriptor.make,
                names,
                episodes,
                out,
                setup.descriptor.dt,
                gate_settings=setup.settings,
                choose=choose_beta,
                label_s=horizon,
                max_steps=max_steps,
                dtype=checkpoint_dtype,
                novelty_scenarios=scenario_list(novelty_scenario),
                keep_bounds=keep_bounds,
            ),
        )
        typer.echo(result.summary())
        typer.echo(f"wrote {out}")

    @group.command("merge")
    def merge(
        runs: Annotated[
            list[str],
            typer.Argument(help="Run folders (or checkpoints) of world-model refits of one policy.", metavar="RUN..."),
        ],
        out: Annotated[Path, typer.Option(help="Folder for the merged run (must not hold a checkpoint yet).")],
        seed: Annotated[int, typer.Option(help="Seed of the draw of calibration states.")] = 0,
        checkpoint_dtype: Annotated[
            str, typer.Option(help="float32, or float16 to halve the file (committed policies).")
        ] = "float32",
    ) -> None:
        """Merge the world models of RUNS into one ensemble of all their members (the first run's policy), and set
        its κ and τ bounds on the states the runs calibrated on (their calibration.npz; a committed policy's folder
        has none and adds only its members). Refits with and without the approach input merge into one reading it."""
        from core.merge import merge_runs

        single_threaded()
        result = _one_line(
            (ValueError, FileNotFoundError), lambda: merge_runs(runs, out, seed=seed, dtype=checkpoint_dtype)
        )
        low, high = result.tau_bounds
        typer.echo(
            f"merged {len(result.runs)} world models into {result.out}: {result.members} members; τ bounds "
            f"({low:.3f}, {high:.3f}) from {result.calibration_states} states ({result.familiar_states} familiar)"
        )
