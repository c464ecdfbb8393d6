"""D3QN pieces for discrete actions (the paper's long-tail study): a dueling Q-network, double-Q targets with
SAGE's fear regularisation, and the discrete form of value-weighted imitation.

The learner :class:`D3QN` (registered as ``d3qn`` and ``sage-d3qn``, :mod:`core.learners`) is built on
:class:`core.sage.learner.BaseLearner` with a Q-network in place of an actor: the same buffers, world model, gate,
checkpoints and guarded update as the continuous learners.

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

import copy
import math
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from core.replay import Batch
from core.sage.captured import CapturedUpdate, fill_batch, static_batch
from core.sage.fear import fear
from core.sage.learner import BaseLearner, DeclaredState
from core.sage.networks import adam, soft_update
from core.sage.sac import advantage_weights, penalty_c_star


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
        # scatter rather than F.one_hot, which checks its indices on the host (a sync, and no CUDA graph capture)
        greedy = self.greedy(obs).unsqueeze(-1)
        one_hot = torch.zeros(*greedy.shape[:-1], self.n_actions, dtype=obs.dtype, device=obs.device)
        return one_hot.scatter_(-1, greedy, 1.0)


def double_q_target(
    online: DuelingQNetwork,
    target: DuelingQNetwork,
    reward: Tensor,
    next_obs: Tensor,
    terminated: Tensor,
    gamma: float,
    *,
    fear_next: Tensor | None = None,
    lam: float | Tensor = 0.0,
    violation: Tensor | None = None,
    c_star: float | Tensor = 0.0,
) -> Tensor:
    """y = r' - λ F(s') + γ (1 - done) Q_target(s', argmax_a Q_online(s', a)), r' = -c* on violations."""
    with torch.no_grad():
        best = online(next_obs).argmax(-1, keepdim=True)
        next_q = target(next_obs).gather(-1, best).squeeze(-1)
        r = reward if violation is None else torch.where(violation > 0.5, -c_star, reward)
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


