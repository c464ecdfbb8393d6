"""``sage study NAME``: train every method of a study over its seeds on Ray, evaluate, write the results folder.

    sage study NAME --budget small --out results/NAME [--address HOST:PORT] [--cpus 2] [--max-concurrent 2]
    sage study NAME --results-doc docs/results.md   # also its table in docs/results.md, the README's summary after
    sage study highway --methods sac,sage --train-steps 40000 --out results/highway-40k   # a longer comparison
    sage study ugv --methods sage --set learner.fear_budget_from_data=false             # an ablation
    sage study pedestrian --set study.expert=hg-dagger                                    # a study setting
    sage study cycles --set finetune.critic_warmup=200                                    # its rounds' setting
    sage study cycles --set learner.lambda_lr=0.1                                         # its rounds' learner

The budget (``smoke|small|full``) is counted in environment steps, the same for every method. Rerunning the
same command resumes the sweep in ``OUT/sweep``. Writes ``seeds.csv``, ``table.md`` (mean ± 95% CI with the
paper's numbers beside), ``summary.json`` and figures, and prints the wall time. ``--set`` takes the study's
settings (``study.KEY=VALUE``), the fine-tuning rounds' of a study that runs them (``finetune.KEY=VALUE``,
:class:`core.finetune.FinetuneConfig`) and learner settings every method trains with (``learner.KEY=VALUE``, or the
field's path in :class:`core.sage.config.AgentConfig`; the cycles study's rounds take them after SAGE's switches),
read by the one parser of every command (:mod:`app.cli.options`).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any

import typer

from app.cli.options import (
    FINETUNE_SECTIONS,
    LEARNER_SECTIONS,
    LEARNER_SET_HELP,
    STUDY_SECTIONS,
    DeviceOption,
    LearnerSetRetired,
    NamedChoicesCommand,
    checked_device,
    fail,
    refuse_retired,
    routed_settings,
)


def register(app: typer.Typer) -> None:
    """Add ``sage study``."""

    @app.command("study", cls=NamedChoicesCommand)
    def study(
        name: Annotated[str, typer.Argument(help="The study: {STUDIES}.", show_default=False)],
        budget: Annotated[str, typer.Option(help=_budget_help())] = "small",
        out: Annotated[Path | None, typer.Option(help="Results folder (default: results/NAME-BUDGET).")] = None,
        address: Annotated[
            str | None,
            typer.Option(
                help="Join the Ray cluster at HOST:PORT (what `ray start --head` printed) instead of running "
                "locally; checked first, one line if nothing answers there."
            ),
        ] = None,
        cpus: Annotated[int | None, typer.Option(min=1, help="Local cores for trials (default: all).")] = None,
        max_concurrent: Annotated[int | None, typer.Option(min=1, help="Most trials at once.")] = None,
        results_doc: Annotated[
            Path | None,
            typer.Option(
                "--results-doc",
                "--readme",
                help="Also write the table into this document's section for the study (the project's: "
                "docs/results.md, which also refreshes README.md's summary).",
            ),
        ] = None,
        section: Annotated[
            str | None,
            typer.Option(
                "--section",
                "--readme-section",
                help="The document section's name (default: the study's; e.g. highway-40k beside highway).",
            ),
        ] = None,
        set_: Annotated[
            list[str] | None,
            typer.Option(
                "--set",
                help="A setting, section.key=value (repeatable): study.KEY=VALUE, a setting of the study (e.g. "
                f"study.expert=hg-dagger for pedestrian); {LEARNER_SET_HELP}, a learner setting every method trains "
                "with (an ablation, e.g. learner.fear_budget_from_data=false); finetune.KEY=VALUE, a setting of the "
                "fine-tuning rounds of a study that runs them (cycles; core.finetune.FinetuneConfig, e.g. "
                "finetune.critic_warmup=200).",
            ),
        ] = None,
        methods: Annotated[
            str | None,
            typer.Option(
                help="Only these of the study's methods, comma-separated (default: all). The studies' methods: "
                "{STUDY_METHODS}."
            ),
        ] = None,
        train_steps: Annotated[
            int | None,
            typer.Option(min=1, help="Environment steps per method and seed instead of the budget's."),
        ] = None,
        device: DeviceOption = "auto",
        learner_set: LearnerSetRetired = None,
    ) -> None:
        """Run a paper study: every method on each of the budget's seeds, the same environment steps for all;
        results with 95% intervals."""
        from studies.budgets import BUDGET_NAMES
        from studies.registry import check_study_learner_overrides, get_study, run_study

        refuse_retired(learner_set=learner_set)
        resolved_device = checked_device(device)
        settings = routed_settings(set_, STUDY_SECTIONS | LEARNER_SECTIONS | FINETUNE_SECTIONS, other="learner")
        learner_overrides = settings.get("learner", [])
        try:
            known = get_study(name).settings
            chosen = [m.strip() for m in (methods or "").split(",") if m.strip()] or None
            unknown = [m for m in chosen or () if m not in get_study(name).methods]
            if unknown:
                raise ValueError(
                    f"--methods: {name} has no {', '.join(unknown)}; its: {', '.join(get_study(name).methods)}"
                )
            if budget not in BUDGET_NAMES:
                raise ValueError(f"unknown budget {budget!r}; choose one of {', '.join(BUDGET_NAMES)}")
            overrides = study_settings(name, known, settings.get("study", []))
            check = get_study(name).check_settings
            if check is not None:
                check({**dict(known), **overrides})
            if settings.get("finetune"):
                overrides["finetune"] = finetune_settings(name, known, settings["finetune"])
            for pair in learner_overrides:
                key = pair.partition("=")[0]
                if key in known:  # a study setting given as the learner's
                    raise ValueError(f"--set {pair}: {key} is a setting of {name}, --set study.{pair}")
            if learner_overrides:
                check_study_learner_overrides(name, learner_overrides)
            if address is not None and address != "auto":
                from studies.sweep import check_cluster_address

                check_cluster_address(address)  # seconds, not Ray's 14 minutes of retries
        except ValueError as error:
            fail(str(error))
        results = out or Path("results") / f"{name}-{budget}"
        from studies.sweep import ClusterError, LedgerError, SweepError

        try:
            run_study(
                name, budget, results, address, cpus, max_concurrent, overrides=overrides, methods=chosen,
                train_steps=train_steps, learner_overrides=learner_overrides, device=resolved_device,
            )  # fmt: skip
        except (SweepError, ClusterError, LedgerError) as error:  # stopped, failed trials, a refused ledger row
            fail(str(error))
        if results_doc is not None:
            from studies.readme import RESULTS_DOC, SUMMARY_README, update_results, update_summary

            update_results(results_doc, section or name, results)
            typer.echo(f"section '{section or name}' written from {results} into {results_doc}")
            if results_doc.resolve() == RESULTS_DOC.resolve():  # the project's document: its README summary follows
                try:
                    update_summary(SUMMARY_README, results_doc)
                except (OSError, ValueError) as error:
                    typer.secho(f"error: the README summary was not written: {error}", fg=typer.colors.RED, err=True)
                    raise typer.Exit(code=2) from None
                typer.echo(f"summary written into {SUMMARY_README}")


def study_settings(name: str, known: Mapping[str, Any], pairs: list[str]) -> dict[str, Any]:
    """``KEY=VALUE`` pairs (``--set study.KEY=VALUE``) as settings of study ``name``, each of its default's type."""
    overrides: dict[str, Any] = {}
    for pair in pairs:
        key, _, value = pair.partition("=")
        if key not in known:
            raise ValueError(f"--set study.{pair}: {name} has no setting {key!r}; its: {', '.join(known) or 'none'}")
        overrides[key] = setting_value(known[key], value, key)
    return overrides


