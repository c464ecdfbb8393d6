"""`sage study cycles`: fine-tuning cycles against the frozen control, the same situations and steps for both."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from studies.cycles_study import METRICS, cycles_above_first, cycles_for, figures, steps_per_cycle, trial
from studies.registry import get_study


def test_the_cycles_study_compares_fine_tuning_with_a_frozen_control_alone_and_supervised(tmp_path: Path) -> None:
    assert get_study("cycles").methods == ("frozen", "sage")
    assert (cycles_for(200), cycles_for(6000), cycles_for(10**6)) == (2, 9, 9)
    assert steps_per_cycle(6000) == 666 and steps_per_cycle(200) == 100  # the budget, in environment steps
    config = {"seed": 0, "train_steps": 120, "eval_episodes": 1, "runs_dir": str(tmp_path), "max_episode_steps": 50}
    results = {method: trial({**config, "method": method}) for method in ("frozen", "sage")}
    for result in results.values():
        assert set(METRICS) <= set(result) and result["cycles"] == 2
        assert result["steps"] == 120  # both methods deploy exactly the budget's steps
    frozen = json.loads((tmp_path / "frozen-s0" / "cycles.json").read_text())
    tuned = json.loads((tmp_path / "sage-s0" / "cycles.json").read_text())
    assert frozen["rounds"] == [] and [c["version"] for c in frozen["cycles"]] == [0, 0]
    assert len(tuned["rounds"]) == 1 and tuned["cycles"][-1]["version"] > 0
    assert tuned["method"].startswith("sage: fear-regularised SAGE")  # the SAC-trained default adapts as SAGE
    # every cycle measures its version alone, on the scenario and on the unseen one of the same kind
    assert {(a["cycle"], a["scenario"], a["seen"]) for a in tuned["alone"]} == {
        (1, "3", True),
        (1, "4", False),
        (2, "3", True),
        (2, "4", False),
    }
    assert all(c["alone_success"] is not None and c["unseen_success"] is not None for c in tuned["cycles"])
    # the first cycle is the same policy in the same situation for both
    assert results["frozen"]["takeover_first"] == results["sage"]["takeover_first"]
    assert results["frozen"]["alone_success_first"] == results["sage"]["alone_success_first"]
    assert trial({**config, "method": "frozen"}) == results["frozen"]  # a finished folder is read back
    drawn = figures(tmp_path / "results", {"runs_dir": str(tmp_path)})
    assert [p.name for p in drawn] == ["cycles_improvement.png"] and drawn[0].read_bytes()[:4] == b"\x89PNG"


def test_cycles_with_more_supervised_collisions_than_the_first_are_counted() -> None:
    """The issue's "no cycle with more supervised collisions than the first": a middle cycle counts too."""
    rows = [{"collision": 0.2}, {"collision": 0.4}, {"collision": 0.2}, {"collision": None}, {"collision": 0.25}]
    assert cycles_above_first(rows, "collision") == 2  # 0.4 and 0.25; equal to the first is not above it
    assert cycles_above_first([{"collision": 0.0}, {"collision": 0.0}], "collision") == 0
    assert cycles_above_first([], "collision") == 0


def test_the_cycles_study_passes_fine_tuning_settings_to_its_rounds(tmp_path: Path) -> None:
    config = {"seed": 2, "train_steps": 120, "eval_episodes": 1, "runs_dir": str(tmp_path), "max_episode_steps": 50}
    trial({**config, "method": "sage", "finetune": ["critic_warmup=5"]})
    tuned = json.loads((tmp_path / "sage-s2" / "cycles.json").read_text())
    assert tuned["config"]["finetune"]["critic_warmup"] == 5
    assert tuned["config"]["finetune"]["seed"] == 2  # the training seed seeds the rounds, not 0 for every seed
    assert tuned["rounds"][0]["losses"]["critic_warmup_updates"] == 5


def test_the_cycles_study_passes_learner_settings_to_its_rounds(tmp_path: Path) -> None:
    """``sage study cycles --set learner.KEY=VALUE`` edits every round's learner: with the dual's rate at 0, λ stays
    where the checkpoint left it, where the default rate raises it (the round's fear is above its budget)."""
    from studies.training import LEARNER_OVERRIDES

    config = {"seed": 2, "train_steps": 120, "eval_episodes": 1, "runs_dir": str(tmp_path), "max_episode_steps": 50}
    trial({**config, "method": "sage", LEARNER_OVERRIDES: ["lambda_lr=0"]})
    tuned = json.loads((tmp_path / "sage-s2" / "cycles.json").read_text())
    assert tuned["config"]["finetune"]["overrides"] == ["lambda_lr=0"]
    losses = tuned["rounds"][0]["losses"]
    assert losses["fear_real"] > losses["fear_budget"]  # so the default rate would have moved λ
    assert losses["lam_end"] == losses["lam_start"]


