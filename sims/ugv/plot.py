"""Pictures of episodes over the scenario map (matplotlib, Agg). Drawing only: the env never draws.

Everything is drawn from plain :mod:`core.scene` data recorded while running, so the same function
serves any simulator whose scene is top-down 2D.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from core.scene import Scene, Shape

OUTCOME_COLORS = {"success": "#2b7de0", "collision": "#d62728", "timeout": "#ff9f1c", "other": "#7f7f7f"}


@dataclass
class EpisodeTrace:
    """What one episode looked like: its first scene, the ego's path and the movers' paths."""

    first_scene: Scene
    ego: list[tuple[float, float]] = field(default_factory=list)
    movers: list[list[tuple[float, float]]] = field(default_factory=list)
    """Per step, the centres of the movers."""
    outcome: str = "other"

    def record(self, scene: Scene) -> None:
        ego = scene["ego"]
        self.ego.append((ego["x"], ego["y"]))
        # boxes and circles: the shapes with a centre (core.scene)
        self.movers.append([(m["x"], m["y"]) for m in scene["movers"] if m["kind"] in ("box", "circle")])


def _corners(shape: Any) -> np.ndarray:
    c, s = math.cos(shape["yaw"]), math.sin(shape["yaw"])
    hl, hw = shape["length"] / 2, shape["width"] / 2
    local = np.array([(hl, hw), (-hl, hw), (-hl, -hw), (hl, -hw)])
    return np.column_stack(
        [shape["x"] + c * local[:, 0] - s * local[:, 1], shape["y"] + s * local[:, 0] + c * local[:, 1]]
    )


def draw_shape(ax: Any, shape: Shape, alpha: float, zorder: int) -> None:
    from matplotlib.patches import Circle, Polygon

    # test shape["kind"] itself (not a copy of it): that is what narrows the shape to its TypedDict
    if shape["kind"] == "box":
        ax.add_patch(Polygon(_corners(shape), closed=True, color=shape["color"], alpha=alpha, lw=0, zorder=zorder))
    elif shape["kind"] == "circle":
        ax.add_patch(
            Circle((shape["x"], shape["y"]), shape["radius"], color=shape["color"], alpha=alpha, lw=0, zorder=zorder)
        )
    elif shape["kind"] == "polyline":
        pts = np.asarray(shape["points"], dtype=float)
        if shape.get("closed"):
            pts = np.vstack([pts, pts[:1]])
        ax.plot(pts[:, 0], pts[:, 1], color=shape["color"], lw=2.5, alpha=alpha, zorder=zorder, solid_capstyle="round")
    elif shape["kind"] == "polygon":
        ax.add_patch(
            Polygon(np.asarray(shape["points"]), closed=True, color=shape["color"], alpha=alpha, lw=0, zorder=zorder)
        )


def stops(xy: np.ndarray, min_steps: int, still: float = 0.005) -> list[tuple[float, float]]:
    """Where the path stood still (moves under ``still`` m per step) for at least ``min_steps`` steps."""
    if len(xy) < 2:
        return []
    moving = np.hypot(*np.diff(xy, axis=0).T) >= still
    found, run = [], 0
    for i, is_moving in enumerate([*moving, True]):
        if not is_moving:
            run += 1
            continue
        if run >= min_steps:
            found.append((float(xy[i, 0]), float(xy[i, 1])))
        run = 0
    return found


def plot_episodes(
    traces: Sequence[EpisodeTrace], out: str | Path, title: str = "", tick_every: int = 10, stop_steps: int = 5
) -> Path:
    """Draw every episode's path over the map (the first episode's layout solid, the others' faint),
    with a dot every ``tick_every`` steps (1 s at 10 Hz) and a square where the robot waited at least
    ``stop_steps`` steps."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    if not traces:
        raise ValueError("no episodes to plot")
    first = traces[0].first_scene
    xmin, ymin, xmax, ymax = first["bounds"]
    width = 9.0
    height = max(3.0, width * (ymax - ymin) / (xmax - xmin)) + 0.8
    fig, ax = plt.subplots(figsize=(width, height), dpi=120)
    for i, trace in enumerate(traces):
        scene = trace.first_scene
        faint = i > 0
        for shape in scene["static"]:
            if shape["kind"] == "polyline" and faint:
                continue  # walls do not move between episodes
            draw_shape(ax, shape, alpha=0.08 if faint else 0.9, zorder=1 if faint else 2)
        goal = scene.get("goal")
        if goal:
            draw_shape(ax, goal, alpha=0.12 if faint else 0.35, zorder=1)
    for trace in traces:
        if trace.movers and trace.movers[0]:
            paths = np.array([step for step in trace.movers if len(step) == len(trace.movers[0])])
            for m in range(paths.shape[1]):
                ax.plot(paths[:, m, 0], paths[:, m, 1], color="#e0812b", lw=0.8, alpha=0.25, ls=":", zorder=3)
    # the movers where the first episode started
    for shape in first["movers"]:
        draw_shape(ax, shape, alpha=0.5, zorder=3)
    for trace in traces:
        if not trace.ego:
            continue
        xy = np.asarray(trace.ego)
        color = OUTCOME_COLORS.get(trace.outcome, OUTCOME_COLORS["other"])
        ax.plot(xy[:, 0], xy[:, 1], color=color, lw=1.3, alpha=0.75, zorder=4)
        ticks = xy[::tick_every]  # one dot per second: where dots pile up the robot waited
        ax.plot(ticks[:, 0], ticks[:, 1], ".", color=color, ms=3, alpha=0.6, zorder=4)
        ax.plot(xy[0, 0], xy[0, 1], "o", color=color, ms=4, zorder=5)
        if trace.outcome == "collision":
            ax.plot(xy[-1, 0], xy[-1, 1], "x", color=color, ms=8, mew=2, zorder=6)
        for x, y in stops(xy, min_steps=stop_steps):
            ax.plot(x, y, "s", mfc="none", mec="#222222", ms=6, mew=1.2, zorder=6)
    ego = dict(first["ego"])
    ego["color"] = "#1f3b70"
    draw_shape(ax, ego, alpha=0.8, zorder=5)  # type: ignore[arg-type]

    counts = {k: sum(t.outcome == k for t in traces) for k in ("success", "collision", "timeout")}
    handles = [Line2D([], [], color=OUTCOME_COLORS[k], lw=2, label=f"{k} ({n})") for k, n in counts.items() if n]
    handles.append(Line2D([], [], color="#7f7f7f", marker=".", ls="", label="robot every 1 s"))
    if any(stops(np.asarray(t.ego), stop_steps) for t in traces if t.ego):
        handles.append(Line2D([], [], marker="s", mfc="none", mec="#222222", ls="", label="waited"))
    if any(t.movers and t.movers[0] for t in traces):
        handles.append(Line2D([], [], color="#e0812b", lw=1, ls=":", label="moving obstacle paths"))
    handles.append(Line2D([], [], marker="o", color="#2bb673", ls="", alpha=0.5, ms=10, label="goal region"))
    ax.legend(
        handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.08), ncol=len(handles), frameon=False, fontsize=8
    )
    ax.set_xlim(xmin - 0.2, xmax + 0.2)
    ax.set_ylim(ymin - 0.2, ymax + 0.2)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.grid(True, lw=0.3, alpha=0.4)
    ax.set_title(title or f"{len(traces)} episodes")
    fig.tight_layout()
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)
    plt.close(fig)
    return out
