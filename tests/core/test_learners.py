"""The learner registry (core.learners): built-ins, registering a toy method, clear errors."""

from __future__ import annotations

import numpy as np
import pytest

from core import learners
from core.sage.config import AgentConfig, for_method, validate
from core.sage.hg_dagger import HGDAgger
from core.sage.learner import BaseLearner
from core.sage.sac import SAC
from core.sage.td3 import TD3


def test_builtin_methods_are_registered_with_their_classes_and_presets() -> None:
    assert learners.learner_names()[:5] == ("sage", "sac", "fni-rl", "td3", "hg-dagger")
    assert learners.learner_entry("td3").cls is TD3
    assert learners.learner_entry("hg-dagger").cls is HGDAgger
    assert learners.preset("fni-rl") == for_method("fni-rl")
    assert learners.preset("sac", hidden=32).hidden == 32


def test_make_learner_builds_the_registered_class_as_it_is_built_directly() -> None:
    cfg = for_method("sac", hidden=16, layers=1)
    by_name = learners.make_learner("sac", cfg, 4, 2, seed=3)
    by_config = SAC(cfg, 4, 2, None, None, 3)
    assert isinstance(by_name, SAC) and type(by_config) is SAC
    obs = np.zeros(4, np.float32)
    np.testing.assert_allclose(by_name.policy_action(obs, True), by_config.policy_action(obs, True))


class ToyLearner(SAC):
    """A registered method that is not built in (stands for D3QN and the UGV baselines)."""


def test_a_registered_toy_method_is_built_listed_and_removed() -> None:
    learners.register_learner("toy", ToyLearner, preset=lambda base=None, **kw: for_method("sac", base, **kw))
    try:
        assert "toy" in learners.learner_names()
        learner = learners.make_learner("toy", learners.preset("toy", hidden=8, layers=1), 3, 1)
        cfg = for_method("sac")
        cfg.method = "toy"
        validate(cfg)  # a configuration may name a registered method
        assert isinstance(learner, ToyLearner)
        with pytest.raises(ValueError, match="already registered"):
            learners.register_learner("toy", ToyLearner, preset=for_method)
    finally:
        learners.unregister_learner("toy")
    assert "toy" not in learners.learner_names()
    with pytest.raises(ValueError, match="method: unknown 'toy'"):
        validate(cfg)


def test_bad_registrations_and_unknown_names_are_clear_errors() -> None:
    with pytest.raises(ValueError, match="unknown method 'nope'; choose one of sage"):
        learners.make_learner("nope", AgentConfig(), 3, 1)
    with pytest.raises(TypeError, match="not a BaseLearner subclass"):
        learners.register_learner("bad", dict, preset=for_method)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="non-empty"):
        learners.register_learner("", BaseLearner, preset=for_method)
    with pytest.raises(KeyError, match="no learner 'nope'"):
        learners.unregister_learner("nope")


def test_action_bounds_take_box_and_discrete_spaces() -> None:
    import gymnasium as gym

    from core.agents import action_bounds

    low, high = action_bounds(gym.spaces.Box(-2.0, 3.0, (2,)))
    assert low.tolist() == [-2.0, -2.0] and high.tolist() == [3.0, 3.0]
    low, high = action_bounds(gym.spaces.Discrete(9, start=1))
    assert low.tolist() == [1.0] and high.tolist() == [9.0]
    with pytest.raises(TypeError, match="neither a Box nor a Discrete"):
        action_bounds(gym.spaces.MultiBinary(3))


def test_a_committed_checkpoint_loads_through_the_registry() -> None:
    import torch

    from core.agents import LearnerPolicy, load_agent

    agent = load_agent("policies/ugv-default")
    assert isinstance(agent.policy, LearnerPolicy)
    assert isinstance(agent.policy.learner, learners.learner_entry(agent.meta.method).cls)
    assert agent.policy.learner.actor is agent.actor
    obs = np.random.default_rng(0).normal(size=agent.meta.obs_dim).astype(np.float32)
    with torch.no_grad():
        expected = agent.actor.deterministic(torch.from_numpy(obs).view(1, -1))[0].numpy()
    np.testing.assert_allclose(agent.policy.act(obs, deterministic=True), expected, rtol=1e-5, atol=1e-6)
    assert agent.has_world_model  # the world model is loaded whatever the acting learner's switches


