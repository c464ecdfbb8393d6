"""Fear, curiosity and the curiosity-modulated threshold (eq:fear, eq:curiosity, eq:threshold).

Short-horizon fear F^m. From (s_t, a_t) every member n of the ensemble rolls its own trajectory for m steps,
the actions after the first coming from the current policy's deterministic action on that member's predicted
state. At step k:

- ĉ_k = mean_n sigmoid(ℓ_{n,k}), ℓ the members' calibrated logit of "a violation within the next few steps"
  (see :mod:`core.sage.world_model`): a predicted violation probability;
- σ_raw,k = std_n sigmoid(ℓ_{n,k}): the ensemble's disagreement about the danger itself. Each member follows
  its own imagined trajectory, so this also holds the members' divergence over earlier steps. (The state
  mixture's predictive std, :meth:`~core.sage.world_model.EnsembleWorldModel.predictive_std`, rises on any novel
  state, dangerous or not: measured on the UGV's crossing and cut-in, it ranked the steps before a collision
  *below* the others, AUROC 0.23 and 0.61, where the disagreement about ĉ gives 0.94 and 0.95.)
- σ̂_k = tanh(σ_raw,k / (2 κ_k)), κ_k the 95th percentile of σ_raw,k over real states rolled out under the
  current policy, recomputed after every world-model fit (:func:`calibrate`). Typical familiar states sit
  near tanh(1/4) ≈ 0.25, the 95th percentile at tanh(1/2) ≈ 0.46, three times it at 0.9: σ̂ ∈ [0, 1) is on
  the scale of ĉ, as eq:fear asks. The scale is per step k because disagreement grows along a rollout even
  on familiar ground; so "unusual" means unusual for that step, whatever the horizon.

ĉ and σ̂ are aggregated over the m steps separately (``max`` by default, or a discounted mean), so a danger
three steps ahead counts as much as an immediate one, then F^m = β ĉ + (1 - β) σ̂ ∈ [0, 1].

:func:`rollout` / :func:`fear` serve the learner (a batch, differentiable w.r.t. the first action and the
policy, through the frozen folded weights of the model) and any custom policy function; :class:`GateKernel`
is the same computation for one state on preallocated buffers, for the gate (tested equal).

Curiosity and the threshold it modulates: :mod:`core.sage.threshold`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from core.motion import approach_rate
from core.sage.config import GateConfig
from core.sage.movers import mover_contact
from core.sage.world_model import FoldedModel, approach_width

PolicyFn = Callable[[Tensor], Tensor]
"""A deterministic policy on torch states ``(B, D) -> (B, A)`` used inside rollouts. A discrete-action
learner (D3QN) passes a function returning the one-hot of its greedy action; the world model then takes
one-hot actions as its action input, and nothing else here changes."""


@dataclass
class Rollout:
    states: Tensor
    """(m + 1, N, B, D): the start state and each member's predicted states."""
    actions: Tensor
    """(m, N, B, A): the first action, then the policy's actions on the predicted states."""
    cost: Tensor
    """(m, N, B): each member's predicted violation probability at each step."""
    sigma_raw: Tensor
    """(m, B): the members' disagreement (std) about the violation probability of each step."""
    learned_steps: int | None = None
    """The first steps whose learned violation head (in ``cost``) and disagreement (``sigma_raw``) count; the steps
    after them hold imagined contact alone (``GateConfig.contact_horizon``). None: every step."""


@dataclass
class Fear:
    fear: Tensor
    """(B,) F^m = β ĉ + (1 - β) σ̂."""
    cost: Tensor
    """(B,) ĉ aggregated over the horizon."""
    sigma: Tensor
    """(B,) σ̂ aggregated over the horizon."""
    sigma_raw: Tensor
    """(B,) σ_raw aggregated over the horizon (before the scale and squash)."""


def contact_floors(cfg: GateConfig | None) -> Tensor | None:
    """The floors of ``cfg``'s imagined contact as a tensor (``GateConfig.imagined_contact``), None when off; a channel
    without a floor (None) is -inf there, which no value (extrapolated or not) reaches."""
    if cfg is None or not cfg.imagined_contact:
        return None
    if not any(f is not None for f in cfg.contact_floors or ()):
        raise ValueError(
            "gate.imagined_contact needs gate.contact_floors (a training run sets them from its simulator)"
        )
    return torch.tensor([-math.inf if f is None else f for f in cfg.contact_floors or ()], dtype=torch.float32)


