"""Figures of a ``sage cycles`` run, drawn from what its session store recorded (matplotlib, no pyplot).

- :func:`trajectories` (the paper's Fig. field_test_1 d): the robot's paths over the deployment / fine-tuning
  cycles, one panel per repeated situation, one line per cycle coloured from the first cycle to the last; a
  wider band where the expert was in control, a cross where a collision ended the episode, a square where the
  robot stood still.
- :func:`cycle_signals` (Fig. field_test_1 c): fear, the curiosity-modulated threshold and the takeover intervals
  over time, for each episode of one chosen cycle.
- :func:`cycle_summary`: takeover rate, success and collision per cycle.
- :func:`improvement`: whether the policy got better: its success ALONE (no gate, no expert) on the cycle's scenario
  and on the unseen one, and the takeover rate under supervision, over the cycles (one line per method, the mean
  over its runs, with each run faint behind it).

Everything comes from plain scene data (:mod:`core.scene`, the ego's pose per step, the static layout per
episode) and the recorded signals, so any top-down 2D simulator draws the same way; shapes are drawn by the UGV
plot helpers (:mod:`sims.ugv.plot`).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib import colormaps
from matplotlib.colors import BoundaryNorm, ListedColormap
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from core.sessions import SessionStore
from sims.ugv.plot import draw_shape, stops

CYCLE_CMAP = "viridis"
TAKEOVER_COLOUR = "#a855f7"
FEAR_COLOUR = "#d62728"
THRESHOLD_COLOUR = "#1f77b4"
MAX_PANELS = 4


class EpisodePath:
    """One recorded episode as the figures need it."""

    def __init__(self, store: SessionStore, session: str, row: dict[str, Any]) -> None:
        self.episode = int(row["episode"])
        self.cycle = int(row["cycle"])
        self.version = int(row["version"])
        self.collision = bool(row.get("collision"))
        self.success = bool(row.get("success"))
        static, scenes = store.scenes(session, self.episode)
        arrays = store.steps(session, self.episode)
        self.static = static or {}
        self.first_scene = next((s for s in scenes if s), {})
        self.xy = np.array([(s["ego"]["x"], s["ego"]["y"]) for s in scenes if s and s.get("ego")], dtype=float)
        self.movers = [[(m["x"], m["y"]) for m in s.get("movers", []) if "x" in m] for s in scenes if s]
        self.t = arrays["t"]
        self.fear = arrays["fear"]
        self.threshold = arrays["threshold"]
        self.takeover = arrays["takeover"]
        self.actor = arrays["actor"]


def load_paths(store: SessionStore, session: str, episodes: list[dict[str, Any]]) -> list[EpisodePath]:
    return [EpisodePath(store, session, row) for row in episodes]


def _cycle_colours(cycles: int) -> tuple[ListedColormap, BoundaryNorm]:
    base = colormaps[CYCLE_CMAP]
    # stop short of viridis' pale yellow end, which vanishes on a white map
    cmap = ListedColormap([base(x) for x in np.linspace(0.0, 0.85, max(cycles, 1))])
    return cmap, BoundaryNorm(np.arange(0.5, cycles + 1.5), cmap.N)


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(first, last) index of every run of True values."""
    runs, start = [], None
    for i, value in enumerate([*mask.tolist(), False]):
        if value and start is None:
            start = i
        elif not value and start is not None:
            runs.append((start, i - 1))
            start = None
    return runs


def _draw_map(ax: Any, path: EpisodePath) -> None:
    for shape in path.static.get("static", []):
        draw_shape(ax, shape, alpha=0.9, zorder=2)
    goal = path.first_scene.get("goal")
    if goal:
        draw_shape(ax, goal, alpha=0.35, zorder=1)
    if path.movers and path.movers[0]:
        count = len(path.movers[0])
        tracks = np.array([step for step in path.movers if len(step) == count])
        for m in range(count):
            ax.plot(tracks[:, m, 0], tracks[:, m, 1], color="#e0812b", lw=1.0, alpha=0.45, ls=":", zorder=3)
        for shape in path.first_scene.get("movers", []):
            draw_shape(ax, shape, alpha=0.35, zorder=3)
    bounds = path.static.get("bounds") or path.first_scene.get("bounds")
    if bounds:
        xmin, ymin, xmax, ymax = bounds
        ax.set_xlim(xmin - 0.2, xmax + 0.2)
        ax.set_ylim(ymin - 0.2, ymax + 0.2)
    ax.set_aspect("equal")
    ax.grid(True, lw=0.3, alpha=0.4)


