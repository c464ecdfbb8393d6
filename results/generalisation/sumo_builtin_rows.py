"""The built-in gate rows of a SUMO run (docs/calibration.md's: gate + scripted expert, 300 episodes a scenario, the
evaluation seeds, a violation judged over 1 s), into a JSON file: ``python sumo_builtin_rows.py RUN OUT.json``."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from studies.calibrate import gate_with_expert  # noqa: E402
from studies.envs import env_factory  # noqa: E402

SCENARIOS = ("c1", "c2", "2", "1-special")
EPISODES = 300


def main() -> None:
    torch.set_num_threads(1)
    run, out = sys.argv[1], Path(sys.argv[2])
    make = env_factory("sumo")
    rows = {}
    for scenario in SCENARIOS:
        start = time.time()
        row = gate_with_expert(run, lambda s=scenario: make(s), EPISODES, warn_steps=2)  # 1 s at SUMO's 0.5 s step
        row["wall_s"] = round(time.time() - start, 1)
        rows[scenario] = row
        print(run, scenario, f"{row['violation_rate']:.3f} at {row['takeover_rate']:.3f}", flush=True)
        out.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
