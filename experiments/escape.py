"""Were the gate + expert table's violations avoidable at the warning the gate gave? (:mod:`studies.escape`)

For each committed default policy and scenario of the gate table in ``experiments/calibration.py`` (the same seeds,
the policy's own gate and the scripted expert), every episode with a violation is replayed from its seed and every
steady manoeuvre (a grid over the action space, each action held ``--hold`` seconds) is tried from the start of the
last takeover before the violation and from ``--before`` seconds before it. A violation no manoeuvre avoids from the
takeover was probably out of reach at that warning (a manoeuvre that changes course on the way might still have
escaped); one that some manoeuvre avoids was within reach of a driver who knew what the others would do (the
manoeuvres are tried against the true future). Writes ``docs/notes/escape/README.md`` with the commit and the command.

    .venv/bin/python -m experiments.escape [--episodes 100] [--hold 3] [--before 1 2] [--levels 5] \
        [--readme docs/notes/calibration_history.md] [--cpus N | --address HOST:PORT]

Each row is a Ray task (:func:`studies.sweep.run_tasks`); rows do not depend on how many run at once. Not a unit
test: it takes minutes.
"""

from __future__ import annotations

import argparse
import subprocess
import time
from pathlib import Path
from typing import Any

import torch

import sims
from experiments.calibration import (
    CASES,
    gate_cases,
    scenario_source,
    shown_scenario,
)
from studies.escape import EscapeReport, escape_check
from studies.readme import include
from studies.sweep import run_tasks

ROOT = Path(__file__).resolve().parents[1]


def escape_row(
    policy: str, sim: str, scenario: str, episodes: int, before_s: list[float], hold_s: float, levels: int
) -> tuple[EscapeReport, float]:
    """One Ray task: the escape check of ``policy`` on a scenario, and its seconds."""
    torch.set_num_threads(1)
    d = sims.descriptor(sim)
    source = scenario_source(sim, scenario)
    started = time.perf_counter()
    report = escape_check(
        ROOT / "policies" / policy,
        lambda: d.make(source),
        d.dt,
        episodes=episodes,
        before_s=before_s,
        hold_s=hold_s,
        levels=levels,
    )
    return report, time.perf_counter() - started


def table_row(policy: str, sim: str, scenario: str, report: EscapeReport, seconds: float) -> str:
    replayed = report.replayed
    cells = [
        policy,
        f"{sim} {shown_scenario(scenario)}",
        f"{report.violations}/{report.episodes}",
        str(report.drifted) if report.drifted else "0",
        f"{report.warned} ({report.under_expert})",
        f"{report.from_takeover}/{report.warned}" if report.warned else "–",
        *(f"{n}/{replayed}" if replayed else "–" for n in report.escapable_before),
        f"{seconds:.0f} s",
    ]
    return "| " + " | ".join(cells) + " |"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--episodes", type=int, default=100, help="episodes per scenario (the gate table's seeds)")
    parser.add_argument("--hold", type=float, default=3.0, help="seconds each manoeuvre is held")
    parser.add_argument("--before", type=float, nargs="*", default=[1.0, 2.0], help="seconds before the violation")
    parser.add_argument("--levels", type=int, default=5, help="values per action dimension of the manoeuvre grid")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "notes" / "escape")
    parser.add_argument(
        "--readme",
        type=Path,
        help="also copy the result into this document's escape block (e.g. docs/notes/calibration_history.md)",
    )
    parser.add_argument("--cpus", type=int, help="cores for local Ray (default: all of them)")
    parser.add_argument("--address", help="join the Ray cluster at this address instead of starting one")
    args = parser.parse_args()
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout
    defaults = sorted({(policy, sim) for policy, sim, _ in CASES if (ROOT / "policies" / policy).is_dir()})
    rows = gate_cases(defaults)
    results = run_tasks(
        escape_row,
        [
            {
                "policy": policy,
                "sim": sim,
                "scenario": scenario,
                "episodes": args.episodes,
                "before_s": args.before,
                "hold_s": args.hold,
                "levels": args.levels,
            }
            for policy, sim, scenario in rows
        ],
        [f"escape: {policy} on {sim} {scenario}" for policy, sim, scenario in rows],
        address=args.address,
        cpus=args.cpus,
    )
    before = [f"{s:g}" for s in args.before]
    command = (
        f"python -m experiments.escape --episodes {args.episodes} --hold {args.hold:g} --before {' '.join(before)} "
        f"--levels {args.levels}"
    )
    text: list[Any] = [
        "# Were the violations avoidable at the warning the gate gave?",
        "",
        f"Generated by `{command}` at commit {commit.strip()}. The gate + scripted expert table's episodes (the "
        "calibration bench's seeds), each violation replayed from its seed with the executed actions; from the "
        "start of the last takeover in the 3 s before it (where there was one) and from a given time before it, "
        f"every steady manoeuvre (a grid of {args.levels} values per action dimension, or every discrete action) "
        f"held for {args.hold:g} s: the violations that at least one of them avoided. The manoeuvres meet the "
        "true future of the other traffic, which the expert only predicts: one that escapes shows the violation was "
        "within reach of a driver who knew it. None escaping is evidence, not proof, that it was out of reach (a "
        "steady grid is a small set: a manoeuvre that changes course on the way may still escape, so a later start "
        "can read more avoidable than an earlier one). Replays that did not reproduce the episode (SUMO's own "
        "driver steers while its expert drives) are counted apart and left out.",
        "",
        "| policy | scenario | episodes with a violation | replay drifted | with a takeover before it (expert "
        "driving) | avoidable from the takeover | "
        + " | ".join(f"avoidable from {s} s before" for s in before)
        + " | time |",
        "|---|---|---|---|---|---|" + "---|" * len(before) + "---|",
    ]
    for (policy, sim, scenario), (report, seconds) in zip(rows, results, strict=True):
        text.append(table_row(policy, sim, scenario, report, seconds))
        print(f"{policy} on {sim} {scenario}: {report.summary()}", flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "README.md").write_text("\n".join(text) + "\n")
    print(f"wrote {args.out / 'README.md'}")
    if args.readme is not None:
        include(args.readme, "escape", args.out / "README.md", "## Calibration of fear")
        print(f"README section 'escape' written into {args.readme}")


if __name__ == "__main__":
    main()
