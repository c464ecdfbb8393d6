"""The spec of one training run, as plain data (no torch, no simulator: ``sage --help`` stays quick).

:func:`studies.training.run_training` runs it; ``sage train``'s flags are its fields.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any


@dataclass
class TrainSpec:
    """One training run: simulator, scenarios, learner, budget, demonstrations, protocol, run folder.

    Plain data (picklable): a sweep ships it to a worker process. ``sage train``'s flags are these fields.
    """

    sim: str = "ugv"
    """Simulator: a name of sims.SIMULATORS."""
    scenario: str | None = None
    """Scenario(s) by the simulator's names (ugv 1-4, highway train|test, sumo c1|c2, ...); a comma list
    trains on each in turn. None: the simulator's default."""
    method: str = "sage"
    """A learner registered in core.learners, by name."""
    episodes: int | None = None
    """Training episodes (demonstrations not counted). None: 100, or unbounded when train_steps is given."""
    train_steps: int | None = None
    """Environment steps in total, demonstrations included: a budget that is the same for every method (the
    studies count budgets this way). None: episodes alone bound the run."""
    seed: int = 0
    """Seed of torch, numpy and the episodes."""
    init: str | None = None
    """Warm-start from this run folder or checkpoint (and take its hyperparameters)."""
    out: str | None = None
    """Run folder. None: runs/<sim>-<scenario>-<method>-s<seed>-<time>."""
    demo_episodes: int = 0
    """Expert episodes recorded and cloned before training."""
    demo_steps: int | None = None
    """Most environment steps the demonstrations may take, the last one cut there (None: up to train_steps)."""
    dataset: list[str] = field(default_factory=list)
    """Offline data loaded before pretraining (repeatable): a recorded session file (sessions/<id>.sqlite) or a
    Minari dataset (minari:<id>); steps an expert drove are its demonstrations."""
    demo_noise: float = 0.0
    """Std of Gaussian noise on the demonstrated expert actions."""
    checkpoint_every: int = 25
    """Episodes between checkpoint versions (0: the final checkpoint only)."""
    checkpoint_dtype: str = "float32"
    """float32, or float16 for small committed policies."""
    max_episode_steps: int | None = None
    """Cut episodes at this many steps (None: the simulator's own time limit)."""
    env: list[str] = field(default_factory=list)
    """Simulator config overrides key=value for every env of the run (``sage train --set env.KEY=VALUE``), e.g.
    expert.yield_to_movers=false on ugv (demonstrations that run into movers); a value is read as JSON where it
    parses (false, 0.3), else as text."""
    overrides: list[str] = field(default_factory=list)
    """Learner config overrides key=value by the field's path, e.g. gate.tau_max=0.7 (``sage train --set``; fields:
    core.sage.config)."""
    expert: str | None = None
    """Run folder or checkpoint whose policy is the expert, or a planner's name (core.planners);
    default: the simulator's scripted expert."""
    demo_expert: str | None = None
    """The expert of the demonstrations alone, by the same names as --expert (e.g. the UGV's planner blind-movers,
    demonstrations that run into movers, while takeovers stay with the expert that yields); default: --expert."""
    protocol: str | None = None
    """Study protocol: route-shift (sumo: C1 on route 1, then C2)."""
    c1: int | None = field(default=None, metadata={"flag": "--c1"})
    """route-shift: episodes of phase C1 (default 40)."""
    c2: int | None = field(default=None, metadata={"flag": "--c2"})
    """route-shift: episodes of phase C2 (default 20)."""
    c1_share: float | None = None
    """route-shift: C1 takes this share of the interaction steps of --train-steps (those left after the
    demonstrations), C2 the rest, instead of --c1/--c2 episodes (the studies' budgets are in steps)."""
    expert_c2: str | None = None
    """route-shift: the expert run of phase C2 (default: the C1 expert)."""
    adversarial_ratio: float | None = None
    """highway: share of adversarial training episodes (default 0.5)."""
    world_model_only: bool = False
    """Refit only the world model of --init: the policy drives (stochastic, no takeover) and nothing else learns;
    the checkpoint keeps the policy's own config, --set world_model_config.* included (e.g. violation_steps)."""
    device: str = "auto"
    """Where the learner's updates run: auto (CUDA when torch sees a GPU, else the CPU), cpu or cuda. The loop's
    policy, the gate and the world model's fit stay on the CPU."""
    refit_gated_share: float = 0.0
    """--world-model-only: the share of the refit's episodes driven as deployed, the policy's gate handing control
    to the expert (the rest: the policy alone), so the model also sees what the policy does where the expert hands
    back."""

    def replace(self, **changes: Any) -> TrainSpec:
        return dataclasses.replace(self, **changes)
