"""Can a policy that sees one scan drive UGV 3 alone at issue 62's 90%? (issue 62; a diagnosis, not a learner)

The cycles study's versions plateau at about 0.8 alone on UGV 3 (ten seed-runs of the defaults: 0.83), and every
alone failure is a collision with the crossing mover. The policy's observation is one lidar scan, the goal and its
last command: nothing in it says where the mover is going. The scripted expert that supervises it reads the movers'
future poses. This probe asks whether the plateau is the learning or the observation: it trains students of the
default actor's shape (58 inputs, 2 x 128 ReLU, tanh) by DAgger from the scripted expert on UGV 3 itself (the
expert labels every state the student visits; the data aggregate over iterations), one student on the observation as
it is, one on the observation plus the change of its 54 ranges over the last step (a velocity cue the policy lacks;
zeros at an episode's first step), and on request one on the observation plus a perfect tracker's view of the
movers (``scan+movers``: their present positions and velocities, :func:`mover_tracks`). Each iteration's student
drives alone (deterministic, no gate, no expert) on the cycles study's alone seeds (9,000,000 on) and more.

    OMP_NUM_THREADS=1 python -m experiments.observability_probe --out docs/notes/observability_probe.md

Nothing here changes a policy or a default; the students are not saved."""

from __future__ import annotations

import argparse
import dataclasses
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from core.planners import make_planner
from sims import descriptor

RANGES = 54
"""The UGV observation's lidar channels (``sims.ugv.env.SECTORS``): the part whose change is the velocity cue."""
ALONE_SEED = 9_000_000
"""The cycles study's alone evaluation seeds start here (``studies.cycles_study``)."""
TRAIN_SEED = 7_000_000
"""Episode seeds of the probe's own drives (no study uses them)."""


@dataclass
class ProbeConfig:
    scenario: str = "3"
    """The scenario the students learn on (a procedural family such as ``ugv-fields:train`` gives a field a seed)."""
    eval_scenario: str = ""
    """The scenario the students are judged on alone ("": ``scenario``; e.g. ``ugv-fields:test:2+``, unseen fields)."""
    expert_episodes: int = 30
    """Iteration 0: the expert drives these episodes and labels its own states."""
    iterations: int = 6
    """DAgger iterations after the expert's: each student drives, the expert labels what it meets."""
    episodes_per_iteration: int = 20
    eval_episodes: int = 50
    """Alone episodes per iteration's student (seeds ALONE_SEED on; the study's 10 are the first 10)."""
    updates: int = 3000
    """Gradient steps per iteration (Adam 1e-3, batch 256, the student trained on from the last iteration's)."""
    max_steps: int = 600
    seed: int = 0
    hidden: tuple[int, ...] = (128, 128)
    """The student's hidden layer widths (the default actor's 2 x 128)."""
    teacher: str = "scripted"
    """Who labels: ``scripted`` (the simulator's privileged expert) or a planner's name (``teb``: the robot's own
    sensing), which also drives iteration 0's demonstrations."""


class Student(nn.Module):
    """The default actor's shape by default: 2 x 128 ReLU, a tanh mean (actions in [-1, 1]^2); ``hidden`` other
    layer widths (a capacity check)."""

    def __init__(self, inputs: int, hidden: tuple[int, ...] = (128, 128)) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        for width in hidden:
            layers += [nn.Linear(inputs, width), nn.ReLU()]
            inputs = width
        self.net = nn.Sequential(*layers, nn.Linear(inputs, 2))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.tanh(self.net(x))


def features(obs: np.ndarray, previous: np.ndarray | None, cue: bool) -> np.ndarray:
    """The student's input: the observation, and with ``cue`` the change of its ranges over the last step."""
    if not cue:
        return obs.astype(np.float32)
    change = np.zeros(RANGES, np.float32) if previous is None else obs[:RANGES] - previous[:RANGES]
    return np.concatenate([obs, change]).astype(np.float32)


TRACKED = 3
"""Movers a tracked student sees (the nearest first; UGV fields have at most three)."""


