"""The study registry and ``sage study``: a registered study runs on Ray and writes its results folder."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from studies.registry import StudyDef, get_study, register_study, run_study, unregister_study


def split_trial(config: dict[str, Any]) -> dict[str, float]:
    """Two table rows per trial (split a and b); the collision rate grows with the seed, larger for 'b'."""
    steps = float(config["train_steps"])
    return {"a/collision_rate": 0.1 * config["seed"], "b/collision_rate": 1.0 + config["seed"], "a/steps": steps}


@pytest.fixture
def toy_study():
    study = StudyDef(
        "toy-split", ("sage",), split_trial, metrics=("collision_rate",), keys=("split", "method"),
        notes=("toy",),
    )  # fmt: skip
    register_study(study)
    yield study
    unregister_study(study.name)


def test_registry_refuses_duplicates_and_unknown_names(toy_study: StudyDef) -> None:
    assert get_study("toy-split") is toy_study
    with pytest.raises(ValueError, match="already registered"):
        register_study(toy_study)
    with pytest.raises(ValueError, match=r"unknown study 'nope'.*toy-split"):
        get_study("nope")


def test_cli_refuses_unknown_study_and_budget(toy_study: StudyDef) -> None:
    from app.cli import app

    result = CliRunner().invoke(app, ["study", "nope"])
    assert result.exit_code == 2 and "unknown study" in result.output
    result = CliRunner().invoke(app, ["study", "toy-split", "--budget", "huge"])
    assert result.exit_code == 2 and "smoke, small, full" in result.output
    result = CliRunner().invoke(app, ["study", "toy-split", "--set", "study.nope=1"])
    assert result.exit_code == 2 and "--set study.nope=1: toy-split has no setting 'nope'" in result.output
    result = CliRunner().invoke(app, ["study", "toy-split", "--methods", "sage,nope"])
    assert result.exit_code == 2 and "toy-split has no nope; its: sage" in result.output


def test_a_study_runs_a_subset_of_its_methods_for_a_given_step_budget(ray_local: None, tmp_path: Path) -> None:
    study = StudyDef("toy-two", ("sac", "sage"), split_trial, metrics=("collision_rate",), keys=("split", "method"))
    register_study(study)
    try:
        with pytest.raises(ValueError, match="toy-two has no method td3"):
            run_study("toy-two", "smoke", tmp_path, log=lambda _: None, methods=["td3"])
        from app.cli import app

        readme = tmp_path / "README.md"
        args = ["study", "toy-two", "--budget", "smoke", "--methods", "sage", "--train-steps", "1234", "--out"]
        args += [str(tmp_path), "--results-doc", str(readme), "--section", "toy-long"]
        result = CliRunner().invoke(app, args)
        assert result.exit_code == 0, result.output
        # the same folder with another budget: its committed trials are refused in one line, never mixed in
        again = CliRunner().invoke(app, [*args[:7], "999", *args[8:]])
        assert again.exit_code == 2 and "sage-s0.json ran with other settings (train_steps)" in again.output
    finally:
        unregister_study(study.name)
    text = (tmp_path / "table.md").read_text()
    # the README gets its own section for this comparison, beside the study's
    assert "<!-- results:toy-long -->\n### toy-long" in readme.read_text()
    assert "| a | sage |" in text and "| a | sac |" not in text
    assert "1234 environment steps per method and seed" in text and "Methods run: sage (the study's: sac, sage)" in text
    rows = (tmp_path / "seeds.csv").read_text().splitlines()
    assert len(rows) == 1 + 2 * 2  # header + 2 seeds x 2 splits, one method


def test_study_runs_every_seed_and_writes_rows_per_split(ray_local: None, toy_study: StudyDef, tmp_path: Path) -> None:
    table = run_study("toy-split", "smoke", tmp_path, log=lambda _: None)
    first = table.read_text()
    table = run_study("toy-split", "smoke", tmp_path, log=lambda _: None)  # resumes: nothing left to run
    text = table.read_text()
    # the table's wall time is the sum over both invocations, and says so
    assert "over the 1 invocation(s)" in first and "over the 2 invocation(s)" in text
    assert "The host's reference speed is not measured at the smoke budget." in text
    import json

    runs = json.loads((tmp_path / "trials" / "wall_times.json").read_text())
    assert len(runs) == 2 and all(r["wall_s"] > 0 and r["finished"] for r in runs)
    total_min = sum(r["wall_s"] for r in runs) / 60
    assert f"wall time {total_min:.1f} min on the CPU (" in text  # and where: the processor's model name
    # smoke budget: two seeds (0, 1); split a: 0.0, 0.1 -> mean 0.05; split b: 1, 2 -> mean 1.5
    assert "| a | sage | 2 | 0.050 ± 0.635 | — |" in text
    assert "| b | sage | 2 | 1.500 ± 6.353 | — |" in text
    assert (tmp_path / "seeds.csv").read_text().count("\n") == 5  # header + 2 seeds x 2 splits
    # another machine: the committed ledger without Tune's state (sweep/) gives the same table, running nothing
    assert sorted(p.name for p in (tmp_path / "trials").glob("*-s*.json")) == ["sage-s0.json", "sage-s1.json"]
    import shutil

    shutil.rmtree(tmp_path / "sweep")
    table = run_study("toy-split", "smoke", tmp_path, log=lambda _: None)
    assert "| b | sage | 2 | 1.500 ± 6.353 | — |" in table.read_text()
    assert not (tmp_path / "sweep").exists()  # no Ray experiment was started


def test_a_study_beyond_the_smoke_budget_states_the_hosts_reference_speed(
    ray_local: None, toy_study: StudyDef, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import json

    import studies.registry
    from studies.host_speed import HostSpeed

    asked: list[str] = []

    def fake_speed() -> HostSpeed:  # the reference itself is measured in tests/studies/test_host_speed.py
        asked.append("measured")
        return HostSpeed(1234.0, 56.7, 2.5, "Test CPU")

    monkeypatch.setattr(studies.registry, "measure_host_speed", fake_speed)
    assert studies.registry._host_speed("smoke", print)[0] is None and asked == []  # the smoke budget is not timed
    said: list[str] = []
    speed, _ = studies.registry._host_speed("small", said.append)
    assert asked == ["measured"] and speed is not None and "1,234 UGV steps/s" in said[0]

    def failing() -> HostSpeed:
        raise RuntimeError("no simulator here\nand a second line")

    monkeypatch.setattr(studies.registry, "measure_host_speed", failing)
    missing, sentence = studies.registry._host_speed("small", said.append)
    assert (
        missing is None
        and sentence == "The host's reference speed could not be measured (RuntimeError: no simulator here)."
    )
    assert "the study runs without it" in said[-1]
    # what a study does with it (run here at the smoke budget, two seeds, with the speed handed in)
    monkeypatch.setattr(studies.registry, "_host_speed", lambda budget_name, log: (speed, ""))
    text = run_study("toy-split", "smoke", tmp_path, log=lambda _: None).read_text()
    assert (
        "Before its trials, this host's reference speed (`python -m studies.host_speed`, Test CPU): 1,234 UGV" in text
    )
    assert "56.7 SAC updates/s" in text and "not measured at the smoke budget" not in text
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["host_speed"]["sim_steps_per_s"] == 1234.0 and summary["host_speed"]["processor"] == "Test CPU"
    runs = json.loads((tmp_path / "trials" / "wall_times.json").read_text())
    assert runs[-1]["host_speed"]["sac_updates_per_s"] == 56.7


def overrides_trial(config: dict[str, Any]) -> dict[str, float]:
    """The learner overrides the trial's run would train with (:func:`studies.training.with_study_overrides`)."""
    from studies.spec import TrainSpec
    from studies.training import with_study_overrides

    spec = with_study_overrides(TrainSpec(sim="ugv", overrides=["hidden=32"]), config)
    assert spec.overrides[0] == "hidden=32"  # the method's own first, the study's after
    return {"collision_rate": float(len(spec.overrides)), "lambda_init": float("lambda_init=0.25" in spec.overrides)}


