"""The paper's route-shift figure panels, drawn with matplotlib (no pyplot: figures are plain objects, saved to PNG).

- :func:`route_shift_rates` (the paper's Fig. sumo_1 b): success, collision and red-light violation rates over
  training episodes, a trailing moving average per run, several runs overlaid, the route switch marked.
- :func:`sage_signals` (Fig. sumo_1 c): SAGE's takeover frequency, mean fear and mean curiosity per episode.

Both return the :class:`~matplotlib.figure.Figure` (tests read its axes and lines); :func:`save` writes it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from studies.route_shift import StudyRun

RATE_PANELS = (("success", "Success rate"), ("collision", "Collision rate"), ("red_light", "Red-light violation rate"))
SIGNAL_PANELS = (
    ("takeover_rate", "Takeover frequency", "share of steps under expert control"),
    ("mean_fear", "Mean fear", "mean F over the episode"),
    ("mean_curiosity", "Mean curiosity", "mean C over the episode"),
)
METHOD_COLOURS = {"sage": "#d62728", "sac": "#1f77b4", "fni-rl": "#2ca02c", "td3": "#9467bd", "hg-dagger": "#8c564b"}
SWITCH_GID = "route-switch"
"""``gid`` of the vertical line marking the route switch (what tests look for)."""


def default_window(episodes: int) -> int:
    """Moving-average window: a tenth of the run, between 3 and 50 episodes (the paper's 1,500 episodes: 50)."""
    return int(max(3, min(50, episodes // 10)))


def trailing_mean(values: Sequence[float | None], window: int) -> np.ndarray:
    """Entry i averages the finite values among episodes max(0, i - window + 1) .. i (NaN when there are none)."""
    from studies.route_shift_schedule import rolling_rates

    rows = [{"v": v} for v in values]
    return rolling_rates(rows, ("v",), window)["v"]


def _column(rows: Sequence[dict[str, Any]], key: str) -> list[float | None]:
    out: list[float | None] = []
    for row in rows:
        value = row.get(key)
        out.append(float(value) if isinstance(value, int | float) and math.isfinite(float(value)) else None)
    return out


def _mark_switch(ax: Axes, switch: int, last: int) -> None:
    """A dashed line between the last C1 episode and the first C2 one (1-based x), C2 shaded, phases named."""
    x = switch + 0.5
    ax.axvline(x, color="0.25", linestyle="--", linewidth=1.2, gid=SWITCH_GID)
    ax.axvspan(x, last + 0.5, color="0.9", zorder=0)
    ax.text(x, 1.01, " route switch", transform=ax.get_xaxis_transform(), fontsize=8, color="0.25", va="bottom")
    ax.text(0.02, 0.97, "C1", transform=ax.transAxes, fontsize=9, color="0.35", va="top", ha="left")
    c2_x = x + 0.02 * last  # just right of the switch, in data units along x
    ax.text(c2_x, 0.97, "C2", transform=ax.get_xaxis_transform(), fontsize=9, color="0.35", va="top")


def route_shift_rates(runs: Sequence[StudyRun], window: int | None = None) -> Figure:
    """Success, collision and red-light rates (%) over training episodes, one line per run, the switch marked."""
    if not runs:
        raise ValueError("no runs to draw")
    switches = sorted({run.switch for run in runs})
    if len(switches) > 1:
        names = ", ".join(f"{run.path.name}: {run.switch}" for run in runs)
        raise ValueError(f"the runs switch routes after different numbers of episodes ({names}): overlay one schedule")
    longest = max(len(run.rows) for run in runs)
    window = window or default_window(longest)
    fig = Figure(figsize=(13.5, 4.4), layout="constrained")
    axes = fig.subplots(1, len(RATE_PANELS), sharex=True)
    for ax, (key, title) in zip(axes, RATE_PANELS, strict=True):
        for k, run in enumerate(runs):
            episodes = np.arange(1, len(run.rows) + 1)
            curve = 100.0 * trailing_mean(_column(run.rows, key), window)
            colour = METHOD_COLOURS.get(run.method, f"C{k}")
            ax.plot(episodes, curve, color=colour, linewidth=2.0, label=run.label)
        _mark_switch(ax, switches[0], longest)
        ax.set_title(title, pad=14)
        ax.set_xlabel("training episode")
        ax.set_ylabel("rate (%)")
        ax.set_xlim(0.5, longest + 0.5)
        ax.set_ylim(-3, 103)
        ax.grid(True, alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncols=max(1, len(runs)), fontsize=10, frameon=False)
    fig.suptitle(f"Route shift (SUMO): rates over training, trailing mean of {window} episodes", fontsize=12)
    return fig


def has_signals(run: StudyRun) -> bool:
    """Whether the run recorded fear (its rows carry finite ``mean_fear``): SAGE, FNI-RL, HG-DAgger."""
    return any(v is not None for v in _column(run.rows, "mean_fear"))


def sage_signals(run: StudyRun, window: int | None = None) -> Figure:
    """Takeover frequency, mean fear and mean curiosity per episode (thin) with their trailing mean (thick)."""
    window = window or default_window(len(run.rows))
    episodes = np.arange(1, len(run.rows) + 1)
    colour = METHOD_COLOURS.get(run.method, "C3")
    fig = Figure(figsize=(13.5, 4.4), layout="constrained")
    axes = fig.subplots(1, len(SIGNAL_PANELS), sharex=True)
    for ax, (key, title, ylabel) in zip(axes, SIGNAL_PANELS, strict=True):
        raw = _column(run.rows, key)
        values = np.array([np.nan if v is None else v for v in raw], dtype=float)
        scale = 100.0 if key == "takeover_rate" else 1.0
        ax.plot(episodes, scale * values, color=colour, alpha=0.3, linewidth=0.9, label="per episode")
        ax.plot(episodes, scale * trailing_mean(raw, window), color=colour, linewidth=2.2, label=f"mean of {window}")
        _mark_switch(ax, run.switch, len(run.rows))
        ax.set_title(title, pad=14)
        ax.set_xlabel("training episode")
        ax.set_ylabel(ylabel + (" (%)" if key == "takeover_rate" else ""))
        ax.set_xlim(0.5, len(run.rows) + 0.5)
        ax.grid(True, alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncols=2, fontsize=10, frameon=False)
    fig.suptitle(f"{run.label} internal signals over training ({run.path.name})", fontsize=12)
    return fig


def save(fig: Figure, path: Path, dpi: int = 120) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    return path


def write_figures(
    runs: list[StudyRun], out_dir: Path, window: int | None = None, prefix: str = "route_shift"
) -> list[Path]:
    """The paper's panels as PNG files in ``out_dir``: the rates of every run, and SAGE's signals for each run that
    has them. Returns the paths written."""
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    fig = route_shift_rates(runs, window=window)
    written.append(save(fig, out_dir / f"{prefix}_rates.png"))
    for run in runs:
        if has_signals(run):
            name = f"{prefix}_signals.png" if len(runs) == 1 else f"{prefix}_signals_{run.path.name}.png"
            written.append(save(sage_signals(run, window=window), out_dir / name))
    return written