# -- the learner ---------------------------------------------------------------------------------------------
class D3QN(BaseLearner):
    """D3QN (double Q-learning with a dueling network) and, with SAGE's switches on, SAGE-D3QN.

    The method's switches are those of SAGE-SAC (:func:`core.sage.config.for_method`): ``d3qn`` has them all off;
    ``sage-d3qn`` trains the world model on one-hot actions, hands takeovers to the expert through the gate (fear
    over the horizon under the greedy policy, the curiosity threshold), regularises the targets with fear and
    -c* on violations, and imitates takeover actions with the ω-weighted margin loss (module docstring).
    Actions: the environment's ``Discrete(n)`` indices (``start`` .. ``start + n - 1``); the buffers and the
    world model hold their one-hot encoding.
    """

    acting_module = "q"
    encodes_actions = True
    uses_random_warmup = True

    def build_networks(self) -> None:
        self.first_action = round(float(self.action_low[0]))
        self.n_actions = round(float(self.action_high[0])) - self.first_action + 1
        if self.act_dim != 1 or self.n_actions < 2:
            raise ValueError(
                f"{self.cfg.method} needs a Discrete action space (one index); got {self.act_dim} action values "
                f"with {self.n_actions} choices"
            )
        cfg = self.cfg
        self.q = DuelingQNetwork(self.obs_dim, self.n_actions, cfg.hidden, cfg.layers).to(self.device)
        self.q_target = copy.deepcopy(self.q).requires_grad_(False)
        self.q_optimizer = adam(self.q.parameters(), cfg.critic_lr, self.captures)

    # -- actions ---------------------------------------------------------------------------------------
    @property
    def model_action_dim(self) -> int:
        return self.n_actions

    def encode_action(self, action: Any) -> np.ndarray:
        value = np.asarray(action, dtype=np.float32).reshape(-1)
        if value.size == self.n_actions:  # already one-hot (a stored row)
            return value
        index = round(float(value[0])) - self.first_action
        if not 0 <= index < self.n_actions:
            raise ValueError(
                f"action {value[0]} is outside {self.first_action}..{self.first_action + self.n_actions - 1}"
            )
        one_hot = np.zeros(self.n_actions, np.float32)
        one_hot[index] = 1.0
        return one_hot

    def _index(self, index: int) -> np.ndarray:
        return np.array([self.first_action + int(index)], dtype=np.int64)

    def random_action(self) -> np.ndarray:
        return self._index(int(self.rng.integers(self.n_actions)))

    def epsilon(self) -> float:
        d = self.cfg.discrete
        if self.warm:
            return d.epsilon_end
        progress = min(1.0, max(0, self.buffer.total - self.cfg.learning_starts) / max(1, d.epsilon_decay_steps))
        return d.epsilon_start + progress * (d.epsilon_end - d.epsilon_start)

    def policy_action(self, obs: np.ndarray, deterministic: bool) -> np.ndarray:
        if not deterministic and self.rng.random() < self.epsilon():
            return self.random_action()
        with torch.inference_mode():
            q = self.acting_network()(torch.from_numpy(np.asarray(obs, dtype=np.float32)).view(1, -1))
        return self._index(int(q.argmax(-1)))

    def rollout_policy(self, obs: Tensor) -> Tensor:
        q = self.acting_network()
        assert isinstance(q, DuelingQNetwork)
        return q.greedy_one_hot(obs)

    def fear_policy(self, obs: Tensor) -> Tensor:
        return self.q.greedy_one_hot(obs)

    # -- learning --------------------------------------------------------------------------------------
    def fear_active(self) -> bool:
        return self.cfg.fear_regularisation and self.world_model_ready()

    def c_star(self) -> float:
        bounds = self.cfg.reward_bounds or self.buffer.reward_bounds() or (0.0, 0.0)
        low, high = bounds
        lam = self.lam if self.fear_active() else 0.0
        paper = penalty_c_star(low, high, self.cfg.gamma, self.cfg.safety_horizon, lam)
        return max(paper, self.cfg.c_star_floor, abs(low), abs(high), self.buffer.reward_magnitude())

    def real_fear(self, obs: Tensor) -> Tensor:
        return self._fear(obs)

    def _fear(self, obs: Tensor) -> Tensor:
        """F(s, greedy a) through the frozen world model."""
        assert self.world_model is not None
        with torch.no_grad():
            obs = obs.to(self.device)
            return fear(
                self.update_folded(),
                self.fear_policy,
                obs,
                self.fear_policy(obs),
                self.cfg.gate,
                horizon=self.cfg.learner_fear_horizon,
            ).fear

    def make_captured(self) -> CapturedUpdate:
        return CapturedD3QNUpdate(self)

    def update(self) -> dict[str, float]:
        if self.cfg.cuda_graph:
            return self.captured_update()
        cfg = self.cfg
        batch = self.buffer.sample(cfg.batch_size, self.rng)
        actions = batch.action.argmax(-1, keepdim=True)
        fear_next = self._fear(batch.next_obs) if self.fear_active() else None
        y = double_q_target(
            self.q,
            self.q_target,
            batch.reward,
            batch.next_obs,
            batch.terminated,
            cfg.gamma,
            fear_next=fear_next,
            lam=self.lam,
            violation=batch.violation if cfg.violation_penalty else None,
            c_star=self.c_star() if cfg.violation_penalty else 0.0,
        )
        q_all = self.q(batch.obs)
        q = q_all.gather(-1, actions).squeeze(-1)
        loss = F.smooth_l1_loss(q, y)
        stats: dict[str, float] = {"q_loss": loss.item(), "q_mean": q.mean().item(), "epsilon": self.epsilon()}
        imitation = self.buffer.sample_takeovers(cfg.bc_batch_size, self.rng) if cfg.imitation else None
        if imitation is not None:
            q_scale = q_all.detach().abs().mean().clamp_min(1.0)
            q_imitation = self.q(imitation.obs)
            expert = imitation.a_expert.argmax(-1)
            with torch.no_grad():
                q_expert = q_imitation.gather(-1, expert.view(-1, 1)).squeeze(-1)
                q_agent = q_imitation.gather(-1, imitation.a_rl.argmax(-1).view(-1, 1)).squeeze(-1)
                omega = advantage_weights(q_expert, q_agent, q_scale, cfg.advantage_temperature, cfg.advantage_clip)
            margin = weighted_margin_loss(q_imitation, expert, omega, cfg.discrete.margin)
            loss = loss + cfg.bc_weight * margin
            stats.update(bc_loss=margin.item(), omega_mean=omega.mean().item())
        self.q_optimizer.zero_grad(set_to_none=True)
        loss.backward()
        if cfg.max_grad_norm is not None:
            torch.nn.utils.clip_grad_norm_(self.q.parameters(), cfg.max_grad_norm)
        self.q_optimizer.step()
        soft_update(self.q_target, self.q, cfg.polyak)
        if self.fear_active():
            fear_real = float(self._fear(batch.obs).mean())
            stats.update(fear_real=fear_real, lam=self.dual_step(fear_real), fear_budget=self.fear_budget())
        return stats

    def behaviour_clone(self, steps: int, lr: float = 1e-3) -> float:
        """The margin loss alone on intervention samples: the expert's action becomes the greedy one."""
        optimizer = torch.optim.Adam(self.q.parameters(), lr=lr)
        loss = torch.tensor(math.nan)
        for _ in range(steps):
            batch = self.buffer.sample_takeovers(self.cfg.batch_size, self.rng)
            if batch is None:
                break
            loss = weighted_margin_loss(self.q(batch.obs), batch.a_expert.argmax(-1), None, self.cfg.discrete.margin)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
        self.q_target.load_state_dict(self.q.state_dict())
        self.refresh_acting()
        return float(loss.detach())

    def declared_state(self) -> DeclaredState:
        return DeclaredState(modules=("q", "q_target"), optimizers=("q_optimizer",), scalars=("lam",))

    def state_dict(self) -> dict[str, Any]:
        state = super().state_dict()
        state["lam"] = torch.tensor(self.lam)
        return state

    def load_state_dict(self, state: dict[str, Any], strict: bool = True) -> list[str]:
        loaded = super().load_state_dict(state, strict)
        if "lam" in state:
            self.lam = float(torch.as_tensor(state["lam"]))
            loaded.append("lam")
        if "q" in loaded and "q_target" not in state:
            self.q_target.load_state_dict(self.q.state_dict())
        return loaded


