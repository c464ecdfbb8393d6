"""What every ``sage`` command reads the same way: ``--set``, ``--scenario``, ``--device``, the simulator of a run, the
retired spellings, the one-line error, and help that names every method, planner, simulator and study.

- ``--set section.key=value`` (repeatable) is read by :func:`core.dotted.route_settings`, one parser for every
  command: ``gate.`` (the gate's settings, :class:`core.sage.config.GateConfig`), ``env.`` (the simulator's config),
  ``study.`` (a study's settings), and the learner's own field paths (:class:`core.sage.config.AgentConfig`:
  ``hidden=16``, ``gate.tau_max=0.7``, ``world_model_config.violation_steps=3``; ``learner.`` and ``world_model.``
  may stand before them).
- ``--scenario`` is repeatable and takes comma lists: ``--scenario 1,2 --scenario 3`` is three scenarios.
- ``--sim`` is the run's own simulator wherever a run folder is given; a ``--sim`` that says otherwise is an error.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal, NoReturn

import typer
from typer.core import TyperCommand

from core.dotted import Section, route_settings

if TYPE_CHECKING:
    # typer (0.29) runs on its own copy of click: its commands take these classes, not the click package's
    from typer._click import Context, HelpFormatter

GATE_SECTIONS: dict[str, Section] = {"gate": Section("gate")}
"""The ``--set`` sections of a command that drives a run's gate (``sage eval --gate``, ``sage gate ...``)."""
LEARNER_SECTIONS: dict[str, Section] = {
    "learner": Section("learner"),
    "world_model": Section("learner", "world_model_config."),
}
"""Spellings of the learner's settings besides its own field paths (which need no section)."""
FINETUNE_SECTIONS: dict[str, Section] = {"finetune": Section("finetune")}
"""``--set finetune.KEY=VALUE``: a setting of the fine-tuning rounds (core.finetune.FinetuneConfig), for the commands
that run them (``sage serve``'s worker, ``sage cycles``, ``sage study cycles``)."""
ENV_SECTIONS: dict[str, Section] = {"env": Section("env")}
STUDY_SECTIONS: dict[str, Section] = {"study": Section("study")}

GATE_SET_HELP = (
    "A setting of the gate over the run's own, gate.KEY=VALUE (repeatable), e.g. gate.hold_seconds=2 or "
    "gate.release=0: any field of core.sage.config.GateConfig."
)
LEARNER_SET_HELP = (
    "learner.KEY=VALUE: any field of core.sage.config.AgentConfig by its path (learner. may be left out: hidden=16, "
    "gate.tau_max=0.7, world_model.violation_steps=3 for world_model_config.violation_steps)"
)


DEVICE_HELP = (
    "Where the learner's updates run: auto (CUDA when torch sees a GPU, else the CPU), cpu or cuda. The loop's policy, "
    "the gate and the world model's fit stay on the CPU."
)
DeviceOption = Annotated[str, typer.Option("--device", help=DEVICE_HELP)]


def checked_device(value: str) -> str:
    """``--device`` resolved (``auto`` becomes ``cpu`` or ``cuda``), or one line and exit 2 where this machine cannot
    give it (``--device cuda`` without CUDA)."""
    from core.device import DeviceError, resolve_device

    try:
        return str(resolve_device(value))
    except DeviceError as exc:
        fail(str(exc))


def describe_device(device: Any) -> str:
    """``cpu (AMD EPYC ...)`` / ``cuda (NVIDIA H200)``: the device and what it is."""
    import torch

    from core.device import device_name

    resolved = torch.device(device)
    return f"{resolved} ({device_name(resolved)})"


def fail(message: str) -> NoReturn:
    """One red line on stderr and exit status 2: bad input never ends in a traceback."""
    typer.secho(f"error: {message}", fg=typer.colors.RED, err=True)
    raise typer.Exit(code=2)


def routed_settings(
    pairs: Sequence[str] | None, sections: Mapping[str, Section], other: str | None = None
) -> dict[str, list[str]]:
    """``--set`` pairs sorted by section (:func:`core.dotted.route_settings`); a bad pair is one error line."""
    try:
        return route_settings(pairs or [], sections, other)
    except ValueError as exc:
        fail(f"--set {exc}")


def gate_pairs(pairs: Sequence[str] | None) -> list[str]:
    """The ``KEY=VALUE`` gate settings of ``--set gate.KEY=VALUE`` pairs (the only section such a command takes)."""
    return routed_settings(pairs, GATE_SECTIONS).get("gate", [])


def scenario_list(values: Sequence[str] | None) -> list[str]:
    """``--scenario`` values, each a name or a comma list, as one list of names (empty when none was given)."""
    names = [name.strip() for value in values or () for name in value.split(",") if name.strip()]
    if values and not names:
        fail("--scenario: give at least one scenario, e.g. 3 or 1,2")
    return names


RegressionAgainstOption = Annotated[
    str,
    typer.Option(
        help="Whom a version's regression test compares it with, alone on the same seeds: base (the policy started "
        "from) or control (the version in control: a version that drives a regression scenario worse alone than the "
        "line already does is not deployed)."
    ),
]
"""``--regression-against`` of ``sage serve`` and ``sage cycles``
(:attr:`core.promotion.PromotionConfig.regression_against`)."""


def checked_regression_against(value: str) -> Literal["base", "control"]:
    """``--regression-against`` as :class:`core.promotion.PromotionConfig` takes it, or one line and exit 2."""
    from core.promotion import REGRESSION_REFERENCES

    if value not in REGRESSION_REFERENCES:
        fail(f"--regression-against {value}: base or control")
    return value  # type: ignore[return-value]


