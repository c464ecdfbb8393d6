"""`sage study pedestrian` end to end at the smoke budget: both methods, every seed, the table and the panels."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from studies.pedestrian import METRICS, read_rows, trial
from studies.registry import get_study, run_study, study_names


def test_the_pedestrian_study_is_registered() -> None:
    assert "pedestrian" in study_names()
    study = get_study("pedestrian")
    assert study.methods == ("d3qn", "sage-d3qn") and study.figures is not None


def test_a_trial_trains_within_the_step_budget_and_resumes_a_finished_run(tmp_path: Path) -> None:
    config = {"method": "sage-d3qn", "seed": 3, "train_steps": 120, "eval_episodes": 2, "runs_dir": str(tmp_path)}
    first = trial(config)
    rows = read_rows(tmp_path / "sage-d3qn-s3")
    assert rows[-1]["steps_done"] == 120 and set(METRICS) <= set(first)
    assert 0.0 <= first["train_collision_rate"] <= 1.0 and first["train_episodes"] == len(rows)
    again = trial(config)  # the finished run is evaluated again, not retrained
    assert again == first and len(read_rows(tmp_path / "sage-d3qn-s3")) == len(rows)


# ~30 s: the trial's path is the test above, the sweep's and the table's in tests/studies/test_registry.py
@pytest.mark.slow
def test_the_smoke_study_writes_seeds_table_and_figures(ray_local: None, tmp_path: Path) -> None:
    table = run_study("pedestrian", "smoke", tmp_path, log=lambda _: None, overrides={"expert": "hg-dagger"})
    with (tmp_path / "seeds.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert sorted((r["method"], r["seed"]) for r in rows) == [("d3qn", "0"), ("d3qn", "1"), ("sage-d3qn", "0"),
                                                              ("sage-d3qn", "1")]  # fmt: skip
    text = table.read_text()
    assert "train_collision_rate" in text and "sage-d3qn" in text and "expert=hg-dagger" in text
    # the expert itself, measured alone, is stated under the table
    assert "The expert (hg-dagger) alone, deterministic, 2 episodes per scenario: crossing: " in text
    assert (tmp_path / "reward.png").stat().st_size > 0 and (tmp_path / "safety_over_training.png").is_file()
    # the paper's kind of expert: trained by HG-DAgger once, cached, and used by SAGE-D3QN's takeovers only
    expert = (tmp_path / "experts" / "hg-dagger").resolve()
    assert (expert / "checkpoint.pt").is_file()
    runs = {
        json.loads((tmp_path / "runs" / name / "config.json").read_text())["run"]["expert"]
        for name in ("sage-d3qn-s0", "sage-d3qn-s1")
    }
    assert runs == {str(expert)}
    assert json.loads((tmp_path / "runs" / "d3qn-s0" / "config.json").read_text())["run"]["expert"] is None
