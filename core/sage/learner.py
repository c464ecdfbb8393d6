"""What every learner shares: the real and virtual buffers, the world model's trainer, the fear budget and λ, the
SAGE gate built on them, the update schedule, the guarded update, demonstrations and checkpoints.

:class:`BaseLearner` builds no network: what a method trains is its own (declared in
:meth:`BaseLearner.declared_state`, which checkpoints and the guarded update read), and it says how it acts
(:meth:`~BaseLearner.policy_action`), which deterministic policy world-model rollouts follow
(:meth:`~BaseLearner.rollout_policy`) and how the environment's actions are written for its buffer and world
model (:meth:`~BaseLearner.encode_action`: identity for continuous actions, one-hot for discrete ones).
:class:`ActorLearner` adds the continuous actor that SAC, TD3 and HG-DAgger share; a value-based discrete learner
(:mod:`core.sage.d3qn`) subclasses the base directly.

World model. A learner whose method trains one owns a :class:`~core.sage.model_trainer.WorldModelTrainer`
(``model_trainer``; None otherwise): the fit and its schedule, the τ bounds on the familiar states, the fear
budget's measurement and the virtual rollouts into D_virtual are the trainer's; the learner hands it its buffers,
its rollout policy and its fear, and keeps what the algorithm trains (λ, the budget in use).

A learner is a :class:`core.protocol.Policy` (``act``) and a step listener (``observe``): the training driver
(:mod:`core.train`) puts it in a :class:`core.loop.Runner` and appends ``observe`` to the step listeners, so
the one step loop feeds the buffer and triggers the updates. The algorithms themselves are one file each:
:mod:`core.sage.sac` (SAC, FNI-RL, SAGE-SAC), :mod:`core.sage.td3`, :mod:`core.sage.hg_dagger`. A discrete
learner (D3QN with the same fear regularisation) would subclass this with a Q-network in place of the actor
and hand the gate a one-hot greedy policy function (see :data:`core.sage.fear.PolicyFn`).
"""

from __future__ import annotations

import collections
import copy
import dataclasses
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import Tensor

from core.device import DeviceError, resolve_device, to_cpu
from core.protocol import StepRecord
from core.replay import ReplayBuffer, VirtualBuffer
from core.sage.calibration import CalibrationSample
from core.sage.captured import CapturedUpdate, require_cuda
from core.sage.config import AgentConfig, GateConfig
from core.sage.critic_transfer import check_state_shapes, fit_to_saved
from core.sage.fear import PolicyFn
from core.sage.gate import SageGate
from core.sage.model_trainer import WorldModelTrainer, familiar_mean_fear
from core.sage.networks import Actor, EnsembleCritic
from core.sage.world_model import EnsembleWorldModel, FitReport, FoldedModel


class ActorPolicy:
    """A :class:`core.protocol.Policy` over an actor: its sample, or its deterministic action.

    The deterministic action runs on preallocated buffers through views of the actor's parameters (which
    stay valid while an optimiser updates them in place): a few tensor ops, no module dispatch."""

    def __init__(self, actor: Actor) -> None:
        self.actor = actor
        self._layers = [(b, w.t()) for w, b in actor.deterministic_layers()]
        self._input = torch.zeros(1, self._layers[0][1].shape[0])
        self._buffers = [torch.zeros(1, w.shape[1]) for _, w in self._layers]
        self._scaled = not (bool((actor.action_scale == 1).all()) and bool((actor.action_bias == 0).all()))

    def act(self, obs: np.ndarray, deterministic: bool = False) -> np.ndarray:
        with torch.inference_mode():
            if not deterministic:
                o = torch.from_numpy(np.asarray(obs, dtype=np.float32)).view(1, -1)
                return self.actor.sample(o)[0][0].numpy()
            self._input.copy_(torch.from_numpy(np.asarray(obs, dtype=np.float32)).view(1, -1))
            x, last = self._input, len(self._layers) - 1
            for i, ((bias, weight_t), buf) in enumerate(zip(self._layers, self._buffers, strict=True)):
                torch.addmm(bias, x, weight_t, out=buf)
                if i < last:
                    buf.clamp_min_(0.0)
                x = buf
            action = torch.tanh(x)
            if self._scaled:
                action = action * self.actor.action_scale + self.actor.action_bias
            return action[0].numpy()


OPTIMIZER_SETTINGS = ("lr", "fused", "foreach", "capturable")
"""What a loaded optimiser keeps of its own (a checkpoint gives only its memory: moments and step counts)."""


def _place_step_counts(optimizer: torch.optim.Optimizer) -> None:
    """Adam keeps its step count on the CPU unless capturable or fused, where it must sit beside the parameter: move
    the loaded counts to where this optimiser's implementation needs them."""
    for group in optimizer.param_groups:
        on_device = bool(group.get("capturable") or group.get("fused"))
        for param in group["params"]:
            state = optimizer.state.get(param)
            if state and isinstance(state.get("step"), torch.Tensor):
                where = param.device if on_device else torch.device("cpu")
                state["step"] = state["step"].to(where, torch.float32)


