"""Does the base policy keep what it knew if the adapted one drives only where the base's own gate fires? (issue 62)

After the cycles study's nine rounds the adapted version drives UGV 3 alone far better than the base and forgets the
static scenarios 1-2 (docs/notes/cycles_mover_gate.md). This probe drives, with no expert, three policies per seed:
the base (v0000) alone, the last version (v0008) alone, and the *switch*: the base acting wherever its SAGE gate does
not fire, the adapted version wherever it does (the gate's hold included): the adapted version in the seat the
expert had while it was being taught. Seeds from the cycles study's ``alone_seed`` (its first ``alone_episodes``
are the study's own alone episodes).

    python -m experiments.base_switch_probe --runs runs/probe-cycles-mover --episodes 20 \
        --out docs/notes/base_switch_probe_20.md
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

import sims
from core.agents import load_agent
from core.experts import ScriptedExpert
from core.loop import NoGate, Runner
from core.protocol import Actor, Policy
from studies.cycles import CyclesConfig, gate_for


class PolicyInTheSeat:
    """An expert that is a policy: the adapted version driving where the base's gate hands over."""

    def __init__(self, policy: Policy) -> None:
        self.policy = policy

    def reset(self) -> None:
        reset = getattr(self.policy, "reset", None)
        if reset is not None:
            reset()

    def wants_control(self) -> bool:
        return False

    def act(self, env: gym.Env[Any, Any], obs: np.ndarray) -> tuple[np.ndarray, Actor]:
        return np.asarray(self.policy.act(obs, deterministic=True)), "expert"


def drive(version: Path, scenario: str, episodes: int, seed: int, adapted: Path | None = None) -> dict[str, float]:
    """``version`` alone (no gate, no expert), or with ``adapted`` in the seat its gate hands to."""
    agent = load_agent(version)
    env = sims.descriptor("ugv").make(scenario)
    success = collision = steps = handed = 0
    try:
        if adapted is None:
            runner = Runner(env, agent.policy, NoGate(), ScriptedExpert(), seed=seed, deterministic=True)
        else:
            other = load_agent(adapted).policy
            runner = Runner(env, agent.policy, gate_for(agent), PolicyInTheSeat(other), seed=seed, deterministic=True)
            stepped = getattr(other, "stepped", None)
            if stepped is not None:  # the seat's policy sees every executed step, as the acting one does
                runner.step_listeners.append(lambda r: stepped(r.obs, r.action, r.next_obs))
        for _ in range(episodes):
            summary = runner.run_episode(None)
            success += int(bool(summary.metrics.get("success")))
            collision += int(bool(summary.metrics.get("collision")))
            steps += summary.steps
            handed += summary.takeovers
    finally:
        env.close()
    return {"success": success, "collision": collision, "episodes": episodes, "handed": handed / max(steps, 1)}


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m experiments.base_switch_probe", description=__doc__.split("\n")[0])
    parser.add_argument("--runs", type=Path, required=True, help="folder of sage-s*/v0000 and v0008")
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--scenarios", default="1,2,3,4")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    seed = CyclesConfig.alone_seed  # the class attribute holds the field's default
    scenarios = args.scenarios.split(",")
    rows = []
    totals: dict[tuple[str, str], list[float]] = {}  # success, collisions, episodes (drive's counts)
    for run in sorted(args.runs.glob("sage-s*")):
        base, last = run / "v0000", run / "v0008"
        for scenario in scenarios:
            for name, version, adapted in (("base", base, None), ("v0008", last, None), ("switch", base, last)):
                r = drive(version, scenario, args.episodes, seed, adapted)
                total = totals.setdefault((name, scenario), [0, 0, 0])
                total[0] += r["success"]
                total[1] += r["collision"]
                total[2] += r["episodes"]
                rows.append(
                    f"| {run.name} | {scenario} | {name} | {r['success']}/{r['episodes']} | {r['collision']} | "
                    f"{100 * r['handed']:.1f}% |"
                )
                print(rows[-1], flush=True)
    lines = [
        f"Made by `python -m experiments.base_switch_probe --runs {args.runs} --episodes {args.episodes} "
        f'--scenarios {args.scenarios}`; seeds from {seed}. "handed": the switch\'s steps driven by the adapted '
        "version (its base's gate fired or held).",
        "",
        "| policy | " + " | ".join(f"UGV {s} success (collisions)" for s in scenarios) + " |",
        "|---|" + "---|" * len(scenarios),
    ]
    for name in ("base", "v0008", "switch"):
        cells = [f"{totals[(name, s)][0]}/{totals[(name, s)][2]} ({totals[(name, s)][1]})" for s in scenarios]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    lines += ["", "| run | scenario | policy | success | collisions | handed |", "|---|---|---|---|---|---|", *rows]
    args.out.write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
