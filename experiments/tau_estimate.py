"""How noisy is the gate's threshold as the learner estimates it, and how many states does it need?

At every world-model fit the learner sets κ and the τ bounds from the fear of real states of its replay buffer
(:func:`core.sage.calibration.calibrate`): τ_max is the 99th percentile of fear on familiar states, a tail estimate.
This
bench drives a committed policy as a world-model refit does (its stochastic actions, no expert, no gate) on the
scenarios its world model was refitted on, labels the familiar states as the learner does
(:func:`core.sage.model_trainer.familiar_for_bounds`), then repeats the calibration on independent draws of N of those
states for several N: the spread of τ over draws is the sampling noise a single fit's estimate carries, and the
time is what one calibration costs. The learner's sample size is ``GateConfig.calibration_states``.

    .venv/bin/python -m experiments.tau_estimate [--policy policies/ugv-default] [--sim ugv] \
        [--scenario 1,2,...] [--env KEY=VALUE ...] [--episodes 200] [--draws 30] \
        [--readme docs/notes/calibration_history.md]

Not a unit test: it takes a few minutes of one core.
"""

from __future__ import annotations

import argparse
import subprocess
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

import sims
from core.agents import LoadedAgent, load_agent
from core.loop import NoGate, Runner
from core.replay import ReplayBuffer
from core.sage.calibration import calibrate
from core.sage.model_trainer import familiar_for_bounds
from experiments.refit_spread import REFIT
from studies.envs import parse_env_overrides
from studies.readme import publish

ROOT = Path(__file__).resolve().parents[1]
CAPACITY = 250_000
"""Rows of the replay buffer the states are collected in (a refit's buffer held about 105,000)."""
SIZES = (2048, 8192, 16384, 32768)
"""States per calibration: 2048 the learner's draw before ``calibration_states``, 16384 its default."""


def collect(policy: Path, sim: str, scenarios: list[str], env: dict[str, Any], episodes: int, seed: int) -> LoadedAgent:
    """The policy's own states on ``scenarios`` (round robin), stored in its learner's replay buffer."""
    agent = load_agent(policy)
    if agent.world_model is None:
        raise SystemExit(f"{policy} has no world model: nothing to calibrate")
    learner = agent.learner
    # a loaded policy carries no replay memory (a buffer of one row): give it room for every step of the episodes
    learner.buffer = ReplayBuffer(learner.buffer.obs_dim, learner.buffer.act_dim, CAPACITY)
    d = sims.descriptor(sim)
    runners = []
    for j, scenario in enumerate(scenarios):
        path = str(ROOT / scenario) if scenario.endswith(".yaml") else scenario
        runner = Runner(d.make(path, **env), learner, NoGate(), None, seed=seed + 1000 * j)
        runner.step_listeners.append(learner.store)
        runners.append(runner)
    for i in range(episodes):
        runners[i % len(runners)].run_episode()
    return agent


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--policy", type=Path, default=ROOT / "policies" / "ugv-default")
    parser.add_argument("--sim", default="ugv")
    parser.add_argument("--scenario", default=REFIT.scenario, help="comma-separated, as sage train takes them")
    parser.add_argument("--env", nargs="*", default=[], help="simulator overrides KEY=VALUE, as sage train takes them")
    parser.add_argument("--episodes", type=int, default=200, help="policy episodes, over the scenarios in turn")
    parser.add_argument("--draws", type=int, default=30, help="independent draws of N states per N")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "notes" / "tau_estimate")
    parser.add_argument(
        "--readme",
        type=Path,
        help="also copy the result into this document's block (e.g. docs/notes/calibration_history.md)",
    )
    args = parser.parse_args()
    torch.set_num_threads(1)
    scenarios = [s for s in args.scenario.split(",") if s]
    started = time.perf_counter()
    agent = collect(args.policy, args.sim, scenarios, parse_env_overrides(args.env), args.episodes, args.seed)
    wm, gate, learner = agent.world_model, agent.gate_config(), agent.learner
    assert wm is not None
    buffer = learner.buffer
    obs = torch.from_numpy(buffer.arrays()["obs"])
    familiar = torch.from_numpy(
        familiar_for_bounds(buffer, wm.cfg.violation_steps, gate.horizon, wm.cfg.conflict_label_weight)
    )
    motion = torch.from_numpy(buffer.previous_deltas(wm.motion_lag, wm.scan)) if wm.motion else None
    drove = time.perf_counter() - started
    rng = np.random.default_rng(args.seed)
    rows = []
    for size in SIZES:
        bounds, seconds = [], []
        for _ in range(args.draws):
            # independent draws of the policy's states (with replacement from the pool): one fit's sample
            idx = torch.from_numpy(rng.integers(0, len(obs), size=size))
            t = time.perf_counter()
            calibrate(
                wm, learner.rollout_policy, obs[idx], gate.horizon, cfg=gate, safe=familiar[idx],
                motion=None if motion is None else motion[idx],
            )  # fmt: skip
            seconds.append(time.perf_counter() - t)
            tau_bounds = wm.tau_bounds  # a registered buffer: nn.Module's attributes read as Tensor | Module
            assert isinstance(tau_bounds, torch.Tensor)
            bounds.append([float(b) for b in tau_bounds])
        values = np.array(bounds)
        rows.append((size, values.mean(0), values.std(0, ddof=1), float(np.median(seconds))))
        print(f"{size} states: tau_max {values[:, 1].mean():.3f} sd {values[:, 1].std(ddof=1):.4f}", flush=True)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True)
    shown = args.policy.resolve()
    shown = shown.relative_to(ROOT) if shown.is_relative_to(ROOT) else shown
    command = f"python -m experiments.tau_estimate --policy {shown} --sim {args.sim} --scenario {args.scenario}"
    if args.env:
        command += " --env " + " ".join(args.env)
    command += f" --episodes {args.episodes} --draws {args.draws} --seed {args.seed}"
    text = [
        "# The threshold's estimate: sampling noise against the states per calibration",
        "",
        f"`{command}` at {commit.stdout.strip()}: {args.episodes} episodes of the policy's stochastic actions (no "
        f"expert, no gate), {len(obs)} states of which {int(familiar.sum())} familiar (no violation within the "
        f"label's {wm.cfg.violation_steps} steps and the {gate.horizon} imagined ones); {drove:.0f} s of driving. "
        f"Each row: τ from {args.draws} independent draws of N of these states (mean ± sd over draws; the sd is the "
        "noise one fit's τ carries), and the median time of one calibration on one core.",
        "",
        "| states per calibration (N) | τ_min | τ_max | seconds per calibration |",
        "|---|---|---|---|",
    ]
    for size, mean, sd, secs in rows:
        text.append(f"| {size} | {mean[0]:.3f} ± {sd[0]:.3f} | {mean[1]:.3f} ± {sd[1]:.3f} | {secs:.2f} |")
    publish(text, args.out, args.readme, "tau-estimate", "## Calibration of fear")


if __name__ == "__main__":
    main()
