"""The gate's rollout compiled with numba: :class:`CompiledGateKernel`, the same computation as
:class:`core.sage.fear.GateKernel` in one compiled call per gate step.

The torch kernel is bound by the cost of dispatching its small operations (some 80 a step for a 5-member ensemble
rolled 5 steps at batch 1, a few microseconds each), not by its arithmetic (under 2 MFLOP). Here the whole rollout
(every member's layers, the ego step, the policy's actions, the violation probabilities and their aggregation) is
one loop nest over the torch kernel's own buffers, which it fills as the torch kernel would, so that the curiosity
and the dashboard's horizon read them unchanged. Float32 products and sums as torch's (summed in another order:
equal within float32 rounding, ``tests/core/sage/test_compiled_gate.py``); the probabilities' mean, spread and
aggregation in float64.

It covers the gate of every committed configuration: a CPU float32 model with or without the motion input, the
approach input (``world_model_config.approach_*``) and the ego step, imagined contact, ``max`` or ``discounted_mean``.
A model with a scan-aligned motion (``scan_*``), or weights on another device, keeps the torch kernel
(:func:`compiled_kernel_supports`).
"""

from __future__ import annotations

import math

import numba
import numpy as np
import torch
from torch import Tensor

from core._ego_kernel import scan as ego_scan
from core.motion import APPROACH_RANGE_FLOOR

# numba's on-disk cache (cache=True) checks the timestamp of this file alone, not of the functions it calls: the gate's
# compiled loop keeps the ego step's scan it was compiled with. A change to core/_ego_kernel.py (its code or the layout
# of the geometry it reads, core.motion._kernel_geometry) must therefore come with a change to this file, e.g. this
# line, or a checkout with a cache runs the old scan on the new layout. Last: the rays per radian as a product, the rays
# each own segment can meet, the bounded bearing, error_model=numpy (issue 63).
from core.sage.config import GateConfig
from core.sage.fear import GateKernel, closing_channels
from core.sage.world_model import FoldedModel


@numba.njit(cache=True, nogil=True)
def _member_layer(x: np.ndarray, weight: np.ndarray, bias: np.ndarray, out: np.ndarray, silu: bool) -> None:
    """out = x @ weight + bias for one member's (in,) row, (in, out) weight and (out,) bias; SiLU when ``silu``.
    The output loop is innermost over contiguous weights: vectorised without reordering any sum."""
    n_out = out.shape[0]
    for j in range(n_out):
        out[j] = bias[j]
    for i in range(x.shape[0]):
        xi = x[i]
        for j in range(n_out):
            out[j] += xi * weight[i, j]
    if silu:
        for j in range(n_out):
            v = np.float64(out[j])
            out[j] = v / (1.0 + math.exp(-v))


@numba.njit(cache=True, nogil=True, fastmath={"reassoc", "contract"})
def _linear_rows(x: np.ndarray, weight: np.ndarray, bias: np.ndarray, out: np.ndarray) -> None:
    """out = x @ weight.T + bias for (B, in) rows and torch's (out, in) weight (read in place: the actor's live
    parameters). Each output is a dot product over contiguous memory; reassociation lets it be vectorised. Output by
    output, every row's: a weight row is read once for all rows (the same sums, a few percent sooner)."""
    rows = x.shape[0]
    for j in range(weight.shape[0]):
        w = weight[j]
        for r in range(rows):
            xr = x[r]
            acc = np.float32(0.0)
            for i in range(w.shape[0]):
                acc += xr[i] * w[i]
            out[r, j] = acc + bias[j]


