"""The built-in gate rows of a run on any simulator (docs/calibration.md's gate table: gate + scripted expert on the
table's scenarios, 300 episodes each, the evaluation seeds, a violation judged over 1 s), into a JSON file:
``python builtin_rows.py SIM RUN OUT.json [KEY=VALUE ...]`` (gate settings over the run's own, e.g. tau_scale=1)."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

import sims  # noqa: E402
from experiments.calibration import table_scenarios  # noqa: E402
from studies.calibrate import gate_with_expert  # noqa: E402
from studies.envs import env_factory  # noqa: E402

EPISODES = 300


def main() -> None:
    torch.set_num_threads(1)
    sim, run, out = sys.argv[1], sys.argv[2], Path(sys.argv[3])
    overrides = {key: json.loads(value) for key, value in (item.split("=", 1) for item in sys.argv[4:])}
    make = env_factory(sim)
    warn_steps = max(1, round(1.0 / sims.descriptor(sim).dt))
    rows = {}
    for scenario in table_scenarios(sim):
        start = time.time()
        row = gate_with_expert(run, lambda s=scenario: make(s), EPISODES, warn_steps=warn_steps, **overrides)
        row["wall_s"] = round(time.time() - start, 1)
        rows[scenario] = row
        print(run, scenario, f"{row['violation_rate']:.3f} at {row['takeover_rate']:.3f}", flush=True)
        out.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
