"""The long-tail study's figure panels (the paper's Fig. carla_1 b-d), from the trials' run folders.

- ``reward.png`` (b): training return over episodes, per method: mean over seeds of a trailing moving average,
  with its 95% band.
- ``trajectories.png`` (c): the ego's path and the pedestrian's, replayed from checkpoints early, in the middle
  and late in training (first seed, one fixed crossing episode, the policy alone).
- ``safety_over_training.png`` (d): collisions, time-to-collision, speed and acceleration variability over
  training episodes, as in (b).
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

SNAPSHOT_SEED = 4_242_424
"""The crossing episode every snapshot replays (outside the training and evaluation seeds)."""
COLORS = {"d3qn": "#f97316", "sage-d3qn": "#2dd4bf"}


def read_rows(out: Path) -> list[dict[str, Any]]:
    """The training episodes of a run folder (demonstrations excluded)."""
    lines = (out / "metrics.jsonl").read_text().splitlines()
    return [row for row in map(json.loads, lines) if row.get("phase") == "train"]


def _runs(runs_dir: Path, method: str) -> list[Path]:
    return sorted(p for p in runs_dir.glob(f"{method}-s*") if (p / "checkpoint.pt").is_file())


def curves(runs_dir: Path, method: str, key: str, window: int) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(episode, mean, 95% half-width) over seeds of the trailing moving average of ``key``, up to the episode
    count every seed reached (budgets are in steps, so seeds differ in episodes)."""
    from studies.stats import mean_ci

    series = []
    for run in _runs(runs_dir, method):
        values = np.array([float(r[key]) if r.get(key) is not None else np.nan for r in read_rows(run)])
        if len(values):
            kernel = np.ones(window)
            filled = np.where(np.isnan(values), 0.0, values)
            counts = np.convolve(~np.isnan(values), kernel)[: len(values)]
            series.append(np.convolve(filled, kernel)[: len(values)] / np.maximum(counts, 1))
    if not series:
        return None
    n = min(len(s) for s in series)
    stacked = np.stack([s[:n] for s in series])
    stats = [mean_ci(list(stacked[:, i])) for i in range(n)]
    mean = np.array([s.mean for s in stats])
    half = np.array([0.0 if math.isnan(s.half_width) else s.half_width for s in stats])
    return np.arange(1, n + 1), mean, half


def _band(ax: Any, runs_dir: Path, methods: Sequence[str], key: str, window: int, label: str) -> None:
    for method in methods:
        curve = curves(runs_dir, method, key, window)
        if curve is None:
            continue
        x, mean, half = curve
        color = COLORS.get(method)
        ax.plot(x, mean, color=color, label=method, linewidth=1.8)
        ax.fill_between(x, mean - half, mean + half, color=color, alpha=0.2, linewidth=0)
    ax.set_xlabel("training episode")
    ax.set_ylabel(label)
    ax.grid(alpha=0.3)


def snapshot_paths(run: Path, scenario: str) -> list[tuple[str, np.ndarray, np.ndarray, bool]]:
    """(label, ego xy, pedestrian xy, collided) replayed from the first, middle and last checkpoint of ``run``."""
    import sims
    from core.agents import list_checkpoints, load_agent
    from sims.pedestrian.env import PedestrianEnv

    checkpoints = list_checkpoints(run)
    if not checkpoints:
        return []
    picks = {"early": checkpoints[0], "middle": checkpoints[len(checkpoints) // 2], "late": checkpoints[-1]}
    out = []
    for label, checkpoint in picks.items():
        agent = load_agent(checkpoint)
        env = sims.make("pedestrian", scenario=scenario)
        try:
            obs, _ = env.reset(seed=SNAPSHOT_SEED)
            inner = env.unwrapped
            assert isinstance(inner, PedestrianEnv)
            ego, ped, collided = [], [], False
            for _ in range(1000):
                ego.append((inner.ego.x, inner.ego.y))
                pos = inner.pedestrian_position()
                ped.append(pos if pos is not None else (np.nan, np.nan))
                obs, _, terminated, truncated, info = env.step(agent.policy.act(obs, deterministic=True))
                collided = collided or bool(info.get("violation"))
                if terminated or truncated:
                    break
        finally:
            env.close()
        out.append((f"{label} ({checkpoint.stem})", np.array(ego), np.array(ped, dtype=float), collided))
    return out


def write_figures(runs_dir: Path, out: Path, methods: Sequence[str], scenario: str) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    lengths = [len(_runs(runs_dir, m)) for m in methods]
    if not any(lengths):
        return []
    episodes = min(len(read_rows(r)) for m in methods for r in _runs(runs_dir, m))
    window = max(1, episodes // 15)
    paths = []

    fig, ax = plt.subplots(figsize=(6.4, 3.8))
    _band(ax, runs_dir, methods, "return", window, f"return (moving average of {window})")
    ax.set_title("(b) training reward")
    ax.legend()
    fig.tight_layout()
    paths.append(out / "reward.png")
    fig.savefig(paths[-1], dpi=120)
    plt.close(fig)

    fig, axes = plt.subplots(2, 2, figsize=(9.6, 6.4))
    for ax, (key, label) in zip(
        axes.ravel(),
        (
            ("collision", "collision rate"),
            ("min_ttc", "time to collision (s)"),
            ("avg_speed", "speed (m/s)"),
            ("acc_std", "acceleration variability (m/s²)"),
        ),
        strict=True,
    ):
        _band(ax, runs_dir, methods, key, window, label)
    axes[0, 0].legend()
    fig.suptitle(f"(d) safety and efficiency over training (moving average of {window}; 95% band over seeds)")
    fig.tight_layout()
    paths.append(out / "safety_over_training.png")
    fig.savefig(paths[-1], dpi=120)
    plt.close(fig)

    snapshots = {m: snapshot_paths(_runs(runs_dir, m)[0], scenario) for m in methods if _runs(runs_dir, m)}
    columns = max((len(s) for s in snapshots.values()), default=0)
    if columns:
        fig, axes = plt.subplots(len(snapshots), columns, figsize=(4.2 * columns, 2.6 * len(snapshots)), squeeze=False)
        for row, (method, shots) in enumerate(snapshots.items()):
            for col, (label, ego, ped, collided) in enumerate(shots):
                ax = axes[row, col]
                ax.plot(ego[:, 0], ego[:, 1], color=COLORS.get(method), linewidth=2, label="ego")
                ax.plot(ped[:, 0], ped[:, 1], color="#e11d48", linewidth=1.5, label="pedestrian")
                ax.scatter(ego[-1:, 0], ego[-1:, 1], color="black" if collided else COLORS.get(method), zorder=3)
                ax.set_title(f"{method} · {label}" + (" · collision" if collided else ""), fontsize=9)
                ax.set_aspect("equal", adjustable="datalim")
                ax.grid(alpha=0.3)
        axes[0, 0].legend(fontsize=8)
        fig.suptitle("(c) one crossing replayed from checkpoints early, middle and late in training (first seed)")
        fig.tight_layout()
        paths.append(out / "trajectories.png")
        fig.savefig(paths[-1], dpi=120)
        plt.close(fig)
    return paths