@numba.njit(cache=True, nogil=True)
def gate_rollout(
    x: np.ndarray,
    outputs: np.ndarray,
    probability: np.ndarray,
    first_base: np.ndarray,
    base: np.ndarray,
    hidden_weights: tuple,
    hidden_biases: tuple,
    out_weight: np.ndarray,
    out_bias: np.ndarray,
    actor_weights: tuple,
    actor_biases: tuple,
    action_scale: np.ndarray,
    action_bias: np.ndarray,
    scaled: bool,
    obs_dim: int,
    act_dim: int,
    motion: bool,
    motion_weight: float,
    approach: np.ndarray,
    ego: bool,
    ego_geometry: tuple,
    floors: np.ndarray,
    closing: np.ndarray,
    closing_rate: np.ndarray,
    sigma_divisor: np.ndarray,
    weights: np.ndarray,
    beta: float,
    learned: int,
) -> tuple[float, float, float]:
    """(F^m, ĉ, σ̂) of the state and first action already in ``x[0]``'s rows (every member's; with the motion
    input, the motion too), as :meth:`GateKernel.__call__` computes them. ``x`` (m + 1, N, width): each step's
    [state, action (, motion)] rows, filled here step by step; ``outputs`` (m, N, D + 1) each step's Δs and
    violation logit; ``probability`` (m, N) each member's violation probability with imagined contact, written;
    ``first_base`` (1, D) and ``base`` (N, D) the ego step's moved states (unused without one). ``floors``: the
    contact floors (empty: none), ``closing`` which of their channels may count, ``closing_rate`` each channel's
    closing per step the real scans show, extrapolated over the imagined steps (zeros: none,
    ``GateConfig.contact_extrapolation``); ``weights`` the discounted mean's (empty: the maximum); ``out_weight``
    (N, H, P) and ``out_bias`` (N, 1, P) the output layer's D + 1 columns zero-padded to P (:func:`padded_columns`);
    ``learned`` the first steps whose learned head and σ̂ count (those after it count imagined contact alone:
    ``GateConfig.contact_horizon``; ``sigma_divisor`` holds these steps'). ``approach`` (3,) float32: the approach
    input's first state channel, its last + 1 and the range floor it divides by (:func:`core.motion.approach_rate`),
    written after the motion in each imagined step's row (the first step's by the caller); empty: no such input."""
    m, n = outputs.shape[0], outputs.shape[1]
    d, a = obs_dim, act_dim
    widest = x.shape[2]
    for w in hidden_weights:
        widest = max(widest, w.shape[2])
    h_in = np.empty(widest, dtype=np.float32)
    h_out = np.empty(widest, dtype=np.float32)
    padded = np.empty(out_weight.shape[2], dtype=np.float32)  # the output layer's row, padded (see the call)
    width_out = outputs.shape[2]
    layers = len(actor_weights)
    directions, segments, numbers, channels = ego_geometry
    for k in range(m):
        for member in range(n):
            row = x[k, member]
            width_in = row.shape[0]
            for i in range(width_in):
                h_in[i] = row[i]
            for layer in range(len(hidden_weights)):
                w = hidden_weights[layer][member]
                _member_layer(h_in[:width_in], w, hidden_biases[layer][member, 0], h_out[: w.shape[1]], True)
                width_in = w.shape[1]
                for i in range(width_in):
                    h_in[i] = h_out[i]
            _member_layer(h_in[:width_in], out_weight[member], out_bias[member, 0], padded, False)
            for i in range(width_out):
                outputs[k, member, i] = padded[i]
        if ego:  # the residual over the scan moved by the action; every member starts from the same (s, a)
            if k == 0:
                ego_scan(x[0, :1, :d], x[0, :1, d : d + a], first_base, directions, segments, numbers, channels)
            else:
                ego_scan(x[k, :, :d], x[k, :, d : d + a], base, directions, segments, numbers, channels)
        for member in range(n):
            for i in range(d):
                start = first_base[0, i] if ego and k == 0 else (base[member, i] if ego else x[k, member, i])
                x[k + 1, member, i] = start + outputs[k, member, i]
            if motion and k + 1 < m:  # the last imagined state's motion feeds no further step
                for i in range(d):
                    change = outputs[k, member, i] if not ego else x[k + 1, member, i] - x[k, member, i]
                    previous = x[k, member, d + a + i]
                    x[k + 1, member, d + a + i] = previous + np.float32(motion_weight) * (change - previous)
                if approach.shape[0] > 0:  # core.motion.approach_rate of the new state and motion, in float32
                    first, stop, floor = int(approach[0]), int(approach[1]), approach[2]
                    for channel in range(first, stop):  # not c: that is the float ĉ below
                        nearing = max(-x[k + 1, member, d + a + channel], np.float32(0.0))
                        reach = max(x[k + 1, member, channel], floor)
                        x[k + 1, member, 2 * d + a + channel - first] = min(nearing / reach, np.float32(1.0))
        if k + 1 < m:  # the policy's action on each member's imagined state
            p_in = np.empty((n, d), dtype=np.float32)  # contiguous rows: the products vectorise
            for member in range(n):
                for i in range(d):
                    p_in[member, i] = x[k + 1, member, i]
            for layer in range(layers):
                w = actor_weights[layer]
                p_out = np.empty((n, w.shape[0]), dtype=np.float32)
                _linear_rows(p_in, w, actor_biases[layer], p_out)
                for member in range(n):
                    for i in range(w.shape[0]):
                        v = p_out[member, i]
                        p_out[member, i] = max(v, np.float32(0.0)) if layer + 1 < layers else math.tanh(v)
                p_in = p_out
            for member in range(n):
                for i in range(a):
                    v = p_in[member, i]
                    x[k + 1, member, d + i] = v * action_scale[i] + action_bias[i] if scaled else v
    cost, sigma, step = np.empty(m), np.empty(learned), np.empty(n)
    for k in range(m):
        if k < learned:
            mean = 0.0
            for member in range(n):
                step[member] = 1.0 / (1.0 + math.exp(-np.float64(outputs[k, member, d])))
                mean += step[member]
            mean /= n
            spread = 0.0
            for member in range(n):
                spread += (step[member] - mean) ** 2
            sigma[k] = math.tanh(math.sqrt(max(spread / n, 1e-12)) / sigma_divisor[k])
        else:  # past the learned steps: imagined contact alone
            for member in range(n):
                step[member] = 0.0
        total = 0.0
        ahead = np.float32(k + 1)  # step k + 1 of the rollout: the closing extrapolated over k + 1 steps
        for member in range(n):
            p = step[member]
            for i in range(floors.shape[0]):
                if closing[i] and x[k + 1, member, i] + ahead * closing_rate[i] <= floors[i]:
                    p = 1.0
                    break
            probability[k, member] = p
            total += p
        cost[k] = total / n
    if weights.shape[0] == 0:
        c, s = cost.max(), sigma.max()
    else:
        c, s = 0.0, 0.0
        for k in range(weights.shape[0]):  # the learned steps: contact_reach refuses a longer discounted mean
            c += cost[k] * weights[k]
            s += sigma[k] * weights[k]
    return beta * c + (1.0 - beta) * s, c, s


