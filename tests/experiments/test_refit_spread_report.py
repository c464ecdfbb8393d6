"""The refit-spread bench's equal-takeover table: each arm at each τ scale, the deployed gate's rows as scale 1."""

from __future__ import annotations

import argparse
from pathlib import Path

from experiments.calibration import table_scenarios
from experiments.refit_spread import arms, earlier_rows, rank_report, report, scaled_report


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


def test_the_ranking_table_gives_each_arms_auroc_over_seeds_and_names_the_rows_without_a_violation() -> None:
    args = argparse.Namespace(sim="ugv", arms=["states16k", "approach"], seeds=[0, 1], rank_episodes=150)
    nan = float("nan")

    def row(auroc: float, elsewhere: float) -> dict[str, float]:
        return {"auroc": auroc, "fire_elsewhere": elsewhere}

    ranked = {
        ("states16k", 0, "4"): row(0.80, 0.50),
        ("states16k", 1, "4"): row(0.90, 0.30),
        ("approach", 0, "4"): row(0.95, 0.10),
        ("approach", 1, "4"): row(nan, 0.20),  # that refit's policy never collided: nothing to rank
        ("deployed", "deployed", "4"): row(0.87, 0.50),
        ("approach", "merged", "4"): row(0.97, 0.18),
        ("states16k", 0, "1"): row(nan, 0.05),
        ("states16k", 1, "1"): row(nan, 0.05),
        ("approach", 0, "1"): row(nan, 0.05),
        ("approach", 1, "1"): row(nan, 0.05),
        ("deployed", "deployed", "1"): row(nan, 0.05),
        ("approach", "merged", "1"): row(nan, 0.05),
    }
    lines = rank_report(args, ranked)
    (ugv4,) = [line for line in lines if line.startswith("| ugv 4 |")]
    cells = [cell.strip() for cell in ugv4.strip("|").split("|")]
    assert cells[1] == "0.80 · 0.90" and cells[2].startswith("0.850 ±") and cells[3] == "40%"
    assert cells[4] == "0.95 · –" and cells[5] == "–" and cells[6] == "15%"  # one known AUROC: no interval
    assert cells[7] == "0.87 · 50%"  # the committed model's own
    assert cells[8] == "0.97 · 18%"  # then each arm's merged refits
    assert cells[9] == "–"  # no p from a single value
    assert not any(line.startswith("| ugv 1 |") for line in lines)
    assert lines[-1] == "No violation with the policy alone, so nothing to rank, on: ugv 1."
    header = next(line for line in lines if line.startswith("| scenario"))
    assert header.index("committed: AUROC") < header.index("approach, merged: AUROC") < header.index("| p, approach")


def test_the_gate_table_tests_each_arms_takeover_as_well_as_its_violations_against_the_first_arm() -> None:
    args = argparse.Namespace(
        sim="ugv", arms=["states16k", "approach"], seeds=[0, 1, 2], episodes=100, merge=False, rank_episodes=150
    )
    measured = {}
    for scenario in table_scenarios("ugv"):
        for seed in args.seeds:
            measured["states16k", seed, scenario] = {"violations": 5 + seed, "takeover": 0.38 + 0.01 * seed}
            measured["approach", seed, scenario] = {"violations": 7 - seed, "takeover": 0.28 + 0.01 * seed}
    lines = report(args, arms("ugv"), measured, "abc1234", [])
    header = next(line for line in lines if line.startswith("| scenario"))
    assert header.endswith("| p, approach vs states16k: violations · takeover |")
    (ugv4,) = [line for line in lines if line.startswith("| ugv 4 |")]
    violations_p, takeover_p = (float(p) for p in ugv4.strip("| ").split("|")[-1].split(" · "))
    assert violations_p == 1.0  # the same mean, 6 either way
    assert takeover_p < 0.001  # 38-40% against 28-30%, the same spread
    assert "of the violations and of the takeover" in lines[2] and "--rank-episodes 150` at commit abc1234" in lines[2]
