"""The composition root: one picklable TrainSpec, run_training(spec), and `sage train` built from the spec."""

from __future__ import annotations

import dataclasses
import json
import pickle
from pathlib import Path

import pytest
from typer.testing import CliRunner

from core.field_docs import field_docs
from core.train import RunConfig, Trainer
from studies.spec import TrainSpec
from studies.training import run_training
from tests.core.sage import envs
from tests.core.test_train import small

SMALL = [
    "hidden=32",
    "batch_size=32",
    "learning_starts=40",
    "wm_min_samples=60",
    "wm_fit_every=100",
    "world_model_config.hidden=16",
    "world_model_config.max_updates_per_fit=50",
]


@pytest.fixture
def point_sim(monkeypatch: pytest.MonkeyPatch) -> None:
    import sims

    monkeypatch.setitem(sims.SIMULATORS, "point", "tests.core.sage.envs")


def test_every_spec_field_is_a_documented_train_flag_with_the_spec_default() -> None:
    """Each field is its flag, but those every command spells the same way (app.cli.options): --sim (a run's own),
    --scenario (repeatable, comma lists) and --set (env. for ``env``, the learner's paths for ``overrides``)."""
    from app.cli import app

    docs = field_docs(TrainSpec)
    fields = dataclasses.fields(TrainSpec)
    assert {f.name for f in fields} == set(docs), "each field carries its docstring"
    command = typer_command(app, "train")
    options = {p.name: p for p in command.params}
    shared = {"sim": "--sim", "scenario": "--scenario", "env": "--set", "overrides": "--set"}
    for f in fields:
        if f.name in shared:
            assert shared[f.name] in options["set_" if shared[f.name] == "--set" else f.name].opts
            continue
        assert f.name in options, f"--{f.name} missing"
        param = options[f.name]
        flag = f.metadata.get("flag", "--" + f.name.replace("_", "-"))
        assert flag in param.opts
        assert param.help.startswith(docs[f.name])
        if f.default is not dataclasses.MISSING:
            assert param.default == f.default
    assert set(options) - {f.name for f in fields} <= {"quiet", "help", "set_"}


def typer_command(app, name: str):
    import typer.main

    group = typer.main.get_command(app)
    return group.commands[name]  # type: ignore[attr-defined]


def test_a_spec_is_plain_data_that_survives_pickling() -> None:
    spec = TrainSpec(sim="ugv", scenario="3", method="sac", train_steps=500, overrides=["gamma=0.9"])
    assert pickle.loads(pickle.dumps(spec)) == spec
    assert spec.replace(seed=4).seed == 4 and spec.seed == 0


