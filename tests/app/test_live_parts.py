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
from core.loop import Gate, NoGate
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


def make_loop(sent: list[dict[str, Any]], gate: Gate | None = None, expert_mode: str = "scripted") -> LiveLoop:
    """A paused live loop on the toy simulator: a constant policy, ``gate`` (none: never fires), scripted expert
    (or ``expert_mode``)."""

    def loader(choice: str, env: Any) -> LoadedPolicy:
        return LoadedPolicy(Constant(0.5), gate if gate is not None else NoGate(), "constant", {})

    return LiveLoop(
        LiveConfig(sim="toy", policy="constant", expert_mode=expert_mode),  # type: ignore[arg-type]
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


def test_each_step_says_why_the_scripted_expert_drove_and_the_counters_add_it_up() -> None:
    from tests.app.fakesim import WaveGate

    sent: list[dict[str, Any]] = []
    loop = make_loop(sent, WaveGate(period=10, fire_from=3, fire_to=6))
    loop.start()
    try:
        for _ in range(25):
            loop.submit(c.StepOnce()).result(10)
        steps = [s for s in sent if s["type"] == "step"]
        # the wave gate fires at steps 3-5 of every 10 with fear over its threshold at the first, and keeps no
        # release level: every step the expert drives is fear or the hold, and only those
        causes = [s["takeover_cause"] for s in steps]
        assert all((cause is None) == (not s["takeover"]) for cause, s in zip(causes, steps, strict=True))
        assert "fear" in causes and set(causes) <= {None, "fear", "hold"}
        shares = loop.state()["counters"]["expert_share_by_cause"]
        for cause in ("fear", "hold", "hysteresis", "manoeuvre"):
            assert shares[cause] == pytest.approx(causes.count(cause) / len(steps))
        assert sum(shares.values()) == pytest.approx(sum(s["takeover"] for s in steps) / len(steps))
    finally:
        loop.stop()


def test_the_fallback_steps_count_as_the_scripted_expert_driving() -> None:
    """In person mode with nobody holding, the scripted fallback answers the gate: the page once said "scripted
    expert drove: -" while the fallback had driven 117 steps."""
    from tests.app.fakesim import WaveGate

    sent: list[dict[str, Any]] = []
    loop = make_loop(sent, WaveGate(period=10, fire_from=3, fire_to=6), expert_mode="person")
    loop.start()
    try:
        for _ in range(25):
            loop.submit(c.StepOnce()).result(10)
        steps = [s for s in sent if s["type"] == "step"]
        fallback = [s for s in steps if s["actor"] == "fallback"]
        assert fallback and all(s["takeover_cause"] in ("fear", "hold") for s in fallback)
        counters = loop.state()["counters"]
        assert counters["fallback_steps"] == len(fallback)
        shares = counters["expert_share_by_cause"]
        assert sum(shares.values()) == pytest.approx(len(fallback) / len(steps))
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


def test_interrupted_episodes_are_recorded_as_ended_with_their_reason(tmp_path: Any) -> None:
    from core.sessions import SessionStore

    def loader(choice: str, env: Any) -> LoadedPolicy:
        return LoadedPolicy(Constant(0.5), NoGate(), choice, {})

    store = SessionStore(tmp_path)
    sent: list[dict[str, Any]] = []
    loop = LiveLoop(
        LiveConfig(sim="toy", policy="first", expert_mode="scripted"),
        env_factory=toy_env_factory,
        policy_loader=loader,
        console=OperatorConsole(),
        publish=lambda text: sent.append(json.loads(text)),
        store=store,
        start_paused=True,
    )
    loop.start()
    try:
        first = loop.state()["session"]
        for _ in range(3):
            loop.submit(c.StepOnce()).result(10)
        loop.submit(c.NewEpisode()).result(10)
        loop.submit(c.StepOnce()).result(10)
        loop.submit(c.Configure(policy="second")).result(10)  # a switch in the middle of episode 1
        second = loop.state()["session"]
        loop.submit(c.StepOnce()).result(10)
    finally:
        loop.stop()
    episodes = store.episodes(first)
    assert [e["end_reason"] for e in episodes] == ["new episode (operator)", "switched to toy / None / second"]
    assert all(e["finished"] for e in episodes)
    assert [e["end_reason"] for e in store.episodes(second)] == ["server stopped"]
    assert [m["reason"] for m in sent if m["type"] == "episode"][:2] == [e["end_reason"] for e in episodes]


def test_the_threshold_streamed_is_the_one_the_gate_compared_fear_with() -> None:
    """The page draws record.threshold as τ: with a one-step hold, the gate fired exactly where fear > τ."""
    from pathlib import Path

    import sims
    from core.agents import load_agent
    from core.loop import Runner

    agent = load_agent(Path(__file__).resolve().parents[2] / "policies" / "ugv-default")
    env = sims.make("ugv", scenario="3")
    records: list[Any] = []
    runner = Runner(env, agent.policy, agent.make_gate(hold_steps=1), None, seed=0, deterministic=True)
    runner.step_listeners.append(records.append)
    runner.run_episode(max_steps=150)
    env.close()
    scored = [r for r in records if r.fear == r.fear]
    assert scored and any(r.gate_fired for r in scored) and not all(r.gate_fired for r in scored)
    assert all(r.gate_fired == (r.fear > r.threshold) for r in scored)
    assert len({round(r.threshold, 6) for r in scored}) > 1  # τ moves with curiosity (smoothed), and is what counts


def test_the_imagined_horizon_is_streamed_with_each_step_and_replayed_from_the_store(tmp_path: Any) -> None:
    from pathlib import Path

    from app.policies import load_policy
    from app.replay import open_replay
    from app.server import make_env
    from core.sessions import SessionStore

    policy = str(Path(__file__).resolve().parents[2] / "policies" / "ugv-default")
    store = SessionStore(tmp_path)
    sent: list[dict[str, Any]] = []
    loop = LiveLoop(
        LiveConfig(sim="ugv", scenario="3", policy=policy, expert_mode="scripted"),
        env_factory=make_env,
        policy_loader=load_policy,
        console=OperatorConsole(),
        publish=lambda text: sent.append(json.loads(text)),
        store=store,
        start_paused=True,
    )
    loop.start()
    try:
        for _ in range(6):
            loop.submit(c.StepOnce()).result(10)
        session = loop.state()["session"]
    finally:
        loop.stop()
    steps = [m for m in sent if m["type"] == "step"]
    from core.agents import load_agent

    gate = load_agent(policy).config.gate  # the imagined contact may reach further than the fear's horizon
    reach = max(gate.horizon, gate.contact_horizon or 0)
    assert reach == 10  # the UGV default's contact test reaches 1 s
    assert all(len(m["horizon"]["cost"]) == reach and len(m["horizon"]["mean"]) == reach for m in steps)
    replay = open_replay(store, session, 0)
    assert replay.series["horizon"] == [m["horizon"] for m in steps]


def _default_policy_live(sim: str, scenario: str, steps: int = 5, timeout: float = 30) -> list[dict[str, Any]]:
    """Open ``sim``'s committed default the way the dashboard's picker does, step it ``steps`` times live with the
    scripted expert, check that it has its gate, and return the streamed step messages."""
    from pathlib import Path

    from app.policies import default_policy, load_policy
    from app.server import make_env

    policy = default_policy([Path(__file__).resolve().parents[2] / "policies"], sim)
    assert policy.endswith(f"{sim}-default")
    sent: list[dict[str, Any]] = []
    loop = LiveLoop(
        LiveConfig(sim=sim, scenario=scenario, policy=policy, expert_mode="scripted"),
        env_factory=make_env,
        policy_loader=load_policy,
        console=OperatorConsole(),
        publish=lambda text: sent.append(json.loads(text)),
        start_paused=True,
    )
    loop.start()
    try:
        for _ in range(steps):
            loop.submit(c.StepOnce()).result(timeout)
        assert loop.state()["has_gate"]
    finally:
        loop.stop()
    return [m for m in sent if m["type"] == "step"]


def test_the_pedestrian_default_policy_is_served_live_with_its_gate() -> None:
    """The dashboard's picker finds policies/pedestrian-default; it drives the discrete-action simulator live
    with a working gate (fear and the imagined horizon on one-hot actions)."""
    steps = _default_policy_live("pedestrian", "crossing", timeout=10)
    assert len(steps) == 5 and all(m["fear"] is not None and len(m["horizon"]["cost"]) == 5 for m in steps)
    assert all(isinstance(m["action"][0], float) and m["action"][0] in range(9) for m in steps)


@pytest.mark.parametrize(("sim", "scenario"), [("highway", "test-adversarial"), ("sumo", "c2")])
def test_the_highway_and_sumo_defaults_are_served_live_with_fear(sim: str, scenario: str) -> None:
    """policies/highway-default and policies/sumo-default carry world models: the dashboard opens them with the
    gate, so fear, the threshold and the imagined horizon stream on every simulator out of the box."""
    steps = _default_policy_live(sim, scenario)
    assert len(steps) == 5
    assert all(0.0 <= m["fear"] <= 1.0 and 0.0 < m["threshold"] < 1.0 for m in steps)
    assert all(m["curiosity"] is not None and len(m["horizon"]["cost"]) == 5 for m in steps)


def test_the_dashboards_gate_settings_reach_every_policy_it_loads(tmp_path: Any) -> None:
    """``sage serve --set gate.hold_seconds=2``: the committed UGV policy's gate (a 1 s hold, 10 steps) holds for
    2 s there, and the live loop loads its policies through that loader."""
    from pathlib import Path

    from app.policies import load_policy
    from app.server import ServerSettings, make_env
    from tests.app.conftest import start_server, stop_server, toy_settings
    from tests.app.fakesim import toy_policy_loader

    policy = str(Path(__file__).resolve().parents[2] / "policies" / "ugv-default")
    env = make_env("ugv", "3")
    try:
        assert ServerSettings(policy_loader=load_policy).loader()(policy, env).gate.cfg.hold == 10
        longer = ServerSettings(policy_loader=load_policy, gate_settings={"hold_seconds": 2.0}).loader()
        assert longer(policy, env).gate.cfg.hold == 20
    finally:
        env.close()
    seen: list[Any] = []

    def recording(choice: str, env: Any, gate_overrides: Any = None) -> Any:
        seen.append(gate_overrides)
        return toy_policy_loader(choice, env)

    live, thread = start_server(toy_settings(tmp_path, policy_loader=recording, gate_settings={"hold_seconds": 2.0}))
    try:
        assert seen and all(s == {"hold_seconds": 2.0} for s in seen)
    finally:
        stop_server(live, thread)
