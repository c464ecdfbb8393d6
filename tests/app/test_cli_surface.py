"""The ``sage`` command surface: its nine commands, the retired spellings that name the new ones, the one ``--set``
syntax (one parser, :func:`core.dotted.route_settings`), the one ``--scenario`` syntax, and help that names every
method, planner and study."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from app.cli import app
from app.cli.options import scenario_list
from core.dotted import Section, route_settings

COMMANDS = {"serve", "train", "eval", "expert", "gate", "study", "cycles", "export", "figure"}
WIDE = {"COLUMNS": "1000"}  # one line per option: a name is never folded across lines
UGV_DEFAULT = str(Path(__file__).resolve().parents[2] / "policies" / "ugv-default")


def sage(*args: str) -> tuple[int, str]:
    result = CliRunner().invoke(app, list(args), env=WIDE)
    return result.exit_code, result.output


def listed_commands(help_text: str) -> set[str]:
    panel = help_text.split("Commands")[1]
    return {m.group(1) for m in re.finditer(r"^│ (\S+)\s", panel, re.MULTILINE)}


def test_sage_help_lists_the_nine_commands() -> None:
    code, out = sage("--help")
    assert code == 0
    assert listed_commands(out) == COMMANDS and len(COMMANDS) <= 10
    code, out = sage("gate", "--help")
    assert code == 0 and listed_commands(out) == {"evaluate", "choose-scale", "refit-bounds", "merge"}


@pytest.mark.parametrize(
    ("old", "new"),
    [
        ("calibrate", "gate evaluate"),
        ("choose-scale", "gate choose-scale"),
        ("recalibrate", "gate refit-bounds"),
        ("merge", "gate merge"),
        ("compare", "eval"),
    ],
)
def test_an_old_spelling_names_the_new_one_and_exits_2(old: str, new: str) -> None:
    for args in ([], ["runs/a", "--sim", "ugv", "--gate-set", "x=1"], ["--help"]):
        code, out = sage(old, *args)
        assert code == 2 and out.strip() == f"`sage {old}` is now `sage {new}`"


def test_set_pairs_are_routed_by_their_section() -> None:
    sections = {
        "env": Section("env"),
        "world_model": Section("learner", "world_model_config."),
        "learner": Section("learner"),
    }
    pairs = ["env.expert.horizon=0.5", "hidden=16", "learner.lr = 3", "world_model.violation_steps=3", "gate.beta=a=b"]
    assert route_settings(pairs, sections, other="learner") == {
        "env": ["expert.horizon=0.5"],
        "learner": ["hidden=16", "lr=3", "world_model_config.violation_steps=3", "gate.beta=a=b"],
    }
    assert route_settings([], sections) == {}
    for bad in ("hidden", "=3", "gate.=1", ".x=1", "a..b=1"):
        with pytest.raises(ValueError, match=r"not of the form section\.key=value"):
            route_settings([bad], sections, other="learner")
    with pytest.raises(ValueError, match=r"names no section this command takes: gate\.KEY=VALUE"):
        route_settings(["hold_seconds=2"], {"gate": Section("gate")})


def test_a_bad_set_is_one_line_and_exit_2() -> None:
    for args, says in (
        (["eval", UGV_DEFAULT, "--gate", "--set", "hold_seconds"], "--set 'hold_seconds' is not of the form"),
        (["eval", UGV_DEFAULT, "--set", "gate.hold_seconds=2"], "--set gate.… needs --gate"),
        (["eval", UGV_DEFAULT, "--gate", "--set", "env.x=1"], "names no section this command takes: gate.KEY=VALUE"),
        (["eval", UGV_DEFAULT, "--gate", "--gate-set", "hold_seconds=2"], "--set gate.hold_seconds=2"),
        (["train", "--set", "learner.nope=1", "--episodes", "0"], "unknown config field 'nope'"),
        (["train", "--env", "expert.horizon=0.5"], "--env is now --set env.KEY=VALUE: --set env.expert.horizon=0.5"),
        (["study", "ugv", "--learner-set", "hidden=8"], "--learner-set is now --set learner.KEY=VALUE"),
        (["study", "pedestrian", "--set", "study.nope=1"], "pedestrian has no setting 'nope'"),
        (["study", "pedestrian", "--set", "expert=x"], "expert is a setting of pedestrian, --set study.expert=x"),
        (["study", "pedestrian", "--set", "learner.hidden=x"], "--set learner.hidden=x: hidden: cannot read 'x'"),
        (["study", "ugv", "--set", "finetune.critic_warmup=2"], "ugv runs no fine-tuning rounds"),
        (["study", "cycles", "--set", "finetune.nope=1"], "--set finetune.: unknown config field 'nope'"),
        (["study", "cycles", "--set", "finetune.critic_warmup=-1"], "critic_warmup must be >= 0, got -1"),
        (["study", "cycles", "--set", "finetune.round_keep=0"], "round_keep must be in (0, 1], got 0.0"),
        (["serve", "--gate-set", "hold_seconds=2"], "--set gate.hold_seconds=2"),
        (["serve", "--set", "hold_seconds=2"], "names no section this command takes: gate.KEY=VALUE"),
    ):
        code, out = sage(*args)
        assert code == 2 and says in out and len(out.strip().splitlines()) == 1, (args, out)


def test_scenarios_are_repeatable_and_take_comma_lists() -> None:
    assert scenario_list(["1,2", " 3 ", "4,"]) == ["1", "2", "3", "4"]
    assert scenario_list(None) == [] and scenario_list([]) == []
    code, out = sage("expert", "--scenario", "3,4", "--episodes", "1")
    assert code == 2 and "sage expert drives one scenario, not 3, 4" in out
    code, out = sage("eval", UGV_DEFAULT, "--scenario", ",")
    assert code == 2 and "give at least one scenario" in out


def test_eval_takes_the_simulator_from_the_run_and_refuses_another() -> None:
    code, out = sage("eval", UGV_DEFAULT, "--sim", "highway", "--episodes", "1")
    assert code == 2 and "--sim highway: the run was trained on ugv" in out
    code, out = sage("cycles", "--policy", UGV_DEFAULT, "--sim", "highway")
    assert code == 2 and "--sim highway: the run was trained on ugv" in out
    code, out = sage("serve", "--policy", UGV_DEFAULT, "--sim", "highway")
    assert code == 2 and "ugv-default was trained on ugv" in out


def test_help_names_every_method_planner_and_study() -> None:
    import sims  # noqa: F401 (registers the simulators' planners)
    from core.learners import learner_names
    from core.planners import planner_names
    from studies.registry import get_study, study_names

    code, out = sage("train", "--help")
    assert code == 0 and "..." not in out.split("--method")[1].splitlines()[0]
    for name in (*learner_names(), *planner_names()):
        assert re.search(rf"[ ,(:]{re.escape(name)}[,.)]", out), name
    code, out = sage("eval", "--help")
    assert code == 0 and all(f"{name}," in out or f"{name})" in out for name in planner_names())
    code, out = sage("study", "--help")
    assert code == 0 and "The study: " + ", ".join(study_names()) + "." in out
    for study in study_names():
        assert f"{study}: {', '.join(get_study(study).methods)}" in out


def test_eval_side_by_side_keeps_runs_that_share_a_name(tmp_path: Path) -> None:
    """Several cycles runs' v0008 side by side: each gets its own rows (they were merged into one, the last)."""
    from app.cli.train import run_labels

    runs = [tmp_path / f"sage-s{seed}" / "versions" / "v0008" for seed in (0, 1)]
    assert run_labels([Path("policies/ugv-default"), *runs]) == [
        "ugv-default",
        "sage-s0/versions/v0008",
        "sage-s1/versions/v0008",
    ]
    assert run_labels([Path("a/run"), Path("a/run")]) == ["a/run #1", "a/run #2"]  # the same run twice
    copies = []
    for name in ("a", "b"):
        copy = tmp_path / name / "ugv-default"
        shutil.copytree(UGV_DEFAULT, copy)
        copies.append(str(copy))
    code, out = sage("eval", *copies, "--scenario", "1", "--episodes", "1", "--quiet")
    assert code == 0, out
    assert "a/ugv-default (ugv 1)" in out and "b/ugv-default (ugv 1)" in out
