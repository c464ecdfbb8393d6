"""A fine-tuning round's updates (:class:`core.finetune.Finetuner`): guarded against non-finite losses, the critics
alone for a warm-up, and the share of a round's change its version keeps. Re-exported by :mod:`core.finetune`."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import torch

from core.replay import Batch
from core.sage.learner import BaseLearner


def weights_finite(learner: BaseLearner) -> bool:
    """Whether every trained value the learner declares (and its world model) is finite."""
    return learner.weights_finite()


def guarded_update(learner: BaseLearner) -> tuple[dict[str, float], bool]:
    """One ``learner.update()``, undone when a loss or a weight comes out NaN/inf: the learner's own guarded
    update (:meth:`BaseLearner.guarded_update`, the one online training uses too). Returns (stats, applied)."""
    return learner.guarded_update()


def critic_only_update(learner: BaseLearner) -> tuple[dict[str, float], bool]:
    """One update of the critics alone on a sampled batch (the actor, α and λ untouched), undone like
    :func:`guarded_update` when a loss or a weight comes out NaN/inf. A learner without a separate critic step
    (``critic_step``) runs its whole guarded update. Returns (stats, applied)."""
    critic_step: Callable[[Batch], dict[str, float]] | None = getattr(learner, "critic_step", None)
    if critic_step is None:
        return learner.guarded_update()
    return learner.guarded_update(lambda: critic_step(learner.buffer.sample(learner.cfg.batch_size, learner.rng)))


def keep_share_of_change(learner: BaseLearner, start: dict[str, Any], keep: float) -> float:
    """Move the learner's declared modules (actor, critics, target critics) back toward ``start`` (a
    :meth:`BaseLearner._snapshot` taken before the round's updates): each floating-point weight becomes
    ``start + keep · (now - start)``, in place (views of the weights stay valid). α, λ and the optimiser states
    stay as they are. Returns the norm of the acting module's change before the move (0 when it did not move)."""
    moved = 0.0
    with torch.no_grad():
        for name, saved in start["modules"].items():
            module = getattr(learner, name)
            now = module.state_dict()
            if name == learner.acting_module:
                moved = math.sqrt(
                    sum(float((now[k] - v).pow(2).sum()) for k, v in saved.items() if v.is_floating_point())
                )
            mixed = {k: v.lerp(now[k], keep) if v.is_floating_point() else now[k] for k, v in saved.items()}
            module.load_state_dict(mixed)
    learner.refresh_acting()
    return moved
