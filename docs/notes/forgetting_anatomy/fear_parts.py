"""The gate's parts along a version's supervised drives of one UGV field (forgetting_anatomy.md, arm W's reading).

    PYTHONPATH=$PWD OMP_NUM_THREADS=1 python docs/notes/forgetting_anatomy/fear_parts.py VERSION... \
        [--scenario ugv-fields:test:1] [--episodes 2]

Each version drives with its own gate and the scripted expert (deterministic, seeds 3,000,000 on); printed per
version: the steps, and the means over them of ĉ, σ̂, fear, the takeover flag and |speed command|.
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

import sims
from core.agents import load_agent
from core.experts import ScriptedExpert
from core.loop import Runner, StepRecord


def gate_parts(version: str, scenario: str, episodes: int) -> tuple[int, np.ndarray]:
    """(steps, means of ĉ, σ̂, fear, takeover, |a_0|) over ``episodes`` supervised drives of ``scenario``."""
    agent = load_agent(version)
    gate = agent.make_gate()
    env = sims.descriptor("ugv").make(scenario)
    rows: list[tuple[float, float, float, float, float]] = []

    def record(r: StepRecord) -> None:
        detail = gate.detail
        fear = getattr(detail, "fear", float("nan"))
        rows.append((detail.cost, detail.sigma, fear, float(r.takeover), float(np.abs(r.action[0]))))

    try:
        runner = Runner(env, agent.policy, gate, ScriptedExpert(), seed=3_000_000, deterministic=True)
        runner.step_listeners.append(record)
        for _ in range(episodes):
            runner.run_episode()
    finally:
        env.close()
    return len(rows), np.nanmean(np.asarray(rows, float), axis=0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("versions", nargs="+")
    parser.add_argument("--scenario", default="ugv-fields:test:1")
    parser.add_argument("--episodes", type=int, default=2)
    args = parser.parse_args()
    torch.set_num_threads(1)
    for version in args.versions:
        steps, (cost, sigma, fear, takeover, speed) = gate_parts(version, args.scenario, args.episodes)
        print(
            f"{version}: steps {steps} cost {cost:.3f} sigma {sigma:.3f} fear {fear:.3f} "
            f"takeover {takeover:.2f} |a0| {speed:.2f}"
        )


if __name__ == "__main__":
    main()
