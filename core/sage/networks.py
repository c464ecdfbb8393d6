"""Networks shared by every learner: a batched ensemble of linear layers, the critic ensemble and the actor.

Ensembles keep their members' weights stacked, shape ``(members, in, out)``, and run all members in one
``torch.baddbmm``; a Python loop over members costs several times more on a CPU (see bench/bench_gate.py).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Mapping

import torch
from torch import Tensor, nn
from torch.nn import functional as F

LOG_STD_MIN, LOG_STD_MAX = -5.0, 2.0


class VectorizedLinear(nn.Module):
    """``members`` independent linear layers applied to a ``(members, batch, in)`` input in one baddbmm."""

    def __init__(self, in_features: int, out_features: int, members: int) -> None:
        super().__init__()
        self.in_features, self.out_features, self.members = in_features, out_features, members
        self.weight = nn.Parameter(torch.empty(members, in_features, out_features))
        self.bias = nn.Parameter(torch.empty(members, 1, out_features))
        self.reset_parameters()

    def reset_parameters(self) -> None:
        # the default initialisation of nn.Linear, member by member
        bound = 1.0 / math.sqrt(self.in_features)
        for n in range(self.members):
            nn.init.kaiming_uniform_(self.weight[n].T, a=math.sqrt(5))
        nn.init.uniform_(self.bias, -bound, bound)

    def forward(self, x: Tensor) -> Tensor:
        return torch.baddbmm(self.bias, x, self.weight)


class VectorizedLayerNorm(nn.Module):
    """``members`` independent layer norms over the last dimension of a ``(members, batch, features)`` input, each
    with its own gain and shift (initialised to 1 and 0, as ``nn.LayerNorm``)."""

    def __init__(self, features: int, members: int, eps: float = 1e-5) -> None:
        super().__init__()
        self.features, self.eps = features, eps
        self.weight = nn.Parameter(torch.ones(members, 1, features))
        self.bias = nn.Parameter(torch.zeros(members, 1, features))

    def forward(self, x: Tensor) -> Tensor:
        return torch.addcmul(self.bias, F.layer_norm(x, (self.features,), eps=self.eps), self.weight)


class EnsembleCritic(nn.Module):
    """Z action-value networks Q_z(s, a) evaluated together; ``forward`` returns ``(Z, batch)``. With
    ``layer_norm`` each hidden layer is normalised before its ReLU (RLPD's critic: bounded features keep the values
    of actions far from the data from running away)."""

    def __init__(
        self, obs_dim: int, act_dim: int, hidden: int, layers: int, members: int, layer_norm: bool = False
    ) -> None:
        super().__init__()
        self.members = members
        dims = [obs_dim + act_dim] + [hidden] * layers
        self.hidden = nn.ModuleList(VectorizedLinear(i, o, members) for i, o in itertools.pairwise(dims))
        self.norms = nn.ModuleList(VectorizedLayerNorm(hidden, members) for _ in range(layers)) if layer_norm else None
        self.out = VectorizedLinear(hidden, 1, members)

    @property
    def layer_norm(self) -> bool:
        return self.norms is not None

    def forward(self, obs: Tensor, action: Tensor) -> Tensor:
        x = torch.cat([obs, action], dim=-1)
        x = x.unsqueeze(0).expand(self.members, *x.shape) if x.dim() == 2 else x
        for k, layer in enumerate(self.hidden):
            x = layer(x)
            if self.norms is not None:
                x = self.norms[k](x)
            x = torch.relu(x)
        return self.out(x).squeeze(-1)

    def fits(self, state: Mapping[str, Tensor]) -> bool:
        """Whether ``state`` is a critic of this one's shape (names and sizes: members, layers, norms)."""
        own = self.state_dict()
        return set(state) == set(own) and all(tuple(state[k].shape) == tuple(v.shape) for k, v in own.items())

    def warm_from(self, state: Mapping[str, Tensor]) -> None:
        """Start from a saved critic of another shape: its linear weights where they fit (the same members, with or
        without norms), this critic's own initialisation elsewhere."""
        own = self.state_dict()
        fitting = {k: v for k, v in state.items() if k in own and tuple(v.shape) == tuple(own[k].shape)}
        self.load_state_dict(fitting, strict=False)

    @staticmethod
    def like(state: Mapping[str, Tensor]) -> EnsembleCritic:
        """A critic of a saved state's shape (members, widths, layers, norms) holding it."""
        first = state["hidden.0.weight"]
        members, in_features, hidden = (int(n) for n in first.shape)
        layers = sum(1 for k in state if k.startswith("hidden.") and k.endswith(".weight"))
        norms = any(k.startswith("norms.") for k in state)
        critic = EnsembleCritic(in_features, 0, hidden, layers, members, layer_norm=norms)
        critic.load_state_dict(dict(state))
        return critic