def test_the_cycles_study_can_compare_its_versions_alone_with_the_version_in_control() -> None:
    from studies.cycles_study import check_settings, promotion_of

    settings = {"regression_scenarios": ("3",), "regression_against": "control"}
    promotion = promotion_of(settings)
    assert promotion is not None and promotion.regression_against == "control" and not promotion.supervised
    assert promotion_of({"regression_scenarios": ("1", "2")}).regression_against == "base"  # the default: v0000
    with pytest.raises(ValueError, match="regression_against=best: base"):
        check_settings({"regression_against": "best"})


def test_the_cycles_study_runs_on_a_procedural_field_with_another_field_unseen(tmp_path: Path) -> None:
    config = {
        "seed": 0,
        "train_steps": 60,
        "eval_episodes": 1,
        "runs_dir": str(tmp_path),
        "max_episode_steps": 30,
        "scenario": "ugv-fields:test:1",
        "unseen_scenario": "ugv-fields:test:4",
    }
    result = trial({**config, "method": "frozen"})
    assert result["steps"] == 60
    from studies.budgets import BUDGETS
    from studies.cycles_study import budget_text

    header = budget_text(BUDGETS["small"], config)  # the table says which fields it ran
    assert "scenario ugv-fields:test:1" in header and "unseen one (ugv-fields:test:4)" in header
    run = json.loads((tmp_path / "frozen-s0" / "cycles.json").read_text())
    assert {(a["scenario"], a["seen"]) for a in run["alone"]} == {
        ("ugv-fields:test:1", True),
        ("ugv-fields:test:4", False),
    }


def test_the_cycles_study_coaches_on_its_share_of_the_agents_steps_and_the_rounds_imitate_the_labels(
    tmp_path: Path,
) -> None:
    config = {"seed": 1, "train_steps": 120, "eval_episodes": 1, "runs_dir": str(tmp_path), "max_episode_steps": 50}
    trial({**config, "method": "sage", "coach_share": 0.5})
    tuned = json.loads((tmp_path / "sage-s1" / "cycles.json").read_text())
    assert tuned["config"]["coach_share"] == 0.5
    first = tuned["cycles"][0]
    # about half of the agent's own steps carry a label; the takeover rate counts the expert's driving only
    assert 0.3 < first["coached_rate"] / (1 - first["takeover_rate"]) < 0.7
    assert tuned["rounds"][0]["coached"] == sum(e.get("coached", 0) for e in tuned["episodes"] if e["cycle"] == 1)
    plain = tmp_path / "plain"
    trial({**config, "runs_dir": str(plain), "method": "sage"})
    untouched = json.loads((plain / "sage-s1" / "cycles.json").read_text())
    assert untouched["config"]["coach_share"] == 0.0 and untouched["rounds"][0]["coached"] == 0
    assert all(c["coached_rate"] == 0 for c in untouched["cycles"])


