"""The gate's imagined horizon: the rollout it already computed, per member and step ahead, read-only."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import sims
from core.agents import load_agent

DEFAULT = Path(__file__).resolve().parents[3] / "policies" / "ugv-default"


def test_the_horizon_is_what_fear_was_computed_from() -> None:
    agent = load_agent(DEFAULT)
    gate = agent.make_gate(hold_steps=1)
    assert gate.last_horizon() is None  # nothing decided yet
    env = sims.make("ugv", scenario="3")
    obs, _ = env.reset(seed=0)
    for _ in range(40):
        action = agent.policy.act(obs, deterministic=True)
        decision = gate.decide(obs, action)
        horizon = gate.last_horizon()
        assert horizon is not None
        cost = np.array(horizon["cost"])
        steps = max(gate.cfg.horizon, gate.cfg.contact_horizon or 0)  # imagined contact may reach further
        assert cost.shape == (steps, agent.world_model.members) and ((cost >= 0) & (cost <= 1)).all()
        np.testing.assert_allclose(horizon["mean"], cost.mean(1), atol=2e-4)
        np.testing.assert_allclose(horizon["spread"], cost.std(1), atol=2e-4)
        # the gate's ĉ is the maximum over the horizon of the members' mean (aggregate "max")
        assert max(horizon["mean"]) == pytest.approx(gate.detail.cost, abs=2e-4)
        assert np.isfinite(decision.fear)
        next_obs, *_ = env.step(action)
        gate.observe(obs, action, next_obs)
        obs = next_obs
    env.close()
