"""The live loop's parts: commands dispatched by class, counters from the runner, the clock, message handlers."""

from __future__ import annotations

import json
import typing
from typing import Any

import pytest

from app import commands as c
from app import messages as m
from app.clock import RateClock
from app.live import LiveConfig, LiveLoop
from app.operator import OperatorConsole
from app.policies import LoadedPolicy
from core.loop import NoGate
from tests.app.test_live_finetune import Constant, toy_env_factory


def test_every_message_class_has_a_handler_and_every_command_a_loop_handler() -> None:
    from app.server import _HANDLERS

    union = typing.get_args(typing.get_args(m.ClientMessage)[0])
    assert set(_HANDLERS) == set(union)
    assert LiveLoop.commands.kinds() == set(typing.get_args(c.Command))
    registry = c.CommandRegistry()
    registry.handles(c.Pause)(lambda owner, command: None)
    with pytest.raises(ValueError, match="already has a handler"):
        registry.handles(c.Pause)(lambda owner, command: None)
    with pytest.raises(c.CommandError, match="unknown command Resume"):
        registry.dispatch(None, c.Resume())


def make_loop(sent: list[dict[str, Any]]) -> LiveLoop:
    def loader(choice: str, env: Any) -> LoadedPolicy:
        return LoadedPolicy(Constant(0.5), NoGate(), "constant", {})

    return LiveLoop(
        LiveConfig(sim="toy", policy="constant", expert_mode="scripted"),
        env_factory=toy_env_factory,
        policy_loader=loader,
        console=OperatorConsole(),
        publish=lambda text: sent.append(json.loads(text)),
        start_paused=True,
    )


def test_commands_apply_in_the_loop_and_the_counters_are_the_runners_own_tallies() -> None:
    sent: list[dict[str, Any]] = []
    loop = make_loop(sent)
    loop.start()
    try:
        for _ in range(5):
            loop.submit(c.StepOnce()).result(10)
        loop.submit(c.NewEpisode()).result(10)
        for _ in range(3):
            loop.submit(c.StepOnce()).result(10)
        loop.submit(c.SetSpeed(2.5)).result(10)
        state = loop.state()
        assert state["paused"] and state["speed"] == 2.5
        episodes = [s for s in sent if s["type"] == "episode"]
        steps = [s for s in sent if s["type"] == "step"]
        counters = state["counters"]
        assert counters["episodes"] == len(episodes) == 1
        assert counters["steps"] == len(steps) == sum(e["steps"] for e in episodes) + counters["episode_steps"]
        assert counters["takeover_steps"] == sum(s["takeover"] for s in steps)
        assert counters["episode_steps"] == 3 and steps[-1]["counters"]["steps"] == counters["steps"]
        assert loop.submit(c.Configure()).result(10)["sim"] == "toy"  # nothing changes: same config back
        with pytest.raises(c.CommandError, match="no fine-tuning here"):
            loop.submit(c.ChooseVersion("follow")).result(10)
        with pytest.raises(c.CommandError, match="unknown command"):
            loop.submit("pause").result(10)  # type: ignore[arg-type]
    finally:
        loop.stop()


def test_the_clock_keeps_the_rate_without_bursts_and_rephases_on_a_takeover() -> None:
    clock = RateClock(0.0)
    assert clock.wait(0.0, onset=False) == 0.0
    clock.stepped(0.01, 0.1, onset=False)
    assert clock.wait(0.05, onset=False) == pytest.approx(0.05)  # due at 0.1
    assert clock.wait(0.05, onset=True) == 0.0  # a takeover steps at once
    clock.stepped(0.06, 0.1, onset=True)
    assert clock.next_at == pytest.approx(0.16)  # re-phased from the takeover step
    clock.stepped(2.0, 0.1, onset=False)  # a 2 s stall
    assert clock.next_at == pytest.approx(1.9)  # catches up one period at most: no burst of missed steps
    clock.stepped(2.0, 0.1, onset=False)
    assert clock.next_at == pytest.approx(2.0)
