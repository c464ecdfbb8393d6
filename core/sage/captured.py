"""The SAGE-SAC and D3QN updates captured once as CUDA graphs and replayed (``AgentConfig.cuda_graph``, CUDA only).

On a GPU the update of these small networks is bound by kernel launches: a stand-in SAGE-SAC update with the
project's sizes took 21.7 ms eager on an H200 at batch 256 and 2.9 ms replayed as a graph (PITFALLS.md). A graph
replays fixed kernels on fixed memory, so the update here is written against the pattern PyTorch documents for
whole-network capture:

- every input lives in a static buffer that each update fills in place: the sampled batch, the virtual states, the
  imitation batch, and the numbers the host decides (λ, c*, the fear budget) as 0-dim device tensors;
- the optimisers are Adam with ``capturable=True`` (their step counts on the device: no host sync);
- the first updates of each structure run eagerly on a side stream (warm-up: lazy state such as Adam's moments and
  the ego step's geometry is allocated outside the capture), then ``torch.cuda.graph`` records one update;
- nothing inside reads a value back to the host: α comes from log α on the device, λ's dual step runs on the device,
  and the statistics are read once after the replay (one sync per update);
- the world model's folded weights are copied in place into the graph's own buffers when the model changes.

A graph is recorded per structure (whether fear is active, whether an imitation batch exists, how many virtual
states the actor batch holds); a checkpoint load or a world model of another shape drops them (recaptured).

:class:`CapturedSACUpdate` and :class:`CapturedD3QNUpdate` also run their body eagerly (``eager=True``), which is how
the CPU tests hold the captured computation to the reference update (``tests/core/sage/test_captured.py``): the
body is the same code a graph records.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any

import torch
import torch.nn.functional as F
from torch import Tensor

from core.device import DeviceError
from core.replay import Batch
from core.sage.fear import closing_channels, contact_floors, fear_of, rollout
from core.sage.networks import soft_update
from core.sage.world_model import FoldedModel

if TYPE_CHECKING:
    from core.sage.d3qn import D3QN
    from core.sage.learner import BaseLearner
    from core.sage.sac import SAC

WARMUP_UPDATES = 3
"""Eager updates on a side stream before a structure is captured (PyTorch's whole-network capture example)."""


def require_cuda(device: torch.device) -> None:
    """The one clear error of ``learner.cuda_graph=true`` anywhere but on CUDA."""
    if device.type != "cuda":
        raise DeviceError(
            f"learner.cuda_graph=true captures the update as a CUDA graph: it needs --device cuda (this run's device "
            f"is {device})"
        )


def _static(batch: Batch) -> Batch:
    return Batch(**{f.name: getattr(batch, f.name).clone() for f in dataclasses.fields(batch)})


def _fill(static: Batch, batch: Batch) -> None:
    for f in dataclasses.fields(batch):
        getattr(static, f.name).copy_(getattr(batch, f.name), non_blocking=True)


class CapturedUpdate:
    """What the SAC and D3QN captures share: structures, warm-up, capture, replay, static world model, statistics."""

    def __init__(self, learner: BaseLearner, *, eager: bool = False) -> None:
        if not eager:
            require_cuda(learner.device)
        self.learner, self.eager = learner, eager
        self.device = learner.device
        self.graphs: dict[tuple[Any, ...], torch.cuda.CUDAGraph] = {}
        self.warmed: dict[tuple[Any, ...], int] = {}
        self.inputs: dict[tuple[Any, ...], dict[str, Any]] = {}
        """Per structure: its static input buffers (what the graph reads)."""
        self.outputs: dict[tuple[Any, ...], dict[str, Tensor]] = {}
        """Per structure: the statistics the graph writes."""
        self.scalars = {name: torch.zeros((), device=self.device) for name in ("lam", "c_star", "fear_budget")}
        self.folded: FoldedModel | None = None
        self.folded_version = -1
        gate = learner.cfg.gate
        floors = contact_floors(gate)
        self.contact = None if floors is None else floors.to(self.device)
        closing = closing_channels(gate, None, floors)
        self.closing = None if closing is None else closing.to(self.device)

    # -- the world model the graph reads --------------------------------------------------------------
    def static_folded(self) -> FoldedModel:
        """The world model's folded weights in buffers of this capture's own, refreshed in place on a new version
        (a graph keeps reading the addresses it recorded); a model of another shape drops the graphs."""
        model = self.learner.world_model
        assert model is not None
        if self.folded is not None and self.folded_version == model.version:
            return self.folded
        fresh = model.folded().to(self.device)
        if self.folded is None or not _same_shapes(self.folded, fresh):
            self.folded = dataclasses.replace(fresh, **{k: _clone(v) for k, v in _tensor_fields(fresh).items()})
            self.graphs.clear()
            self.warmed.clear()
        else:
            with torch.no_grad():
                for name, value in _tensor_fields(fresh).items():
                    _copy_into(getattr(self.folded, name), value)
            self.folded.curiosity_ref = fresh.curiosity_ref
        self.folded_version = model.version
        return self.folded

    def fear(self, obs: Tensor, action: Tensor, policy: Any) -> Tensor:
        """F(s, a) as the learner's ``learner_fear`` computes it, on the static model and device-side contact."""
        cfg = self.learner.cfg
        assert self.folded is not None
        ro = rollout(self.folded, policy, obs, action, cfg.learner_fear_horizon, None, self.contact, self.closing)
        return fear_of(self.folded, ro, cfg.gate).fear

    # -- run ------------------------------------------------------------------------------------------
    def run(self, key: tuple[Any, ...], body: Any) -> dict[str, float]:
        """The update of structure ``key`` whose inputs were just filled: eagerly (warm-up, or ``eager``), or by
        replaying its graph (captured on first use after the warm-up)."""
        if self.eager:
            return self._read(body())
        if key in self.graphs:
            self.graphs[key].replay()
            return self._read(self.outputs[key])
        if self.warmed.get(key, 0) < WARMUP_UPDATES:
            self.warmed[key] = self.warmed.get(key, 0) + 1
            side = torch.cuda.Stream(self.device)
            side.wait_stream(torch.cuda.current_stream(self.device))
            with torch.cuda.stream(side):
                stats = body()
            torch.cuda.current_stream(self.device).wait_stream(side)
            return self._read(stats)
        for optimizer in self.optimizers():
            optimizer.zero_grad(set_to_none=True)  # the graph allocates its gradients from its own pool
        graph = torch.cuda.CUDAGraph()
        with torch.cuda.graph(graph):
            self.outputs[key] = body()
        self.graphs[key] = graph
        graph.replay()  # the capture recorded the update; this runs it
        return self._read(self.outputs[key])

    def zero(self, optimizer: torch.optim.Optimizer) -> None:
        """``zero_grad`` where the update runs eagerly; inside a capture the gradients are written, not summed (they
        are None when the capture starts)."""
        if self.eager or not torch.cuda.is_current_stream_capturing():
            optimizer.zero_grad(set_to_none=True)

    def optimizers(self) -> list[torch.optim.Optimizer]:
        return [getattr(self.learner, name) for name in self.learner.declared_state().optimizers]

    def _read(self, stats: dict[str, Tensor]) -> dict[str, float]:
        """The statistics as floats (one host sync); λ written back to the learner."""
        names = list(stats)
        values = torch.stack([stats[n].detach().reshape(()).float() for n in names]).tolist()
        out = dict(zip(names, values, strict=True))
        if "lam" in out:
            self.learner.lam = out["lam"]
        return out

    def drop(self) -> None:
        """Forget every graph (a checkpoint replaced the optimisers' memory): the next updates warm up again."""
        self.graphs.clear()
        self.warmed.clear()
        self.outputs.clear()


class CapturedSACUpdate(CapturedUpdate):
    """:meth:`core.sage.sac.SAC.update` (critic, actor, α, λ) as one graph per structure."""

    learner: SAC

    def __call__(self) -> dict[str, float]:
        sac, cfg = self.learner, self.learner.cfg
        batch = sac.buffer.sample(cfg.batch_size, sac.rng)
        fear_on = sac.fear_active()
        imitation = sac.imitation_batch()
        n_virtual = 0
        if sac.virtual is not None and len(sac.virtual) > 0 and cfg.virtual_ratio > 0:
            n_virtual = round(cfg.virtual_ratio * len(batch))
        virtual = None if n_virtual == 0 else sac.virtual.sample_obs(n_virtual, sac.rng)  # type: ignore[union-attr]
        if fear_on:
            self.static_folded()
        key = (fear_on, imitation is not None, n_virtual)
        if key not in self.inputs:
            self.inputs[key] = {
                "batch": _static(batch),
                "imitation": None if imitation is None else _static(imitation),
                "virtual": None if virtual is None else virtual.clone(),
            }
        inputs = self.inputs[key]
        _fill(inputs["batch"], batch)
        if imitation is not None:
            _fill(inputs["imitation"], imitation)
        if virtual is not None:
            inputs["virtual"].copy_(virtual, non_blocking=True)
        self.scalars["lam"].fill_(sac.lam)
        self.scalars["c_star"].fill_(sac.c_star() if cfg.violation_penalty else 0.0)
        self.scalars["fear_budget"].fill_(sac.fear_budget())
        return self.run(key, lambda: self.body(inputs["batch"], inputs["imitation"], inputs["virtual"], fear_on))

    def alpha(self) -> Tensor | float:
        sac = self.learner
        return sac.log_alpha.detach().exp() if sac.cfg.autotune_alpha else sac.cfg.init_alpha

    def body(self, batch: Batch, imitation: Batch | None, virtual: Tensor | None, fear_on: bool) -> dict[str, Tensor]:
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
            action, log_prob = sac.actor.sample(states)
            q_pi = sac.critic(states, action).min(0).values
            actor_loss = (self.alpha() * log_prob - q_pi).mean()
            fear_real = None
            if fear_on:
                fear_values = self.fear(states, action, sac.fear_policy)
                actor_loss = actor_loss + lam * fear_values.mean()
                fear_real = fear_values[:n_real].mean()
                stats.update(fear_real=fear_real.detach(), fear_budget=self.scalars["fear_budget"])
            q_scale = q_pi.detach().abs().mean().clamp_min(1.0)
            if imitation is not None:
                with torch.no_grad():
                    q_expert = sac.critic(imitation.obs, imitation.a_expert).min(0).values
                    q_agent = sac.critic(imitation.obs, imitation.a_rl).min(0).values
                    scale = cfg.advantage_temperature * q_scale
                    omega = torch.exp(((q_expert - q_agent) / scale).clamp(-cfg.advantage_clip, cfg.advantage_clip))
                error = (sac.actor.deterministic(imitation.obs) - imitation.a_expert).pow(2).sum(-1)
                bc = (omega * error).mean()
                actor_loss = actor_loss + cfg.bc_weight * q_scale * bc
                stats.update(bc_loss=bc.detach(), omega_mean=omega.mean())
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


class CapturedD3QNUpdate(CapturedUpdate):
    """:meth:`core.sage.d3qn.D3QN.update` as one graph per structure."""

    learner: D3QN

    def __call__(self) -> dict[str, float]:
        from core.sage.d3qn import D3QN

        learner, cfg = self.learner, self.learner.cfg
        assert isinstance(learner, D3QN)
        batch = learner.buffer.sample(cfg.batch_size, learner.rng)
        fear_on = learner.fear_active()
        imitation = learner.buffer.sample_takeovers(cfg.bc_batch_size, learner.rng) if cfg.imitation else None
        if fear_on:
            self.static_folded()
        key = (fear_on, imitation is not None)
        if key not in self.inputs:
            self.inputs[key] = {"batch": _static(batch), "imitation": None if imitation is None else _static(imitation)}
        inputs = self.inputs[key]
        _fill(inputs["batch"], batch)
        if imitation is not None:
            _fill(inputs["imitation"], imitation)
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
        from core.sage.d3qn import double_q_target, weighted_margin_loss

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


# -- helpers ------------------------------------------------------------------------------------------------
def _tensor_fields(folded: FoldedModel) -> dict[str, Any]:
    return {
        f.name: getattr(folded, f.name)
        for f in dataclasses.fields(folded)
        if isinstance(getattr(folded, f.name), Tensor) or f.name == "hidden"
    }


def _clone(value: Any) -> Any:
    if isinstance(value, Tensor):
        return value.clone()
    return [(w.clone(), b.clone()) for w, b in value]


def _copy_into(target: Any, source: Any) -> None:
    if isinstance(target, Tensor):
        target.copy_(source)
        return
    for (tw, tb), (sw, sb) in zip(target, source, strict=True):
        tw.copy_(sw)
        tb.copy_(sb)


def _shapes(value: Any) -> Any:
    if isinstance(value, Tensor):
        return tuple(value.shape)
    return [(tuple(w.shape), tuple(b.shape)) for w, b in value]


def _same_shapes(a: FoldedModel, b: FoldedModel) -> bool:
    fa, fb = _tensor_fields(a), _tensor_fields(b)
    return all(_shapes(fa[name]) == _shapes(fb[name]) for name in fa)
