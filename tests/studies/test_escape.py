"""The escape check: violations replayed from their seed, steady manoeuvres tried from before them (point world)."""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch

from core.agents import load_agent
from core.loop import Runner
from studies.calibrate import EVAL_SEED, _episode
from studies.escape import _replay_to, escape_check, steady_actions
from tests.core.sage import envs
from tests.core.test_finetune import deployed  # noqa: F401  (the module fixture)

torch.set_num_threads(1)

NEVER = {"tau_from_data": False, "tau_min": 10.0, "tau_max": 10.0}
"""A gate that never fires: the policy drives alone, so its violations play out."""


def test_steady_actions_cover_a_box_on_a_grid_and_every_discrete_action() -> None:
    grid = steady_actions(gym.spaces.Box(-1.0, 1.0, (2,), np.float32), levels=3)
    assert len(grid) == 9 and all(a.shape == (2,) and a.dtype == np.float32 for a in grid)
    assert {tuple(a.tolist()) for a in grid} == {(x, y) for x in (-1.0, 0.0, 1.0) for y in (-1.0, 0.0, 1.0)}
    assert [int(a) for a in steady_actions(gym.spaces.Discrete(4, start=1))] == [1, 2, 3, 4]
    with pytest.raises(ValueError, match="levels"):
        steady_actions(gym.spaces.Box(-1.0, 1.0, (1,), np.float32), levels=1)
    with pytest.raises(ValueError, match="MultiBinary"):
        steady_actions(gym.spaces.MultiBinary(3))


def test_a_replay_is_the_same_episode_up_to_its_violation(deployed: Path) -> None:  # noqa: F811
    agent = load_agent(deployed)
    env = envs.make("dynamic")
    runner = Runner(env, agent.policy, agent.make_gate(**NEVER), None, seed=EVAL_SEED, deterministic=True)
    found = None
    for episode in range(10):
        records = _episode(runner, None)
        step = next((i for i, r in enumerate(records) if r.violation), None)
        if step is not None:
            found = (EVAL_SEED + episode, records, step)
            break
    assert found is not None, "the statically trained policy should meet the moving obstacle"
    seed, records, step = found
    assert _replay_to(env, seed, records, step)
    assert env.step(records[step].action)[4]["violation"], "the recorded action leads into the same violation"
    assert not _replay_to(env, seed + 1, records, step), "another seed is another episode"


def test_escape_check_finds_a_way_out_of_each_violation_given_time_to_act(deployed: Path) -> None:  # noqa: F811
    report = escape_check(
        deployed, functools.partial(envs.make, "dynamic"), dt=0.1, episodes=10, before_s=(2.0,), **NEVER
    )
    assert report.violations > 0, "the statically trained policy should meet the moving obstacle"
    assert report.drifted == 0, "the point world is deterministic: every replay is the same episode"
    assert report.warned == 0 and report.under_expert == 0 and report.from_takeover == 0  # the gate never fired
    # two seconds ahead some held action (standing still, or steering off the obstacle's path) avoids each one
    assert report.escapable_before == [report.violations]
    assert f"avoidable from 2 s before: {report.violations}" in report.summary()


class _Jittered(gym.Wrapper[Any, Any, Any, Any]):
    """The point world with observations that differ at every reset: a replay never matches the recording."""

    def __init__(self, env: gym.Env[Any, Any]) -> None:
        super().__init__(env)
        self.resets = 0

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(**kwargs)
        self.resets += 1
        return np.asarray(obs) + 0.01 * self.resets, info


def test_a_replay_that_does_not_reproduce_the_episode_is_left_out(deployed: Path) -> None:  # noqa: F811
    report = escape_check(
        deployed, lambda: _Jittered(envs.make("dynamic")), dt=0.1, episodes=6, before_s=(2.0,), **NEVER
    )
    assert report.violations > 0 and report.drifted == report.violations
    assert report.replayed == 0 and report.escapable_before == [0]
    assert "replays drifted, left out" in report.summary()
