"""The SAGE gate (implements :class:`core.protocol.Gate`): fear against the curiosity-modulated threshold.

``decide``: F^m_t of the policy's intended action a_RL (m-step rollout of the ensemble under the policy,
:mod:`core.sage.fear`) against τ_t; Ξ_t = 1 when F^m_t > τ_t, and once fired the expert keeps control for
k steps (``GateConfig.hold``: ``hold_steps``, or ``hold_seconds`` in the simulator's steps; each new firing
restarts the count), which avoids frame-by-frame switching. With
``release`` > 0 (off in the paper's gate; the committed default policies deploy 1; docs/calibration.md,
says what it measured), fear over a lower release level (between τ_t and τ_min) restarts the count too while the
expert holds control: hysteresis, so that control goes back to the policy only once its own plan looks safe again.
``observe``: curiosity C_{t+1} of the executed transition, which sets the threshold of the next step.
The loop (:class:`core.loop.Runner`) executes a = (1 - Ξ) a_RL + Ξ a_expert and records both actions.

A whole step (m = 5, N = 5 rollout, policy, curiosity, threshold) costs 0.16 ms on one core, 0.24 ms over the
UGV's ego step (bench/bench_gate.py --ego): the rollout is one compiled call
(:class:`core.sage.compiled_gate.CompiledGateKernel`) on cached folded weights, where the torch kernel's few dozen
small operations took twice that. The UGV default's gate as it deploys it (the mover model, contact over 10 steps;
``bench/bench_gate.py --policy policies/ugv-default``) costs about 1.0 ms a step on a loaded machine (1.3x the
synthetic gate's in the same run), its mover model compiled too (:mod:`core.sage.compiled_movers`; 2.8 ms before).
"""

from __future__ import annotations

import collections
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from core.motion import motion_between
from core.protocol import GateDecision
from core.sage.config import GateConfig
from core.sage.fear import (
    GateKernel,
    PolicyFn,
    closing_rate,
    contact_reach,
    contact_terms,
    fear_of,
    rollout,
    unexplained_change,
)
from core.sage.movers import mover_velocities
from core.sage.networks import Actor
from core.sage.novelty import NoveltyReference, novelty_features
from core.sage.threshold import CuriosityThreshold
from core.sage.world_model import EnsembleWorldModel


@dataclass
class GateDetail:
    """The last step's internals, for plots and the dashboard."""

    fear: float = math.nan
    cost: float = math.nan
    """ĉ aggregated over the horizon."""
    sigma: float = math.nan
    """σ̂ aggregated over the horizon."""
    threshold: float = math.nan
    curiosity: float = math.nan
    rho: float = math.nan
    level: float = math.nan
    """The fear that (re)started the hold at this step: τ_t, or the lower release level while the expert held
    control (:attr:`GateConfig.release`)."""
    hold_remaining: int = 0
    vetoed: bool = False
    """Fear was over the level, and the gate's closing veto withheld the hand-over (:attr:`GateConfig.closing_veto`)."""


class TakeoverHold:
    """The gate's k-step hold: once triggered, the expert keeps control for the next k decisions (this one
    included), and every new trigger restarts the count. The SAGE gate triggers it with fear over τ_t (or over the
    release level while it holds: hysteresis); the reference gatings of :mod:`studies.calibrate` with their own
    rules, so that they hold and hand back control exactly as it does."""

    def __init__(self) -> None:
        self.remaining = 0
        """Decisions left under the expert after the last one."""

    @property
    def holding(self) -> bool:
        """Whether the expert holds control now (the last decision left some of the hold)."""
        return self.remaining > 0

    def reset(self) -> None:
        self.remaining = 0

    def step(self, trigger: bool, steps: int) -> bool:
        """One decision: ``trigger`` (re)starts a hold of ``steps`` decisions; whether the expert drives this one."""
        if trigger:
            self.remaining = steps
        fired = self.remaining > 0
        if fired:
            self.remaining -= 1
        return fired