def with_contact(
    probability: Tensor,
    states: Tensor,
    floors: Tensor | None,
    closing: Tensor | None = None,
    closing_rate: Tensor | None = None,
) -> Tensor:
    """Each member's violation probability at each imagined step, raised to 1 where its predicted state is in
    contact (some channel i at or under ``floors[i]``): ``probability`` (m, N, B), ``states`` (m, N, B, D) the
    states those steps led to. Unchanged when ``floors`` is None. ``closing``: where given, a bool (..., B, n) mask of
    the channels the real last step shows closing (``GateConfig.contact_needs_closing``); contact counts there only.
    ``closing_rate``: where given, (B, n) each channel's closing per step that the robot's own motion does not explain
    (<= 0, :func:`closing_rate`); step k (1-based) then tests state_k[i] + k rate[i] <= floors[i]: the movers' closing
    extrapolated at constant speed on top of the imagined ego motion (``GateConfig.contact_extrapolation``).

    It enters ĉ (the members' mean) only: σ̂ stays the members' disagreement about the learned danger. Counted in σ̂
    too, contact would make fear fall as the members come to agree on it: all five in contact give β, two of five
    nearly 1 (σ̂ saturates), so a certain contact would fire the gate less often than a doubtful one."""
    if floors is None:
        return probability
    if floors.shape[0] > states.shape[-1]:
        raise ValueError(f"gate.contact_floors has {floors.shape[0]} channels, the observation {states.shape[-1]}")
    ranges = states[..., : floors.shape[0]]
    if closing_rate is not None:
        steps = torch.arange(1, ranges.shape[0] + 1, dtype=ranges.dtype, device=ranges.device)
        ranges = ranges + steps.view(-1, *([1] * (ranges.dim() - 1))) * closing_rate.to(ranges.device)
    touching = ranges <= floors.to(states.device)
    if closing is not None:
        touching = touching & closing.to(states.device)
    return torch.maximum(probability, touching.any(-1).to(probability.dtype))


def contact_reach(cfg: GateConfig | None, horizon: int) -> int:
    """The steps a fear of ``horizon`` learned steps rolls out under the gate ``cfg``: ``cfg.contact_horizon`` where
    imagined contact reaches further (:attr:`GateConfig.contact_horizon`), else ``horizon``. A discounted mean over
    steps that hold contact alone would dilute the learned steps' weights: refused (the config refuses it too)."""
    if cfg is None or not cfg.imagined_contact or cfg.contact_horizon is None or cfg.contact_horizon <= horizon:
        return horizon
    if cfg.aggregate != "max":
        raise ValueError("gate.contact_horizon beyond gate.horizon needs gate.aggregate=max")
    return cfg.contact_horizon


def contact_terms(cfg: GateConfig | None, motion: Tensor | None) -> tuple[Tensor | None, Tensor | None]:
    """``rollout``'s ``contact`` and ``closing`` for the gate ``cfg``, given the real last change of state."""
    floors = contact_floors(cfg)
    return floors, closing_channels(cfg, motion, floors)


def closing_channels(cfg: GateConfig | None, motion: Tensor | None, floors: Tensor | None) -> Tensor | None:
    """The channels that may count imagined contact under ``cfg.contact_needs_closing``: those the real last change
    of state (``motion``, (..., D)) shows falling; none without a motion input. None: every channel may."""
    if floors is None or cfg is None or not cfg.contact_needs_closing:
        return None
    n = floors.shape[0]
    if motion is None:
        return torch.zeros(n, dtype=torch.bool)
    return motion[..., :n] < 0


def unexplained_change(base: Tensor, next_obs: Tensor, channels: int) -> Tensor:
    """The change of the first ``channels`` channels (the contact floors' scan sectors) that the robot's own motion
    does not explain: ``next_obs`` minus ``base``, the observation moved by the world model's ego step
    (:meth:`core.motion.EgoScanStep.apply`; the observation itself for a model without one). Over a static world it is
    about 0; a mover's own range rate shows in it, per sector and step."""
    return next_obs[..., :channels] - base[..., :channels]


def closing_rate(previous: Tensor, latest: Tensor) -> Tensor:
    """Each channel's closing per step (<= 0) from the two last :func:`unexplained_change` of one episode: where both
    fall, the one nearer 0, else 0. A range whose return newly appears (an edge entering the sector, an occlusion
    ending) jumps by far more than any mover moves in a step, once: seen in two consecutive steps and taken at its
    smaller magnitude, such a jump never counts, while a mover closing at a steady speed counts at that speed."""
    both = (previous < 0) & (latest < 0)
    return torch.where(both, torch.maximum(previous, latest), torch.zeros_like(latest))