def mover_tracks(sim: Any) -> np.ndarray:
    """A perfect tracker's view of the movers now (``scan+movers`` students): for the three nearest, whether there,
    and their position (m / 10) and velocity over the last step (m/s / 2) in the robot's frame. Not the expert's
    privilege: nothing about where a mover will go beyond its present motion."""
    out = np.zeros(TRACKED * 5, np.float32)
    world, layout = sim.world, sim.layout
    if world is None or layout is None or not layout.movers:
        return out
    k = world.k
    world.ensure_table(k)
    x, y, yaw = sim._pose
    cos, sin = np.cos(-yaw), np.sin(-yaw)
    now = world.mover_poses[:, k, 0:2] - (x, y)
    moved = (world.mover_poses[:, k, 0:2] - world.mover_poses[:, max(k - 1, 0), 0:2]) / world.dt
    rotate = np.array([[cos, -sin], [sin, cos]])
    now, moved = now @ rotate.T, moved @ rotate.T
    for slot, i in enumerate(np.argsort(np.hypot(now[:, 0], now[:, 1]))[:TRACKED]):
        out[slot * 5 : slot * 5 + 5] = (1.0, *(now[i] / 10.0), *(moved[i] / 2.0))
    return out


@dataclass
class Outcome:
    success: int = 0
    collision: int = 0
    timeout: int = 0
    steps: int = 0
    x: list[np.ndarray] = field(default_factory=list)
    y: list[np.ndarray] = field(default_factory=list)


def drive(
    cfg: ProbeConfig,
    student: Student | None,
    cue: bool,
    seeds: range,
    label: bool,
    outcome: Outcome | None = None,
    scenario: str = "",
    tracks: bool = False,
) -> Outcome:
    """Episodes at ``seeds`` of ``scenario`` (default ``cfg.scenario``): the student drives (the expert where
    ``student`` is None); with ``label`` the expert's action at every visited state is kept as the target."""
    env = descriptor("ugv").make(scenario or cfg.scenario)
    out = outcome or Outcome()
    sim: Any = env.unwrapped
    planner = None if cfg.teacher == "scripted" else make_planner(cfg.teacher, env, "ugv")
    try:
        for seed in seeds:
            obs, _ = env.reset(seed=seed)
            previous = None
            for _ in range(cfg.max_steps):
                x = features(obs, previous, cue)
                if tracks:
                    x = np.concatenate([x, mover_tracks(sim)])
                expert = None
                if label or student is None:
                    teacher = sim.expert_action() if planner is None else planner.act(obs, deterministic=True)
                    expert = np.asarray(teacher, np.float32).reshape(2)
                if student is None:
                    assert expert is not None
                    action = expert
                else:
                    with torch.no_grad():
                        action = student(torch.from_numpy(x)[None])[0].numpy()
                if label:
                    assert expert is not None
                    out.x.append(x)
                    out.y.append(expert)
                previous = obs
                obs, _, terminated, truncated, info = env.step(action)
                out.steps += 1
                if terminated or truncated:
                    break
            if info.get("success"):
                out.success += 1
            elif info.get("collision"):
                out.collision += 1
            else:
                out.timeout += 1
    finally:
        env.close()
    return out


def train(student: Student, x: np.ndarray, y: np.ndarray, updates: int, rng: np.random.Generator) -> float:
    optimiser = torch.optim.Adam(student.parameters(), lr=1e-3)
    xs, ys = torch.from_numpy(x), torch.from_numpy(y)
    loss = torch.tensor(math.nan)
    for _ in range(updates):
        idx = torch.from_numpy(rng.integers(0, len(x), size=256))
        loss = (student(xs[idx]) - ys[idx]).pow(2).sum(-1).mean()
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        optimiser.step()
    return float(loss.detach())


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    if n == 0:
        return math.nan, math.nan
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return centre - half, centre + half


def run(cfg: ProbeConfig, cue: bool, tracks: bool = False) -> list[dict[str, Any]]:
    """DAgger for one student; a row per iteration: data size, training loss and the student alone."""
    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    student = Student(58 + (RANGES if cue else 0) + (TRACKED * 5 if tracks else 0), cfg.hidden)
    data = drive(cfg, None, cue, range(TRAIN_SEED, TRAIN_SEED + cfg.expert_episodes), label=True, tracks=tracks)
    rows: list[dict[str, Any]] = []
    next_seed = TRAIN_SEED + cfg.expert_episodes
    for iteration in range(cfg.iterations + 1):
        if iteration > 0:
            seeds = range(next_seed, next_seed + cfg.episodes_per_iteration)
            next_seed += cfg.episodes_per_iteration
            drive(cfg, student, cue, seeds, label=True, outcome=data, tracks=tracks)
        loss = train(student, np.stack(data.x), np.stack(data.y), cfg.updates, rng)
        alone = drive(
            cfg,
            student,
            cue,
            range(ALONE_SEED, ALONE_SEED + cfg.eval_episodes),
            label=False,
            scenario=cfg.eval_scenario,
            tracks=tracks,
        )
        rows.append(
            {
                "iteration": iteration,
                "samples": len(data.x),
                "loss": loss,
                "success": alone.success,
                "collision": alone.collision,
                "timeout": alone.timeout,
            }
        )
        print(f"cue={cue} tracks={tracks} iteration {iteration}: {len(data.x)} samples, loss {loss:.4f}, "
              f"alone {alone.success}/{cfg.eval_episodes} (collisions {alone.collision}, "
              f"timeouts {alone.timeout})", flush=True)  # fmt: skip
    return rows