class SageGate:
    """Fear vs curiosity-modulated threshold, with a k-step hold (:class:`TakeoverHold`). Cheap enough to run at
    every step. ``GateConfig.tau_scale`` scales τ's bounds, and so τ_t and the release level: the gate's operating
    point, also the operating curve's knob (:func:`studies.calibrate.curve_point`)."""

    def __init__(
        self,
        world_model: EnsembleWorldModel,
        policy: Actor | PolicyFn,
        cfg: GateConfig | None = None,
        encode: Callable[[Any], np.ndarray] | None = None,
        compiled: bool = True,
    ) -> None:
        """``policy``: the learner's :class:`Actor` (fast preallocated path, always its current weights) or
        any deterministic torch policy function (generic path, e.g. a discrete learner's one-hot greedy).
        ``encode``: turns the loop's actions into the world model's (a discrete action index into its one-hot);
        None when they are the same. ``compiled``: with an :class:`Actor`, the rollout as one compiled call
        (:class:`CompiledGateKernel`, where it covers the model) rather than the torch kernel's small operations; and
        the mover model's velocities compiled (:mod:`core.sage.compiled_movers`) rather than numpy's."""
        self.encode = encode
        self.compiled = compiled
        self.world_model = world_model
        self.actor = policy if isinstance(policy, Actor) else None
        self.policy: PolicyFn = policy.deterministic if isinstance(policy, Actor) else policy
        self.cfg = cfg or GateConfig()
        self._novelty: tuple[int, NoveltyReference | None] | None = None
        self.threshold = CuriosityThreshold(self.cfg, self._curiosity_reference(), self._model_bounds())
        self._reference_version = world_model.version
        self._kernel: tuple[int, GateKernel] | None = None
        self._fitted_version, self._fitted = -1, False
        self._last: tuple[np.ndarray | None, np.ndarray | None, int] = (None, None, -1)
        """The last decision's (obs, action, world model version), whose first rollout step observe may reuse."""
        self._precision: tuple[int, np.ndarray] | None = None
        self.takeover_hold = TakeoverHold()
        self.detail = GateDetail(threshold=self.threshold.threshold)
        self._history: collections.deque[np.ndarray] = collections.deque(maxlen=world_model.motion_lag)
        """The last observations the gate saw in this episode, oldest first (at most ``motion_lag``): the world
        model's motion input is (obs - the oldest) / their number."""
        self._horizon_source: Any = None
        """The last decision's rollout costs (the kernel's buffers, or an (m, N) array): :meth:`last_horizon`."""
        self._changes: collections.deque[torch.Tensor] = collections.deque(maxlen=2)
        """The scan sectors' changes the robot's own motion left unexplained over this episode's last two observed
        steps (``gate.contact_extrapolation``; :func:`core.sage.fear.unexplained_change`), oldest first."""
        self._contact_seen: collections.deque[np.ndarray] = collections.deque(maxlen=3)
        """The contact channels of this episode's last three observed states, oldest first (``gate.closing_veto``)."""
        self._veto_cache: tuple[list[float | None], np.ndarray] | None = None
        """The configuration's floors list and the veto's array made from it (:meth:`_veto_floors`)."""
        self._transitions: collections.deque[tuple[np.ndarray, np.ndarray, np.ndarray]] = collections.deque(
            maxlen=max(self.cfg.mover_history, 2)
        )
        """This episode's last ``gate.mover_history`` observed transitions (obs, encoded action, next obs), oldest
        first: the scans and actions the mover model reads (``gate.mover_model``; :func:`core.sage.movers`)."""

    def _encoded(self, action: Any) -> np.ndarray:
        if self.encode is not None:
            return np.asarray(self.encode(action), dtype=np.float32)
        return np.asarray(action, dtype=np.float32)

    def _delta_precision(self) -> np.ndarray:
        """1 / std(Δ)² per state channel of the model's present fit (the disagreement's units), kept per fit."""
        version = self.world_model.version
        if self._precision is None or self._precision[0] != version:
            std = self.world_model.out_std[: self.world_model.obs_dim].detach().double().cpu().numpy()
            self._precision = (version, 1.0 / np.square(std))
        return self._precision[1]

    def kernel(self) -> GateKernel | None:
        if self.actor is None:
            return None
        if self._kernel is None or self._kernel[0] != self.world_model.version:
            actor = self.actor
            # numba's import (and a first compilation where its cache is cold) is paid by the first kernel
            from core.sage.compiled_gate import CompiledGateKernel, compiled_kernel_supports

            layers, folded = actor.deterministic_layers(), self.world_model.folded()
            compiled = self.compiled and compiled_kernel_supports(folded, layers)
            build = CompiledGateKernel if compiled else GateKernel
            kernel = build(folded, layers, actor.action_scale, actor.action_bias, self.cfg)
            self._kernel = (self.world_model.version, kernel)
        return self._kernel[1]

    @property
    def hold_remaining(self) -> int:
        """Decisions left under the expert after the last one (:class:`TakeoverHold`)."""
        return self.takeover_hold.remaining

    def reset(self) -> None:
        self.takeover_hold.reset()
        self.detail.hold_remaining = 0
        self.threshold.reset_smoothing()
        self._history.clear()
        self._changes.clear()
        self._contact_seen.clear()
        self._transitions.clear()

    def closing_rate(self) -> torch.Tensor | None:
        """(1, n) each scan sector's closing per step, the movers' own (<= 0), from the episode's last two observed
        steps (:func:`core.sage.fear.closing_rate`): what ``gate.contact_extrapolation`` extrapolates over the imagined
        steps. None when the gate does not extrapolate or has seen fewer than two steps of this episode."""
        if not self.cfg.contact_extrapolation or len(self._changes) < 2:
            return None
        return closing_rate(self._changes[0], self._changes[1])

    def mover_velocity(self) -> torch.Tensor | None:
        """(1, S, 2) each scan sector's velocity that the episode's last ``gate.mover_history`` + 1 real scans show
        (zeros: static), for the mover model (:func:`core.sage.movers.mover_velocities`). None when the gate has none,
        the model no ego step, or the episode has shown fewer steps."""
        velocity = self._mover_velocity()
        return None if velocity is None else torch.from_numpy(velocity.astype(np.float32)).unsqueeze(0)

    def _mover_velocity(self) -> np.ndarray | None:
        """:meth:`mover_velocity` as (S, 2) float64 (what :func:`core.sage.movers.mover_velocities` returns)."""
        ego = self.world_model.ego
        if self.cfg.mover_model == "none" or ego is None or len(self._transitions) < self.cfg.mover_history:
            return None
        transitions = list(self._transitions)
        scans = np.stack([obs[: ego.sectors] for obs, _, _ in transitions] + [transitions[-1][2][: ego.sectors]])
        velocities = mover_velocities
        if self.compiled:  # numba's import (and a first compilation where its cache is cold) is paid here, once
            from core.sage.compiled_movers import compiled_mover_velocities

            velocities = compiled_mover_velocities
        return velocities(
            ego,
            scans,
            np.stack([action for _, action, _ in transitions]),
            self.cfg.mover_max_speed,
            self.cfg.mover_max_size,
            self.cfg.mover_min_speed,
        )

    def _motion(self, obs: np.ndarray) -> torch.Tensor | None:
        """(s_t - s_{t-k}) / k as a (1, D) tensor, k = ``motion_lag`` or the steps seen so far in this episode
        (None at an episode's start, or for a model without the input)."""
        if not self.world_model.motion or not self._history:
            return None
        oldest = self._history[0]
        current = np.asarray(obs, dtype=np.float32).reshape(1, -1)
        delta = motion_between(oldest.reshape(1, -1), current, self.world_model.scan) / len(self._history)
        return torch.from_numpy(delta)

    def _curiosity_reference(self) -> float:
        """Curiosity's starting average (``curiosity_reference="recent"``) or fixed reference ("fitted"): the
        signal's value on the model's last fit or calibration. A fitted model that never measured its disagreement
        (a checkpoint from before the setting) is refused with the command that measures it."""
        signal = self.cfg.curiosity_signal
        if signal == "error":
            return float(self.world_model.curiosity_ref)
        if signal == "disagreement":
            value = float(self.world_model.disagreement_ref)
        else:  # "novelty": measured along with its reference set
            value = float(self.world_model.novelty_ref) if self.novelty_reference() is not None else math.nan
        if math.isfinite(value):
            return value
        if bool(self.world_model.fitted):
            what = "disagreement on" if signal == "disagreement" else "reference set of"
            raise ValueError(
                f"gate.curiosity_signal={signal} needs the world model's {what} its calibration states, "
                "which this checkpoint never measured: run `sage gate refit-bounds RUN --scenario ... --out NEW` "
                "with the same --set, and use NEW"
            )
        return 1.0  # not fitted yet: the first fit's calibration measures it

    def novelty_reference(self) -> NoveltyReference | None:
        """The model's state-novelty reference (``curiosity_signal="novelty"``), built once per model version."""
        if self._novelty is None or self._novelty[0] != self.world_model.version:
            self._novelty = (self.world_model.version, self.world_model.novelty_reference())
        return self._novelty[1]

    def _model_bounds(self) -> tuple[float, float] | None:
        """The (τ_min, τ_max) measured at the model's last calibration, when the config asks for them."""
        if not self.cfg.tau_from_data:
            return None
        lo, hi = (float(v) for v in self.world_model.tau_bounds)
        return (lo, hi)

    def _refresh_reference(self) -> None:
        # after a refit the model's errors change scale: restart the curiosity average at the new reference
        if self.world_model.version != self._reference_version:
            self._reference_version = self.world_model.version
            self.threshold.ema = max(self._curiosity_reference(), 1e-8)
            self.threshold.set_bounds(self._model_bounds())

    def _ready(self) -> bool:
        """Whether the model is fitted (read once per model version, not at every step)."""
        version = self.world_model.version
        if self._fitted_version != version:
            self._fitted = bool(self.world_model.fitted)
            self._fitted_version = version
        return self._fitted

    def decide(self, obs: np.ndarray, a_rl: np.ndarray) -> GateDecision:
        threshold = self.threshold.threshold
        if not self._ready():
            return GateDecision(math.nan, threshold, False)
        self._refresh_reference()
        with torch.inference_mode():
            o = torch.from_numpy(np.asarray(obs, dtype=np.float32)).view(1, -1)
            a = torch.from_numpy(self._encoded(a_rl)).view(1, -1)
            kernel = self.kernel()
            motion = self._motion(obs)
            rate = self.closing_rate()
            velocity = self._mover_velocity()
            movers = None  # nothing moves: no moving point can touch (the same fear, without the test's cost)
            if velocity is not None and velocity.any():
                movers = torch.from_numpy(velocity.astype(np.float32)).unsqueeze(0)
            if kernel is not None:
                if movers is None:
                    value, cost, sigma = kernel(o, a, motion, rate)
                else:
                    value, cost, sigma = kernel(o, a, motion, rate, movers)
                self._last = (obs, a_rl, self.world_model.version)
                self._horizon_source = kernel
            else:
                folded = self.world_model.folded()
                steps = contact_reach(self.cfg, self.cfg.horizon)  # imagined contact may reach past the horizon
                contact = contact_terms(self.cfg, motion)
                horizon = self.cfg.horizon
                ro = rollout(
                    folded,
                    self.policy,
                    o,
                    a,
                    steps,
                    motion,
                    *contact,
                    learned_steps=horizon,
                    closing_rate=rate,
                    mover_velocity=movers,
                )
                terms = fear_of(folded, ro, self.cfg)
                value, cost, sigma = float(terms.fear), float(terms.cost), float(terms.sigma)
                self._horizon_source = ro.cost[..., 0].numpy().copy()
        level = self._level(threshold)
        over = value > level
        allowed = not over or self.closing_allows(obs)
        fired = self.takeover_hold.step(over and allowed, self.cfg.hold)
        d = self.detail
        d.vetoed = not allowed
        d.fear, d.cost, d.sigma, d.threshold, d.level = value, cost, sigma, threshold, level
        d.hold_remaining = self.hold_remaining
        return GateDecision(value, threshold, fired)

    def closing_allows(self, obs: np.ndarray) -> bool:
        """Whether the real observations let fear hand over now (``gate.closing_veto``; True when off): some channel
        with a contact floor would reach it within the veto's seconds at the closing per step that the episode's last
        two observed changes show (both falling: the one nearer 0, :func:`core.sage.fear.closing_rate`). True until the
        episode has shown three states, and where a channel is at its floor already."""
        veto = self.cfg.closing_veto
        if veto is None:
            return True
        floors = self._veto_floors()
        current = np.asarray(obs, dtype=np.float64).reshape(-1)[: floors.shape[0]]
        seen = list(self._contact_seen)
        if len(seen) < 2 or not np.array_equal(seen[-1], current):
            return True  # the last observed transition did not end in this state: too little seen to withhold
        if len(seen) < 3:
            return True
        rate = closing_rate(torch.from_numpy(seen[1] - seen[0]), torch.from_numpy(seen[2] - seen[1])).numpy()
        if self.cfg.step_seconds is None:
            raise ValueError("gate.closing_veto needs gate.step_seconds, the simulator's step (a training run sets it)")
        steps = veto / self.cfg.step_seconds
        return bool(np.any(current + steps * rate <= floors))

    def _veto_floors(self) -> np.ndarray:
        """The contact floors the veto reads, -inf where a channel has none (it never reaches one); made once per
        configuration, not at every decision."""
        floors = self.cfg.contact_floors or []
        if self._veto_cache is None or self._veto_cache[0] is not floors:
            values = np.array([-math.inf if f is None else float(f) for f in floors], dtype=np.float64)
            self._veto_cache = (floors, values)
        return self._veto_cache[1]

    def _level(self, threshold: float) -> float:
        """The fear that (re)starts the hold now: τ_t, or while the expert holds control the release level."""
        return self.release_level(threshold) if self.takeover_hold.holding else threshold

    def release_level(self, threshold: float) -> float:
        """τ_t - r (τ_t - τ_min), r = ``release``: while the expert holds control, fear above this keeps it there
        (hysteresis), so that control is not handed back while the danger that called the expert persists."""
        return threshold - self.cfg.release * max(threshold - self.threshold.tau_min, 0.0)

    def last_horizon(self) -> dict[str, list[Any]] | None:
        """The last decision's imagined horizon, read-only: ``cost`` (m lists of N members' predicted violation
        probabilities, one list per step ahead), ``mean`` and ``spread`` (the members' mean and standard deviation
        per step). None before the model is fitted. Costs nothing unless called (the rollout is the gate's own)."""
        source = getattr(self, "_horizon_source", None)
        if source is None:
            return None
        costs = source.last_member_costs() if isinstance(source, GateKernel) else source
        return {
            "cost": np.round(costs, 4).tolist(),
            "mean": np.round(costs.mean(1), 4).tolist(),
            "spread": np.round(costs.std(1), 4).tolist(),
        }

    def observe(self, obs: np.ndarray, action: np.ndarray, next_obs: np.ndarray) -> float:
        if not self._ready():
            return math.nan
        self._refresh_reference()
        with torch.inference_mode():
            kernel = self.kernel()
            curiosity = math.nan  # "novelty" reads the state arrived at, once this one is in the history (below)
            last_obs, last_action, version = self._last
            # the executed action is the decided one (the policy drove): the decision's first rollout step already
            # predicted every member's next state for it
            reuse = (
                version == self.world_model.version
                and last_obs is obs
                and last_action is not None  # (None before the first decision, whose version is -1)
                and (last_action is action or np.array_equal(last_action, action))
            )
            signal = self.cfg.curiosity_signal
            extrapolate = self.cfg.contact_extrapolation and bool(self.cfg.contact_floors)
            from_decision = signal == "disagreement" and kernel is not None and reuse
            if from_decision:  # the common case: the decision's own Δs
                assert kernel is not None  # from_decision says so
                curiosity = kernel.first_step_spread(self._delta_precision())
                if not extrapolate:  # and no tensor needed (a few microseconds a step)
                    return self._observed(obs, action, next_obs, curiosity)
            o = torch.from_numpy(np.asarray(obs, dtype=np.float32)).view(1, -1)
            a = torch.from_numpy(self._encoded(action)).view(1, -1)
            s1 = torch.from_numpy(np.asarray(next_obs, dtype=np.float32)).view(1, -1)
            if signal == "disagreement" and not from_decision:
                curiosity = float(self.world_model.disagreement(o, a, self._motion(obs))[0])
            elif signal == "error" and kernel is not None:
                # reusing the decision's first step reads its motion there: none to compute again
                motion = None if reuse else self._motion(obs)
                curiosity = kernel.curiosity(o, a, s1, reuse_first_step=reuse, motion=motion)
            elif signal == "error":
                curiosity = float(curiosity_folded(self.world_model, o, a, s1, self._motion(obs))[0])
            if extrapolate:
                # the movers' own change per sector: the next scan against this one moved by the robot's action
                channels = len(self.cfg.contact_floors or ())  # some: extrapolate says so
                self._changes.append(unexplained_change(self.world_model.base(o, a), s1, channels).clone())
        return self._observed(obs, action, next_obs, curiosity)

    def _observed(self, obs: np.ndarray, action: np.ndarray, next_obs: np.ndarray, curiosity: float) -> float:
        """:meth:`observe`'s bookkeeping once the transition's curiosity is known: the mover model's and the motion
        input's histories, the threshold."""
        if self.cfg.mover_model != "none":
            self._transitions.append(
                (
                    np.array(obs, dtype=np.float64).reshape(-1),
                    self._encoded(action).astype(np.float64).reshape(-1),
                    np.array(next_obs, dtype=np.float64).reshape(-1),
                )
            )
        self._history.append(np.array(obs, dtype=np.float32).reshape(-1))
        if self.cfg.closing_veto is not None:
            channels = len(self.cfg.contact_floors or ())
            if not self._contact_seen:
                self._contact_seen.append(np.asarray(obs, dtype=np.float64).reshape(-1)[:channels].copy())
            self._contact_seen.append(np.asarray(next_obs, dtype=np.float64).reshape(-1)[:channels].copy())
        if self.cfg.curiosity_signal == "novelty":
            curiosity = self._novelty_of(next_obs)
        self.detail.rho = self.threshold.rho(curiosity)
        self.threshold.update(curiosity)
        self.detail.curiosity = curiosity
        return curiosity

    def _novelty_of(self, state: np.ndarray) -> float:
        """The novelty of the state the next decision is made in, with the motion input that decision will read."""
        reference = self.novelty_reference()
        if reference is None:
            return math.nan
        with torch.inference_mode():
            s = torch.from_numpy(np.asarray(state, dtype=np.float32)).view(1, -1)
            return float(reference(novelty_features(s, self._motion(state), self.world_model.motion))[0])

    def state(self) -> dict[str, float]:
        """What persists across episodes (the curiosity average, named by the signal it averages), for checkpoints."""
        return {self._ema_key(): self.threshold.ema}

    def _ema_key(self) -> str:
        # an average of another signal is on another scale: each signal's has its own name
        return "curiosity_ema" if self.cfg.curiosity_signal == "error" else f"{self.cfg.curiosity_signal}_ema"

    def load_state(self, state: dict[str, float]) -> None:
        key = self._ema_key()
        if key in state and self.cfg.curiosity_reference == "recent":  # a fixed reference is the model's, not a run's
            self.threshold.ema = float(state[key])
            self._reference_version = self.world_model.version


