"""SAC, FNI-RL and SAGE-SAC: one soft actor-critic whose SAGE extras are switches of :class:`AgentConfig`.

Critic (eq:critic_loss_fear). An ensemble of Z critics (one batched forward) regresses on

    y = r + γ (1 - done) [ min_z Q̄_z(s', a') - α log π(a'|s') - λ F_{t+1} ],   a' ~ π(·|s')
    y = -c*                                                 if the transition is a safety violation

(``fear_regularisation`` adds -λF_{t+1}, ``violation_penalty`` the terminal -c*). F is the fear of
(s', a') through the frozen world model, ``learner_fear_horizon`` steps (1 = eq:fear).

c* (eq:penalty) = (r̄ - r̲) / (γ^H (1 - γ)) + λ / γ^H - r̄ / (1 - γ). The inequality before it asks for
c* > (r̄ - r̲ + λ (1 - γ)(f̄ - f̲)) / γ^H - r̄. The paper's choice does not always meet it: their difference is
γ/(1-γ) [(r̄ - r̲)/γ^H - r̄] + λ (1 - (1-γ)(f̄ - f̲)) / γ^H, negative when rewards are all positive with a
narrow range (r̲ > γ^H r̄). :func:`penalty_c_star` therefore takes the larger of eq:penalty and the bound
itself (plus a margin), and never less than 0, so the inequality holds for any bounds.

Actor (eq:actor_loss_fear + eq:actor_loss_expert). On states from D_actual ∪ D_virtual (``virtual_ratio``),
a ~ π(·|s) reparameterised:

    L_a = E[ α log π(a|s) - min_z Q_z(s, a) + λ F(s, a) ] + w_bc · max(1, mean|Q|) · L_BC

F(s, a) is differentiable w.r.t. a through the world model's folded weights, which are detached constants:
the actor gets the fear gradient, the world model gets none. L_BC = E_{Ξ=1}[ω ||μ_θ(s) - a_E||²] on
intervention samples, ω = exp(clip(A / (T · max(1, mean|Q|)), -κ, κ)), A = min_z Q_z(s, a_E) - min_z Q_z(s, a_RL)
(detached). Dividing the advantage by the batch's Q scale makes ω independent of the reward's units, and the
clip keeps it in [e^-κ, e^κ] however large the Q gap: a huge advantage can neither overflow nor let one
sample swamp the batch. The imitation term is scaled by mean|Q| so that it keeps pace with the Q term; with
``fear_scale="q"`` the fear term is too (λ·max(1, mean|Q|)·F, :func:`actor_fear_weight`), the critic target's -λF not.

Dual (eq:lambda_update): λ ← clip(λ + lr_λ (mean F(s, π(s)) - F_0), 0, λ_max) on the real states of the
actor batch: λ grows while mean fear exceeds the budget and shrinks (never below 0) otherwise. F_0 is measured
at every world-model fit, the mean fear of its familiar states (``fear_budget_from_data``), or a constant.
Temperature: SAC v2 automatic α towards entropy -dim(A).

IBRL (``ibrl``, Hu et al. 2023; off in the paper's SAGE): a second actor π_IL, cloned on the expert's rows only.
The acting policy proposes a_RL and π_IL's a_IL and takes the one with the higher min_z Q_z(s, ·)
(:meth:`SAC.policy_action`, also in a published version: the checkpoint holds π_IL), and the target's next value is
the larger of the two proposals', max(min_z Q̄_z(s', a') - α log π(a'|s'), min_z Q̄_z(s', a_IL')) (each less λF
where fear is on). The gate's imagined rollouts after the judged action follow the RL actor.
"""

from __future__ import annotations

import copy
import math
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from core.protocol import StepRecord
from core.replay import Batch, ReplayBuffer
from core.sage.captured import CapturedUpdate, fill_batch, static_batch
from core.sage.config import AgentConfig
from core.sage.fear import fear, one_step_fear
from core.sage.learner import CRITIC_DISTIL_UPDATES, ActorLearner, DeclaredState
from core.sage.networks import EnsembleCritic, adam, soft_update


def penalty_c_star(
    reward_min: float, reward_max: float, gamma: float, horizon: int, lam: float, fear_range: float = 1.0
) -> float:
    """c* of eq:penalty, raised where needed so that the sufficient condition before it holds strictly."""
    gh = gamma**horizon
    paper = (reward_max - reward_min) / (gh * (1.0 - gamma)) + lam / gh - reward_max / (1.0 - gamma)
    bound = (reward_max - reward_min + lam * (1.0 - gamma) * fear_range) / gh - reward_max
    margin = 1e-6 * max(1.0, abs(bound))
    return max(paper, bound + margin, 0.0)


