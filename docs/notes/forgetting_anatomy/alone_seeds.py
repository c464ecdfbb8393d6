"""Each alone episode of a cycles run's versions, one by one: ``python docs/notes/forgetting_anatomy/alone_seeds.py
RUNS SCENARIO EPISODES VERSION`` (RUNS: a cycles results folder's ``runs/``, e.g.
``results/cycles-small-defaults/runs``). Drives, as `studies.cycles.drive_alone_rates` does (deterministic, no gate,
seeds 9,000,000 on), the scripted expert alone, v0000 alone, and every seed's VERSION alone, and prints one letter an
episode: S success, C collision, T time-out."""

import sys
from pathlib import Path

from core.agents import load_agent
from core.experts import ScriptedExpert
from core.loop import NoGate, Runner
from core.sage.gate import AlwaysGate
from studies.envs import env_factory

make_env = env_factory("ugv")
root, scenario, episodes, version = Path(sys.argv[1]), sys.argv[2], int(sys.argv[3]), sys.argv[4]


def drive(policy: object, gate: object) -> str:
    env = make_env(scenario)
    out = []
    try:
        runner = Runner(env, policy, gate, ScriptedExpert(), seed=9_000_000, deterministic=True)
        for _ in range(episodes):
            metrics = runner.run_episode(None).metrics
            out.append("S" if metrics.get("success") else ("C" if metrics.get("collision") else "T"))
    finally:
        env.close()
    return "".join(out)


base = load_agent(root / "sage-s0/versions/v0000")
print("expert ", drive(base.policy, AlwaysGate()))
print("v0000  ", drive(base.policy, NoGate()))
for seed in range(5):
    print("s", seed, version, drive(load_agent(root / f"sage-s{seed}/versions/{version}").policy, NoGate()))
