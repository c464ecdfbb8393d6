"""The ensemble world model: N probabilistic MLPs, each a diagonal Gaussian over (Δstate, cost).

Training (:meth:`EnsembleWorldModel.fit`) follows PETS (Chua et al. 2018): every member minimises the Gaussian
negative log-likelihood of the real transitions on its own bootstrap resample; log-variances are kept between
learnable soft bounds (``max_logvar - softplus(max_logvar - lv)`` then ``min_logvar + softplus(lv - min_logvar)``,
with a small penalty on ``max_logvar - min_logvar``); inputs and targets are normalised; a held-out split
drives early stopping (each member keeps its best held-out snapshot, as in MBPO).

The cost channel is a classifier, not a Gaussian: its output is the logit of "a violation happens at this
transition or within the next ``violation_steps``" (labels from the replay buffer's episodes,
:meth:`core.replay.ReplayBuffer.violation_soon`, joined by a dense safety cost as a soft label). Violations
are rare, and a Gaussian NLL head absorbs a rare binary target as variance and predicts "never" (measured:
0.008 vs 0.003). So each member minimises a class-balanced binary cross-entropy (positives weighted by
n_neg / n_pos), and the balancing's known shift of the logit, log(n_neg / n_pos), is taken back out of the
output bias afterwards (prior correction), so that sigmoid(logit) is a calibrated probability again: the
ĉ of eq:fear is the members' mean of it.

Normalisers are refitted at every fit, on all the data so far, and the first and last layers are rewritten
so that the network computes the same function under the new normalisers (an affine change of variables):
a model first fitted on violation-free demonstrations keeps learning when violations and new states arrive,
and a warm-started model keeps its meaning.

Uncertainty. The paper's σ̂ averages the members' own standard deviations. That is aleatoric noise: it
does not grow off the training distribution (a released predecessor used one random member's own std and
its fear was flat on novel inputs). We use the total predictive variance of the equally weighted mixture of
the members, per normalised state dimension d,

    var_d = mean_n σ²_{n,d}  +  var_n μ_{n,d}          (aleatoric  +  epistemic disagreement)

and σ_raw = mean_d sqrt(var_d). The disagreement term is what rises where the members were not trained.
Over a rollout each member propagates its own trajectory, so the disagreement of the predicted states also
carries the divergence accumulated over earlier steps (:func:`core.sage.fear.rollout`).

Inference. :meth:`EnsembleWorldModel.folded` returns the weights with the input normalisation folded into
the first layer and the output de-normalisation of the means folded into the last, cached until the model
changes, so that a gate step is a handful of ``baddbmm`` calls and no normalisation arithmetic.
"""

from __future__ import annotations

import copy
import dataclasses
import itertools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from core.motion import EgoScanStep, ScanAlignment, approach_rate
from core.sage.config import WorldModelConfig
from core.sage.networks import VectorizedLinear
from core.sage.novelty import NoveltyReference, fit_reference, novelty_features, novelty_width

if TYPE_CHECKING:
    from torch.nn.modules.module import _IncompatibleKeys  # what nn.Module.load_state_dict returns

STD_FLOOR = 1e-3
IN_STD_FLOOR = 1e-2
"""Input std floor: a constant (or binary, rarely set) observation channel must not blow up after normalising."""
MAX_POS_WEIGHT = 1000.0
"""Largest class-balancing weight of positive (violation-soon) samples."""
MAX_HORIZON = 16
"""Longest rollout whose per-step σ scale is stored (longer horizons reuse the last step's scale)."""


