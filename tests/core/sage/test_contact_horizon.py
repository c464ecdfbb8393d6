"""``gate.contact_horizon``: imagined contact reaches past the gate's horizon while the learned head (ĉ) and σ̂ keep
theirs. None reproduces today's fear; a contact imagined only past the horizon raises fear, one imagined within it
counts as before; the torch kernel, the compiled kernel and the reference rollout agree."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from core.agents import fear_shape_moved
from core.sage.calibration import calibrate
from core.sage.compiled_gate import CompiledGateKernel
from core.sage.config import AgentConfig, GateConfig, WorldModelConfig, parse_gate_settings, validate
from core.sage.fear import GateKernel, fear, fear_of, rollout
from core.sage.gate import SageGate
from core.sage.networks import Actor
from core.sage.world_model import EnsembleWorldModel

torch.set_num_threads(1)

OBS, ACT, HORIZON, REACH = 6, 2, 5, 10
RTOL, ATOL = 1e-5, 1e-6


def rare_danger_model() -> tuple[EnsembleWorldModel, Actor]:
    """A briefly fitted model whose learned violation probability is low (rare labels), as on ordinary ground, so
    that an imagined contact shows in ĉ; κ set on its own states."""
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    model = EnsembleWorldModel(OBS, ACT, WorldModelConfig(hidden=32, max_updates_per_fit=60))
    s = rng.normal(size=(300, OBS)).astype(np.float32)
    a = rng.uniform(-1, 1, (300, ACT)).astype(np.float32)
    labels = (rng.random(300) < 0.03).astype(np.float32)
    model.fit(s, a, s + 0.1 * rng.normal(size=s.shape).astype(np.float32), labels, rng)
    actor = Actor(OBS, ACT, 32, 2, -torch.ones(ACT) * 2, torch.ones(ACT) * 2)
    calibrate(model, actor.deterministic, torch.as_tensor(s), HORIZON)
    return model, actor


def start() -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(0)
    return torch.randn(1, OBS, generator=g), torch.rand(1, ACT, generator=g) * 4 - 2


def contact_cfg(floor: float, reach: int | None) -> GateConfig:
    return GateConfig(beta=0.5, horizon=HORIZON, imagined_contact=True, contact_floors=[floor], contact_horizon=reach)


def kernels(model: EnsembleWorldModel, actor: Actor, cfg: GateConfig) -> list[GateKernel]:
    folded, layers = model.folded(), actor.deterministic_layers()
    return [
        build(folded, layers, actor.action_scale, actor.action_bias, cfg) for build in (GateKernel, CompiledGateKernel)
    ]


def all_paths(model: EnsembleWorldModel, actor: Actor, cfg: GateConfig) -> tuple[float, float, float]:
    """(F, ĉ, σ̂) of the reference rollout, after checking the torch and the compiled kernel against it."""
    obs, action = start()
    with torch.inference_mode():
        reference = fear(model.folded(), actor.deterministic, obs, action, cfg)
        expected = (float(reference.fear), float(reference.cost), float(reference.sigma))
        for kernel in kernels(model, actor, cfg):
            np.testing.assert_allclose(kernel(obs, action), expected, rtol=RTOL, atol=ATOL)
    return expected


def channel0(model: EnsembleWorldModel, actor: Actor) -> tuple[torch.Tensor, float]:
    """Each member's imagined channel 0 over REACH steps ((REACH, N)), and the learned ĉ of the first HORIZON."""
    obs, action = start()
    with torch.no_grad():
        ro = rollout(model.folded(), actor.deterministic, obs, action, REACH)
    return ro.states[1:, :, 0, 0], float(ro.cost[:HORIZON].mean(1).max())


def test_none_and_a_reach_within_the_horizon_reproduce_todays_fear() -> None:
    model, actor = rare_danger_model()
    states, _ = channel0(model, actor)
    floor = float(states[:HORIZON].min()) + 1e-3  # some member in contact within the horizon
    obs, action = start()
    with torch.no_grad():  # today's computation, independent of the new code: a plain HORIZON-step rollout
        today = fear_of(
            model.folded(),
            rollout(model.folded(), actor.deterministic, obs, action, HORIZON, contact=torch.tensor([floor])),
            contact_cfg(floor, None),
        )
    for reach in (None, HORIZON, 3):
        got = all_paths(model, actor, contact_cfg(floor, reach))
        np.testing.assert_allclose(
            got, (float(today.fear), float(today.cost), float(today.sigma)), rtol=RTOL, atol=ATOL
        )
    assert len(kernels(model, actor, contact_cfg(floor, None))[0].last_member_costs()) == HORIZON


