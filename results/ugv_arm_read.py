"""One method's success in an arm's UGV study against the same method in a base study, paired by seed.

    .venv/bin/python results/ugv_arm_read.py ARM_FOLDER BASE_FOLDER [METHOD] > READING.md

Per scenario: both means and the arm minus the base, 95% t-interval over the seeds both ran (the reading of
results/ugv-30k-bc10.sh, written before its run, decides from scenario 3's row).
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "results"))

from ugv_budget_read import SCENARIOS, success  # noqa: E402

from studies.stats import mean_ci  # noqa: E402


def main() -> None:
    arm, base = Path(sys.argv[1]), Path(sys.argv[2])
    method = sys.argv[3] if len(sys.argv) > 3 else "sage"
    a, b = success(arm), success(base)
    print(f"# {method}: {arm.name} against {base.name}, paired by seed\n")
    print("Made by `python results/ugv_arm_read.py " + " ".join(sys.argv[1:]) + "`.\n")
    print(f"| scenario | {arm.name}: per seed | mean | {base.name}: per seed | mean | difference [95%] |")
    print("|---|---|---|---|---|---|")
    for scenario in SCENARIOS:
        x, y = a.get((scenario, method), {}), b.get((scenario, method), {})
        seeds = sorted(set(x) & set(y))
        if not seeds:
            print(f"| {scenario} | not measured | – | – | – | – |")
            continue
        diff = mean_ci([x[s] - y[s] for s in seeds])
        print(
            f"| {scenario} | {', '.join(f'{x[s]:.0f}' for s in seeds)} | {sum(x[s] for s in seeds) / len(seeds):.1f} | "
            f"{', '.join(f'{y[s]:.0f}' for s in seeds)} | {sum(y[s] for s in seeds) / len(seeds):.1f} | "
            f"{diff.mean:+.1f} [{diff.low:+.1f}, {diff.high:+.1f}] |"
        )


if __name__ == "__main__":
    main()
