"""The learner's one-step fear (``core.sage.fear.one_step_fear``, issue 63) computes what ``fear(..., horizon=1)``
computes: values and the gradient w.r.t. the action, with and without imagined contact and the ego step, under a
gradient and without one. Its own forward and its hand-written backward agree with torch's autograd through
``rollout`` and ``fear_of`` up to float32 rounding (both sum products in a different order)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from torch import Tensor

from core.sage import fear as fear_module
from core.sage.config import GateConfig
from core.sage.fear import fear, one_step_fear
from tests.core.sage.test_fear_rollout import VARIANTS, gate_config, model_and_actor, states

torch.set_num_threads(1)


def inputs(variant: str, rows: int = 64) -> tuple[fear_module.FoldedModel, object, Tensor, Tensor]:
    model, actor = model_and_actor(variant)
    g = torch.Generator().manual_seed(5)
    obs = torch.as_tensor(states(np.random.default_rng(5), rows))
    action = (actor.deterministic(obs) + 0.3 * torch.randn(rows, 2, generator=g)).clamp(-1, 1).detach()
    return model.folded(), actor.deterministic, obs, action


def value_and_gradient(fn: object, model: object, policy: object, obs: Tensor, action: Tensor, cfg: GateConfig):
    action = action.clone().requires_grad_(True)
    value = fn(model, policy, obs, action, cfg)  # type: ignore[operator]
    weights = torch.linspace(0.5, 1.5, len(obs))  # a gradient that differs per row
    (gradient,) = torch.autograd.grad((value * weights).sum(), [action])
    return value.detach(), gradient


def reference(model: object, policy: object, obs: Tensor, action: Tensor, cfg: GateConfig) -> Tensor:
    return fear(model, policy, obs, action, cfg, horizon=1).fear  # type: ignore[arg-type]


@pytest.mark.parametrize("variant", list(VARIANTS))
@pytest.mark.parametrize("contact", [False, True])
def test_one_step_fear_equals_fear_over_one_step(variant: str, contact: bool) -> None:
    if variant == "ego":
        pytest.importorskip("numba")
    model, policy, obs, action = inputs(variant)
    cfg = gate_config(contact)
    expected, expected_grad = value_and_gradient(reference, model, policy, obs, action, cfg)
    got, got_grad = value_and_gradient(one_step_fear, model, policy, obs, action, cfg)
    assert float(expected.std()) > 1e-4  # the rows differ in fear: the comparison can fail
    assert float(expected_grad.abs().sum()) > 0
    torch.testing.assert_close(got, expected, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(got_grad, expected_grad, rtol=1e-4, atol=1e-6)
    with torch.no_grad():  # the critic target's call: no graph
        torch.testing.assert_close(one_step_fear(model, policy, obs, action, cfg), expected, rtol=1e-5, atol=1e-6)


def test_the_ego_contact_case_runs_no_rollout_and_tests_contact(monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip("numba")
    model, policy, obs, action = inputs("ego")
    cfg = gate_config(True)
    expected, expected_grad = value_and_gradient(reference, model, policy, obs, action, cfg)

    def refused(*args: object, **kwargs: object) -> None:
        raise AssertionError("one_step_fear rolled out")

    monkeypatch.setattr(fear_module, "rollout", refused)
    got, got_grad = value_and_gradient(one_step_fear, model, policy, obs, action, cfg)
    torch.testing.assert_close(got, expected, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(got_grad, expected_grad, rtol=1e-4, atol=1e-6)
    # contact decides some rows: their ĉ is raised by members in contact, which the gradient then skips
    no_contact = one_step_fear(model, policy, obs, action, gate_config(False))
    assert bool((got > no_contact + 1e-3).any()) and bool((got - no_contact).abs().lt(1e-7).any())


def test_contact_that_needs_closing_counts_none_without_a_motion() -> None:
    pytest.importorskip("numba")
    model, policy, obs, action = inputs("ego")
    cfg = dataclasses.replace(gate_config(True), contact_needs_closing=True)
    expected, expected_grad = value_and_gradient(reference, model, policy, obs, action, cfg)
    got, got_grad = value_and_gradient(one_step_fear, model, policy, obs, action, cfg)
    torch.testing.assert_close(got, expected, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(got_grad, expected_grad, rtol=1e-4, atol=1e-6)
    torch.testing.assert_close(got, one_step_fear(model, policy, obs, action, gate_config(False)))
