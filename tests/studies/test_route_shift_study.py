"""`sage study route-shift`: the route switch by environment steps, the same budget for every method."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from studies.registry import get_study
from studies.route_shift import read_run
from studies.route_shift_study import C1_SHARE, DEMO_SHARE, METRICS, trial
from studies.training import prepare_training


def test_the_route_shift_study_is_registered_with_the_papers_methods() -> None:
    study = get_study("route-shift")
    assert study.methods == ("sac", "fni-rl", "sage") and study.prepare is not None


def test_the_switch_comes_after_the_c1_share_of_the_step_budget(tmp_path: Path) -> None:
    budget = 600  # five route-1 demonstrations alone would take more than the whole budget
    result = trial({"method": "sac", "seed": 0, "train_steps": budget, "eval_episodes": 1, "demo_episodes": 5,
                    "runs_dir": str(tmp_path)})  # fmt: skip
    assert set(METRICS) <= set(result)
    run = read_run(tmp_path / "sac-s0")
    study = json.loads((tmp_path / "sac-s0" / "study.json").read_text())
    rows = [json.loads(line) for line in (tmp_path / "sac-s0" / "metrics.jsonl").read_text().splitlines()]
    demo_steps = sum(r["steps"] for r in rows if r["phase"] == "demo")
    assert demo_steps == DEMO_SHARE * budget  # the demonstrations stop at their share, leaving C1 and C2 steps
    assert study["switch_episode"] == run.switch and study["c1_steps"] == round(C1_SHARE * (budget - demo_steps))
    c1_steps = sum(r["steps"] for r in run.rows[: run.switch])
    assert c1_steps == study["c1_steps"]  # C1's last episode is cut where its steps end: the same for every method
    assert {r["route"] for r in run.rows[: run.switch]} == {1} and {r["route"] for r in run.rows[run.switch :]} == {2}
    assert rows[-1]["steps_done"] == budget


def test_a_switch_by_steps_needs_a_step_budget_and_no_episode_counts() -> None:
    with pytest.raises(ValueError, match="needs --train-steps"):
        prepare_training("sumo", protocol="route-shift", c1_share=0.5)
    with pytest.raises(ValueError, match="drop --c1 and --c2"):
        prepare_training("sumo", protocol="route-shift", c1_share=0.5, c1=3, bounded_by_steps=True)


@pytest.mark.slow  # SUMO experts and six SUMO trials (~3 min); the trial and run_tasks tests cover the same path
def test_the_smoke_study_trains_one_rl_expert_per_route_and_hands_each_its_phase(
    ray_local: None, tmp_path: Path
) -> None:
    from studies.registry import run_study

    table = run_study("route-shift", "smoke", tmp_path, log=lambda _: None, overrides={"expert": "sac"})
    text = table.read_text()
    assert "The expert (sac, trained on route1) alone" in text and "sac, trained on route2" in text
    experts = {route: (tmp_path / "experts" / "sac" / route).resolve() for route in ("route1", "route2")}
    for route, scenario in (("route1", "c1"), ("route2", "c2")):
        config = json.loads((experts[route] / "config.json").read_text())
        assert config["run"]["scenarios"] == [scenario] and config["meta"]["method"] == "sac"
    study = json.loads((tmp_path / "runs" / "sage-s0" / "study.json").read_text())
    assert (study["expert_c1"], study["expert_c2"]) == (str(experts["route1"]), str(experts["route2"]))
