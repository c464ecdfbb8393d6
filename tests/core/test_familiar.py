"""A fine-tuned version that lets the base drive first (``finetune.base_first``): the base acts wherever the gate,
watching the base's action, would not ask for help; the version acts where it would."""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
import pytest
import torch

from core.agents import LearnerPolicy, load_agent, load_checkpoint
from core.experts import ScriptedExpert
from core.familiar import STATE_KEY, BaseFirstPolicy
from core.finetune import FinetuneConfig, Finetuner, drive_alone
from core.loop import NoGate, Runner
from core.protocol import GateDecision
from tests.core.test_finetune import deployed, fast, point_env, setup  # noqa: F401  (fixtures)

torch.set_num_threads(1)


class Constant:
    def __init__(self, value: float, size: int = 2) -> None:
        self.value, self.size = value, size

    def act(self, obs: np.ndarray, deterministic: bool = False) -> np.ndarray:
        return np.full(self.size, self.value, np.float32)


class Watch:
    """Fires where the observation's first entry is over 0; counts what the loop tells it."""

    def __init__(self) -> None:
        self.resets = 0
        self.observed: list[np.ndarray] = []
        self.judged: list[np.ndarray] = []

    def reset(self) -> None:
        self.resets += 1

    def decide(self, obs: np.ndarray, a_rl: np.ndarray) -> GateDecision:
        self.judged.append(np.asarray(a_rl))
        return GateDecision(0.0, 0.0, bool(obs[0] > 0))

    def observe(self, obs: np.ndarray, action: np.ndarray, next_obs: np.ndarray) -> float:
        self.observed.append(np.asarray(action))
        return 0.0


def test_the_base_acts_until_the_watch_over_its_action_fires() -> None:
    watch = Watch()
    policy = BaseFirstPolicy(Constant(1.0), Constant(-1.0), watch)
    assert policy.act(np.array([-1.0, 0.0]))[0] == -1.0 and policy.last_base
    assert policy.act(np.array([1.0, 0.0]))[0] == 1.0 and not policy.last_base
    assert all(a[0] == -1.0 for a in watch.judged)  # the watch judges the base's proposal, never the version's
    assert (policy.steps, policy.base_steps) == (2, 1)


def test_the_loop_tells_a_watching_policy_where_episodes_start_and_what_was_executed() -> None:
    watch = Watch()
    env = point_env("static")
    policy = BaseFirstPolicy(Constant(0.5), Constant(0.0), watch)
    runner = Runner(env, policy, NoGate(), ScriptedExpert(), seed=0, deterministic=True)
    steps = sum(runner.run_episode(max_steps=15).steps for _ in range(3))
    assert watch.resets == 3
    assert len(watch.observed) == steps == policy.steps


def test_fine_tuned_versions_carry_the_base_and_act_as_it_where_their_gate_would_not_fire(setup) -> None:  # noqa: F811
    versions, store, session = setup
    prior = functools.partial(drive_alone, make_env=point_env, scenarios=["static"])
    version = Finetuner(versions, store, session, fast(prior_episodes=2, base_first=True), prior=prior).round().version
    assert version is not None and version.metrics["base_first"] is True
    saved = load_checkpoint(version.path)["state"][STATE_KEY]["acting"]
    base_actor = load_checkpoint(versions.get(0).path)["state"]["actor"]
    assert saved.keys() == base_actor.keys() and all(torch.equal(saved[k], base_actor[k]) for k in base_actor)

    agent, base = load_agent(version.path), load_agent(versions.get(0).path)
    policy = agent.policy
    assert isinstance(policy, BaseFirstPolicy) and isinstance(policy.version, LearnerPolicy)
    obs = np.asarray(point_env("static").reset(seed=0)[0], np.float32)
    quiet = GateDecision(0.0, 1.0, False)
    policy.watch.decide = lambda o, a: quiet  # type: ignore[method-assign]
    np.testing.assert_allclose(policy.act(obs, True), base.policy.act(obs, True), atol=1e-6)
    policy.watch.decide = lambda o, a: GateDecision(2.0, 1.0, True)  # type: ignore[method-assign]
    np.testing.assert_allclose(policy.act(obs, True), policy.version.act(obs, True), atol=1e-6)
    assert not np.allclose(base.policy.act(obs, True), policy.version.act(obs, True), atol=1e-4)  # the round moved it

    plain = Finetuner(versions, store, session, fast(), prior=prior).round().version
    assert plain is not None and STATE_KEY not in load_checkpoint(plain.path)["state"]
    assert isinstance(load_agent(plain.path).policy, LearnerPolicy)


def test_a_version_that_lets_the_base_drive_first_needs_a_world_model_to_watch_it(setup, tmp_path: Path) -> None:  # noqa: F811
    versions, store, session = setup
    version = Finetuner(versions, store, session, fast(base_first=True)).round().version
    assert version is not None
    payload = load_checkpoint(version.path)
    payload.pop("file")
    del payload["state"]["world_model"]
    torch.save(payload, tmp_path / "checkpoint.pt")
    with pytest.raises(ValueError, match="no fitted world model to watch the base"):
        load_agent(tmp_path / "checkpoint.pt")
    with pytest.raises(ValueError, match="base_first"):
        FinetuneConfig().with_settings(["base_first=maybe"])
