"""`sage study highway`: the paper's split x method x condition table, equal budgets and demonstrations."""

from __future__ import annotations

import json
from pathlib import Path

from studies.highway_study import METRICS, figures, trial
from studies.paper import paper_value
from studies.registry import _unpack, get_study
from studies.training import LEARNER_OVERRIDES


def test_the_highway_study_has_the_papers_rows_beside() -> None:
    study = get_study("highway")
    assert study.keys == ("split", "method", "condition") and study.methods == ("sac", "td3", "fni-rl", "sage")
    assert paper_value("highway", ("test", "sac", "adversarial"), "success_rate_pct").mean == 46.8


def test_every_method_gets_the_same_demonstrations_within_the_same_step_budget(tmp_path: Path) -> None:
    # two demonstrations take 300-400 steps; the budget leaves room for the two training episodes a curve needs. The
    # pretraining on them is cut short (half the trial's time at its default length): what is shared is the data
    config = {"seed": 1, "train_steps": 700, "eval_episodes": 1, "demo_episodes": 2, "runs_dir": str(tmp_path)}
    config[LEARNER_OVERRIDES] = ["pretrain_bc_steps=200", "pretrain_critic_steps=200"]
    results = {method: trial({**config, "method": method}) for method in ("sac", "sage")}
    demos = {}
    for method in ("sac", "sage"):
        lines = (tmp_path / f"{method}-s1" / "metrics.jsonl").read_text().splitlines()
        rows = [json.loads(line) for line in lines]
        demos[method] = [(r["steps"], round(r["return"], 6)) for r in rows if r["phase"] == "demo"]
        assert sum(r["steps"] for r in rows) == 700 and any(r["phase"] == "train" for r in rows)
    assert demos["sac"] == demos["sage"] and len(demos["sac"]) == 2
    table_rows = _unpack({"method": "sac", "seed": 1, **results["sac"]}, ("split", "condition"), METRICS)
    assert sorted((r["split"], r["condition"]) for r in table_rows) == sorted(
        (s, c) for s in ("train", "test") for c in ("normal", "adversarial")
    )
    paths = figures(tmp_path, {"runs_dir": str(tmp_path)})
    assert [p.name for p in paths] == ["learning_curves.png"] and paths[0].stat().st_size > 0