def trajectories(paths: list[EpisodePath], title: str = "") -> Figure:
    """The paths of every cycle, one panel per repeated situation (episode slot within a cycle)."""
    if not paths:
        raise ValueError("no episodes to draw")
    cycles = max(p.cycle for p in paths)
    per_cycle = max(sum(1 for p in paths if p.cycle == c) for c in range(1, cycles + 1))
    panels = min(per_cycle, MAX_PANELS)
    cmap, norm = _cycle_colours(cycles)
    bounds = paths[0].static.get("bounds") or [0, 0, 1, 1]
    aspect = (bounds[3] - bounds[1]) / max(bounds[2] - bounds[0], 1e-6)
    width = 6.2
    fig = Figure(figsize=(width * panels + 1.2, width * aspect + 1.6), layout="constrained")
    axes = np.atleast_1d(fig.subplots(1, panels, sharey=True))
    slots: dict[int, list[EpisodePath]] = {}
    for c in range(1, cycles + 1):
        for slot, path in enumerate(sorted((p for p in paths if p.cycle == c), key=lambda p: p.episode)):
            slots.setdefault(slot, []).append(path)
    for slot, ax in enumerate(axes):
        group = slots.get(slot, [])
        if not group:
            continue
        _draw_map(ax, group[0])
        for path in group:
            if len(path.xy) < 2:
                continue
            colour = cmap(norm(path.cycle))
            xy = path.xy
            for first, last in _runs(path.takeover[: len(xy)]):
                seg = xy[first : last + 2]
                ax.plot(seg[:, 0], seg[:, 1], color=TAKEOVER_COLOUR, lw=6, alpha=0.22, zorder=4, solid_capstyle="round")
            ax.plot(xy[:, 0], xy[:, 1], color=colour, lw=1.6, alpha=0.9, zorder=5)
            ax.plot(xy[0, 0], xy[0, 1], "o", color=colour, ms=3.5, zorder=6)
            if path.collision:
                ax.plot(xy[-1, 0], xy[-1, 1], "x", color="#d62728", ms=9, mew=2.2, zorder=7)
            for x, y in stops(xy, min_steps=5):
                ax.plot(x, y, "s", mfc="none", mec=colour, ms=6, mew=1.2, zorder=6)
        ax.set_title(f"situation {slot + 1} (episode seed +{slot})", fontsize=10)
        ax.set_xlabel("x (m)")
    axes[0].set_ylabel("y (m)")
    mappable = _scalar_mappable(cmap, norm)
    bar = fig.colorbar(mappable, ax=list(axes), shrink=0.85, pad=0.01, ticks=range(1, cycles + 1))
    bar.set_label("deployment / fine-tuning cycle")
    handles = [
        Line2D([], [], color=TAKEOVER_COLOUR, lw=6, alpha=0.35, label="expert in control (takeover)"),
        Line2D([], [], color="#d62728", marker="x", ls="", mew=2, label="collision"),
        Line2D([], [], color="0.3", marker="s", mfc="none", ls="", label="stood still ≥ 0.5 s"),
        Line2D([], [], color="#e0812b", ls=":", label="moving obstacle"),
        Patch(color="#2bb673", alpha=0.35, label="goal"),
    ]
    fig.legend(handles=handles, loc="outside lower center", ncol=len(handles), frameon=False, fontsize=9)
    fig.suptitle(title or f"Trajectories over {cycles} deployment / fine-tuning cycles", fontsize=12)
    return fig


def _scalar_mappable(cmap: ListedColormap, norm: BoundaryNorm) -> Any:
    from matplotlib.cm import ScalarMappable

    return ScalarMappable(norm=norm, cmap=cmap)