def curiosity_folded(
    world_model: EnsembleWorldModel,
    obs: torch.Tensor,
    action: torch.Tensor,
    next_obs: torch.Tensor,
    motion: torch.Tensor | None = None,
) -> torch.Tensor:
    """C on the folded weights (no normalisation arithmetic): ||(s + mean_n Δ_n - s') / std(s)||₂ (s moved by the
    model's ego step, where it has one)."""
    fm = world_model.folded()
    h = world_model.inputs(obs, action, motion).unsqueeze(0).expand(fm.members, obs.shape[0], -1)
    for weight, bias in fm.hidden:
        h = torch.nn.functional.silu(torch.baddbmm(bias, h, weight))
    delta = torch.baddbmm(fm.out_bias[..., : fm.obs_dim], h, fm.out_weight[..., : fm.obs_dim]).mean(0)
    return ((fm.base(obs, action) + delta - next_obs) * fm.inv_obs_std).norm(dim=-1)


class AlwaysGate:
    """Fires at every step: the expert drives throughout (demonstration collection, with both actions
    recorded so that the demonstrations enter the buffer as intervention samples)."""

    def reset(self) -> None:
        pass

    def decide(self, obs: np.ndarray, a_rl: np.ndarray) -> GateDecision:
        return GateDecision(math.nan, math.nan, True)

    def observe(self, obs: np.ndarray, action: np.ndarray, next_obs: np.ndarray) -> float:
        return math.nan