@dataclass
class FoldedModel:
    """Inference weights of the ensemble (see :meth:`EnsembleWorldModel.folded`); all plain tensors, no grad."""

    hidden: list[tuple[Tensor, Tensor]]
    """(weight (N, in, out), bias (N, 1, out)) of each hidden layer; the first takes raw (obs, action)."""
    out_weight: Tensor
    """(N, hidden, 2 (D + 1)): the first D + 1 columns give de-normalised (Δs, cost) means, the rest raw log-vars."""
    out_bias: Tensor
    max_logvar: Tensor
    min_logvar: Tensor
    inv_delta_var: Tensor
    """1 / std(Δs)² per state dim: converts state disagreement into normalised units."""
    inv_obs_std: Tensor
    """1 / std(s) per state dim: curiosity is measured on normalised states."""
    obs_dim: int
    members: int
    motion: bool
    """Whether the first layer also reads the last change of state (after obs and action)."""
    motion_lag: int
    """k of the motion input (s_t - s_{t-k}) / k (``WorldModelConfig.motion_lag``)."""
    sigma_scale: Tensor
    """(MAX_HORIZON,) scale κ_k of σ_raw at rollout step k on real states (:func:`core.sage.calibration.calibrate`)."""
    curiosity_ref: float
    """Mean one-step curiosity on held-out real transitions at the last fit (the curiosity EMA's start)."""
    scan: ScanAlignment | None = None
    """How the motion input turns the previous scan to the current heading (None: plain differences)."""
    approach: tuple[int, int] | None = None
    """Range channels [start, stop) whose approach rate the first layer also reads, after the motion (None: none)."""
    ego: EgoScanStep | None = None
    """The geometric step the predicted Δ is a residual over (None: Δ is the whole change)."""

    def base(self, state: Tensor, action: Tensor) -> Tensor:
        """What the predicted Δ is added to: the state, or with an ego step the state moved by it."""
        return state if self.ego is None else self.ego.apply(state, action)

    def to(self, device: torch.device) -> FoldedModel:
        """A copy with every tensor on ``device`` (the learner's update device: :mod:`core.device`)."""
        return dataclasses.replace(
            self,
            hidden=[(w.to(device), b.to(device)) for w, b in self.hidden],
            out_weight=self.out_weight.to(device),
            out_bias=self.out_bias.to(device),
            max_logvar=self.max_logvar.to(device),
            min_logvar=self.min_logvar.to(device),
            inv_delta_var=self.inv_delta_var.to(device),
            inv_obs_std=self.inv_obs_std.to(device),
            sigma_scale=self.sigma_scale.to(device),
        )


@dataclass
class FitReport:
    """What one call to :meth:`EnsembleWorldModel.fit` did."""

    epochs: int
    updates: int
    holdout_nll_before: float
    holdout_nll: float
    """Held-out NLL (mean over members) of the kept snapshot."""
    holdout_mse: float
    """Held-out MSE of the ensemble mean in normalised target units."""
    train_nll: list[float] = field(default_factory=list)
    holdout_history: list[float] = field(default_factory=list)


