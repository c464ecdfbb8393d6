"""A study's results folder: per-seed rows, a mean ± 95% CI table with the paper's numbers beside, figures.

Written by the study command, never by hand:

- ``seeds.csv``: one row per (row key, training seed) with every metric, as measured.
- ``table.md``: one row per key (method, or split/method/condition), each metric as mean ± 95% t-interval
  over seeds, and the paper's reported number in the next column where it has one; the header names the
  study, the budget, the commit, the wall time and the device the learners' updates ran on.
- ``summary.json``: the same table as data (mean, half-width, n, paper value).
- ``<metric>.png``: per-key means with their 95% intervals, one figure per plotted metric.
"""

from __future__ import annotations

import csv
import json
import math
import subprocess
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from studies.budgets import Budget
from studies.paper import paper_value
from studies.stats import Interval, mean_ci


def current_commit(repo: Path | None = None) -> str:
    """The short commit id of the code that produced the results (``unknown`` outside a git checkout)."""
    try:
        out = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=repo, capture_output=True, text=True, check=True
        )
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return out.stdout.strip() or "unknown"


NO_DEVICE = "device not recorded"
"""What a table says of the device where its folder does not record one (written before tables named it)."""


def wall_and_device(wall_s: float, device: str | None) -> str:
    """``wall time 4.1 min on the CPU (AMD EPYC)``, or ``..., device not recorded``: the table header's timing."""
    return f"wall time {wall_s / 60:.1f} min " + (f"on {device}" if device else f"({NO_DEVICE})")


def summarise(
    rows: Sequence[Mapping[str, Any]], keys: Sequence[str], metrics: Sequence[str]
) -> dict[tuple[str, ...], dict[str, Interval]]:
    """Mean ± 95% CI of each metric over the seeds of each row key, keys in order of first appearance. A NaN value
    is a metric that does not apply to that seed (e.g. a takeover share of a method that never hands over): the
    interval is over the seeds that have it (n says how many), an undefined one (NaN mean, n 0) where none has."""
    groups: dict[tuple[str, ...], list[Mapping[str, Any]]] = {}
    for row in rows:
        missing = [k for k in (*keys, "seed", *metrics) if k not in row]
        if missing:
            raise ValueError(f"result row {dict(row)} lacks {missing}")
        groups.setdefault(tuple(str(row[k]) for k in keys), []).append(row)
    return {key: {m: _applicable_ci([r[m] for r in group]) for m in metrics} for key, group in groups.items()}


def _applicable_ci(values: Sequence[Any]) -> Interval:
    applicable = [float(v) for v in values if not math.isnan(float(v))]
    return mean_ci(applicable) if applicable else Interval(math.nan, math.nan, 0)


NOT_APPLICABLE = "–"
"""A table cell whose metric no seed of the row has (it does not apply there)."""


def format_cell(cell: Interval, seeds: int) -> str:
    """``mean ± half`` at three digits; ``–`` where no seed has the metric; ``(n=k)`` after it where only ``k`` of
    the row's ``seeds`` have it."""
    if cell.n == 0:
        return NOT_APPLICABLE
    text = cell.format(3)
    return text if cell.n == seeds or cell.n == 1 else f"{text} (n={cell.n})"


