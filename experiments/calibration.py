"""Does each committed default policy's fear predict danger? ``sage gate evaluate`` on every default that has a world
model, on the scenarios where its simulator's danger lives; writes ``docs/notes/calibration/README.md`` (the table
docs/calibration.md quotes) and each run's figures, with the commit and the command that produced them.

    .venv/bin/python -m experiments.calibration [--episodes 20] [--curve-episodes 10] [--gate-episodes 20] \
        [--lead-episodes N] [--compare-gate KEY=VALUE ...] [--readme docs/calibration.md] \
        [--cpus N | --address HOST:PORT]
    .venv/bin/python -m experiments.calibration --gate-only --gate-episodes 300 --compare-gate KEY=VALUE ... \
        [--out DIR] [--readme docs/notes/calibration_history.md --block NAME]
    .venv/bin/python -m experiments.calibration --curves-only --sims highway --episodes 150 --curve-episodes 300 \
        [--out DIR] [--readme docs/notes/calibration_history.md --block NAME]
    .venv/bin/python -m experiments.calibration --sims highway --episodes 150 --curve-episodes 300 \
        --gate-episodes 300 [--readme docs/calibration.md]

``--sims`` alone (no ``--curves-only`` or ``--gate-only``): the whole bench on those simulators' defaults, written to
``docs/notes/calibration_<sims>`` and the block ``calibration-<sims>`` (e.g. after a new default policy), so
that the table of every default (``docs/notes/calibration``, block ``calibration``) is not cut down to them.

``--curves-only`` leaves the gate tables out: the calibration table and operating curves of ``--sims``' cases, e.g. a
curve at more episodes where 100 a point left the comparison with random gating undecided. Each point of a curve is a
task of its own (:class:`studies.calibrate.CurvePlan`): the fear points, the curiosity pilot and the expert alone
first, beside the calibrations and gate rows; then random and curiosity-only gating at the rates the fear points
reached (at 300 episodes a point, highway's whole curve took 42 minutes of one core as one task).

``--compare-gate release=0`` adds a second gate table with those GateConfig settings over the policies' own (there:
the paper's gate, without the hold's hysteresis that the defaults deploy). Below about 100 ``--episodes`` an AUROC
near 0.85 is not decided: with 10 violations in 40 highway episodes it moves by about ±0.05.

Fear's calibration (no operating curve) is also measured on the layouts beyond the built-in scenarios (``FIELDS``).

The gate table gives each row's 95% Wilson interval and says under it where issue #11's target is met
(:class:`studies.calibrate.GateTarget`): as read, and where the episodes decide it (the interval wholly under or over
the target's share); at 100 episodes a row of 1-9 violations is undecided either way.

Targets (issue #11): fear AUROC >= 0.85 for "violation within 1 s"; the operating curve above random and
curiosity-only gating at every takeover rate. Not a unit test: it takes minutes. Each calibration, each point of an
operating curve and each row of the gate table is a Ray task (:func:`studies.sweep.run_tasks`, one core and one
process each, libsumo's rule), on this machine's cores or a Ray cluster's; the results do not depend on how many run
at once (fixed seeds per task).
"""

from __future__ import annotations

import argparse
import math
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

import sims
from core.loop import TAKEOVER_CAUSES
from core.metrics import wilson_interval
from core.sage.config import parse_gate_settings
from studies.calibrate import (
    EXPERT_ALONE,
    CalibrationReport,
    CurvePlan,
    GateTarget,
    calibrate_run,
    compare_curves,
    curve_point,
    expert_lead,
    gate_with_expert,
    write_figures,
)
from studies.readme import include
from studies.sweep import run_tasks

