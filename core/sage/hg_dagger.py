"""HG-DAgger (Kelly et al. 2019): interactive imitation by aggregating the expert's takeovers.

The learner drives; when the takeover rule fires, the expert drives, and every expert-labelled state
(s, a_expert) joins an aggregated dataset (here: the intervention samples Ξ = 1 of the real buffer,
demonstrations included). The policy is trained by plain supervised regression of its deterministic action
onto the expert's on that aggregate, ``updates_per_step`` minibatch steps per environment step. There is no
critic, no reward and no exploration noise.

Takeover rule. In the original a person takes over when they judge the state unsafe. Here the takeover is
driven by the same SAGE gate (fear of the learner's intended action vs the curiosity-modulated threshold, on
a world model trained on the real buffer), so that HG-DAgger and SAGE differ only in what they learn from
the takeovers (pure aggregated imitation vs fear-regularised SAC with value-weighted imitation), not in
when the expert is asked.
"""

from __future__ import annotations

import numpy as np
import torch

from core.sage.config import AgentConfig
from core.sage.learner import ActorLearner, DeclaredState


class HGDAgger(ActorLearner):
    uses_random_warmup = False

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
        self.optimizer = torch.optim.Adam(self.actor.parameters(), lr=cfg.dagger_lr)

    def policy_action(self, obs: np.ndarray, deterministic: bool) -> np.ndarray:
        return super().policy_action(obs, deterministic=True)  # HG-DAgger's learner never explores

    def declared_state(self) -> DeclaredState:
        return DeclaredState(modules=("actor",), optimizers=("optimizer",))

    def update_threshold(self) -> int:
        return 1  # learn from the first expert label on

    def update(self) -> dict[str, float]:
        batch = self.buffer.sample_takeovers(self.cfg.batch_size, self.rng)
        if batch is None:
            return {}
        loss = (self.actor.deterministic(batch.obs) - batch.a_expert).pow(2).sum(-1).mean()
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        if self.cfg.max_grad_norm is not None:
            torch.nn.utils.clip_grad_norm_(self.actor.parameters(), self.cfg.max_grad_norm)
        self.optimizer.step()
        return {"bc_loss": loss.item(), "aggregate_size": float(self.buffer.takeover_count())}
