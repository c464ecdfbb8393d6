"""Which runs the dashboard offers, and which one it opens with."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from app.policies import SCRIPTED, default_policy, discover, load_policy
from tests.app.fakesim import ToyRobotEnv


def run(root: Path, name: str, sim: str | None, versions: int = 0, final: bool = True) -> Path:
    folder = root / name
    (folder / "checkpoints").mkdir(parents=True)
    if sim is not None:
        (folder / "config.json").write_text(json.dumps({"run": {"sim": sim}, "meta": {"sim": sim}}))
    if final:
        (folder / "checkpoint.pt").write_bytes(b"")
    for k in range(versions):
        (folder / "checkpoints" / f"episode_{(k + 1) * 50:05d}.pt").write_bytes(b"")
    return folder


def test_runs_and_their_versions_are_offered_for_their_simulator(tmp_path: Path) -> None:
    policies, runs = tmp_path / "policies", tmp_path / "runs"
    run(policies, "ugv-default", "ugv")
    run(runs, "ugv-sage", "ugv", versions=2)
    run(runs, "highway-sac", "highway")
    run(runs, "ugv-starting", "ugv", final=False)  # no checkpoint yet: not offered
    labels = [c.label for c in discover([policies, runs], "ugv")]
    assert labels == [
        "policies/ugv-default",
        "runs/ugv-sage",
        "runs/ugv-sage @ episode_00050",
        "runs/ugv-sage @ episode_00100",
        "scripted expert (no gate)",
        "TEB local planner (sensing only)",  # the simulator's own planners (sims.PLANNERS)
        "scripted expert blind to movers (no gate)",
    ]
    assert next(c.label for c in discover([runs], "highway")) == "runs/highway-sac"


def test_the_committed_default_wins_then_any_run_then_the_scripted_expert(tmp_path: Path) -> None:
    policies, runs = tmp_path / "policies", tmp_path / "runs"
    assert default_policy([policies, runs], "ugv") == SCRIPTED
    trained = run(runs, "ugv-sage", "ugv")
    assert default_policy([policies, runs], "ugv") == str(trained)
    committed = run(policies, "ugv-default", "ugv")
    assert default_policy([policies, runs], "ugv") == str(committed)
    assert default_policy([policies, runs], "sumo") == SCRIPTED


def test_loading_reports_what_is_wrong(tmp_path: Path) -> None:
    env = ToyRobotEnv()
    assert load_policy(SCRIPTED, env).label.startswith("scripted")
    with pytest.raises(FileNotFoundError, match="no policy"):
        load_policy(str(tmp_path / "missing"), env)
    broken = run(tmp_path, "broken", "ugv")
    with pytest.raises(ValueError, match="not a readable SAGE checkpoint"):
        load_policy(str(broken), env)