@numba.njit(cache=True, nogil=True)
def reused_curiosity(outputs: np.ndarray, base: np.ndarray, next_obs: np.ndarray, inv_obs_std: np.ndarray) -> float:
    """||(base + mean_n Δ_n - s') / std(s)||₂ from the first rollout step's (N, D + 1) outputs (float64 sums)."""
    n, d = outputs.shape[0], base.shape[0]
    total = 0.0
    for i in range(d):
        delta = 0.0
        for member in range(n):
            delta += outputs[member, i]
        e = (np.float32(delta / n) + base[i] - next_obs[i]) * inv_obs_std[i]
        total += np.float64(e) ** 2
    return math.sqrt(total)


PAIRWISE_BLOCK = 128
"""numpy's ``PW_BLOCKSIZE``: the longest run its pairwise summation sums with eight accumulators, unsplit."""


@numba.njit(cache=True, nogil=True)
def _pairwise_sum(a: np.ndarray) -> float:
    """numpy's pairwise summation of a contiguous float64 run (``np.add.reduce``'s order): the same sum, bit for bit,
    where numpy's reduction runs its plain pairwise loop."""
    n = a.shape[0]
    if n < 8:
        total = 0.0
        for i in range(n):
            total += a[i]
        return total
    if n > PAIRWISE_BLOCK:
        half = n // 2
        half -= half % 8
        return _pairwise_sum(a[:half]) + _pairwise_sum(a[half:])
    r0, r1, r2, r3, r4, r5, r6, r7 = a[0], a[1], a[2], a[3], a[4], a[5], a[6], a[7]
    i = 8
    while i < n - n % 8:
        r0 += a[i]
        r1 += a[i + 1]
        r2 += a[i + 2]
        r3 += a[i + 3]
        r4 += a[i + 4]
        r5 += a[i + 5]
        r6 += a[i + 6]
        r7 += a[i + 7]
        i += 8
    total = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        total += a[i]
        i += 1
    return total


