"""Study budgets counted in ENVIRONMENT STEPS, the same for every method.

Budgets counted in episodes starve the methods whose episodes end early (a policy that crashes in ten steps
gets ten times fewer updates than one that drives for a hundred), so each study gives every method the same
number of environment steps for training and the same number of evaluation episodes per seed.

- ``smoke``: seconds; runs inside a test, checks the pipeline end to end, says nothing about learning.
- ``small``: at most about an hour for a whole study (every method, five seeds) on a 2-core machine.
- ``full``: paper scale, meant for a cluster (``--address``).
"""

from __future__ import annotations

from dataclasses import dataclass

BUDGET_NAMES = ("smoke", "small", "full")


@dataclass(frozen=True)
class Budget:
    """How much each method gets, per training seed."""

    name: str
    train_steps: int
    """Environment steps of training per method and seed (expert-driven steps count too)."""
    eval_episodes: int
    """Evaluation episodes per method, seed and evaluation split."""
    seeds: int
    """Training seeds per method (the paper's studies use five)."""
    expert_steps: int = 0
    """Environment steps of an expert trained by reinforcement learning (``--set expert=sac``, once per results
    folder and route; :mod:`studies.experts`), demonstrations included."""


BUDGETS: dict[str, Budget] = {
    "smoke": Budget("smoke", train_steps=200, eval_episodes=2, seeds=2, expert_steps=300),
    "small": Budget("small", train_steps=6_000, eval_episodes=10, seeds=5, expert_steps=20_000),
    "full": Budget("full", train_steps=200_000, eval_episodes=100, seeds=5, expert_steps=1_000_000),
}


def budget(name: str) -> Budget:
    """The named budget; an unknown name is a clear error listing the choices."""
    try:
        return BUDGETS[name]
    except KeyError:
        raise ValueError(f"unknown budget {name!r}; choose one of {', '.join(BUDGET_NAMES)}") from None
