"""Exploratory: a base-first version alone on one scenario: who acts at each step, and how the episode ends.

    PYTHONPATH=$PWD OMP_NUM_THREADS=1 python docs/notes/forgetting_anatomy/base_first_alone.py \
        results/cycles-small-fields-base-first/runs/sage-s0/versions/v0008 ugv-fields:test:1

Prints the version (the composite: the base, its watch, the version's actor) and ``v0000`` beside it, each alone
(no gate, no expert, deterministic) on the alone seed 9,000,000: steps, outcome, the base's share of the steps, the
first step the version acted, how often the actor switched, and who acted over the last 15 steps. A third argument,
comma-separated scales of the watch's threshold bounds (e.g. ``1,0.7,0.5,0.35,0``; 0: the version from the first
step), drives the composite once per scale instead: does a watch that fires earlier get the version through?
"""

from __future__ import annotations

import sys
from typing import Any

import numpy as np

from core.agents import load_agent
from core.experts import ScriptedExpert
from core.loop import NoGate, Runner
from studies.envs import env_factory


def drive(path: str, scenario: str, watch_scale: float = 1.0) -> str:
    agent = load_agent(path)
    env = env_factory("ugv")(scenario)
    policy = agent.policy
    if watch_scale != 1.0:
        threshold = policy.watch.threshold
        set_bounds = threshold.set_bounds

        def scaled(bounds: Any) -> None:  # the gate sets its bounds again from its model: scale them every time
            set_bounds(bounds)
            threshold.tau_min, threshold.tau_max = threshold.tau_min * watch_scale, threshold.tau_max * watch_scale

        threshold.set_bounds = scaled
        threshold.tau_min, threshold.tau_max = threshold.tau_min * watch_scale, threshold.tau_max * watch_scale
    who: list[bool] = []

    def listen(record: Any) -> None:
        base = getattr(policy, "last_base", None)
        if base is not None:
            who.append(bool(base))

    try:
        runner = Runner(env, policy, NoGate(), ScriptedExpert(), seed=9_000_000, deterministic=True)
        runner.step_listeners.append(listen)
        summary = runner.run_episode(max_steps=600)
    finally:
        env.close()
    outcome = {k: v for k, v in summary.metrics.items() if k in ("success", "collision", "timeout")}
    if not who:
        return f"steps {summary.steps} {outcome}"
    acted = np.array(who, dtype=bool)
    first = int(np.argmin(acted)) if (~acted).any() else None
    flips = int(np.sum(acted[1:] != acted[:-1]))
    last = "".join("B" if base else "v" for base in acted[-15:])
    return (
        f"steps {summary.steps} {outcome} base share {acted.mean():.2f} first version step {first} flips {flips} "
        f"last 15 (B: base, v: version) {last}"
    )


if __name__ == "__main__":
    version, scenario = sys.argv[1], sys.argv[2]
    if len(sys.argv) > 3:
        for scale in (float(x) for x in sys.argv[3].split(",")):
            print(f"watch x{scale}", drive(version, scenario, scale))
    else:
        print("version", drive(version, scenario))
        print("v0000  ", drive(str(version).rsplit("/", 1)[0] + "/v0000", scenario))
