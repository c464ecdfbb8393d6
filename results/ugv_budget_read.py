"""The reading of results/ugv-30k.sh (written before its run): the UGV study at two budgets, from their seeds.csv.

    .venv/bin/python results/ugv_budget_read.py SMALL_FOLDER LARGE_FOLDER > results/ugv-30k-read.md

1. per scenario, SAGE's success minus each other learner's, paired by seed, 95% t-interval: wholly above 0, the
   paper's direction decided; wholly below, against it decided; else undecided; at both budgets;
2. every learner's success on the static scenarios 1-2 at both budgets (warm-start collapse);
3. SAGE's success per scenario against the paper's 100%.
"""

from __future__ import annotations

import csv
import sys
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from studies.stats import mean_ci  # noqa: E402

LEARNERS = ("sac", "td3", "hg-dagger", "multi-hug", "diffusion-bc", "diffusion-ql")
SCENARIOS = ("1", "2", "3", "4")


def success(folder: Path) -> dict[tuple[str, str], dict[int, float]]:
    """(scenario, method) -> seed -> success rate in %."""
    rows: dict[tuple[str, str], dict[int, float]] = defaultdict(dict)
    with open(folder / "seeds.csv", newline="") as f:
        for row in csv.DictReader(f):
            rows[(row["scenario"], row["method"])][int(row["seed"])] = float(row["success_rate_pct"])
    return rows


def verdict(low: float, high: float) -> str:
    if low > 0:
        return "paper's direction, decided"
    if high < 0:
        return "against the paper, decided"
    return "undecided"


def main() -> None:
    small, large = Path(sys.argv[1]), Path(sys.argv[2])
    # optional column names (default: the two budgets), e.g. two hosts at one budget
    first, second = sys.argv[3:5] if len(sys.argv) >= 5 else ("6,000", "30,000")
    budgets = {first: success(small), second: success(large)}
    print(f"# The UGV study: {first} against {second} ({small.name}, {large.name})\n")
    command = "python results/ugv_budget_read.py " + " ".join(sys.argv[1:])
    print(f"Made by `{command}` (the rule in results/ugv-30k.sh).\n")
    print("## 0. Success alone, mean over seeds (%), scenarios 1 / 2 / 3 / 4\n")
    print(f"| method | at {first} | at {second} |")
    print("|---|---|---|")
    for method in ("sage", *LEARNERS, "teb", "scripted"):
        cells = []
        for rows in budgets.values():
            means = [rows.get((scenario, method), {}) for scenario in SCENARIOS]
            shown = [f"{sum(m.values()) / len(m):.0f}" if m else "–" for m in means]
            cells.append(" / ".join(shown))
        print(f"| {method} | " + " | ".join(cells) + " |")
    print()
    print("## 1. SAGE's success minus each learner's, paired by seed (points of %, 95% t-interval)\n")
    print(f"| scenario | learner | at {first} | reading | at {second} | reading |")
    print("|---|---|---|---|---|---|")
    for scenario in SCENARIOS:
        for learner in LEARNERS:
            cells = []
            for rows in budgets.values():
                sage, other = rows.get((scenario, "sage"), {}), rows.get((scenario, learner), {})
                seeds = sorted(set(sage) & set(other))
                if len(seeds) < 2:
                    cells += ["not measured", "–"]
                    continue
                diff = mean_ci([sage[s] - other[s] for s in seeds])
                shown = f"{diff.mean:+.1f} [{diff.low:+.1f}, {diff.high:+.1f}] (n={diff.n})"
                cells += [shown, verdict(diff.low, diff.high)]
            print(f"| {scenario} | {learner} | " + " | ".join(cells) + " |")
    print("\n## 2. Success on the static scenarios 1-2 (mean ± 95% over seeds; the warm start drives both)\n")
    print(f"| scenario | method | at {first} | at {second} |")
    print("|---|---|---|---|")
    for scenario in ("1", "2"):
        for method in ("sage", *LEARNERS):
            cells = []
            for rows in budgets.values():
                seeds = rows.get((scenario, method), {})
                cells.append(mean_ci(list(seeds.values())).format(1) if seeds else "not measured")
            print(f"| {scenario} | {method} | " + " | ".join(cells) + " |")
    print("\n## 3. SAGE against the paper's 100% (mean ± 95% over seeds)\n")
    print(f"| scenario | at {first} | at {second} |")
    print("|---|---|---|")
    for scenario in SCENARIOS:
        cells = []
        for rows in budgets.values():
            seeds = rows.get((scenario, "sage"), {})
            cells.append(mean_ci(list(seeds.values())).format(1) if seeds else "not measured")
        print(f"| {scenario} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