def finetune_settings(name: str, known: Mapping[str, Any], pairs: list[str]) -> list[str]:
    """``KEY=VALUE`` pairs (``--set finetune.KEY=VALUE``) for the fine-tuning rounds of a study that runs them (its
    ``finetune`` setting), checked against :class:`core.finetune.FinetuneConfig`; other studies refuse them."""
    from core.finetune import FinetuneConfig

    if "finetune" not in known:
        raise ValueError(f"--set finetune.{pairs[0]}: {name} runs no fine-tuning rounds")
    try:
        FinetuneConfig().with_settings(pairs)  # an unknown field or an unreadable value is one error line here
    except ValueError as error:
        raise ValueError(f"--set finetune.: {error}") from None
    return [*known["finetune"], *pairs]


def _budget_help() -> str:
    """What each budget runs, from the budgets themselves (per method: seeds, training steps, evaluation)."""
    from studies.budgets import BUDGETS

    runs = "; ".join(
        f"{b.name}: {b.seeds} seeds x {b.train_steps:,} environment steps, {b.eval_episodes} evaluation episodes"
        for b in BUDGETS.values()
    )
    return f"{' | '.join(BUDGETS)}, per method ({runs}; a study may evaluate more episodes)."


def setting_value(default: Any, text: str, key: str) -> Any:
    """``text`` as a value of the setting's own type: a comma list for a list, a number for a number."""
    if isinstance(default, list | tuple):
        return [part.strip() for part in text.split(",") if part.strip()]
    if isinstance(default, bool):
        return text.lower() in ("1", "true", "yes", "on")
    if isinstance(default, int | float):
        try:
            return type(default)(text)
        except ValueError:
            raise ValueError(f"--set study.{key}={text}: {key} is a number") from None
    return text
