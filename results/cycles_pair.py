"""Read two cycles runs side by side, seed by seed: an arm against its control (their ``seeds.csv``).

    .venv/bin/python results/cycles_pair.py CONTROL_FOLDER ARM_FOLDER

Prints, per column issue 62's rules read (alone and unseen success, takeover, static success after the last cycle,
collision cycles above the first), each seed's value in both runs, the means, and how many of the arm's seeds are
lower than their control seed. It decides nothing: the rule is in the arm's script."""

from __future__ import annotations

import csv
import sys
from pathlib import Path

COLUMNS = (
    "alone_success_last",
    "unseen_success_last",
    "takeover_last",
    "static_success_last",
    "collision_cycles_above_first",
)


def rows(folder: Path) -> dict[int, dict[str, float]]:
    with (folder / "seeds.csv").open() as f:
        return {
            int(r["seed"]): {k: float(r[k]) for k in COLUMNS if r.get(k) not in (None, "")}
            for r in csv.DictReader(f)
            if r["method"] == "sage"
        }


def main(control: Path, arm: Path) -> None:
    a, b = rows(control), rows(arm)
    seeds = sorted(set(a) & set(b))
    print(f"control {control}, arm {arm}; seeds in both: {seeds}")
    for column in COLUMNS:
        pairs = [(a[s].get(column), b[s].get(column)) for s in seeds]
        pairs = [(x, y) for x, y in pairs if x is not None and y is not None]
        if not pairs:
            continue
        mean_a = sum(x for x, _ in pairs) / len(pairs)
        mean_b = sum(y for _, y in pairs) / len(pairs)
        total = column == "collision_cycles_above_first"
        lower = sum(y < x for x, y in pairs)
        cells = ", ".join(f"{y:.3g} ({x:.3g})" for x, y in pairs)
        summary = f"sum {sum(y for _, y in pairs):g} ({sum(x for x, _ in pairs):g})" if total else ""
        print(f"{column}: arm {mean_b:.3f} vs control {mean_a:.3f} {summary}; arm lower on {lower}; by seed {cells}")


if __name__ == "__main__":
    main(Path(sys.argv[1]), Path(sys.argv[2]))
