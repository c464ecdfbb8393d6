"""``sage study NAME``: train every method of a study over its seeds on Ray, evaluate, write the results folder.

    sage study NAME --budget small --out results/NAME [--address HOST:PORT] [--cpus 2] [--max-concurrent 2]
    sage study highway --methods sac,sage --train-steps 40000 --out results/highway-40k   # a longer comparison
    sage study ugv --methods sage --learner-set fear_budget_from_data=false               # an ablation

The budget (``smoke|small|full``) is counted in environment steps, the same for every method. Rerunning the
same command resumes the sweep in ``OUT/sweep``. Writes ``seeds.csv``, ``table.md`` (mean ± 95% CI with the
paper's numbers beside), ``summary.json`` and figures, and prints the wall time.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer


def register(app: typer.Typer) -> None:
    """Add ``sage study``."""

    @app.command("study")
    def study(
        name: Annotated[str, typer.Argument(help="Registered study name.")],
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
        readme: Annotated[
            Path | None, typer.Option(help="Also write the table into this README's section for the study.")
        ] = None,
        readme_section: Annotated[
            str | None,
            typer.Option(help="The README section's name (default: the study's; e.g. highway-40k beside highway)."),
        ] = None,
        set_: Annotated[
            list[str] | None,
            typer.Option("--set", help="A study setting key=value (e.g. expert=hg-dagger for pedestrian); repeatable."),
        ] = None,
        methods: Annotated[
            str | None, typer.Option(help="Only these of the study's methods, comma-separated (default: all).")
        ] = None,
        train_steps: Annotated[
            int | None,
            typer.Option(min=1, help="Environment steps per method and seed instead of the budget's."),
        ] = None,
        learner_set: Annotated[
            list[str] | None,
            typer.Option(
                "--learner-set",
                help="A learner setting key=value every method trains with (an ablation, e.g. "
                "fear_budget_from_data=false); repeatable.",
            ),
        ] = None,
    ) -> None:
        """Run a paper study: every method on each of the budget's seeds, the same environment steps for all;
        results with 95% intervals."""
        from studies.budgets import BUDGET_NAMES
        from studies.registry import check_study_learner_overrides, get_study, run_study

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
            overrides: dict[str, Any] = {}
            for pair in set_ or []:
                key, sep, value = pair.partition("=")
                key = key.strip()
                if not sep or key not in known:
                    raise ValueError(f"--set {pair!r}: give key=value with a setting of {name}: {', '.join(known)}")
                overrides[key] = setting_value(known[key], value.strip(), key)
            if learner_set:
                check_study_learner_overrides(name, learner_set)
            if address is not None and address != "auto":
                from studies.sweep import check_cluster_address

                check_cluster_address(address)  # seconds, not Ray's 14 minutes of retries
        except ValueError as error:
            typer.secho(f"error: {error}", fg=typer.colors.RED, err=True)
            raise typer.Exit(code=2) from None
        results = out or Path("results") / f"{name}-{budget}"
        run_study(
            name, budget, results, address, cpus, max_concurrent, overrides=overrides, methods=chosen,
            train_steps=train_steps, learner_overrides=learner_set or (),
        )  # fmt: skip
        if readme is not None:
            from studies.readme import update_readme

            update_readme(readme, readme_section or name, results)
            typer.echo(f"README section '{readme_section or name}' written from {results} into {readme}")


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
            raise ValueError(f"--set {key}={text}: {key} is a number") from None
    return text
