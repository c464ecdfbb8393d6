"""Curiosity as the ensemble's disagreement, against a fixed reference (``gate.curiosity_signal``,
``gate.curiosity_reference``): what it measures, where its reference comes from, and that the paper's default holds."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from core.sage.calibration import calibrate
from core.sage.config import GateConfig, WorldModelConfig
from core.sage.gate import SageGate
from core.sage.networks import Actor
from core.sage.world_model import EnsembleWorldModel

torch.set_num_threads(1)


def fitted_model(updates: int = 300) -> tuple[EnsembleWorldModel, np.ndarray, np.ndarray]:
    """A model fitted on states near the origin (|s| of order 1)."""
    rng = np.random.default_rng(0)
    model = EnsembleWorldModel(3, 2, WorldModelConfig(hidden=32, max_updates_per_fit=updates))
    s = rng.normal(size=(400, 3)).astype(np.float32)
    a = rng.uniform(-1, 1, (400, 2)).astype(np.float32)
    model.fit(s, a, s + 0.1 * a.sum(1, keepdims=True), np.zeros(400, np.float32), rng)
    return model, s, a


def actor() -> Actor:
    torch.manual_seed(0)
    return Actor(3, 2, 16, 1, -torch.ones(2), torch.ones(2))


def test_disagreement_rises_off_the_training_data_and_vanishes_for_identical_members() -> None:
    model, s, a = fitted_model()
    near = model.disagreement(torch.from_numpy(s[:50]), torch.from_numpy(a[:50])).mean()
    far = model.disagreement(torch.from_numpy(s[:50] + 8.0), torch.from_numpy(a[:50])).mean()
    assert far > 3 * near > 0
    twins = {k: v.clone() for k, v in model.state_dict().items()}
    for name in model._member_parameter_names():
        twins[name] = twins[name][:1].expand_as(twins[name]).clone()  # every member the first one
    model.load_state_dict(twins)
    assert float(model.disagreement(torch.from_numpy(s[:50]), torch.from_numpy(a[:50])).max()) < 1e-5


def test_calibration_measures_the_reference_and_an_old_checkpoint_reads_as_unmeasured() -> None:
    model, s, _ = fitted_model()
    assert np.isnan(float(model.disagreement_ref))
    policy = actor()
    calibrate(model, policy.deterministic, torch.from_numpy(s), 3, cfg=GateConfig())
    expected = model.disagreement(torch.from_numpy(s), policy.deterministic(torch.from_numpy(s))).mean()
    assert float(model.disagreement_ref) == pytest.approx(float(expected), rel=1e-4)
    old = {k: v for k, v in model.state_dict().items() if k != "disagreement_ref"}
    reloaded = EnsembleWorldModel(3, 2, model.cfg)
    reloaded.load_state_dict(old)
    assert np.isnan(float(reloaded.disagreement_ref))
    with pytest.raises(ValueError, match="refit-bounds"):
        SageGate(reloaded, actor(), GateConfig(curiosity_signal="disagreement"))


def test_the_gate_scores_disagreement_and_a_fitted_reference_keeps_novel_ground_novel() -> None:
    model, s, a = fitted_model()
    policy = actor()
    calibrate(model, policy.deterministic, torch.from_numpy(s), 3, cfg=GateConfig())
    bounds = dict(tau_min=0.2, tau_max=0.8, tau_from_data=False)
    fixed = SageGate(model, policy, GateConfig(curiosity_signal="disagreement", curiosity_reference="fitted", **bounds))
    recent = SageGate(model, policy, GateConfig(curiosity_signal="disagreement", **bounds))
    paper = SageGate(model, policy, GateConfig(**bounds))
    novel = s[0] + 8.0
    expected = float(model.disagreement(torch.from_numpy(novel).view(1, -1), torch.from_numpy(a[0]).view(1, -1))[0])
    for _ in range(300):  # ground that stays novel
        for gate in (fixed, recent):
            value = gate.observe(novel, a[0], novel)
        assert value == pytest.approx(expected, rel=1e-4)
    # the fixed reference still reads it as novel; the moving average has caught up with it
    assert fixed.threshold.threshold < 0.25
    assert recent.threshold.threshold > 0.45
    assert fixed.threshold.ema == pytest.approx(float(model.disagreement_ref))
    # the paper's curiosity is the prediction error, not the disagreement
    error = paper.observe(s[0], a[0], s[0] + 5.0)
    assert error != pytest.approx(float(model.disagreement(torch.from_numpy(s[:1]), torch.from_numpy(a[:1]))[0]))


def test_a_saved_average_is_read_back_only_by_a_gate_of_the_same_signal() -> None:
    model, s, _ = fitted_model()
    policy = actor()
    calibrate(model, policy.deterministic, torch.from_numpy(s), 3, cfg=GateConfig())
    paper = SageGate(model, policy, GateConfig())
    paper.threshold.ema = 7.0
    other = SageGate(model, policy, GateConfig(curiosity_signal="disagreement"))
    other.load_state(paper.state())
    assert other.threshold.ema == pytest.approx(float(model.disagreement_ref))
    same = SageGate(model, policy, GateConfig())
    same.load_state(paper.state())
    assert same.threshold.ema == 7.0


@pytest.mark.parametrize("compiled", [True, False])
def test_the_disagreement_after_a_decision_is_read_from_its_first_step_not_predicted_again(
    compiled: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    model, s, a = fitted_model()
    policy = actor()
    calibrate(model, policy.deterministic, torch.from_numpy(s), 3, cfg=GateConfig())
    cfg = GateConfig(curiosity_signal="disagreement", curiosity_reference="fitted")
    reused, predicted = (SageGate(model, policy, cfg, compiled=compiled) for _ in range(2))
    values = []
    for i in range(6):
        obs = s[i] + 2.0 * i  # from familiar to novel ground, with the motion history a gate keeps
        decided = policy.deterministic(torch.from_numpy(obs).view(1, -1))[0].detach().numpy()
        reused.decide(obs, decided)
        predicted.decide(obs, decided)
        with monkeypatch.context() as patched:  # the policy's own action: no second prediction
            patched.setattr(model, "disagreement", lambda *_: pytest.fail("predicted again"))
            value = reused.observe(obs, decided, obs)
        # another state object than the decided one: the disagreement predicted for what was executed
        assert value == pytest.approx(predicted.observe(obs.copy(), decided, obs), rel=1e-4, abs=1e-7)
        values.append(value)
    assert values[-1] > 3 * values[0] > 0  # it still rises off the training data
    other = SageGate(model, policy, cfg, compiled=compiled)
    other.decide(s[0], decided)  # an expert's action after the decision: predicted for it, not the decided one's
    expected = float(model.disagreement(torch.from_numpy(s[:1]), torch.from_numpy(a[:1]))[0])
    assert other.observe(s[0], a[0], s[0]) == pytest.approx(expected, rel=1e-4, abs=1e-7)