def rollout(
    model: FoldedModel,
    policy: PolicyFn,
    obs: Tensor,
    action: Tensor,
    horizon: int,
    motion: Tensor | None = None,
    contact: Tensor | None = None,
    closing: Tensor | None = None,
    *,
    states_needed: bool = True,
    learned_steps: int | None = None,
    closing_rate: Tensor | None = None,
    mover_velocity: Tensor | None = None,
) -> Rollout:
    """Roll every member m steps from (obs, action) under ``policy``, all members in each baddbmm. ``motion``:
    the last observed change of state (zeros when None), for a model with the motion input; later steps take
    each member's own predicted Δ into their motion (:func:`next_motion`; scan-aligned for a model with a
    :class:`core.motion.ScanAlignment`). ``contact``: the observation's contact floors (:func:`contact_floors`),
    where an imagined state in contact is a violation (:func:`with_contact`), in the ``closing`` channels only where
    given ((B, n), :func:`closing_channels`).

    ``states_needed=False``: the caller reads only ``cost`` and ``sigma_raw`` (the fear terms). The last imagined
    state then feeds nothing but the contact test, a comparison without a gradient: it is computed only where
    ``contact`` is given, without a graph, and otherwise not at all (no Δ columns, no ego step), and ``states``
    ends at the state before it. The fear terms are the same either way (``tests/core/sage/test_fear_rollout.py``).

    ``learned_steps``: where fewer than ``horizon``, the steps after them count imagined contact alone (their learned
    violation probability is left out of ``cost``; :func:`fear_of` reads σ̂ over the first ``learned_steps`` only):
    the gate's ``contact_horizon`` (:func:`contact_reach`). None: every step counts both.

    ``closing_rate``: (B, n) the channels' closing the real scans show (:func:`closing_rate`), extrapolated over the
    imagined steps in the contact test (:func:`with_contact`; ``GateConfig.contact_extrapolation``). None: none.

    ``mover_velocity``: (B, S, 2) the velocity of each sector's return that the real scans show moving
    (:func:`core.sage.movers.mover_velocities`, ``GateConfig.mover_model``); each member's imagined contact then also
    counts those points moved at constant velocity into its imagined poses (:func:`core.sage.movers.mover_contact`;
    needs ``contact`` and the model's ego step). None: none."""
    n, d = model.members, model.obs_dim
    batch = obs.shape[0]
    s = obs.unsqueeze(0).expand(n, batch, d)
    a = action.unsqueeze(0).expand(n, batch, action.shape[-1])
    m = None
    if model.motion and motion is not None:
        m = motion.unsqueeze(0).expand(n, batch, d)
    # the Δs means and the violation logit (the log-variance columns feed no rollout); the logit alone
    mean_weight, mean_bias = model.out_weight[..., : d + 1], model.out_bias[..., : d + 1]
    logit_weight, logit_bias = model.out_weight[..., d : d + 1], model.out_bias[..., d : d + 1]
    states, actions, costs = [s], [], []
    last_contact = None
    """(N, B) bool: the last imagined state's contact, where it is tested without the state (states_needed=False)."""
    for k in range(horizon):
        last = k + 1 == horizon
        h = first_layer(model, s, a, m)
        for weight, bias in model.hidden[1:]:
            h = F.silu(torch.baddbmm(bias, h, weight))
        actions.append(a)
        if last and not states_needed:
            costs.append(torch.baddbmm(logit_bias, h, logit_weight)[..., 0])
            if contact is not None:  # the last state's values for the contact test; no gradient goes through it
                with torch.no_grad():
                    delta = torch.baddbmm(mean_bias[..., :d], h, mean_weight[..., :d])
                    compiled = model.ego is not None and delta.device.type == "cpu" and contact.shape[0] <= d
                    if compiled and closing_rate is None:  # the compiled test does not extrapolate a closing
                        # the ego step and the test in one compiled call, the state itself never formed
                        last_contact = _ego_contact(model, obs if k == 0 else s, action if k == 0 else a, delta,
                                                    contact, closing)  # fmt: skip
                    else:
                        base = model.base(obs, action).expand(n, batch, d) if k == 0 else model.base(s, a)
                        states.append(base + delta)
            break
        out = torch.baddbmm(mean_bias, h, mean_weight)
        # every member starts from the same state and action: the first step's base (an ego step's scan) once
        base = model.base(obs, action).expand(n, batch, d) if k == 0 else model.base(s, a)
        s_next = base + out[..., :d]
        if model.motion and not last:  # the last imagined state's motion feeds no further step
            if model.scan is not None:
                m = model.scan.motion(s, s_next)
            else:
                delta = out[..., :d] if model.ego is None else s_next - s
                m = next_motion(torch.zeros_like(s) if m is None else m, delta, model.motion_lag)
        s = s_next
        states.append(s)
        costs.append(out[..., d])  # the violation logit
        if not last:
            a = policy(s.reshape(n * batch, d)).reshape(n, batch, -1)
    probability = torch.sigmoid(torch.stack(costs))  # (m, N, B)
    # (x - mean)^2 by hand: Tensor.var over a non-last dim takes a slow path on CPU (milliseconds here)
    spread = (probability - probability.mean(1, keepdim=True)).square().mean(1)
    sigma_raw = spread.clamp_min(1e-12).sqrt()
    learned = probability
    if learned_steps is not None and learned_steps < horizon:
        # steps beyond the learned ones: imagined contact alone (the learned head keeps its own reach)
        keep = torch.arange(horizon, device=probability.device) < learned_steps
        learned = probability * keep.to(probability.dtype).view(horizon, 1, 1)
    else:
        learned_steps = None
    if contact is None:
        cost = learned
    elif last_contact is None:
        cost = with_contact(learned, torch.stack(states[1:]), contact, closing, closing_rate)
    else:  # the steps before the last tested on their states, the last one's test already made (no extrapolation)
        earlier = with_contact(learned[:-1], torch.stack(states[1:]), contact, closing) if horizon > 1 else learned[:-1]
        cost = torch.cat([earlier, torch.maximum(learned[-1:], last_contact.unsqueeze(0).to(learned.dtype))])
    if mover_velocity is not None and contact is not None and model.ego is not None:
        # the movers' points at constant velocity, seen from each member's imagined poses: ĉ only, like contact
        touching = mover_contact(model.ego, obs, mover_velocity, torch.stack(actions), contact)
        cost = torch.maximum(cost, touching.to(cost.dtype))
    return Rollout(torch.stack(states), torch.stack(actions), cost, sigma_raw, learned_steps)


