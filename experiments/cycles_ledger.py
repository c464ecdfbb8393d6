"""Every finished ``sage study cycles`` run in one table, read against issue 62's targets.

    python -m experiments.cycles_ledger --out docs/notes/cycles_ledger.md

Issue 62 has been measured as some ninety five-seed runs of the cycles study (the defaults on several hosts, and one
arm per lever), each with its own table in ``results/<folder>/table.md`` and its rule and reading in
``docs/notes/forgetting_anatomy.md`` or ``adaptation_probe.md``. This reads each folder's ``summary.json`` (SAGE's
row: means over the seeds), ``seeds.csv`` (the collision cycles summed over seeds) and ``table.md`` (the settings it
changed, its host and commit) and writes one table per ground (UGV 3, UGV 4, each procedural field), oldest commit
first, with the targets each row meets on its means:

- ``A``: the policy alone after the last cycle succeeds in at least 90% of episodes;
- ``T``: takeover in the last cycle at most 10%, and below the first by a decided margin (the 95% interval of the
  change lies below 0);
- ``C``: no cycle after the first with more supervised collisions than the first, on any seed;
- ``S``: the static scenarios (UGV 1-2) alone after the last cycle no worse than the starting policy's.

It decides nothing about an arm: each arm's rule compared it with its own control (same host kind, same commit's
defaults), and the defaults moved over the sessions, so two rows of different commits or hosts are not a pair. What
it shows is which targets any measured setting has met, and which none has."""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import re
import subprocess
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

#: Issue 62's targets, as (mark, what it asks) in the order the table shows them.
TARGETS: tuple[tuple[str, str], ...] = (
    ("A", "alone after the last cycle >= 90%"),
    ("T", "takeover in the last cycle <= 10%, decidedly below the first"),
    ("C", "no cycle with more supervised collisions than the first (any seed)"),
    ("S", "static scenarios alone no worse than the starting policy's"),
)

ALONE_TARGET = 0.90
TAKEOVER_TARGET = 0.10


@dataclass(frozen=True)
class Run:
    """One finished cycles run: SAGE's means over its seeds and what the table says of how it was made."""

    folder: Path
    ground: str
    changed: str
    commit: str
    host: str
    seeds: int
    alone_last: float
    unseen_last: float
    takeover_first: float
    takeover_last: float
    takeover_change_upper: float
    static_first: float
    static_last: float
    collision_cycles: float

    def meets(self) -> dict[str, bool | None]:
        """Each target's mark: True met, False missed, None not measured by this run (no static scenarios)."""
        static = (
            None
            if math.isnan(self.static_last) or math.isnan(self.static_first)
            else self.static_last >= self.static_first - 1e-9
        )
        return {
            "A": self.alone_last >= ALONE_TARGET - 1e-9,
            "T": self.takeover_last <= TAKEOVER_TARGET + 1e-9 and self.takeover_change_upper < 0,
            "C": self.collision_cycles == 0,
            "S": static,
        }


def _mean(metrics: dict, name: str) -> float:
    value = (metrics.get(name) or {}).get("mean")
    return math.nan if value is None else float(value)


def setting_line(table: str, prefix: str) -> str:
    match = re.search(rf"{re.escape(prefix)}(.*?)\.(?:\s|$)", table)
    return match.group(1).strip() if match else ""


def _ground(changed: str, table: str) -> str:
    """The scenario the run adapted on: the table's ``scenario=`` setting, else its budget line's, else UGV 3 (the
    study's default scenario, which the earliest tables did not name)."""
    match = re.search(r"\bscenario=([^,\s]+)", changed) or re.search(r"on ugv scenario ([^;)\s]+)", table)
    name = match.group(1).rstrip(".,") if match else "3"
    return f"UGV {name}" if name.isdigit() else name


def _host(table: str) -> str:
    processor = re.search(r"on the CPU \(([^)]*)\)", table)
    speed = re.search(r"and ([\d,.]+) SAC updates/s", table)
    name = processor.group(1) if processor else "not stated"
    return f"{name}, {speed.group(1)} SAC updates/s" if speed else name


def read_run(folder: Path) -> Run | None:
    """The run in ``folder``, or None where it is not a finished cycles run with SAGE's row."""
    summary_path, table_path = folder / "summary.json", folder / "table.md"
    if not summary_path.is_file() or not table_path.is_file():
        return None
    summary = json.loads(summary_path.read_text())
    if summary.get("study") != "cycles":
        return None
    row = next((r for r in summary.get("rows", []) if r.get("method") == "sage"), None)
    if row is None:
        return None
    metrics = row["metrics"]
    table = table_path.read_text()
    changed = "; ".join(
        part
        for part in (
            setting_line(table, "Settings changed from the study's defaults: "),
            setting_line(table, "Learner settings changed for every method: "),
        )
        if part
    )
    change = metrics.get("takeover_change") or {}
    upper = float(change.get("mean", math.nan)) + float(change.get("ci95_half_width") or 0.0)
    return Run(
        folder=folder,
        ground=_ground(changed, table),
        changed=changed,
        commit=str(summary.get("commit", "")),
        host=_host(table),
        seeds=int(row.get("seeds", 0)),
        alone_last=_mean(metrics, "alone_success_last"),
        unseen_last=_mean(metrics, "unseen_success_last"),
        takeover_first=_mean(metrics, "takeover_first"),
        takeover_last=_mean(metrics, "takeover_last"),
        takeover_change_upper=upper,
        static_first=_mean(metrics, "static_success_first"),
        static_last=_mean(metrics, "static_success_last"),
        collision_cycles=_collision_cycles(folder / "seeds.csv", metrics),
    )


