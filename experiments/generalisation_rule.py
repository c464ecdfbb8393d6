"""Does a candidate gate pass the adoption rule of ``docs/notes/generalisation.md`` against the baseline?

Reads, measuring nothing, the gate + scripted expert rows that ``python -m studies.generalisation`` left in its caches
for the baseline and the candidate on the same ground and seeds, and prints per ground: each one's episodes with a
violation and takeover rate, the 95% interval of the difference in violation share (candidate minus baseline,
:func:`core.metrics.difference_interval`), the takeover difference, and the rule's reading of them (clause 1 on the
unseen ground, clause 2 on the seen one). Clause 3 (three refit seeds, the median refit) is read by the person.

    python -m experiments.generalisation_rule --candidate runs/wm-fields-s0 \
        --candidate-cache results/generalisation/ugv-wm-fields-s0.json --episodes 100 --seen-episodes 120

The baseline's cache stays on the machine that measured it. Without it, ``--baseline-table docs/generalisation.md``
reads the baseline's gate rows from the committed table instead (its row for the same ground, scenarios and number of
gate episodes; the seeds are the study's own, from :data:`studies.calibrate.EVAL_SEED`). The table gives the
takeover rate in whole percent, so a reading that a half point either way would change is reported as undecided.
"""

from __future__ import annotations

import argparse
import math
import re
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from core.metrics import difference_interval
from studies.generalisation import gate_settings_of, generalisation_table

BUILT_IN_UGV = ["1", "2", "sims/ugv/scenarios/clutter.yaml", "sims/ugv/scenarios/movers.yaml"]
"""The committed UGV policy's training scenarios: the rule's seen ground."""


def verdict(
    ground: str, candidate: tuple[int, int, float], baseline: tuple[int, int, float]
) -> tuple[tuple[float, float], float, str]:
    """The difference interval of violation shares, the takeover difference (points) and the rule's reading: on the
    ``unseen`` ground clause 1 (pass / fail / undecided), on the ``seen`` one clause 2 (pass / fail)."""
    (violations, episodes, takeover), (base_violations, base_episodes, base_takeover) = candidate, baseline
    low, high = difference_interval(violations, episodes, base_violations, base_episodes)
    rise = 100 * (takeover - base_takeover)
    if ground == "seen":
        return (low, high), rise, "pass" if low <= 0 and rise <= 5 else "fail"
    if math.isnan(low):
        return (low, high), rise, "undecided"
    if high < 0:
        return (low, high), rise, "pass" if rise <= 5 and takeover <= 0.35 else "fail"
    if low > 0:
        return (low, high), rise, "fail"
    return (low, high), rise, "pass" if rise <= -5 else "undecided"


GATE_CELL = re.compile(r"(\d+) of (\d+) ")
"""The start of a table's gate cell: "13 of 300 (4%) [3%, 7%]"."""


