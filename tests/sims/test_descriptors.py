"""Every simulator's descriptor: one naming of scenarios for the CLI, the dashboard and the studies."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import pytest

import sims
from core.descriptor import ScenarioNameError


def test_named_scenarios_build_the_variants_the_paper_names() -> None:
    assert sims.descriptor("ugv").scenario_kwargs("3") == {"scenario": 3}
    assert sims.descriptor("highway").scenario_kwargs("test-adversarial") == {"split": "test", "mode": "adversarial"}
    assert sims.descriptor("highway").scenario_kwargs("17") == {"scenario_id": 17}
    assert sims.descriptor("sumo").scenario_kwargs("c2") == {"route": 2, "special_vehicles": True}
    assert sims.descriptor("sumo").scenario_kwargs("2") == {"route": 2, "special_vehicles": False}
    assert sims.descriptor("sumo").scenario_kwargs(None) == {"route": 1, "special_vehicles": False}


def test_a_bad_name_is_a_clear_error_listing_the_names() -> None:
    with pytest.raises(ScenarioNameError, match="choose one of c1, c2"):
        sims.descriptor("sumo").scenario_kwargs("route 2")
    with pytest.raises(ScenarioNameError, match="1-4"):
        sims.descriptor("ugv").scenario_kwargs("9")
    with pytest.raises(ValueError, match="unknown simulator 'carla'; choose one of ugv"):
        sims.descriptor("carla")


def test_every_descriptor_is_complete_and_builds_its_default_scenario() -> None:
    for name in ("ugv", "highway"):
        d = sims.descriptor(name)
        env = sims.make(name)
        try:
            assert env.spec is not None and env.spec.id == d.env_id
            safe = d.safe(env.action_space)
            assert env.action_space.contains(safe)
            env.reset(seed=0)
            metrics = env.unwrapped.metrics()
            assert set(d.metric_columns) <= set(metrics), set(d.metric_columns) - set(metrics)
        finally:
            env.close()
        assert 0 < d.dt < 1


def test_a_ugv_scenario_file_is_a_scenario_name(tmp_path: Path) -> None:
    from sims.ugv.scenario import BUILTIN_SCENARIOS, SCENARIO_DIR

    source = SCENARIO_DIR / BUILTIN_SCENARIOS[2]
    copy = tmp_path / "mine.yaml"
    copy.write_text(source.read_text())
    env = sims.make("ugv", str(copy))
    assert isinstance(env, gym.Env)
    env.close()
    with pytest.raises(ScenarioNameError, match="scenario file not found"):
        sims.make("ugv", str(tmp_path / "missing.yaml"))


def test_a_policys_recorded_scenario_file_resolves_from_any_working_directory(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """policies/ugv-default records sims/ugv/scenarios/clutter.yaml from the repository root; a Ray trial runs in its
    own folder, where the fine-tuning rounds' base-policy drives failed to find it and ran without them."""
    import json

    repository = Path(__file__).resolve().parents[2]
    recorded = json.loads((repository / "policies" / "ugv-default" / "config.json").read_text())["run"]["scenarios"]
    files = [name for name in recorded if name.endswith(".yaml")]
    assert files, "the default policy no longer records a scenario file: this test needs another"
    monkeypatch.chdir(tmp_path)
    for name in files:
        assert sims.descriptor("ugv").scenario_kwargs(name) == {"scenario": str(repository / name)}
        env = sims.make("ugv", name)
        env.close()
    with pytest.raises(ScenarioNameError, match="scenario file not found"):
        sims.make("ugv", "sims/ugv/scenarios/missing.yaml")
