"""The SAGE gate: fires when fear exceeds the threshold, holds the expert for k steps, works in the loop."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from core.experts import ScriptedExpert
from core.loop import Runner, StepRecord
from core.sage.config import GateConfig, WorldModelConfig
from core.sage.gate import AlwaysGate, SageGate
from core.sage.networks import Actor
from core.sage.world_model import EnsembleWorldModel
from tests.core.sage.envs import make

torch.set_num_threads(1)


class ScriptedFear:
    """Stands in for the gate's kernel: returns the given fear values in turn."""

    def __init__(self, values: list[float]) -> None:
        self.values = list(values)

    def __call__(
        self,
        obs: torch.Tensor,
        action: torch.Tensor,
        motion: torch.Tensor | None = None,
        closing_rate: torch.Tensor | None = None,
    ) -> tuple[float, float, float]:
        value = self.values.pop(0)
        return value, value, 0.0

    def curiosity(
        self,
        obs: torch.Tensor,
        action: torch.Tensor,
        next_obs: torch.Tensor,
        reuse_first_step: bool = False,
        motion: torch.Tensor | None = None,
    ) -> float:
        return 1.0


def fitted_gate(k: int, fears: list[float], release: float = 1.0) -> SageGate:
    rng = np.random.default_rng(0)
    model = EnsembleWorldModel(3, 2, WorldModelConfig(hidden=16, max_updates_per_fit=5))
    s = rng.normal(size=(50, 3)).astype(np.float32)
    model.fit(s, rng.normal(size=(50, 2)).astype(np.float32), s, np.zeros(50, np.float32), rng)
    gate = SageGate(model, Actor(3, 2, 16, 1, -torch.ones(2), torch.ones(2)), GateConfig(hold_steps=k, release=release))
    gate.kernel = lambda: fake  # type: ignore[method-assign]
    fake = ScriptedFear(fears)
    gate.threshold.threshold = 0.5
    gate.threshold.tau_min = 0.15
    gate.threshold.update = lambda c: 0.5  # type: ignore[method-assign]
    return gate


def decisions(gate: SageGate, n: int) -> list[bool]:
    obs, action = np.zeros(3, np.float32), np.zeros(2, np.float32)
    return [gate.decide(obs, action).fired for _ in range(n)]


def test_gate_holds_the_expert_for_k_steps() -> None:
    gate = fitted_gate(3, [0.9] + [0.1] * 6)
    assert decisions(gate, 7) == [True, True, True, False, False, False, False]


def test_a_hold_in_seconds_holds_the_same_time_whatever_the_step() -> None:
    for step, held in ((0.1, 10), (0.5, 2), (0.3, 3)):
        cfg = GateConfig(hold_steps=5, hold_seconds=1.0, step_seconds=step)
        assert cfg.hold == held
        gate = fitted_gate(5, [0.9] + [0.1] * 12)
        gate.cfg = cfg
        assert decisions(gate, 13) == [True] * held + [False] * (13 - held)
    assert GateConfig(hold_steps=4).hold == 4
    with pytest.raises(ValueError, match="step_seconds"):
        _ = GateConfig(hold_seconds=1.0).hold


def test_a_new_firing_during_the_hold_restarts_it_and_reset_clears_it() -> None:
    gate = fitted_gate(3, [0.9, 0.1, 0.9, 0.1, 0.1, 0.1, 0.1, 0.9, 0.1])
    assert decisions(gate, 6) == [True, True, True, True, True, False]
    gate.reset()
    assert decisions(gate, 3) == [False, True, True]  # the hold starts again only on a firing


def test_the_expert_keeps_control_while_fear_stays_over_the_release_level() -> None:
    # τ = 0.5, τ_min = 0.15: fear 0.3 does not fire the gate, but keeps a fired gate holding (hysteresis); once
    # fear is under τ_min the hold runs its k = 2 steps out
    fears = [0.3, 0.9, 0.3, 0.3, 0.3, 0.3, 0.1, 0.1, 0.1, 0.3, 0.3]
    held = decisions(fitted_gate(2, fears, release=1.0), len(fears))
    assert held == [False, True, True, True, True, True, True, False, False, False, False]


def test_half_release_sits_between_tau_and_tau_min_and_zero_release_hands_back_under_tau() -> None:
    # release 0.5: the level is 0.5 - 0.5 (0.5 - 0.15) = 0.325; fear 0.35 keeps the hold, 0.3 does not
    fears = [0.9, 0.35, 0.35, 0.3, 0.3, 0.3]
    assert decisions(fitted_gate(2, fears, release=0.5), 6) == [True, True, True, True, False, False]
    gate = fitted_gate(2, [0.9, 0.35, 0.35, 0.3, 0.3, 0.3], release=0.0)
    assert decisions(gate, 6) == [True, True, False, False, False, False]
    assert gate.detail.level == 0.5


def test_decision_reports_fear_and_threshold() -> None:
    gate = fitted_gate(1, [0.7, 0.2])
    first = gate.decide(np.zeros(3, np.float32), np.zeros(2, np.float32))
    second = gate.decide(np.zeros(3, np.float32), np.zeros(2, np.float32))
    assert (first.fear, first.threshold, first.fired) == (0.7, 0.5, True)
    assert (second.fear, second.fired) == (0.2, False)
    assert gate.detail.cost == 0.2 and gate.detail.hold_remaining == 0


