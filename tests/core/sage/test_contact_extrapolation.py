"""``gate.contact_extrapolation``: each scan sector's closing that the robot's own motion leaves unexplained, seen in
two consecutive real steps, is extrapolated at constant speed over the imagined steps of the contact test. Off is
today's gate; a sector closing at a steady speed is imagined in contact the steps ahead that its speed says, a one-off
jump is not; the reference rollout, the torch kernel and the compiled kernel agree; the calibration reads the rates
the gate would have read."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from core.agents import fear_shape_moved
from core.replay import ReplayBuffer
from core.sage.calibration import CalibrationSample, calibrate
from core.sage.compiled_gate import CompiledGateKernel
from core.sage.config import AgentConfig, GateConfig, WorldModelConfig, parse_gate_settings, validate
from core.sage.fear import (
    GateKernel,
    closing_rate,
    fear_of,
    rollout,
    with_contact,
)
from core.sage.gate import SageGate
from core.sage.model_trainer import buffer_closing_rates
from core.sage.networks import Actor
from core.sage.world_model import EnsembleWorldModel

torch.set_num_threads(1)

OBS, ACT, SECTORS = 9, 2, 8
EGO = {
    "ego_sectors": SECTORS,
    "ego_scan_start": -1.2,
    "ego_sector_width": 0.3,
    "ego_forward_scale": 0.03,
    "ego_forward_offset": 0.03,
    "ego_turn_scale": 0.3,
}
RTOL, ATOL = 1e-5, 1e-6


def test_a_closing_counts_only_when_seen_two_steps_running_and_at_its_smaller_magnitude() -> None:
    steady = torch.tensor([[-0.02, -0.02]])
    assert torch.equal(closing_rate(steady, steady), steady)
    # an edge entering the sector: a one-off jump, then the mover's own speed, then nothing
    jump, mover, still = torch.tensor([[-0.5]]), torch.tensor([[-0.02]]), torch.tensor([[0.0]])
    assert float(closing_rate(still, jump)) == 0.0  # the jump alone never counts
    assert float(closing_rate(jump, mover)) == pytest.approx(-0.02)  # after it, the mover's speed, not the jump's
    assert float(closing_rate(jump, still)) == 0.0
    assert float(closing_rate(torch.tensor([[0.03]]), torch.tensor([[-0.03]]))) == 0.0  # opening, then closing


def test_a_sector_closing_at_constant_speed_is_imagined_in_contact_as_many_steps_ahead_as_its_speed_says() -> None:
    """A still imagined world (every member's sector 0 at 0.5 for 10 steps), contact floor 0.2: today's test finds no
    contact; a sector closing 0.05 a step reaches the floor at step 6, and the extrapolated test marks it from step 6
    on (6 steps before the real contact, at the decision); the rate of a one-off jump marks nothing."""
    m, members = 10, 5
    states = torch.full((m, members, 1, 3), 0.5)
    probability = torch.zeros(m, members, 1)
    floors = torch.tensor([0.2, 0.2])
    assert not with_contact(probability, states, floors).any()
    rate = closing_rate(torch.tensor([[-0.05, 0.0]]), torch.tensor([[-0.05, 0.0]]))
    marked = with_contact(probability, states, floors, closing_rate=rate)[:, 0, 0]
    first = int(torch.nonzero(marked).min()) + 1  # 1-based step
    assert first == 6 and bool(marked[first - 1 :].all())
    # the real sector: 0.5 - 0.05 k, at the floor at k = 6 (float32: compare with a margin)
    assert 0.5 - 0.05 * first <= 0.2 + 1e-6 and 0.5 - 0.05 * (first - 1) > 0.2
    jumped = closing_rate(torch.tensor([[-0.4, 0.0]]), torch.tensor([[0.0, 0.0]]))
    assert not with_contact(probability, states, floors, closing_rate=jumped).any()


def fitted() -> tuple[EnsembleWorldModel, Actor, np.ndarray]:
    """A briefly fitted model with the ego step (the UGV's layout) on scans in (0.05, 1]."""
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    model = EnsembleWorldModel(OBS, ACT, WorldModelConfig(hidden=32, max_updates_per_fit=40, motion_input=True, **EGO))
    s = np.concatenate([rng.uniform(0.05, 1.0, (400, SECTORS)), rng.uniform(-1, 1, (400, 1))], axis=1)
    s = s.astype(np.float32)
    a = rng.uniform(-1, 1, (400, ACT)).astype(np.float32)
    nxt = np.clip(s + 0.05 * rng.normal(size=s.shape).astype(np.float32), 0.01, 1.0)
    model.fit(s, a, nxt, (rng.random(400) < 0.05).astype(np.float32), rng)
    actor = Actor(OBS, ACT, 32, 2, -torch.ones(ACT) * 2, torch.ones(ACT) * 2)
    calibrate(model, actor.deterministic, torch.as_tensor(s), 5)
    return model, actor, s


def gate_cfg(extrapolate: bool, floor: float = 0.2, **more: object) -> GateConfig:
    return GateConfig(
        imagined_contact=True,
        contact_floors=[floor] * SECTORS,
        contact_horizon=10,
        contact_extrapolation=extrapolate,
        **more,  # type: ignore[arg-type]
    )


def closing_episode(model: EnsembleWorldModel, steps: int, speed: float, jump_at: int | None = None) -> np.ndarray:
    """Real scans under a fixed action: each the last moved by the ego step, sector 3 closing ``speed`` a step
    (a mover on course), or with ``jump_at``: still, except sector 3 jumping 0.4 nearer once (an edge entering)."""
    obs = np.full((steps + 1, OBS), 0.9, np.float32)
    obs[0, SECTORS] = 0.0
    action = torch.tensor([[0.0, 0.0]])
    for t in range(steps):
        with torch.no_grad():
            moved = model.base(torch.from_numpy(obs[t : t + 1]), action)[0].numpy()
        obs[t + 1] = moved
        if jump_at is None:
            obs[t + 1, 3] -= speed
        elif t + 1 == jump_at:
            obs[t + 1, 3] -= 0.4
    return obs


def test_the_gate_reads_a_movers_closing_from_the_real_scans_and_not_a_one_off_jump() -> None:
    model, actor, _ = fitted()
    gate = SageGate(model, actor, gate_cfg(True))
    action = np.zeros(ACT, np.float32)
    steady = closing_episode(model, 4, 0.03)
    rates = []
    for t in range(4):
        gate.decide(steady[t], action)
        gate.observe(steady[t], action, steady[t + 1])
        rates.append(gate.closing_rate())
    assert rates[0] is None  # one step seen: not yet
    for rate in rates[1:]:
        assert rate is not None
        assert float(rate[0, 3]) == pytest.approx(-0.03, abs=1e-5)
        assert float(rate.abs().sum() - rate[0, 3].abs()) == pytest.approx(0.0, abs=1e-5)
    gate.reset()
    assert gate.closing_rate() is None  # an episode's rates do not carry into the next
    jumped = closing_episode(model, 4, 0.0, jump_at=2)
    for t in range(4):
        gate.decide(jumped[t], action)
        gate.observe(jumped[t], action, jumped[t + 1])
        rate = gate.closing_rate()
        assert rate is None or float(rate.min()) > -1e-5
    assert SageGate(model, actor, gate_cfg(False)).closing_rate() is None


def all_paths(
    model: EnsembleWorldModel, actor: Actor, cfg: GateConfig, obs: torch.Tensor, rate: torch.Tensor | None
) -> tuple[float, float, float]:
    """(F, ĉ, σ̂) of the reference rollout, after checking the torch and the compiled kernel against it."""
    folded, layers = model.folded(), actor.deterministic_layers()
    action = torch.zeros(1, ACT)
    with torch.inference_mode():
        ro = rollout(
            folded,
            actor.deterministic,
            obs,
            action,
            10,
            None,
            torch.tensor(cfg.contact_floors),
            learned_steps=cfg.horizon,
            closing_rate=rate if cfg.contact_extrapolation else None,
        )
        terms = fear_of(folded, ro, cfg)
        expected = (float(terms.fear), float(terms.cost), float(terms.sigma))
        for build in (GateKernel, CompiledGateKernel):
            kernel = build(folded, layers, actor.action_scale, actor.action_bias, cfg)
            np.testing.assert_allclose(kernel(obs, action, None, rate), expected, rtol=RTOL, atol=ATOL)
    return expected


def test_off_is_todays_gate_and_on_raises_fear_only_where_a_sector_closes() -> None:
    model, actor, states = fitted()
    obs = torch.as_tensor(states[:1])
    with torch.no_grad():
        ro = rollout(model.folded(), actor.deterministic, obs, torch.zeros(1, ACT), 10)
    floor = float(ro.states[1:, :, 0, :SECTORS].min()) - 0.05  # no member imagines contact without extrapolation
    rate = torch.zeros(1, SECTORS)
    # sector 2 closing fast enough that every member's imagined sector is at the floor by the 10th step
    rate[0, 2] = (floor - float(ro.states[10, :, 0, 2].max())) / 10 - 0.01
    today = all_paths(model, actor, gate_cfg(False, floor), obs, None)
    np.testing.assert_allclose(all_paths(model, actor, gate_cfg(False, floor), obs, rate), today, rtol=RTOL)
    np.testing.assert_allclose(all_paths(model, actor, gate_cfg(True, floor), obs, None), today, rtol=RTOL)
    np.testing.assert_allclose(
        all_paths(model, actor, gate_cfg(True, floor), obs, torch.zeros(1, SECTORS)), today, rtol=RTOL
    )
    closing = all_paths(model, actor, gate_cfg(True, floor), obs, rate)
    assert closing[1] == pytest.approx(1.0) and closing[0] > today[0]
    assert closing[2] == pytest.approx(today[2], abs=ATOL)  # σ̂ is the members' disagreement: untouched


def test_the_three_gate_paths_take_the_same_decisions_with_extrapolation() -> None:
    """The generic path (a policy function: the reference rollout), the torch kernel and the compiled kernel, over a
    recorded sequence with sectors closing, the rates read by each gate from the scans: the same fears and takeovers,
    and more imagined contact than without extrapolation."""
    model, actor, _ = fitted()
    rng = np.random.default_rng(3)
    steps = 60
    obs = np.empty((steps + 1, OBS), np.float32)
    obs[0] = np.concatenate([rng.uniform(0.4, 1.0, SECTORS), [0.0]])
    actions = rng.uniform(-1, 1, (steps, ACT)).astype(np.float32)
    speed = rng.uniform(0.0, 0.04, SECTORS).astype(np.float32)
    for t in range(steps):
        with torch.no_grad():
            moved = model.base(torch.from_numpy(obs[t : t + 1]), torch.from_numpy(actions[t : t + 1]))[0].numpy()
        obs[t + 1] = moved
        obs[t + 1, :SECTORS] = np.clip(moved[:SECTORS] - speed, 0.05, 1.0)
    floor = 0.15
    costs = {}
    for extrapolate in (False, True):
        cfg = dataclasses.replace(
            gate_cfg(extrapolate, floor), hold_steps=2, tau_from_data=False, tau_min=0.3, tau_max=0.6
        )
        gates = [
            SageGate(model, actor.deterministic, cfg),
            SageGate(model, actor, cfg, compiled=False),
            SageGate(model, actor, cfg, compiled=True),
        ]
        assert [type(g.kernel()) for g in gates[1:]] == [GateKernel, CompiledGateKernel] and gates[0].kernel() is None
        records: list[list[tuple[bool, float, float]]] = [[], [], []]
        for t in range(steps):
            if t == 30:
                for g in gates:
                    g.reset()
            for g, record in zip(gates, records, strict=True):
                decision = g.decide(obs[t], actions[t])
                g.observe(obs[t], actions[t], obs[t + 1])
                record.append((decision.fired, decision.fear, g.detail.cost))
        for record in records[1:]:
            assert [r[0] for r in record] == [r[0] for r in records[0]]
            np.testing.assert_allclose([r[1:] for r in record], [r[1:] for r in records[0]], rtol=RTOL, atol=ATOL)
        costs[extrapolate] = np.array([r[2] for r in records[0]])
    assert (costs[True] >= costs[False] - ATOL).all() and (costs[True] > costs[False] + 0.1).any()


def test_the_calibration_reads_the_rates_the_gate_would_have_read() -> None:
    model, actor, _ = fitted()
    cfg = gate_cfg(True)
    steady = closing_episode(model, 6, 0.03)
    second = closing_episode(model, 5, 0.0, jump_at=2)
    buffer = ReplayBuffer(OBS, ACT, 32)
    action = np.zeros(ACT, np.float32)
    expected = []
    for episode in (steady, second):
        gate = SageGate(model, actor, cfg)
        for t in range(len(episode) - 1):
            rate = gate.closing_rate()
            expected.append(np.zeros(SECTORS, np.float32) if rate is None else rate[0].numpy())
            gate.observe(episode[t], action, episode[t + 1])
            buffer.add(episode[t], action, 0.0, episode[t + 1], t == len(episode) - 2)
    idx = np.arange(len(buffer))
    got = buffer_closing_rates(buffer, model, cfg, idx)
    assert got is not None
    np.testing.assert_allclose(got, np.array(expected), atol=1e-6)
    assert float(got[:6, 3].min()) == pytest.approx(-0.03, abs=1e-5) and float(got[6:].min()) > -1e-5
    assert buffer_closing_rates(buffer, model, gate_cfg(False), idx) is None
    # the sample keeps them through a save and a load, and the τ bounds are measured with them
    sample = CalibrationSample(
        obs=buffer.obs[:11], action=buffer.action[:11], next_obs=buffer.next_obs[:11], familiar=np.ones(11, bool)
    )
    with_rates = dataclasses.replace(sample, closing_rate=got)
    joined = CalibrationSample.concat([sample, with_rates])
    assert joined.closing_rate is not None and not joined.closing_rate[:11].any()
    np.testing.assert_allclose(joined.closing_rate[11:], got)


def test_the_calibration_sample_keeps_its_rates_through_a_file(tmp_path: object) -> None:
    from pathlib import Path

    rng = np.random.default_rng(0)
    rates = -rng.uniform(0, 0.05, (5, SECTORS)).astype(np.float32)
    sample = CalibrationSample(
        obs=rng.normal(size=(5, OBS)).astype(np.float32),
        action=np.zeros((5, ACT), np.float32),
        next_obs=rng.normal(size=(5, OBS)).astype(np.float32),
        familiar=np.ones(5, bool),
        closing_rate=rates,
    )
    loaded = CalibrationSample.load(sample.save(Path(str(tmp_path)) / "calibration.npz"))
    assert loaded.closing_rate is not None
    np.testing.assert_array_equal(loaded.closing_rate, rates)
    np.testing.assert_array_equal(loaded.subset(np.array([1, 3])).closing_rate, rates[[1, 3]])  # type: ignore[arg-type]


def test_the_setting_is_read_and_checked() -> None:
    assert parse_gate_settings(["contact_extrapolation=true"]) == {"contact_extrapolation": True}
    assert fear_shape_moved(GateConfig(), dataclasses.replace(GateConfig(), contact_extrapolation=True)) == [
        "contact_extrapolation"
    ]
    with pytest.raises(ValueError, match=r"needs gate\.imagined_contact"):
        validate(dataclasses.replace(AgentConfig(), gate=GateConfig(contact_extrapolation=True)))
    validate(dataclasses.replace(AgentConfig(), gate=gate_cfg(True)))
