"""highway-env's own environments: continuous actions on merge and roundabout maps, and the fast config."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from sims.highway.compat import FAST_CONFIG, make_stock


@pytest.mark.filterwarnings("ignore::DeprecationWarning")
@pytest.mark.parametrize("env_id", ["merge-v0", "roundabout-v0"])
def test_continuous_actions_work_on_maps_whose_reward_reads_a_discrete_action(env_id: str) -> None:
    stock = gym.make(env_id)
    stock.unwrapped.configure({"action": {"type": "ContinuousAction"}})
    with pytest.raises(ValueError, match="truth value of an array"):
        stock.reset(seed=0)  # the highway-env 1.12 bug this module works around (remove it when this fails)
    env = make_stock(env_id, continuous=True)
    env.reset(seed=0)
    for _ in range(3):
        _, reward, *_ = env.step(np.array([0.2, -0.1], np.float32))
    assert np.isfinite(reward) and env.action_space.shape == (2,)
    assert env.unwrapped.vehicle.action["steering"] != 0.0  # the continuous steering reached the vehicle


def test_fast_config_applies_only_where_the_env_knows_the_key_and_rejects_typos() -> None:
    env = make_stock("highway-v0")
    cfg = env.unwrapped.config
    assert all(cfg[k] == v for k, v in FAST_CONFIG.items())
    merge = make_stock("merge-v1")
    assert "vehicles_count" not in merge.unwrapped.config
    assert merge.unwrapped.config["policy_frequency"] == FAST_CONFIG["policy_frequency"]
    with pytest.raises(ValueError, match="unknown config key"):
        make_stock("highway-v0", vehicle_count=10)
    with pytest.raises(ValueError, match="not a registered"):
        make_stock("autobahn-v0")
