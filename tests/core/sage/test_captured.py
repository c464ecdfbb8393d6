"""The captured (CUDA graph) updates of SAGE-SAC and D3QN: the body a graph records, run eagerly on the CPU, agrees
with the reference update within float32 tolerance; ``learner.cuda_graph`` off CUDA is one clear error."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import torch

from core.device import DeviceError
from core.finetune import SharedReplayBuffer
from core.learners import make_learner
from core.sage.config import for_method
from core.sage.d3qn import CapturedD3QNUpdate
from core.sage.learner import BaseLearner
from core.sage.sac import SAC, CapturedSACUpdate

torch.set_num_threads(1)
OBS, ACT = 6, 2
EGO_LAYOUT = {
    "ego_sectors": 4, "ego_scan_start": -0.6, "ego_sector_width": 0.3, "ego_rays_per_sector": 2,
    "ego_forward_channel": 0, "ego_forward_scale": 0.01, "ego_turn_channel": 1, "ego_turn_scale": 0.1,
}  # fmt: skip
"""A 4-sector scan in the first channels, moved by the action's forward and turn channels (the ego step's tests)."""


def sage_learner(prior_rows: int = 0, device: str = "cpu", **overrides: object) -> BaseLearner:
    """``prior_rows``: the first rows are a base policy's drives in a fine-tuning buffer (the distillation anchor's);
    ``device``: where the update runs (``tests/core/sage/test_cuda.py`` builds the same learner on CUDA)."""
    cfg = for_method("sage", hidden=32, batch_size=64, bc_batch_size=32, **overrides)
    cfg.world_model_config.hidden = 32
    cfg.world_model_config.max_updates_per_fit = 60
    learner = make_learner("sage", cfg, OBS, ACT, seed=0, device=device)
    if prior_rows:
        learner.buffer = SharedReplayBuffer(OBS, ACT, learner.buffer.capacity, prior_share=0.5)
    rng = np.random.default_rng(0)
    s = rng.normal(size=(401, OBS)).astype(np.float32)
    for i in range(400):
        a = rng.uniform(-1, 1, ACT).astype(np.float32)
        takeover = i % 5 == 0 and i >= prior_rows
        if isinstance(learner.buffer, SharedReplayBuffer):
            learner.buffer.adding_prior = i < prior_rows
        learner.buffer.add(
            s[i], a, float(-np.abs(s[i]).sum()), s[i + 1], False, cost=float(i % 37 == 0), violation=i % 37 == 0,
            takeover=takeover, a_rl=-a, a_expert=a if takeover else None,
        )  # fmt: skip
    learner.warm = True
    learner.fit_world_model()
    return learner


def d3qn_learner(device: str = "cpu", **overrides: object) -> BaseLearner:
    cfg = for_method("sage", hidden=32, batch_size=64, bc_batch_size=32, **overrides)
    cfg.method = "sage-d3qn"
    cfg.world_model_config.hidden = 32
    cfg.world_model_config.max_updates_per_fit = 60
    learner = make_learner("sage-d3qn", cfg, OBS, 1, np.array([0.0]), np.array([2.0]), seed=0, device=device)
    rng = np.random.default_rng(0)
    s = rng.normal(size=(401, OBS)).astype(np.float32)
    for i in range(400):
        takeover = i % 5 == 0
        action = np.array([i % 3], np.float32)
        learner.buffer.add(
            s[i], learner.encode_action(action), float(-np.abs(s[i]).sum()), s[i + 1], False,
            cost=float(i % 37 == 0), violation=i % 37 == 0, takeover=takeover,
            a_rl=learner.encode_action(np.array([(i + 1) % 3], np.float32)),
            a_expert=learner.encode_action(action) if takeover else None,
        )  # fmt: skip
    learner.warm = True
    learner.fit_world_model()
    return learner


def assert_same_update(reference: BaseLearner, captured: BaseLearner, run_captured: object, updates: int = 3) -> None:
    for _ in range(updates):
        torch.manual_seed(7)
        expected = reference.update()
        torch.manual_seed(7)
        got = run_captured()  # type: ignore[operator]
        assert set(got) == set(expected)
        for key, value in expected.items():
            assert got[key] == pytest.approx(value, rel=1e-4, abs=1e-5), key
        assert captured.lam == pytest.approx(reference.lam, rel=1e-5, abs=1e-7)
    for name in reference.declared_state().modules:
        for key, value in getattr(reference, name).state_dict().items():
            torch.testing.assert_close(getattr(captured, name).state_dict()[key], value, rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize("virtual_ratio", [0.25, 0.0])
def test_the_captured_sage_sac_body_agrees_with_the_reference_update(virtual_ratio: float) -> None:
    reference = sage_learner(virtual_ratio=virtual_ratio)
    assert reference.fear_active()
    captured = copy.deepcopy(reference)
    assert_same_update(reference, captured, CapturedSACUpdate(captured, eager=True))


def test_the_captured_sage_sac_body_weighs_fear_as_the_reference_with_fear_scale_q() -> None:
    reference = sage_learner(fear_scale="q")
    assert isinstance(reference, SAC) and reference.fear_active()
    with torch.no_grad():  # values of tens, so that the scale max(1, mean|Q|) is not 1
        reference.critic.out.weight.mul_(300.0)
        reference.critic.out.bias.mul_(300.0)
        reference.critic_target.load_state_dict(reference.critic.state_dict())
    batch = reference.buffer.sample(64, np.random.default_rng(0))
    assert reference.critic(batch.obs, batch.action).abs().mean() > 5.0
    captured = copy.deepcopy(reference)
    assert_same_update(reference, captured, CapturedSACUpdate(captured, eager=True))


def test_the_captured_sage_sac_body_holds_the_actor_to_the_prior_rows_as_the_reference() -> None:
    reference = sage_learner(prior_rows=100)
    assert isinstance(reference, SAC)
    reference.prior_distill = 2.0
    assert "prior_distill_loss" in copy.deepcopy(reference).update()  # the reference update runs the anchor
    captured = copy.deepcopy(reference)
    assert_same_update(reference, captured, CapturedSACUpdate(captured, eager=True))  # the same statistics' names


def test_the_captured_sage_sac_body_over_the_ego_step_agrees_with_the_reference() -> None:
    pytest.importorskip("numba")
    from core.sage.config import WorldModelConfig

    assert set(EGO_LAYOUT) <= set(WorldModelConfig.__dataclass_fields__)
    reference = sage_learner(**{f"world_model_config.{k}": v for k, v in EGO_LAYOUT.items()})
    assert reference.world_model is not None and reference.world_model.ego is not None and reference.fear_active()
    captured = copy.deepcopy(reference)
    assert_same_update(reference, captured, CapturedSACUpdate(captured, eager=True), updates=2)


def test_the_captured_d3qn_body_agrees_with_the_reference_update() -> None:
    reference = d3qn_learner()
    assert reference.fear_active()
    captured = copy.deepcopy(reference)
    assert_same_update(reference, captured, CapturedD3QNUpdate(captured, eager=True))


def test_cuda_graph_off_cuda_is_one_clear_error() -> None:
    learner = sage_learner(cuda_graph=True)
    assert learner.device.type == "cpu" and not learner.captures
    with pytest.raises(DeviceError, match="needs --device cuda") as caught:
        learner.update()
    assert "\n" not in str(caught.value)
    with pytest.raises(DeviceError, match="needs --device cuda"):
        CapturedSACUpdate(learner)
