"""D3QN pieces (#12): the dueling aggregation, double-Q targets with fear and c*, and the margin loss."""

from __future__ import annotations

import pytest
import torch

from core.sage.d3qn import DuelingQNetwork, double_q_target, weighted_margin_loss


def test_dueling_advantages_have_zero_mean_and_greedy_one_hot() -> None:
    torch.manual_seed(0)
    net = DuelingQNetwork(5, 9, hidden=16)
    obs = torch.randn(7, 5)
    q = net(obs)
    h = net.trunk(obs)
    assert torch.allclose(q.mean(-1), net.value(h).squeeze(-1), atol=1e-6)
    one_hot = net.greedy_one_hot(obs)
    assert torch.equal(one_hot.argmax(-1), q.argmax(-1)) and torch.equal(one_hot.sum(-1), torch.ones(7))
    with pytest.raises(ValueError):
        DuelingQNetwork(5, 1)


def test_double_q_target_uses_online_argmax_target_value_fear_and_c_star() -> None:
    torch.manual_seed(1)
    online = DuelingQNetwork(3, 4, hidden=8)
    target = DuelingQNetwork(3, 4, hidden=8)
    next_obs = torch.randn(6, 3)
    reward = torch.linspace(-1, 1, 6)
    done = torch.tensor([0, 0, 0, 0, 1, 0], dtype=torch.float32)
    y = double_q_target(online, target, reward, next_obs, done, 0.9)
    expected_next = target(next_obs).gather(-1, online(next_obs).argmax(-1, keepdim=True)).squeeze(-1)
    assert torch.allclose(y, reward + 0.9 * (1 - done) * expected_next.detach())
    fear = torch.full((6,), 0.5)
    violation = torch.tensor([1, 0, 0, 0, 0, 0], dtype=torch.float32)
    y2 = double_q_target(
        online, target, reward, next_obs, done, 0.9, fear_next=fear, lam=2.0, violation=violation, c_star=50.0
    )
    assert torch.allclose(y2[1:], y[1:] - 1.0)
    assert torch.allclose(y2[0], -50.0 - 1.0 + 0.9 * expected_next[0].detach())


def test_margin_loss_makes_the_expert_action_greedy_and_weights_scale_it() -> None:
    torch.manual_seed(2)
    net = DuelingQNetwork(4, 9, hidden=32)
    obs = torch.randn(64, 4)
    expert = (obs[:, 0] > 0).long() * 3 + 1  # a state-dependent expert: action 1 or 4
    assert (net.greedy(obs) == expert).float().mean() < 0.5
    optimizer = torch.optim.Adam(net.parameters(), lr=1e-2)
    for _ in range(300):
        loss = weighted_margin_loss(net(obs), expert)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    assert (net.greedy(obs) == expert).float().mean() > 0.95
    q = net(obs).detach()
    base = weighted_margin_loss(q, (expert + 1) % 9)
    assert base > 0 and torch.isclose(weighted_margin_loss(q, (expert + 1) % 9, torch.full((64,), 3.0)), 3 * base)