class DiscreteHGDAgger(D3QN):
    """HG-DAgger on discrete actions: the dueling network's outputs as a classifier's logits, trained by
    cross-entropy on the aggregated expert labels (takeovers and demonstrations); it never explores and has no
    critic target (see :mod:`core.sage.hg_dagger` for the takeover rule, the same SAGE gate). The paper's
    long-tail expert is trained this way from a human's demonstrations and corrections; here from the scripted
    driver's."""

    uses_random_warmup = False

    def build_networks(self) -> None:
        super().build_networks()
        self.q_optimizer = torch.optim.Adam(self.q.parameters(), lr=self.cfg.dagger_lr)

    def policy_action(self, obs: np.ndarray, deterministic: bool) -> np.ndarray:
        return super().policy_action(obs, deterministic=True)

    def update_threshold(self) -> int:
        return 1  # learn from the first expert label on

    def update(self) -> dict[str, float]:
        batch = self.buffer.sample_takeovers(self.cfg.batch_size, self.rng)
        if batch is None:
            return {}
        loss = F.cross_entropy(self.q(batch.obs), batch.a_expert.argmax(-1))
        self.q_optimizer.zero_grad(set_to_none=True)
        loss.backward()
        if self.cfg.max_grad_norm is not None:
            torch.nn.utils.clip_grad_norm_(self.q.parameters(), self.cfg.max_grad_norm)
        self.q_optimizer.step()
        return {"bc_loss": loss.item(), "aggregate_size": float(self.buffer.takeover_count())}

    def behaviour_clone(self, steps: int, lr: float = 1e-3) -> float:
        loss = torch.tensor(math.nan)
        for _ in range(steps):
            stats = self.update()
            if not stats:
                break
            loss = torch.tensor(stats["bc_loss"])
        return float(loss)