def _ego_contact(
    model: FoldedModel, state: Tensor, action: Tensor, delta: Tensor, contact: Tensor, closing: Tensor | None
) -> Tensor:
    """(N, B) bool: :func:`with_contact`'s test of the imagined states ``model.base(state, action) + delta`` over a
    model's ego step (:meth:`core.motion.EgoScanStep.contact`): the same numbers compared, without the torch reductions
    over the floors' few channels, which cost more than the test. No channel may count where ``closing`` allows none."""
    members, batch, width = delta.shape[0], delta.shape[1], contact.shape[0]
    if closing is not None and not bool(closing.any()):
        return torch.zeros(members, batch, dtype=torch.bool)
    assert model.ego is not None
    return model.ego.contact(state, action, delta[..., :width], contact, closing)


def first_layer(model: FoldedModel, state: Tensor, action: Tensor, motion: Tensor | None) -> Tensor:
    """The first hidden layer of every member on (state, action (, motion (, approach))), one product per input
    block: the state's (a constant in the learner's losses) sends no gradient back, the action's few columns do, and
    a ``motion`` of None (zeros: a start without the motion input) skips the motion's and the approach's blocks,
    whose products are zero (the approach rate of no motion is 0). The layer on the concatenated input, up to the
    order of the sums."""
    weight, bias = model.hidden[0]
    d, a = model.obs_dim, action.shape[-1]
    h = torch.baddbmm(bias, state, weight[:, :d])
    h = torch.baddbmm(h, action, weight[:, d : d + a])
    if model.motion and motion is not None:
        h = torch.baddbmm(h, motion, weight[:, d + a : 2 * d + a])
        if model.approach is not None:
            h = torch.baddbmm(h, approach_rate(state, motion, *model.approach), weight[:, 2 * d + a :])
    return F.silu(h)


def next_motion(motion: Tensor, delta: Tensor, lag: int) -> Tensor:
    """The motion input one imagined step on: ((k - 1) m + Δ) / k, which is Δ itself for k = 1 (the mean change
    over the last k steps, with the step that leaves the window taken as the mean)."""
    return torch.lerp(motion, delta, 1.0 / lag)


def aggregate(per_step: Tensor, how: str, discount: float) -> Tensor:
    """(m, B) -> (B,): the maximum over the horizon, or a mean with weights discount^k."""
    if how == "max":
        return per_step.max(0).values
    if how == "discounted_mean":
        weights = discount ** torch.arange(per_step.shape[0], dtype=per_step.dtype, device=per_step.device)
        return (weights[:, None] * per_step).sum(0) / weights.sum()
    raise ValueError(f"unknown fear aggregation {how!r}; use 'max' or 'discounted_mean'")


def step_scales(scale: Tensor, horizon: int) -> Tensor:
    """κ_k for k < horizon as a (horizon, 1) column (steps beyond the stored ones reuse the last)."""
    idx = torch.arange(horizon, device=scale.device).clamp_max(scale.shape[0] - 1)
    return scale[idx].clamp_min(1e-8).unsqueeze(1)


def squash_sigma(sigma_raw: Tensor, scale: Tensor) -> Tensor:
    """σ̂_k = tanh(σ_raw,k / (2 κ_k)) for (m, B) raw values."""
    return torch.tanh(sigma_raw / (2.0 * step_scales(scale, sigma_raw.shape[0])))


def fear_of(model: FoldedModel, ro: Rollout, cfg: GateConfig) -> Fear:
    """F^m of a rollout: ĉ aggregated over all its steps (those past ``ro.learned_steps`` hold imagined contact
    alone), σ̂ over the learned steps."""
    cost = aggregate(ro.cost.mean(1), cfg.aggregate, cfg.discount)
    sigma_raw_steps = ro.sigma_raw if ro.learned_steps is None else ro.sigma_raw[: ro.learned_steps]
    sigma = aggregate(squash_sigma(sigma_raw_steps, model.sigma_scale), cfg.aggregate, cfg.discount)
    sigma_raw = aggregate(sigma_raw_steps, cfg.aggregate, cfg.discount)
    return Fear(cfg.beta * cost + (1.0 - cfg.beta) * sigma, cost, sigma, sigma_raw)


def fear(
    model: FoldedModel,
    policy: PolicyFn,
    obs: Tensor,
    action: Tensor,
    cfg: GateConfig,
    horizon: int | None = None,
    motion: Tensor | None = None,
) -> Fear:
    """F^m for a batch of (state, first action), m = ``horizon`` or ``cfg.horizon``; differentiable w.r.t.
    the action and the policy unless called under no_grad / inference_mode (the model's folded weights are
    constants, so the world model itself never receives a gradient). ``motion``: see :func:`rollout` (the
    learner's batches pass none: their fear terms then assume no motion). Without ``horizon`` it is the gate's fear,
    imagined contact reaching ``cfg.contact_horizon`` (:func:`contact_reach`); a given ``horizon`` (the learner's)
    rolls exactly that many steps."""
    terms = contact_terms(cfg, motion)
    learned = horizon or cfg.horizon
    steps = learned if horizon else contact_reach(cfg, learned)
    # the gate's contact reaching past its horizon: the steps past the learned ones count imagined contact alone
    learned_steps = learned if steps > learned else None
    ro = rollout(model, policy, obs, action, steps, motion, *terms, states_needed=False, learned_steps=learned_steps)
    return fear_of(model, ro, cfg)