def penalty_condition_holds(
    c_star: float,
    reward_min: float,
    reward_max: float,
    gamma: float,
    horizon: int,
    lam: float,
    fear_min: float = 0.0,
    fear_max: float = 1.0,
) -> bool:
    """The paper's inequality: the best unsafe return is below the worst safe return."""
    gh = gamma**horizon
    unsafe = (reward_max * (1 - gh) - c_star * gh) / (1 - gamma) - lam * fear_min
    safe = reward_min / (1 - gamma) - lam * fear_max
    return unsafe < safe


def advantage_weights(
    q_expert: Tensor, q_agent: Tensor, q_scale: Tensor | float, temperature: float, clip: float
) -> Tensor:
    """ω = exp(clip((Q(s,a_E) - Q(s,a_RL)) / (T · max(1, q_scale)), -clip, clip)) (eq:qa_weight, bounded)."""
    scale = temperature * torch.clamp(torch.as_tensor(q_scale, dtype=q_expert.dtype, device=q_expert.device), min=1.0)
    return torch.exp(((q_expert - q_agent) / scale).clamp(-clip, clip))


def ensemble_value(q: Tensor, mean: bool) -> Tensor:
    """The critics' ``(Z, batch)`` values as one: their minimum, or their mean (``critic_target_subset``'s actor)."""
    return q.mean(0) if mean else q.min(0).values


def expert_and_agent_q(critic: EnsembleCritic, imitation: Batch, mean: bool = False) -> tuple[Tensor, Tensor]:
    """min_z Q_z(s, a_E) and min_z Q_z(s, a_RL) (the mean over z with ``mean``) of the intervention samples, from one
    critic pass over both (the same values as two passes up to the float32 rounding of products over more rows)."""
    q = critic(torch.cat([imitation.obs, imitation.obs]), torch.cat([imitation.a_expert, imitation.a_rl]))
    q = ensemble_value(q, mean)
    return q[: len(imitation.obs)], q[len(imitation.obs) :]


def actor_fear_weight(lam: Tensor | float, q_scale: Tensor, fear_scale: str) -> Tensor | float:
    """The weight of F in the actor's loss: λ (``fear_scale="none"``) or λ·max(1, mean|Q|) (``"q"``, detached)."""
    return lam * q_scale if fear_scale == "q" else lam