def write_results(
    out: Path,
    study: str,
    rows: Sequence[Mapping[str, Any]],
    keys: Sequence[str],
    metrics: Sequence[str],
    budget: Budget,
    wall_s: float,
    commit: str | None = None,
    plot: Sequence[str] = (),
    notes: Sequence[str] = (),
    budget_text: str | None = None,
    untrained: Sequence[str] = (),
    device: str | None = None,
    host_speed: Mapping[str, Any] | None = None,
) -> Path:
    """Write the results folder ``out`` for ``study`` and return the table's path.

    ``keys`` name a row (``("method",)`` or ``("split", "method", "condition")``), matched against the
    paper's table by :func:`studies.paper.paper_value`; ``plot`` lists the metrics to draw; ``notes`` are
    printed under the table (what could not be run, and why). ``budget_text``: what the budget ran, when the study
    spends it otherwise than as training steps and evaluation episodes (the cycles study: cycles of episodes).
    ``untrained``: methods that are not trained (planners): each of their seeds is a set of evaluation episodes, so
    their ± is a spread over evaluation episodes, and their rows say so. ``device``: what ran the learners' updates, in
    words (``the CPU (AMD EPYC)``, ``CUDA:0 (NVIDIA H200)``); the header says where it was not recorded.
    ``host_speed``: the host's reference speed before the trials (:class:`studies.host_speed.HostSpeed`), kept in
    ``summary.json`` beside the wall time.
    """
    if not rows:
        raise ValueError(f"study {study!r} produced no result rows")
    out.mkdir(parents=True, exist_ok=True)
    commit = commit or current_commit()
    columns = [*keys, "seed", *metrics]
    with (out / "seeds.csv").open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)
    summary = summarise(rows, keys, metrics)

    header = [*keys, "seeds"]
    for m in metrics:
        header += [m, f"paper {m}"]
    spent = budget_text or (
        f"{budget.train_steps} environment steps per method and seed, {budget.eval_episodes} evaluation episodes"
    )
    planners = [m for m in dict.fromkeys(str(r.get("method")) for r in rows) if m in untrained]
    untrained_text = (
        f" {', '.join(planners)}: not trained, so their seeds are only different evaluation episodes and their ± "
        "(seeds column: eval) is a spread over evaluation episodes."
        if planners
        else ""
    )
    lines = [
        f"# {study}: mean ± 95% CI over training seeds",
        "",
        f"Budget `{budget.name}` ({spent}), commit `{commit}`, {wall_and_device(wall_s, device)}. "
        f"Paper columns are the paper's reported values (± is its spread over episodes, not a CI).{untrained_text}",
        "",
        "| " + " | ".join(header) + " |",
        "|" + "---|" * len(header),
    ]
    data: list[dict[str, Any]] = []
    for key, cells in summary.items():
        n = max(cell.n for cell in cells.values())
        method = dict(zip(keys, key, strict=True)).get("method")
        row_text = [*key, f"{n} eval" if method in planners else str(n)]
        entry: dict[str, Any] = {**dict(zip(keys, key, strict=True)), "seeds": n, "metrics": {}}
        for m in metrics:
            paper = paper_value(study, key, m)
            row_text += [format_cell(cells[m], n), paper.format() if paper else "—"]
            entry["metrics"][m] = {
                "mean": cells[m].mean,  # NaN (JSON's NaN, as a single seed's half-width) where it does not apply
                "ci95_half_width": cells[m].half_width,
                "paper": None if paper is None else {"mean": paper.mean, "spread": paper.spread},
            }
        lines.append("| " + " | ".join(row_text) + " |")
        data.append(entry)
    lines += ["", *[f"- {note}" for note in notes]]
    table = out / "table.md"
    table.write_text("\n".join(lines).rstrip() + "\n")
    meta: dict[str, Any] = {"study": study, "budget": budget.name, "commit": commit, "wall_s": wall_s, "device": device}
    if host_speed is not None:
        meta["host_speed"] = dict(host_speed)
    meta["rows"] = data
    (out / "summary.json").write_text(json.dumps(meta, indent=2, default=float))
    for metric in plot:
        _plot(out / f"{metric}.png", study, summary, metric)
    return table


def _plot(path: Path, study: str, summary: Mapping[tuple[str, ...], Mapping[str, Interval]], metric: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = ["/".join(k) for k in summary]
    means = [cells[metric].mean for cells in summary.values()]
    errors = [0.0 if cells[metric].n < 2 else cells[metric].half_width for cells in summary.values()]
    fig, ax = plt.subplots(figsize=(max(4.0, 0.8 * len(labels) + 2), 3.5))
    ax.bar(range(len(labels)), means, yerr=errors, capsize=4, color="#4c72b0")
    ax.set_xticks(range(len(labels)), labels, rotation=30, ha="right")
    ax.set_ylabel(metric)
    ax.set_title(f"{study}: {metric} (mean ± 95% CI over seeds)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
