"""``sage calibrate``: does the policy's fear predict danger? (:mod:`studies.calibrate`)

sage calibrate policies/ugv-default --sim ugv --scenario 3 --episodes 20 --curve-episodes 20 --out calib/ugv3
sage calibrate policies/ugv-default --sim ugv --scenario 3 --episodes 150 --curve-episodes 300 --cpus 16
sage calibrate policies/ugv-default --sim ugv --scenario 4 --episodes 20 --expert-lead
sage calibrate policies/ugv-default --sim ugv --scenario 3 --episodes 20 --escape
sage calibrate policies/ugv-default --sim ugv --scenario 3 --episodes 20 --curve-episodes 20 --gate-set hold_seconds=2

``sage choose-scale``: the gate's operating point for a risk target, chosen on the training scenarios
(:func:`studies.calibrate.choose_tau_scale`); deploy it with ``--set gate.tau_scale=X`` (a 0-episode run):

sage choose-scale policies/highway-default --sim highway --scenario train --scenario train-adversarial --episodes 100

``sage recalibrate``: the τ bounds measured again for other fear settings, or for β chosen on the training
scenarios' drives (:mod:`studies.recalibrate`); a new run folder, the world model's weights unchanged:

sage recalibrate policies/ugv-default --sim ugv --scenario 1 --scenario 2 --gate-set beta=0.8 --out runs/ugv-beta08
sage recalibrate policies/pedestrian-default --sim pedestrian --scenario crossing --scenario rare --choose-beta \
    --out runs/pedestrian-beta
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path
from typing import Annotated, Any

import typer


def register(app: typer.Typer) -> None:
    @app.command()
    def calibrate(
        run: Annotated[str, typer.Argument(help="Run folder or checkpoint with a world model.")],
        sim: Annotated[str, typer.Option(help="Simulator.")] = "ugv",
        scenario: Annotated[str | None, typer.Option(help="Scenario name (default: the simulator's).")] = None,
        episodes: Annotated[int, typer.Option(min=1, help="Episodes driven by the policy alone (no expert).")] = 20,
        horizon: Annotated[float, typer.Option(help="Label: a violation within this many seconds.")] = 1.0,
        curve_episodes: Annotated[
            int, typer.Option(min=0, help="Episodes per point of the operating curve (0: no curve).")
        ] = 0,
        max_steps: Annotated[int | None, typer.Option(help="Cut episodes at this many steps.")] = None,
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
        gate_set: Annotated[
            list[str] | None,
            typer.Option(
                "--gate-set",
                help="A setting of the gate over the run's own, KEY=VALUE (repeatable), e.g. hold_seconds=2: any "
                "field of core.sage.config.GateConfig.",
            ),
        ] = None,
        out: Annotated[Path | None, typer.Option(help="Folder for report.json and the PNG figures.")] = None,
        cpus: Annotated[
            int | None,
            typer.Option(min=1, help="Drive the operating curve's points at once as Ray tasks on this many cores."),
        ] = None,
        address: Annotated[
            str | None, typer.Option(help="... or on the Ray cluster at this address (HOST:PORT).")
        ] = None,
    ) -> None:
        """Run the policy with its gate and no expert; report how well fear ranks the steps before a
        violation (AUROC, average precision), the gate's firing, a reliability diagram and the operating curve."""
        import torch

        import sims
        from core.agents import load_agent
        from core.sage.config import parse_gate_settings
        from studies.calibrate import calibrate_run, write_figures
        from studies.calibrate import expert_lead as measure_lead
        from studies.escape import escape_check
        from studies.sweep import SweepError

        # batch-1 inference gains nothing from a second thread and loses much when another job holds a core
        # (UGV 4 with a short curve beside a busy core: 35 s wall with torch's default threads, 12.5 s with one)
        torch.set_num_threads(1)
        try:
            descriptor = sims.descriptor(sim)
            name = scenario or descriptor.default_scenario
            descriptor.scenario_kwargs(name)
            settings = parse_gate_settings(gate_set or [], descriptor.contact_floors)
            load_agent(run).gate_config(**settings)  # a setting the run's gate refuses stops here, before any episode

            def make_env() -> Any:
                return descriptor.make(name)

            common: dict[str, Any] = {"episodes": episodes, "max_steps": max_steps}
            report = calibrate_run(
                run,
                make_env,
                descriptor.dt,
                sim=sim,
                scenario=name,
                horizon_s=horizon,
                curve_episodes=curve_episodes,
                gate_settings=settings,
                curve_cpus=cpus,
                curve_address=address,
                **common,
            )
            lead = measure_lead(run, make_env, descriptor.dt, gate_settings=settings, **common) if expert_lead else None
            escaped = escape_check(run, make_env, descriptor.dt, **common, **settings) if escape else None
        except (ValueError, FileNotFoundError, LookupError, SweepError) as exc:
            typer.secho(f"error: {exc}", fg=typer.colors.RED, err=True)
            raise typer.Exit(code=2) from None
        typer.echo(report.summary())
        if lead is not None:
            typer.echo(lead.summary())
        if escaped is not None:
            typer.echo(escaped.summary())
        if out is not None:
            for path in write_figures(report, out):
                typer.echo(f"wrote {path}")
            if lead is not None:
                path = out / "expert_lead.json"
                path.write_text(json.dumps(asdict(lead) | {"needed_s": lead.needed_s()}, indent=2) + "\n")
                typer.echo(f"wrote {path}")
            if escaped is not None:
                path = out / "escape.json"
                path.write_text(json.dumps(asdict(escaped) | {"replayed": escaped.replayed}, indent=2) + "\n")
                typer.echo(f"wrote {path}")

    @app.command("choose-scale")
    def choose_scale(
        run: Annotated[str, typer.Argument(help="Run folder or checkpoint with a world model.")],
        sim: Annotated[str, typer.Option(help="Simulator.")] = "ugv",
        scenario: Annotated[
            list[str] | None,
            typer.Option(help="A scenario to choose on (repeatable): those the policy was trained on."),
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
        max_steps: Annotated[int | None, typer.Option(help="Cut episodes at this many steps.")] = None,
        gate_set: Annotated[
            list[str] | None,
            typer.Option("--gate-set", help="A setting of the gate over the run's own, KEY=VALUE (repeatable)."),
        ] = None,
        out: Annotated[Path | None, typer.Option(help="Write the measured rows and the choice here (JSON).")] = None,
        cpus: Annotated[
            int | None,
            typer.Option(min=1, help="Drive every (scale, scenario) row at once as Ray tasks on this many cores."),
        ] = None,
        address: Annotated[
            str | None, typer.Option(help="... or on the Ray cluster at this address (HOST:PORT).")
        ] = None,
    ) -> None:
        """Choose gate.tau_scale, the gate's operating point: the largest scale at which the gate with the scripted
        expert meets the target (violations, takeover) on every given scenario."""
        import torch

        import sims
        from core.sage.config import parse_gate_settings
        from studies.calibrate import DEFAULT_SCALES, GateTarget, choose_tau_scale
        from studies.sweep import SweepError

        torch.set_num_threads(1)
        try:
            if not scenario:
                raise ValueError("give the scenarios to choose on with --scenario (those the policy was trained on)")
            descriptor = sims.descriptor(sim)
            for name in scenario:
                descriptor.scenario_kwargs(name)
            settings = parse_gate_settings(gate_set or [], descriptor.contact_floors)

            def factory(name: str) -> Any:
                return lambda: descriptor.make(name)

            choice = choose_tau_scale(
                run,
                {name: factory(name) for name in scenario},
                episodes,
                scale or DEFAULT_SCALES,
                GateTarget(violation_share, takeover),
                sim=sim,
                max_steps=max_steps,
                gate_settings=settings,
                on_row=lambda r: typer.echo(
                    f"tau_scale {r['scale']:g} on {r['scenario']}: {r['violations']}/{r['episodes']} episodes with a "
                    f"violation, takeover {r['takeover_rate']:.1%}",
                    err=True,
                ),
                cpus=cpus,
                address=address,
            )
        except (ValueError, FileNotFoundError, LookupError, SweepError) as exc:
            typer.secho(f"error: {exc}", fg=typer.colors.RED, err=True)
            raise typer.Exit(code=2) from None
        typer.echo(choice.summary())
        if choice.met:
            typer.echo(
                f"deploy: sage train --sim {sim} --scenario {scenario[0]} --init {run} --world-model-only --episodes 0 "
                f"--demo-episodes 0 "
                + " ".join(
                    f"--set gate.{key}={value:g}" if isinstance(value, float) else f"--set gate.{key}={value}"
                    for key, value in choice.deploy_settings().items()
                )
                + " --checkpoint-every 0 --out RUN"
            )
        if out is not None:
            out.parent.mkdir(parents=True, exist_ok=True)
            out.write_text(json.dumps(choice.as_dict(), indent=2) + "\n")
            typer.echo(f"wrote {out}")

    @app.command()
    def recalibrate(
        run: Annotated[str, typer.Argument(help="Run folder or checkpoint with a world model.")],
        sim: Annotated[str, typer.Option(help="Simulator.")] = "ugv",
        scenario: Annotated[
            list[str] | None,
            typer.Option(help="A scenario to drive (repeatable): those the policy was trained on."),
        ] = None,
        episodes: Annotated[int, typer.Option(min=1, help="Episodes of the policy alone per scenario.")] = 100,
        gate_set: Annotated[
            list[str] | None,
            typer.Option(
                "--gate-set", help="A gate setting to measure the bounds for, KEY=VALUE (repeatable), e.g. beta=0.8."
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
        max_steps: Annotated[int | None, typer.Option(help="Cut episodes at this many steps.")] = None,
        checkpoint_dtype: Annotated[str, typer.Option(help="float32, or float16 (half the file).")] = "float32",
        out: Annotated[Path | None, typer.Option(help="The new run folder.")] = None,
    ) -> None:
        """Measure the gate's τ bounds (and κ) again, for other fear settings or a chosen β: the run with its world
        model's weights unchanged, written to a new folder."""
        import torch

        import sims
        from core.sage.config import parse_gate_settings
        from studies.recalibrate import recalibrate_run

        torch.set_num_threads(1)
        try:
            if not scenario:
                raise ValueError("give the scenarios to drive with --scenario (those the policy was trained on)")
            if out is None:
                raise ValueError("give the new run folder with --out")
            descriptor = sims.descriptor(sim)
            for name in scenario:
                descriptor.scenario_kwargs(name)
            result = recalibrate_run(
                run,
                descriptor.make,
                scenario,
                episodes,
                out,
                descriptor.dt,
                gate_settings=parse_gate_settings(gate_set or [], descriptor.contact_floors),
                choose=choose_beta,
                label_s=horizon,
                max_steps=max_steps,
                dtype=checkpoint_dtype,
            )
        except (ValueError, FileNotFoundError, LookupError) as exc:
            typer.secho(f"error: {exc}", fg=typer.colors.RED, err=True)
            raise typer.Exit(code=2) from None
        typer.echo(result.summary())
        typer.echo(f"wrote {out}")
