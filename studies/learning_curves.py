"""Learning curves of a study's trials over environment steps, from their run folders (``<runs>/<method>-s<seed>``).

Budgets are in environment steps, so the x axis is too: each seed's trailing moving average of a training metric is
interpolated onto a common grid of steps, and the figure shows the mean over seeds with its 95% band, one line per
method. A method's curve ends where its shortest seed ended.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np

GRID = 60
"""Points on the environment-step axis."""


def train_rows(run: Path) -> list[dict[str, float]]:
    """The training episodes of a run folder (demonstrations excluded)."""
    file = run / "metrics.jsonl"
    if not file.is_file():
        return []
    rows = [json.loads(line) for line in file.read_text().splitlines() if line.strip()]
    return [row for row in rows if row.get("phase") == "train"]


def curve(runs_dir: Path, method: str, key: str, window: int = 10) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(environment steps, mean over seeds, 95% half-width) of the moving average of ``key``; None without data."""
    from studies.stats import mean_ci

    series = []
    for run in sorted(runs_dir.glob(f"{method}-s*")):
        rows = [r for r in train_rows(run) if key in r and "steps_done" in r]
        if len(rows) < 2:
            continue
        steps = np.array([float(r["steps_done"]) for r in rows])
        values = np.array([float(r[key]) for r in rows])
        smooth = np.array([values[max(0, i - window + 1) : i + 1].mean() for i in range(len(values))])
        series.append((steps, smooth))
    if not series:
        return None
    start = max(s[0] for s, _ in series)
    end = min(s[-1] for s, _ in series)
    if end <= start:
        return None
    grid = np.linspace(start, end, GRID)
    stacked = np.array([np.interp(grid, s, v) for s, v in series])
    stats = [mean_ci(stacked[:, i].tolist()) for i in range(GRID)]
    half = np.nan_to_num(np.array([s.half_width for s in stats]))  # one seed: no band
    return grid, np.array([s.mean for s in stats]), half


def write_learning_curves(
    runs_dir: Path, out: Path, methods: Sequence[str], keys: Sequence[str], name: str = "learning_curves.png"
) -> list[Path]:
    """One panel per metric in ``keys``, every method that has training episodes: the figure's path, or no path when
    no method has any (the shape a study's ``figures`` returns)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(keys), figsize=(4.6 * len(keys), 3.4), squeeze=False)
    drawn = False
    for ax, key in zip(axes[0], keys, strict=True):
        for method in methods:
            found = curve(runs_dir, method, key)
            if found is None:
                continue
            steps, mean, half = found
            ax.plot(steps, mean, label=method)
            ax.fill_between(steps, mean - half, mean + half, alpha=0.2)
            drawn = True
        ax.set_xlabel("environment steps (demonstrations included)")
        ax.set_ylabel(f"{key} (moving average of 10 episodes)")
        ax.grid(alpha=0.3)
    if not drawn:
        plt.close(fig)
        return []
    axes[0][0].legend(fontsize=8)
    fig.suptitle("training, mean over seeds with 95% band")
    fig.tight_layout()
    path = out / name
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return [path]
