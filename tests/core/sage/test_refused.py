"""The critic term on proposals the gate refused (``AgentConfig.refused_weight``): Q(s, a_RL) held to -c* where the
expert drove because fear was over τ, so the critic learns the failure the robot never had to make."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from core.learners import make_learner
from core.sage.config import for_method
from core.sage.learner import BaseLearner

OBS, ACT = 6, 2
REFUSED_ACTION = np.array([0.9, -0.9], np.float32)
EXPERT_ACTION = np.array([-0.5, 0.5], np.float32)


def learner(method: str, weight: float, seed: int = 0) -> BaseLearner:
    cfg = for_method(method, hidden=32, batch_size=64, critics=2, gamma=0.9, refused_weight=weight)
    return make_learner(cfg.method, cfg, OBS, ACT, seed=seed)


def fill(agent: BaseLearner, rng: np.random.Generator) -> np.ndarray:
    """Random transitions (reward ~ N(0, 0.1), so that c* stays some tens); every fifth an expert takeover whose
    refused proposal is REFUSED_ACTION. Returns the refused rows' states."""
    obs = rng.random((1001, OBS)).astype(np.float32)
    refused = []
    for i in range(1000):
        takeover = i % 5 == 0
        agent.buffer.add(
            obs[i],
            EXPERT_ACTION if takeover else rng.uniform(-1, 1, ACT).astype(np.float32),
            0.1 * float(rng.normal()),
            obs[i + 1],
            False,
            takeover=takeover,
            a_rl=REFUSED_ACTION if takeover else None,
            a_expert=EXPERT_ACTION if takeover else None,
            refused=takeover,
        )
        if takeover:
            refused.append(obs[i])
    agent.warm = True
    return np.stack(refused)


def q_of(agent: BaseLearner, states: np.ndarray, action: np.ndarray) -> float:
    with torch.no_grad():
        s = torch.from_numpy(states)
        return float(agent.critic(s, torch.from_numpy(action).expand(len(s), ACT)).min(0).values.mean())


def test_the_critic_learns_that_a_refused_proposal_would_have_failed() -> None:
    """Same seed, same data, 500 updates: with the term, Q at the refused proposals falls most of the way to -c*,
    and the expert's action at the same states stays well above it (so ω can prefer the expert there); without it
    nothing in the data says the proposal was bad, and the plain critic rates it as the expert's."""
    results = {}
    for weight in (0.0, 1.0):
        agent = learner("sac", weight)
        states = fill(agent, np.random.default_rng(0))
        stats: dict[str, float] = {}
        for _ in range(500):
            stats = agent.update()
        results[weight] = (q_of(agent, states, REFUSED_ACTION), q_of(agent, states, EXPERT_ACTION), stats)
        c_star = agent.c_star()
    (plain_refused, plain_expert, plain_stats), (held_refused, held_expert, held_stats) = results[0.0], results[1.0]
    assert "refused_loss" not in plain_stats
    assert held_stats["refused_loss"] < 0.5 * c_star**2  # two critics: some 2 c*^2 at the start
    assert abs(plain_refused - plain_expert) < 0.1 * c_star
    assert held_refused < plain_refused - 0.5 * c_star
    assert held_expert > held_refused + 0.4 * c_star


def test_refused_weight_is_refused_where_no_learner_would_read_it() -> None:
    with pytest.raises(ValueError, match="refused_weight must be a finite number >= 0"):
        for_method("sage", refused_weight=-1.0)
    with pytest.raises(ValueError, match="cuda_graph"):
        for_method("sage", refused_weight=1.0, cuda_graph=True)
    with pytest.raises(ValueError, match="SAC learners only"):
        learner("td3", 1.0)
    assert learner("sage", 1.0).cfg.refused_weight == 1.0