def test_run_training_spends_exactly_the_step_budget_demonstrations_included(point_sim, tmp_path: Path) -> None:
    spec = TrainSpec(
        sim="point",
        scenario="static",
        method="sac",
        train_steps=130,
        demo_episodes=1,
        seed=1,
        checkpoint_every=0,
        overrides=SMALL,
        out=str(tmp_path / "run"),
    )
    outcome = run_training(spec)
    rows = [json.loads(line) for line in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    demo = sum(r["steps"] for r in rows if r["phase"] == "demo")
    trained = sum(r["steps"] for r in rows if r["phase"] == "train")
    assert demo > 0 and trained > 0
    assert demo + trained == 130
    assert rows[-1]["steps_done"] == 130
    assert (outcome.out / "checkpoint.pt").exists()
    config = json.loads((outcome.out / "config.json").read_text())
    assert config["run"]["train_steps"] == 130 and config["meta"]["extra"]["steps_done"] == 130


def test_the_episode_count_and_the_step_budget_both_bound_a_run() -> None:
    run = RunConfig(sim="point", scenarios=["static"], episodes=2, train_steps=10_000, checkpoint_every=0)
    trainer = Trainer(run, small("sac"), envs.make, None, progress=False)
    result = trainer.train()
    assert len(result.rows) == 2 and trainer.steps_done < 10_000
    with pytest.raises(ValueError, match="bound the run"):
        Trainer(RunConfig(sim="point", scenarios=["static"], episodes=None), small("sac"), envs.make)
    with pytest.raises(ValueError, match="train_steps"):
        Trainer(RunConfig(sim="point", scenarios=["static"], episodes=1, train_steps=0), small("sac"), envs.make)


def test_sage_train_runs_the_spec_it_is_given(point_sim, tmp_path: Path) -> None:
    from app.cli import app

    out = tmp_path / "cli"
    args = ["train", "--sim", "point", "--scenario", "static", "--method", "sac", "--train-steps", "50"]
    args += ["--checkpoint-every", "0", "--quiet", "--out", str(out)]
    for item in SMALL:
        args += ["--set", item]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    config = json.loads((out / "config.json").read_text())
    assert config["run"]["train_steps"] == 50 and config["meta"]["extra"]["steps_done"] == 50
    assert config["agent"]["hidden"] == 32
    again = CliRunner().invoke(app, args)
    assert again.exit_code == 2 and "already holds a finished run" in again.output


def test_a_world_model_only_refit_keeps_the_policys_own_config_whatever_method_is_named(
    point_sim, tmp_path: Path
) -> None:
    """``--world-model-only`` from a policy that imitates its takeovers: the refit's checkpoint keeps the
    policy's switches (a method preset turned imitation off, and fine-tuning from the refit then ignored the
    expert), with the --set overrides applied."""
    from core.agents import load_agent

    common = dict(sim="point", scenario="static", seed=1, checkpoint_every=0)
    # SAC with a world model and imitation, as policies/ugv-default was trained: no preset of its method has these
    switched = [*SMALL, "world_model=true", "imitation=true"]
    policy = run_training(
        TrainSpec(**common, method="sac", train_steps=120, overrides=switched, out=str(tmp_path / "policy"))
    ).out
    before = load_agent(policy).config
    assert before.imitation and before.world_model
    refit = TrainSpec(
        **common,
        method="sac",
        episodes=2,
        init=str(policy),
        world_model_only=True,
        overrides=["world_model_config.cost_label_weight=0.3"],
        out=str(tmp_path / "refit"),
    )
    outcome = run_training(refit)
    after = load_agent(outcome.out).config
    assert (after.method, after.imitation, after.world_model) == ("sac", True, True)
    assert after.world_model_config.cost_label_weight == 0.3 and after.updates_per_step == before.updates_per_step
    assert not any(line.startswith("note:") for line in outcome.lines)
    # a refit that adds an input to the world model, or whose model learns the residual over an ego step, cannot read
    # the old weights (they learned the whole change from fewer inputs): it says so and fits a new one
    changes = {
        "wider": (["world_model_config.approach_start=0", "world_model_config.approach_stop=1"], "approach", (0, 1)),
        "ego": (["world_model_config.ego_sectors=2", "world_model_config.ego_sector_width=0.5"], "ego", 2),
    }
    for name, (overrides, part, expected) in changes.items():
        outcome = run_training(dataclasses.replace(refit, overrides=overrides, out=str(tmp_path / name)))
        assert any("does not fit this run's world_model_config" in line for line in outcome.lines), outcome.lines
        model = load_agent(outcome.out).world_model
        assert model is not None and bool(model.fitted)
        value = getattr(model, part)
        assert (value.sectors if part == "ego" else value) == expected


def test_a_world_model_only_refit_of_a_discrete_policy_runs_in_a_fresh_process(tmp_path: Path) -> None:
    """The committed D3QN policy refitted (0 episodes: only its gate's settings change) by the CLI in a process of
    its own, where no learner has been registered yet: the refit once validated the policy's method before the
    built-in learners were registered and refused ``sage-d3qn``."""
    import subprocess
    import sys

    from core.agents import load_agent

    root = Path(__file__).resolve().parents[2]
    out = tmp_path / "refit"
    policy = root / "policies" / "pedestrian-default"
    args = ["train", "--sim", "pedestrian", "--scenario", "crossing", "--init", str(policy)]
    args += ["--world-model-only", "--episodes", "0", "--demo-episodes", "0", "--set", "gate.release=0.5"]
    args += ["--checkpoint-every", "0", "--quiet", "--out", str(out)]
    code = "import sys; from app.cli import app; app(sys.argv[1:])"
    done = subprocess.run([sys.executable, "-c", code, *args], cwd=root, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "trained sage-d3qn on pedestrian" in done.stdout
    refit = load_agent(out).config
    assert (refit.method, refit.gate.release, refit.world_model) == ("sage-d3qn", 0.5, True)