ROOT = Path(__file__).resolve().parents[1]
CASES = [
    ("ugv-default", "ugv", "3"),
    ("ugv-default", "ugv", "4"),
    ("highway-default", "highway", "test-adversarial"),
    ("sumo-default", "sumo", "c2"),
    ("pedestrian-default", "pedestrian", "crossing"),
]
"""(policy under policies/, simulator, scenario): the issue's four measured cases, and the occluded crossing."""
FIELDS = {
    "ugv": ["sims/ugv/scenarios/head_on.yaml", "sims/ugv/scenarios/traffic.yaml", "sims/ugv/scenarios/slow_lead.yaml"],
}
"""Scenario files beyond a simulator's built-in scenarios that its gate-table rows also cover: layouts with movers
on paths drawn at each reset, which no committed model was trained on (its refits used 1, 2, clutter.yaml and
movers.yaml)."""
LEADS_S = (0.5, 1.0, 1.5, 2.0, 3.0)
"""Seconds before the policy's violation at which the expert takes over in the table of the warning it needs."""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--curve-episodes", type=int, default=10)
    parser.add_argument("--gate-episodes", type=int, default=20, help="episodes per scenario of the gate table")
    parser.add_argument(
        "--lead-episodes",
        type=int,
        help="episodes per scenario of the expert-lead table (default: --gate-episodes; it replays each violation "
        "at five leads, so it costs several times a gate row)",
    )
    parser.add_argument(
        "--gate-only",
        action="store_true",
        help="only the gate table, its gate with the --compare-gate settings (a comparison with the deployed gate's "
        "table of the same episodes), written to --out (default docs/notes/calibration_gate) and --readme's --block",
    )
    parser.add_argument(
        "--curves-only",
        action="store_true",
        help="only the calibration table and its operating curves (no gate tables), written to --out (default "
        "docs/notes/calibration_curves) and --readme's --block: e.g. a case's curve at more --curve-episodes, "
        "where 100 leave its points undecided",
    )
    parser.add_argument(
        "--sims",
        nargs="+",
        help="only the cases (and layouts) of these simulators (default: every default policy's)",
    )
    parser.add_argument(
        "--block", help="--readme's block of --gate-only or --curves-only (calibration-gate, calibration-curves)"
    )
    parser.add_argument(
        "--out",
        type=Path,
        help="default: docs/notes/calibration (docs/notes/calibration_gate with --gate-only, "
        "docs/notes/calibration_curves with --curves-only)",
    )
    parser.add_argument(
        "--readme",
        type=Path,
        help="also copy the result into this document's block (the project's: docs/calibration.md)",
    )
    parser.add_argument("--cpus", type=int, help="cores for local Ray (default: all of them)")
    parser.add_argument("--address", help="join the Ray cluster at this address instead of starting one")
    parser.add_argument(
        "--compare-gate",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="also a second gate table with these GateConfig settings (repeatable), e.g. release=1",
    )
    args = parser.parse_args()
    if args.gate_only and args.curves_only:
        parser.error("--gate-only and --curves-only leave nothing to run together; give one")
    if args.sims:
        unknown = sorted(set(args.sims) - {sim for _, sim, _ in CASES})
        if unknown:
            parser.error(
                f"--sims: no case on {', '.join(unknown)}; choose from {', '.join(sorted({c[1] for c in CASES}))}"
            )
    # the whole bench on some simulators alone (a new default policy measured without rerunning the others') goes
    # to its own folder and block, so the table of every default stays whole
    subset = "-".join(args.sims) if args.sims and not (args.curves_only or args.gate_only) else None
    args.block = args.block or (
        "calibration-curves"
        if args.curves_only
        else "calibration-gate"
        if args.gate_only
        else f"calibration-{subset}"
        if subset
        else "calibration"
    )
    torch.set_num_threads(1)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout
    rows: list[str] = []
    notes: list[str] = []
    curves: list[str] = []
    cases = []
    for policy, sim, scenario in CASES:
        if args.sims and sim not in args.sims:
            continue
        if (ROOT / "policies" / policy / "checkpoint.pt").is_file():
            cases.append((policy, sim, scenario))
        else:
            notes.append(f"- `{policy}` ({sim} {scenario}): no committed policy, not measured.")
    defaults = sorted({(case[0], case[1]) for case in cases})
    compare = gate_settings(args.compare_gate, [policy for policy, _ in defaults])
    table_cases = gate_cases(defaults)
    # the layouts beyond the built-in scenarios: fear's ranking there too (no operating curve: a calibration's cost)
    field_cases = [(policy, sim, field) for policy, sim in defaults for field in FIELDS.get(sim, [])]
    calibrated = cases + field_cases
    calibrations = [
        {"policy": policy, "sim": sim, "scenario": scenario, "episodes": args.episodes, "curve_episodes": 0}
        for policy, sim, scenario in calibrated
    ]
    plan = CurvePlan()
    curved = cases if args.curve_episodes > 0 else []
    first_calls = [
        {"policy": policy, "sim": sim, "scenario": scenario, "episodes": args.curve_episodes, "call": call}
        for policy, sim, scenario in curved
        for call in plan.first()
    ]
    gate_rows = [
        {"policy": policy, "sim": sim, "scenario": scenario, "episodes": args.gate_episodes}
        for policy, sim, scenario in table_cases
    ]
    compare_rows = [row | {"gate": compare} for row in gate_rows] if compare else []
    if args.curves_only:
        gate_rows, compare_rows, table_cases = [], [], []
    if args.gate_only:
        gate_only(args, table_cases, compare_rows or gate_rows, compare, commit.strip())
        return
    args.out = args.out or ROOT / "docs" / "notes" / (
        "calibration_curves" if args.curves_only else f"calibration_{subset}" if subset else "calibration"
    )
    lead_episodes = args.lead_episodes or args.gate_episodes
    lead_rows = [row | {"lead": True, "episodes": lead_episodes} for row in gate_rows]
    # one batch, so that the gate table's short rows fill the cores beside the long calibrations
    results = run_tasks(
        run_task,
        calibrations + gate_rows + compare_rows + lead_rows + first_calls,
        [f"{policy} on {sim} {scenario}" for policy, sim, scenario in calibrated]
        + [f"gate table: {policy} on {sim} {scenario}" for policy, sim, scenario in table_cases]
        + (
            [f"gate table ({compare}): {policy} on {sim} {scenario}" for policy, sim, scenario in table_cases]
            if compare
            else []
        )
        + [f"expert lead: {policy} on {sim} {scenario}" for policy, sim, scenario in table_cases]
        + [f"curve point {task['call']['kind']}: {task['policy']} on {task['scenario']}" for task in first_calls],
        address=args.address,
        cpus=args.cpus,
    )
    firsts = results[len(results) - len(first_calls) :]
    results = results[: len(results) - len(first_calls)]
    curve_seconds = attach_curves(args, plan, curved, calibrated, results[: len(calibrated)], firsts)
    for (policy, sim, scenario), (report, seconds) in zip(calibrated, results[: len(calibrated)], strict=True):
        seconds += curve_seconds.get((policy, sim, scenario), 0.0)
        figures = write_figures(report, args.out / f"{policy}-{Path(scenario).stem}")
        curves += [
            f"![{policy} on {sim} {scenario}]({f.parent.name}/{f.name})" for f in figures if f.stem == "operating_curve"
        ]
        rows.append(calibration_row(policy, sim, shown_scenario(scenario), report, seconds))
        print(report.summary(), flush=True)
    text = [
        "# Calibration of the default policies' fear"
        + (
            f" ({', '.join(args.sims)}: the operating curves at {args.curve_episodes} episodes a point)"
            if args.curves_only
            else f" ({', '.join(args.sims)})"
            if subset
            else ""
        ),
        "",
        f"Generated by `python -m experiments.calibration --episodes {args.episodes} --curve-episodes "
        f"{args.curve_episodes}"
        + (" --curves-only" if args.curves_only else f" --gate-episodes {args.gate_episodes}")
        + (f" --sims {' '.join(args.sims)}" if args.sims else "")
        + (f" --lead-episodes {args.lead_episodes}" if args.lead_episodes and not args.curves_only else "")
        + "".join(f" --compare-gate {item}" for item in args.compare_gate if not args.curves_only)
        + f"` at commit {commit.strip()}. "
        "Label: a violation within 1 s; policies drive with "
        "their gate and no expert (AUROC, firing); the operating curve adds the scripted expert.",
        "",
        "| policy | scenario | AUROC fear | ĉ | σ̂ | curiosity | firing before violation / elsewhere "
        "| violations warned | fewest violations (at takeover) | fear vs random | fear vs curiosity only "
        "| expert alone | time |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
        *rows,
        "",
        *notes,
        "",
        "Rows named by a file (`*.yaml`) are layouts beyond the built-in scenarios that no committed model was trained "
        "on (`FIELDS`): fear's ranking there, without an operating curve.",
        "",
        "Figures: `<policy>-<scenario>/reliability.png` and `operating_curve.png`; numbers: `report.json`.",
        "",
        "Fear vs random / curiosity only: the fear curve's points better · tied · worse than the other gating's "
        "point nearest in takeover rate (within 5 points; the rest unmatched), better or worse where the 95% "
        "interval of the difference in the share of episodes with a violation (Newcombe's hybrid score interval) "
        "excludes 0. The target, above random at every takeover rate, is all better. Where neither gating has a "
        "violation at a takeover rate, the point is tied: no curve can lie above another there. Expert alone: the "
        "scripted expert driving every step of the curve's episodes, the level every gating tends towards as it hands "
        "the expert more of the steps (the dotted line of the figures). Time: seconds of one core, the case's "
        "calibration and every point of its curve added up.",
        "",
        "Operating curves (episodes with a violation against the takeover rate, the gate's τ scaled; random and "
        "curiosity-only gating at equal takeover rates; bars: 95% Wilson intervals):",
        "",
        " ".join(curves),
    ]
    first = len(calibrated) + len(gate_rows)
    last = first + len(compare_rows)
    if not args.curves_only:
        text += gate_table(args.gate_episodes, results[len(calibrated) : first])
        if compare:
            text += gate_table(args.gate_episodes, results[first:last], compare)
        text += lead_table(lead_episodes, results[last:])
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "README.md").write_text("\n".join(text) + "\n")
    print(f"wrote {args.out / 'README.md'}")
    if args.readme is not None:
        include(args.readme, args.block, args.out / "README.md", "## Calibration of fear")
        print(f"README section {args.block!r} written into {args.readme}")


