"""Read the sumo-contact run (results/generalisation/sumo-contact.sh) by its rule: the gate rows of the candidate and
the baseline from their caches (chunks of 10 episodes, the same seeds), the built-in rows from their JSON files, each
difference's 95% interval (core.metrics.difference_interval, candidate minus baseline)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from core.metrics import difference_interval  # noqa: E402

HERE = ROOT / "results" / "generalisation"


def gate_rows(cache: Path) -> dict[str, tuple[int, int, float]]:
    """Per ground (the unseen scenario, or 'seen'): (episodes with a violation, episodes, takeover rate)."""
    totals: dict[str, list[float]] = {}
    for key, chunk in json.loads(cache.read_text()).items():
        kind, _run, _sim, scenario, *_ = key.split("|")
        if kind != "gate":
            continue
        ground = scenario if scenario.startswith("sumo-shift") else "seen"
        n = chunk["episodes"]
        row = totals.setdefault(ground, [0.0, 0.0, 0.0, 0.0])
        row[0] += round(chunk["violation_rate"] * n)
        row[1] += n
        row[2] += chunk["takeover_rate"] * chunk["steps"]
        row[3] += chunk["steps"]
    return {g: (int(v), int(n), t / s if s else float("nan")) for g, (v, n, t, s) in totals.items()}


def line(name: str, cand: tuple[int, int, float], base: tuple[int, int, float]) -> str:
    low, high = difference_interval(cand[0], cand[1], base[0], base[1])
    return (
        f"| {name} | {cand[0]} of {cand[1]} at {cand[2]:.1%} | {base[0]} of {base[1]} at {base[2]:.1%} | "
        f"[{low:+.3f}, {high:+.3f}] | {100 * (cand[2] - base[2]):+.1f} |"
    )


def main() -> None:
    cand, base = gate_rows(HERE / "sumo-contact.json"), gate_rows(HERE / "sumo-baseline-16.json")
    print("| ground | candidate: violations at takeover | baseline | difference [95%] | takeover, points |")
    print("|---|---|---|---|---|")
    for ground in sorted(set(cand) & set(base)):
        print(line(ground, cand[ground], base[ground]))
    files = HERE / "sumo-contact-builtin-rows.json", HERE / "sumo-baseline-16-builtin-rows.json"
    if all(f.exists() for f in files):
        rows = [json.loads(f.read_text()) for f in files]
        for scenario in rows[0]:
            if scenario in rows[1]:
                c, b = rows[0][scenario], rows[1][scenario]
                as_row = [
                    (round(r["violation_rate"] * r["episodes"]), int(r["episodes"]), r["takeover_rate"]) for r in (c, b)
                ]
                print(line(f"built-in {scenario}", as_row[0], as_row[1]))


if __name__ == "__main__":
    main()
