"""TD3 (Fujimoto et al. 2018), the paper's second model-free baseline, on the shared networks and buffers.

Deterministic actor: the :class:`~core.sage.networks.Actor`'s ``tanh(mean)`` path (so a SAC checkpoint can
warm-start it); Gaussian exploration noise; twin (``critics``) critics with clipped double-Q targets,
target policy smoothing and delayed actor/target updates. No SAGE extras: a TD3 run trains no world model
unless ``world_model=true`` is set (then it has a gate for display, never used for takeover in training).
"""

from __future__ import annotations

import copy
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from core.sage.config import AgentConfig
from core.sage.learner import CRITIC_DISTIL_UPDATES, ActorLearner, DeclaredState
from core.sage.networks import EnsembleCritic, adam, soft_update


class TD3(ActorLearner):
    def __init__(
        self,
        cfg: AgentConfig,
        obs_dim: int,
        act_dim: int,
        action_low: np.ndarray | None = None,
        action_high: np.ndarray | None = None,
        seed: int = 0,
        *,
        device: str | torch.device = "cpu",
    ) -> None:
        super().__init__(cfg, obs_dim, act_dim, action_low, action_high, seed, device=device)
        self.actor_target = copy.deepcopy(self.actor).requires_grad_(False)
        self.critic = EnsembleCritic(
            obs_dim, act_dim, cfg.hidden, cfg.layers, max(2, cfg.critics), layer_norm=cfg.critic_layer_norm
        ).to(self.device)
        self.critic_target = copy.deepcopy(self.critic).requires_grad_(False)
        self.actor_optimizer = adam(self.actor.parameters(), cfg.actor_lr)
        self.critic_optimizer = adam(self.critic.parameters(), cfg.critic_lr)
        self.scale = (self.action_high - self.action_low) / 2.0
        # the action bounds where the update's target actions are clipped
        bounds = (self.action_low, self.action_high, self.scale)
        self._low, self._high, self._scale = (t.to(self.device) for t in bounds)

    def policy_action(self, obs: np.ndarray, deterministic: bool) -> np.ndarray:
        with torch.inference_mode():
            action = self.acting_actor.deterministic(torch.from_numpy(np.asarray(obs, dtype=np.float32)).view(1, -1))[0]
            if not deterministic:
                action = action + torch.randn_like(action) * self.cfg.td3_exploration_noise * self.scale
                action = torch.max(torch.min(action, self.action_high), self.action_low)
        return action.numpy()

    def update(self) -> dict[str, float]:
        if self.critic_teacher is not None:
            self.distil_critic(CRITIC_DISTIL_UPDATES)  # a warm start's critics of another shape, before any TD step
        cfg = self.cfg
        batch = self.buffer.sample(cfg.batch_size, self.rng)
        with torch.no_grad():
            noise = (torch.randn_like(batch.action) * cfg.td3_policy_noise).clamp(
                -cfg.td3_noise_clip, cfg.td3_noise_clip
            )
            next_action = self.actor_target.deterministic(batch.next_obs) + noise * self._scale
            next_action = torch.max(torch.min(next_action, self._high), self._low)
            next_q = self.critic_target(batch.next_obs, next_action).min(0).values
            y = batch.reward + cfg.gamma * (1.0 - batch.terminated) * next_q
        q = self.critic(batch.obs, batch.action)
        critic_loss = F.mse_loss(q, y.unsqueeze(0).expand_as(q), reduction="none").mean(1).sum()
        self.critic_optimizer.zero_grad(set_to_none=True)
        critic_loss.backward()
        if cfg.max_grad_norm is not None:
            torch.nn.utils.clip_grad_norm_(self.critic.parameters(), cfg.max_grad_norm)
        self.critic_optimizer.step()
        stats = {"critic_loss": critic_loss.item(), "q_mean": q.mean().item()}
        if self.updates % cfg.td3_policy_delay == 0:
            self.critic.requires_grad_(False)
            actor_loss = -self.critic(batch.obs, self.actor.deterministic(batch.obs))[0].mean()
            self.actor_optimizer.zero_grad(set_to_none=True)
            actor_loss.backward()
            self.critic.requires_grad_(True)
            if cfg.max_grad_norm is not None:
                torch.nn.utils.clip_grad_norm_(self.actor.parameters(), cfg.max_grad_norm)
            self.actor_optimizer.step()
            soft_update(self.critic_target, self.critic, cfg.polyak)
            soft_update(self.actor_target, self.actor, cfg.polyak)
            stats["actor_loss"] = actor_loss.item()
        return stats

    def pretrain(self, returns: np.ndarray | None = None) -> dict[str, float]:
        stats = super().pretrain(returns)
        self.actor_target.load_state_dict(self.actor.state_dict())
        distilled = self.distil_critic(CRITIC_DISTIL_UPDATES)
        if distilled is not None:
            stats["pretrain_critic_distil_loss"] = distilled
        return stats

    def load_state_dict(self, state: dict[str, Any], strict: bool = True) -> list[str]:
        loaded = super().load_state_dict(state, strict)
        if "actor" in loaded and "actor_target" not in loaded:
            self.actor_target.load_state_dict(self.actor.state_dict())
            loaded.append("actor_target")
        if "critic" in loaded and "critic_target" not in loaded:
            self.critic_target.load_state_dict(self.critic.state_dict())
        return loaded

    def declared_state(self) -> DeclaredState:
        return DeclaredState(
            modules=("actor", "critic", "critic_target", "actor_target"),
            optimizers=("actor_optimizer", "critic_optimizer"),
        )