class CapturedD3QNUpdate(CapturedUpdate):
    """:meth:`core.sage.d3qn.D3QN.update` as one graph per structure."""

    learner: D3QN

    def __call__(self) -> dict[str, float]:
        learner, cfg = self.learner, self.learner.cfg
        assert isinstance(learner, D3QN)
        batch = learner.buffer.sample(cfg.batch_size, learner.rng)
        fear_on = learner.fear_active()
        imitation = learner.buffer.sample_takeovers(cfg.bc_batch_size, learner.rng) if cfg.imitation else None
        if fear_on:
            self.static_folded()
        key = (fear_on, imitation is not None)
        if key not in self.inputs:
            imitation_inputs = None if imitation is None else static_batch(imitation)
            self.inputs[key] = {"batch": static_batch(batch), "imitation": imitation_inputs}
        inputs = self.inputs[key]
        fill_batch(inputs["batch"], batch)
        if imitation is not None:
            fill_batch(inputs["imitation"], imitation)
        self.scalars["lam"].fill_(learner.lam)
        self.scalars["c_star"].fill_(learner.c_star() if cfg.violation_penalty else 0.0)
        self.scalars["fear_budget"].fill_(learner.fear_budget())
        stats = self.run(key, lambda: self.body(inputs["batch"], inputs["imitation"], fear_on))
        stats["epsilon"] = learner.epsilon()
        if fear_on:
            stats["fear_budget"] = learner.fear_budget()
        else:
            stats.pop("lam", None)
        return stats

    def body(self, batch: Batch, imitation: Batch | None, fear_on: bool) -> dict[str, Tensor]:
        learner, cfg, lam = self.learner, self.learner.cfg, self.scalars["lam"]
        actions = batch.action.argmax(-1, keepdim=True)
        fear_next = None
        if fear_on:
            with torch.no_grad():
                fear_next = self.fear(batch.next_obs, learner.fear_policy(batch.next_obs), learner.fear_policy)
        y = double_q_target(
            learner.q, learner.q_target, batch.reward, batch.next_obs, batch.terminated, cfg.gamma,
            fear_next=fear_next, lam=lam, violation=batch.violation if cfg.violation_penalty else None,
            c_star=self.scalars["c_star"],
        )  # fmt: skip
        q_all = learner.q(batch.obs)
        q = q_all.gather(-1, actions).squeeze(-1)
        loss = F.smooth_l1_loss(q, y)
        stats: dict[str, Tensor] = {"q_loss": loss.detach(), "q_mean": q.detach().mean()}
        if imitation is not None:
            q_scale = q_all.detach().abs().mean().clamp_min(1.0)
            q_imitation = learner.q(imitation.obs)
            expert = imitation.a_expert.argmax(-1)
            with torch.no_grad():
                q_expert = q_imitation.gather(-1, expert.view(-1, 1)).squeeze(-1)
                q_agent = q_imitation.gather(-1, imitation.a_rl.argmax(-1).view(-1, 1)).squeeze(-1)
                scale = cfg.advantage_temperature * q_scale
                omega = torch.exp(((q_expert - q_agent) / scale).clamp(-cfg.advantage_clip, cfg.advantage_clip))
            margin = weighted_margin_loss(q_imitation, expert, omega, cfg.discrete.margin)
            loss = loss + cfg.bc_weight * margin
            stats.update(bc_loss=margin.detach(), omega_mean=omega.mean())
        self.zero(learner.q_optimizer)
        loss.backward()
        if cfg.max_grad_norm is not None:
            torch.nn.utils.clip_grad_norm_(learner.q.parameters(), cfg.max_grad_norm)
        learner.q_optimizer.step()
        soft_update(learner.q_target, learner.q, cfg.polyak)
        if fear_on:
            with torch.no_grad():
                fear_real = self.fear(batch.obs, learner.fear_policy(batch.obs), learner.fear_policy).mean()
            stats["fear_real"] = fear_real
            stats["lam"] = (lam + cfg.lambda_lr * (fear_real - self.scalars["fear_budget"])).clamp(0.0, cfg.lambda_max)
        else:
            stats["lam"] = lam
        return stats
