"""How much action change the base's static competence tolerates (issue 62, forgetting anatomy): policies/ugv-default
alone on UGV 1 and 2 (the study's 10 alone seeds) with a constant offset on one action dimension, or Gaussian noise.

    PYTHONPATH=$PWD OMP_NUM_THREADS=1 python docs/notes/forgetting_anatomy/sensitivity.py
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from core.agents import load_agent
from core.experts import ScriptedExpert
from core.loop import NoGate, Runner
from studies.envs import env_factory

MAKE_ENV = env_factory("ugv")
BASE = Path(__file__).resolve().parents[3] / "policies" / "ugv-default"


class Shifted:
    def __init__(self, policy: Any, offset: np.ndarray, noise: float, seed: int = 0) -> None:
        self.policy, self.offset, self.noise = policy, offset, noise
        self.rng = np.random.default_rng(seed)

    def act(self, obs: np.ndarray, deterministic: bool = False) -> np.ndarray:
        a = np.asarray(self.policy.act(obs, True), np.float32) + self.offset
        if self.noise > 0:
            a = a + self.rng.normal(0.0, self.noise, a.shape)
        return np.clip(a, -1.0, 1.0).astype(np.float32)


def rates(policy: Any, scenario: str) -> dict[str, int]:
    env = MAKE_ENV(scenario)
    out = {"success": 0, "collision": 0, "timeout": 0}
    try:
        runner = Runner(env, policy, NoGate(), ScriptedExpert(), seed=9_000_000, deterministic=True)
        for _ in range(10):
            m = runner.run_episode(None).metrics
            out["success" if m.get("success") else "collision" if m.get("collision") else "timeout"] += 1
    finally:
        env.close()
    return out


def main() -> None:
    agent = load_agent(BASE)
    rows = []
    cases = [((0.0, 0.0), 0.0)]
    cases += [((0.0, w), 0.0) for w in (-0.2, -0.1, -0.05, 0.05, 0.1, 0.2)]
    cases += [((v, 0.0), 0.0) for v in (-0.2, -0.5)]
    cases += [((0.0, 0.0), s) for s in (0.05, 0.1, 0.2)]
    for offset, noise in cases:
        policy = Shifted(agent.policy, np.asarray(offset, np.float32), noise)
        row = {"offset": offset, "noise": noise, **{f"ugv{s}": rates(policy, s) for s in ("1", "2")}}
        rows.append(row)
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