@numba.njit(cache=True, nogil=True)
def first_step_spread(deltas: np.ndarray, precision: np.ndarray) -> float:
    """:meth:`GateKernel.first_step_spread` of the (N, D) float32 Δs: sqrt(mean_i precision_i var_n Δ_ni), in float64
    with numpy's order of sums (the members' in turn, the channels' pairwise), so the same number as the numpy version
    in a few hundred nanoseconds where its dozen array calls took some 9 µs."""
    n, d = deltas.shape
    mean = np.empty(d)
    weighted = np.empty(d)
    for i in range(d):
        total = np.float64(deltas[0, i])
        for member in range(1, n):
            total += np.float64(deltas[member, i])
        mean[i] = total / n
    for i in range(d):
        e = np.float64(deltas[0, i]) - mean[i]
        total = e * e
        for member in range(1, n):
            e = np.float64(deltas[member, i]) - mean[i]
            total += e * e
        weighted[i] = total / n * precision[i]
    return math.sqrt(_pairwise_sum(weighted) / d)


@numba.njit(cache=True, nogil=True)
def movers_touching(
    ranges: np.ndarray,
    velocity: np.ndarray,
    x: np.ndarray,
    act_offset: int,
    cos: np.ndarray,
    sin: np.ndarray,
    numbers: np.ndarray,
    channels: np.ndarray,
    floors: np.ndarray,
    touching: np.ndarray,
) -> bool:
    """:func:`core.sage.movers.mover_contact` for one state on the rollout's buffers, in float32 as torch computes it:
    ``touching`` (m, N) is written, whether some moving point of ``ranges`` (S,) moved at its ``velocity`` (S, 2) to
    p + k v falls at or under the floor of its sector from member n's imagined pose after k steps, the poses integrated
    from the actions in ``x[k, n, act_offset:]`` (the rollout's, the first the real one). ``numbers``: start, width,
    forward scale and offset, turn scale; ``channels``: the action's forward and turn channels. Returns whether any
    touches. Only the moving points are visited (the others never touch)."""
    m, n, s = touching.shape[0], touching.shape[1], ranges.shape[0]
    start, width = np.float32(numbers[0]), np.float32(numbers[1])
    forward_scale, forward_offset, turn_scale = np.float32(numbers[2]), np.float32(numbers[3]), np.float32(numbers[4])
    forward_channel, turn_channel = channels[0], channels[1]
    count = floors.shape[0]
    moving = np.empty(s, dtype=np.int64)
    k_moving = 0
    for i in range(s):
        if (abs(velocity[i, 0]) + abs(velocity[i, 1]) > 0) and ranges[i] < 1.0:
            moving[k_moving] = i
            k_moving += 1
    px, py = np.empty(s, dtype=np.float32), np.empty(s, dtype=np.float32)
    for i in range(s):
        px[i], py[i] = ranges[i] * cos[i], ranges[i] * sin[i]
    one = np.float32(1.0)
    anything = False
    for member in range(n):
        heading, x_pose, y_pose = np.float32(0.0), np.float32(0.0), np.float32(0.0)
        for k in range(m):
            touching[k, member] = False
            distance = x[k, member, act_offset + forward_channel] * forward_scale + forward_offset
            turn = x[k, member, act_offset + turn_channel] * turn_scale
            half = np.float32(0.5) * turn
            small = abs(half) <= np.float32(1e-6)
            sinc = np.float32(math.sin(half)) / (one if small else half)
            chord = distance * (one if small else sinc)
            heading = heading + turn
            along = heading - half
            x_pose = x_pose + chord * np.float32(math.cos(along))
            y_pose = y_pose + chord * np.float32(math.sin(along))
            ahead = np.float32(k + 1)
            c, sn = np.float32(math.cos(heading)), np.float32(math.sin(heading))
            for q in range(k_moving):
                i = moving[q]
                dx = px[i] + ahead * velocity[i, 0] - x_pose
                dy = py[i] + ahead * velocity[i, 1] - y_pose
                lx, ly = c * dx + sn * dy, c * dy - sn * dx
                sector = math.floor((np.float32(math.atan2(ly, lx)) - start) / width)
                if sector < 0 or sector >= count:
                    continue
                if np.float32(math.hypot(lx, ly)) <= floors[int(sector)]:
                    touching[k, member] = True
                    anything = True
                    break
    return anything