def test_an_unfitted_model_never_fires() -> None:
    model = EnsembleWorldModel(3, 2, WorldModelConfig(hidden=16))
    gate = SageGate(model, Actor(3, 2, 16, 1, -torch.ones(2), torch.ones(2)))
    decision = gate.decide(np.zeros(3, np.float32), np.zeros(2, np.float32))
    assert math.isnan(decision.fear) and not decision.fired
    assert math.isnan(gate.observe(np.zeros(3, np.float32), np.zeros(2, np.float32), np.zeros(3, np.float32)))


def test_surprising_transitions_lower_the_threshold() -> None:
    rng = np.random.default_rng(0)
    model = EnsembleWorldModel(3, 2, WorldModelConfig(hidden=16, max_updates_per_fit=200))
    s = rng.normal(size=(400, 3)).astype(np.float32)
    a = rng.uniform(-1, 1, (400, 2)).astype(np.float32)
    model.fit(s, a, s + 0.1 * a.sum(1, keepdims=True), np.zeros(400, np.float32), rng)
    gate = SageGate(model, Actor(3, 2, 16, 1, -torch.ones(2), torch.ones(2)), GateConfig(tau_min=0.2, tau_max=0.8))
    obs, action = s[0], a[0]
    gate.observe(obs, action, obs + 0.1 * action.sum())
    familiar = gate.threshold.threshold
    gate.observe(obs, action, obs + 5.0)
    surprised = gate.threshold.threshold
    assert surprised < familiar and 0.2 <= surprised < 0.35


def test_in_the_loop_takeovers_come_in_segments_of_at_least_k_steps() -> None:
    env = make("static")
    gate = fitted_gate(4, [0.9 if i % 9 == 0 else 0.1 for i in range(200)])
    runner = Runner(env, _Forward(), gate, ScriptedExpert(), seed=0)
    records: list[StepRecord] = []
    runner.step_listeners.append(records.append)
    runner.run_episode()
    flags = [r.takeover for r in records]
    segments, run = [], 0
    for flag in [*flags, False]:
        if flag:
            run += 1
        elif run:
            segments.append(run)
            run = 0
    assert segments and all(n >= 4 for n in segments[:-1])
    takeover = [r for r in records if r.takeover]
    assert all(r.a_expert is not None and r.actor == "expert" for r in takeover)
    assert all(np.array_equal(r.action, r.a_expert) for r in takeover)


def test_always_gate_fires() -> None:
    gate = AlwaysGate()
    assert gate.decide(np.zeros(2), np.zeros(2)).fired


class _Forward:
    def act(self, obs: np.ndarray, deterministic: bool = False) -> np.ndarray:
        return np.array([1.0, 0.0], np.float32)


@pytest.fixture(autouse=True)
def _threads() -> None:
    torch.set_num_threads(1)


@pytest.mark.parametrize(("lag", "scan"), [(1, False), (3, False), (1, True)])
def test_the_gates_motion_input_is_the_one_the_world_model_was_fitted_on(lag: int, scan: bool) -> None:
    """What the gate feeds the model at decision time, step by step through an episode and into the next, equals
    what the replay buffer gives the fit for the same rows (``previous_deltas``): one definition of motion, with
    or without a scan turned to the current heading."""
    from core.replay import ReplayBuffer

    rng = np.random.default_rng(1)
    layout = {"scan_sectors": 2, "scan_turn_channel": 2, "scan_turn_sectors": 0.8} if scan else {}
    model = EnsembleWorldModel(3, 2, WorldModelConfig(hidden=16, max_updates_per_fit=5, motion_lag=lag, **layout))
    s = rng.normal(size=(50, 3)).astype(np.float32)
    model.fit(s, rng.normal(size=(50, 2)).astype(np.float32), s, np.zeros(50, np.float32), rng)
    gate = SageGate(model, Actor(3, 2, 16, 1, -torch.ones(2), torch.ones(2)), GateConfig())
    buffer = ReplayBuffer(3, 2, capacity=64)
    seen: list[np.ndarray] = []
    action = np.zeros(2, np.float32)
    for length in (7, 4):
        gate.reset()
        states = np.cumsum(rng.normal(size=(length + 1, 3)), axis=0).astype(np.float32)
        for t in range(length):
            motion = gate._motion(states[t])
            seen.append(np.zeros(3, np.float32) if motion is None else motion.numpy().reshape(-1))
            gate.observe(states[t], action, states[t + 1])
            buffer.add(states[t], action, 0.0, states[t + 1], t == length - 1)
    np.testing.assert_allclose(np.stack(seen), buffer.previous_deltas(lag, model.scan), atol=1e-6)
    assert lag == 1 or not np.allclose(buffer.previous_deltas(lag), buffer.previous_deltas(1))
    assert not scan or not np.allclose(buffer.previous_deltas(lag, model.scan), buffer.previous_deltas(lag))
