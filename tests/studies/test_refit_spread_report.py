"""The refit-spread bench's equal-takeover table: each arm at each τ scale, the deployed gate's rows as scale 1."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))

from bench_refit_spread import earlier_rows, scaled_report


def test_the_equal_takeover_table_puts_each_arm_at_each_scale_beside_the_deployed_gate(tmp_path: Path) -> None:
    args = argparse.Namespace(
        sim="highway", arms=["plain", "conflict"], seeds=[5, 6], episodes=100, scales=[0.5], scale_scenarios=None
    )
    scenario = "train-adversarial"
    measured = {
        ("plain", 5, scenario): {"violations": 10, "takeover": 0.10},
        ("plain", 6, scenario): {"violations": 8, "takeover": 0.12},
        ("conflict", 5, scenario): {"violations": 6, "takeover": 0.16},
        ("conflict", 6, scenario): {"violations": 6, "takeover": 0.14},
    }
    scaled = {
        ("plain", 5, scenario, 0.5): {"violations": 7, "takeover": 0.17},
        ("plain", 6, scenario, 0.5): {"violations": 5, "takeover": 0.15},
        ("conflict", 5, scenario, 0.5): {"violations": 3, "takeover": 0.22},
        ("conflict", 6, scenario, 0.5): {"violations": 5, "takeover": 0.24},
    }
    lines = scaled_report(args, measured, scaled)
    rows = [line for line in lines if line.startswith("| highway train-adversarial")]
    assert len(rows) == 2  # scale 1 (as deployed) first, then 0.5
    deployed, half = rows
    assert "| 1 |" in deployed and "9.0 ±" in deployed and "@ 11%" in deployed and "6.0 ± 0.0 @ 15%" in deployed
    assert "| 0.5 |" in half and "6.0 ±" in half and "@ 16%" in half and "4.0 ±" in half and "@ 23%" in half
    assert "`--scales 0.5`" in lines[1]

    # an earlier run's rows.json with scaled rows: --rows takes the deployed-gate rows alone
    saved = tmp_path / "rows.json"
    saved.write_text(
        '[{"arm": "plain", "seed": 5, "scenario": "x", "violations": 1, "takeover": 0.1},'
        ' {"arm": "plain", "seed": 5, "scenario": "x", "scale": 0.5, "violations": 0, "takeover": 0.2}]'
    )
    assert earlier_rows(saved) == {
        ("plain", 5, "x"): {"arm": "plain", "seed": 5, "scenario": "x", "violations": 1, "takeover": 0.1}
    }
