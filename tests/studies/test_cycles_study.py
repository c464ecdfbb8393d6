"""`sage study cycles`: fine-tuning cycles against the frozen control, the same situations for both."""

from __future__ import annotations

import json
from pathlib import Path

from studies.cycles_study import METRICS, cycles_for, trial
from studies.registry import get_study


def test_the_cycles_study_compares_fine_tuning_with_a_frozen_control(tmp_path: Path) -> None:
    assert get_study("cycles").methods == ("frozen", "sage")
    assert (cycles_for(200), cycles_for(6000), cycles_for(10**6)) == (2, 9, 9)
    config = {"seed": 0, "train_steps": 200, "eval_episodes": 1, "episodes_per_cycle": 1, "runs_dir": str(tmp_path)}
    results = {method: trial({**config, "method": method}) for method in ("frozen", "sage")}
    for result in results.values():
        assert set(METRICS) <= set(result) and result["cycles"] == 2
    frozen = json.loads((tmp_path / "frozen-s0" / "cycles.json").read_text())
    tuned = json.loads((tmp_path / "sage-s0" / "cycles.json").read_text())
    assert frozen["rounds"] == [] and [c["version"] for c in frozen["cycles"]] == [0, 0]
    assert len(tuned["rounds"]) == 1 and tuned["cycles"][-1]["version"] > 0
    # the first cycle is the same policy in the same situation for both
    assert results["frozen"]["takeover_first"] == results["sage"]["takeover_first"]
    assert trial({**config, "method": "frozen"}) == results["frozen"]  # a finished folder is read back