def _restore_in_place(optimizer: torch.optim.Optimizer, saved: dict[str, Any]) -> None:
    """An optimiser's state as ``saved`` (its ``state_dict``) copied into its own tensors."""
    params = [p for group in optimizer.param_groups for p in group["params"]]
    with torch.no_grad():
        for index, values in saved["state"].items():
            own = optimizer.state[params[index]]
            for key, value in values.items():
                if isinstance(own.get(key), torch.Tensor):
                    own[key].copy_(value)
                else:
                    own[key] = value


def _copy_optimizer_state(saved: dict[str, Any]) -> dict[str, Any]:
    """``copy.deepcopy`` of an optimiser's ``state_dict``, its per-parameter tensors cloned directly: the same copy at a
    fifth of the cost (deepcopy's generic walk was a tenth of a SAGE-SAC update, taken before every guarded update)."""
    copied = {key: copy.deepcopy(value) for key, value in saved.items() if key != "state"}
    copied["state"] = {
        index: {
            key: value.clone() if isinstance(value, Tensor) else copy.deepcopy(value) for key, value in values.items()
        }
        for index, values in saved["state"].items()
    }
    return copied


def _all_finite(tensors: list[Tensor]) -> bool:
    """Whether every element of ``tensors`` is finite: numpy's test on float CPU tensors (torch's costs ten times more
    on tensors this small, and the guarded update tests every trained weight after each update), torch's elsewhere."""
    for tensor in tensors:
        if tensor.device.type == "cpu" and tensor.dtype in (torch.float32, torch.float64):
            if not np.isfinite(tensor.detach().numpy()).all():
                return False
        elif not bool(torch.isfinite(tensor).all()):
            return False
    return True


@dataclass(frozen=True)
class DeclaredState:
    """What :meth:`BaseLearner.update` trains, by attribute name (Stable-Baselines3 style): checkpoints save and
    load optimisers from it, and the guarded update snapshots and restores exactly these. The world model is
    not here: only ``fit`` trains it (it is checkpointed on its own)."""

    modules: tuple[str, ...] = ("actor",)
    optimizers: tuple[str, ...] = ()
    tensors: tuple[str, ...] = ()
    """Tensors changed in place (e.g. SAC's log α)."""
    scalars: tuple[str, ...] = ()
    """Plain floats (e.g. SAC's λ)."""


CRITIC_DISTIL_UPDATES = 1000
"""Updates :meth:`ActorLearner.distil_critic` takes when a warm start's critics are of another shape than this run's
(without its layer norms, or fewer members): a few seconds in all on one CPU thread at the default sizes."""


