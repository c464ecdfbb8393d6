"""State novelty: how far a state lies from the states a world model was calibrated on (``curiosity_signal=novelty``).

The model's prediction error and its members' disagreement are read on one transition; on ground whose every
transition is locally familiar (a pedestrian who runs, a route that turns elsewhere: issue 60, ``docs/notes/
novelty_probe.md``) neither rises. Novelty reads the state itself: the mean distance from the state's features (the
observation and, where the model has the input, its last change of state: a one-step window, which carries a speed or
a turn) to its :data:`NEIGHBOURS` nearest states of a reference set drawn from the calibration states, with every
feature in units of the calibration states' own spread, as a root mean square per feature (1: a neighbour about one
standard deviation away in every feature). The set, the spread and the novelty's mean on calibration states held
out of the set (the fixed reference that ρ reads it against) are measured by :func:`core.sage.calibration.calibrate`
and kept in the world model's checkpoint.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

NEIGHBOURS = 5
"""k: the novelty is the mean distance to the k nearest reference states (one near-duplicate does not make a state
familiar)."""
REFERENCE_STATES = 2048
"""Most reference states kept: a few thousand feature rows, one matrix-vector product per gate step."""
HELD_OUT_STATES = 2048
"""Most calibration states, outside the reference set, whose mean novelty is the fixed reference."""
SCALE_FLOOR = 1e-2
"""Smallest spread a feature is divided by: a feature constant on the calibration states must not blow up."""


def novelty_width(obs_dim: int, with_motion: bool) -> int:
    """F, the number of features novelty reads (:func:`novelty_features`)."""
    return 2 * obs_dim if with_motion else obs_dim


def novelty_features(obs: Tensor, motion: Tensor | None, with_motion: bool) -> Tensor:
    """(B, F) the features novelty reads: the observation, then its last change of state when the model reads one
    (zeros where unknown, as the model's motion input)."""
    if not with_motion:
        return obs
    return torch.cat([obs, torch.zeros_like(obs) if motion is None else motion], dim=-1)


@dataclass
class NoveltyReference:
    """A reference set ready to score states: its rows standardised, their squared norms kept."""

    states: Tensor
    """(K, F) the reference states' features, standardised."""
    squared: Tensor
    """(K,) their squared norms."""
    center: Tensor
    """(F,) the calibration states' mean per feature."""
    inv_scale: Tensor
    """(F,) 1 / their spread per feature (floored)."""

    @classmethod
    def of(cls, states: Tensor, center: Tensor, scale: Tensor) -> NoveltyReference:
        inv_scale = scale.clamp_min(SCALE_FLOOR).reciprocal()
        standard = ((states - center) * inv_scale).contiguous()
        return cls(standard, standard.square().sum(-1), center, inv_scale)

    def __call__(self, features: Tensor) -> Tensor:
        """(B,) each row's novelty: the root mean square per feature of its distance to each of its
        :data:`NEIGHBOURS` nearest reference states, averaged over them."""
        x = (features - self.center) * self.inv_scale
        # |x - r|² = |x|² - 2 x·r + |r|²: one matrix product, no (B, K, F) difference
        squared = (x.square().sum(-1, keepdim=True) - 2.0 * x @ self.states.T + self.squared).clamp_min(0.0)
        k = min(NEIGHBOURS, squared.shape[-1])
        nearest = torch.topk(squared, k, dim=-1, largest=False).values
        return (nearest / x.shape[-1]).sqrt().mean(-1)


def fit_reference(features: Tensor, seed: int = 0) -> tuple[Tensor, Tensor, Tensor, float]:
    """From calibration states' features (N, F): the reference set (at most :data:`REFERENCE_STATES` rows, drawn
    without replacement with a fixed seed), the features' mean and spread, and the novelty's mean on states held out
    of the set (at most :data:`HELD_OUT_STATES`; half of the states each when there are fewer than both)."""
    n = len(features)
    if n < 2:
        raise ValueError(f"state novelty needs at least 2 calibration states, got {n}")
    order = torch.randperm(n, generator=torch.Generator().manual_seed(seed))
    kept = min(REFERENCE_STATES, n - min(HELD_OUT_STATES, n // 2))
    reference, held_out = features[order[:kept]], features[order[kept : kept + HELD_OUT_STATES]]
    center, scale = features.mean(0), features.std(0)
    mean = float(NoveltyReference.of(reference, center, scale)(held_out).mean())
    return reference.clone(), center, scale, mean