def test_learner_overrides_reach_every_trial_and_are_stated_under_the_table(ray_local: None, tmp_path: Path) -> None:
    from app.cli import app

    study = StudyDef("toy-ablation", ("sage",), overrides_trial, metrics=("collision_rate", "lambda_init"))
    register_study(study)
    try:
        args = ["study", "toy-ablation", "--budget", "smoke", "--out", str(tmp_path)]
        args += ["--set", "learner.fear_budget_from_data=false", "--set", "lambda_init=0.25"]
        result = CliRunner().invoke(app, args)
        assert result.exit_code == 0, result.output
        # a setting no learner has is refused before any trial runs, and so is one of the wrong type
        for bad in ("nope=1", "lambda_init=high"):
            result = CliRunner().invoke(app, ["study", "toy-ablation", "--budget", "smoke", "--set", f"learner.{bad}"])
            assert result.exit_code == 2 and f"--set learner.{bad}: " in result.output
    finally:
        unregister_study(study.name)
    text = (tmp_path / "table.md").read_text()
    assert "| sage | 2 | 3.000 ± 0.000 | — | 1.000 ± 0.000 | — |" in text
    assert "Learner settings changed for every method: fear_budget_from_data=false, lambda_init=0.25." in text


def test_a_study_that_trains_no_learner_of_its_own_refuses_learner_overrides(tmp_path: Path) -> None:
    from app.cli import app

    study = StudyDef("toy-planner", ("teb",), overrides_trial, metrics=("collision_rate",), learner_overrides=False)
    register_study(study)
    try:
        result = CliRunner().invoke(app, ["study", "toy-planner", "--budget", "smoke", "--set", "learner.hidden=16"])
        assert result.exit_code == 2 and "toy-planner trains no learner from a spec of its own" in result.output
        with pytest.raises(ValueError, match="takes no learner settings"):
            run_study("toy-planner", "smoke", tmp_path, log=lambda _: None, learner_overrides=["hidden=16"])
    finally:
        unregister_study(study.name)
    # the cycles study takes them: its rounds' learner edits (tests/studies/test_cycles_study.py)
    assert get_study("cycles").learner_overrides


def folder_trial(config: dict[str, Any]) -> dict[str, float]:
    """A learner writes its run folder, as a real trial does; a planner (``teb``) writes none."""
    if config["method"] != "teb":
        (Path(config["runs_dir"]) / f"{config['method']}-s{config['seed']}").mkdir(parents=True, exist_ok=True)
    return {"collision_rate": float(config["seed"])}


def test_only_learners_without_their_run_folder_are_said_to_have_run_elsewhere(ray_local: None, tmp_path: Path) -> None:
    study = StudyDef(
        "toy-planned", ("sage", "teb"), folder_trial, metrics=("collision_rate",), untrained=("teb",),
        figures=lambda out, settings: [],
    )  # fmt: skip
    register_study(study)
    try:
        here = run_study("toy-planned", "smoke", tmp_path, log=lambda _: None).read_text()
        assert "ran on another machine" not in here  # the planner's trials have no folder anywhere
        import shutil

        shutil.rmtree(tmp_path / "runs" / "sage-s1")  # as if that trial had run on another machine
        again = run_study("toy-planned", "smoke", tmp_path, log=lambda _: None).read_text()
    finally:
        unregister_study(study.name)
    assert "1 of 4 trials ran on another machine" in again
