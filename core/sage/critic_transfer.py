"""Critics of another shape than a warm start's (RLPD's layer norms, a larger ensemble): fitting them to the saved
critics before they are trusted, and refusing saved optimiser moments of the wrong shapes."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

import torch
from torch import Tensor

from core.sage.networks import EnsembleCritic


def fit_to_saved(
    critic: EnsembleCritic,
    teacher: EnsembleCritic,
    optimizer: torch.optim.Optimizer,
    rows: Callable[[], tuple[Tensor, Tensor]],
    updates: int,
    max_grad_norm: float | None,
) -> float:
    """``updates`` steps of the squared difference between ``critic`` and ``teacher`` on the (observations, actions)
    ``rows()`` returns, member z of the critic learning the teacher's member z mod the teacher's number; returns the
    last step's mean squared difference."""
    members = torch.arange(critic.members, device=critic.out.weight.device) % teacher.members
    loss = torch.tensor(math.nan)
    for _ in range(updates):
        obs, action = rows()
        with torch.no_grad():
            target = teacher(obs, action)[members]
        loss = (critic(obs, action) - target).pow(2).mean()
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        if max_grad_norm is not None:
            torch.nn.utils.clip_grad_norm_(critic.parameters(), max_grad_norm)
        optimizer.step()
    return float(loss.detach())


def check_state_shapes(optimizer: torch.optim.Optimizer, saved: Mapping[str, Any]) -> None:
    """A ValueError when a saved optimiser's per-parameter tensors (Adam's moments) do not have their parameters'
    shapes here: ``load_state_dict`` checks only how many parameters there are, and a fused step over moments of
    another shape (a critic ensemble of another size) reads out of bounds."""
    params = [p for group in optimizer.param_groups for p in group["params"]]
    indices = [i for group in saved.get("param_groups", []) for i in group["params"]]
    states = saved.get("state", {})
    for param, index in zip(params, indices, strict=False):
        for key, value in states.get(index, {}).items():
            if isinstance(value, Tensor) and value.dim() > 0 and tuple(value.shape) != tuple(param.shape):
                raise ValueError(f"saved {key} of shape {tuple(value.shape)} for a parameter of {tuple(param.shape)}")