def one_step_fear(model: FoldedModel, policy: PolicyFn, obs: Tensor, action: Tensor, cfg: GateConfig) -> Tensor:
    """(B,) F^1 of (obs, action): ``fear(model, policy, obs, action, cfg, horizon=1).fear``, the learner's fear term
    (``learner_fear_horizon`` 1, no motion input), differentiable w.r.t. ``action``, in fewer operations (issue 63).

    One imagined step reads no policy and no state, only each member's violation logit and, with imagined contact,
    the compiled contact test (:func:`_ego_contact`); ĉ, σ_raw and σ̂ are then statistics over the members of an (N, B)
    tensor, and the maximum or discounted mean over one step is that step. So it is computed here without autograd's
    graph (each SiLU as z·sigmoid(z), its sigmoid kept), and the gradient w.r.t. the action is written out by hand
    (:class:`_OneStepFear`): a SAGE-SAC update's two fear terms ran some sixty small tensor operations and their
    autograd nodes each, and SiLU's backward computed its sigmoid again. Same formulas as :func:`rollout` and
    :func:`fear_of`, so the same values up to float32 rounding (``tests/core/sage/test_one_step_fear.py`` holds it to
    :func:`fear`, values and gradients). Elsewhere (a state that needs a gradient, contact without the compiled test:
    no ego step or not on the CPU) it is :func:`fear`."""
    floors, closing = contact_terms(cfg, None)
    compiled = model.ego is not None and obs.device.type == "cpu"
    if obs.requires_grad or (floors is not None and not (compiled and floors.shape[0] <= model.obs_dim)):
        return fear(model, policy, obs, action, cfg, horizon=1).fear
    if torch.is_grad_enabled() and action.requires_grad:
        value = _OneStepFear.apply(action, obs, model, cfg, floors, closing)
        assert isinstance(value, Tensor)
        return value
    with torch.no_grad():
        return _one_step(model, obs, action, cfg, floors, closing, None)


def _one_step(
    model: FoldedModel,
    obs: Tensor,
    action: Tensor,
    cfg: GateConfig,
    floors: Tensor | None,
    closing: Tensor | None,
    saved: dict[str, object] | None,
) -> Tensor:
    """:func:`one_step_fear`'s values, without a graph; ``saved``: where given, receives what the backward reads."""
    n, d = model.members, model.obs_dim
    batch, width = obs.shape[0], action.shape[-1]
    weight, bias = model.hidden[0]
    # the first layer as rollout's first_layer without the motion input: the state's product, then the action's
    z = torch.baddbmm(bias, obs.unsqueeze(0).expand(n, batch, d), weight[:, :d])
    z = torch.baddbmm(z, action.unsqueeze(0).expand(n, batch, width), weight[:, d : d + width])
    layers: list[tuple[Tensor, Tensor]] = []
    h = z
    for i, (layer_weight, layer_bias) in enumerate(model.hidden):
        if i > 0:
            z = torch.baddbmm(layer_bias, h, layer_weight)
        gate = torch.sigmoid(z)
        if saved is None:
            h = z.mul_(gate)  # SiLU
        else:
            h = z * gate
            layers.append((z, gate))
    # the violation logit, one column: a product and a sum over each row (a 1-column baddbmm costs some 3 times more)
    logit = (h * model.out_weight[..., d : d + 1].transpose(1, 2)).sum(-1) + model.out_bias[..., d]
    probability = torch.sigmoid(logit)  # (N, B)
    deviation = probability - probability.mean(0)
    spread = deviation.square().mean(0)
    sigma_raw = spread.clamp_min(1e-12).sqrt()
    touching = None
    if floors is None:
        member_cost = probability
    else:  # rollout's last-step contact test: the moved state's first channels, compiled
        channels = floors.shape[0]
        delta = torch.baddbmm(model.out_bias[..., :channels], h, model.out_weight[..., :channels])
        touching = _ego_contact(model, obs, action, delta, floors, closing).to(probability.dtype)
        member_cost = torch.maximum(probability, touching)
    cost = member_cost.mean(0)
    divisor = 2.0 * step_scales(model.sigma_scale, 1)[0]
    sigma = torch.tanh(sigma_raw / divisor)
    if saved is not None:
        saved.update(
            layers=layers, probability=probability, deviation=deviation, spread=spread, sigma_raw=sigma_raw,
            touching=touching, divisor=divisor, sigma=sigma,
        )  # fmt: skip
    return cfg.beta * cost + (1.0 - cfg.beta) * sigma


