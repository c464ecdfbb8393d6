"""What a --scenario string means to each simulator."""

from __future__ import annotations

import pytest

from studies.envs import default_scenario, env_factory, scenario_kwargs


def test_each_simulator_reads_its_own_scenario_names() -> None:
    assert scenario_kwargs("ugv", "3") == {"scenario": 3}
    assert scenario_kwargs("highway", "test") == {"split": "test", "mode": "normal"}
    assert scenario_kwargs("highway", "17") == {"scenario_id": 17}
    assert scenario_kwargs("sumo", "c1") == {"route": 1, "special_vehicles": False}
    assert scenario_kwargs("sumo", "C2") == {"route": 2, "special_vehicles": True}
    assert scenario_kwargs("sumo", "2") == {"route": 2, "special_vehicles": False}
    assert [default_scenario(s) for s in ("ugv", "highway", "sumo")] == ["1", "train", "c1"]


@pytest.mark.parametrize(("sim", "name", "hint"), [("highway", "validation", "split"), ("sumo", "3", "c1")])
def test_a_bad_scenario_name_says_what_to_give(sim: str, name: str, hint: str) -> None:
    with pytest.raises(ValueError, match=hint):
        scenario_kwargs(sim, name)


def test_the_factory_builds_the_named_variant() -> None:
    env = env_factory("sumo")("c2")  # a SUMO env starts its simulation at reset, so building is cheap
    try:
        assert (env.unwrapped.config.route, env.unwrapped.config.special_vehicles) == (2, True)
    finally:
        env.close()
    with pytest.raises(ValueError, match="unknown simulator"):
        env_factory("carla")


def test_env_overrides_are_read_as_json_where_they_parse_and_reach_every_env() -> None:
    from studies.envs import parse_env_overrides
    from studies.training import prepare_training

    overrides = parse_env_overrides(["expert.yield_to_movers=false", "time_limit=30", "lidar.backend=pymunk"])
    assert overrides == {"expert.yield_to_movers": False, "time_limit": 30, "lidar.backend": "pymunk"}
    assert parse_env_overrides(["expert.yield_to_movers=False"]) == {"expert.yield_to_movers": False}
    with pytest.raises(ValueError, match="key=value"):
        parse_env_overrides(["yield_to_movers"])
    setup = prepare_training("ugv", scenario="3,4", env={"expert.yield_to_movers": False})
    for scenario in setup.scenarios:
        env = setup.make_env(scenario).unwrapped
        assert env.config.expert.yield_to_movers is False and env.expert.yield_to_movers is False
    with pytest.raises(ValueError, match="unknown UGV config field"):
        setup = prepare_training("ugv", scenario="3", env={"expert.yield": False})
        setup.make_env("3")


def test_highway_takes_dotted_env_overrides_into_its_world_expert_and_adversary() -> None:
    """``sage train --sim highway --set env.expert.horizon=0.5``: the override reaches the config the scripted expert
    and the CAT adversary read, on every env of the run; a typo is an error, not a silent default."""
    from studies.training import prepare_training

    setup = prepare_training("highway", scenario="train", env={"expert.horizon": 0.5, "adversary.risk_weight": 2.0})
    env = setup.make_env("train").unwrapped
    try:
        assert env.cfg.expert.horizon == 0.5 and env.expert.cfg.expert.horizon == 0.5
        assert env.cfg.adversary.risk_weight == 2.0
        assert env.cfg.dt == 0.1  # the rest stays the default
    finally:
        env.close()
    with pytest.raises(ValueError, match=r"unknown highway config field 'expert\.horizn'"):
        prepare_training("highway", scenario="train", env={"expert.horizn": 0.5}).make_env("train")


@pytest.mark.parametrize(
    ("sim", "label"), [("ugv", "UGV"), ("pedestrian", "pedestrian"), ("sumo", "SUMO"), ("highway", "highway")]
)
def test_every_simulator_names_an_unknown_override_and_what_its_config_has(sim: str, label: str) -> None:
    import sims

    with pytest.raises(ValueError, match=rf"unknown {label} config field 'no_such': no 'no_such' among \w+"):
        sims.make(sim, no_such=1)
