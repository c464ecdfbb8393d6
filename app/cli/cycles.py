"""``sage cycles``: deploy → takeover → fine-tune cycles, headless, and the paper's continual-adaptation figures.

    sage cycles --scenario 3 --cycles 9 --episodes-per-cycle 3 --policy policies/ugv-default --out DIR
    sage cycles ... --steps-per-cycle 1500 --set finetune.updates_per_step=2 --legacy-rounds

Each cycle deploys the current policy version with its SAGE gate and the scripted expert, records the session, then
fine-tunes on it with the same function the live server's worker runs (:mod:`core.finetune`) and deploys the new
version in the next cycle (:mod:`studies.cycles`); every cycle also drives the version alone on the scenario and on
an unseen one of the same kind. Writes the per-cycle table (``table.md``), ``cycles.json``,
and the figures (:mod:`studies.cycles_figures`): ``trajectories.png`` (paths over the cycles, coloured by cycle),
``signals_cycle<K>.png`` (fear, threshold and takeover intervals in cycle K, ``--show-cycle K``, repeatable) and
``cycles_summary.png``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from app.cli.options import (
    FINETUNE_SECTIONS,
    LEARNER_SECTIONS,
    LEARNER_SET_HELP,
    NamedChoicesCommand,
    RegressionAgainstOption,
    checked_regression_against,
    checked_scenarios,
    fail,
    one_scenario,
    routed_settings,
    runs_sim,
)


def register(app: typer.Typer) -> None:
    """Add ``sage cycles``."""

    @app.command("cycles", cls=NamedChoicesCommand)
    def cycles(
        sim: Annotated[
            str | None, typer.Option(help="Simulator: {SIMS} (default: the --policy run's, else ugv; must match it).")
        ] = None,
        scenario: Annotated[
            list[str] | None, typer.Option(help="The scenario of every cycle (one; default 3: UGV's crossing).")
        ] = None,
        cycles: Annotated[int, typer.Option(min=1, help="Deployment cycles (fine-tuning rounds between them).")] = 9,
        episodes_per_cycle: Annotated[int, typer.Option(min=1, help="Episodes deployed per cycle.")] = 3,
        steps_per_cycle: Annotated[
            int | None,
            typer.Option(min=1, help="Deploy exactly this many environment steps a cycle (not --episodes-per-cycle)."),
        ] = None,
        alone_episodes: Annotated[
            int, typer.Option(min=0, help="Per cycle, episodes of the version alone (no gate, no expert) per scenario.")
        ] = 10,
        unseen_scenario: Annotated[
            str | None,
            typer.Option(help="Scenario of the same kind never deployed, driven alone (default: UGV 4 for 3)."),
        ] = None,
        policy: Annotated[
            str | None, typer.Option(help="Run folder or checkpoint deployed first (default: policies/<sim>-default).")
        ] = None,
        out: Annotated[Path | None, typer.Option(help="Run folder (default: runs/cycles-SIM-SCENARIO-sSEED).")] = None,
        seed: Annotated[int, typer.Option(help="Episode e of every cycle uses seed + e.")] = 0,
        show_cycle: Annotated[
            list[int] | None,
            typer.Option(help="Cycle whose fear / threshold / takeovers are drawn (repeatable; default: the first)."),
        ] = None,
        updates: Annotated[
            int | None, typer.Option(min=0, help="Most gradient updates a round (default: finetune.updates).")
        ] = None,
        set_: Annotated[
            list[str] | None,
            typer.Option(
                "--set",
                help="A setting (repeatable): finetune.KEY a round's (core.finetune.FinetuneConfig, e.g. "
                f"finetune.updates_per_step=2), else {LEARNER_SET_HELP}.",
            ),
        ] = None,
        promote: Annotated[
            bool,
            typer.Option(help="Judge each version as the live worker does; deploy only promoted ones (15 episodes)."),
        ] = False,
        regression_scenario: Annotated[
            list[str] | None,
            typer.Option(
                help="A regression test against forgetting (repeatable, e.g. 1 and 2): a version is deployed only if, "
                "ALONE on this scenario's fixed seeds, it succeeds in as many episodes as the starting policy."
            ),
        ] = None,
        regression_against: RegressionAgainstOption = "base",
        frozen: Annotated[
            bool, typer.Option(help="The control: deploy the first version in every cycle, never fine-tuned.")
        ] = False,
        legacy_rounds: Annotated[
            bool,
            typer.Option(help="Fine-tune as before issue 62 (the base's own method, 400 updates, session data only)."),
        ] = False,
        expert: Annotated[
            str,
            typer.Option(
                help="Who takes over: scripted (the simulator's privileged expert) or a planner's name (teb on the "
                "UGV: from the robot's own sensing, as a person)."
            ),
        ] = "scripted",
        coach_share: Annotated[
            float,
            typer.Option(
                min=0.0,
                max=1.0,
                help="Coaching: on this share of the agent's own steps the scripted expert's action is recorded as a "
                "label and imitated, not executed (as a person steering along at the dashboard; 0: takeovers only).",
            ),
        ] = 0.0,
        stochastic: Annotated[bool, typer.Option(help="Deploy the sampled policy instead of its mean action.")] = False,
        max_episode_steps: Annotated[int | None, typer.Option(min=1, help="Cut episodes at this many steps.")] = None,
        figures: Annotated[Path | None, typer.Option(help="Folder for the figures (default: the run folder).")] = None,
        quiet: Annotated[bool, typer.Option(help="No per-cycle progress lines.")] = False,
    ) -> None:
        """Run deploy / takeover / fine-tune cycles headless; print the per-cycle table; draw the figures."""
        import torch

        from core.finetune import FinetuneConfig, FinetuneError
        from core.promotion import PromotionConfig
        from studies.cycles import CyclesConfig, format_cycle_table, read_cycles, run_cycles
        from studies.cycles_figures import write_figures
        from studies.envs import env_factory

        torch.set_num_threads(1)
        shown = show_cycle or [1]
        for k in shown:
            if not 1 <= k <= cycles:
                fail(f"--show-cycle {k} is not one of the cycles (1-{cycles})")
        routed = routed_settings(set_, {**LEARNER_SECTIONS, **FINETUNE_SECTIONS}, other="learner")
        round_settings, learner_settings = routed.get("finetune", []), tuple(routed.get("learner", []))
        name = one_scenario(scenario, "sage cycles") or "3"
        policy_path = policy or f"policies/{sim or 'ugv'}-default"
        if not Path(policy_path).exists():
            fail(f"no policy at {policy_path!r} (give --policy a run folder or a checkpoint)")
        sim = runs_sim([policy_path], sim)
        regression = checked_scenarios(sim, regression_scenario or [], "--regression-scenario")
        against = checked_regression_against(regression_against)
        folder = out or Path("runs") / f"cycles-{sim}-{name}-s{seed}"
        try:
            make_env = env_factory(sim)
            # each cycle is the unit of data the user chose (see CyclesConfig.finetune)
            fixed: dict[str, Any] = {
                "overrides": learner_settings,
                "seed": seed,
                "min_steps": 1,
                "min_takeover_samples": 0,
            }
            if updates is not None:
                fixed["updates"] = updates
            rounds = FinetuneConfig.legacy(**fixed) if legacy_rounds else FinetuneConfig(**fixed)
            config = CyclesConfig(
                sim=sim,
                scenario=name,
                policy=policy_path,
                cycles=cycles,
                episodes_per_cycle=episodes_per_cycle,
                steps_per_cycle=steps_per_cycle,
                fine_tune=not frozen,
                promotion=(
                    PromotionConfig(
                        supervised=promote,
                        regression_scenarios=regression,
                        max_steps=max_episode_steps or PromotionConfig().max_steps,
                        regression_against=against,
                    )
                    if promote or regression
                    else None
                ),
                alone_episodes=alone_episodes,
                unseen_scenario=unseen_scenario,
                seed=seed,
                deterministic=not stochastic,
                max_episode_steps=max_episode_steps,
                coach_share=coach_share,
                expert=expert,
                finetune=rounds.with_settings(round_settings),
            )
            result = run_cycles(config, folder, make_env, progress=None if quiet else typer.echo)
        except (ValueError, FileNotFoundError, FileExistsError, FinetuneError) as exc:
            fail(str(exc))
        table = format_cycle_table(result.cycles, result.rounds)
        (folder / "table.md").write_text(table + "\n")
        typer.echo(table)
        for path in write_figures(folder, read_cycles(folder), shown, figures):
            typer.echo(f"figure: {path}")
        typer.echo(f"run folder: {folder} ({result.seconds:.0f} s)")
