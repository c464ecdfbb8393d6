"""The study registry: ``sage study NAME`` runs a registered study end to end.

A study is one :class:`StudyDef` entry: its methods, the picklable trial function that trains one method on
one seed within the budget and evaluates it (returning result rows), how rows are keyed, which metrics go in
the table and figures. :func:`run_study` sweeps every (method, seed) on Ray (:mod:`studies.sweep`), then
writes the results folder (:mod:`studies.results`) and returns its table. New studies (pedestrian, UGV) plug
in with one :func:`register_study` call.

A trial returns a flat ``{metric: value}`` dict, or, for tables with more than one row per method (highway's
split x condition), metrics named ``"<row part>/<row part>/<metric>"`` that :func:`run_study` unpacks into the
other key columns (``keys`` besides ``method``).
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from studies.budgets import Budget, budget
from studies.host_speed import HostSpeed, measure_host_speed
from studies.results import write_results
from studies.sweep import SweepError, TrialFn, TrialLedger, run_sweep, trial_gpu_share


@dataclass(frozen=True)
class StudyDef:
    """One study as ``sage study NAME`` runs it."""

    name: str
    methods: tuple[str, ...]
    """Learner names trained and compared, each on every seed with the same environment-step budget."""
    trial: TrialFn
    """``trial(config) -> metrics``; config holds ``method``, ``seed``, ``train_steps``, ``eval_episodes``."""
    metrics: tuple[str, ...]
    """Metrics shown in the table (mean ± 95% CI over seeds)."""
    keys: tuple[str, ...] = ("method",)
    """Table row key, in the paper's order (highway: ``("split", "method", "condition")``); the columns other
    than ``method`` are unpacked from prefixed metric names."""

    @property
    def row_keys(self) -> tuple[str, ...]:
        return tuple(k for k in self.keys if k != "method")

    plot: tuple[str, ...] = ()
    """Metrics drawn as figures."""
    notes: tuple[str, ...] = ()
    """Stated under the table: the terminal-violation rule, the experts used, what a budget leaves out."""
    settings: Mapping[str, Any] = field(default_factory=dict)
    """Fixed settings passed to every trial (``min_eval_episodes`` raises the budget's evaluation episodes for this
    study; besides the budget and ``runs_dir``, where trials keep their run
    folders: ``<results folder>/runs``)."""
    prepare: Callable[[Path, dict[str, Any]], dict[str, Any]] | None = None
    """``prepare(results folder, settings) -> more settings``, run once before the sweep: e.g. train (or find in
    its cache, ``<results folder>/experts``) the expert the trials use (:mod:`studies.experts`). Its
    ``PREPARED_NOTES`` entry, a list of sentences (how good that expert is alone), goes under the table."""
    learner_overrides: bool = True
    """Whether its trials take ``sage study --set learner.KEY=VALUE``: those that train through
    :func:`studies.training.train_once` after their own settings; the cycles study as edits of its fine-tuning rounds'
    learner configuration (``FinetuneConfig.overrides``, applied after SAGE's switches)."""
    budget_text: Callable[[Budget, Mapping[str, Any]], str] | None = None
    """``budget_text(budget, settings) -> what it ran``, for the table's header, when the study spends the budget
    otherwise than as training steps and evaluation episodes (the cycles study: cycles of episodes)."""
    check_settings: Callable[[Mapping[str, Any]], None] | None = None
    """``check_settings(settings)``: raises ValueError (one line) for settings the study cannot run (e.g. an unknown
    scenario), before any trial starts."""
    untrained: tuple[str, ...] = ()
    """Methods that are not trained (planners): their table rows say that their ± is over evaluation episodes."""
    figures: Callable[[Path, dict[str, Any]], list[Path]] | None = None
    """``figures(results folder, settings) -> paths``: the study's own figures from its trials' run folders,
    drawn after the table."""


LEDGER = "trials"
"""The results folder's subfolder of finished trials' rows (committed; a study resumes from it on any machine)."""

PREPARED_NOTES = "table_notes"
"""The key of a ``prepare`` result whose sentences go under the table rather than to the trials."""

_STUDIES: dict[str, StudyDef] = {}


BUILTIN_STUDIES = (
    "studies.pedestrian",
    "studies.ugv",
    "studies.highway_study",
    "studies.route_shift_study",
    "studies.cycles_study",
)
"""Modules whose ``STUDY`` is registered on first use (lazily: a study imports its simulator)."""
_BUILTINS_DONE = False


def _builtins() -> None:
    global _BUILTINS_DONE
    if _BUILTINS_DONE:
        return
    _BUILTINS_DONE = True
    import importlib

    for module in BUILTIN_STUDIES:
        study = importlib.import_module(module).STUDY
        _STUDIES.setdefault(study.name, study)


def register_study(study: StudyDef) -> None:
    """Add a study; a second study under the same name is an error (unregister it first)."""
    _builtins()
    if study.name in _STUDIES:
        raise ValueError(f"study {study.name!r} is already registered")
    _STUDIES[study.name] = study


def unregister_study(name: str) -> None:
    _STUDIES.pop(name, None)


def study_names() -> list[str]:
    _builtins()
    return sorted(_STUDIES)


def get_study(name: str) -> StudyDef:
    _builtins()
    try:
        return _STUDIES[name]
    except KeyError:
        known = ", ".join(study_names()) or "none registered"
        raise ValueError(f"unknown study {name!r}; known studies: {known}") from None


def _unpack(row: Mapping[str, Any], row_keys: Sequence[str], metrics: Sequence[str]) -> list[dict[str, Any]]:
    """One sweep row -> table rows, splitting ``a/b/metric`` names into the ``row_keys`` columns."""
    if not row_keys:
        return [dict(row)]
    rows: dict[tuple[str, ...], dict[str, Any]] = {}
    for name, value in row.items():
        parts = name.split("/")
        if len(parts) != len(row_keys) + 1 or parts[-1] not in metrics:
            continue
        key = tuple(parts[:-1])
        rows.setdefault(key, {"method": row["method"], "seed": row["seed"], **dict(zip(row_keys, key, strict=True))})
        rows[key][parts[-1]] = value
    return list(rows.values())


def check_study_learner_overrides(name: str, pairs: Sequence[str]) -> list[str]:
    """``pairs`` (``sage study --set learner.KEY=VALUE``) checked for study ``name``: a study that trains no learner
    from a spec of its own refuses them, and each must fit a learner's configuration (a ValueError says which)."""
    from studies.training import check_learner_overrides

    if not get_study(name).learner_overrides:
        raise ValueError(f"{name} trains no learner from a spec of its own, so it takes no learner settings")
    return check_learner_overrides(pairs)


def run_study(
    name: str,
    budget_name: str,
    out: Path,
    address: str | None = None,
    cpus: int | None = None,
    max_concurrent: int | None = None,
    log: Callable[[str], None] = print,
    overrides: Mapping[str, Any] | None = None,
    methods: Sequence[str] | None = None,
    train_steps: int | None = None,
    learner_overrides: Sequence[str] = (),
    device: str = "cpu",
) -> Path:
    """Train and evaluate every method of study ``name`` on every seed, write ``out``; returns the table path.

    ``methods``: only these of the study's methods (default: all); ``train_steps``: this many environment steps per
    method and seed instead of the budget's (e.g. a longer comparison of two methods); both are stated under the
    table. ``learner_overrides``: ``key=value`` learner settings every trained method takes after its own (an
    ablation at the same budgets and seeds), stated under the table too. ``device``: where every trial's updates
    run (resolved, ``cpu`` or ``cuda``: :func:`core.device.resolve_device`); on CUDA each trial asks Ray for a share of
    the GPU. The table states it. The Ray experiment state lives in
    ``out/sweep`` and each finished trial's row in ``out/trials`` (:class:`studies.sweep.TrialLedger`, committed with
    the table): rerunning the same command resumes, on this machine or another.
    """
    study = get_study(name)
    spent: Budget = budget(budget_name)
    seeds = list(range(spent.seeds))
    chosen_methods = tuple(methods) if methods else study.methods
    unknown = [m for m in chosen_methods if m not in study.methods]
    if unknown:
        raise ValueError(f"{name} has no method {', '.join(unknown)}; its methods: {', '.join(study.methods)}")
    if learner_overrides:
        learner_overrides = check_study_learner_overrides(name, learner_overrides)
    if train_steps is not None:
        if train_steps <= 0:
            raise ValueError(f"train_steps must be positive, not {train_steps}")
        spent = dataclasses.replace(spent, name=f"{spent.name}, train_steps={train_steps}", train_steps=train_steps)
    # a study may evaluate more episodes than the budget's default (the UGV table's 20 trials per scenario)
    chosen = {**dict(study.settings), **dict(overrides or {})}
    spent = dataclasses.replace(spent, eval_episodes=max(spent.eval_episodes, int(chosen.get("min_eval_episodes", 0))))
    settings = {
        **chosen,
        "train_steps": spent.train_steps,
        "eval_episodes": spent.eval_episodes,
        "expert_steps": spent.expert_steps,
        "runs_dir": str((out / "runs").resolve()),
        "methods": list(chosen_methods),
    }
    if learner_overrides:
        from studies.training import LEARNER_OVERRIDES

        settings[LEARNER_OVERRIDES] = list(learner_overrides)
    from studies.training import STUDY_DEVICE

    settings[STUDY_DEVICE] = device
    host, host_unmeasured = _host_speed(budget_name, log)
    start = time.perf_counter()
    prepared_notes: list[str] = []
    if study.prepare is not None:
        from studies.sweep import ensure_ray

        ensure_ray(address, cpus)  # a prepare may run Ray tasks (experts): on the trials' cluster, with their cores
        prepared = dict(study.prepare(out, settings))
        prepared_notes = [str(n) for n in prepared.pop(PREPARED_NOTES, [])]
        settings.update(prepared)
    wall_log = out / LEDGER / "wall_times.json"
    try:
        rows = run_sweep(
            study.trial,
            chosen_methods,
            seeds,
            out / "sweep",
            name,
            settings=settings,
            address=address,
            cpus=cpus,
            max_concurrent=max_concurrent,
            gpu_share=trial_gpu_share(device, max_concurrent or cpus),
            ledger=TrialLedger.for_results(out / LEDGER, settings, out),
        )
    except SweepError:  # a stopped or partly failed invocation spent its wall time too: the log keeps it
        _log_wall_time(wall_log, time.perf_counter() - start, max_concurrent, finished=False, host=host)
        raise
    wall_s = time.perf_counter() - start
    runs = _log_wall_time(wall_log, wall_s, max_concurrent, host=host)
    total_s = sum(float(r["wall_s"]) for r in runs)
    table_rows = [r for row in rows for r in _unpack(row, study.row_keys, study.metrics)]
    trial_s = sum(float(row.get("trial_seconds", 0.0)) for row in rows)
    changed = [f"{k}={v}" for k, v in (overrides or {}).items()]
    elsewhere = [  # a planner's trial writes no run folder wherever it runs
        r
        for r in rows
        if r["method"] not in study.untrained
        and not (Path(settings["runs_dir"]) / f"{r['method']}-s{r['seed']}").is_dir()
    ]
    if elsewhere and study.figures is not None:
        prepared_notes.append(
            f"{len(elsewhere)} of {len(rows)} trials ran on another machine (their rows are from `{LEDGER}/`, their "
            "run folders are not here): the figures drawn from run folders show only the others."
        )
    timing = (
        f"The trials ran {trial_s / 60:.1f} min in total ({len(rows)} trials, at most "
        f"{max_concurrent or 'one per core'} at once). The wall time above is the sum over the {len(runs)} "
        f"invocation(s) of this command on this results folder, stopped ones included (this one: {wall_s / 60:.1f} "
        f"min); a rerun resumes: finished trials are read from `{LEDGER}/`, not run again. "
        + (
            f"Before its trials, {host.words()}: a wall time reads against it on another host (hosts of one name "
            "differ)."
            if host is not None
            else host_unmeasured
        )
    )
    table = write_results(
        out,
        name,
        table_rows,
        keys=study.keys,
        metrics=study.metrics,
        budget=spent,
        wall_s=total_s,
        plot=study.plot,
        budget_text=study.budget_text(spent, settings) if study.budget_text is not None else None,
        untrained=study.untrained,
        device=_device_words(device),
        host_speed=None if host is None else host.as_dict(),
        notes=(
            *study.notes,
            *([f"Settings changed from the study's defaults: {', '.join(changed)}."] if changed else []),
            *(
                [f"Methods run: {', '.join(chosen_methods)} (the study's: {', '.join(study.methods)})."]
                if chosen_methods != study.methods
                else []
            ),
            *([f"Training budget: {train_steps} environment steps (not the budget's)."] if train_steps else []),
            *(
                [f"Learner settings changed for every method: {', '.join(learner_overrides)}."]
                if learner_overrides
                else []
            ),
            *prepared_notes,
            timing,
        ),
    )
    if study.figures is not None:
        for path in study.figures(out, settings):
            log(f"figure: {path}")
    log(
        f"study {name}: {len(rows)} trials, wall time {wall_s / 60:.1f} min "
        f"(all runs on this folder: {total_s / 60:.1f} min); table {table}"
    )
    return table


def _host_speed(budget_name: str, log: Callable[[str], None]) -> tuple[HostSpeed | None, str]:
    """The host's reference speed before the trials (:mod:`studies.host_speed`, a few seconds), or None and the
    sentence the table says instead: at the smoke budget (whose whole run lasts about as long) it is not measured,
    and a reference that fails (a simulator that cannot start here) costs the study only that sentence."""
    if budget_name == "smoke":
        return None, "The host's reference speed is not measured at the smoke budget."
    try:
        host = measure_host_speed()
    except Exception as exc:  # the reference is a note beside the results, never a reason to lose them
        first_line = str(exc).splitlines()[0] if str(exc) else ""
        reason = f"{type(exc).__name__}: {first_line}" if first_line else type(exc).__name__
        log(f"the host's reference speed could not be measured ({reason}); the study runs without it")
        return None, f"The host's reference speed could not be measured ({reason})."
    log(f"{host.words()} ({host.seconds:.1f} s)")
    return host, ""


def _log_wall_time(
    path: Path,
    wall_s: float,
    max_concurrent: int | None,
    finished: bool = True,
    host: HostSpeed | None = None,
) -> list[dict[str, Any]]:
    """Append this invocation's wall time to the results folder's log (committed with the ledger) and return every
    entry: a study that was interrupted and resumed, here or elsewhere, reports the wall time it really took."""
    runs: list[dict[str, Any]] = []
    if path.exists():
        try:
            loaded = json.loads(path.read_text())
            runs = [r for r in loaded if isinstance(r, dict) and isinstance(r.get("wall_s"), (int, float))]
        except (OSError, ValueError):
            runs = []  # an unreadable log loses only earlier timings, never the results
    ended = time.strftime("%Y-%m-%dT%H:%M:%S")
    entry: dict[str, Any] = {"wall_s": wall_s, "max_concurrent": max_concurrent, "ended": ended, "finished": finished}
    if host is not None:
        entry["host_speed"] = host.as_dict()
    runs.append(entry)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(runs, indent=1))
    return runs


def _device_words(device: str) -> str:
    """``the CPU (AMD EPYC)`` / ``AMD EPYC, the learners' updates on CUDA:0 (NVIDIA H200)``: where a study table says it
    ran (the simulators always run on the CPU)."""
    import torch

    from core.device import device_name, processor_name

    resolved = torch.device(device)
    if resolved.type == "cpu":
        return f"the CPU ({processor_name()})"
    return f"{processor_name()}, the learners' updates on {str(resolved).upper()} ({device_name(resolved)})"
