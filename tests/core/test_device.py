"""``--device``: resolved in one place (:mod:`core.device`); a learner's update on it, its checkpoints device-free."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from core.device import DeviceError, resolve_device, to_cpu
from core.learners import make_learner
from core.sage.config import for_method

OBS, ACT = 6, 2


def filled(method: str, device: str) -> object:
    cfg = for_method(method, hidden=16, batch_size=32, critics=2)
    cfg.world_model_config.max_updates_per_fit = 10
    learner = make_learner(method, cfg, OBS, ACT, seed=0, device=device)
    rng = np.random.default_rng(0)
    for i in range(200):
        obs = rng.random(OBS).astype(np.float32)
        action = rng.uniform(-1, 1, ACT).astype(np.float32)
        takeover = i % 10 == 0
        learner.buffer.add(
            obs, action, float(rng.normal()), obs + 0.01, False, cost=0.0, violation=i % 50 == 0, takeover=takeover,
            a_rl=action, a_expert=action if takeover else None,
        )  # fmt: skip
    learner.warm = True
    if learner.world_model is not None:
        learner.fit_world_model()
    return learner


def test_auto_resolves_to_the_cpu_without_cuda() -> None:
    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA: auto is cuda here")
    assert resolve_device("auto") == torch.device("cpu")
    assert resolve_device(None) == torch.device("cpu")
    assert resolve_device("cpu") == torch.device("cpu")


def test_cuda_without_cuda_is_one_clear_error() -> None:
    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    with pytest.raises(DeviceError, match="no CUDA device") as caught:
        resolve_device("cuda")
    assert "\n" not in str(caught.value)
    with pytest.raises(DeviceError, match="choose one of auto, cpu, cuda"):
        resolve_device("tpu")
    with pytest.raises(DeviceError):
        make_learner("sac", for_method("sac"), OBS, ACT, device="cuda")


@pytest.mark.parametrize("method", ["sage", "sac", "td3", "sage-d3qn"])
def test_a_learner_on_the_cpu_device_trains_and_checkpoints(method: str, tmp_path: Path) -> None:
    if method == "sage-d3qn":
        cfg = for_method("sage", hidden=16, batch_size=32)
        cfg.method = "sage-d3qn"
        learner = make_learner("sage-d3qn", cfg, OBS, 1, np.array([0.0]), np.array([2.0]), device="cpu")
        rng = np.random.default_rng(0)
        for i in range(100):
            obs = rng.random(OBS).astype(np.float32)
            learner.buffer.add(obs, learner.encode_action([i % 3]), 0.0, obs, False)
        learner.warm = True
    else:
        learner = filled(method, "cpu")
    assert learner.device == torch.device("cpu")
    assert learner.buffer.sample(4, np.random.default_rng(0)).obs.device == torch.device("cpu")
    stats, applied = learner.guarded_update()
    assert applied and all(np.isfinite(float(v)) for v in stats.values())
    file = tmp_path / "state.pt"
    torch.save(learner.state_dict(), file)
    state = torch.load(file, map_location="cpu", weights_only=True)
    again = make_learner(learner.cfg.method, learner.cfg, learner.obs_dim, learner.act_dim,
                         learner.action_low.numpy(), learner.action_high.numpy(), device="auto")  # fmt: skip
    loaded = again.load_state_dict(state)
    assert again.acting_module in loaded
    for name, module in again._modules_for_state().items():
        for key, value in module.state_dict().items():
            torch.testing.assert_close(
                value.cpu(), getattr(learner, name).state_dict()[key], equal_nan=True, msg=name + key
            )  # ``auto`` is CUDA where there is one


def test_checkpoint_state_is_device_free() -> None:
    nested = {"a": torch.ones(2), "b": [torch.zeros(1), {"c": torch.tensor(3.0)}], "d": 1.5}
    moved = to_cpu(nested)
    assert moved["a"].device.type == "cpu" and moved["b"][1]["c"].device.type == "cpu" and moved["d"] == 1.5
    learner = filled("sage", "cpu")
    state = learner.state_dict()
    devices = {t.device.type for t in _tensors(state)}
    assert devices == {"cpu"}


def test_the_acting_network_is_the_trained_one_on_the_cpu() -> None:
    learner = filled("sac", "cpu")
    assert learner.acting_network() is learner.actor  # no copy, no sync: CPU runs behave as before


def _tensors(value: object) -> list[torch.Tensor]:
    if isinstance(value, torch.Tensor):
        return [value]
    if isinstance(value, dict):
        return [t for v in value.values() for t in _tensors(v)]
    if isinstance(value, list | tuple):
        return [t for v in value for t in _tensors(v)]
    return []