def checked_scenarios(sim: str, values: Sequence[str], flag: str) -> tuple[str, ...]:
    """Scenario names given to ``flag`` (repeatable, each may be comma-separated), each one ``sim`` knows; one line
    and exit 2 otherwise."""
    import sims

    names = tuple(part.strip() for value in values for part in value.split(",") if part.strip())
    for name in names:
        try:
            sims.descriptor(sim).scenario_kwargs(name)
        except (ValueError, OSError) as exc:
            fail(f"{flag} {name}: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}")
    return names


def one_scenario(values: Sequence[str] | None, command: str) -> str | None:
    """The one scenario of a command that drives one (None when not given)."""
    names = scenario_list(values)
    if len(names) > 1:
        fail(f"--scenario: {command} drives one scenario, not {', '.join(names)}")
    return names[0] if names else None


def run_sim(run: str | Path) -> str:
    """The simulator a run folder or checkpoint was trained on (what it records beside its weights)."""
    from core.agents import load_checkpoint, meta_of

    try:
        return meta_of(load_checkpoint(run)).sim
    except (FileNotFoundError, ValueError) as exc:
        fail(str(exc))


def runs_sim(runs: Sequence[str | Path], sim: str | None, planners: bool = False) -> str:
    """The simulator of ``runs`` (all trained on one), which a given ``sim`` must be. With ``planners``, a planner's
    name (:mod:`core.planners`) stands for a policy too and drives the ``sim`` it is given."""
    import sims  # noqa: F401 (registers the simulators' planners)
    from core.planners import is_planner

    seen = [run_sim(run) for run in runs if not (planners and is_planner(str(run)))]
    if sim is not None and any(s != sim for s in seen):
        fail(f"--sim {sim}: the run was trained on {', '.join(sorted(set(seen)))} (leave --sim out: it is the run's)")
    if not seen and sim is None:
        fail(f"{runs[0]} is a planner: say which simulator it drives with --sim")
    return sim if sim is not None else seen[0]


def policy_sim(policy: str | None, sim: str | None, default: str = "ugv") -> str:
    """The simulator to open a ``--policy`` on: the one its run records (``sim``, when given, must be it); ``sim`` or
    ``default`` where the policy is none, a planner, or cannot be read (its own check then says why)."""
    from core.agents import load_checkpoint, meta_of

    recorded = None
    if policy is not None and Path(policy).exists():
        try:
            recorded = meta_of(load_checkpoint(policy)).sim
        except Exception:  # an unreadable policy is refused where it is loaded, in one line
            recorded = None
    if sim is not None and recorded is not None and sim != recorded:
        fail(f"--sim {sim}: {policy} was trained on {recorded} (leave --sim out: it is the policy's)")
    return sim or recorded or default


def refuse_retired(**given: Sequence[str] | None) -> None:
    """A retired flag (``--gate-set``, ``--env``, ``--learner-set``) that was given: one line with its new spelling."""
    for name, values in given.items():
        if not values:
            continue
        flag, section = RETIRED[name]
        new = " ".join(f"--set {section}{value}" for value in values)
        fail(f"{flag} is now --set {section}KEY=VALUE: {new}")


RETIRED: dict[str, tuple[str, str]] = {
    "gate_set": ("--gate-set", "gate."),
    "env": ("--env", "env."),
    "learner_set": ("--learner-set", "learner."),
}
"""A retired flag's parameter name -> (the flag, the section its pairs now take)."""
GateSetRetired = Annotated[list[str] | None, typer.Option("--gate-set", hidden=True)]
EnvRetired = Annotated[list[str] | None, typer.Option("--env", hidden=True)]
LearnerSetRetired = Annotated[list[str] | None, typer.Option("--learner-set", hidden=True)]


def _method_names() -> str:
    from core.learners import learner_names

    return ", ".join(learner_names())


def _planner_names() -> str:
    import sims  # noqa: F401 (registers the simulators' planners)
    from core.planners import planner_names

    return ", ".join(planner_names())


def _sim_names() -> str:
    import sims

    return ", ".join(sims.names())


def _study_names() -> str:
    from studies.registry import study_names

    return ", ".join(study_names())


def _study_methods() -> str:
    from studies.registry import get_study, study_names

    return "; ".join(f"{name}: {', '.join(get_study(name).methods)}" for name in study_names())


CHOICES: dict[str, Callable[[], str]] = {
    "{METHODS}": _method_names,
    "{PLANNERS}": _planner_names,
    "{SIMS}": _sim_names,
    "{STUDIES}": _study_names,
    "{STUDY_METHODS}": _study_methods,
}
"""Placeholders a command's help may hold, filled with every registered name when the help is shown (the method
names import torch: ``sage --help`` and the commands themselves do not wait for them)."""


def fill_choices(text: str) -> str:
    for token, names in CHOICES.items():
        if token in text:
            text = text.replace(token, names())
    return text


class NamedChoicesCommand(TyperCommand):
    """A command whose help names every choice: the :data:`CHOICES` placeholders are filled when it is shown."""

    def format_help(self, ctx: Context, formatter: HelpFormatter) -> None:
        if self.help:
            self.help = fill_choices(self.help)
        for param in self.params:
            text: Any = getattr(param, "help", None)
            if isinstance(text, str):
                param.help = fill_choices(text)  # type: ignore[attr-defined]
        super().format_help(ctx, formatter)