LANES = 16
"""float32 lanes of the widest vector the kernels are compiled for (AVX-512); a width that is a multiple of it leaves
:func:`_member_layer`'s vectorised loop no remainder."""


def padded_columns(weights: np.ndarray) -> np.ndarray:
    """``weights`` (..., C) with zero columns appended up to a multiple of :data:`LANES`. The output layer's 59 columns
    (the UGV's 58 Δs and the logit) cost :func:`_member_layer` three times what 64 do (its vectorised loop's remainder);
    each output's sum is the same (its own column, in the same order), the extra outputs are dropped."""
    width = weights.shape[-1]
    pad = -width % LANES
    if pad == 0:
        return np.ascontiguousarray(weights)
    return np.ascontiguousarray(np.concatenate([weights, np.zeros((*weights.shape[:-1], pad), weights.dtype)], -1))


def compiled_kernel_supports(model: FoldedModel, actor_layers: list[tuple[Tensor, Tensor]]) -> bool:
    """Whether :class:`CompiledGateKernel` computes this model's and actor's gate: CPU float32 contiguous weights
    and no scan-aligned motion."""
    tensors = [model.out_weight, model.out_bias, model.inv_obs_std, *(t for layer in model.hidden for t in layer)]
    tensors += [t for layer in actor_layers for t in layer]
    plain = all(t.device.type == "cpu" and t.dtype == torch.float32 and t.is_contiguous() for t in tensors)
    return plain and model.scan is None


