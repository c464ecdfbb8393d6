"""More episodes where a measured operating curve left fear undecided against a comparison gating.

    .venv/bin/python -m experiments.curve_extend \\
        docs/notes/calibration_highway_defensive/highway-default-test-adversarial \\
        --at-rates 0.47 0.56 --episodes 3000 [--chunk 250] [--against 'curiosity only'] [--out DIR] \\
        [--readme FILE --block NAME] [--cpus N | --address HOST:PORT]

Reads the curve of a ``report.json`` that ``experiments/calibration.py`` wrote, takes fear's points nearest to
``--at-rates`` and each comparison gating's point that :func:`studies.calibrate.compare_curves` matched to them
(:class:`studies.calibrate.CurveExtension`), and runs each again at its own knob (τ's scale, the random firing share,
the curiosity level) on ``--episodes`` new episodes: the evaluation seeds after the curve's, the same for every point.
Where a gating had no point within 5 points of fear's, one at the knob interpolated between its two points around
fear's rate, on the new episodes alone. Prints and writes (``--out``, default ``docs/notes/curve_extension``) each pair
on the new episodes alone and pooled with the curve's, with the 95% interval of the difference in the share of
episodes with a violation (Newcombe's); the verdict is the pooled one's. Pooling follows a first look that left the
points undecided, so the pooled interval's 5% is nominal (two looks); the new episodes' own interval is the one that
no earlier look touched.

Each ``--chunk`` of a point's episodes is a Ray task (:func:`studies.sweep.run_tasks`) that writes its result to
``OUT/chunks/``; a rerun with the same arguments runs only the chunks not there (resumable). Not a unit test: at
1000 episodes a point, highway's points take about 400 s of one core each.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import time
from pathlib import Path
from typing import Any

import torch

import sims
from studies.calibrate import (
    CurveExtension,
    ExtendedPoint,
    curve_point,
    extension_rows,
    pool_points,
    violation_interval,
)
from studies.readme import publish
from studies.sweep import run_tasks

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("report", type=Path, help="a case's folder of experiments/calibration.py (or its report.json)")
    parser.add_argument("--at-rates", type=float, nargs="+", required=True, help="fear's takeover rates to extend")
    parser.add_argument("--episodes", type=int, required=True, help="new episodes a point")
    parser.add_argument("--chunk", type=int, default=250, help="episodes a Ray task")
    parser.add_argument(
        "--against",
        nargs="+",
        default=["random", "curiosity only"],
        choices=["random", "curiosity only"],
        help="the comparison gatings to extend beside fear (default: both)",
    )
    parser.add_argument("--policy", type=Path, help="the policy (default: policies/<the report's run's name>)")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "notes" / "curve_extension")
    parser.add_argument("--readme", type=Path, help="also copy the table into this file's --block")
    parser.add_argument("--block", default="curve-extension")
    parser.add_argument("--cpus", type=int, help="cores for local Ray (default: all of them)")
    parser.add_argument("--address", help="join the Ray cluster at this address instead of starting one")
    args = parser.parse_args()
    path = args.report / "report.json" if args.report.is_dir() else args.report
    if not path.is_file():
        parser.error(f"{path}: no report.json (experiments/calibration.py writes one per case)")
    if args.episodes < 1 or args.chunk < 1:
        parser.error("--episodes and --chunk must be at least 1")
    report = json.loads(path.read_text())
    curve = report.get("curve")
    if not curve:
        parser.error(f"{path}: the report has no operating curve")
    policy = args.policy or ROOT / "policies" / Path(report["run"]).name
    if not (policy / "checkpoint.pt").is_file():
        parser.error(f"{policy}: no checkpoint.pt (give --policy)")
    extension = CurveExtension(args.at_rates, tuple(args.against))
    try:
        points = extension.points(curve)
    except ValueError as error:
        parser.error(str(error))
    first = CurveExtension.first_seed(curve)
    torch.set_num_threads(1)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout
    chunks_dir = args.out / "chunks"
    chunks_dir.mkdir(parents=True, exist_ok=True)
    starts = list(range(first, first + args.episodes, args.chunk))
    todo = [
        {
            "policy": str(policy),
            "sim": report["sim"],
            "scenario": report["scenario"],
            "episodes": min(args.chunk, first + args.episodes - start),
            "call": point.call(),
            "first_seed": start,
            "path": str(chunks_dir / chunk_name(point, start)),
        }
        for point in points
        for start in starts
    ]
    left = [task for task in todo if not Path(task["path"]).is_file()]
    print(f"{len(points)} points, {len(todo)} chunks of up to {args.chunk} episodes, {len(left)} to run", flush=True)
    if left:
        run_tasks(
            run_chunk,
            left,
            [f"{t['call']['kind']} at knob {t['call']['knob']:.4g}, seeds from {t['first_seed']}" for t in left],
            address=args.address,
            cpus=args.cpus,
        )
    fresh, seconds = [], 0.0
    for point in points:
        parts = [json.loads((chunks_dir / chunk_name(point, start)).read_text()) for start in starts]
        seconds += sum(part.pop("seconds") for part in parts)
        fresh.append(pool_points(parts))
    rows = extension_rows(points, fresh)
    command = (
        f"python -m experiments.curve_extend {args.report.as_posix()} --at-rates "
        + " ".join(f"{r:g}" for r in args.at_rates)
        + f" --episodes {args.episodes}"
        + (" --against " + " ".join(f"'{a}'" for a in args.against) if len(args.against) < 2 else "")
    )
    lines = table(rows, report, command, commit.strip(), first, args.episodes, seconds)
    (args.out / "extension.json").write_text(
        json.dumps({"points": [vars(p) for p in points], "new": fresh, "rows": rows}, indent=1, default=float)
    )
    publish(lines, args.out, args.readme, args.block, "## Calibration")


def chunk_name(point: ExtendedPoint, start: int) -> str:
    return f"{point.kind.replace(' ', '_').replace('(', '').replace(')', '')}-{point.knob:.6g}-{start}.json"


def run_chunk(
    policy: str, sim: str, scenario: str, episodes: int, call: dict[str, Any], first_seed: int, path: str
) -> None:
    """One chunk of a point's new episodes, written to ``path`` (with its seconds of one core)."""
    d = sims.descriptor(sim)
    started = time.perf_counter()
    result = curve_point(policy, lambda: d.make(scenario), episodes, call, first_seed=first_seed)
    result["seconds"] = time.perf_counter() - started
    Path(path).write_text(json.dumps(result, default=float))


