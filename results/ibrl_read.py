"""Read an IBRL cycles run beside its control: the rounds' statistics and how often π_IL's proposal drives alone.

    .venv/bin/python results/ibrl_read.py CONTROL_FOLDER IBRL_FOLDER [--episodes 10]

Per seed: the rounds' mean ω, the RL actor's and π_IL's held-out takeover error (means over the rounds), the update at
which π_IL's weights were kept, and, for the last version of the IBRL run, the share of steps on which π_IL's action
acted when it drives the cycles' scenario alone (deterministic, no gate; the study's alone seeds), and the same
version's RL actor alone there without the actor proposal. It decides nothing:
the rule is in results/cycles-twentyseventh-ibrl.sh."""

from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path
from typing import Any

from core.agents import load_agent
from core.experts import ScriptedExpert
from core.loop import NoGate, Runner
from studies.envs import env_factory


def rounds(run: Path) -> list[dict[str, float]]:
    versions = sorted((run / "versions").glob("v*/metrics.json"))
    return [m["losses"] for m in (json.loads(v.read_text()) for v in versions) if "losses" in m]


def mean_of(rows: list[dict[str, float]], key: str) -> float:
    values = [r[key] for r in rows if key in r]
    return statistics.fmean(values) if values else float("nan")


def alone(agent: Any, cfg: dict[str, Any], episodes: int) -> float:
    """Success of ``agent``'s policy alone on the cycles' scenario over the study's alone seeds."""
    env = env_factory(cfg["sim"])(cfg["scenario"])
    runner = Runner(env, agent.policy, NoGate(), ScriptedExpert(), seed=cfg["alone_seed"], deterministic=True)
    success = 0
    for _ in range(episodes):
        success += int(bool(runner.run_episode(cfg["max_episode_steps"]).metrics.get("success")))
    env.close()
    return success / episodes


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("control", type=Path)
    parser.add_argument("ibrl", type=Path)
    parser.add_argument("--episodes", type=int, default=10)
    args = parser.parse_args()
    print(
        "| seed | ω control | ω IBRL | RL actor held-out error, control | RL actor, IBRL | π_IL held-out error | "
        "π_IL kept at update (mean) | π_IL's share of steps alone, last version | alone success there | "
        "its RL actor alone |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for run in sorted((args.ibrl / "runs").glob("sage-s*")):
        control = rounds(args.control / "runs" / run.name)
        arm = rounds(run)
        cycles = json.loads((run / "cycles.json").read_text())
        cfg = cycles["config"]
        last = sorted((run / "versions").glob("v*"))[-1]
        agent = load_agent(last)
        success = alone(agent, cfg, args.episodes)
        rl, il = agent.learner.proposals  # type: ignore[attr-defined]
        agent.learner.cfg.ibrl = False  # the same version's RL actor alone, without the actor proposal
        rl_only = alone(agent, cfg, args.episodes)
        print(
            f"| {run.name[-1]} | {mean_of(control, 'omega_mean'):.3f} | {mean_of(arm, 'omega_mean'):.3f} | "
            f"{mean_of(control, 'heldout_imitation_error'):.3f} | {mean_of(arm, 'heldout_imitation_error'):.3f} | "
            f"{mean_of(arm, 'il_heldout_error'):.3f} | {mean_of(arm, 'il_kept_update'):.0f} | "
            f"{il / max(1, rl + il):.2f} ({il} of {rl + il}) | {success:.1f} | {rl_only:.1f} |"
        )


if __name__ == "__main__":
    main()