class BaseLearner:
    """Shared machinery; subclasses implement :meth:`update` (one gradient step) and may extend the rest."""

    uses_random_warmup = True
    """Act uniformly at random until ``learning_starts`` transitions (unless warm-started)."""
    acting_module = "actor"
    """The declared module a checkpoint must hold for the learner to act (the actor, a Q-network, ...)."""
    device_capable = True
    """Whether the method's update can run on a CUDA device (:mod:`core.device`); one that cannot trains on the CPU
    under ``auto`` and refuses an explicit ``cuda``."""
    reads_critic_subset = False
    """Whether the update reads ``AgentConfig.critic_target_subset``; one that does not refuses it."""
    reads_conservative = False
    """Whether the critics' update reads ``AgentConfig.conservative_weight`` (Cal-QL); one that does not refuses it."""
    reads_ibrl = False
    """Whether the learner has IBRL's imitation actor and proposals (``AgentConfig.ibrl``); one that has not refuses
    it."""
    reads_refused = False
    """Whether the update reads the gate's refused proposals (``AgentConfig.refused_weight``); one that does not
    refuses a weight over 0 rather than ignore it."""

    @classmethod
    def check_config(cls, cfg: AgentConfig) -> None:
        """Refuse settings this learner would not read (a ValueError naming them), before any network is built: the
        dashboard checks a round's learner settings this way before the server starts."""
        sac_only = (
            ("critic_target_subset", cfg.critic_target_subset is not None, cls.reads_critic_subset, "none"),
            ("conservative_weight", cfg.conservative_weight > 0, cls.reads_conservative, "0"),
            ("ibrl", cfg.ibrl, cls.reads_ibrl, "false"),
        )
        for name, used, read, off in sac_only:
            if used and not read:
                raise ValueError(
                    f"{name} is read by the SAC learners only (sage, sac, fni-rl), not {cfg.method}: set {name}={off}"
                )
        if cfg.refused_weight > 0 and not cls.reads_refused:
            raise ValueError(
                f"refused_weight is read by the SAC learners only (sage, sac, fni-rl); {cfg.method} has no critic "
                "of continuous actions to hold to it: set refused_weight=0"
            )

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
        self.cfg, self.obs_dim, self.act_dim, self.seed = cfg, obs_dim, act_dim, seed
        self.check_config(cfg)
        self.device = self._resolve_device(device)
        """Where the update runs: the trained networks, their optimisers and the sampled batches
        (:func:`core.device.resolve_device`). What acts in the loop and the world model's fit stay on the CPU."""
        self.captures = cfg.cuda_graph and self.device.type == "cuda"
        """Whether the update is captured once as a CUDA graph and replayed (``AgentConfig.cuda_graph`` on CUDA:
        :mod:`core.sage.captured`); its optimisers are then capturable."""
        self._captured: CapturedUpdate | None = None
        self._acting_copy: torch.nn.Module | None = None
        self._device_folded: tuple[int, FoldedModel] | None = None
        torch.manual_seed(seed)
        self.rng = np.random.default_rng(seed)
        low = torch.as_tensor(-np.ones(act_dim) if action_low is None else action_low, dtype=torch.float32)
        high = torch.as_tensor(np.ones(act_dim) if action_high is None else action_high, dtype=torch.float32)
        self.action_low, self.action_high = low, high
        self.build_networks()
        width = self.model_action_dim
        self.buffer = ReplayBuffer(obs_dim, width, cfg.buffer_size, device=self.device)
        self.model_trainer = WorldModelTrainer(self.new_world_model(), cfg, self.rng) if cfg.world_model else None
        """Fits the world model and measures what each fit sets (None: this method trains no world model)."""
        self.virtual = (
            VirtualBuffer(obs_dim, width, cfg.virtual_size, device=self.device) if cfg.virtual_rollouts else None
        )
        self.warm = False
        """True once the policy holds knowledge (loaded or pretrained): no random warm-up actions."""
        self.critic_teacher: EnsembleCritic | None = None
        """The warm start's critics as saved, when their shape is not this run's (without its layer norms,
        ``AgentConfig.critic_layer_norm``, or fewer members, ``critics``): :meth:`ActorLearner.distil_critic` fits
        the new critics to them, then drops them."""
        self.env_steps = 0
        self.updates = 0
        self._update_credit = 0.0
        self.lam = float(cfg.lambda_init)
        """λ, the dual variable of the fear constraint (methods with a fear term train it; :meth:`dual_step`)."""
        self.measured_fear_budget = math.nan
        """F_0 measured at the last world-model fit (``AgentConfig.fear_budget_from_data``); NaN before one."""
        self.info: dict[str, float] = {}
        """Latest training statistics (losses, λ, α, ...), for progress bars and metrics rows."""
        self._gates: list[SageGate] = []
        self._inherited_gate: tuple[dict[str, float], int] | None = None
        """A loaded checkpoint's gate state (its curiosity average) and the model version it belongs to: the
        gates of this run start from it until the world model is refitted."""

    def _resolve_device(self, device: str | torch.device) -> torch.device:
        resolved = resolve_device(device)
        if resolved.type == "cpu" or self.device_capable:
            return resolved
        if str(device) == "auto":
            return torch.device("cpu")
        raise DeviceError(f"--device {device}: method {self.cfg.method!r} trains on the CPU only")

    def acting_network(self) -> torch.nn.Module:
        """The :attr:`acting_module` as the loop's policy and the SAGE gate read it, one state at a time: the trained
        module itself on the CPU; on another device a CPU copy, refreshed in place after each update
        (:meth:`refresh_acting`), so that views of its weights (the gate's kernel, :class:`ActorPolicy`) stay valid."""
        module: torch.nn.Module = getattr(self, self.acting_module)
        if self.device.type == "cpu":
            return module
        if self._acting_copy is None:
            self._acting_copy = copy.deepcopy(module).cpu().requires_grad_(False)
        return self._acting_copy

    def refresh_acting(self) -> None:
        """Copy the trained acting module's weights into its CPU copy (a no-op on the CPU, where they are one)."""
        if self.device.type == "cpu" or self._acting_copy is None:
            return
        with torch.no_grad():
            self._acting_copy.load_state_dict(getattr(self, self.acting_module).state_dict())

    def update_folded(self) -> FoldedModel:
        """The world model's folded weights on :attr:`device`, for the fear terms of the update (the CPU ones on the
        CPU; a device copy otherwise, made again when the model changes)."""
        assert self.world_model is not None
        folded = self.world_model.folded()
        if self.device.type == "cpu":
            return folded
        version = self.world_model.version
        if self._device_folded is None or self._device_folded[0] != version:
            self._device_folded = (version, folded.to(self.device))
        return self._device_folded[1]

    def make_captured(self) -> CapturedUpdate:
        """The method's update as a CUDA graph (:mod:`core.sage.captured`; methods without one refuse
        ``learner.cuda_graph``)."""
        raise DeviceError(f"learner.cuda_graph: method {self.cfg.method!r} has no captured update (SAC and D3QN do)")

    def captured_update(self) -> dict[str, float]:
        """One update replayed from its CUDA graph (``AgentConfig.cuda_graph``): a DeviceError off CUDA."""
        if self._captured is None:
            require_cuda(self.device)
            self._captured = self.make_captured()
        return self._captured()

    def fear_policy(self, obs: Tensor) -> Tensor:
        """The rollout policy on :attr:`device`, which the update's fear terms roll out (with gradients through the
        trained network where the loss asks for them); :meth:`rollout_policy` on the CPU."""
        return self.rollout_policy(obs)

    @property
    def world_model(self) -> EnsembleWorldModel | None:
        """The world model (its trainer's; None when the method trains none)."""
        return None if self.model_trainer is None else self.model_trainer.world_model

    @property
    def last_calibration(self) -> CalibrationSample | None:
        """The states the last fit calibrated κ and the τ bounds on (kept by a run folder for ``sage gate merge``)."""
        return None if self.model_trainer is None else self.model_trainer.last_calibration

    # -- what a method provides --------------------------------------------------------------------
    def build_networks(self) -> None:
        """Build what the method trains (called once by the base constructor, before the buffers)."""

    @property
    def model_action_dim(self) -> int:
        """Width of an action as the buffers and the world model hold it (see :meth:`encode_action`)."""
        return self.act_dim

    def encode_action(self, action: Any) -> np.ndarray:
        """An environment action as the buffers and the world model hold it (continuous: as it is)."""
        return np.asarray(action, dtype=np.float32).reshape(self.model_action_dim)

    def new_world_model(self) -> EnsembleWorldModel:
        """A fresh world model for this learner's observations and encoded actions."""
        return EnsembleWorldModel(self.obs_dim, self.model_action_dim, self.cfg.world_model_config)

    def random_action(self) -> np.ndarray:
        """A uniformly random action (the warm-up before ``learning_starts``)."""
        return self.rng.uniform(self.action_low.numpy(), self.action_high.numpy()).astype(np.float32)

    def policy_action(self, obs: np.ndarray, deterministic: bool) -> np.ndarray:
        """The method's action for the environment (sampled while training, or its deterministic one)."""
        raise NotImplementedError

    def rollout_policy(self, obs: Tensor) -> Tensor:
        """The deterministic torch policy that world-model rollouts (fear, virtual buffer) follow, in the
        encoded action space."""
        raise NotImplementedError

    def gate_policy(self) -> Actor | PolicyFn:
        """What the SAGE gate rolls out: an :class:`Actor` (its fast path) or a torch policy function."""
        return self.rollout_policy

    def behaviour_clone(self, steps: int, lr: float = 1e-3) -> float:
        """Fit the policy to the expert's actions on intervention samples; returns the last loss."""
        raise NotImplementedError

    # -- acting ----------------------------------------------------------------------------------
    def act(self, obs: np.ndarray, deterministic: bool = False) -> np.ndarray:
        if not deterministic and self.in_random_warmup():
            return self.random_action()
        return self.policy_action(obs, deterministic)

    def in_random_warmup(self) -> bool:
        return self.uses_random_warmup and not self.warm and self.buffer.total < self.cfg.learning_starts

    # -- the loop's listener -----------------------------------------------------------------------
    _last_row: int | None = None
    _last_key: tuple[int, int] | None = None
    shaped = 0
    """Transitions whose reward was shaped by an intervention so far (``AgentConfig.intervention_penalty``)."""
    looked_back = 0
    """Agent steps labelled with the expert's onset action so far (``AgentConfig.lookback_labels``)."""
    _recent: collections.deque[tuple[int, tuple[int, int], bool]] | None = None

    def store(self, record: StepRecord) -> None:
        """Add one step of the loop to the real buffer, its actions encoded (:meth:`encode_action`). With
        ``intervention_penalty`` > 0, the agent's own transition just before a takeover starts (the same episode, the
        step before) loses that much reward: the action that brought the expert in is marked bad (Multi-Hug's
        intervention-based shaping; RLIF's intervention as a cost), whoever called for the takeover."""
        buffer = self.buffer
        previous_row, previous_key = self._last_row, self._last_key
        penalty = self.cfg.intervention_penalty
        if penalty > 0 and record.takeover and previous_row is not None:
            agent_before = not bool(buffer.takeover[previous_row]) or bool(buffer.coached[previous_row])
            if agent_before and previous_key == (record.episode, record.t - 1):
                buffer.set_rewards(previous_row, buffer.reward[previous_row] - penalty)
                self.shaped += 1
        self._last_row = buffer.pos
        encoded = self.encoded(record)
        if self.cfg.lookback_labels > 0:
            self._look_back(encoded)
        buffer.add_record(encoded)
        self._last_key = (record.episode, record.t)

    def _look_back(self, record: StepRecord) -> None:
        """``lookback_labels``: at a takeover onset (the agent drove the step before, same episode), the agent's
        last steps before it, back to the first gap or expert step, become imitation rows labelled with the
        expert's onset action: the state the expert took over in came from them, and the gate fired too late to
        label them. Rows are remembered as (row, (episode, t), the agent drove)."""
        buffer, steps = self.buffer, self.cfg.lookback_labels
        if self._recent is None or self._recent.maxlen != steps:
            self._recent = collections.deque(maxlen=steps)
        recent = self._recent
        if record.takeover and record.a_expert is not None and recent:
            label = np.asarray(record.a_expert, np.float32).reshape(-1)
            for back, (row, key, agent) in enumerate(reversed(recent), start=1):
                if not agent or key != (record.episode, record.t - back) or buffer.takeover[row]:
                    break
                buffer.label(row, label)
                self.looked_back += 1
        recent.append((buffer.pos, (record.episode, record.t), not record.takeover))

    def encoded(self, record: StepRecord) -> StepRecord:
        """The step with its actions as the buffers and the world model hold them (:meth:`encode_action`)."""
        if self.model_action_dim != self.act_dim or self.encodes_actions:
            return dataclasses.replace(
                record,
                action=self.encode_action(record.action),
                a_rl=self.encode_action(record.a_rl),
                a_expert=None if record.a_expert is None else self.encode_action(record.a_expert),
            )
        return record

    encodes_actions = False
    """Whether :meth:`encode_action` changes actions (a discrete learner's one-hot), so :meth:`store` must."""

    def observe(self, record: StepRecord) -> None:
        """Store the step, refit the world model / roll it out when due, and run the updates due."""
        self.store(record)
        self.env_steps += 1
        self.maybe_fit_world_model()
        self.maybe_virtual_rollout()
        if len(self.buffer) < self.update_threshold():
            return
        self._update_credit += self.cfg.updates_per_step
        while self._update_credit >= 1.0:
            self._update_credit -= 1.0
            stats, applied = self.guarded_update()
            self.info.update(stats)
            if not applied:
                self.info["skipped_updates"] = self.info.get("skipped_updates", 0.0) + 1.0

    def update_threshold(self) -> int:
        return self.cfg.batch_size if self.warm else max(self.cfg.learning_starts, self.cfg.batch_size)

    def update(self) -> dict[str, float]:
        raise NotImplementedError

    def declared_state(self) -> DeclaredState:
        """The state :meth:`update` trains (subclasses declare their networks, optimisers and numbers)."""
        return DeclaredState()

    def guarded_update(self, step: Callable[[], dict[str, float]] | None = None) -> tuple[dict[str, float], bool]:
        """One :meth:`update` (or ``step``, e.g. a critic-only step), undone when a loss or a trained value comes out
        NaN/inf (as if it had never run).

        Online training (:meth:`observe`) and fine-tuning both update through here. Returns (stats, applied);
        ``updates`` counts applied updates only."""
        snapshot = self._snapshot()
        try:
            stats = (step or self.update)()
        except FloatingPointError:
            stats = {"error": math.nan}
        finite = all(math.isfinite(float(v)) for v in stats.values() if isinstance(v, int | float))
        if finite and self.weights_finite():
            self.updates += 1
            self.refresh_acting()
            return stats, True
        self._restore(snapshot)
        self.refresh_acting()
        return stats, False

    def weights_finite(self) -> bool:
        """Whether every declared trained value (and the world model) is finite."""
        declared = self.declared_state()
        modules = [getattr(self, name) for name in declared.modules]
        if self.device.type != "cpu":  # one host sync for all the device's weights, not one per tensor
            trained = [p.detach() for module in modules for p in module.parameters()]
            trained += [getattr(self, name).detach().reshape(-1) for name in declared.tensors]
            if not bool(torch.stack([torch.isfinite(t).all() for t in trained]).all()):
                return False
            modules = []
        if self.world_model is not None:
            modules.append(self.world_model)
        if not _all_finite([p for module in modules for p in module.parameters()]):
            return False
        if not _all_finite([getattr(self, name) for name in declared.tensors]):
            return False
        return all(math.isfinite(float(getattr(self, name))) for name in declared.scalars)

    def _snapshot(self) -> dict[str, Any]:
        declared = self.declared_state()
        return {
            "modules": {
                n: {k: v.detach().clone() for k, v in getattr(self, n).state_dict().items()} for n in declared.modules
            },
            "optimizers": {n: _copy_optimizer_state(getattr(self, n).state_dict()) for n in declared.optimizers},
            "tensors": {n: getattr(self, n).detach().clone() for n in declared.tensors},
            "scalars": {n: getattr(self, n) for n in declared.scalars},
        }

    def _restore(self, snapshot: dict[str, Any]) -> None:
        for name, saved in snapshot["modules"].items():
            getattr(self, name).load_state_dict(saved)  # copies in place: views of the weights (ActorPolicy) stay valid
        for name, saved in snapshot["optimizers"].items():
            if self.captures:  # in place: a CUDA graph reads the moments where it recorded them
                _restore_in_place(getattr(self, name), saved)
            else:
                getattr(self, name).load_state_dict(saved)
        with torch.no_grad():
            for name, saved in snapshot["tensors"].items():
                getattr(self, name).copy_(saved)
        for name, saved in snapshot["scalars"].items():
            setattr(self, name, saved)

    # -- fear budget (eq:fear_cmdp) ----------------------------------------------------------------
    def fear_active(self) -> bool:
        """Whether the fear term of the critic, actor and dual runs (a method with one, and a fitted model)."""
        return False

    def real_fear(self, obs: Tensor) -> Tensor:
        """F(s, a) on real states ``obs`` as the dual update measures it, a the learner's own action (methods with
        a fear term)."""
        raise NotImplementedError(f"{type(self).__name__} has no fear term")

    def fear_budget(self) -> float:
        """F_0 in use: the one measured at the last fit (``fear_budget_from_data``), else the configured one."""
        if self.cfg.fear_budget_from_data and math.isfinite(self.measured_fear_budget):
            return self.measured_fear_budget
        return self.cfg.fear_budget

    def measure_fear_budget(self, sample: CalibrationSample) -> None:
        """Set F_0 to the mean fear of ``sample``'s familiar states (``AgentConfig.fear_budget_from_data``,
        :func:`~core.sage.model_trainer.familiar_mean_fear`); kept as it was when the sample holds too few."""
        if not (self.cfg.fear_budget_from_data and self.fear_active()):
            return
        measured = familiar_mean_fear(sample, self.real_fear)
        if measured is None:
            return
        self.measured_fear_budget = measured
        self.info["fear_budget"] = self.measured_fear_budget

    def describe_fear_term(self) -> str | None:
        """One line on what the fear term of eq:fear_cmdp did by now (None for a method without one): the budget
        and where it came from, λ and the last mean fear of real states; it says so where λ is 0, the fear term
        then adding nothing to the critic's target or the actor's loss."""
        if not self.cfg.fear_regularisation or self.world_model is None:
            return None
        measured = self.cfg.fear_budget_from_data and math.isfinite(self.measured_fear_budget)
        source = "measured at the last world-model fit" if measured else "configured"
        line = f"fear term: budget F_0 {self.fear_budget():.3g} ({source}), λ {self.lam:.3g}"
        if "fear_real" in self.info:
            line += f", mean fear of real states {self.info['fear_real']:.3g}"
        if self.lam == 0.0:
            line += " — λ is 0: the fear term adds nothing now (the real states' fear is under the budget)"
        return line

    def dual_step(self, fear_real: float) -> float:
        """Projected dual ascent on λ (eq:lambda_update) against :meth:`fear_budget`; returns the new λ."""
        self.lam = min(max(self.lam + self.cfg.lambda_lr * (fear_real - self.fear_budget()), 0.0), self.cfg.lambda_max)
        return self.lam

    # -- world model (its trainer's: core.sage.model_trainer) ---------------------------------------
    def world_model_ready(self) -> bool:
        return self.model_trainer is not None and self.model_trainer.ready()

    def maybe_fit_world_model(self) -> None:
        if self.model_trainer is not None and self.model_trainer.fit_due(self.buffer, self.env_steps):
            self.fit_world_model()

    def fit_world_model(self) -> FitReport | None:
        """Fit on the whole real buffer (which recalibrates κ and the τ bounds), measure F_0 on the fit's familiar
        states, and refresh the virtual buffer."""
        if self.model_trainer is None:
            return None
        report = self.model_trainer.fit(self.buffer, self.rollout_policy, self.env_steps)
        assert self.model_trainer.last_calibration is not None  # a fit always leaves one
        self.measure_fear_budget(self.model_trainer.last_calibration)
        self.info.update(wm_holdout_nll=report.holdout_nll, wm_holdout_mse=report.holdout_mse, wm_epochs=report.epochs)
        self.virtual_rollout()
        return report

    def maybe_virtual_rollout(self) -> None:
        if (
            self.virtual is not None
            and self.model_trainer is not None
            and self.model_trainer.rollout_due(self.env_steps)
        ):
            self.virtual_rollout()

    def virtual_rollout(self) -> None:
        """Roll the model m steps from real states under the current policy into D_virtual."""
        if self.virtual is None or self.model_trainer is None:
            return
        self.model_trainer.virtual_rollout(self.buffer, self.virtual, self.rollout_policy, self.env_steps)

    # -- gate --------------------------------------------------------------------------------------
    def make_gate(
        self,
        cfg: GateConfig | None = None,
        *,
        world_model: EnsembleWorldModel | None = None,
        state: Mapping[str, float] | None = None,
    ) -> SageGate:
        """A SAGE gate on this learner's (live) policy: every SAGE gate of a learner is built here, in training and
        for a loaded run (:meth:`core.agents.LoadedAgent.make_gate`, which resolves its overrides first).

        On the learner's own world model by default: the gate starts from the curiosity average the learner
        inherited for that model version and is the one its checkpoints save. ``world_model``: another one (a
        loaded run's, another run's), the gate then starting from ``state`` (:meth:`SageGate.state`) where given."""
        own = world_model is None
        model = self.world_model if own else world_model
        if model is None:
            raise ValueError(f"method {self.cfg.method!r} trains no world model, so it has no SAGE gate")
        gate = SageGate(model, self.gate_policy(), cfg or self.cfg.gate, encode=self.gate_encoder())
        if own:
            if self._inherited_gate is not None and self._inherited_gate[1] == model.version:
                gate.load_state(self._inherited_gate[0])
            self._gates.append(gate)
        elif state:
            gate.load_state(dict(state))
        return gate

    # -- demonstrations ----------------------------------------------------------------------------
    def pretrain(self, returns: np.ndarray | None = None) -> dict[str, float]:
        """Learn from the demonstrations in the buffer (intervention samples) before interacting:
        behaviour cloning of the actor, then (subclasses) critic-only steps; then fit the world model.
        ``returns``: discounted returns-to-go of the first ``len(returns)`` buffer rows (the demonstrations),
        which critics regress on first, so that values need not crawl back from the goal one TD step at a time."""
        stats: dict[str, float] = {}
        if self.buffer.takeover_count() > 0 and self.cfg.pretrain_bc_steps > 0:
            stats["pretrain_bc_loss"] = self.behaviour_clone(self.cfg.pretrain_bc_steps)
            self.warm = True
        self.refresh_acting()  # the fit's rollouts read the cloned policy
        if self.world_model is not None and len(self.buffer) >= 10:
            self.fit_world_model()
        self.info.update(stats)
        return stats

    def gate_encoder(self) -> Any:
        """How the gate turns the loop's actions into the world model's (None: they are already)."""
        return self.encode_action if self.encodes_actions else None

    # -- checkpoints -------------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        """Plain state dicts and tensors only (loadable with ``torch.load(weights_only=True)``): the modules the
        method declares, the world model, the gate's running state and the optimisers."""
        state: dict[str, Any] = {name: module.state_dict() for name, module in self._modules_for_state().items()}
        if self.world_model is not None:
            state["world_model"] = self.world_model.state_dict()
        if self._gates:
            state["gate"] = {k: torch.tensor(v) for k, v in self._gates[-1].state().items()}
        elif self._inherited_gate is not None and self._inherited_gate[1] == getattr(self.world_model, "version", -1):
            state["gate"] = {k: torch.tensor(v) for k, v in self._inherited_gate[0].items()}
        optimizers = self.declared_state().optimizers
        if optimizers:  # a warm start continues (Adam's moments and step), rather than restarts
            state["optimizers"] = {name: getattr(self, name).state_dict() for name in optimizers}
        if math.isfinite(self.measured_fear_budget):  # a warm start keeps it until its own first fit
            state["fear_budget"] = torch.tensor(self.measured_fear_budget)
        return to_cpu(state)  # device-free: a checkpoint loads on either

    def load_state_dict(self, state: dict[str, Any], strict: bool = True) -> list[str]:
        """Load what matches; returns the names of the parts loaded. ``strict`` refuses missing parts
        this learner needs (a warm start with ``strict=False`` takes what the checkpoint has)."""
        loaded: list[str] = []
        for name, module in self._modules_for_state().items():
            if name in state:
                if not strict and isinstance(module, EnsembleWorldModel) and not module.reads(state[name]):
                    continue  # a warm start from a model of another input layout or ego step: refit it
                if not strict and isinstance(module, EnsembleCritic) and not module.fits(state[name]):
                    # critics saved in another shape than this run asks for (without its layer norms, fewer members):
                    # what fits starts the new critics, which are then fitted to the saved ones (distil_critic)
                    module.warm_from(state[name])
                    if name == "critic":
                        self.critic_teacher = EnsembleCritic.like(state[name]).to(self.device).requires_grad_(False)
                    loaded.append(name)
                    continue
                module.load_state_dict(state[name])
                loaded.append(name)
            elif strict:
                raise KeyError(f"checkpoint has no {name!r} (it has {', '.join(sorted(state))})")
        loaded.extend(self._load_optimizers(state.get("optimizers", {}), strict))
        if self._captured is not None:
            self._captured.drop()  # new optimiser memory: capture again
        if "fear_budget" in state:
            self.measured_fear_budget = float(torch.as_tensor(state["fear_budget"]))
            loaded.append("fear_budget")
        if self.acting_module in loaded:
            self.warm = True
            self.refresh_acting()
        if self.model_trainer is not None and "world_model" in loaded:
            self.model_trainer.schedule_refit()  # refit on this run's data once there is enough of it
            if "gate" in state:
                saved = {k: float(torch.as_tensor(v)) for k, v in state["gate"].items()}
                self._inherited_gate = (saved, self.model_trainer.world_model.version)
        return loaded

    def _load_optimizers(self, saved: dict[str, Any], strict: bool) -> list[str]:
        """Restore the declared optimisers the checkpoint holds (older checkpoints hold none: fresh optimisers).
        The learning rates stay this run's configuration's; only the optimiser's memory is restored."""
        loaded: list[str] = []
        for name in self.declared_state().optimizers:
            if name not in saved:
                continue
            optimizer: torch.optim.Optimizer = getattr(self, name)
            # this run's rates and implementation (fused on the CPU, capturable for a CUDA graph), whatever the
            # checkpoint's run used: only the optimiser's memory is restored
            kept = [{k: group[k] for k in OPTIMIZER_SETTINGS if k in group} for group in optimizer.param_groups]
            try:
                check_state_shapes(optimizer, saved[name])
                optimizer.load_state_dict(saved[name])
            except (ValueError, KeyError) as exc:
                if strict:
                    raise ValueError(f"optimizer {name!r} does not fit this learner: {exc}") from None
                continue
            for group, settings in zip(optimizer.param_groups, kept, strict=True):
                group.update(settings)
            _place_step_counts(optimizer)
            loaded.append(f"optimizers.{name}")
        return loaded

    def _modules_for_state(self) -> dict[str, torch.nn.Module]:
        """Every declared module and the world model, by name (what checkpoints hold)."""
        modules: dict[str, torch.nn.Module] = {name: getattr(self, name) for name in self.declared_state().modules}
        if self.world_model is not None:
            modules["world_model"] = self.world_model
        return modules