class SAC(ActorLearner):
    """Soft actor-critic with SAGE's switches (see :func:`core.sage.config.for_method`)."""

    reads_refused = True
    reads_critic_subset = True
    reads_conservative = True
    reads_ibrl = True

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
        self.critic = EnsembleCritic(
            obs_dim, act_dim, cfg.hidden, cfg.layers, cfg.critics, layer_norm=cfg.critic_layer_norm
        ).to(self.device)
        self.critic_target = copy.deepcopy(self.critic).requires_grad_(False)
        self.actor_optimizer = adam(self.actor.parameters(), cfg.actor_lr, self.captures)
        self.critic_optimizer = adam(self.critic.parameters(), cfg.critic_lr, self.captures)
        self.log_alpha = torch.tensor(math.log(cfg.init_alpha), device=self.device, requires_grad=True)
        self.alpha_optimizer = adam([self.log_alpha], cfg.alpha_lr, self.captures)
        if cfg.ibrl:
            self.il_actor = copy.deepcopy(self.actor)
            """IBRL's π_IL: the expert's rows only, by behaviour cloning (:meth:`fit_imitation_policy`)."""
            self.il_optimizer = torch.optim.Adam(self.il_actor.parameters(), lr=cfg.actor_lr)
        self.proposals = [0, 0]
        """With ``ibrl``: how often the RL actor's and π_IL's action acted (:meth:`policy_action`)."""
        self.target_entropy = -float(act_dim) if cfg.target_entropy is None else cfg.target_entropy
        self.prior_distill = 0.0
        """Weight of the distillation anchor on the buffer's prior rows (set by fine-tuning:
        ``FinetuneConfig.prior_distill``); 0: no anchor batch is drawn."""
        self._returns_key: tuple[int, int] | None = None
        self._returns: tuple[np.ndarray, np.ndarray] = (np.zeros(0), np.zeros(0))
        """The buffer's discounted sums ahead (rewards off violations, violations) for :meth:`recorded_returns`."""
        self.anchor_rows: ReplayBuffer | None = None
        """Rows the anchor draws from instead of the buffer's prior rows when set and not empty, each ``a_rl`` the
        base's deterministic action at its state (``FinetuneConfig.anchor_relabel``); None: the prior rows."""

    # -- IBRL ----------------------------------------------------------------------------------------
    def policy_action(self, obs: np.ndarray, deterministic: bool) -> np.ndarray:
        """The actor's action; with ``ibrl``, IBRL's actor proposal: π_IL's deterministic action instead where the
        critics' minimum (their mean with ``critic_target_subset``) values it higher than the actor's."""
        action = super().policy_action(obs, deterministic)
        if not self.cfg.ibrl:
            return action
        with torch.inference_mode():
            o = torch.as_tensor(np.asarray(obs, dtype=np.float32), device=self.device).view(1, -1)
            proposed = torch.as_tensor(np.asarray(action, dtype=np.float32), device=self.device).view(1, -1)
            il_action = self.il_actor.deterministic(o)
            q = self.critic(torch.cat([o, o]), torch.cat([proposed, il_action]))
            q = ensemble_value(q, self.cfg.critic_target_subset is not None)
            imitation = bool(q[1] > q[0])
        self.proposals[int(imitation)] += 1
        return il_action[0].cpu().numpy() if imitation else action

    def fit_imitation_policy(
        self, updates: int, heldout_obs: np.ndarray | None = None, heldout_expert: np.ndarray | None = None
    ) -> dict[str, float]:
        """Behaviour cloning of IBRL's π_IL on the buffer's expert rows (takeovers, demonstrations), ``updates`` steps
        on from its present weights; with held-out expert rows, their error is measured every 100 updates and the
        weights of the lowest kept. Returns the last loss, the held-out error kept and the update it was kept at
        (empty without ``ibrl`` or without expert rows)."""
        if not self.cfg.ibrl or updates <= 0 or self.buffer.takeover_count() == 0:
            return {}
        held = heldout_obs is not None and heldout_expert is not None and len(heldout_obs) > 0

        def heldout_error() -> float:
            assert heldout_obs is not None and heldout_expert is not None
            with torch.no_grad():
                action = self.il_actor.deterministic(torch.as_tensor(heldout_obs, device=self.device))
                return float((action - torch.as_tensor(heldout_expert, device=self.device)).pow(2).sum(-1).mean())

        best = heldout_error() if held else math.inf
        best_at, best_state = 0, copy.deepcopy(self.il_actor.state_dict()) if held else None
        loss = torch.tensor(math.nan)
        done = 0
        for k in range(updates):
            batch = self.buffer.sample_takeovers(self.cfg.bc_batch_size, self.rng)
            if batch is None:
                break
            loss = (self.il_actor.deterministic(batch.obs) - batch.a_expert).pow(2).sum(-1).mean()
            self.il_optimizer.zero_grad(set_to_none=True)
            loss.backward()
            self.il_optimizer.step()
            done = k + 1
            if held and (done % 100 == 0 or done == updates):
                error = heldout_error()
                if error < best:
                    best, best_at, best_state = error, done, copy.deepcopy(self.il_actor.state_dict())
        stats = {"il_bc_loss": float(loss.detach()), "il_updates": float(done)}
        if held and best_state is not None:
            if best_at != done:
                self.il_actor.load_state_dict(best_state)
            stats.update(il_heldout_error=best, il_kept_update=float(best_at))
        return stats

    def observe(self, record: StepRecord) -> None:
        super().observe(record)
        every = self.cfg.ibrl_refit_every
        if self.cfg.ibrl and every > 0 and self.env_steps % every == 0:
            self.info.update(self.fit_imitation_policy(self.cfg.ibrl_updates))  # the takeovers so far, online

    # -- pieces ------------------------------------------------------------------------------------
    @property
    def alpha(self) -> float:
        return self.log_alpha.detach().exp().item() if self.cfg.autotune_alpha else self.cfg.init_alpha

    def fear_active(self) -> bool:
        return self.cfg.fear_regularisation and self.world_model_ready()

    def real_fear(self, obs: Tensor) -> Tensor:
        """F(s, a), a ~ π(·|s): the fear the actor's loss and the dual update read on real states."""
        obs = obs.to(self.device)  # the fit's calibration states come from numpy, on the CPU
        return self.learner_fear(obs, self.actor.sample(obs)[0])

    def learner_fear(self, obs: Tensor, action: Tensor) -> Tensor:
        """F(s, a) through the frozen world model (differentiable w.r.t. ``action`` under grad mode)."""
        assert self.world_model is not None
        if self.cfg.learner_fear_horizon == 1:  # the default: one step, its gradient by hand
            return one_step_fear(
                self.update_folded(), self.fear_policy, obs.to(self.device), action.to(self.device), self.cfg.gate
            )
        return fear(
            self.update_folded(),
            self.fear_policy,
            obs.to(self.device),
            action.to(self.device),
            self.cfg.gate,
            horizon=self.cfg.learner_fear_horizon,
        ).fear

    def reward_bounds(self) -> tuple[float, float]:
        if self.cfg.reward_bounds is not None:
            return self.cfg.reward_bounds
        return self.buffer.reward_bounds() or (0.0, 0.0)

    def c_star(self) -> float:
        low, high = self.reward_bounds()
        paper = penalty_c_star(
            low, high, self.cfg.gamma, self.cfg.safety_horizon, self.lam if self.fear_active() else 0.0
        )
        recorded = self.buffer.reward_magnitude()
        return max(paper, self.cfg.c_star_floor, abs(low), abs(high), recorded)

    def critic_target_values(self, batch: Batch) -> Tensor:
        cfg = self.cfg
        with torch.no_grad():
            next_action, next_log_prob = self.actor.sample(batch.next_obs)
            next_qs = self.critic_target(batch.next_obs, next_action)
            if cfg.critic_target_subset is not None:
                drawn = torch.randperm(len(next_qs), device=next_qs.device)[: cfg.critic_target_subset]
                next_qs = next_qs[drawn]
            next_q = next_qs.min(0).values - self.alpha * next_log_prob
            if self.fear_active():
                next_q = next_q - self.lam * self.learner_fear(batch.next_obs, next_action)
            if cfg.ibrl:  # the bootstrap proposal: π_IL's next action where the critics value it higher
                il_action = self.il_actor.deterministic(batch.next_obs)
                il_qs = self.critic_target(batch.next_obs, il_action)
                if cfg.critic_target_subset is not None:
                    il_qs = il_qs[drawn]
                il_q = il_qs.min(0).values
                if self.fear_active():
                    il_q = il_q - self.lam * self.learner_fear(batch.next_obs, il_action)
                next_q = torch.maximum(next_q, il_q)
            y = batch.reward + cfg.gamma * (1.0 - batch.terminated) * next_q
            if cfg.violation_penalty:
                y = torch.where(batch.violation > 0.5, torch.full_like(y, -self.c_star()), y)
        return y

    def refused_loss(self) -> Tensor | None:
        """The critics' squared error from -c* on proposals the gate refused (``refused_weight``): each such row's
        a_RL was judged dangerous where it was proposed, and the expert drove instead, so no real transition says
        what it would have led to; the term says it would have been a violation. None: off or no such row."""
        if self.cfg.refused_weight <= 0:
            return None
        refused = self.buffer.sample_refused(self.cfg.bc_batch_size, self.rng)
        if refused is None:
            return None
        q = self.critic(refused.obs, refused.a_rl)
        return (q + self.c_star()).pow(2).mean(1).sum()

    def recorded_returns(self, batch: Batch) -> Tensor | None:
        """The discounted return to go recorded from each row of ``batch`` (drawn from :attr:`buffer`), a violation's
        reward counted as -c* where the critics' target counts it so; None for a batch that names no rows. The
        buffer's two sums (rewards off violations, violations) are kept until its rows change: c* moves with λ."""
        if batch.rows is None:
            return None
        buffer, gamma = self.buffer, self.cfg.gamma
        key = (id(buffer), buffer.writes)
        if self._returns_key != key:
            n = buffer.size
            violation = (buffer.violation[:n] > 0.5) if self.cfg.violation_penalty else np.zeros(n, bool)
            rewards = np.where(violation, 0.0, buffer.reward[:n])
            self._returns = (buffer.discounted_ahead(rewards, gamma), buffer.discounted_ahead(violation, gamma))
            self._returns_key = key
        plain, violations = self._returns
        ahead = plain[batch.rows]
        if self.cfg.violation_penalty:
            ahead = ahead - self.c_star() * violations[batch.rows]
        return torch.as_tensor(ahead, dtype=torch.float32, device=self.device)

    def conservative_loss(self, batch: Batch, q_data: Tensor) -> Tensor:
        """CQL(H)'s term (Cal-QL's where ``conservative_calibrated``), summed over the critics: the log-sum-exp of
        each critic's values at ``conservative_actions`` uniform actions and as many of the policy's per state, each
        less its log-density, minus its value ``q_data`` (critics x batch) at the recorded action. Cal-QL holds the
        policy actions' values no lower than the recorded return to go, so that it does not push a value under what
        the data achieved from the state (Nakamoto et al. 2023, eq. 5.1)."""
        cfg = self.cfg
        n, rows = cfg.conservative_actions, len(batch)
        states = batch.obs.repeat_interleave(n, 0)
        with torch.no_grad():
            policy_actions, policy_log_prob = self.actor.sample(states)
            low, high = self.action_low.to(self.device), self.action_high.to(self.device)
            uniform = low + (high - low) * torch.rand_like(policy_actions)
            uniform_log_density = -torch.log(high - low).sum()
        both = self.critic(torch.cat([states, states]), torch.cat([uniform, policy_actions]))
        q_uniform, q_policy = both.view(len(both), 2, rows, n).unbind(1)
        floor = self.recorded_returns(batch) if cfg.conservative_calibrated else None
        if floor is not None:
            q_policy = torch.maximum(q_policy, floor.view(1, rows, 1))
        weighted = torch.cat([q_uniform - uniform_log_density, q_policy - policy_log_prob.view(1, rows, n)], -1)
        return (torch.logsumexp(weighted, -1) - q_data).mean(1).sum()

    def critic_step(self, batch: Batch) -> dict[str, float]:
        y = self.critic_target_values(batch)
        q = self.critic(batch.obs, batch.action)
        loss = F.mse_loss(q, y.unsqueeze(0).expand_as(q), reduction="none").mean(1).sum()
        refused = self.refused_loss()
        if refused is not None:
            loss = loss + self.cfg.refused_weight * refused
        conservative = self.conservative_loss(batch, q) if self.cfg.conservative_weight > 0 else None
        if conservative is not None:
            loss = loss + self.cfg.conservative_weight * conservative
        self.critic_optimizer.zero_grad(set_to_none=True)
        loss.backward()
        if self.cfg.max_grad_norm is not None:
            torch.nn.utils.clip_grad_norm_(self.critic.parameters(), self.cfg.max_grad_norm)
        self.critic_optimizer.step()
        soft_update(self.critic_target, self.critic, self.cfg.polyak)
        stats = {"critic_loss": loss.item(), "q_mean": q.mean().item()}
        if refused is not None:
            stats["refused_loss"] = refused.item()
        if conservative is not None:
            stats["conservative_loss"] = conservative.item()
        return stats

    def actor_states(self, batch: Batch) -> tuple[Tensor, int]:
        """States of the actor batch: real ones first, then virtual ones; returns (states, number real)."""
        n_virtual = 0
        if self.virtual is not None and len(self.virtual) > 0 and self.cfg.virtual_ratio > 0:
            n_virtual = round(self.cfg.virtual_ratio * len(batch))
        n_real = len(batch) - n_virtual
        if n_virtual == 0:
            return batch.obs, n_real
        assert self.virtual is not None
        return torch.cat([batch.obs[:n_real], self.virtual.sample_obs(n_virtual, self.rng)]), n_real

    def actor_loss(
        self, batch: Batch, imitation: Batch | None, anchor: Batch | None = None
    ) -> tuple[Tensor, Tensor, dict[str, float]]:
        """The composite actor loss, the log-probabilities (for α) and statistics. ``anchor``: prior rows whose
        recorded actions (``a_rl``, the base policy's) the deterministic action is held to, with weight
        ``prior_distill`` on the imitation's scale (no ω: the base's action is not judged by the critic)."""
        cfg = self.cfg
        states, n_real = self.actor_states(batch)
        # the deterministic actions of the imitation and anchor rows from the same trunk pass as the sample
        others = [rows.obs for rows in (imitation, anchor) if rows is not None]
        action, log_prob, modes = self.actor.sample_with_modes(states, *others)
        q = ensemble_value(self.critic(states, action), cfg.critic_target_subset is not None)
        loss = (self.alpha * log_prob - q).mean()
        stats: dict[str, float] = {}
        q_scale = q.detach().abs().mean().clamp_min(1.0)
        if self.fear_active():
            fear_values = self.learner_fear(states, action)
            loss = loss + actor_fear_weight(self.lam, q_scale, cfg.fear_scale) * fear_values.mean()
            stats["fear_real"] = fear_values[:n_real].mean().item()
            stats["fear_budget"] = self.fear_budget()
        if imitation is not None:
            with torch.no_grad():  # Q(s, a_E) and Q(s, a_RL) in one pass
                q_expert, q_agent = expert_and_agent_q(self.critic, imitation, cfg.critic_target_subset is not None)
                omega = advantage_weights(q_expert, q_agent, q_scale, cfg.advantage_temperature, cfg.advantage_clip)
            error = (modes[0] - imitation.a_expert).pow(2).sum(-1)
            bc = (omega * error).mean()
            loss = loss + cfg.bc_weight * q_scale * bc
            stats.update(bc_loss=bc.item(), omega_mean=omega.mean().item())
        if anchor is not None:
            distill = (modes[-1] - anchor.a_rl).pow(2).sum(-1).mean()
            loss = loss + self.prior_distill * q_scale * distill
            stats["prior_distill_loss"] = distill.item()
        return loss, log_prob, stats

    def imitation_batch(self) -> Batch | None:
        if not self.cfg.imitation:
            return None
        return self.buffer.sample_takeovers(self.cfg.bc_batch_size, self.rng)

    def anchor_batch(self) -> Batch | None:
        """Rows for the distillation anchor: ``anchor_rows`` where set, else the buffer's prior rows (None while
        ``prior_distill`` is 0: nothing drawn)."""
        if self.prior_distill <= 0:
            return None
        if self.anchor_rows is not None and len(self.anchor_rows) > 0:
            return self.anchor_rows.sample(self.cfg.bc_batch_size, self.rng)
        return self.buffer.sample_prior(self.cfg.bc_batch_size, self.rng)

    def actor_step(self, batch: Batch) -> dict[str, float]:
        self.critic.requires_grad_(False)  # the actor's loss needs gradients w.r.t. actions, not critic weights
        try:
            loss, log_prob, stats = self.actor_loss(batch, self.imitation_batch(), self.anchor_batch())
            self.actor_optimizer.zero_grad(set_to_none=True)
            loss.backward()
        finally:
            self.critic.requires_grad_(True)
        if self.cfg.max_grad_norm is not None:
            torch.nn.utils.clip_grad_norm_(self.actor.parameters(), self.cfg.max_grad_norm)
        self.actor_optimizer.step()
        if self.cfg.autotune_alpha:
            alpha_loss = -(self.log_alpha * (log_prob.detach() + self.target_entropy)).mean()
            self.alpha_optimizer.zero_grad(set_to_none=True)
            alpha_loss.backward()
            self.alpha_optimizer.step()
        if "fear_real" in stats:
            self.dual_step(stats["fear_real"])
        stats.update(actor_loss=loss.item(), alpha=self.alpha, lam=self.lam, entropy=-log_prob.mean().item())
        return stats

    # -- the update ----------------------------------------------------------------------------------
    def make_captured(self) -> CapturedUpdate:
        return CapturedSACUpdate(self)

    def update(self) -> dict[str, float]:
        if self.critic_teacher is not None:
            self.distil_critic(CRITIC_DISTIL_UPDATES)  # a warm start's critics of another shape, before any TD step
        if self.cfg.cuda_graph:
            return self.captured_update()
        batch = self.buffer.sample(self.cfg.batch_size, self.rng)
        stats = self.critic_step(batch)
        stats.update(self.actor_step(batch))
        return stats

    def pretrain(self, returns: np.ndarray | None = None) -> dict[str, float]:
        stats = super().pretrain(returns)
        if self.cfg.ibrl and "pretrain_bc_loss" in stats:
            self.il_actor.load_state_dict(self.actor.state_dict())  # IBRL's π_IL: the demonstrations' clone
        if not self.warm or len(self.buffer) < self.cfg.batch_size:
            return stats
        distilled = self.distil_critic(CRITIC_DISTIL_UPDATES)
        if distilled is not None:
            stats["pretrain_critic_distil_loss"] = distilled
        td_steps = self.cfg.pretrain_critic_steps
        if returns is not None and len(returns) > 0:
            regression = td_steps // 2
            td_steps -= regression
            stats["pretrain_return_loss"] = self.regress_critic(returns, regression)
            self.critic_target.load_state_dict(self.critic.state_dict())
        for _ in range(td_steps):
            stats.update(self.critic_step(self.buffer.sample(self.cfg.batch_size, self.rng)))
        self.info.update(stats)
        return stats

    def regress_critic(self, returns: np.ndarray, steps: int) -> float:
        """Monte-Carlo regression of every critic onto the demonstrations' returns-to-go."""
        targets = torch.as_tensor(returns, dtype=torch.float32, device=self.device)
        loss = torch.tensor(math.nan)
        for _ in range(steps):
            idx = self.rng.integers(0, len(returns), size=self.cfg.batch_size)
            obs = torch.from_numpy(self.buffer.obs[idx]).to(self.device)
            action = torch.from_numpy(self.buffer.action[idx]).to(self.device)
            q = self.critic(obs, action)
            loss = F.mse_loss(q, targets[idx].unsqueeze(0).expand_as(q), reduction="none").mean(1).sum()
            self.critic_optimizer.zero_grad(set_to_none=True)
            loss.backward()
            if self.cfg.max_grad_norm is not None:
                torch.nn.utils.clip_grad_norm_(self.critic.parameters(), self.cfg.max_grad_norm)
            self.critic_optimizer.step()
        return loss.item()

    # -- checkpoints -----------------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        state = super().state_dict()  # the declared modules (actor, critics), world model, optimisers
        state.update(log_alpha=self.log_alpha.detach().cpu().clone(), lam=torch.tensor(self.lam))
        return state

    def load_state_dict(self, state: dict[str, Any], strict: bool = True) -> list[str]:
        loaded = super().load_state_dict(state, strict)
        for name in ("log_alpha", "lam"):
            if name in state:
                value = torch.as_tensor(state[name])
                if name == "log_alpha":
                    with torch.no_grad():
                        self.log_alpha.copy_(value)
                else:
                    self.lam = float(value)
                loaded.append(name)
        if "critic" in loaded and "critic_target" not in state:
            self.critic_target.load_state_dict(self.critic.state_dict())
        if self.cfg.ibrl and "actor" in loaded and "il_actor" not in loaded:
            self.il_actor.load_state_dict(self.actor.state_dict())  # a base without π_IL: it starts as the actor
        return loaded

    def declared_state(self) -> DeclaredState:
        ibrl = self.cfg.ibrl
        return DeclaredState(
            modules=("actor", "critic", "critic_target") + (("il_actor",) if ibrl else ()),
            optimizers=("actor_optimizer", "critic_optimizer", "alpha_optimizer") + (("il_optimizer",) if ibrl else ()),
            tensors=("log_alpha",),
            scalars=("lam",),
        )


