"""`sage study ugv`: the paper's four-scenario table, every method from the same warm start and budget."""

from __future__ import annotations

from pathlib import Path

from studies.registry import _unpack, get_study
from studies.ugv import METRICS, trial


def test_the_ugv_study_is_registered_with_the_papers_rows_beside() -> None:
    from studies.paper import paper_value

    study = get_study("ugv")
    assert study.keys == ("scenario", "method") and "sage" in study.methods and "scripted" in study.methods
    assert paper_value("ugv", ("3", "sage"), "success_rate_pct").mean == 100.0
    assert paper_value("ugv", ("4", "sac"), "avg_speed").mean == 0.49


def test_a_trial_adapts_from_the_warm_start_and_reports_every_scenario(tmp_path: Path) -> None:
    config = {"method": "sac", "seed": 1, "train_steps": 60, "eval_episodes": 1, "min_eval_episodes": 1,
              "scenarios": ["1", "3"], "runs_dir": str(tmp_path)}  # fmt: skip
    result = trial(config)
    assert (tmp_path / "sac-s1" / "checkpoint.pt").is_file()
    assert set(result) == {f"{s}/{m}" for s in ("1", "3") for m in METRICS}
    rows = _unpack({"method": "sac", "seed": 1, **result}, ("scenario",), METRICS)
    assert sorted(r["scenario"] for r in rows) == ["1", "3"] and all(set(METRICS) <= set(r) for r in rows)
    scripted = trial({**config, "method": "scripted"})
    assert scripted["1/success_rate_pct"] == 100.0 and scripted["3/collision_rate_pct"] == 0.0


def test_all_the_papers_methods_are_rows_and_the_baselines_run_through_the_same_trial(tmp_path: Path) -> None:
    """The paper's eight methods (plus our scripted reference); the offline learners spend the budget on
    demonstrations, the planner is evaluated as it is."""
    import json

    from studies.paper import paper_value

    study = get_study("ugv")
    paper_rows = ("teb", "sac", "td3", "hg-dagger", "diffusion-bc", "diffusion-ql", "multi-hug", "sage")
    assert set(paper_rows) <= set(study.methods)
    assert all(paper_value("ugv", ("1", m), "success_rate_pct") is not None for m in paper_rows)
    config = {"seed": 2, "train_steps": 150, "eval_episodes": 1, "scenarios": ["2"], "runs_dir": str(tmp_path)}
    offline = trial({**config, "method": "diffusion-bc"})
    rows = [json.loads(line) for line in (tmp_path / "diffusion-bc-s2" / "metrics.jsonl").read_text().splitlines()]
    assert {r["phase"] for r in rows} == {"demo"} and sum(r["steps"] for r in rows) == 150
    assert set(offline) == {f"2/{m}" for m in METRICS}
    teb = trial({**config, "method": "teb"})
    assert teb["2/success_rate_pct"] == 100.0 and not (tmp_path / "teb-s2").exists()