def gate_only(
    args: argparse.Namespace,
    cases: list[tuple[str, str, str]],
    tasks: list[dict[str, Any]],
    gate: dict[str, Any],
    commit: str,
) -> None:
    """``--gate-only``: the gate table alone, with ``gate`` over the policies' own settings."""
    rows = run_tasks(
        run_case,
        tasks,
        [f"gate table: {policy} on {sim} {scenario}" for policy, sim, scenario in cases],
        address=args.address,
        cpus=args.cpus,
    )
    settings = ", ".join(f"{key}={value}" for key, value in gate.items())
    title = f"with the gate's settings changed ({settings})" if settings else "of the default policies as deployed"
    text = [
        f"# The gate table {title}",
        "",
        f"Generated by `python -m experiments.calibration --gate-only --gate-episodes {args.gate_episodes}"
        + (f" --sims {' '.join(args.sims)}" if args.sims else "")
        + "".join(f" --compare-gate {item}" for item in args.compare_gate)
        + f"` at commit {commit}: the same episodes (seeds) as the calibration bench's gate table.",
        *gate_table(args.gate_episodes, rows, gate),
    ]
    out = args.out or ROOT / "docs" / "notes" / "calibration_gate"
    out.mkdir(parents=True, exist_ok=True)
    (out / "README.md").write_text("\n".join(text) + "\n")
    print("\n".join(text[-3:]))
    print(f"wrote {out / 'README.md'}")
    if args.readme is not None:
        include(args.readme, args.block, out / "README.md", "## Calibration of fear")
        print(f"README section {args.block!r} written into {args.readme}")