class CompiledGateKernel(GateKernel):
    """:class:`GateKernel` whose rollout and reused curiosity are one compiled call each (:func:`gate_rollout`);
    its buffers, its curiosity of another (s, a) and its horizon are the torch kernel's."""

    def __init__(
        self,
        model: FoldedModel,
        actor_layers: list[tuple[Tensor, Tensor]],
        output_scale: Tensor,
        output_bias: Tensor,
        cfg: GateConfig,
    ) -> None:
        super().__init__(model, actor_layers, output_scale, output_bias, cfg)
        m, n, d = self.m, self.n, self.d
        self._x = self.x.numpy().reshape(m + 1, n, -1)  # views of the torch kernel's buffers
        self._outputs = self.outputs.numpy().reshape(m, n, d + 1)
        self._first_base = self.first_base.numpy().reshape(1, d)
        self._base = self.base.numpy().reshape(n, d)
        self._probability = np.zeros((m, n), dtype=np.float32)
        self.probability = torch.from_numpy(self._probability).view(m, n, 1)
        self._hidden = (
            tuple(w.numpy() for w, _ in model.hidden),
            tuple(b.numpy() for _, b in model.hidden),
        )
        self._out = (padded_columns(self.out_w.numpy()), padded_columns(self.out_b.numpy()))
        # the actor's live parameters (an optimiser updates them in place; the views follow)
        self._actor = (
            tuple(w.detach().numpy() for w, _ in actor_layers),
            tuple(b.detach().numpy() for _, b in actor_layers),
        )
        self._scale = (output_scale.detach().float().numpy(), output_bias.detach().float().numpy())
        self._touching = np.zeros((m, n), dtype=np.bool_)
        """Whether the movers touch each member at each step (:func:`movers_touching`, written by each call)."""
        if self.ego is not None:
            from core.motion import _geometry, _kernel_geometry

            self._geometry = _kernel_geometry(self.ego)
            bearings = _geometry(self.ego, torch.float32)  # the movers' contact test in float32, as torch's
            ego = self.ego
            self._mover_geometry = (
                bearings.cos.numpy().copy(),
                bearings.sin.numpy().copy(),
                np.array([ego.start, ego.width, ego.forward_scale, ego.forward_offset, ego.turn_scale], np.float64),
                np.array([ego.forward_channel, ego.turn_channel], np.int64),
            )
        else:
            self._geometry = (np.zeros((1, 2)), np.zeros((1, 3), np.int64), np.zeros(6), np.zeros(2, np.int64))
        self._floors = np.zeros(0, np.float32) if self.contact is None else self.contact.numpy()
        self._all_closing = np.ones(self._floors.shape[0], dtype=np.bool_)
        self._no_closing_rate = np.zeros(self._floors.shape[0], dtype=np.float32)
        self._divisor = self.sigma_divisor[:, 0].double().numpy().copy()
        self._weights = np.zeros(0) if self.weights is None else self.weights.double().numpy().copy()
        self._inv_obs_std = model.inv_obs_std.reshape(-1).numpy()
        self._approach_input = np.zeros(0, np.float32)
        if self.approach is not None:
            self._approach_input = np.array([*self.approach, APPROACH_RANGE_FLOOR], np.float32)

    def __call__(
        self,
        obs: Tensor,
        action: Tensor,
        motion: Tensor | None = None,
        closing_rate: Tensor | None = None,
        mover_velocity: Tensor | None = None,
    ) -> tuple[float, float, float]:
        d, a = self.d, self.act_dim
        x = self._x
        x[0, :, :d] = obs.numpy()
        x[0, :, d : d + a] = action.numpy()
        if self.motion:
            x[0, :, d + a : 2 * d + a] = 0.0 if motion is None else motion.numpy()
            self._approach(0)  # the first step's approach rates, by the torch kernel's own function
        closing = closing_channels(self.cfg, motion, self.contact)
        closing_mask = self._all_closing if closing is None else closing.reshape(-1).numpy()
        rate = self._no_closing_rate
        if self.cfg.contact_extrapolation and closing_rate is not None:
            rate = np.ascontiguousarray(closing_rate.reshape(-1).numpy(), np.float32)
        terms = gate_rollout(
            x,
            self._outputs,
            self._probability,
            self._first_base,
            self._base,
            *self._hidden,
            *self._out,
            *self._actor,
            *self._scale,
            self.scaled,
            d,
            a,
            self.motion,
            self.motion_weight,
            self._approach_input,
            self.ego is not None,
            self._geometry,
            self._floors,
            closing_mask,
            rate,
            self._divisor,
            self._weights,
            float(self.cfg.beta),
            self.learned,
        )
        if mover_velocity is None or self.contact is None or self.ego is None:
            return terms
        return self._with_movers(obs, mover_velocity, terms)

    def _with_movers(
        self, obs: Tensor, mover_velocity: Tensor, terms: tuple[float, float, float]
    ) -> tuple[float, float, float]:
        """The gate's mover model over the compiled rollout: the movers' imagined contact (in the members' imagined
        poses from the actions the rollout wrote into ``x``) raises the probabilities it wrote, and ĉ and F^m are
        aggregated again as :func:`gate_rollout` aggregates them (σ̂ unchanged)."""
        assert self.contact is not None and self.ego is not None
        touching = self._touching
        ranges = obs.numpy().reshape(-1)[: self.ego.sectors]
        velocity = np.ascontiguousarray(mover_velocity.reshape(-1, 2).numpy(), np.float32)
        if not movers_touching(ranges, velocity, self._x, self.d, *self._mover_geometry, self._floors, touching):
            return terms
        probability = np.maximum(self._probability, touching.astype(np.float32))
        self._probability[...] = probability
        cost = probability.astype(np.float64).mean(1)
        sigma = terms[2]
        c = (
            float(cost.max())
            if self._weights.shape[0] == 0
            else float((cost[: len(self._weights)] * self._weights).sum())
        )
        return self.cfg.beta * c + (1.0 - self.cfg.beta) * sigma, c, sigma

    def first_step_spread(self, precision: np.ndarray) -> float:
        return float(first_step_spread(self._outputs[0, :, : self.d], precision))

    def curiosity(
        self,
        obs: Tensor,
        action: Tensor,
        next_obs: Tensor,
        reuse_first_step: bool = False,
        motion: Tensor | None = None,
    ) -> float:
        if not reuse_first_step:
            return super().curiosity(obs, action, next_obs, reuse_first_step, motion)
        base = self._first_base[0] if self.ego is not None else obs.numpy().reshape(-1)
        return float(reused_curiosity(self._outputs[0], base, next_obs.numpy().reshape(-1), self._inv_obs_std))
