"""The compiled gate kernel agrees with the torch kernel (the reference rollout) within float32 rounding, and a gate
built on it takes the same decisions over a recorded sequence."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from core.sage.calibration import calibrate
from core.sage.compiled_gate import CompiledGateKernel, compiled_kernel_supports, first_step_spread, padded_columns
from core.sage.config import GateConfig, WorldModelConfig
from core.sage.fear import GateKernel
from core.sage.gate import SageGate
from core.sage.networks import Actor
from core.sage.world_model import EnsembleWorldModel

torch.set_num_threads(1)

OBS, ACT = 9, 2
EGO = {
    "ego_sectors": 8,
    "ego_scan_start": -1.2,
    "ego_sector_width": 0.3,
    "ego_forward_scale": 0.03,
    "ego_forward_offset": 0.03,
    "ego_turn_scale": 0.3,
}
RTOL, ATOL = 1e-5, 1e-6


def scans(rng: np.random.Generator, n: int) -> np.ndarray:
    """States whose first 8 channels read as ranges in (0, 1] (the ego step's scan), the last a turn."""
    return np.concatenate([rng.uniform(0.05, 1.0, (n, 8)), rng.uniform(-1, 1, (n, 1))], axis=1).astype(np.float32)


def fitted(layout: dict[str, Any], scaled: bool = True) -> tuple[EnsembleWorldModel, Actor, np.ndarray]:
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    model = EnsembleWorldModel(OBS, ACT, WorldModelConfig(hidden=32, max_updates_per_fit=40, **layout))
    s, a = scans(rng, 400), rng.uniform(-1, 1, (400, ACT)).astype(np.float32)
    nxt = np.clip(s + 0.05 * rng.normal(size=s.shape).astype(np.float32), 0.01, 1.0)
    model.fit(s, a, nxt, (rng.random(400) < 0.2).astype(np.float32), rng)
    bound = 2.0 if scaled else 1.0
    actor = Actor(OBS, ACT, 32, 2, -torch.ones(ACT) * bound, torch.ones(ACT) * bound)
    calibrate(model, actor.deterministic, torch.as_tensor(s), 5)
    return model, actor, s


LAYOUTS = {
    "plain": {"motion_input": False},
    "motion": {"motion_input": True, "motion_lag": 2},
    "ego step": {"motion_input": True, **EGO},
    # each range channel's approach rate as an input too (world_model_config.approach_*; highway's candidates)
    "approach": {"motion_input": True, "motion_lag": 2, "approach_start": 0, "approach_stop": 8},
}
GATES = {
    "max": GateConfig(beta=0.3),
    "discounted mean": GateConfig(aggregate="discounted_mean", beta=0.6),
    "imagined contact": GateConfig(imagined_contact=True, contact_floors=[0.2] * 8),
    "contact when closing": GateConfig(imagined_contact=True, contact_floors=[0.3] * 8, contact_needs_closing=True),
    # imagined contact reaching 1 s, the learned terms 0.5 s (gate.contact_horizon)
    "imagined contact reaching past the horizon": GateConfig(
        imagined_contact=True, contact_floors=[0.2] * 8, contact_horizon=10
    ),
    # the real scans' closing extrapolated over the imagined steps (gate.contact_extrapolation)
    "imagined contact with closing extrapolated": GateConfig(
        imagined_contact=True, contact_floors=[0.1] * 8, contact_extrapolation=True
    ),
}


@pytest.mark.parametrize("layout", LAYOUTS)
@pytest.mark.parametrize("gate", GATES)
def test_compiled_kernel_agrees_with_the_torch_kernel(layout: str, gate: str) -> None:
    if gate == "contact when closing" and not LAYOUTS[layout]["motion_input"]:
        pytest.skip("contact_needs_closing reads the motion input")
    model, actor, states = fitted(LAYOUTS[layout], scaled=gate != "max")
    cfg, folded, layers = GATES[gate], model.folded(), actor.deterministic_layers()
    assert compiled_kernel_supports(folded, layers)
    reference = GateKernel(folded, layers, actor.action_scale, actor.action_bias, cfg)
    compiled = CompiledGateKernel(folded, layers, actor.action_scale, actor.action_bias, cfg)
    rng = np.random.default_rng(1)
    fired = 0
    for i in range(20):
        obs = torch.as_tensor(states[i : i + 1])
        action = torch.as_tensor(rng.uniform(-2, 2, (1, ACT)).astype(np.float32))
        motion = None if i == 0 else torch.as_tensor(states[i : i + 1] - states[i + 1 : i + 2])
        nxt = torch.as_tensor(states[i + 1 : i + 2])
        # a closing rate (<= 0) in some sectors, none in others (ignored by the gates that do not extrapolate)
        rate = torch.as_tensor(np.minimum(rng.uniform(-0.06, 0.03, (1, 8)), 0.0).astype(np.float32))
        with torch.inference_mode():
            expected, got = reference(obs, action, motion, rate), compiled(obs, action, motion, rate)
            np.testing.assert_allclose(got, expected, rtol=RTOL, atol=ATOL)
            # every imagined state, action and motion (the last state's motion feeds nothing: the torch kernel's
            # is not compared), and each member's probability, not only the aggregate. The products' rounding
            # (summed in another order) compounds along the rollout, the more through the ego step's geometry:
            # the first step is held to float32 rounding, the first five steps to 1e-5. A 10-step rollout
            # (gate.contact_horizon=10) of this briefly fitted model diverges (states past ±100 by the 10th step
            # through the ego step's geometry), and the rounding with it (seen: 1.2e-4 relative): its later steps
            # to 1e-3 relative, its fear and member costs still to float32 rounding.
            last = reference.m
            rtol, atol = (RTOL, 1e-5) if last <= 5 else (1e-3, 1e-4)
            np.testing.assert_allclose(compiled.x[:2].numpy(), reference.x[:2].numpy(), rtol=RTOL, atol=ATOL)
            np.testing.assert_allclose(compiled.x[:5].numpy(), reference.x[:5].numpy(), rtol=RTOL, atol=1e-5)
            np.testing.assert_allclose(compiled.x[:last].numpy(), reference.x[:last].numpy(), rtol=rtol, atol=atol)
            np.testing.assert_allclose(
                compiled.states[last].numpy(), reference.states[last].numpy(), rtol=rtol, atol=atol
            )
            np.testing.assert_allclose(
                compiled.last_member_costs(), reference.last_member_costs(), rtol=RTOL, atol=ATOL
            )
            for reuse in (True, False):
                np.testing.assert_allclose(
                    compiled.curiosity(obs, action, nxt, reuse_first_step=reuse, motion=motion),
                    reference.curiosity(obs, action, nxt, reuse_first_step=reuse, motion=motion),
                    rtol=RTOL,
                    atol=ATOL,
                )
        fired += expected[1] > 0.5
    if gate.startswith("imagined"):
        assert fired > 0, "the sequence never imagines contact: the contact branch went untested"


def test_compiled_kernel_follows_actor_updates_in_place() -> None:
    model, actor, states = fitted(LAYOUTS["motion"])
    folded, layers = model.folded(), actor.deterministic_layers()
    reference = GateKernel(folded, layers, actor.action_scale, actor.action_bias, GateConfig())
    compiled = CompiledGateKernel(folded, layers, actor.action_scale, actor.action_bias, GateConfig())
    obs, action = torch.as_tensor(states[:1]), torch.zeros(1, ACT)
    with torch.inference_mode():
        before = compiled(obs, action)
    with torch.no_grad():
        for p in actor.parameters():
            p.add_(0.3)
    with torch.inference_mode():
        after = compiled(obs, action)
        np.testing.assert_allclose(after, reference(obs, action), rtol=RTOL, atol=ATOL)
    assert after != before


@pytest.mark.parametrize("layout", ["motion", "ego step", "approach"])
def test_a_compiled_gate_takes_the_reference_gates_decisions(layout: str) -> None:
    """Over a recorded sequence (episode starts included): the same takeovers, fears and thresholds."""
    model, actor, states = fitted(LAYOUTS[layout])
    # τ scaled up to where this briefly fitted model's fears sit, so that the gate both fires and holds back
    cfg = GateConfig(hold_steps=2, tau_scale=2.9, imagined_contact=True, contact_floors=[0.06] * 8)
    gates = [SageGate(model, actor, cfg, compiled=compiled) for compiled in (False, True)]
    assert [type(g.kernel()) for g in gates] == [GateKernel, CompiledGateKernel]
    rng = np.random.default_rng(2)
    actions = rng.uniform(-2, 2, (len(states), ACT)).astype(np.float32)
    records: list[list[tuple[bool, float, float]]] = [[], []]
    for i in range(200):
        if i % 50 == 0:
            for g in gates:
                g.reset()
        for g, record in zip(gates, records, strict=True):
            decision = g.decide(states[i], actions[i])
            g.observe(states[i], actions[i], states[i + 1])
            record.append((decision.fired, decision.fear, decision.threshold))
    fired = [[r[0] for r in record] for record in records]
    assert fired[0] == fired[1] and 0 < sum(fired[0]) < 200
    np.testing.assert_allclose([r[1:] for r in records[1]], [r[1:] for r in records[0]], rtol=RTOL, atol=ATOL)


def test_approach_rates_over_the_ego_step_agree_where_rounding_allows() -> None:
    """The approach input over the ego step: fear, member costs and the first imagined step to float32 rounding. Later
    steps carry each approach rate's rounding, the motion's and range's divided by a range of at least
    APPROACH_RANGE_FLOOR (up to 50 times theirs), back through the network and the ego step's geometry: held to 1e-3."""
    model, actor, states = fitted({"motion_input": True, "approach_start": 2, "approach_stop": 7, **EGO})
    cfg, folded, layers = (
        GateConfig(imagined_contact=True, contact_floors=[0.2] * 8),
        model.folded(),
        actor.deterministic_layers(),
    )
    assert compiled_kernel_supports(folded, layers) and folded.approach == (2, 7)
    reference = GateKernel(folded, layers, actor.action_scale, actor.action_bias, cfg)
    compiled = CompiledGateKernel(folded, layers, actor.action_scale, actor.action_bias, cfg)
    rng = np.random.default_rng(1)
    rates = []
    for i in range(20):
        obs = torch.as_tensor(states[i : i + 1])
        action = torch.as_tensor(rng.uniform(-2, 2, (1, ACT)).astype(np.float32))
        motion = None if i == 0 else torch.as_tensor(states[i : i + 1] - states[i + 1 : i + 2])
        with torch.inference_mode():
            np.testing.assert_allclose(
                compiled(obs, action, motion), reference(obs, action, motion), rtol=RTOL, atol=ATOL
            )
            np.testing.assert_allclose(compiled.x[:2].numpy(), reference.x[:2].numpy(), rtol=RTOL, atol=ATOL)
            # the last imagined state's motion feeds nothing (the compiled kernel leaves it): states only there
            last = reference.m
            np.testing.assert_allclose(compiled.x[:last].numpy(), reference.x[:last].numpy(), rtol=1e-3, atol=1e-3)
            np.testing.assert_allclose(
                compiled.states[last].numpy(), reference.states[last].numpy(), rtol=1e-3, atol=1e-3
            )
            np.testing.assert_allclose(
                compiled.last_member_costs(), reference.last_member_costs(), rtol=RTOL, atol=ATOL
            )
        rates.append(compiled.approaches[1:].numpy().copy())
    assert np.concatenate(rates).max() > 0.05, "no imagined step approached anything: the approach rates went untested"


def test_unsupported_models_keep_the_torch_kernel() -> None:
    model, actor, _ = fitted(
        {"motion_input": True, "scan_sectors": 8, "scan_turn_channel": 8, "scan_turn_sectors": 1.5}
    )
    gate = SageGate(model, actor, GateConfig())
    assert not compiled_kernel_supports(model.folded(), actor.deterministic_layers())
    assert type(gate.kernel()) is GateKernel


def test_warm_up_builds_the_compiled_kernel_of_a_committed_policy_before_any_live_step(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """``sage serve`` warms the gate of the policy it opens, so a fresh install's one-off compile is not paid by the
    live loop's first step (the UGV default's mover model too: its compiled velocities and contact test are called);
    a policy with no world model has no gate to warm."""
    from pathlib import Path

    from core.agents import warm_gate_kernels
    from core.sage import compiled_gate, compiled_movers

    calls: list[str] = []
    for module, name in ((compiled_movers, "compiled_mover_velocities"), (compiled_gate, "movers_touching")):
        original = getattr(module, name)
        monkeypatch.setattr(module, name, lambda *a, _f=original, _n=name, **k: calls.append(_n) or _f(*a, **k))
    root = Path(__file__).resolve().parents[3] / "policies"
    assert warm_gate_kernels([str(root / "ugv-default")]) == [str(root / "ugv-default")]
    assert set(calls) == {"compiled_mover_velocities", "movers_touching"}


def test_warm_up_compiles_the_reused_curiosity_whichever_curiosity_the_policy_reads(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """numba's cache is shared by every policy: a policy whose gate reads the ensemble's disagreement still warms the
    compiled curiosity that a gate reading the prediction error calls (the dashboard may open such a policy next;
    otherwise its first live step compiles it, tens of seconds on a loaded machine)."""
    from core import agents
    from core.sage import compiled_gate

    policy = str(Path(__file__).resolve().parents[3] / "policies" / "ugv-default")
    agent = agents.load_agent(policy)
    agent.config.gate.curiosity_signal = "disagreement"
    agent.config.gate.curiosity_reference = "recent"
    assert agent.make_gate().cfg.curiosity_signal == "disagreement"
    monkeypatch.setattr(agents, "load_agent", lambda path: agent)
    calls: list[str] = []
    original = compiled_gate.reused_curiosity
    monkeypatch.setattr(compiled_gate, "reused_curiosity", lambda *a, **k: calls.append("reused") or original(*a, **k))
    assert agents.warm_gate_kernels([policy]) == [policy]
    assert calls


@pytest.mark.parametrize("members", [1, 5, 7])
@pytest.mark.parametrize("channels", [3, 9, 58, 64, 200])
def test_the_compiled_spread_is_the_numpy_spread(members: int, channels: int) -> None:
    """The disagreement read from a decision's first step: the compiled sums in numpy's order (the members' in turn,
    the channels' pairwise, split past numpy's block of 128) give its number, from (N, D) rows of a wider buffer."""
    rng = np.random.default_rng(channels * 10 + members)
    for scale in (1e-3, 1.0, 40.0):
        rows = (scale * rng.normal(size=(members, channels + 1))).astype(np.float32)
        deltas = rows[:, :channels]  # the Δs of the (N, D + 1) outputs: strided rows, as the kernel holds them
        precision = 1.0 / np.square(rng.uniform(0.05, 2.0, channels))
        wide = deltas.astype(np.float64)
        expected = np.sqrt((np.square(wide - wide.mean(0)).mean(0) * precision).mean())
        assert first_step_spread(deltas, precision) == pytest.approx(expected, rel=1e-12, abs=0.0)


def test_the_output_layer_is_padded_to_whole_vectors_and_keeps_its_columns() -> None:
    weights = np.arange(2 * 3 * 59, dtype=np.float32).reshape(2, 3, 59)
    padded = padded_columns(weights)
    assert padded.shape == (2, 3, 64) and padded.flags.c_contiguous
    assert np.array_equal(padded[..., :59], weights) and not padded[..., 59:].any()
    assert padded_columns(padded) is padded  # already whole vectors: the same array