class EnsembleWorldModel(nn.Module):
    """N diagonal-Gaussian MLPs predicting (s_{t+1} - s_t, c_t) from (s_t, a_t), all members in one forward."""

    # registered buffers, described where __init__ registers them (nn.Module.__getattr__ would type them as
    # Tensor | Module)
    in_mean: Tensor
    in_std: Tensor
    out_mean: Tensor
    out_std: Tensor
    sigma_scale: Tensor
    curiosity_ref: Tensor
    disagreement_ref: Tensor
    novelty_states: Tensor
    novelty_center: Tensor
    novelty_scale: Tensor
    novelty_ref: Tensor
    fitted: Tensor
    pos_weight: Tensor
    tau_bounds: Tensor
    ego_geometry: Tensor

    def __init__(self, obs_dim: int, act_dim: int, cfg: WorldModelConfig) -> None:
        super().__init__()
        self.obs_dim, self.act_dim, self.cfg = obs_dim, act_dim, cfg
        self.members = cfg.members
        self.motion = bool(cfg.motion_input)
        self.motion_lag = int(cfg.motion_lag)
        self.scan = (
            ScanAlignment.of(cfg.scan_sectors, cfg.scan_turn_channel, cfg.scan_turn_sectors, obs_dim)
            if self.motion
            else None
        )
        """How the motion input turns the previous scan to the current heading (:mod:`core.motion`)."""
        self.approach = _approach_channels(cfg, obs_dim) if self.motion else None
        """Range channels [start, stop) whose approach rate is an input (:func:`core.motion.approach_rate`)."""
        self.ego = EgoScanStep.of(cfg, obs_dim, act_dim)
        """The geometric step of the scan under the robot's own motion; Δ is learned over it (None: no step)."""
        in_dim = obs_dim + act_dim + (obs_dim if self.motion else 0) + approach_width(self.approach)
        out_dim = obs_dim + 1
        dims = [in_dim] + [cfg.hidden] * cfg.layers
        self.hidden_layers = nn.ModuleList(VectorizedLinear(i, o, cfg.members) for i, o in itertools.pairwise(dims))
        self.out = VectorizedLinear(cfg.hidden, 2 * out_dim, cfg.members)
        self.max_logvar = nn.Parameter(torch.full((1, 1, out_dim), 0.5))
        self.min_logvar = nn.Parameter(torch.full((1, 1, out_dim), -10.0))
        self.register_buffer("in_mean", torch.zeros(in_dim))
        self.register_buffer("in_std", torch.ones(in_dim))
        self.register_buffer("out_mean", torch.zeros(out_dim))
        self.register_buffer("out_std", torch.ones(out_dim))
        self.register_buffer("sigma_scale", torch.ones(MAX_HORIZON))
        self.register_buffer("curiosity_ref", torch.tensor(1.0))
        self.register_buffer("disagreement_ref", torch.tensor(float("nan")))
        """The members' mean disagreement about the next state on the last calibration's states (NaN: not measured),
        the fixed reference of a gate with ``curiosity_signal="disagreement"``, ``curiosity_reference="fitted"``."""
        features = novelty_width(obs_dim, self.motion)
        self.register_buffer("novelty_states", torch.zeros(0, features))
        """The reference set of ``curiosity_signal="novelty"`` (:mod:`core.sage.novelty`): (K, F) calibration states'
        features, K <= REFERENCE_STATES; none until a calibration for that gate measures them."""
        self.register_buffer("novelty_center", torch.zeros(features))
        self.register_buffer("novelty_scale", torch.ones(features))
        """The calibration states' mean and spread per feature: the units novelty is measured in."""
        self.register_buffer("novelty_ref", torch.tensor(0.0))
        """The novelty's mean on calibration states held out of the set, its fixed reference (with no set: none)."""
        self.register_buffer("fitted", torch.tensor(False))
        self.register_buffer("pos_weight", torch.tensor(1.0))
        """Class-balancing weight of the last fit (n_neg / n_pos); log of it is taken out of the cost logit."""
        self.register_buffer("tau_bounds", torch.tensor([float("nan"), float("nan")]))
        """(τ_min, τ_max) from the fear of familiar states at the last calibration (NaN: use the config's)."""
        self.register_buffer("ego_geometry", self.ego.geometry() if self.ego is not None else torch.zeros(0))
        """The ego step's numbers (empty without one): a warm start from weights learned over another step, or over
        none, does not fit (:meth:`reads`) and is refitted."""
        self.version = 0
        self._folded: tuple[int, FoldedModel] | None = None
        self._optimizer: torch.optim.Optimizer | None = None

    # -- forward ---------------------------------------------------------------------------------
    def forward_normalised(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """(N, B, in) normalised inputs -> normalised means and bounded log-variances, both (N, B, D + 1)."""
        h = x
        for layer in self.hidden_layers:
            h = F.silu(layer(h))
        out = self.out(h)
        mean, raw_logvar = out.chunk(2, dim=-1)
        return mean, self.bound_logvar(raw_logvar)

    def bound_logvar(self, raw: Tensor) -> Tensor:
        logvar = self.max_logvar - F.softplus(self.max_logvar - raw)
        return self.min_logvar + F.softplus(logvar - self.min_logvar)

    def inputs(self, obs: Tensor, action: Tensor, motion: Tensor | None = None) -> Tensor:
        """The raw model input: (s, a) and, with ``motion_input``, the last change of state (zeros if unknown),
        then the approach rates of the range channels (``approach_*``)."""
        if not self.motion:
            return torch.cat([obs, action], dim=-1)
        motion = torch.zeros_like(obs) if motion is None else motion
        if self.approach is None:
            return torch.cat([obs, action, motion], dim=-1)
        return torch.cat([obs, action, motion, approach_rate(obs, motion, *self.approach)], dim=-1)

    def normalise_inputs(self, obs: Tensor, action: Tensor, motion: Tensor | None = None) -> Tensor:
        return (self.inputs(obs, action, motion) - self.in_mean) / self.in_std

    def predict(self, obs: Tensor, action: Tensor, motion: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """Per-member de-normalised means (N, B, D + 1) of (Δs, violation logit) and log-variances in normalised
        units; ``motion``: s_t - s_{t-1} (the model's motion input; zeros when None)."""
        x = self.normalise_inputs(obs, action, motion)
        x = x.unsqueeze(0).expand(self.members, *x.shape) if x.dim() == 2 else x
        mean, logvar = self.forward_normalised(x)
        return mean * self.out_std + self.out_mean, logvar

    @torch.no_grad()
    def disagreement(self, obs: Tensor, action: Tensor, motion: Tensor | None = None) -> Tensor:
        """Per sample, the members' spread about the next state: sqrt(mean_d var_n(Δ_n,d) / std(Δ_d)²), the
        epistemic part of :meth:`predictive_std` alone (a mover's unpredictability, which every member learned
        alike, does not raise it; a state unlike the training data does)."""
        mean, _ = self.predict(obs, action, motion)
        return self._members_variance(mean).mean(-1).sqrt()

    def novelty_reference(self) -> NoveltyReference | None:
        """The reference set ready to score states (:mod:`core.sage.novelty`); None until a calibration measured it."""
        if not len(self.novelty_states):
            return None
        return NoveltyReference.of(self.novelty_states.float(), self.novelty_center.float(), self.novelty_scale.float())

    @torch.no_grad()
    def set_novelty_reference(self, obs: Tensor, motion: Tensor | None = None) -> None:
        """Measure the state novelty's reference set, units and mean on these (calibration) states."""
        states, center, scale, mean = fit_reference(novelty_features(obs, motion, self.motion).float())
        self.novelty_states = states
        self.novelty_center.copy_(center)
        self.novelty_scale.copy_(scale)
        self.novelty_ref.fill_(mean)

    def _members_variance(self, mean: Tensor) -> Tensor:
        """(B, D) the members' variance of the predicted Δs per state channel, in units of the Δ's std."""
        delta = mean[..., : self.obs_dim]
        return (delta - delta.mean(0, keepdim=True)).square().mean(0) / self.out_std[: self.obs_dim].pow(2)

    def predictive_std(self, obs: Tensor, action: Tensor, motion: Tensor | None = None) -> Tensor:
        """The state mixture's std per sample: mean over normalised state dims of sqrt(mean σ² + var μ)."""
        mean, logvar = self.predict(obs, action, motion)
        aleatoric = logvar[..., : self.obs_dim].exp().mean(0)
        return (self._members_variance(mean) + aleatoric).sqrt().mean(-1)

    # -- training --------------------------------------------------------------------------------
    def _nll(self, x: Tensor, y: Tensor, pos_weight: Tensor | None = None) -> Tensor:
        """Per-member loss, shape (N,): Gaussian NLL (without the constant) of the Δ-state dims averaged over
        samples and dims, plus the class-balanced binary cross-entropy of the violation logit."""
        mean, logvar = self.forward_normalised(x)
        d = self.obs_dim
        state = 0.5 * (((mean[..., :d] - y[..., :d]) ** 2) * torch.exp(-logvar[..., :d]) + logvar[..., :d])
        weight = self.pos_weight if pos_weight is None else pos_weight
        bce = F.binary_cross_entropy_with_logits(
            mean[..., d] + self._logit_offset(), y[..., d], pos_weight=weight, reduction="none"
        )
        return state.mean(dim=(1, 2)) + bce.mean(dim=1)

    def _logit_offset(self) -> Tensor:
        """The balancing shift log(pos_weight): training sees logit + it, inference the bare (calibrated) logit."""
        return torch.log(self.pos_weight.clamp_min(1.0))

    def fit(
        self,
        obs: np.ndarray,
        action: np.ndarray,
        next_obs: np.ndarray,
        cost: np.ndarray,
        rng: np.random.Generator,
        violation_soon: np.ndarray | None = None,
        motion: np.ndarray | None = None,
        conflict: np.ndarray | None = None,
    ) -> FitReport:
        """Train on real transitions with a held-out split; keep each member's best held-out snapshot.

        ``violation_soon``: the classifier's labels (1 when a violation happens within the next
        ``violation_steps``), joined by the clipped ``cost`` times ``cost_label_weight`` as a soft label (a dense
        cost warns earlier) and by the simulator's ``conflict`` flags times ``conflict_label_weight``.
        The normalisers are refitted on this data first, preserving the function the network computes (see the
        module docstring).
        """
        cfg = self.cfg
        n = len(obs)
        if n < 10:
            raise ValueError(f"world model fit needs at least 10 transitions, got {n}")
        # a dense safety cost (the UGV's proximity cost) is a graded early warning: it joins the label as a soft
        # target; a binary cost equals the violation flag and adds nothing
        label = cfg.cost_label_weight * np.clip(cost, 0.0, 1.0)
        if violation_soon is not None:
            label = np.maximum(label, np.clip(violation_soon, 0.0, 1.0))
        if conflict is not None and cfg.conflict_label_weight > 0:
            label = np.maximum(label, cfg.conflict_label_weight * np.clip(conflict, 0.0, 1.0))
        label = label.astype(np.float32)
        inputs = self.inputs(
            torch.as_tensor(obs, dtype=torch.float32),
            torch.as_tensor(action, dtype=torch.float32),
            None if motion is None else torch.as_tensor(motion, dtype=torch.float32),
        )
        with torch.no_grad():
            base = self.base(inputs[:, : self.obs_dim], inputs[:, self.obs_dim : self.obs_dim + self.act_dim]).numpy()
        targets = torch.as_tensor(np.concatenate([next_obs - base, label[:, None]], axis=1), dtype=torch.float32)
        perm = rng.permutation(n)
        n_hold = max(1, min(int(n * cfg.holdout_ratio), cfg.max_holdout))
        hold, train = perm[:n_hold], perm[n_hold:]
        self.renormalise(inputs[train], targets[train])
        positives = float(targets[train, self.obs_dim].sum())
        negatives = float(len(train)) - positives
        with torch.no_grad():
            new_weight = min(max(negatives / max(positives, 1e-6), 1.0), MAX_POS_WEIGHT) if positives > 0 else 1.0
            # the network's output stays the calibrated logit: only the training-time shift log(w) changes
            self.pos_weight.fill_(new_weight)
            if not bool(self.fitted):
                # start the violation logit at the base rate (a rare class learns slowly from logit 0)
                rate = min(max(positives / max(len(train), 1), 1e-3), 0.5)
                self.out.bias[..., self.obs_dim] = float(np.log(rate / (1.0 - rate)))
        x = (inputs - self.in_mean) / self.in_std
        y = (targets - self.out_mean) / self.out_std
        x_hold = x[hold].unsqueeze(0).expand(self.members, -1, -1)
        y_hold = y[hold].unsqueeze(0).expand(self.members, -1, -1)
        if self._optimizer is None:
            decay = [p for layer in [*self.hidden_layers, self.out] for p in [layer.weight]]
            rest = [p for name, p in self.named_parameters() if not name.endswith("weight")]
            self._optimizer = torch.optim.Adam(
                [{"params": decay, "weight_decay": cfg.weight_decay}, {"params": rest, "weight_decay": 0.0}],
                lr=cfg.lr,
            )
        optimizer = self._optimizer

        def holdout_nll() -> Tensor:
            with torch.no_grad():
                return self._nll(x_hold, y_hold)

        best = holdout_nll()
        before = float(best.mean())
        snapshot = copy.deepcopy(self.state_dict())
        bootstrap = torch.as_tensor(rng.integers(0, len(train), size=(self.members, len(train))))
        train_t = torch.as_tensor(train)
        report = FitReport(0, 0, before, before, float("nan"))
        since_improved = 0
        for epoch in range(cfg.max_epochs):
            order = bootstrap[:, torch.randperm(len(train), generator=_torch_generator(rng))]
            epoch_loss = []
            for start in range(0, len(train), cfg.batch_size):
                idx = train_t[order[:, start : start + cfg.batch_size]]
                loss = self._nll(x[idx], y[idx]).sum()
                loss = loss + cfg.logvar_bound_weight * (self.max_logvar.sum() - self.min_logvar.sum())
                optimizer.zero_grad(set_to_none=True)
                loss.backward()
                optimizer.step()
                report.updates += 1
                epoch_loss.append(float(loss.detach()) / self.members)
                if report.updates >= cfg.max_updates_per_fit:
                    break
            report.epochs = epoch + 1
            report.train_nll.append(float(np.mean(epoch_loss)))
            current = holdout_nll()
            report.holdout_history.append(float(current.mean()))
            improved = current < best - 1e-3 * best.abs().clamp_min(1e-3)
            if bool(improved.any()):
                state = self.state_dict()
                for name in self._member_parameter_names():
                    # stacked member parameters have the member axis first; copy only improved members
                    snapshot[name][improved] = state[name][improved]
                best = torch.where(improved, current, best)
                since_improved = 0
            else:
                since_improved += 1
            if since_improved > cfg.patience or report.updates >= cfg.max_updates_per_fit:
                break
        optimizer.zero_grad(set_to_none=True)  # leave no gradients behind: the frozen model must not hold any
        # the learnable log-var bounds and normalisers are shared, keep their latest values
        for name in ("max_logvar", "min_logvar"):
            snapshot[name] = self.state_dict()[name]
        self.load_state_dict(snapshot)
        with torch.no_grad():
            final = self._nll(x_hold, y_hold)
            mean, _ = self.forward_normalised(x_hold)
            report.holdout_nll = float(final.mean())
            report.holdout_mse = float(((mean.mean(0)[:, : self.obs_dim] - y[hold, : self.obs_dim]) ** 2).mean())
            self.fitted.fill_(True)
            d, a = self.obs_dim, self.act_dim
            hold_obs, hold_action = inputs[hold, :d], inputs[hold, d : d + a]
            hold_motion = inputs[hold, d + a : 2 * d + a] if self.motion else None
            hold_next = torch.as_tensor(next_obs[hold], dtype=torch.float32)
            self.curiosity_ref.fill_(float(self.curiosity(hold_obs, hold_action, hold_next, hold_motion).mean()))
        self.touch()
        return report

    @torch.no_grad()
    def renormalise(self, inputs: Tensor, targets: Tensor) -> None:
        """Set the normalisers from this data and rewrite the first and last layers so that the network's
        de-normalised outputs are unchanged (an exact affine change of variables). The violation logit is not
        normalised (mean 0, std 1): it is a logit."""
        d = self.obs_dim
        in_mean, in_std = inputs.mean(0), inputs.std(0).clamp_min(IN_STD_FLOOR)
        out_mean, out_std = targets.mean(0), targets.std(0).clamp_min(STD_FLOOR)
        out_mean[d], out_std[d] = 0.0, 1.0
        self.set_normalisers(in_mean, in_std, out_mean, out_std)

    @torch.no_grad()
    def set_normalisers(self, in_mean: Tensor, in_std: Tensor, out_mean: Tensor, out_std: Tensor) -> None:
        """Take these normalisers; a fitted model's first and last layers are rewritten so that it computes the
        same function (an unfitted one has no function to keep)."""
        d = self.obs_dim
        if bool(self.fitted):
            first = self.hidden_layers[0]
            assert isinstance(first, VectorizedLinear)  # every hidden layer is one (__init__)
            # x_old = (x - m_old) / s_old = x_new * (s_new / s_old) + (m_new - m_old) / s_old
            scale = in_std / self.in_std
            shift = (in_mean - self.in_mean) / self.in_std
            first.bias.add_(torch.matmul(shift.view(1, 1, -1), first.weight))
            first.weight.mul_(scale.view(1, -1, 1))
            # y_new = (y_old * s_old + m_old - m_new) / s_new, for the means; log-vars shift by 2 log(s_old / s_new)
            ratio = self.out_std / out_std
            offset = (self.out_mean - out_mean) / out_std
            out = self.out
            out.weight[..., : d + 1] *= ratio.view(1, 1, -1)
            out.bias[..., : d + 1] = out.bias[..., : d + 1] * ratio.view(1, 1, -1) + offset.view(1, 1, -1)
            log_ratio = 2.0 * torch.log(ratio)
            out.bias[..., d + 1 :] += log_ratio.view(1, 1, -1)
            self.max_logvar.add_(log_ratio.view(1, 1, -1))
            self.min_logvar.add_(log_ratio.view(1, 1, -1))
        self.in_mean.copy_(in_mean)
        self.in_std.copy_(in_std)
        self.out_mean.copy_(out_mean)
        self.out_std.copy_(out_std)
        self._optimizer = None  # Adam's moments were for the old parametrisation
        self.touch()

    def _member_parameter_names(self) -> list[str]:
        layers = [f"hidden_layers.{i}" for i in range(len(self.hidden_layers))] + ["out"]
        return [f"{layer}.{kind}" for layer in layers for kind in ("weight", "bias")]

    def base(self, obs: Tensor, action: Tensor) -> Tensor:
        """What the predicted Δ is added to: the state, or with an ego step the state moved by it."""
        return obs if self.ego is None else self.ego.apply(obs, action)

    def curiosity(self, obs: Tensor, action: Tensor, next_obs: Tensor, motion: Tensor | None = None) -> Tensor:
        """C = ||ŝ_{t+1} - s_{t+1}||₂ on normalised states, ŝ the ensemble-mean prediction (eq:curiosity)."""
        mean, _ = self.predict(obs, action, motion)
        predicted = self.base(obs, action) + mean[..., : self.obs_dim].mean(0)
        return ((predicted - next_obs) / self.in_std[: self.obs_dim]).norm(dim=-1)

    # -- inference weights -----------------------------------------------------------------------
    def touch(self) -> None:
        """Mark the weights as changed (invalidates :meth:`folded`)."""
        self.version += 1

    def reads(self, state_dict: dict[str, Tensor]) -> bool:
        """Whether a saved state fits this model tensor for tensor (names and shapes) and was learned over the same
        ego step (a state from before the step was an option learned over none)."""
        own = self.state_dict()
        saved_geometry = state_dict.get("ego_geometry", torch.zeros(0))
        # a checkpoint is read back in float32 (core.agents.load_checkpoint), and a file halved to float16 before
        # its float64 tensors were kept holds the numbers to float16's precision: equal to that
        if saved_geometry.shape != self.ego_geometry.shape or not torch.allclose(
            saved_geometry.double(), self.ego_geometry.double(), rtol=1e-3, atol=1e-6
        ):
            return False
        return all(
            tuple(state_dict[k].shape) == tuple(v.shape)
            for k, v in own.items()
            if k in state_dict and k != "novelty_states"  # as many rows as its calibration kept
        ) and all(k in own for k in state_dict)

    def load_state_dict(
        self, state_dict: Mapping[str, Any], strict: bool = True, assign: bool = False
    ) -> _IncompatibleKeys:
        if "ego_geometry" not in state_dict:  # saved before the ego step was an option: learned over none
            state_dict = {**state_dict, "ego_geometry": torch.zeros(0)}
        if "disagreement_ref" not in state_dict:  # saved before it was measured: unknown until a calibration
            state_dict = {**state_dict, "disagreement_ref": torch.tensor(float("nan"))}
        state_dict = {**unmeasured_novelty(self.novelty_center.shape[0]), **state_dict}  # saved before the option
        # the reference set has as many rows as its calibration kept: take the saved shape
        own = self.novelty_states
        self.novelty_states = torch.zeros(state_dict["novelty_states"].shape, dtype=own.dtype, device=own.device)
        if "pos_weight" not in state_dict and "out.bias" in state_dict:
            # a checkpoint from before the violation classifier: its cost column was a Gaussian regression, which
            # means nothing as a logit. Keep its dynamics and uncertainty; its ĉ says "no violation known" until
            # the next fit (refit it, or retrain the policy)
            state_dict = dict(state_dict)
            d = self.obs_dim
            weight, bias = state_dict["out.weight"].clone(), state_dict["out.bias"].clone()
            weight[..., d] = 0.0
            bias[..., d] = float(np.log(1e-3 / (1 - 1e-3)))
            state_dict["out.weight"], state_dict["out.bias"] = weight, bias
            out_mean, out_std = state_dict["out_mean"].clone(), state_dict["out_std"].clone()
            out_mean[d], out_std[d] = 0.0, 1.0
            state_dict["out_mean"], state_dict["out_std"] = out_mean, out_std
            state_dict["pos_weight"] = torch.tensor(1.0)
            state_dict["tau_bounds"] = torch.tensor([float("nan"), float("nan")])
        result = super().load_state_dict(state_dict, strict=strict, assign=assign)
        if self.ego is not None:  # the config's numbers, exact, whatever precision the file kept
            self.ego_geometry.copy_(self.ego.geometry())
        self.touch()
        return result

    def folded(self) -> FoldedModel:
        """Inference weights with the normalisation folded in (cached until :meth:`touch`)."""
        if self._folded is not None and self._folded[0] == self.version:
            return self._folded[1]
        d = self.obs_dim
        # never inference tensors, even when the gate asks first: the learner's autograd reads them too
        with torch.inference_mode(False), torch.no_grad():
            hidden: list[tuple[Tensor, Tensor]] = []
            for i, layer in enumerate(self.hidden_layers):
                assert isinstance(layer, VectorizedLinear)  # every hidden layer is one (__init__)
                w, b = layer.weight.detach().clone(), layer.bias.detach().clone()
                if i == 0:
                    # ((x - m) / s) W + b  =  x (W / s) + (b - (m / s) W)
                    w = w / self.in_std.view(1, -1, 1)
                    b = b - torch.matmul((self.in_mean / self.in_std).view(1, 1, -1), layer.weight)
                hidden.append((w.contiguous(), b.contiguous()))
            ow, ob = self.out.weight.detach().clone(), self.out.bias.detach().clone()
            ow[..., : d + 1] *= self.out_std.view(1, 1, -1)
            ob[..., : d + 1] = ob[..., : d + 1] * self.out_std.view(1, 1, -1) + self.out_mean.view(1, 1, -1)
            folded = FoldedModel(
                hidden=hidden,
                out_weight=ow.contiguous(),
                out_bias=ob.contiguous(),
                max_logvar=self.max_logvar.detach().clone()[..., :d],
                min_logvar=self.min_logvar.detach().clone()[..., :d],
                inv_delta_var=self.out_std[:d].pow(-2).clone(),
                inv_obs_std=self.in_std[:d].reciprocal().clone(),
                obs_dim=d,
                members=self.members,
                motion=self.motion,
                motion_lag=self.motion_lag,
                scan=self.scan,
                approach=self.approach,
                ego=self.ego,
                sigma_scale=self.sigma_scale.clone(),
                curiosity_ref=float(self.curiosity_ref),
            )
        self._folded = (self.version, folded)
        return folded


def with_approach_input(model: EnsembleWorldModel, approach: tuple[int, int]) -> EnsembleWorldModel:
    """A copy of ``model`` (fitted, with the motion input and without the approach input) that also reads the approach
    rates of the range channels ``approach`` = [start, stop) (``world_model_config.approach_*``) with zero weights: the
    same function, now in an ensemble's shape that models with the input share (:func:`merge_ensembles`). The new
    inputs' normalisers are 0 and 1; their weights stay 0 until a fit moves them."""
    if model.approach is not None:
        raise ValueError(f"the world model already reads the approach rates of channels {model.approach}")
    if not model.motion:
        raise ValueError("the approach input needs the motion input (world_model_config.motion_input)")
    cfg = dataclasses.replace(model.cfg, approach_start=approach[0], approach_stop=approach[1])
    wide = EnsembleWorldModel(model.obs_dim, model.act_dim, cfg)
    width = approach_width(wide.approach)
    state = {name: value.detach().clone() for name, value in model.state_dict().items()}
    weight = state["hidden_layers.0.weight"]  # (N, in, H): the approach inputs come last
    state["hidden_layers.0.weight"] = torch.cat([weight, weight.new_zeros(weight.shape[0], width, weight.shape[2])], 1)
    state["in_mean"] = torch.cat([state["in_mean"], state["in_mean"].new_zeros(width)])
    state["in_std"] = torch.cat([state["in_std"], state["in_std"].new_ones(width)])
    wide.load_state_dict(state)
    return wide


def merge_ensembles(models: Sequence[EnsembleWorldModel]) -> EnsembleWorldModel:
    """One ensemble holding every member of ``models`` (bagging over refits: fits on different draws of the
    data, whose errors in the timing of a warning partly cancel in the members' mean).

    The models must share their shape and configuration but for ``members``, and for the approach input: where some
    read it (all over the same channels) and others do not, those are widened to read it with zero weights
    (:func:`with_approach_input`), computing what they computed. Each is first moved, exactly, to
    the first one's normalisers (:meth:`EnsembleWorldModel.set_normalisers`), so that every member computes what
    it computed in its own model; the shared soft log-variance bounds become the widest of them. κ and the τ bounds
    are left unset (NaN): they belong to the new ensemble, so recalibrate it (:func:`core.sage.calibration.calibrate`).
    ``curiosity_ref``, the curiosity EMA's starting value, is the mean of the models'.
    """
    if len(models) < 2:
        raise ValueError(f"merging needs at least two world models, got {len(models)}")
    approaches = {model.approach for model in models if model.approach is not None}
    if len(approaches) > 1:
        raise ValueError(f"the world models read the approach rates of different channels: {sorted(approaches)}")
    if approaches:
        approach = approaches.pop()
        models = [
            with_approach_input(m, approach) if m.approach is None and m.motion and bool(m.fitted) else m
            for m in models
        ]
    first = models[0]
    shape = (first.obs_dim, first.act_dim)
    base_cfg = dataclasses.replace(first.cfg, members=0)
    for i, model in enumerate(models[1:], start=2):
        if (model.obs_dim, model.act_dim) != shape:
            raise ValueError(
                f"world model {i} predicts {model.obs_dim} states from {model.act_dim} actions, the first "
                f"{shape[0]} from {shape[1]}: merge only models of one policy"
            )
        differing = [
            f.name
            for f in dataclasses.fields(base_cfg)
            if getattr(dataclasses.replace(model.cfg, members=0), f.name) != getattr(base_cfg, f.name)
        ]
        if differing:
            raise ValueError(f"world model {i}'s config differs from the first's in {', '.join(differing)}")
        if not bool(model.fitted):
            raise ValueError(f"world model {i} was never fitted")
    if not bool(first.fitted):
        raise ValueError("world model 1 was never fitted")
    moved = []
    for model in models:
        twin = copy.deepcopy(model)
        twin.set_normalisers(first.in_mean, first.in_std, first.out_mean, first.out_std)
        moved.append(twin)
    members = sum(m.members for m in models)
    merged = EnsembleWorldModel(first.obs_dim, first.act_dim, dataclasses.replace(first.cfg, members=members))
    state = {name: value.clone() for name, value in first.state_dict().items()}
    for name in first._member_parameter_names():
        state[name] = torch.cat([twin.state_dict()[name] for twin in moved], dim=0)
    state["max_logvar"] = torch.stack([twin.max_logvar.detach() for twin in moved]).amax(0)
    state["min_logvar"] = torch.stack([twin.min_logvar.detach() for twin in moved]).amin(0)
    state["curiosity_ref"] = torch.stack([m.curiosity_ref for m in models]).mean()
    state["disagreement_ref"] = torch.tensor(float("nan"))  # the union's members disagree anew: calibrate it
    state.update(unmeasured_novelty(first.novelty_center.shape[0]))  # measured again on the union's calibration
    state["sigma_scale"] = torch.ones(MAX_HORIZON)
    state["tau_bounds"] = torch.tensor([float("nan"), float("nan")])
    merged.load_state_dict(state)
    return merged


def unmeasured_novelty(features: int) -> dict[str, Tensor]:
    """The novelty buffers of a model whose calibration never measured them (:mod:`core.sage.novelty`)."""
    return {
        "novelty_states": torch.zeros(0, features),
        "novelty_center": torch.zeros(features),
        "novelty_scale": torch.ones(features),
        "novelty_ref": torch.tensor(0.0),
    }


def _approach_channels(cfg: WorldModelConfig, obs_dim: int) -> tuple[int, int] | None:
    """The config's approach channels, checked against the observation (None when off)."""
    start, stop = int(cfg.approach_start), int(cfg.approach_stop)
    if stop <= start:
        return None
    if not 0 <= start < stop <= obs_dim:
        raise ValueError(
            f"world_model_config.approach_start..approach_stop must lie within the {obs_dim} observation channels, "
            f"got {start}..{stop}"
        )
    return (start, stop)


def approach_width(approach: tuple[int, int] | None) -> int:
    """How many approach-rate inputs the first layer reads."""
    return 0 if approach is None else approach[1] - approach[0]


def _torch_generator(rng: np.random.Generator) -> torch.Generator:
    return torch.Generator().manual_seed(int(rng.integers(0, 2**31 - 1)))
