"""Beside the UGV study's IBRL arm: how often π_IL's proposal acts alone, and the same runs' RL actors alone.

    .venv/bin/python results/ibrl_ugv_read.py RESULTS_FOLDER [--episodes 20] > READING.md

For each seed's final checkpoint of SAGE in an IBRL UGV study (``--set learner.ibrl=true``): on every scenario, the
study's own evaluation (the policy alone, deterministic, the study's evaluation seeds) with the actor proposal, the
share of steps π_IL's action acted, the same checkpoint's RL actor alone without it, and π_IL alone (the clone of
the takeovers, as HG-DAgger's policy is). It decides nothing: the
reading is in results/ugv-30k-ibrl.sh."""

from __future__ import annotations

import argparse
import statistics
from pathlib import Path

from core.agents import load_agent
from core.sage.learner import ActorPolicy
from core.train import SCENARIO_SEED_STRIDE, evaluate
from studies.envs import env_factory

SCENARIOS = ("1", "2", "3", "4")


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("results", type=Path)
    parser.add_argument("--episodes", type=int, default=20)
    args = parser.parse_args()
    print(f"Made by `python results/ibrl_ugv_read.py {args.results}`: success alone (%) per seed.\n")
    print(
        "| scenario | with the actor proposal | π_IL's share of steps | the RL actor alone | π_IL alone | "
        "mean: with / RL actor / π_IL |"
    )
    print("|---|---|---|---|---|---|")
    runs = sorted((args.results / "runs").glob("sage-s*"))
    for j, scenario in enumerate(SCENARIOS):
        composite, shares, plain, clone = [], [], [], []
        for run in runs:
            # the study evaluates the four scenarios in one call: scenario j's episodes start j strides on
            seed = int(run.name.rsplit("-s", 1)[1]) + j * SCENARIO_SEED_STRIDE
            agent = load_agent(run)
            rows = evaluate(agent.policy, env_factory("ugv"), [scenario], args.episodes, seed, progress=False)
            composite.append(100 * statistics.fmean(float(bool(r["success"])) for r in rows[scenario]))
            rl, il = agent.learner.proposals  # type: ignore[attr-defined]
            shares.append(il / max(1, rl + il))
            agent.learner.cfg.ibrl = False
            rows = evaluate(agent.policy, env_factory("ugv"), [scenario], args.episodes, seed, progress=False)
            plain.append(100 * statistics.fmean(float(bool(r["success"])) for r in rows[scenario]))
            il_alone = ActorPolicy(agent.learner.il_actor)  # type: ignore[attr-defined]
            rows = evaluate(il_alone, env_factory("ugv"), [scenario], args.episodes, seed, progress=False)
            clone.append(100 * statistics.fmean(float(bool(r["success"])) for r in rows[scenario]))
        print(
            f"| {scenario} | {', '.join(f'{v:.0f}' for v in composite)} | {', '.join(f'{v:.2f}' for v in shares)} | "
            f"{', '.join(f'{v:.0f}' for v in plain)} | {', '.join(f'{v:.0f}' for v in clone)} | "
            f"{statistics.fmean(composite):.1f} / {statistics.fmean(plain):.1f} / {statistics.fmean(clone):.1f} |"
        )


if __name__ == "__main__":
    main()
