"""Planners that are not learners, by name: as the policy (sage eval, the policy picker) and as the expert."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from typer.testing import CliRunner

from core.planners import (
    PlannerExpert,
    is_planner,
    make_planner,
    planner_names,
    register_planner,
    unregister_planner,
)


class Cautious:
    """A toy planner for the point robot: half the scripted expert's action (it reads only the observation)."""

    def __init__(self, env: Any) -> None:
        self.env = env
        self.calls = 0

    def act(self, obs: np.ndarray, deterministic: bool = False) -> np.ndarray:
        self.calls += 1
        return 0.5 * np.asarray(self.env.unwrapped.expert_action(), np.float32)


@pytest.fixture
def point_and_planner(monkeypatch: pytest.MonkeyPatch) -> Any:
    import sims

    monkeypatch.setitem(sims.SIMULATORS, "point", "tests.core.sage.envs")
    register_planner("cautious", Cautious, title="cautious planner (test)", sims=("point",))
    yield
    unregister_planner("cautious")


def test_the_registry_names_planners_per_simulator_and_refuses_paths_and_duplicates(point_and_planner: Any) -> None:
    assert planner_names("point") == ["scripted", "cautious"]
    assert planner_names("ugv") == ["scripted", "teb", "blind-movers"]
    assert is_planner("cautious") and not is_planner("runs/x")
    with pytest.raises(ValueError, match="already registered"):
        register_planner("cautious", Cautious)
    with pytest.raises(ValueError, match="plain word"):
        register_planner("runs/teb", Cautious)
    with pytest.raises(ValueError, match="unknown planner"):
        PlannerExpert("nope")
    import sims

    env = sims.make("ugv", scenario="1")
    with pytest.raises(ValueError, match="drives point, not ugv"):
        make_planner("cautious", env, sim="ugv")
    env.close()


def test_a_planner_is_evaluated_by_name_and_serves_as_the_expert(point_and_planner: Any, tmp_path: Path) -> None:
    from app.cli import app
    from app.policies import discover, load_policy

    cli = CliRunner()
    save = tmp_path / "rows.jsonl"
    args = ["eval", "cautious", "--sim", "point", "--scenario", "static", "--episodes", "2", "--quiet"]
    result = cli.invoke(app, [*args, "--save", str(save)])
    assert result.exit_code == 0, result.output
    assert "cautious (point static)" in result.output and len(save.read_text().splitlines()) == 2
    result = cli.invoke(app, ["eval", "cautious", "--episodes", "1", "--quiet"])
    assert result.exit_code == 2 and "--sim" in result.output
    result = cli.invoke(app, ["eval", "cautious", "--sim", "point", "--gate", "--quiet"])
    assert result.exit_code == 2 and "no SAGE gate" in result.output

    # as the expert of a training run: its actions are the demonstrations' labels
    out = tmp_path / "hg"
    train = ["train", "--sim", "point", "--scenario", "static", "--method", "hg-dagger", "--episodes", "0"]
    result = cli.invoke(app, [*train, "--demo-episodes", "1", "--expert", "cautious", "--quiet", "--out", str(out)])
    assert result.exit_code == 0, result.output
    config = json.loads((out / "config.json").read_text())
    assert config["run"]["expert"] == "cautious"

    # in the dashboard's policy picker and loader
    choices = [c.id for c in discover([tmp_path / "none"], "point")]
    assert choices[-2:] == ["scripted", "cautious"]
    import sims

    env = sims.make("point", scenario="static")
    loaded = load_policy("cautious", env)
    env.reset(seed=0)
    assert loaded.label == "cautious planner (test)" and loaded.policy.act(np.zeros(8)).shape == (2,)
    env.close()


def test_the_planner_expert_labels_takeovers_with_the_planners_actions(point_and_planner: Any) -> None:
    import sims
    from core.loop import Runner
    from core.sage.gate import AlwaysGate

    env = sims.make("point", scenario="static")
    expert = PlannerExpert("cautious", "point")
    runner = Runner(env, make_planner("scripted", env), AlwaysGate(), expert, seed=0)
    record = runner.step()
    assert record is not None and record.actor == "expert" and record.takeover
    np.testing.assert_allclose(record.a_expert, 0.5 * record.a_rl, atol=1e-5)  # half the scripted expert's
    env.close()