class CapturedSACUpdate(CapturedUpdate):
    """:meth:`core.sage.sac.SAC.update` (critic, actor, α, λ) as one graph per structure."""

    learner: SAC

    def __init__(self, learner: SAC, *, eager: bool = False) -> None:
        super().__init__(learner, eager=eager)
        self.scalars["prior_distill"] = torch.zeros((), device=self.device)

    def __call__(self) -> dict[str, float]:
        sac, cfg = self.learner, self.learner.cfg
        batch = sac.buffer.sample(cfg.batch_size, sac.rng)
        fear_on = sac.fear_active()
        imitation = sac.imitation_batch()
        anchor = sac.anchor_batch()
        n_virtual = 0
        if sac.virtual is not None and len(sac.virtual) > 0 and cfg.virtual_ratio > 0:
            n_virtual = round(cfg.virtual_ratio * len(batch))
        virtual = None if n_virtual == 0 else sac.virtual.sample_obs(n_virtual, sac.rng)  # type: ignore[union-attr]
        if fear_on:
            self.static_folded()
        key = (fear_on, imitation is not None, n_virtual, anchor is not None)
        if key not in self.inputs:
            self.inputs[key] = {
                "batch": static_batch(batch),
                "imitation": None if imitation is None else static_batch(imitation),
                "virtual": None if virtual is None else virtual.clone(),
                "anchor": None if anchor is None else static_batch(anchor),
            }
        inputs = self.inputs[key]
        fill_batch(inputs["batch"], batch)
        if imitation is not None:
            fill_batch(inputs["imitation"], imitation)
        if anchor is not None:
            fill_batch(inputs["anchor"], anchor)
        self.scalars["prior_distill"].fill_(sac.prior_distill)
        if virtual is not None:
            inputs["virtual"].copy_(virtual, non_blocking=True)
        self.scalars["lam"].fill_(sac.lam)
        self.scalars["c_star"].fill_(sac.c_star() if cfg.violation_penalty else 0.0)
        self.scalars["fear_budget"].fill_(sac.fear_budget())
        return self.run(
            key,
            lambda: self.body(inputs["batch"], inputs["imitation"], inputs["virtual"], fear_on, inputs["anchor"]),
        )

    def alpha(self) -> Tensor | float:
        sac = self.learner
        return sac.log_alpha.detach().exp() if sac.cfg.autotune_alpha else sac.cfg.init_alpha

    def body(
        self,
        batch: Batch,
        imitation: Batch | None,
        virtual: Tensor | None,
        fear_on: bool,
        anchor: Batch | None = None,
    ) -> dict[str, Tensor]:
        """One SAC update on the static inputs, kernels only: :meth:`SAC.critic_step` then :meth:`SAC.actor_step`."""
        sac, cfg, lam = self.learner, self.learner.cfg, self.scalars["lam"]
        stats: dict[str, Tensor] = {}
        # critic (SAC.critic_target_values, SAC.critic_step)
        with torch.no_grad():
            next_action, next_log_prob = sac.actor.sample(batch.next_obs)
            next_q = sac.critic_target(batch.next_obs, next_action).min(0).values - self.alpha() * next_log_prob
            if fear_on:
                next_q = next_q - lam * self.fear(batch.next_obs, next_action, sac.fear_policy)
            y = batch.reward + cfg.gamma * (1.0 - batch.terminated) * next_q
            if cfg.violation_penalty:
                y = torch.where(batch.violation > 0.5, -self.scalars["c_star"], y)
        q = sac.critic(batch.obs, batch.action)
        critic_loss = F.mse_loss(q, y.unsqueeze(0).expand_as(q), reduction="none").mean(1).sum()
        self.zero(sac.critic_optimizer)
        critic_loss.backward()
        if cfg.max_grad_norm is not None:
            torch.nn.utils.clip_grad_norm_(sac.critic.parameters(), cfg.max_grad_norm)
        sac.critic_optimizer.step()
        soft_update(sac.critic_target, sac.critic, cfg.polyak)
        stats.update(critic_loss=critic_loss.detach(), q_mean=q.detach().mean())
        # actor (SAC.actor_loss, SAC.actor_step)
        states = batch.obs if virtual is None else torch.cat([batch.obs[: len(batch.obs) - len(virtual)], virtual])
        n_real = len(states) if virtual is None else len(states) - len(virtual)
        sac.critic.requires_grad_(False)
        try:
            others = [rows.obs for rows in (imitation, anchor) if rows is not None]
            action, log_prob, modes = sac.actor.sample_with_modes(states, *others)  # as SAC.actor_loss
            q_pi = sac.critic(states, action).min(0).values
            actor_loss = (self.alpha() * log_prob - q_pi).mean()
            fear_real = None
            q_scale = q_pi.detach().abs().mean().clamp_min(1.0)
            if fear_on:
                fear_values = self.fear(states, action, sac.fear_policy)
                actor_loss = actor_loss + actor_fear_weight(lam, q_scale, cfg.fear_scale) * fear_values.mean()
                fear_real = fear_values[:n_real].mean()
                stats.update(fear_real=fear_real.detach(), fear_budget=self.scalars["fear_budget"])
            if imitation is not None:
                with torch.no_grad():
                    q_expert, q_agent = expert_and_agent_q(sac.critic, imitation)
                    scale = cfg.advantage_temperature * q_scale
                    omega = torch.exp(((q_expert - q_agent) / scale).clamp(-cfg.advantage_clip, cfg.advantage_clip))
                error = (modes[0] - imitation.a_expert).pow(2).sum(-1)
                bc = (omega * error).mean()
                actor_loss = actor_loss + cfg.bc_weight * q_scale * bc
                stats.update(bc_loss=bc.detach(), omega_mean=omega.mean())
            if anchor is not None:  # SAC.actor_loss's distillation anchor
                distill = (modes[-1] - anchor.a_rl).pow(2).sum(-1).mean()
                actor_loss = actor_loss + self.scalars["prior_distill"] * q_scale * distill
                stats.update(prior_distill_loss=distill.detach())
            self.zero(sac.actor_optimizer)
            actor_loss.backward()
        finally:
            sac.critic.requires_grad_(True)
        if cfg.max_grad_norm is not None:
            torch.nn.utils.clip_grad_norm_(sac.actor.parameters(), cfg.max_grad_norm)
        sac.actor_optimizer.step()
        if cfg.autotune_alpha:
            alpha_loss = -(sac.log_alpha * (log_prob.detach() + sac.target_entropy)).mean()
            self.zero(sac.alpha_optimizer)
            alpha_loss.backward()
            sac.alpha_optimizer.step()
        new_lam = lam
        if fear_real is not None:  # the dual step (BaseLearner.dual_step) on the device
            step = cfg.lambda_lr * (fear_real.detach() - self.scalars["fear_budget"])
            new_lam = (lam + step).clamp(0.0, cfg.lambda_max)
        stats.update(
            actor_loss=actor_loss.detach(), alpha=torch.as_tensor(self.alpha(), device=self.device), lam=new_lam,
            entropy=-log_prob.detach().mean(),
        )  # fmt: skip
        return stats