def _collision_cycles(seeds_csv: Path, metrics: dict) -> float:
    """Collision cycles above the first summed over SAGE's seeds (the seeds' file; the mean times the seeds else)."""
    if seeds_csv.is_file():
        with seeds_csv.open() as f:
            values = [
                float(r["collision_cycles_above_first"])
                for r in csv.DictReader(f)
                if r.get("method") == "sage" and r.get("collision_cycles_above_first") not in (None, "")
            ]
        if values:
            return sum(values)
    return math.nan


def commit_order(commits: Iterable[str], repo: Path) -> dict[str, int]:
    """Each commit's author time (seconds), for ordering; a commit git does not know sorts last."""
    order: dict[str, int] = {}
    for commit in set(commits):
        result = subprocess.run(
            ["git", "-C", str(repo), "show", "-s", "--format=%ct", commit],
            capture_output=True,
            text=True,
            check=False,
        )
        order[commit] = int(result.stdout.strip()) if result.returncode == 0 and result.stdout.strip() else 2**62
    return order


def _mark(value: bool | None, mark: str) -> str:
    return "–" if value is None else (f"**{mark}**" if value else "·")


def _fraction(value: float) -> str:
    return "–" if math.isnan(value) else f"{value:.2f}"


def _ground_key(ground: str) -> tuple[int, str]:
    return (0, ground) if ground.startswith("UGV ") else (1, ground)


def render(
    runs: Sequence[Run],
    order: dict[str, int],
    command: str,
    commit: str,
    out_dir: Path,
    unfinished: Sequence[str] = (),
) -> str:
    """The ledger as Markdown: a count of the rows meeting each target, then one table per ground; each run links to
    its table relative to ``out_dir`` (where the ledger is written); ``unfinished`` names the folders read past (no
    finished table)."""
    lines = [
        "# Issue 62's cycles runs, read against its targets",
        "",
        f"Generated by `{command}` at commit `{commit}`; do not edit. Each row is one finished five-seed (or fewer)",
        "`sage study cycles` run: SAGE's means over its seeds (`summary.json`), the collision cycles summed over seeds",
        "(`seeds.csv`), and what its table says of how it was made. A mark is a target met on the means:",
        "",
        *[f"- **{mark}**: {text}." for mark, text in TARGETS],
        "",
        "`·` missed, `–` not measured. Rows of different commits or hosts are not pairs: the defaults moved over the",
        "sessions and learner rows reproduce only per processor, so each arm was judged against its own control by the",
        "rule in its script (`results/cycles-*.sh`), read in",
        "[forgetting_anatomy.md](forgetting_anatomy.md) and [adaptation_probe.md](adaptation_probe.md). Settings are",
        "those changed from the defaults of the row's commit.",
        "",
        "| ground | runs | A | T | C | S | all four |",
        "|---|---|---|---|---|---|---|",
    ]
    grounds = sorted({r.ground for r in runs}, key=_ground_key)
    for ground in grounds:
        rows = [r for r in runs if r.ground == ground]
        marks = [r.meets() for r in rows]
        counts = [sum(bool(m[k]) for m in marks) for k, _ in TARGETS]
        every = sum(all(bool(m[k]) for k, _ in TARGETS) for m in marks)
        lines.append(f"| {ground} | {len(rows)} | " + " | ".join(str(c) for c in counts) + f" | {every} |")
    if unfinished:
        lines += [
            "",
            f"Folders without a finished table (stopped or running), not in the rows: {', '.join(unfinished)}.",
        ]
    for ground in grounds:
        rows = sorted((r for r in runs if r.ground == ground), key=lambda r: (order.get(r.commit, 2**62), r.folder))
        lines += [
            "",
            f"## {ground}",
            "",
            "| run | settings changed | commit | host | seeds | alone last | unseen last | takeover first → last "
            "| static first → last | collision cycles | A | T | C | S |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
        ]
        for run in rows:
            run_marks = run.meets()
            link = Path(os.path.relpath(run.folder.resolve() / "table.md", out_dir.resolve())).as_posix()
            cycles = "–" if math.isnan(run.collision_cycles) else f"{run.collision_cycles:g}"
            lines.append(
                f"| [{run.folder.name}]({link}) | {run.changed or 'the defaults'} | `{run.commit}` | {run.host} | "
                f"{run.seeds} | {_fraction(run.alone_last)} | {_fraction(run.unseen_last)} | "
                f"{run.takeover_first:.3f} → {run.takeover_last:.3f} | {_fraction(run.static_first)} → "
                f"{_fraction(run.static_last)} | {cycles} | "
                + " | ".join(_mark(run_marks[k], k) for k, _ in TARGETS)
                + " |"
            )
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--results", type=Path, default=Path("results"), help="the folder holding the runs")
    parser.add_argument("--pattern", default="cycles-*", help="run folders to read (a glob under --results)")
    parser.add_argument("--out", type=Path, default=Path("docs/notes/cycles_ledger.md"))
    args = parser.parse_args(argv)
    folders = sorted(p for p in args.results.glob(args.pattern) if p.is_dir())
    read = {p: read_run(p) for p in folders}
    runs = [run for run in read.values() if run is not None]
    unfinished = [p.name for p, run in read.items() if run is None]
    if not runs:
        raise SystemExit(f"no finished cycles runs under {args.results}/{args.pattern}")
    repo = Path.cwd()
    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=False)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    command = "python -m experiments.cycles_ledger" + (
        "" if args.out == parser.get_default("out") else f" --out {args.out}"
    )
    text = render(
        runs, commit_order((r.commit for r in runs), repo), command, head.stdout.strip(), args.out.parent, unfinished
    )
    args.out.write_text(text)
    print(f"{len(runs)} runs of {len(folders)} folders into {args.out}")


if __name__ == "__main__":
    main()