def verdict(curve: dict[str, list[dict[str, float]]], against: str) -> str:
    """``better · tied · worse`` (and how many were unmatched) of the fear curve against another gating."""
    if not curve.get(against):
        return "–"
    v = compare_curves(curve, against)
    return f"{v['better']} · {v['tied']} · {v['worse']}" + (f" ({v['unmatched']} unmatched)" if v["unmatched"] else "")


def gate_settings(items: list[str], policies: list[str]) -> dict[str, Any]:
    """``KEY=VALUE`` strings as GateConfig settings of the right types, checked against each policy's own gate as
    ``make_gate`` will apply them; a wrong one stops the bench before anything runs."""
    from core.agents import load_agent

    try:
        settings = parse_gate_settings(items)
        for policy in policies:
            load_agent(ROOT / "policies" / policy).gate_config(**settings)
    except ValueError as exc:
        raise SystemExit(f"--compare-gate: {exc}") from None
    return settings


def run_task(**kwargs: Any) -> Any:
    """One Ray task of the bench: a point of an operating curve (``call``, :func:`curve_case`) or a case's
    calibration or table row (:func:`run_case`)."""
    return curve_case(**kwargs) if "call" in kwargs else run_case(**kwargs)


def curve_case(policy: str, sim: str, scenario: str, episodes: int, call: dict[str, Any]) -> tuple[Any, float]:
    """One call of a :class:`~studies.calibrate.CurvePlan` for ``policy`` on a scenario, as ``(result, seconds)``."""
    d = sims.descriptor(sim)
    source = scenario_source(sim, scenario)
    started = time.perf_counter()
    result = curve_point(ROOT / "policies" / policy, lambda: d.make(source), episodes, call)
    return result, time.perf_counter() - started