class _OneStepFear(torch.autograd.Function):
    """:func:`_one_step` with its gradient w.r.t. the action written out: the derivatives torch's autograd takes through
    :func:`rollout` and :func:`fear_of` at one step (``maximum`` splitting a tie's gradient in halves, ``clamp_min``
    passing it where the input is at or above the bound), the model's weights and the states constants."""

    @staticmethod
    def forward(
        ctx: torch.autograd.function.FunctionCtx,
        action: Tensor,
        obs: Tensor,
        model: FoldedModel,
        cfg: GateConfig,
        floors: Tensor | None,
        closing: Tensor | None,
    ) -> Tensor:
        saved: dict[str, object] = {}
        value = _one_step(model, obs, action, cfg, floors, closing, saved)
        ctx.saved = saved  # type: ignore[attr-defined]
        ctx.model, ctx.beta, ctx.action_width = model, cfg.beta, action.shape[-1]  # type: ignore[attr-defined]
        return value

    @staticmethod
    def backward(ctx: torch.autograd.function.FunctionCtx, grad: Tensor) -> tuple[Tensor, None, None, None, None, None]:
        saved, model, beta = ctx.saved, ctx.model, ctx.beta  # type: ignore[attr-defined]
        probability, deviation = saved["probability"], saved["deviation"]
        members = probability.shape[0]
        sigma = saved["sigma"]
        # σ̂ = tanh(σ_raw / divisor), σ_raw = sqrt(max(spread, 1e-12)), spread = mean_n (p_n - mean p)^2
        grad_raw = (grad * (1.0 - beta)) * (1.0 - sigma * sigma) / saved["divisor"]
        grad_spread = torch.where(saved["spread"] >= 1e-12, grad_raw / (2.0 * saved["sigma_raw"]), 0.0)
        grad_deviation = deviation * (grad_spread * (2.0 / members))
        grad_p = grad_deviation - grad_deviation.mean(0)
        # ĉ = mean_n max(p_n, contact_n)
        grad_cost = (grad * beta) / members
        touching = saved["touching"]
        if touching is None:
            grad_p = grad_p + grad_cost
        else:
            share = torch.where(probability == touching, 0.5, (probability > touching).to(probability.dtype))
            grad_p = grad_p + grad_cost * share
        grad_logit = grad_p * probability * (1.0 - probability)
        d = model.obs_dim
        grad_h = grad_logit.unsqueeze(-1) * model.out_weight[..., d : d + 1].transpose(1, 2)
        weight, layers = model.hidden[0][0], saved["layers"]
        for i in range(len(layers) - 1, -1, -1):
            z, gate = layers[i]
            grad_z = (1.0 - gate).mul_(z).add_(1.0).mul_(gate).mul_(grad_h)  # SiLU'(z) = s (1 + z (1 - s))
            # into the layer's input: the hidden layer before it, or the first layer's action columns
            below = model.hidden[i][0] if i > 0 else weight[:, d : d + ctx.action_width]  # type: ignore[attr-defined]
            grad_h = torch.bmm(grad_z, below.transpose(1, 2))
        return grad_h.sum(0), None, None, None, None, None  # the members' shares of the one action


