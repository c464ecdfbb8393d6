"""The learner's fear rollout computes what the plain rollout computed before it was made cheaper (issue 63): the first
layer as one product per input block, the output layer without its log-variance columns, and with
``states_needed=False`` no last imagined state but where contact reads it. Held to a verbatim copy of the plain
rollout, values and gradients (w.r.t. the first action and the policy), on models with and without the ego step,
the motion input and the approach input, with and without imagined contact, over one and three steps."""

from __future__ import annotations

import copy
import itertools

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from torch import Tensor

from core import motion as motion_module
from core.motion import approach_rate
from core.sage import fear as fear_module
from core.sage.calibration import calibrate
from core.sage.config import GateConfig, WorldModelConfig
from core.sage.fear import (
    PolicyFn,
    Rollout,
    contact_terms,
    fear,
    fear_of,
    next_motion,
    rollout,
    with_contact,
)
from core.sage.networks import Actor
from core.sage.world_model import EnsembleWorldModel, FoldedModel

torch.set_num_threads(1)
OBS, ACT = 6, 2
EGO = {
    "ego_sectors": 4, "ego_scan_start": -0.6, "ego_sector_width": 0.3, "ego_rays_per_sector": 2,
    "ego_forward_channel": 0, "ego_forward_scale": 0.05, "ego_turn_channel": 1, "ego_turn_scale": 0.2,
}  # fmt: skip
"""A 4-sector scan in the first channels, moved by the action's forward and turn channels."""
VARIANTS = {
    "plain": {"motion_input": False},
    "motion": {},
    "approach": {"approach_start": 0, "approach_stop": 4},
    "ego": EGO,
}


def reference_rollout(
    model: FoldedModel,
    policy: PolicyFn,
    obs: Tensor,
    action: Tensor,
    horizon: int,
    motion: Tensor | None = None,
    contact: Tensor | None = None,
    closing: Tensor | None = None,
) -> Rollout:
    """:func:`core.sage.fear.rollout` as it was before (commit c7a06ed): the concatenated first layer, the whole output
    layer, every state."""
    n, d = model.members, model.obs_dim
    batch = obs.shape[0]
    s = obs.unsqueeze(0).expand(n, batch, d)
    a = action.unsqueeze(0).expand(n, batch, action.shape[-1])
    m = None
    if model.motion:
        m = (torch.zeros_like(obs) if motion is None else motion).unsqueeze(0).expand(n, batch, d)
    states, actions, costs = [s], [], []
    for k in range(horizon):
        if m is None:
            h = torch.cat([s, a], dim=-1)
        elif model.approach is None:
            h = torch.cat([s, a, m], dim=-1)
        else:
            h = torch.cat([s, a, m, approach_rate(s, m, *model.approach)], dim=-1)
        for weight, bias in model.hidden:
            h = F.silu(torch.baddbmm(bias, h, weight))
        out = torch.baddbmm(model.out_bias, h, model.out_weight)
        base = model.base(obs, action).expand(n, batch, d) if k == 0 else model.base(s, a)
        s_next = base + out[..., :d]
        if m is not None and k + 1 < horizon:
            if model.scan is not None:
                m = model.scan.motion(s, s_next)
            else:
                m = next_motion(m, out[..., :d] if model.ego is None else s_next - s, model.motion_lag)
        s = s_next
        states.append(s)
        actions.append(a)
        costs.append(out[..., d])
        if k + 1 < horizon:
            a = policy(s.reshape(n * batch, d)).reshape(n, batch, -1)
    probability = torch.sigmoid(torch.stack(costs))
    spread = (probability - probability.mean(1, keepdim=True)).square().mean(1)
    sigma_raw = spread.clamp_min(1e-12).sqrt()
    cost = with_contact(probability, torch.stack(states[1:]), contact, closing)
    return Rollout(torch.stack(states), torch.stack(actions), cost, sigma_raw)


def states(rng: np.random.Generator, n: int) -> np.ndarray:
    """Ranges in the first four channels (the ego step's scan: some beyond the scan's reach at 1), the rest free."""
    ranges = rng.uniform(0.2, 1.2, (n, 4)).clip(max=1.0)
    return np.concatenate([ranges, rng.normal(size=(n, OBS - 4))], axis=1).astype(np.float32)


def model_and_actor(variant: str) -> tuple[EnsembleWorldModel, Actor]:
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    cfg = WorldModelConfig(hidden=32, max_updates_per_fit=40)
    for key, value in VARIANTS[variant].items():
        setattr(cfg, key, value)
    model = EnsembleWorldModel(OBS, ACT, cfg)
    s, a = states(rng, 300), rng.uniform(-1, 1, (300, ACT)).astype(np.float32)
    s_next = s + 0.05 * rng.normal(size=s.shape).astype(np.float32)
    model.fit(s, a, s_next, (s[:, :4].min(1) < 0.35).astype(np.float32), rng)
    actor = Actor(OBS, ACT, 32, 2, -torch.ones(ACT), torch.ones(ACT))
    calibrate(model, actor.deterministic, torch.as_tensor(s), 3)
    return model, actor


def gate_config(contact: bool) -> GateConfig:
    if not contact:
        return GateConfig(beta=0.4)
    return GateConfig(beta=0.4, imagined_contact=True, contact_floors=[0.35] * 4)


