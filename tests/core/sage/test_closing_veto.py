"""``gate.closing_veto``: fear over τ hands over only where a contact channel of the real observations is closing on
its floor within the veto's time; everything else about the gate is unchanged."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from core.sage.config import AgentConfig, GateConfig, parse_gate_settings, validate
from core.sage.gate import SageGate
from tests.core.sage.test_gate import fitted_gate

torch.set_num_threads(1)

FLOORS = [0.1, None, None]


def veto_gate(veto: float | None, fears: list[float]) -> SageGate:
    gate = fitted_gate(1, fears, release=0.0)
    gate.cfg = dataclasses.replace(gate.cfg, closing_veto=veto, contact_floors=FLOORS, step_seconds=0.1, hold_steps=1)
    return gate


def drive(gate: SageGate, states: list[list[float]]) -> list[bool]:
    """The gate's decisions along ``states`` (each observed as the next state of the one before)."""
    action = np.zeros(2, np.float32)
    fired = []
    for now, then in zip(states, [*states[1:], states[-1]], strict=True):
        fired.append(gate.decide(np.asarray(now, np.float32), action).fired)
        gate.observe(np.asarray(now, np.float32), action, np.asarray(then, np.float32))
    return fired


def test_without_the_veto_every_fear_over_tau_hands_over() -> None:
    states = [[0.5, 0.0, 0.0]] * 6
    assert drive(veto_gate(None, [0.9] * 6), states) == [True] * 6


def test_nothing_closing_withholds_fear_once_three_states_are_seen() -> None:
    gate = veto_gate(0.3, [0.9] * 6)
    assert drive(gate, [[0.5, 0.0, 0.0]] * 6) == [True, True, False, False, False, False]
    assert gate.detail.vetoed
    gate.reset()  # a new episode withholds nothing until it has shown three states again
    gate.kernel().values = [0.9] * 3  # type: ignore[attr-defined]
    assert drive(gate, [[0.5, 0.0, 0.0]] * 3) == [True, True, False]


def test_a_channel_closing_on_its_floor_within_the_veto_hands_over() -> None:
    # 0.1 a step: from 0.3, three steps (0.3 s) reach 0.0, under the floor 0.1
    fast = [[0.5, 0, 0], [0.4, 0, 0], [0.3, 0, 0], [0.2, 0, 0]]
    assert drive(veto_gate(0.3, [0.9] * 4), fast) == [True, True, True, True]
    # 0.02 a step: 0.46 - 3 x 0.02 = 0.40 stays over the floor
    slow = [[0.5, 0, 0], [0.48, 0, 0], [0.46, 0, 0], [0.44, 0, 0]]
    assert drive(veto_gate(0.3, [0.9] * 4), slow) == [True, True, False, False]
    # the same closing reaches the floor within a longer veto (3 s: 30 steps)
    assert drive(veto_gate(3.0, [0.9] * 4), slow) == [True, True, True, True]


def test_closing_counts_only_when_two_changes_running_fall_and_only_on_a_floored_channel() -> None:
    # a jump (an object appearing) is one fall: not closing
    jump = [[0.9, 0, 0], [0.9, 0, 0], [0.2, 0, 0], [0.2, 0, 0]]
    assert drive(veto_gate(0.3, [0.9] * 4), jump) == [True, True, False, False]
    # a channel without a floor closes as fast as it likes: withheld
    unfloored = [[0.5, 0.9, 0], [0.5, 0.5, 0], [0.5, 0.1, 0], [0.5, 0.0, 0]]
    assert drive(veto_gate(0.3, [0.9] * 4), unfloored) == [True, True, False, False]
    # a channel at its floor already hands over without closing
    touching = [[0.05, 0, 0]] * 4
    assert drive(veto_gate(0.3, [0.9] * 4), touching) == [True] * 4


def test_fear_under_tau_never_hands_over_whatever_closes() -> None:
    fast = [[0.5, 0, 0], [0.4, 0, 0], [0.3, 0, 0], [0.2, 0, 0]]
    gate = veto_gate(0.3, [0.1] * 4)
    assert drive(gate, fast) == [False] * 4
    assert not gate.detail.vetoed


def test_the_veto_is_validated_and_brings_the_simulators_floors() -> None:
    def checked(**gate: object) -> None:
        cfg = AgentConfig()
        cfg.gate = dataclasses.replace(GateConfig(step_seconds=0.1, contact_floors=FLOORS), **gate)
        validate(cfg)

    checked(closing_veto=3.0)
    with pytest.raises(ValueError, match="positive number of seconds"):
        checked(closing_veto=0.0)
    with pytest.raises(ValueError, match="contact_floors"):
        checked(closing_veto=3.0, contact_floors=None)
    with pytest.raises(ValueError, match="step_seconds"):
        checked(closing_veto=3.0, step_seconds=None)
    gate = veto_gate(0.3, [0.9] * 4)
    gate.cfg = dataclasses.replace(gate.cfg, step_seconds=None)  # a gate made without the config's checks
    with pytest.raises(ValueError, match="step_seconds"):
        drive(gate, [[0.5, 0, 0]] * 4)
    assert parse_gate_settings(["closing_veto=3"], (0.1, None)) == {"closing_veto": 3.0, "contact_floors": [0.1, None]}
    assert parse_gate_settings(["closing_veto=none"], (0.1, None)) == {"closing_veto": None}