def report(cfg: ProbeConfig, results: dict[str, list[dict[str, Any]]], seconds: float, commit: str) -> str:
    lines = [
        "# Observability probe: DAgger students of the scripted expert on UGV "
        f"{cfg.scenario}"
        + (f", judged on {cfg.eval_scenario}" if cfg.eval_scenario and cfg.eval_scenario != cfg.scenario else "")
        + " (generated by `python -m experiments.observability_probe`; do not edit)",
        "",
        f"Commit `{commit}`, {seconds / 60:.1f} min. Expert drives {cfg.expert_episodes} episodes, then "
        f"{cfg.iterations} DAgger iterations of {cfg.episodes_per_iteration}; {cfg.updates} updates an iteration; "
        f"each student alone on {cfg.eval_episodes} episodes (seeds {ALONE_SEED:,} on), success with its 95% Wilson "
        f"interval. Students' hidden layers: {' x '.join(str(w) for w in cfg.hidden)} (ReLU). Teacher: {cfg.teacher}.",
        "",
        "| student | iteration | samples | training loss | alone success [95%] | collisions | timeouts |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, rows in results.items():
        for r in rows:
            low, high = wilson(r["success"], cfg.eval_episodes)
            lines.append(
                f"| {name} | {r['iteration']} | {r['samples']} | {r['loss']:.4f} | {r['success']}/{cfg.eval_episodes}"
                f" [{low:.0%}, {high:.0%}] | {r['collision']} | {r['timeout']} |"
            )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    import subprocess

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=None, help="write the table here (markdown)")
    parser.add_argument("--iterations", type=int, default=ProbeConfig.iterations)
    parser.add_argument("--episodes-per-iteration", type=int, default=ProbeConfig.episodes_per_iteration)
    parser.add_argument("--expert-episodes", type=int, default=ProbeConfig.expert_episodes)
    parser.add_argument("--eval-episodes", type=int, default=ProbeConfig.eval_episodes)
    parser.add_argument("--updates", type=int, default=ProbeConfig.updates)
    parser.add_argument(
        "--students", default="scan,scan+change", help="which students: scan, scan+change, scan+movers (tracked movers)"
    )
    parser.add_argument("--seeds", default="0", help="training seeds (student init and minibatches), e.g. 0,1,2")
    parser.add_argument("--scenario", default=ProbeConfig.scenario, help="learn here (e.g. ugv-fields:train)")
    parser.add_argument("--eval-scenario", default="", help="judge alone here (default: --scenario)")
    parser.add_argument("--hidden", default="128,128", help="the students' hidden widths (default: the actor's)")
    parser.add_argument("--teacher", default="scripted", help="who labels: scripted (privileged) or a planner (teb)")
    args = parser.parse_args(argv)
    cfg = ProbeConfig(
        teacher=args.teacher,
        hidden=tuple(int(w) for w in args.hidden.split(",")),
        scenario=args.scenario,
        eval_scenario=args.eval_scenario,
        iterations=args.iterations,
        episodes_per_iteration=args.episodes_per_iteration,
        expert_episodes=args.expert_episodes,
        eval_episodes=args.eval_episodes,
        updates=args.updates,
    )
    torch.set_num_threads(1)
    start = time.time()
    results = {
        f"{name}, seed {seed}": run(
            dataclasses.replace(cfg, seed=int(seed)), cue=name == "scan+change", tracks=name == "scan+movers"
        )
        for name in args.students.split(",")
        for seed in args.seeds.split(",")
    }
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    text = report(cfg, results, time.time() - start, commit)
    print(text)
    if args.out is not None:
        args.out.write_text(text)


if __name__ == "__main__":
    main()