def fear_and_gradients(
    rollout_fn: object, variant: str, horizon: int, contact: bool, with_motion: bool
) -> tuple[Tensor, Tensor, list[Tensor]]:
    model, actor = model_and_actor(variant)
    folded, cfg = model.folded(), gate_config(contact)
    g = torch.Generator().manual_seed(3)
    obs = torch.as_tensor(states(np.random.default_rng(3), 64))
    motion = 0.05 * torch.randn(64, OBS, generator=g) if with_motion else None
    action = actor.deterministic(obs) + 0.3 * torch.randn(64, ACT, generator=g)
    action = action.clamp(-1, 1).detach().requires_grad_(True)
    ro = rollout_fn(folded, actor.deterministic, obs, action, horizon, motion, *contact_terms(cfg, motion))  # type: ignore[operator]
    value = fear_of(folded, ro, cfg).fear
    if contact:  # some imagined states touch: the contact test is exercised
        assert bool((ro.cost == 1.0).any()) and bool((ro.cost < 1.0).any())
    params = list(actor.parameters())
    grads = torch.autograd.grad(value.sum(), [action, *params], allow_unused=True)
    zeros = [torch.zeros_like(p) if g is None else g for p, g in zip([action, *params], grads, strict=True)]
    return value.detach(), zeros[0], zeros[1:]


@pytest.mark.parametrize(
    ("variant", "horizon", "contact", "with_motion"),
    [
        (v, h, c, m)
        for v, h, c, m in itertools.product(VARIANTS, [1, 3], [False, True], [False, True])
        if not (m and v == "plain")
    ],
)
def test_the_fear_rollout_equals_the_plain_one_in_value_and_gradient(
    variant: str, horizon: int, contact: bool, with_motion: bool
) -> None:
    if variant == "ego":
        pytest.importorskip("numba")

    def fast(*args: object) -> Rollout:
        return rollout(*args, states_needed=False)  # type: ignore[arg-type]

    expected, expected_action, expected_params = fear_and_gradients(
        reference_rollout, variant, horizon, contact, with_motion
    )
    got, got_action, got_params = fear_and_gradients(fast, variant, horizon, contact, with_motion)
    assert float(expected.std()) > 1e-4  # the states differ in fear: the comparison can fail
    torch.testing.assert_close(got, expected, rtol=1e-5, atol=1e-6)
    assert float(expected_action.abs().sum()) > 0
    torch.testing.assert_close(got_action, expected_action, rtol=1e-4, atol=1e-6)
    for value, reference in zip(got_params, expected_params, strict=True):
        torch.testing.assert_close(value, reference, rtol=1e-4, atol=1e-6)


@pytest.mark.parametrize("variant", ["motion", "ego"])
def test_a_rollout_that_keeps_its_states_equals_the_plain_one(variant: str) -> None:
    if variant == "ego":
        pytest.importorskip("numba")
    model, actor = model_and_actor(variant)
    folded, cfg = model.folded(), gate_config(True)
    obs = torch.as_tensor(states(np.random.default_rng(4), 32))
    with torch.no_grad():
        action = actor.deterministic(obs)
        expected = reference_rollout(folded, actor.deterministic, obs, action, 3, None, *contact_terms(cfg, None))
        got = rollout(folded, actor.deterministic, obs, action, 3, None, *contact_terms(cfg, None))
    for name in ("states", "actions", "cost", "sigma_raw"):
        torch.testing.assert_close(getattr(got, name), getattr(expected, name), rtol=1e-5, atol=1e-6)


def test_without_contact_the_last_imagined_state_is_not_computed(monkeypatch: pytest.MonkeyPatch) -> None:
    """Where only the fear terms are read, one step over the ego step costs no ego step at all."""
    pytest.importorskip("numba")
    model, actor = model_and_actor("ego")
    calls: list[int] = []
    apply = motion_module.EgoScanStep.apply

    def counted(step: motion_module.EgoScanStep, state: Tensor, action: Tensor) -> Tensor:
        calls.append(len(state))
        return apply(step, state, action)

    contact = motion_module.EgoScanStep.contact

    def counted_contact(step: motion_module.EgoScanStep, state: Tensor, *args: object) -> Tensor:
        calls.append(len(state))
        return contact(step, state, *args)  # type: ignore[arg-type]

    monkeypatch.setattr(motion_module.EgoScanStep, "apply", counted)
    monkeypatch.setattr(motion_module.EgoScanStep, "contact", counted_contact)
    obs = torch.as_tensor(states(np.random.default_rng(5), 16))
    action = actor.deterministic(obs).detach().requires_grad_(True)
    fear(model.folded(), actor.deterministic, obs, action, gate_config(False), horizon=1).fear.sum().backward()
    assert calls == []
    fear(model.folded(), actor.deterministic, obs, action, gate_config(True), horizon=1).fear.sum().backward()
    assert calls == [16]  # once, on the batch's rows (not once per member), moved and tested in one call


def test_the_sage_sac_losses_equal_those_of_the_plain_rollout(monkeypatch: pytest.MonkeyPatch) -> None:
    """One SAGE-SAC update over the ego step (critic target, critic and actor losses, λ, the new weights) on a fixed
    seed batch, with the learner's fear rollout and with the plain one."""
    pytest.importorskip("numba")
    from tests.core.sage.test_captured import sage_learner

    fast = sage_learner(**{f"world_model_config.{k}": v for k, v in EGO.items()})
    assert fast.world_model is not None and fast.world_model.ego is not None and fast.fear_active()
    plain = copy.deepcopy(fast)
    torch.manual_seed(7)
    got = fast.update()
    monkeypatch.setattr(fear_module, "rollout", lambda *args, states_needed=True: reference_rollout(*args))
    torch.manual_seed(7)
    expected = plain.update()
    assert set(got) == set(expected) and "fear_real" in got
    for key, value in expected.items():
        assert got[key] == pytest.approx(value, rel=1e-5, abs=1e-6), key
    for name in ("actor", "critic"):
        for key, value in getattr(plain, name).state_dict().items():
            torch.testing.assert_close(getattr(fast, name).state_dict()[key], value, rtol=1e-5, atol=1e-6)