def cycle_signals(paths: list[EpisodePath], cycle: int, dt: float = 0.1) -> Figure:
    """Fear, threshold and takeover intervals over time for each episode of ``cycle``."""
    group = sorted((p for p in paths if p.cycle == cycle), key=lambda p: p.episode)
    if not group:
        known = sorted({p.cycle for p in paths})
        raise ValueError(f"no cycle {cycle} in this run (cycles {known[0]}-{known[-1]})" if known else "no episodes")
    rows = min(len(group), MAX_PANELS)
    fig = Figure(figsize=(11.0, 1.0 + 2.2 * rows), layout="constrained")
    axes = np.atleast_1d(fig.subplots(rows, 1, sharex=True))
    top = max(
        [float(np.nanmax(v)) for p in group for v in (p.fear, p.threshold) if len(v) and np.isfinite(v).any()] or [1.0]
    )
    for ax, path in zip(axes, group, strict=False):
        time_s = path.t * dt
        for first, last in _runs(path.takeover):
            ax.axvspan(time_s[first] - dt / 2, time_s[last] + dt / 2, color=TAKEOVER_COLOUR, alpha=0.22, lw=0)
        ax.plot(time_s, path.fear, color=FEAR_COLOUR, lw=1.6, label="fear F")
        ax.plot(time_s, path.threshold, color=THRESHOLD_COLOUR, lw=1.3, ls="--", label="threshold τ")
        outcome = "collision" if path.collision else "success" if path.success else "no goal"
        share = float(np.mean(path.takeover)) if len(path.takeover) else math.nan
        ax.set_title(f"episode {path.episode}: {outcome}, takeover {100 * share:.0f}% of steps", fontsize=9, loc="left")
        ax.set_ylabel("fear / τ")
        ax.set_ylim(0, top * 1.08)
        ax.grid(True, alpha=0.3)
    axes[-1].set_xlabel("time (s)")
    handles = [
        Line2D([], [], color=FEAR_COLOUR, lw=1.6, label="fear F (m-step)"),
        Line2D([], [], color=THRESHOLD_COLOUR, lw=1.3, ls="--", label="threshold τ (curiosity-modulated)"),
        Patch(color=TAKEOVER_COLOUR, alpha=0.3, label="expert takeover"),
    ]
    axes[0].legend(handles=handles, loc="upper right", fontsize=8, framealpha=0.9)
    fig.suptitle(f"Cycle {cycle} (policy v{group[0].version:04d}): fear, threshold and takeovers", fontsize=12)
    return fig


def cycle_summary(rows: list[dict[str, Any]]) -> Figure:
    """Takeover rate per cycle (bars), success and collision rates (lines)."""
    if not rows:
        raise ValueError("no cycles to draw")
    cycles = [int(r["cycle"]) for r in rows]
    cmap, norm = _cycle_colours(max(cycles))
    fig = Figure(figsize=(8.0, 3.9), layout="constrained")
    ax = fig.subplots()
    rates = [100 * float(r["takeover_rate"]) for r in rows]
    ax.bar(cycles, rates, color=[cmap(norm(c)) for c in cycles], alpha=0.85, label="takeover rate (steps)")
    for c, rate, row in zip(cycles, rates, rows, strict=True):
        ax.text(c, rate, f"v{int(row['version'])}", ha="center", va="bottom", fontsize=7, color="0.3")
    ax.set_ylim(0, max(rates) * 1.15 + 1)  # room for the version labels
    ax.set_xlabel("cycle")
    ax.set_ylabel("takeover rate (% of steps)")
    ax.set_xticks(cycles)
    ax.grid(True, axis="y", alpha=0.3)
    twin = ax.twinx()
    for key, colour, marker in (("success", "#2b7de0", "o"), ("collision", "#d62728", "x")):
        values = [100 * float(r[key]) if r.get(key) is not None else np.nan for r in rows]
        twin.plot(cycles, values, color=colour, marker=marker, lw=1.4, label=f"{key} rate")
    twin.set_ylabel("success / collision (% of episodes)")
    twin.set_ylim(-5, 105)
    lines = ax.get_legend_handles_labels()
    more = twin.get_legend_handles_labels()
    fig.legend(lines[0] + more[0], lines[1] + more[1], loc="outside lower center", ncol=3, frameon=False, fontsize=8)
    fig.suptitle("Takeover rate, success and collision per deployment / fine-tuning cycle", fontsize=11)
    return fig