def attach_curves(
    args: argparse.Namespace,
    plan: CurvePlan,
    curved: list[tuple[str, str, str]],
    calibrated: list[tuple[str, str, str]],
    calibrations: list[tuple[CalibrationReport, float]],
    firsts: list[tuple[Any, float]],
) -> dict[tuple[str, str, str], float]:
    """The curves' second stage (random and curiosity-only gating at the fear points' rates, one task a point), then
    each curve into its case's report; returns each case's seconds of curve work (all its tasks, added up)."""
    per_case = len(plan.first())
    stage_one = {case: firsts[i * per_case : (i + 1) * per_case] for i, case in enumerate(curved)}
    second_calls = {case: plan.second([result for result, _ in stage_one[case]]) for case in curved}
    tasks = [
        {"policy": policy, "sim": sim, "scenario": scenario, "episodes": args.curve_episodes, "call": call}
        for policy, sim, scenario in curved
        for call in second_calls[(policy, sim, scenario)]
    ]
    second_stage = (
        run_tasks(
            curve_case,
            tasks,
            [
                f"curve point {task['call']['kind']} at {task['call']['rate']:.0%}: {task['policy']} on "
                f"{task['scenario']}"
                for task in tasks
            ],
            address=args.address,
            cpus=args.cpus,
        )
        if tasks
        else []
    )
    spent: dict[tuple[str, str, str], float] = {}
    start = 0
    reports = dict(zip(calibrated, (report for report, _ in calibrations), strict=True))
    for case in curved:
        done = second_stage[start : start + len(second_calls[case])]
        start += len(done)
        reports[case].curve = plan.curve([r for r, _ in stage_one[case]], [r for r, _ in done])
        spent[case] = sum(t for _, t in stage_one[case]) + sum(t for _, t in done)
    return spent