def test_a_contact_imagined_only_past_the_horizon_raises_fear_and_the_learned_terms_keep_their_reach() -> None:
    model, actor = rare_danger_model()
    states, learned_cost = channel0(model, actor)
    early, late = float(states[:HORIZON].min()), float(states[HORIZON:].min())
    assert late < early, "the imagined channel never falls past the horizon: pick another start"
    floor = (early + late) / 2  # no member in contact in the first HORIZON steps, some after them
    late_share = float((states[HORIZON:] <= floor).float().mean(1).max())
    assert late_share > learned_cost, "the learned ĉ already exceeds the late contact's share: the test reads nothing"
    today = all_paths(model, actor, contact_cfg(floor, None))
    reached = all_paths(model, actor, contact_cfg(floor, REACH))
    assert today[1] == pytest.approx(learned_cost, abs=ATOL)  # no contact within today's horizon
    assert reached[1] == pytest.approx(late_share, abs=ATOL) and reached[0] > today[0]
    assert reached[2] == pytest.approx(today[2], abs=ATOL)  # σ̂ keeps its 0.5 s
    # with no contact anywhere, the reach changes nothing: the learned head is not read past the horizon
    # (rolling the whole fear REACH steps would: gate.horizon=10, the candidate that failed its train check)
    nowhere = float(states.min()) - 1.0
    np.testing.assert_allclose(
        all_paths(model, actor, contact_cfg(nowhere, REACH)),
        all_paths(model, actor, contact_cfg(nowhere, None)),
        rtol=RTOL,
        atol=ATOL,
    )
    obs, action = start()
    for kernel in kernels(model, actor, contact_cfg(nowhere, REACH)):
        with torch.inference_mode():
            kernel(obs, action)
        assert kernel.last_member_costs().shape[0] == REACH and not kernel.last_member_costs()[HORIZON:].any()
    with torch.no_grad():  # where the learned head, rolled on, would have said something
        assert float(rollout(model.folded(), actor.deterministic, obs, action, REACH).cost[HORIZON:].min()) > 0.0


def test_a_contact_imagined_within_the_horizon_counts_as_before() -> None:
    model, actor = rare_danger_model()
    states, learned_cost = channel0(model, actor)
    floor = float(states[:HORIZON].min()) + 1e-3
    early_share = float((states[:HORIZON] <= floor).float().mean(1).max())
    today, reached = contact_cfg(floor, None), contact_cfg(floor, REACH)
    before, after = all_paths(model, actor, today), all_paths(model, actor, reached)
    assert before[1] >= early_share > learned_cost  # the contact within the horizon raises ĉ today
    assert after[1] >= before[1] - ATOL and after[2] == pytest.approx(before[2], abs=ATOL)
    obs, action = start()
    for kernel_today, kernel_reached in zip(kernels(model, actor, today), kernels(model, actor, reached), strict=True):
        with torch.inference_mode():
            kernel_today(obs, action), kernel_reached(obs, action)
        # each member's cost over the first HORIZON steps, contact included, as before; contact alone after them
        np.testing.assert_allclose(
            kernel_reached.last_member_costs()[:HORIZON], kernel_today.last_member_costs(), rtol=RTOL, atol=ATOL
        )
        assert set(np.unique(kernel_reached.last_member_costs()[HORIZON:])) <= {0.0, 1.0}


def test_the_compiled_gate_takes_the_reference_gates_decisions_with_a_longer_contact_reach() -> None:
    model, actor = rare_danger_model()
    rng = np.random.default_rng(3)
    states = rng.normal(size=(121, OBS)).astype(np.float32)
    actions = rng.uniform(-2, 2, (120, ACT)).astype(np.float32)
    floor = float(np.quantile(states[:, 0], 0.1))
    cfg = dataclasses.replace(contact_cfg(floor, REACH), hold_steps=2, tau_from_data=False, tau_min=0.2, tau_max=0.3)
    gates = [SageGate(model, actor, cfg, compiled=compiled) for compiled in (False, True)]
    assert [type(g.kernel()) for g in gates] == [GateKernel, CompiledGateKernel]
    records: list[list[tuple[bool, float]]] = [[], []]
    for i in range(120):
        for g, record in zip(gates, records, strict=True):
            decision = g.decide(states[i], actions[i])
            g.observe(states[i], actions[i], states[i + 1])
            record.append((decision.fired, decision.fear))
    assert [r[0] for r in records[0]] == [r[0] for r in records[1]] and any(r[0] for r in records[0])
    np.testing.assert_allclose([r[1] for r in records[1]], [r[1] for r in records[0]], rtol=RTOL, atol=ATOL)


def test_calibration_keeps_the_learned_steps_scales_and_reads_the_reaching_fear() -> None:
    model, actor = rare_danger_model()
    s = torch.as_tensor(np.random.default_rng(4).normal(size=(200, OBS)).astype(np.float32))
    floor = float(s[:, 0].quantile(0.2))
    bounds = {}
    for reach in (None, REACH):
        calibrate(model, actor.deterministic, s, HORIZON, cfg=contact_cfg(floor, reach))
        bounds[reach] = (model.sigma_scale[:HORIZON].clone(), model.tau_bounds.clone())
    np.testing.assert_allclose(bounds[REACH][0].numpy(), bounds[None][0].numpy(), rtol=1e-6)
    assert float(bounds[REACH][1][1]) >= float(bounds[None][1][1])  # more imagined contact, not less


def test_contact_horizon_settings_are_read_and_checked() -> None:
    assert parse_gate_settings(["contact_horizon=10"]) == {"contact_horizon": 10}
    assert parse_gate_settings(["contact_horizon=none"]) == {"contact_horizon": None}
    assert fear_shape_moved(GateConfig(), dataclasses.replace(GateConfig(), contact_horizon=10)) == ["contact_horizon"]
    for gate, message in (
        (GateConfig(contact_horizon=10), "needs gate.imagined_contact"),
        (contact_cfg(0.1, 0), ">= 1"),
        (dataclasses.replace(contact_cfg(0.1, 10), aggregate="discounted_mean"), "aggregate=max"),
    ):
        with pytest.raises(ValueError, match=message):
            validate(dataclasses.replace(AgentConfig(), gate=gate))
    validate(dataclasses.replace(AgentConfig(), gate=contact_cfg(0.1, 10)))
    with pytest.raises(ValueError, match="aggregate=max"):
        kernels(*rare_danger_model(), dataclasses.replace(contact_cfg(0.1, 10), aggregate="discounted_mean"))
