"""D3QN pieces for discrete actions (the paper's long-tail study): a dueling Q-network, double-Q targets with
SAGE's fear regularisation, and the discrete form of value-weighted imitation.

Not yet a learner: these are the network and the one-step losses that a ``D3QN`` / ``SAGE-D3QN`` learner on
:class:`core.sage.learner.BaseLearner` will use (issue #12); they are tested on their own.

Discrete imitation. The paper's actor loss adds ω(s) · ||π(s) - a_E||² on takeover samples, with
ω = exp((Q(s, a_E) - Q(s, a_RL)) / T) clipped. A Q-network has no actor; its greedy policy is argmax_a Q(s, a),
so the same pull becomes a large-margin loss (DQfD, Hester et al. 2018) weighted by the same ω:
ω(s) · [max_a (Q(s, a) + ℓ(a_E, a)) - Q(s, a_E)], ℓ = margin for a ≠ a_E and 0 for a_E. It is zero exactly when
the expert's action is greedy by the margin, so it moves the greedy policy toward a_E as the BC term moves π;
ω stays large where the agent's greedy action is worth much less than the expert's.

Fear-regularised targets. As for SAGE-SAC: y = r - λ F(s') + γ (1 - done) Q_target(s', argmax_a Q(s', a)), and
on a violation (cost flag) the reward is replaced by -c* (:func:`core.sage.sac.penalty_c_star`).
"""

from __future__ import annotations

import torch
from torch import Tensor, nn


class DuelingQNetwork(nn.Module):
    """Q(s, a) = V(s) + A(s, a) - mean_a A(s, a) over a shared ReLU trunk."""

    def __init__(self, obs_dim: int, n_actions: int, hidden: int = 128, layers: int = 2) -> None:
        super().__init__()
        if n_actions < 2:
            raise ValueError(f"a Q-network needs at least 2 actions, got {n_actions}")
        trunk: list[nn.Module] = []
        width = obs_dim
        for _ in range(layers):
            trunk += [nn.Linear(width, hidden), nn.ReLU()]
            width = hidden
        self.trunk = nn.Sequential(*trunk)
        self.value = nn.Linear(width, 1)
        self.advantage = nn.Linear(width, n_actions)
        self.n_actions = n_actions

    def forward(self, obs: Tensor) -> Tensor:
        h = self.trunk(obs)
        advantage = self.advantage(h)
        return self.value(h) + advantage - advantage.mean(-1, keepdim=True)

    def greedy(self, obs: Tensor) -> Tensor:
        """Greedy action indices (long)."""
        return self(obs).argmax(-1)

    def greedy_one_hot(self, obs: Tensor) -> Tensor:
        """The greedy action as a one-hot float vector: the policy that world-model rollouts (fear) follow."""
        return torch.nn.functional.one_hot(self.greedy(obs), self.n_actions).to(obs.dtype)


def double_q_target(
    online: DuelingQNetwork,
    target: DuelingQNetwork,
    reward: Tensor,
    next_obs: Tensor,
    terminated: Tensor,
    gamma: float,
    *,
    fear_next: Tensor | None = None,
    lam: float = 0.0,
    violation: Tensor | None = None,
    c_star: float = 0.0,
) -> Tensor:
    """y = r' - λ F(s') + γ (1 - done) Q_target(s', argmax_a Q_online(s', a)), r' = -c* on violations."""
    with torch.no_grad():
        best = online(next_obs).argmax(-1, keepdim=True)
        next_q = target(next_obs).gather(-1, best).squeeze(-1)
        r = reward if violation is None else torch.where(violation > 0.5, torch.full_like(reward, -c_star), reward)
        if fear_next is not None:
            r = r - lam * fear_next
        return r + gamma * (1.0 - terminated) * next_q


def weighted_margin_loss(
    q: Tensor, expert_action: Tensor, weights: Tensor | None = None, margin: float = 0.8
) -> Tensor:
    """ω-weighted large-margin loss toward the expert's action (see the module docstring); ``q`` is (B, A)."""
    penalty = torch.full_like(q, margin)
    penalty.scatter_(-1, expert_action.long().view(-1, 1), 0.0)
    loss = (q + penalty).max(-1).values - q.gather(-1, expert_action.long().view(-1, 1)).squeeze(-1)
    return (loss if weights is None else weights * loss).mean()