class Actor(nn.Module):
    """Tanh-squashed Gaussian policy (SAC). TD3 and HG-DAgger use its deterministic path ``tanh(mean)``,
    so one checkpoint can warm-start every method."""

    # registered buffers (nn.Module.__getattr__ would type them as Tensor | Module)
    action_scale: Tensor
    action_bias: Tensor

    def __init__(
        self, obs_dim: int, act_dim: int, hidden: int, layers: int, action_low: Tensor, action_high: Tensor
    ) -> None:
        super().__init__()
        dims = [obs_dim] + [hidden] * layers
        blocks: list[nn.Module] = []
        for i, o in itertools.pairwise(dims):
            blocks += [nn.Linear(i, o), nn.ReLU()]
        self.trunk = nn.Sequential(*blocks)
        self.mean = nn.Linear(hidden, act_dim)
        self.log_std = nn.Linear(hidden, act_dim)
        self.register_buffer("action_scale", (action_high - action_low) / 2.0)
        self.register_buffer("action_bias", (action_high + action_low) / 2.0)

    def forward(self, obs: Tensor) -> tuple[Tensor, Tensor]:
        h = self.trunk(obs)
        return self.mean(h), self._log_std(h)

    def _log_std(self, h: Tensor) -> Tensor:
        log_std = torch.tanh(self.log_std(h))
        return LOG_STD_MIN + 0.5 * (LOG_STD_MAX - LOG_STD_MIN) * (log_std + 1.0)

    def deterministic(self, obs: Tensor) -> Tensor:
        """The mode of the squashed Gaussian, in the env's action units."""
        return torch.tanh(self.mean(self.trunk(obs))) * self.action_scale + self.action_bias

    def deterministic_layers(self) -> list[tuple[Tensor, Tensor]]:
        """(weight, bias) of the linear layers on the deterministic path (ReLU between, tanh after)."""
        linears = [m for m in self.trunk if isinstance(m, nn.Linear)] + [self.mean]
        return [(m.weight, m.bias) for m in linears]

    def sample(self, obs: Tensor) -> tuple[Tensor, Tensor]:
        """A reparameterised sample and its log-probability (with the tanh change of variables)."""
        return self._sampled(*self(obs))

    def sample_with_modes(self, obs: Tensor, *others: Tensor) -> tuple[Tensor, Tensor, list[Tensor]]:
        """:meth:`sample` of ``obs`` and :meth:`deterministic` of each of ``others``, from one pass of the trunk over
        all their rows (one forward and one backward of its layers instead of one per batch: the SAGE-SAC actor loss's
        imitation term, issue 63). The same values up to the float32 rounding of products over more rows, and the same
        draws of the random generator as :meth:`sample` alone."""
        if not others:
            return *self.sample(obs), []
        rows = len(obs)
        h = self.trunk(torch.cat([obs, *others]))
        mean = self.mean(h)
        action, log_prob = self._sampled(mean[:rows], self._log_std(h[:rows]))
        modes = torch.tanh(mean[rows:]) * self.action_scale + self.action_bias
        return action, log_prob, list(modes.split([len(o) for o in others]))

    def _sampled(self, mean: Tensor, log_std: Tensor) -> tuple[Tensor, Tensor]:
        std = log_std.exp()
        noise = torch.randn_like(mean)
        u = mean + std * noise
        y = torch.tanh(u)
        log_prob = (-0.5 * noise.pow(2) - log_std - 0.5 * math.log(2 * math.pi)).sum(-1)
        log_prob = log_prob - torch.log(self.action_scale * (1 - y.pow(2)) + 1e-6).sum(-1)
        return y * self.action_scale + self.action_bias, log_prob


def soft_update(target: nn.Module, source: nn.Module, tau: float) -> None:
    """target ← target + τ (source - target), every parameter in one foreach call (a loop of lerp_ per tensor costs a
    dispatch each; the values are the same)."""
    with torch.no_grad():
        # list[Tensor]: the foreach ops take tensors, and list is invariant in its item type (Parameter is one)
        targets: list[Tensor] = list(target.parameters())
        sources: list[Tensor] = list(source.parameters())
        if len(targets) != len(sources):
            raise ValueError(f"soft_update: {len(targets)} target parameters, {len(sources)} source parameters")
        torch._foreach_lerp_(targets, sources, tau)


def adam(params: Iterable[Tensor], lr: float, capturable: bool = False) -> torch.optim.Adam:
    """The update's Adam: ``fused`` (one kernel over every tensor: ~6% of a SAC update on one CPU thread, measured
    with bench/bench_sac.py), also ``capturable`` (its step count on the device, no host sync) for an update captured
    as a CUDA graph (:mod:`core.sage.captured`). The captured update keeps the fused kernel the eager one runs: on an
    H200 its graph then agreed with the eager update to 1e-7 (5e-6 with the foreach kernel) and timed the same or
    less (docs/notes/gpu_check.md)."""
    return torch.optim.Adam(params, lr=lr, fused=True, capturable=capturable)