def table_point(text: str, run: str, ground: str, scenarios: Sequence[str]) -> tuple[int, int, float] | None:
    """A gate row (violations, episodes, takeover rate) of ``run``'s section in a table written by
    ``studies.generalisation`` (its subsections too): the row of ``ground`` ("unseen" / "seen") whose scenarios are
    ``scenarios``; None if there is none."""
    in_section = False
    for line in text.splitlines():
        if line.startswith("## "):
            # "## SIM: RUN": any simulator's section (the table has one per simulator)
            in_section = line.strip().partition(": ")[2] == run
        cells = [cell.strip() for cell in line.strip().strip("|").split("|")]
        if not in_section or len(cells) != 11 or not cells[0].startswith(f"{ground} ("):
            continue
        gate, takeover = GATE_CELL.match(cells[9]), cells[10]
        if cells[1] == ", ".join(scenarios) and gate and takeover.endswith("%"):
            return int(gate[1]), int(gate[2]), float(takeover.removesuffix("%")) / 100
    return None


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m experiments.generalisation_rule", description=__doc__.split("\n")[0]
    )
    parser.add_argument("--sim", default="ugv", help="the simulator of both runs (default: ugv)")
    parser.add_argument("--candidate", required=True, help="the candidate run folder, as the study was given it")
    parser.add_argument("--candidate-cache", type=Path, required=True)
    parser.add_argument("--candidate-set", action="append", default=[], help="its gate.KEY=VALUE, as measured")
    parser.add_argument("--baseline", default="policies/ugv-default")
    parser.add_argument("--baseline-cache", type=Path, default=Path("results/generalisation/ugv.json"))
    parser.add_argument(
        "--baseline-table",
        type=Path,
        help="read the baseline's gate rows from this committed table (docs/generalisation.md), not its cache",
    )
    parser.add_argument("--unseen", default="ugv-fields:test")
    parser.add_argument("--seen", action="append", default=[], help="comma lists (default: the UGV's built-in four)")
    parser.add_argument("--episodes", type=int, default=300, help="episodes on the unseen ground (signals and gate)")
    parser.add_argument("--seen-episodes", type=int, default=0, help="episodes on the seen ground (0: none)")
    args = parser.parse_args(argv)
    seen = [name for value in args.seen for name in value.split(",") if name] or BUILT_IN_UGV
    grounds = {"unseen": ([args.unseen], args.episodes), "seen": (seen, args.seen_episodes)}
    try:
        settings = gate_settings_of(args.candidate_set, args.sim)
    except ValueError as exc:
        print(f"error: --candidate-set {exc}", file=sys.stderr)
        return 2
    print(
        "| ground | episodes | baseline: violations, takeover | candidate: violations, takeover "
        "| difference in violation share [95%] | takeover difference | rule |"
    )
    print("|---|---|---|---|---|---|---|")
    table = None
    if args.baseline_table is not None:
        if not args.baseline_table.is_file():
            print(f"error: no table {args.baseline_table}", file=sys.stderr)
            return 2
        table = args.baseline_table.read_text()
    for ground, (scenarios, episodes) in grounds.items():
        if episodes <= 0:
            continue
        points = []
        if table is not None:
            point = table_point(table, args.baseline, ground, scenarios)
            if point is None or point[1] != episodes:
                print(
                    f"error: {args.baseline_table} has no {ground} gate row of {episodes} episodes on "
                    f"{', '.join(scenarios)} for {args.baseline}",
                    file=sys.stderr,
                )
                return 2
            points.append(point)
        measured_rows: list[tuple[str, Path | None, dict[str, Any] | None]] = [
            (args.candidate, args.candidate_cache, settings)
        ]
        if table is None:
            measured_rows.insert(0, (args.baseline, args.baseline_cache, None))
        for run, cache, gate_settings in measured_rows:
            rows = generalisation_table(
                run,
                args.sim,
                {ground: scenarios},
                episodes,
                episodes,
                cache=cache,
                cached_only=True,
                gate_settings=gate_settings,
            )
            gate = rows[0].gate if rows else {}
            if int(gate.get("episodes", 0)) != episodes:
                print(
                    f"error: {run} has {int(gate.get('episodes', 0))} of {episodes} {ground} gate episodes in {cache}",
                    file=sys.stderr,
                )
                return 2
            violations, measured = rows[0].gate_violations
            points.append((violations, measured, float(gate["takeover_rate"])))
        (low, high), rise, reading = verdict(ground, points[1], points[0])
        if table is not None:
            # the table's takeover is rounded to a whole percent: a reading it could flip is not a reading
            violations, measured, takeover = points[0]
            readings = {verdict(ground, points[1], (violations, measured, takeover + d))[2] for d in (-0.005, 0.005)}
            if readings != {reading}:
                reading = f"undecided (the baseline's takeover is rounded: {' / '.join(sorted(readings))})"
        print(
            f"| {ground} | {episodes} | {points[0][0]} ({points[0][2]:.0%}) | {points[1][0]} ({points[1][2]:.0%}) "
            f"| [{low:+.3f}, {high:+.3f}] | {rise:+.1f} points | {reading} |"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