class GateKernel:
    """The gate's F^m for one state: the computation of :func:`fear` on preallocated buffers with views
    prepared once, so that a step is a few dozen small tensor ops and no allocation of note.

    Each rollout step owns a block of rows [state, action] that the world model reads directly (no
    concatenation); the next state and the policy's action are written into the next block in place, and
    reductions over members use ``sum`` with the 1/N folded in (``mean`` over a strided axis costs more than
    the matrix products on a CPU). The last rollout step needs no policy action.

    It reads the actor's parameters through views that stay valid while an optimiser updates them in
    place, and the world model's folded weights of the version it was built for (rebuild it after a fit).
    ``tests/core/sage/test_fear.py`` checks that it agrees with :func:`fear`.
    """

    def __init__(
        self,
        model: FoldedModel,
        actor_layers: list[tuple[Tensor, Tensor]],
        output_scale: Tensor,
        output_bias: Tensor,
        cfg: GateConfig,
    ) -> None:
        """``actor_layers``: (weight (out, in), bias) of the actor's deterministic path, ReLU between them and
        tanh after the last, then ``* output_scale + output_bias`` (see :meth:`core.sage.networks.Actor`)."""
        self.model, self.cfg = model, cfg
        # m steps rolled out; the learned head and σ̂ read over the first ``learned`` (contact over all: contact_reach)
        n, d, m = model.members, model.obs_dim, contact_reach(cfg, cfg.horizon)
        self.learned = cfg.horizon
        act_dim = actor_layers[-1][0].shape[0]
        self.d, self.m, self.n = d, m, n
        self.out_w = model.out_weight[..., : d + 1].contiguous()  # the Δs means and the violation logit
        self.out_b = model.out_bias[..., : d + 1].contiguous()
        self.delta_w = model.out_weight[..., :d].contiguous()
        self.delta_b = model.out_bias[..., :d].contiguous()
        self.motion = model.motion
        self.motion_weight = 1.0 / model.motion_lag  # see next_motion
        self.scan = model.scan
        self.approach = model.approach
        self.ego = model.ego
        motion_end = d + act_dim + (d if self.motion else 0)
        width = motion_end + approach_width(self.approach)
        self.x = torch.zeros(m + 1, n, 1, width)  # rows [state, action (, motion (, approach))], one block per step
        self.states = self.x[..., :d]
        self.actions = self.x[..., d : d + act_dim]
        self.motions = self.x[..., d + act_dim : motion_end]
        self.approaches = self.x[..., motion_end:]
        self.outputs = torch.zeros(m, n, 1, d + 1)
        self.hidden = [torch.empty(n, 1, w.shape[-1]) for w, _ in model.hidden]
        self.policy_buffers = [torch.empty(n, w.shape[0]) for w, _ in actor_layers]
        self.actor = [(b, w.t()) for w, b in actor_layers]
        self.scaled = not (bool((output_scale == 1).all()) and bool((output_bias == 0).all()))
        self.output_scale, self.output_bias = output_scale, output_bias
        self.inputs = [self.x[k] for k in range(m)]
        self.state_steps = [self.states[k] for k in range(m + 1)]
        self.action_steps = [self.actions[k] for k in range(m)]
        self.output_steps = [self.outputs[k] for k in range(m)]
        self.policy_inputs = [self.x[k + 1, :, 0, :d] for k in range(m)]
        self.policy_outputs = [self.x[k + 1, :, 0, d : d + act_dim] for k in range(m - 1)]
        self.motion_steps = [self.motions[k] for k in range(m + 1)]
        self.approach_steps = [self.approaches[k] for k in range(m + 1)]
        self.deltas = [self.outputs[k, :, :, :d] for k in range(m)]
        self.step_cost = self.outputs[..., d]
        self.inv_members = 1.0 / n
        self.sigma_divisor = 2.0 * step_scales(model.sigma_scale, self.learned)
        self.weights = discount_weights(cfg)
        self.c_hidden = [torch.empty(n, 1, w.shape[-1]) for w, _ in model.hidden]
        self.c_input = torch.zeros(n, 1, width)
        self.act_dim = act_dim
        self.c_delta = torch.empty(n, 1, d)
        self.contact = contact_floors(cfg)
        self.probability = torch.zeros(m, n, 1)
        self.first_base = torch.zeros(1, 1, d)
        """The last call's (s, a) moved by the ego step (a model with one)."""
        self.base = torch.zeros(n, 1, d)
        self.moves: list[Callable[[], None]] = []
        if self.ego is not None:
            # every member starts from the same (s, a): one row, which the curiosity of that (s, a) reads again
            self.moves.append(self.ego.bound(self.states[0, :1], self.actions[0, :1], self.first_base, views=True))
            self.moves += [self.ego.bound(self.states[k], self.actions[k], self.base, views=True) for k in range(1, m)]
            for move in self.moves:  # a first call compiles (seconds on a fresh install): when the gate is built
                move()

    def _trunk(self, x: Tensor, buffers: list[Tensor]) -> Tensor:
        h = x
        for (weight, bias), buf in zip(self.model.hidden, buffers, strict=True):
            torch.baddbmm(bias, h, weight, out=buf)
            F.silu(buf, inplace=True)
            h = buf
        return h

    def __call__(
        self,
        obs: Tensor,
        action: Tensor,
        motion: Tensor | None = None,
        closing_rate: Tensor | None = None,
        mover_velocity: Tensor | None = None,
    ) -> tuple[float, float, float]:
        """(F^m, ĉ, σ̂) of a (1, D) state and (1, A) first action (``motion``: the last observed change of state,
        zeros when None; ``closing_rate``: (1, n) the real scans' closing, extrapolated in the contact test where the
        gate asks for it, :func:`closing_rate`; ``mover_velocity``: (1, S, 2) the movers the real scans show, for the
        gate's mover model, :func:`rollout`); call under ``torch.inference_mode``."""
        states, actions = self.state_steps, self.action_steps
        states[0].copy_(obs)
        actions[0].copy_(action)
        if self.motion:
            if motion is None:
                self.motion_steps[0].zero_()
            else:
                self.motion_steps[0].copy_(motion)
            self._approach(0)
        last = len(self.actor) - 1
        for k in range(self.m):
            h = self._trunk(self.inputs[k], self.hidden)
            torch.baddbmm(self.out_b, h, self.out_w, out=self.output_steps[k])
            if self.ego is None:
                torch.add(states[k], self.deltas[k], out=states[k + 1])
            else:  # the residual over the scan moved by the action
                self.moves[k]()
                torch.add(self.first_base if k == 0 else self.base, self.deltas[k], out=states[k + 1])
            if self.scan is not None:
                if k + 1 < self.m:  # the last imagined state's motion feeds no further step
                    # the imagined step's change, with the imagined turn taken out of the scan (core.motion)
                    self.motion_steps[k + 1].copy_(self.scan.motion(states[k], states[k + 1]))
            elif self.motion:
                # each member's own predicted change enters its motion (next_motion, in place)
                change = self.deltas[k] if self.ego is None else states[k + 1] - states[k]
                torch.lerp(self.motion_steps[k], change, self.motion_weight, out=self.motion_steps[k + 1])
            if self.approach is not None and k + 1 < self.m:
                self._approach(k + 1)
            if k + 1 < self.m:
                x = self.policy_inputs[k]
                for i, ((bias, weight_t), buf) in enumerate(zip(self.actor, self.policy_buffers, strict=True)):
                    torch.addmm(bias, x, weight_t, out=buf)
                    if i < last:
                        buf.clamp_min_(0.0)
                    x = buf
                if self.scaled:
                    torch.tanh(x, out=x)
                    torch.addcmul(self.output_bias, x, self.output_scale, out=self.policy_outputs[k])
                else:
                    torch.tanh(x, out=self.policy_outputs[k])
        probability = torch.sigmoid(self.step_cost)  # (m, N, 1)
        learned = probability[: self.learned]
        mean = learned.sum(1, keepdim=True).mul_(self.inv_members)
        # the members' disagreement about the danger of each step (1/N applied once)
        sigma_raw = (learned - mean).square_().sum(1).mul_(self.inv_members).clamp_min_(1e-12).sqrt_()
        sigma = torch.tanh(sigma_raw.div_(self.sigma_divisor))
        if self.learned < self.m:  # the steps past the learned ones count imagined contact alone
            probability[self.learned :] = 0.0
        closing = closing_channels(self.cfg, motion, self.contact)  # None unless contact needs closing
        rate = closing_rate if self.cfg.contact_extrapolation else None
        self.probability = with_contact(probability, self.states[1:], self.contact, closing, rate)
        if mover_velocity is not None and self.contact is not None and self.ego is not None:
            touching = mover_contact(self.ego, obs, mover_velocity, self.actions[: self.m], self.contact)
            self.probability = torch.maximum(self.probability, touching.to(self.probability.dtype))
        cost = self.probability.sum(1)
        if self.weights is None:
            c, sg = float(cost.max()) * self.inv_members, float(sigma.max())
        else:
            c = float((cost[:, 0] * self.weights).sum()) * self.inv_members
            sg = float((sigma[:, 0] * self.weights).sum())
        return self.cfg.beta * c + (1.0 - self.cfg.beta) * sg, c, sg

    def _approach(self, k: int) -> None:
        """Step k's approach rates from its state and motion (a model with the input; no-op otherwise). Unlike the
        rest of a step it allocates its temporaries: the input is an option, off in every committed policy."""
        if self.approach is not None:
            self.approach_steps[k].copy_(approach_rate(self.state_steps[k], self.motion_steps[k], *self.approach))

    def last_member_costs(self) -> np.ndarray:
        """(m, N): each member's predicted violation probability at each step of the last rollout (read-only;
        what the dashboard's imagined-horizon chart draws)."""
        return self.probability[..., 0].numpy().copy()

    def first_step_spread(self, precision: np.ndarray) -> float:
        """The members' spread about the next state (:meth:`EnsembleWorldModel.disagreement`) of the last call's state
        and action, from its first rollout step's Δs: no second prediction. ``precision``: 1 / std(Δ)² per state
        channel. In float64 on the host: a handful of torch calls on a (N, D) array cost more than the sums."""
        deltas = self.deltas[0][:, 0].numpy().astype(np.float64)
        variance = np.square(deltas - deltas.mean(0)).mean(0)
        return math.sqrt(float((variance * precision).mean()))

    def curiosity(
        self,
        obs: Tensor,
        action: Tensor,
        next_obs: Tensor,
        reuse_first_step: bool = False,
        motion: Tensor | None = None,
    ) -> float:
        """C = ||s + mean_n Δ_n(s, a) - s'||₂ on normalised states, for (1, D) / (1, A) tensors.
        ``reuse_first_step``: (obs, action, motion) are those of the last call, whose first rollout step already
        predicted Δ_n(s, a) (the common case: the executed action is the policy's)."""
        if reuse_first_step:
            delta = self.deltas[0]
        else:
            d, a = self.d, self.act_dim
            self.c_input[:, :, :d].copy_(obs)
            self.c_input[:, :, d : d + a].copy_(action)
            if self.motion:
                moved = self.c_input[:, :, d + a : 2 * d + a]
                if motion is None:
                    moved.zero_()
                else:
                    moved.copy_(motion)
                if self.approach is not None:
                    self.c_input[:, :, 2 * d + a :].copy_(approach_rate(self.c_input[..., :d], moved, *self.approach))
            h = self._trunk(self.c_input, self.c_hidden)
            delta = torch.baddbmm(self.delta_b, h, self.delta_w, out=self.c_delta)
        if self.ego is None:
            base = obs
        elif reuse_first_step:
            base = self.first_base[0]
        else:
            base = self.ego.apply(obs, action)
        error = delta.mean(0).add_(base).sub_(next_obs).mul_(self.model.inv_obs_std)
        return float(error.norm())