METHOD_COLOURS = ("#2b7de0", "#7f7f7f", "#d62728", "#2ca02c", "#9467bd")


def improvement(runs: dict[str, list[dict[str, Any]]]) -> Figure:
    """Alone success (the cycle's scenario solid, the unseen one dashed) and supervised takeover rate per cycle;
    ``runs``: method -> the ``cycles.json`` of each of its runs (seeds)."""
    if not runs:
        raise ValueError("no runs to draw")
    fig = Figure(figsize=(10.0, 3.9), layout="constrained")
    alone_ax, takeover_ax = fig.subplots(1, 2)
    most = max((len(d["cycles"]) for datas in runs.values() for d in datas), default=1)
    for i, (method, datas) in enumerate(sorted(runs.items(), key=lambda item: item[0] != "sage")):
        colour = METHOD_COLOURS[i % len(METHOD_COLOURS)]
        for key, ax, style, label in (
            ("alone_success", alone_ax, "-", f"{method}: scenario"),
            ("unseen_success", alone_ax, "--", f"{method}: unseen"),
            ("takeover_rate", takeover_ax, "-", method),
        ):
            curves = [[100 * float(r[key]) if r.get(key) is not None else np.nan for r in d["cycles"]] for d in datas]
            if not curves or all(np.isnan(v) for curve in curves for v in curve):
                continue
            length = max(len(c) for c in curves)
            padded = np.full((len(curves), length), np.nan)
            for row, curve in enumerate(curves):
                padded[row, : len(curve)] = curve
            cycles = np.arange(1, length + 1)
            if len(curves) > 1:
                for line in padded:
                    ax.plot(cycles, line, color=colour, ls=style, lw=0.6, alpha=0.25)
            ax.plot(cycles, np.nanmean(padded, axis=0), color=colour, ls=style, lw=1.8, marker="o", ms=3, label=label)
    alone_ax.set_ylabel("success alone (% of episodes)")
    alone_ax.set_ylim(-5, 105)
    alone_ax.set_title("the policy alone: no gate, no expert", fontsize=10)
    takeover_ax.set_ylabel("takeover rate (% of steps)")
    takeover_ax.set_title("under supervision", fontsize=10)
    for ax in (alone_ax, takeover_ax):
        ax.set_xlabel("cycle")
        ax.set_xticks(range(1, most + 1))
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("Does the policy get better over the deployment / fine-tuning cycles?", fontsize=11)
    return fig


def save(fig: Figure, path: Path, dpi: int = 110) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    return path


def write_figures(out: Path, data: dict[str, Any], show_cycles: list[int], figures: Path | None = None) -> list[Path]:
    """Draw the figures of the run in ``out`` (its ``cycles.json`` is ``data``) into ``figures``: the trajectories,
    the signals of each cycle in ``show_cycles``, the summary, and the improvement (where the run measured the
    policy alone)."""
    figures = Path(figures or out)
    store = SessionStore(Path(out) / "sessions")
    paths = load_paths(store, data["session"], data["episodes"])
    info = store.info(data["session"])
    dt = float(info.meta.get("dt", 0.1))
    title = f"{info.sim} scenario {info.scenario}: trajectories over {max(p.cycle for p in paths)} cycles"
    written = [save(trajectories(paths, title), figures / "trajectories.png")]
    for cycle in show_cycles:
        written.append(save(cycle_signals(paths, cycle, dt), figures / f"signals_cycle{cycle}.png"))
    written.append(save(cycle_summary(data["cycles"]), figures / "cycles_summary.png"))
    if any(row.get("alone_success") is not None for row in data["cycles"]):
        written.append(save(improvement({"this run": [data]}), figures / "improvement.png"))
    return written