def run_case(
    policy: str,
    sim: str,
    scenario: str,
    episodes: int,
    curve_episodes: int | None = None,
    gate: dict[str, Any] | None = None,
    lead: bool = False,
) -> Any:
    """One Ray task: the calibration of ``policy`` on a scenario, as ``(report, seconds)``, or (no
    ``curve_episodes``) one row of the gate table (``gate``: GateConfig settings over the policy's own), or
    (``lead``) one row of the table of the warning the expert needs."""
    folder = ROOT / "policies" / policy
    d = sims.descriptor(sim)
    started = time.perf_counter()
    source = scenario_source(sim, scenario)
    if curve_episodes is not None:
        report = calibrate_run(
            folder,
            lambda: d.make(source),
            d.dt,
            sim=sim,
            scenario=scenario,
            episodes=episodes,
            curve_episodes=curve_episodes,
        )
        return report, time.perf_counter() - started
    shown = shown_scenario(scenario)
    if lead:
        measured = expert_lead(folder, lambda: d.make(source), d.dt, episodes=episodes, leads_s=LEADS_S)
        warning = float(np.median(measured.gate_warning_s)) if measured.gate_warning_s else math.nan
        needed = measured.needed_s()
        return (
            f"| {policy} | {sim} {shown} | {measured.violations}/{episodes} | "
            + (f"{warning:.1f} s" if math.isfinite(warning) else "–")
            + " | "
            + (" | ".join(str(n) for n in measured.left) if measured.violations else " | ".join("–" for _ in LEADS_S))
            + " | "
            + _needed(needed, measured.violations)
            + f" | {time.perf_counter() - started:.0f} s |"
        )
    warn_steps = max(1, round(1.0 / d.dt))
    point = gate_with_expert(folder, lambda: d.make(source), episodes, warn_steps=warn_steps, **(gate or {}))
    return GateRow(
        policy=policy,
        sim=sim,
        scenario=f"{sim} {shown}",
        beyond=scenario in FIELDS.get(sim, []),
        violations=round(point["violation_rate"] * episodes),
        episodes=episodes,
        takeover_rate=point["takeover_rate"],
        takeover_parts=tuple(point[f"takeover_{cause}"] for cause in TAKEOVER_CAUSES),
        under_expert=int(point["violations_under_expert"]),
        expert_held_s=point["expert_steps_before_violation"] * d.dt,
        handed_back=int(point["violations_handed_back"]),
        under_threshold=int(point["violations_under_threshold"]),
        unforeseen=int(point["violations_unforeseen"]),
        seconds=time.perf_counter() - started,
    )


@dataclass(frozen=True)
class GateRow:
    """One scenario's row of the gate + scripted expert table (:func:`studies.calibrate.gate_with_expert`)."""

    policy: str
    sim: str
    scenario: str
    """As the table names it: the simulator, then the scenario."""
    beyond: bool
    """A layout of ``FIELDS``, beyond the built-in scenarios (the target is the built-in scenarios')."""
    violations: int
    episodes: int
    takeover_rate: float
    takeover_parts: tuple[float, ...]
    """The takeover rate's parts, shares of the steps, by why the expert drove (``TAKEOVER_CAUSES``: fear over τ,
    the hold, its hysteresis, the expert's own manoeuvre)."""
    under_expert: int
    expert_held_s: float
    handed_back: int
    under_threshold: int
    unforeseen: int
    seconds: float

    def line(self) -> str:
        low, high = wilson_interval(self.violations, self.episodes)
        held = f" ({self.expert_held_s:.1f} s)" if self.under_expert else ""
        return (
            f"| {self.policy} | {self.scenario} | {self.violations}/{self.episodes} ({low:.0%}-{high:.0%}) "
            f"| {self.takeover_rate:.0%} | {' · '.join(f'{100 * part:.0f}' for part in self.takeover_parts)} "
            f"| {self.under_expert}{held} | {self.handed_back} | {self.under_threshold} "
            f"| {self.unforeseen} | {self.seconds:.0f} s |"
        )

    def met(self, target: GateTarget) -> bool:
        return target.met(self.violations, self.episodes, self.takeover_rate)

    def reading(self) -> str:
        """The row in a sentence's list: scenario, violations and takeover."""
        return f"{self.scenario} {self.violations}/{self.episodes} at {self.takeover_rate:.1%}"


TARGET = GateTarget()
"""Issue #11's target for the gate table."""


