"""`sage study route-shift`: the route switch by environment steps, the same budget for every method."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from studies.registry import get_study
from studies.route_shift import read_run
from studies.route_shift_study import C1_SHARE, METRICS, trial
from studies.training import prepare_training


def test_the_route_shift_study_is_registered_with_the_papers_methods() -> None:
    study = get_study("route-shift")
    assert study.methods == ("sac", "fni-rl", "sage") and study.prepare is not None


def test_the_switch_comes_after_the_c1_share_of_the_step_budget(tmp_path: Path) -> None:
    budget = 1200
    result = trial({"method": "sac", "seed": 0, "train_steps": budget, "eval_episodes": 1, "demo_episodes": 1,
                    "runs_dir": str(tmp_path)})  # fmt: skip
    assert set(METRICS) <= set(result)
    run = read_run(tmp_path / "sac-s0")
    study = json.loads((tmp_path / "sac-s0" / "study.json").read_text())
    rows = [json.loads(line) for line in (tmp_path / "sac-s0" / "metrics.jsonl").read_text().splitlines()]
    demo_steps = sum(r["steps"] for r in rows if r["phase"] == "demo")
    assert study["switch_episode"] == run.switch and study["c1_steps"] == round(C1_SHARE * (budget - demo_steps))
    c1_steps = sum(r["steps"] for r in run.rows[: run.switch])
    assert c1_steps >= study["c1_steps"] > c1_steps - run.rows[run.switch - 1]["steps"]  # the first episode after
    assert {r["route"] for r in run.rows[: run.switch]} == {1} and {r["route"] for r in run.rows[run.switch :]} == {2}
    assert rows[-1]["steps_done"] == budget


def test_a_switch_by_steps_needs_a_step_budget_and_no_episode_counts() -> None:
    with pytest.raises(ValueError, match="needs --train-steps"):
        prepare_training("sumo", protocol="route-shift", c1_share=0.5)
    with pytest.raises(ValueError, match="drop --c1 and --c2"):
        prepare_training("sumo", protocol="route-shift", c1_share=0.5, c1=3, bounded_by_steps=True)