def discount_weights(cfg: GateConfig) -> Tensor | None:
    """Normalised weights discount^k of the ``discounted_mean`` aggregation (None for ``max``)."""
    if cfg.aggregate == "max":
        return None
    if cfg.aggregate != "discounted_mean":
        raise ValueError(f"unknown fear aggregation {cfg.aggregate!r}; use 'max' or 'discounted_mean'")
    weights = cfg.discount ** torch.arange(cfg.horizon, dtype=torch.float32)
    return weights / weights.sum()


def sample_member_transitions(ro: Rollout, rng: np.random.Generator) -> tuple[np.ndarray, ...]:
    """One randomly chosen member's trajectory per start, flattened to (m B) transitions
    (state, action, next state, cost) for the virtual buffer."""
    m, n, b, _ = ro.actions.shape
    member = torch.as_tensor(rng.integers(0, n, size=b))
    cols = torch.arange(b)
    states = ro.states[:, member, cols]  # (m + 1, B, D)
    actions = ro.actions[:, member, cols]
    cost = ro.cost[:, member, cols]
    return (
        states[:-1].reshape(m * b, -1).numpy(),
        actions.reshape(m * b, -1).numpy(),
        states[1:].reshape(m * b, -1).numpy(),
        cost.reshape(m * b).numpy(),
    )