def target_summary(rows: list[GateRow], target: GateTarget = TARGET) -> str:
    """Where the gate table meets issue #11's target, as read and as its episodes can decide it."""
    built_in = [row for row in rows if not row.beyond]
    beyond = [row for row in rows if row.beyond]
    missed = [row for row in built_in if not row.met(target)]
    decided = {
        kind: [row for row in built_in if target.decided(row.violations, row.episodes) == kind]
        for kind in ("under", "over", "undecided")
    }

    def named(group: list[GateRow]) -> str:
        return "; ".join(row.reading() for row in group) or "none"

    text = (
        f"Issue #11's target (a violation in at most {target.violation_share:.0%} of the episodes, at most "
        f"{target.takeover_rate:.0%} takeover) is met on {len(built_in) - len(missed)} of the {len(built_in)} "
        f"built-in scenarios as read; missed on: {named(missed)}. By the 95% intervals of the share of episodes "
        f"with a violation, {len(decided['under'])} lie wholly at or under {target.violation_share:.0%}, "
        f"{len(decided['over'])} wholly over it ({named(decided['over'])}) and {len(decided['undecided'])} "
        "are undecided (their interval straddles it)."
    )
    if beyond:
        met = sum(row.met(target) for row in beyond)
        text += f" The layouts beyond them: {met} of {len(beyond)} as read ({named(beyond)})."
    return text


def lead_table(episodes: int, rows: list[str]) -> list[str]:
    """How much warning the scripted expert needs (:func:`studies.calibrate.expert_lead`) beside the warning the
    gate gives, on every scenario of the gate table."""
    leads = " | ".join(f"left, expert from {lead:g} s before" for lead in LEADS_S)
    return [
        "",
        f"## The warning the expert needs ({episodes} episodes per scenario)",
        "",
        "The policy drives alone with its gate watching (no expert). Each episode with a violation is replayed from "
        "the same seed with the scripted expert taking over a given time before the policy's violation and driving "
        "to the end: the columns count the violations it could not avoid from there. Gate's warning: the median "
        f"time from the gate's first firing in the {max(LEADS_S):g} s before a violation to it (0: none). "
        "Warning needed: the shortest of these leads at which the expert avoided them all.",
        "",
        f"| policy | scenario | policy alone: episodes with a violation | gate's warning | {leads} | warning needed "
        "| time |",
        "|---|---|---|---|" + "---|" * len(LEADS_S) + "---|---|",
        *rows,
    ]


def calibration_row(policy: str, sim: str, scenario: str, report: CalibrationReport, seconds: float) -> str:
    """The calibration table's row: AUROC of fear and its parts, firing, the curve's best point and verdicts."""
    s = report.scores
    curve = report.curve.get("fear (SAGE)", [])
    best = min(curve, key=lambda p: (p["violation_rate"], p["takeover_rate"])) if curve else None
    aurocs = " | ".join(_shown(s[name].auroc, ".2f") for name in ("fear", "cost", "sigma", "curiosity"))
    return (
        f"| {policy} | {sim} {scenario} | {aurocs} "
        f"| {_shown(report.fire_rate_before_violation, '.0%')} / {_shown(report.fire_rate_elsewhere, '.0%')} "
        f"| {_shown(report.violations_warned, '.0%')} | "
        + (f"{best['violation_rate']:.0%} at {best['takeover_rate']:.0%}" if best else "–")
        + f" | {verdict(report.curve, 'random')} | {verdict(report.curve, 'curiosity only')}"
        + f" | {_alone(report.curve)}"
        + f" | {seconds:.0f} s |"
    )


def _alone(curve: dict[str, list[dict[str, float]]]) -> str:
    """The scripted expert alone on the curve's episodes: episodes with a violation, as a share and a count."""
    points = curve.get(EXPERT_ALONE)
    if not points:
        return "–"
    n = int(points[0]["episodes"])
    violations = round(points[0]["violation_rate"] * n)
    return f"{violations / n:.1%} ({violations}/{n})"


def _needed(seconds: float, violations: int) -> str:
    """The warning the expert needs, as the table shows it: – with nothing to avoid, an upper bound when the
    shortest lead was enough, a lower bound when the longest was not."""
    if violations == 0:
        return "–"
    if not math.isfinite(seconds):
        return f"> {max(LEADS_S):g} s"
    return f"≤ {seconds:g} s" if seconds <= min(LEADS_S) else f"{seconds:g} s"


def shown_scenario(scenario: str) -> str:
    """A scenario as the tables name it: a layout file by its file name."""
    return Path(scenario).name if scenario.endswith(".yaml") else scenario