def test_the_cycles_study_refuses_a_bad_scenario_in_one_line(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from app.cli import app

    check = get_study("cycles").check_settings
    assert check is not None
    check({"sim": "ugv", "scenario": "ugv-fields:test:1", "unseen_scenario": "ugv-fields:test:4"})
    check({"sim": "ugv", "scenario": "3", "unseen_scenario": ""})  # UGV 4, the built-in unseen one
    for pairs, words in (
        (["study.scenario=ugv-fields:test:x"], "the index must be a whole number"),
        (["study.scenario=9"], "give 1-4"),
        (["study.scenario=ugv-fields:test:1", "study.unseen_scenario=ugv-fields:test:1"], "must differ"),
        (["study.scenario=4", "study.unseen_scenario=bogus"], "study.unseen_scenario=bogus"),
        (["study.policy=runs/no-such-policy"], "study.policy=runs/no-such-policy"),
        (["study.coach_share=1.5"], "study.coach_share=1.5"),
        (["study.expert=nobody"], "study.expert=nobody: unknown planner"),
        (["study.expert=teb", "study.coach_share=0.25"], "is the scripted expert's"),
    ):
        args = ["study", "cycles", "--budget", "small", "--out", str(tmp_path / "never")]
        for pair in pairs:
            args += ["--set", pair]
        result = CliRunner().invoke(app, args)
        assert result.exit_code == 2, result.output
        assert words in result.output and "Traceback" not in result.output
        assert len(result.output.strip().splitlines()) == 1
    assert not (tmp_path / "never").exists()  # refused before any trial


def test_the_cycles_study_hands_its_trials_the_starting_policy_as_an_absolute_path(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from studies.cycles_study import DEFAULT_POLICY, prepare

    monkeypatch.chdir(DEFAULT_POLICY.parents[1])  # the repository root, where the path below is relative
    given = Path("policies") / DEFAULT_POLICY.name
    prepared = prepare(tmp_path, {"policy": str(given)})
    assert Path(prepared["policy"]).is_absolute() and Path(prepared["policy"]) == DEFAULT_POLICY


def test_the_cycles_study_can_judge_its_versions_by_the_regression_test_alone(tmp_path: Path) -> None:
    from studies.cycles_study import promotion_of

    assert promotion_of(get_study("cycles").settings) is None  # by default every version drives, as before
    config = {"seed": 0, "train_steps": 120, "eval_episodes": 1, "runs_dir": str(tmp_path), "max_episode_steps": 50}
    trial({**config, "method": "sage", "regression_scenarios": ["1", "2"]})
    tuned = json.loads((tmp_path / "sage-s0" / "cycles.json").read_text())
    promotion = tuned["config"]["promotion"]
    assert promotion["supervised"] is False and list(promotion["regression_scenarios"]) == ["1", "2"]
    verdict = tuned["rounds"][0]["promotion"]
    assert "regression" in verdict["reason"] or "no worse alone" in verdict["reason"]
    # a rejected version is not deployed: the last cycle drives the version in control
    assert tuned["cycles"][-1]["version"] == (1 if verdict["promoted"] else 0)


def test_the_cycles_study_measures_forgetting_on_the_static_scenarios_first_and_last(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Issue 62's "scenarios 1-2 alone no worse than the default's": the first and the last cycle's version alone on
    UGV 1 and 2, on the alone evaluations' seeds, kept per scenario in the run folder and read back."""
    import studies.cycles as cycles_module
    from studies.cycles_study import STATIC_FILE, static_scenarios_of

    assert static_scenarios_of({"sim": "ugv"}) == ("1", "2")  # the UGV default
    assert static_scenarios_of({"sim": "ugv", "static_scenarios": "none"}) == ()
    assert static_scenarios_of({"sim": "ugv", "static_scenarios": ["2"]}) == ("2",)
    assert static_scenarios_of({"sim": "highway"}) == ()  # a simulator without static scenarios measures none
    # full-length episodes: the starting policy solves the static scenarios alone, so a forgetting version would show
    config = {"seed": 1, "train_steps": 120, "eval_episodes": 1, "runs_dir": str(tmp_path)}
    frozen = trial({**config, "method": "frozen"})
    assert frozen["static_success_first"] == 1.0 and frozen["static_success_last"] == 1.0
    assert frozen["static_success_change"] == 0.0
    short = {**config, "max_episode_steps": 50, "runs_dir": str(tmp_path / "short")}
    tuned = trial({**short, "method": "sage"})
    run = json.loads((tmp_path / "short" / "sage-s1" / "cycles.json").read_text())
    last = run["cycles"][-1]["version"]
    static = json.loads((tmp_path / "short" / "sage-s1" / STATIC_FILE).read_text())
    assert static["seed"] == run["config"]["alone_seed"] and static["max_steps"] == 50
    assert {(r["version"], r["scenario"]) for r in static["rows"]} == {(0, "1"), (0, "2"), (last, "1"), (last, "2")}
    assert last > 0 and all(r["episodes"] == 1 and r["steps"] <= 50 for r in static["rows"])
    assert tuned["static_success_change"] == pytest.approx(tuned["static_success_last"] - tuned["static_success_first"])

    def never(*args: object, **kwargs: object) -> None:
        raise AssertionError("a finished trial's static evaluations are read back, not driven again")

    monkeypatch.setattr(cycles_module, "drive_alone_rates", never)
    assert trial({**short, "method": "sage"}) == tuned
    skipped = trial({**short, "method": "sage", "static_scenarios": "none"})
    assert all(math.isnan(skipped[k]) for k in ("static_success_first", "static_success_last"))
    check = get_study("cycles").check_settings
    assert check is not None
    with pytest.raises(ValueError, match=r"study\.static_scenarios=9"):
        check({"sim": "ugv", "scenario": "3", "static_scenarios": "1,9"})
