"""The base policy's own drives kept beside a fine-tuning session's data, so that a round does not forget them.

A round (:meth:`core.finetune.Finetuner.round`) fills the prior part of its buffer once with the base version
driving alone over its training scenarios (:func:`drive_alone`), and every batch it samples takes a fixed share of
its rows from them (:class:`SharedReplayBuffer`), as RLPD and HIL-SERL sample offline or intervention data beside
online data; ``FinetuneConfig.prior_distill`` also holds the actor to the base's recorded actions there.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from core.protocol import StepRecord
from core.replay import Batch, ReplayBuffer, SortedRows, read_only
from core.versions import FinetuneError

PriorSource = Callable[[Path, int, int], list[StepRecord]]
"""``prior(version_folder, episodes, seed) -> steps``: the version driving alone (no gate, no expert) over its
training scenarios (picklable for the worker: a partial of :func:`drive_alone`)."""


def drive_alone(
    path: Path,
    episodes: int,
    seed: int,
    *,
    make_env: Callable[[str], Any],
    scenarios: Iterable[str] | None = None,
    max_steps: int | None = None,
) -> list[StepRecord]:
    """``episodes`` episodes of the policy at ``path`` alone (deterministic, no gate, no expert) over ``scenarios``
    in turn (default: the ones it was trained on, from its checkpoint), episode ``i`` on seed ``seed + i``."""
    from core.agents import load_agent
    from core.experts import ScriptedExpert
    from core.loop import NoGate, Runner

    agent = load_agent(path)
    names = list(scenarios) if scenarios is not None else [str(s) for s in agent.meta.scenarios]
    if not names:
        raise FinetuneError(f"{path} names no training scenario to drive the base policy on")
    steps: list[StepRecord] = []
    for i in range(episodes):
        env = make_env(names[i % len(names)])
        try:
            runner = Runner(env, agent.policy, NoGate(), ScriptedExpert(), seed=seed + i, deterministic=True)
            runner.step_listeners.append(steps.append)
            runner.run_episode(max_steps=max_steps)
        finally:
            env.close()
    return steps


class SharedReplayBuffer(ReplayBuffer):
    """The round's real buffer: the base policy's own drives (prior rows) beside the session's rows, every sample
    drawn in fixed shares from the two (``prior_share`` from the prior rows), as RLPD and HIL-SERL sample offline
    or intervention data beside online data. Everything else (world-model fits, takeover samples) sees all rows."""

    def __init__(
        self, obs_dim: int, act_dim: int, capacity: int, prior_share: float, device: torch.device | str = "cpu"
    ) -> None:
        super().__init__(obs_dim, act_dim, capacity, device)
        self._prior = np.zeros(capacity, bool)
        self.prior = read_only(self._prior)
        """Read-only: rows are prior rows by being added while :attr:`adding_prior` is True."""
        self.prior_share = prior_share
        self.adding_prior = False
        """Rows added while this is True are prior rows."""
        self._prior_rows, self._own_rows = SortedRows(), SortedRows()

    def add(self, *args: Any, **kwargs: Any) -> None:
        row, stored = self.pos, self.pos < self.size
        was = bool(self._prior[row])
        super().add(*args, **kwargs)
        now = self.adding_prior
        self._prior[row] = now
        self._prior_rows.change(row, stored and was, now)
        self._own_rows.change(row, stored and not was, not now)

    def prior_count(self) -> int:
        return self._prior_rows.count

    def sample_prior(self, batch_size: int, rng: np.random.Generator) -> Batch | None:
        """Prior rows only (the batch of the distillation anchor, ``FinetuneConfig.prior_distill``); None if none."""
        prior = self._prior_rows.view()
        if len(prior) == 0:
            return None
        return self._batch(prior[rng.integers(0, len(prior), size=batch_size)])

    def sample(self, batch_size: int, rng: np.random.Generator) -> Batch:
        prior, own = self._prior_rows.view(), self._own_rows.view()
        n_prior = round(self.prior_share * batch_size)
        if len(prior) == 0 or len(own) == 0 or n_prior == 0:
            return super().sample(batch_size, rng)
        idx = np.concatenate(
            [
                prior[rng.integers(0, len(prior), size=n_prior)],
                own[rng.integers(0, len(own), size=batch_size - n_prior)],
            ]
        )
        return self._batch(idx)