class ActorLearner(BaseLearner):
    """A learner with a continuous, tanh-squashed actor (SAC, TD3, HG-DAgger share it)."""

    critic: EnsembleCritic
    critic_target: EnsembleCritic
    critic_optimizer: torch.optim.Optimizer
    """The critics and their optimiser, in the learners that have them (SAC, TD3; not HG-DAgger)."""

    def build_networks(self) -> None:
        self.actor = Actor(
            self.obs_dim, self.act_dim, self.cfg.hidden, self.cfg.layers, self.action_low, self.action_high
        ).to(self.device)
        self._policy: ActorPolicy | None = None

    @property
    def acting_actor(self) -> Actor:
        """The actor the loop and the gate read (:meth:`acting_network`: the trained one on the CPU)."""
        actor = self.acting_network()
        assert isinstance(actor, Actor)
        return actor

    def policy_action(self, obs: np.ndarray, deterministic: bool) -> np.ndarray:
        if self._policy is None:
            self._policy = ActorPolicy(self.acting_actor)
        return self._policy.act(obs, deterministic)

    def rollout_policy(self, obs: Tensor) -> Tensor:
        return self.acting_actor.deterministic(obs)

    def fear_policy(self, obs: Tensor) -> Tensor:
        return self.actor.deterministic(obs)

    def gate_policy(self) -> Actor | PolicyFn:
        return self.acting_actor  # the gate's preallocated fast path, always the current weights

    def distil_critic(self, updates: int) -> float | None:
        """Fit the critics to :attr:`critic_teacher` (the warm start's critics, saved in another shape: without the
        layer norms these have, or fewer members, member z learning saved member z mod their number) on the buffer's
        states, at the recorded actions and at the actor's, so that the critics keep what the checkpoint's learned
        before the first update trusts them; the targets then copy them and the teacher is dropped. Returns the last
        batch's mean squared error (None: no teacher, or fewer rows than a batch yet)."""
        teacher, critic = self.critic_teacher, self.critic
        if teacher is None or len(self.buffer) < self.cfg.batch_size:
            return None

        def rows() -> tuple[Tensor, Tensor]:
            batch = self.buffer.sample(self.cfg.batch_size, self.rng)
            with torch.no_grad():
                policy = self.actor.sample(batch.obs)[0]
            return torch.cat([batch.obs, batch.obs]), torch.cat([batch.action, policy])

        loss = fit_to_saved(critic, teacher, self.critic_optimizer, rows, updates, self.cfg.max_grad_norm)
        self.critic_target.load_state_dict(critic.state_dict())
        self.critic_teacher = None
        if self._captured is not None:
            self._captured.drop()  # the optimiser's memory was written outside the graph: capture again
        return loss

    def behaviour_clone(self, steps: int, lr: float = 1e-3) -> float:
        """Plain regression of the deterministic action onto the expert's (intervention samples)."""
        optimizer = torch.optim.Adam(self.actor.parameters(), lr=lr)
        loss = torch.tensor(math.nan)
        for _ in range(steps):
            batch = self.buffer.sample_takeovers(self.cfg.batch_size, self.rng)
            if batch is None:
                break
            loss = (self.actor.deterministic(batch.obs) - batch.a_expert).pow(2).sum(-1).mean()
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
        self.refresh_acting()
        return float(loss.detach())
