"""Exploratory: how often the UGV default's deployed gate hands a scenario to the scripted expert, and why.

    PYTHONPATH=$PWD OMP_NUM_THREADS=1 python docs/notes/forgetting_anatomy/gate_on_static.py 1 10

``policies/ugv-default`` with its own gate and the scripted expert on the calibration seeds (from 3,000,000), as
``studies.calibrate.gate_with_expert`` drives it: the takeover rate and its parts (fear over τ, the hold, the
hysteresis), episodes with a violation. The eleventh session's arm B quotes it on UGV 1 (1.7% over 10 episodes) and
on ``ugv-fields:test:2+`` (54.5% over 30: fear 32.8%, hold 16.5%, hysteresis 4.5%).
"""

from __future__ import annotations

import sys

from core.agents import load_agent
from studies.calibrate._gated_runs import run_gated
from studies.envs import env_factory

if __name__ == "__main__":
    scenario, episodes = sys.argv[1], int(sys.argv[2])
    agent = load_agent("policies/ugv-default")
    make_env = env_factory("ugv")
    result = run_gated(agent, lambda: make_env(scenario), agent.make_gate(), episodes, None)
    print(scenario, {k: round(v, 4) for k, v in result.items() if isinstance(v, float)})
