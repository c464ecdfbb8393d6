"""Diffusion-BC and Diffusion-QL: they learn the expert's actions offline, keep a bimodal expert's modes apart,
prefer the better mode with the Q term, and train from recorded sessions and Minari datasets."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from core.datasets import DatasetError, records
from core.export import export_minari
from core.learners import make_learner, preset
from core.loop import StepRecord
from core.sage.diffusion import DiffusionPolicy, Mish
from core.sessions import SessionStore
from tests.core.test_export import recorded  # noqa: F401 (a fixture)

OBS, ACT = 3, 2


def step(obs: np.ndarray, action: np.ndarray, reward: float = 0.0) -> StepRecord:
    action = np.asarray(action, np.float32)
    return StepRecord(
        episode=0, t=0, obs=obs.astype(np.float32), a_rl=action, a_expert=action, action=action, takeover=True,
        gate_fired=False, actor="expert", fear=math.nan, threshold=math.nan, curiosity=math.nan, reward=reward,
        cost=0.0, violation=False, terminated=True, truncated=False, next_obs=obs.astype(np.float32), wall_time=0.0,
    )  # fmt: skip


def learner(method: str, offline_steps: int, seed: int = 0, **overrides: object) -> DiffusionPolicy:
    cfg = preset(method, hidden=64, batch_size=128, **{"diffusion.offline_steps": offline_steps, **overrides})
    built = make_learner(method, cfg, OBS, ACT, -np.ones(ACT), np.ones(ACT), seed=seed)
    assert isinstance(built, DiffusionPolicy)
    return built


def expert_action(obs: np.ndarray) -> np.ndarray:
    return np.tanh(np.array([obs[0] - obs[1], 0.8 * obs[2] + 0.5 * obs[0]]))


def test_diffusion_bc_learns_the_experts_actions_on_held_out_states() -> None:
    rng = np.random.default_rng(0)
    policy = learner("diffusion-bc", 1500)
    for obs in rng.uniform(-1, 1, (2000, OBS)):
        policy.store(step(obs, expert_action(obs)))
    held_out = rng.uniform(-1, 1, (200, OBS))
    target = np.array([expert_action(o) for o in held_out])

    def error() -> float:
        return float(np.mean([np.sum((policy.act(o, True) - t) ** 2) for o, t in zip(held_out, target, strict=True)]))

    before = error()
    policy.pretrain()
    after = error()
    spread = float(np.mean(np.sum((target - target.mean(0)) ** 2, axis=1)))
    assert before > 0.5 * spread  # an untrained denoiser knows nothing
    assert after < 0.1 * spread, (before, after, spread)


def bimodal(policy: DiffusionPolicy, rewarded_mode: float | None = None, n: int = 1500, seed: int = 1) -> None:
    """For every state the expert steers either -0.8 or +0.8 (half each); ``rewarded_mode`` earns reward 1."""
    rng = np.random.default_rng(seed)
    for obs in rng.uniform(-1, 1, (n, OBS)):
        mode = 0.8 if rng.random() < 0.5 else -0.8
        reward = 1.0 if rewarded_mode is not None and mode == rewarded_mode else 0.0
        policy.store(step(obs, np.array([mode, 0.0]), reward))


def test_diffusion_bc_keeps_a_bimodal_experts_modes_apart() -> None:
    """Regression onto both modes would steer straight (0); the diffusion policy draws from each mode."""
    policy = learner("diffusion-bc", 1500)
    bimodal(policy)
    policy.pretrain()
    steer = np.array([policy.act(o)[0] for o in np.random.default_rng(5).uniform(-1, 1, (200, OBS))])
    assert np.mean(np.abs(steer) > 0.5) > 0.75
    assert 0.25 < np.mean(steer > 0) < 0.75  # both modes, not one


def test_diffusion_ql_prefers_the_mode_that_pays() -> None:
    torch.manual_seed(0)
    ql = learner("diffusion-ql", 500)
    bimodal(ql, rewarded_mode=0.8)
    stats = ql.pretrain()
    assert math.isfinite(stats["offline_critic_loss"])
    steer = np.array([ql.act(o)[0] for o in np.random.default_rng(6).uniform(-1, 1, (100, OBS))])
    assert np.mean(steer > 0.5) > 0.8, np.mean(steer > 0.5)


def test_sampling_steps_is_an_option_and_bad_values_are_refused() -> None:
    fast = learner("diffusion-bc", 1, **{"diffusion.sampling_steps": 2})
    assert fast.act(np.zeros(OBS)).shape == (ACT,)
    with pytest.raises(ValueError, match="sampling_steps"):
        learner("diffusion-bc", 1, **{"diffusion.sampling_steps": 50})
    with pytest.raises(ValueError, match="--demo-episodes or --dataset"):
        learner("diffusion-bc", 1).pretrain()  # nothing to learn from


def test_recorded_sessions_and_minari_exports_are_datasets(
    recorded: tuple[SessionStore, str],  # noqa: F811
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    store, session_id = recorded
    steps = store.steps(session_id)
    from_session = list(records(str(store.path(session_id)), obs_dim=1, act_dim=1))
    assert len(from_session) == len(steps["obs"])
    assert sum(r.takeover for r in from_session) == int(np.sum(steps["actor"] != "agent"))
    assert all(np.array_equal(r.a_expert, r.action) for r in from_session if r.takeover)

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "minari"))
    export_minari(store, session_id, "sage/line/takeovers")
    from_minari = list(records("minari:sage/line/takeovers-v0", obs_dim=1, act_dim=1))
    assert [r.takeover for r in from_minari] == [r.takeover for r in from_session]
    assert np.allclose([r.action for r in from_minari], [r.action for r in from_session])

    with pytest.raises(DatasetError, match="1 values, this simulator has 4"):
        list(records(str(store.path(session_id)), obs_dim=4))
    with pytest.raises(DatasetError, match="recorded session file"):
        list(records(str(tmp_path / "nothing.csv")))
    with pytest.raises(DatasetError, match="minari:nope"):
        list(records("minari:nope/none-v0"))


def test_the_denoisers_mish_is_torchs_to_float32_rounding_with_its_gradient() -> None:
    """Values and gradients equal nn.Mish's over the range an activation meets, the far tails included (no inf or
    NaN where torch's is finite), under no_grad too (sampling) and through a layer's backward."""
    x = torch.cat([torch.linspace(-60.0, 60.0, 2 * Mish.FUSED_FROM), torch.tensor([-1e4, -88.0, 19.99, 20.0, 1e4])])
    x64 = x.double().requires_grad_(True)
    expected = torch.nn.functional.mish(x64)
    (expected_grad,) = torch.autograd.grad(expected.sum(), x64)
    ours = x.clone().requires_grad_(True)
    y = Mish()(ours)
    (grad,) = torch.autograd.grad(y.sum(), ours)
    assert torch.isfinite(y).all() and torch.isfinite(grad).all()
    # float32 against the float64 reference: a few ulps of each value (|x| up to 1e4)
    assert torch.allclose(y.double(), expected, rtol=1e-6, atol=1e-6)
    assert torch.allclose(grad.double(), expected_grad, rtol=1e-5, atol=1e-6)
    with torch.no_grad():
        assert torch.equal(Mish()(x), y.detach())
    layer = torch.nn.Linear(4, 8)
    inputs = torch.randn(64, 4)
    for activation in (Mish(), torch.nn.Mish()):
        layer.zero_grad()
        activation(layer(inputs)).square().sum().backward()
        assert layer.weight.grad is not None
        if isinstance(activation, Mish):
            ours_weight_grad = layer.weight.grad.clone()
    assert torch.allclose(ours_weight_grad, layer.weight.grad, rtol=1e-5, atol=1e-6)