def _count(point: dict[str, float] | None) -> str:
    if point is None:
        return "–"
    n = int(point["episodes"])
    k = round(point["violation_rate"] * n)
    return f"{k}/{n} at {point['takeover_rate']:.1%}"


def _interval(bounds: tuple[float, float]) -> str:
    low, high = bounds
    return "–" if math.isnan(low) else f"{low * 100:+.1f} to {high * 100:+.1f}"


def table(
    rows: list[dict[str, Any]],
    report: dict[str, Any],
    command: str,
    commit: str,
    first: int,
    episodes: int,
    seconds: float,
) -> list[str]:
    lines = [
        f"# More episodes at the operating curve's undecided points ({report['sim']} {report['scenario']})",
        "",
        f"Generated by `{command}` at commit {commit}: each point again at its own knob on {episodes} new episodes "
        f"(evaluation seeds {first}-{first + episodes - 1}, after the curve's), pooled with the curve's own "
        f"episodes. {seconds:.0f} s of one core.",
        "",
        "| fear's takeover | against | fear: curve · new · pooled (episodes with a violation) | other: curve · new · "
        "pooled | fear − other, new episodes (points, 95%) | fear − other, pooled | verdict (pooled) |",
        "|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        fear, other = row["fear"], row["other"]
        lines.append(
            f"| {row['near']:.0%} | {row['against']} | "
            + " · ".join(_count(fear[k]) for k in ("prior", "new", "pooled"))
            + " | "
            + " · ".join(_count(other[k]) for k in ("prior", "new", "pooled"))
            + f" | {_interval(row['new_interval'])} | {_interval(row['pooled_interval'])} | {row['verdict']} |"
        )
    shares = []
    for row in rows:
        pooled = row["other"]["pooled"]
        low, high = violation_interval(pooled)
        shares.append(
            f"{row['against']} near {row['near']:.0%}: {pooled['violation_rate'] * 100:.1f}% "
            f"({low * 100:.1f}-{high * 100:.1f})"
        )
    lines += [
        "",
        "Curve: the report's own episodes at the point (– where the gating had no point within 5 points of fear's and "
        "one was made at the knob interpolated between its two around fear's rate). Verdict: better where the pooled "
        "interval lies wholly below 0 (fewer episodes with a violation under fear's gate), worse wholly above, tied "
        "otherwise; unmatched where the pooled takeover rates lie more than 5 points apart. The pooled interval "
        "follows a first look (the curve's) that left these points undecided, so its 5% is nominal; the new "
        "episodes' interval is untouched by that look.",
        "",
        "Pooled shares with a violation (95% Wilson): " + "; ".join(shares) + ".",
    ]
    return lines


if __name__ == "__main__":
    main()