def scenario_source(sim: str, scenario: str) -> str:
    """What the simulator is made from: a layout of ``FIELDS`` by its absolute path (a Ray worker's cwd may differ),
    a built-in scenario by its name."""
    return str(ROOT / scenario) if scenario in FIELDS.get(sim, []) else scenario


def aliases(sim: str) -> dict[str, str]:
    """Built-in scenarios of ``sim`` that repeat an earlier one's settings under another name (SUMO's route 1 is the
    route-shift study's C1), each with the name it repeats: the gate table leaves them out, so that no scenario
    counts twice towards the target."""
    first: dict[str, str] = {}
    repeated: dict[str, str] = {}
    for spec in sims.descriptor(sim).scenarios:
        key = repr(sorted(spec.kwargs.items()))
        if key in first:
            repeated[spec.name] = first[key]
        else:
            first[key] = spec.name
    return repeated


def table_scenarios(sim: str) -> list[str]:
    """The gate table's rows on ``sim``: its built-in scenarios (one name for each setting, :func:`aliases`), then
    its ``FIELDS``."""
    left_out = aliases(sim)
    return [spec.name for spec in sims.descriptor(sim).scenarios if spec.name not in left_out] + FIELDS.get(sim, [])


def gate_cases(policies: list[tuple[str, str]]) -> list[tuple[str, str, str]]:
    """(policy, simulator, scenario) of the gate table: :func:`table_scenarios` of each (policy, simulator)."""
    return [(policy, sim, scenario) for policy, sim in policies for scenario in table_scenarios(sim)]


def _shown(value: float, spec: str) -> str:
    """``value`` formatted, or – where there is none (no violation among the episodes: no AUROC, no firing rate)."""
    return format(value, spec) if math.isfinite(value) else "–"


def gate_table(episodes: int, rows: list[GateRow], gate: dict[str, Any] | None = None) -> list[str]:
    """Gate + scripted expert at the gate's own threshold on every scenario of each default's simulator
    (issue #11's target: a violation in at most 1 of 20 episodes, at a takeover rate of at most 35%); ``gate``:
    the GateConfig settings the rows ran with over the policies' own."""
    settings = ", ".join(f"{key}={value}" for key, value in (gate or {}).items())
    return [
        "",
        f"## Gate + scripted expert at the gate's own threshold ({episodes} episodes per scenario"
        + (f"; gate {settings}" if settings else "")
        + ")",
        "",
        "Each episode's first violation, by who drove and what fear did in the second before it: the expert driving "
        "(the gate warned; for how long it had been driving), or the policy driving after the gate fired and handed "
        "back, with fear over τ_min but under τ (within the threshold's reach: its place is the lever), or with fear "
        "under τ_min throughout (unforeseen: no threshold in the gate's range would have fired). The takeover rate "
        "by why the expert drove each step: fear over τ (the gate fired), the hold's k steps after a firing, the "
        "hold restarted by fear over the release level though under τ (the hysteresis, `gate.release`), or the "
        "expert finishing a manoeuvre past the hold (the UGV's evasions).",
        "",
        "Rows named by a file (`*.yaml`) are layouts beyond the built-in scenarios that no committed model was trained "
        "on (`FIELDS` in `experiments/calibration.py`).",
        "",
        "| policy | scenario | episodes with a violation (95% interval) | takeover rate "
        "| why the expert drove: fear over τ · hold · hysteresis · manoeuvre (% of steps) "
        "| expert driving (for how long) | handed back | fear over τ_min, under τ | unforeseen | time |",
        "|---|---|---|---|---|---|---|---|---|---|",
        *(row.line() for row in rows),
        "",
        target_summary(rows),
        *alias_note(sorted({row.sim for row in rows})),
    ]


def alias_note(simulators: list[str]) -> list[str]:
    """The line that names the scenarios the gate table leaves out as repeats (none: no line)."""
    repeats = [f"{sim} {name} (= {kept})" for sim in simulators for name, kept in aliases(sim).items()]
    if not repeats:
        return []
    return ["", "Left out as the same settings under another name: " + ", ".join(repeats) + "."]


if __name__ == "__main__":
    main()
