"""State novelty as curiosity (``gate.curiosity_signal=novelty``, :mod:`core.sage.novelty`): about its reference on
training states, clearly above it off them, kept through a checkpoint, and a bad setting refused in one line."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from core.sage.calibration import calibrate
from core.sage.config import AgentConfig, GateConfig, WorldModelConfig, validate
from core.sage.gate import SageGate
from core.sage.networks import Actor
from core.sage.novelty import REFERENCE_STATES, NoveltyReference, fit_reference
from core.sage.world_model import EnsembleWorldModel

torch.set_num_threads(1)

NOVELTY = GateConfig(
    curiosity_signal="novelty", curiosity_reference="fitted", tau_min=0.2, tau_max=0.8, tau_from_data=False
)


def fitted_model(motion: bool = True) -> tuple[EnsembleWorldModel, np.ndarray, np.ndarray]:
    """A model fitted on states near the origin, with (by default) the motion input."""
    rng = np.random.default_rng(0)
    model = EnsembleWorldModel(3, 2, WorldModelConfig(hidden=16, max_updates_per_fit=50, motion_input=motion))
    s = rng.normal(size=(3000, 3)).astype(np.float32)
    a = rng.uniform(-1, 1, (3000, 2)).astype(np.float32)
    model.fit(s, a, s + 0.1 * a.sum(1, keepdims=True), np.zeros(3000, np.float32), rng)
    return model, s, a


def actor() -> Actor:
    torch.manual_seed(0)
    return Actor(3, 2, 16, 1, -torch.ones(2), torch.ones(2))


def test_novelty_is_about_its_reference_on_training_states_and_higher_off_them() -> None:
    rng = np.random.default_rng(1)
    train = torch.from_numpy(rng.normal(size=(6000, 4)).astype(np.float32))
    states, center, scale, mean = fit_reference(train)
    assert len(states) == REFERENCE_STATES
    reference = NoveltyReference.of(states, center, scale)
    fresh = torch.from_numpy(rng.normal(size=(1000, 4)).astype(np.float32))  # more states of the same ground
    assert float(reference(fresh).mean()) == pytest.approx(mean, rel=0.1)
    shifted = fresh + torch.tensor([0.0, 0.0, 4.0, 0.0])  # one feature four spreads away
    assert float(reference(shifted).mean()) > 2 * mean
    # a row of the set is its own nearest neighbour: the matrix-product distance agrees with the plain one
    x = states[:3]
    plain = ((x[:, None] - states[None]) * reference.inv_scale).square().mean(-1).sqrt().sort(-1).values[:, :5].mean(-1)
    assert torch.allclose(reference(x), plain, atol=1e-4)


def test_the_gate_reads_novelty_against_the_calibrated_mean_and_lowers_tau_off_the_training_states() -> None:
    model, s, a = fitted_model()
    policy = actor()
    assert model.novelty_reference() is None
    # the states as a trajectory: each one's motion input is its change from the one before
    obs, motion = torch.from_numpy(s[1:]), torch.from_numpy(s[1:] - s[:-1])
    calibrate(model, policy.deterministic, obs, 3, cfg=GateConfig(), motion=motion)
    assert model.novelty_reference() is None  # a gate that does not read it keeps no set
    calibrate(model, policy.deterministic, obs, 3, cfg=NOVELTY, motion=motion)
    reference = float(model.novelty_ref)
    assert np.isfinite(reference) and reference > 0
    familiar, novel = SageGate(model, policy, NOVELTY), SageGate(model, policy, NOVELTY)
    assert familiar.threshold.ema == pytest.approx(reference)
    seen, unseen = [], []
    for t in range(200):
        seen.append(familiar.observe(s[t], a[t], s[t + 1]))
        unseen.append(novel.observe(s[t] + 4.0, a[t], s[t + 1] + 4.0))
    assert np.mean(seen) == pytest.approx(reference, rel=0.5)
    assert np.mean(unseen) > 3 * np.mean(seen)
    assert novel.threshold.threshold < familiar.threshold.threshold
    assert novel.threshold.threshold < 0.3  # the fixed reference keeps ground that stays novel novel


def test_the_reference_set_survives_a_checkpoint_and_an_old_one_is_refused_in_one_line() -> None:
    model, s, _ = fitted_model()
    calibrate(model, actor().deterministic, torch.from_numpy(s), 3, cfg=NOVELTY)
    saved = {k: v.half() if v.dtype == torch.float32 else v for k, v in model.state_dict().items()}  # as committed
    reloaded = EnsembleWorldModel(3, 2, model.cfg)
    assert reloaded.reads(saved)
    reloaded.load_state_dict({k: v.float() if v.dtype == torch.float16 else v for k, v in saved.items()})
    assert reloaded.novelty_states.shape == model.novelty_states.shape
    assert float(reloaded.novelty_ref) == pytest.approx(float(model.novelty_ref), rel=1e-3)
    assert float(model.novelty_ref) > 0
    probe = torch.from_numpy(s[:20] + 1.5)
    features = torch.cat([probe, torch.zeros_like(probe)], -1)
    before, after = model.novelty_reference(), reloaded.novelty_reference()
    assert before is not None and after is not None
    assert torch.allclose(before(features), after(features), rtol=1e-2, atol=1e-3)
    old = {k: v for k, v in model.state_dict().items() if not k.startswith("novelty_")}
    older = EnsembleWorldModel(3, 2, model.cfg)
    older.load_state_dict(old)
    with pytest.raises(ValueError, match="refit-bounds") as error:
        SageGate(older, actor(), NOVELTY)
    assert "\n" not in str(error.value)


def test_novelty_against_a_moving_average_is_refused_in_one_line() -> None:
    cfg = AgentConfig()
    cfg.gate.curiosity_signal = "novelty"
    with pytest.raises(ValueError, match="curiosity_reference=fitted") as error:
        validate(cfg)
    assert "\n" not in str(error.value)
    cfg.gate.curiosity_reference = "fitted"
    validate(cfg)
