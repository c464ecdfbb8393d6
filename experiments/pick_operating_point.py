"""Which τ scale does the operating-point rule of ``docs/notes/generalisation.md`` choose from a train-ground sweep?

Reads, measuring nothing, two JSON files that ``sage gate choose-scale --out`` wrote on the same train ground and
seeds: the baseline's (one row, its own scale) and the candidate's sweep (a row per scale). The rule: among the swept
scales whose takeover rate is at most the baseline's, the one with the fewest episodes with a violation; a tie goes to
the larger scale (less takeover). Where no scale's takeover is within the baseline's, none is chosen and scale 1
stays. ``choose-scale``'s own choice (the largest scale that meets a fixed target) answers a different question,
so its ``scale`` field is not read.

    python -m experiments.pick_operating_point --baseline results/generalisation/oppoint-baseline-train2.json \
        --sweep results/generalisation/oppoint-sweep-train2.json

prints the sweep's rows against the baseline's and the choice; ``--scale-only`` prints the chosen scale alone (for a
script's next stage).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from core.metrics import wilson_interval


def pick_scale(rows: Sequence[Mapping[str, Any]], baseline_takeover: float) -> float | None:
    """The rule's scale among ``rows`` (one per scale, choose-scale's row fields), or None where no row's takeover
    rate is at most ``baseline_takeover``."""
    within = [r for r in rows if float(r["takeover_rate"]) <= baseline_takeover]
    if not within:
        return None
    best = min(within, key=lambda r: (int(r["violations"]), -float(r["scale"])))
    return float(best["scale"])


def _rows(path: Path) -> list[dict[str, Any]]:
    data = json.loads(path.read_text())
    rows = data.get("rows") if isinstance(data, dict) else None
    if not rows:
        raise ValueError(f"{path} holds no choose-scale rows")
    if len({r["scenario"] for r in rows}) != 1:
        raise ValueError(f"{path}: the rule reads one scenario, these rows have several")
    return list(rows)


def _row_text(label: str, row: Mapping[str, Any], baseline_takeover: float, chosen: float | None) -> str:
    low, high = wilson_interval(int(row["violations"]), int(row["episodes"]))
    within = "yes" if float(row["takeover_rate"]) <= baseline_takeover else "no"
    mark = "chosen" if chosen is not None and float(row["scale"]) == chosen else ""
    return (
        f"| {label} | {row['violations']} of {row['episodes']} [{low:.0%}, {high:.0%}] | "
        f"{float(row['takeover_rate']):.1%} | {within} | {mark} |"
    )


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m experiments.pick_operating_point", description=__doc__.split("\n")[0]
    )
    parser.add_argument("--baseline", type=Path, required=True, help="choose-scale's JSON for the baseline (one row)")
    parser.add_argument("--sweep", type=Path, required=True, help="choose-scale's JSON for the candidate's sweep")
    parser.add_argument("--scale-only", action="store_true", help="print the chosen scale alone (1 where none is)")
    args = parser.parse_args(argv)
    try:
        baseline_rows, sweep_rows = _rows(args.baseline), _rows(args.sweep)
    except (OSError, ValueError, KeyError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if len(baseline_rows) != 1:
        print(f"error: {args.baseline} should hold one row (the baseline at its own scale)", file=sys.stderr)
        return 2
    base = baseline_rows[0]
    if base["scenario"] != sweep_rows[0]["scenario"] or base["episodes"] != sweep_rows[0]["episodes"]:
        print("error: the baseline and the sweep were not measured on the same scenario and episodes", file=sys.stderr)
        return 2
    takeover = float(base["takeover_rate"])
    chosen = pick_scale(sweep_rows, takeover)
    if args.scale_only:
        print(f"{chosen if chosen is not None else 1.0:g}")
        return 0
    print(f"{sweep_rows[0]['scenario']}, {base['episodes']} episodes a row (gate + scripted expert)")
    print()
    print("| gate | episodes with a violation [95%] | takeover | takeover within the baseline's | rule |")
    print("|---|---|---|---|---|")
    print(_row_text(f"baseline ({args.baseline.name})", base, takeover, None))
    for row in sorted(sweep_rows, key=lambda r: -float(r["scale"])):
        print(_row_text(f"tau_scale {float(row['scale']):g}", row, takeover, chosen))
    print()
    if chosen is None:
        print("chosen: none (no scale's takeover is within the baseline's); gate.tau_scale=1 stays")
    else:
        print(
            f"chosen: gate.tau_scale={chosen:g}, the fewest episodes with a violation at a takeover within the "
            "baseline's (a tie to the larger scale)"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
