"""The paper's Waymo evaluation on the highway pool: one episode per scenario of a split, in a mode.

``evaluate(policy, split="test", mode="adversarial")`` runs the policy through ``core.loop.Runner``
(so exactly the loop every other face uses) and returns one row per episode; :func:`studies.highway.paper_table`
formats them as the paper's table (one table code for the CLI, the study, the tests and the bench).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Literal

import gymnasium as gym

from core.experts import ExpertPolicy
from core.loop import Expert, Gate, Policy, Runner
from sims.highway.config import HighwayConfig
from sims.highway.env import EgoPredictor, HighwayEnv, Mode
from sims.highway.scenarios import Split, scenario_ids

PolicyLike = Policy | Callable[[gym.Env[Any, Any]], Policy] | Literal["expert"]
Predictor = Literal["policy", "reference"] | EgoPredictor


def evaluate(
    policy: PolicyLike,
    split: Split = "test",
    mode: Mode = "normal",
    *,
    episodes: int | None = None,
    seed: int = 0,
    predictor: Predictor = "policy",
    gate: Gate | None = None,
    expert: Expert | None = None,
    config: HighwayConfig | None = None,
    on_episode: Callable[[dict[str, Any]], None] | None = None,
) -> list[dict[str, Any]]:
    """Run ``policy`` once on each scenario of ``split`` (the first ``episodes`` ids if given) in ``mode``.

    ``policy``: a ``core.loop.Policy``, a factory ``env -> Policy`` (for policies that need the env), or
    ``"expert"`` for the scripted expert. ``predictor`` is what the adversarial resampling rolls to
    predict the ego (CAT): ``"policy"`` the evaluated policy itself (the paper's closed loop),
    ``"reference"`` the log's IDM reference driver, or any ``EgoPredictor``. ``gate`` and ``expert``
    are passed to the Runner (for evaluating with takeovers); by default the policy drives alone.
    Rows are ``EpisodeSummary.as_row()`` plus ``split`` and ``mode``; group them by (split, mode) for
    :func:`studies.highway.paper_table`.
    """
    env = gym.make("sage/Highway-v0", split=split, mode=mode, config=config)
    inner = env.unwrapped
    assert isinstance(inner, HighwayEnv)
    if policy == "expert":
        pol: Policy = ExpertPolicy(env)
    elif hasattr(policy, "act"):
        pol = policy
    elif callable(policy):
        pol = policy(env)
    else:
        raise TypeError(f"policy must be a Policy, a factory env -> Policy, or 'expert'; got {type(policy).__name__}")
    if predictor == "policy":
        inner.set_ego_predictor("expert" if policy == "expert" else pol)
    elif predictor == "reference":
        inner.set_ego_predictor(None)
    else:
        inner.set_ego_predictor(predictor)
    ids = scenario_ids(split)
    if episodes is not None:
        ids = ids[: max(0, int(episodes))]
    runner = Runner(env, pol, gate, expert, seed=seed, deterministic=True)
    rows: list[dict[str, Any]] = []
    try:
        for sid in ids:
            inner.scenario_id = sid
            row = runner.run_episode().as_row()
            row.update(split=split, mode=mode)
            rows.append(row)
            if on_episode is not None:
                on_episode(row)
    finally:
        env.close()
    return rows