def _trained_sac(seed: int = 0, **overrides: object) -> SAC:
    from core.loop import StepRecord

    cfg = for_method("sac", hidden=16, layers=1, batch_size=8, learning_starts=8, **overrides)
    learner = learners.make_learner("sac", cfg, 3, 1, seed=seed)
    rng = np.random.default_rng(seed)
    for t in range(20):
        obs = rng.normal(size=3).astype(np.float32)
        action = rng.uniform(-1, 1, size=1).astype(np.float32)
        learner.observe(
            StepRecord(
                episode=0,
                t=t,
                obs=obs,
                a_rl=action,
                a_expert=None,
                action=action,
                takeover=False,
                gate_fired=False,
                actor="agent",
                fear=0.0,
                threshold=1.0,
                curiosity=0.0,
                reward=float(action[0]),
                cost=0.0,
                violation=False,
                terminated=False,
                truncated=t == 19,
                next_obs=obs,
                wall_time=0.0,
            )
        )
    return learner


def test_checkpoints_keep_optimiser_state_and_load_with_weights_only(tmp_path) -> None:
    import torch

    from core.agents import AgentMeta, load_checkpoint, save_checkpoint

    learner = _trained_sac()
    assert learner.updates > 0
    meta = AgentMeta("sac", "toy", [], 3, 1, [-1.0], [1.0], updates=learner.updates)
    file = save_checkpoint(tmp_path / "c.pt", learner, meta)
    raw = torch.load(file, weights_only=True)
    assert set(raw["state"]["optimizers"]) == {"actor_optimizer", "critic_optimizer", "alpha_optimizer"}
    warm = learners.make_learner("sac", for_method("sac", hidden=16, layers=1, actor_lr=1e-5), 3, 1, seed=1)
    loaded = warm.load_state_dict(load_checkpoint(file)["state"], strict=False)
    assert "optimizers.critic_optimizer" in loaded
    saved_steps = learner.critic_optimizer.state_dict()["state"][0]["step"]
    assert float(warm.critic_optimizer.state_dict()["state"][0]["step"]) == float(saved_steps) > 0  # continues
    assert warm.actor_optimizer.param_groups[0]["lr"] == 1e-5  # the new run's learning rate, not the old one's


def test_the_guarded_updates_snapshot_of_an_optimiser_is_a_deep_copy_of_its_state() -> None:
    """The snapshot copies an optimiser's state as copy.deepcopy does (tensors cloned, hyperparameters copied), and
    an optimiser step after it leaves it as it was."""
    import copy

    import torch

    from core.sage.learner import _copy_optimizer_state

    learner = _trained_sac()
    saved = learner.critic_optimizer.state_dict()
    fast, slow = _copy_optimizer_state(saved), copy.deepcopy(saved)
    assert fast["param_groups"] == slow["param_groups"] and fast["param_groups"] is not saved["param_groups"]
    assert set(fast["state"]) == set(slow["state"]) and len(fast["state"]) > 0
    for index, values in slow["state"].items():
        assert set(fast["state"][index]) == set(values)
        for key, value in values.items():
            assert torch.equal(fast["state"][index][key], value)
            assert fast["state"][index][key].data_ptr() != saved["state"][index][key].data_ptr()
    learner.update()  # the optimiser's moments move on; the snapshot does not
    moved = learner.critic_optimizer.state_dict()["state"][0]["exp_avg"]
    assert not torch.equal(moved, fast["state"][0]["exp_avg"])
    assert torch.equal(fast["state"][0]["exp_avg"], slow["state"][0]["exp_avg"])


@pytest.mark.parametrize("dtype", ["float32", "float64", "float16"])
@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_the_finite_check_finds_one_bad_element_in_any_float_tensor(dtype: str, bad: float) -> None:
    import torch

    from core.sage.learner import _all_finite

    tensors = [torch.ones(3, 4, dtype=getattr(torch, dtype)), torch.zeros(7, dtype=getattr(torch, dtype))]
    assert _all_finite(tensors)
    tensors[1][5] = bad
    assert not _all_finite(tensors)
    assert not _all_finite([tensors[0].t(), tensors[1]])  # any layout


def test_the_guarded_update_undoes_a_nan_update_from_the_declared_state() -> None:
    learner = _trained_sac()
    before = {k: v.clone() for k, v in learner.critic.state_dict().items()}
    lam, updates = learner.lam, learner.updates

    def poisoned() -> dict[str, float]:
        for p in learner.critic.parameters():
            p.data.fill_(float("nan"))
        learner.lam = float("nan")
        return {"critic_loss": 1.0}

    learner.update = poisoned  # type: ignore[method-assign]
    _stats, applied = learner.guarded_update()
    assert not applied and learner.updates == updates and learner.lam == lam
    for k, v in learner.critic.state_dict().items():
        assert bool((v == before[k]).all())
