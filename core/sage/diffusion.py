"""Diffusion-BC (Pearce et al. 2023) and Diffusion-QL (Wang et al. 2022): conditional diffusion policies, offline.

The policy is a denoising diffusion model of the action given the observation: a small MLP ε_θ(a_k, k, s) predicts
the noise that was mixed into a demonstrated action at noise level k of a variance-preserving (cosine) schedule
of T levels. Acting runs the reverse process as DDIM (deterministic updates) over ``sampling_steps`` of those T
levels from Gaussian noise, and clips to the action bounds.

- **Diffusion-BC**: the denoising loss on the expert's actions (the intervention samples Ξ = 1 of the buffer:
  demonstrations, recorded takeovers, or a whole offline dataset).
- **Diffusion-QL**: the same loss plus a Q-learning term. Twin critics learn by TD on every stored transition, the
  next action sampled from an EMA copy of the policy; the policy loss is BC − η Q(s, π(s)) / mean|Q|, with π(s)
  sampled through the reverse chain so that the gradient reaches the denoiser. It acts with the best of
  ``candidates`` sampled actions by Q.

Both learn offline: :meth:`DiffusionPolicy.pretrain` runs ``offline_steps`` gradient steps on the buffer (filled by
``--demo-episodes`` and/or ``--dataset``) and stepping the environment afterwards only stores transitions. The
number of sampling steps is a setting (``--set diffusion.sampling_steps=K``), also at evaluation time.
"""

from __future__ import annotations

import copy
import itertools
import math

import numpy as np
import torch
from torch import Tensor, nn

from core.protocol import StepRecord
from core.sage.learner import BaseLearner, DeclaredState
from core.sage.networks import EnsembleCritic, soft_update


def cosine_alpha_bars(steps: int, offset: float = 0.008) -> Tensor:
    """ᾱ_k for k = 0..T (ᾱ_0 = 1): the cosine schedule of Nichol & Dhariwal, clipped away from 0."""
    k = torch.arange(steps + 1, dtype=torch.float64)
    f = torch.cos((k / steps + offset) / (1 + offset) * math.pi / 2) ** 2
    return (f / f[0]).clamp(min=1e-4).float()


class _MishFunction(torch.autograd.Function):
    """mish(x) = x · tanh(softplus(x)) from one exponential: with n = eˣ, tanh(softplus(x)) = m / (m + 2), m = n(n + 2),
    and its derivative t + x(1 - t²)σ(x) = t + 4xn(n + 1) / (m + 2)², made in the forward pass where a gradient is
    wanted. torch's own CPU kernel (``nn.Mish``) does not vectorise: 0.50 ms forward and 1.15 ms with its backward
    for a 256 x 256 batch on one core of this project's machine, against 0.19-0.22 and 0.40 ms here (torch's exp is
    vectorised); the denoiser runs it some 100 times an update. The two agree to float32 rounding
    (``tests/core/test_diffusion.py``)."""

    @staticmethod
    def forward(ctx: torch.autograd.function.FunctionCtx, x: Tensor) -> Tensor:
        with torch.no_grad():
            n = x.clamp(max=20.0).exp_()  # past 20, tanh(softplus(x)) is 1 in float32 and n² would grow towards inf
            m = (n + 2.0).mul_(n)
            q = m + 2.0
            t = m.div_(q)
            y = x * t
            # the ctx torch passes has needs_input_grad; the FunctionCtx stub does not declare it
            if ctx.needs_input_grad[0]:  # type: ignore[attr-defined]
                slope = (n + 1.0).mul_(n).div_(q).div_(q).mul_(x).mul_(4.0).add_(t)
                ctx.save_for_backward(slope)
        return y

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx: torch.autograd.function.FunctionCtx, grad: Tensor) -> Tensor:
        (slope,) = ctx.saved_tensors  # type: ignore[attr-defined]
        return grad * slope


class Mish(nn.Module):
    """``nn.Mish``'s function (the denoiser's activation): by :class:`_MishFunction` on a batch of at least
    ``FUSED_FROM`` values, by torch's kernel below it, where the seven element-wise calls cost more than they save
    (an action's 10 candidates: 2.0 ms against 1.4 ms with torch's alone, measured)."""

    FUSED_FROM = 8192

    def forward(self, x: Tensor) -> Tensor:
        if x.numel() < self.FUSED_FROM:
            return nn.functional.mish(x)
        return _MishFunction.apply(x)


class Denoiser(nn.Module):
    """ε_θ(a_k, k, s): an MLP on the noisy action, a sinusoidal embedding of k and the observation."""

    frequencies: Tensor  # a registered buffer (nn.Module.__getattr__ would type it as Tensor | Module)

    def __init__(self, obs_dim: int, act_dim: int, hidden: int, layers: int, embedding: int) -> None:
        super().__init__()
        self.embedding = embedding
        dims = [act_dim + embedding + obs_dim] + [hidden] * layers
        blocks: list[nn.Module] = []
        for i, o in itertools.pairwise(dims):
            blocks += [nn.Linear(i, o), Mish()]
        self.body = nn.Sequential(*blocks, nn.Linear(hidden, act_dim))
        half = embedding // 2
        self.register_buffer("frequencies", torch.exp(-math.log(1000.0) * torch.arange(half) / max(half - 1, 1)))

    def forward(self, noisy: Tensor, level: Tensor, obs: Tensor) -> Tensor:
        angles = level.float().unsqueeze(-1) * self.frequencies
        embedded = torch.cat([torch.sin(angles), torch.cos(angles)], dim=-1)
        return self.body(torch.cat([noisy, embedded, obs], dim=-1))


class DiffusionPolicy(BaseLearner):
    """Diffusion-BC, or Diffusion-QL when ``cfg.diffusion.q_weight > 0`` (see the module docstring).

    It acts by sampling, in evaluation too: a diffusion policy's point is to draw from the demonstrated modes, and
    the reverse chain from zero noise lands between them (``tests/core/test_diffusion.py`` checks that samples keep
    a bimodal expert's modes apart). The sampler's generator is seeded, so a run repeats."""

    uses_random_warmup = False
    acting_module = "denoiser"
    device_capable = False  # its sampler and Q-weighting build CPU tensors: trains on the CPU (auto falls back)

    def build_networks(self) -> None:
        dcfg = self.cfg.diffusion
        if not 1 <= dcfg.sampling_steps <= dcfg.denoising_steps:
            raise ValueError(
                f"diffusion.sampling_steps must be in [1, denoising_steps={dcfg.denoising_steps}], "
                f"got {dcfg.sampling_steps}"
            )
        self.denoiser = Denoiser(self.obs_dim, self.act_dim, dcfg.hidden, dcfg.layers, dcfg.time_embedding)
        self.optimizer = torch.optim.Adam(self.denoiser.parameters(), lr=dcfg.lr)
        self.alpha_bars = cosine_alpha_bars(dcfg.denoising_steps)
        self.q_learning = dcfg.q_weight > 0
        if self.q_learning:
            self.critic = EnsembleCritic(self.obs_dim, self.act_dim, self.cfg.hidden, self.cfg.layers, 2)
            self.critic_target = copy.deepcopy(self.critic)
            self.denoiser_target = copy.deepcopy(self.denoiser)
            self.critic_optimizer = torch.optim.Adam(self.critic.parameters(), lr=dcfg.lr)
        self._generator = torch.Generator().manual_seed(self.seed)
        self._ddim_cache: dict[tuple[int, int, int], list[tuple[Tensor, Tensor, Tensor, Tensor, Tensor, bool]]] = {}
        self._scale = (self.action_high - self.action_low) / 2
        self._centre = (self.action_high + self.action_low) / 2

    def declared_state(self) -> DeclaredState:
        if self.q_learning:
            return DeclaredState(
                modules=("denoiser", "critic", "critic_target", "denoiser_target"),
                optimizers=("optimizer", "critic_optimizer"),
            )
        return DeclaredState(modules=("denoiser",), optimizers=("optimizer",))

    # -- the diffusion model -----------------------------------------------------------------------
    def _normalise(self, action: Tensor) -> Tensor:
        return (action - self._centre) / self._scale

    def denoising_loss(self, obs: Tensor, action: Tensor) -> Tensor:
        """E ||ε − ε_θ(√ᾱ_k a + √(1 − ᾱ_k) ε, k, s)||² over k ~ U{1..T} (actions normalised to [-1, 1])."""
        x0 = self._normalise(action)
        levels = torch.randint(1, len(self.alpha_bars), (len(obs),))
        noise = torch.randn_like(x0)
        alpha_bar = self.alpha_bars[levels].unsqueeze(-1)
        noisy = alpha_bar.sqrt() * x0 + (1 - alpha_bar).sqrt() * noise
        return (self.denoiser(noisy, levels, obs) - noise).pow(2).sum(-1).mean()

    def _ddim_steps(self, batch: int) -> list[tuple[Tensor, Tensor, Tensor, Tensor, Tensor, bool]]:
        """Per reverse step: its level for each of ``batch`` rows, √(1 − ᾱ_k), √ᾱ_k, √ᾱ_next, √(1 − ᾱ_next) and
        whether a next level follows. The same 0-d tensors the step computed every time, made once per settings and
        batch size (the settings may change between calls: ``sampling_steps`` at evaluation time)."""
        total, steps = len(self.alpha_bars) - 1, self.cfg.diffusion.sampling_steps
        key = (steps, total, batch)
        cache = self._ddim_cache
        if key not in cache:
            levels = torch.linspace(total, 0, steps + 1).round().long().tolist()
            plan = []
            for k, k_next in itertools.pairwise(levels):
                alpha_bar, alpha_next = self.alpha_bars[k], self.alpha_bars[k_next]
                plan.append(
                    (
                        torch.full((batch,), k),
                        (1 - alpha_bar).sqrt(),
                        alpha_bar.sqrt(),
                        alpha_next.sqrt(),
                        (1 - alpha_next).sqrt(),
                        k_next > 0,
                    )
                )
            cache[key] = plan
        return cache[key]

    def sample(self, obs: Tensor, deterministic: bool = False, denoiser: Denoiser | None = None) -> Tensor:
        """Actions for a batch of observations by DDIM over ``sampling_steps`` levels (differentiable)."""
        denoiser = denoiser or self.denoiser
        shape = (obs.shape[0], self.act_dim)
        x = torch.zeros(shape) if deterministic else torch.randn(shape, generator=self._generator)
        for level, noise_scale, signal_scale, next_signal, next_noise, more in self._ddim_steps(shape[0]):
            eps = denoiser(x, level, obs)
            x0 = ((x - noise_scale * eps) / signal_scale).clamp(-1.0, 1.0)
            x = next_signal * x0 + next_noise * eps if more else x0
        return x.clamp(-1.0, 1.0) * self._scale + self._centre

    # -- acting ------------------------------------------------------------------------------------
    def policy_action(self, obs: np.ndarray, deterministic: bool) -> np.ndarray:
        with torch.inference_mode():
            o = torch.from_numpy(np.asarray(obs, dtype=np.float32)).view(1, -1)
            candidates = self.cfg.diffusion.candidates if self.q_learning else 1
            if candidates <= 1:  # a sample, in evaluation too (see the class docstring)
                return self.sample(o)[0].numpy()
            actions = self.sample(o.expand(candidates, -1), deterministic=False)
            q = self.critic(o.expand(candidates, -1), actions).min(0).values
            return actions[int(torch.argmax(q))].numpy()

    def rollout_policy(self, obs: Tensor) -> Tensor:
        return self.sample(obs, deterministic=True)

    # -- learning: offline only --------------------------------------------------------------------
    def observe(self, record: StepRecord) -> None:
        """Transitions after offline training are stored, not learned from (these methods are offline)."""
        self.store(record)
        self.env_steps += 1

    def behaviour_clone(self, steps: int, lr: float = 1e-3) -> float:
        loss = math.nan
        for _ in range(steps):
            stats = self.update()
            loss = stats.get("bc_loss", loss)
        return loss

    def pretrain(self, returns: np.ndarray | None = None) -> dict[str, float]:
        """Offline training: ``offline_steps`` updates on the buffer (refused when it holds no expert action)."""
        if self.buffer.takeover_count() == 0:
            raise ValueError(f"{self.cfg.method} learns offline from expert actions: give --demo-episodes or --dataset")
        stats: dict[str, float] = {}
        for _ in range(self.cfg.diffusion.offline_steps):
            step_stats, applied = self.guarded_update()
            if applied:
                stats = step_stats
        self.warm = True
        self.info.update(stats)
        return {f"offline_{k}": v for k, v in stats.items()}

    def update(self) -> dict[str, float]:
        expert = self.buffer.sample_takeovers(self.cfg.batch_size, self.rng)
        if expert is None:
            return {}
        bc_loss = self.denoising_loss(expert.obs, expert.a_expert)
        stats = {"bc_loss": float(bc_loss.detach())}
        if not self.q_learning:
            self.optimizer.zero_grad(set_to_none=True)
            bc_loss.backward()
            self.optimizer.step()
            return stats
        batch = self.buffer.sample(self.cfg.batch_size, self.rng)
        with torch.no_grad():
            next_action = self.sample(batch.next_obs, denoiser=self.denoiser_target)
            next_q = self.critic_target(batch.next_obs, next_action).min(0).values
            target = batch.reward + self.cfg.gamma * (1.0 - batch.terminated) * next_q
        critic_loss = (self.critic(batch.obs, batch.action) - target).pow(2).mean()
        self.critic_optimizer.zero_grad(set_to_none=True)
        critic_loss.backward()
        self.critic_optimizer.step()
        action = self.sample(expert.obs)
        # the policy loss reaches the denoiser through the critics' input; their own weights' gradients would be
        # thrown away (the critic's next step starts from zero_grad), so they are not computed
        self.critic.requires_grad_(False)
        try:
            q = self.critic(expert.obs, action)
            q_term = q[0] if self.rng.random() < 0.5 else q[1]
            q_loss = -q_term.mean() / q.abs().mean().detach().clamp(min=1e-6)
            loss = bc_loss + self.cfg.diffusion.q_weight * q_loss
            self.optimizer.zero_grad(set_to_none=True)
            loss.backward()
        finally:
            self.critic.requires_grad_(True)
        if self.cfg.max_grad_norm is not None:
            torch.nn.utils.clip_grad_norm_(self.denoiser.parameters(), self.cfg.max_grad_norm)
        self.optimizer.step()
        soft_update(self.critic_target, self.critic, self.cfg.polyak)
        soft_update(self.denoiser_target, self.denoiser, self.cfg.polyak)
        stats.update(critic_loss=float(critic_loss.detach()), q_loss=float(q_loss.detach()))
        return stats
