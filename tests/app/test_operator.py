"""The person as an expert: the fail-safe timing (injected clock, no sleeping), latest input wins,
the three expert modes, the control token, and the per-simulator input mapping."""

from __future__ import annotations

import itertools

import gymnasium as gym
import numpy as np
import pytest

from app.input_map import InputMapping, mapping_for, to_action
from app.operator import ControlDesk, OperatorConsole, PersonExpert
from tests.app.fakesim import ToyRobotEnv

BOX2 = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture
def setup() -> tuple[Clock, OperatorConsole, PersonExpert, ToyRobotEnv]:
    clock = Clock()
    console = OperatorConsole(clock=clock, timeout=0.2)
    expert = PersonExpert(console, mapping_for("ugv", BOX2), BOX2, mode="person")
    env = ToyRobotEnv()
    env.reset(seed=0)
    return clock, console, expert, env


def send(console: OperatorConsole, ts: float, held: bool, throttle: float = 0.0, steer: float = 0.0, seq: int = 0):
    return console.accept_input(seq=seq, ts=ts, held=held, throttle=throttle, steer=steer, source="keyboard")


def test_fresh_input_drives_and_silence_hands_over_to_the_fallback_after_200_ms(setup) -> None:
    clock, console, expert, env = setup
    console.connect()
    send(console, 1000.0, held=True, throttle=0.5, steer=-0.25)
    assert expert.wants_control()
    action, actor = expert.act(env, env._obs())
    assert actor == "person" and np.allclose(action, [0.5, -0.25])
    clock.now += 0.199
    assert expert.act(env, env._obs())[1] == "person"
    clock.now += 0.002  # 201 ms without input
    action, actor = expert.act(env, env._obs())
    assert actor == "fallback" and np.allclose(action, env.expert_action())
    assert expert.wants_control(), "a silent operator who was holding keeps the takeover, with the fallback"
    send(console, 1300.0, held=True, seq=1)  # the heartbeat is back...
    assert expert.act(env, env._obs())[1] == "fallback"  # ...but a late heartbeat must not flip control at once
    clock.now += expert.rejoin_after
    send(console, 1800.0, held=True, seq=2)
    assert expert.act(env, env._obs())[1] == "person"


def test_an_idle_page_never_drives_the_fallback_does_and_the_latency_is_measured(setup) -> None:
    """Heartbeats say the page is there, not that a person acts: the gate's request goes to the fallback until
    the person takes hold, and no person step is recorded without input."""
    clock, console, expert, env = setup
    console.connect()
    for k in range(10):  # a focused, idle page: fresh heartbeats, nothing held
        send(console, 1000.0 + 50 * k, held=False, seq=k)
        clock.now += 0.05
        action, actor = expert.act(env, env._obs())  # the gate fires
        assert actor == "fallback" and np.allclose(action, env.expert_action())
        expert.note_executed(action, actor, takeover=True)
    send(console, 1600.0, held=True, throttle=1.0, seq=20)  # the person answers the alert
    assert expert.act(env, env._obs())[1] == "person"
    assert expert.latencies and abs(expert.latencies[-1] - 0.45) < 1e-9  # first request to first hold


def test_late_heartbeats_do_not_flip_control_step_to_step(setup) -> None:
    clock, console, expert, env = setup
    console.connect()
    actors = []
    for k in range(40):  # a person holding, heartbeats arriving every 50 ms but one in four 300 ms late
        clock.now += 0.3 if k % 4 == 3 else 0.05
        send(console, 2000.0 + 100 * k, held=True, seq=k)
        actors.append(expert.act(env, env._obs())[1])
    switches = sum(a != b for a, b in itertools.pairwise(actors))
    assert switches <= 2 * 40 * 0.05 / expert.rejoin_after + 2, actors


def test_handover_is_bumpless_and_neutral_input_stops() -> None:
    clock = Clock()
    console = OperatorConsole(clock=clock, timeout=0.2)
    safe = np.array([-1.0, 0.0], np.float32)  # the UGV's: speed 0, no turning
    expert = PersonExpert(console, mapping_for("ugv", BOX2), BOX2, mode="person", safe=safe, max_jump=0.25)
    env = ToyRobotEnv()
    env.reset(seed=0)
    console.connect()
    expert.note_executed(np.array([1.0, 1.0], np.float32), "agent", takeover=False)  # full speed, turning
    send(console, 1.0, held=True, throttle=0.0, steer=0.0)  # holding, no direction: the safe action
    steps = []
    for _ in range(6):
        action, actor = expert.act(env, env._obs())
        assert actor == "person"
        expert.note_executed(action, actor, takeover=True)
        steps.append(action.copy())
    jumps = np.abs(np.diff(np.vstack([[1.0, 1.0], *steps]), axis=0)).max(axis=1)
    assert (jumps <= 0.25 * 2.0 + 1e-6).all(), jumps  # never more than a quarter of the range per step
    assert np.allclose(steps[-1], safe)  # and it arrives at a stop, not at half speed
    assert expert.handover_stats()["handover_jump_max"] <= 0.25 + 1e-6


def test_gate_requested_takeover_without_any_operator_goes_to_the_fallback_at_once(setup) -> None:
    _, console, expert, env = setup
    assert not expert.wants_control()  # nobody connected: the person never asks for control
    assert expert.act(env, env._obs())[1] == "fallback"  # but a gate-requested takeover is answered
    console.connect()
    assert expert.act(env, env._obs())[1] == "fallback"  # connected but no input yet


@pytest.mark.parametrize("leave", ["disconnect", "blur", "hide"])
def test_leaving_mid_takeover_latches_the_fallback_until_the_episode_ends(setup, leave: str) -> None:
    _, console, expert, env = setup
    console.connect()
    send(console, 1.0, held=True, throttle=1.0)
    assert expert.act(env, env._obs())[1] == "person"
    if leave == "disconnect":
        console.disconnect()
    else:
        console.set_presence(focused=leave != "blur", visible=leave != "hide")
    assert expert.wants_control() and expert.act(env, env._obs())[1] == "fallback"
    expert.reset()  # new episode
    assert not expert.wants_control()


def test_returning_operator_who_released_gives_control_back_to_the_agent(setup) -> None:
    clock, console, expert, env = setup
    console.connect()
    send(console, 1.0, held=True)
    assert expert.wants_control()  # the loop saw the person holding
    clock.now += 1.0
    assert expert.wants_control() and expert.act(env, env._obs())[1] == "fallback"
    send(console, 2.0, held=False, seq=1)
    assert not expert.wants_control()


def test_latest_input_wins_and_older_ones_are_dropped(setup) -> None:
    _, console, _, _ = setup
    console.connect()
    assert send(console, 10.0, held=True, throttle=1.0, seq=5)
    assert not send(console, 9.0, held=False, throttle=-1.0, seq=6)  # read earlier on the page: stale
    assert not send(console, 10.0, held=False, seq=5)  # the same input twice
    snap = console.snapshot()
    assert snap.held and snap.throttle == 1.0 and snap.seq == 5
    assert send(console, 10.0, held=False, seq=6)  # same ms, later sequence number


def test_input_from_nobody_is_refused(setup) -> None:
    _, console, _, _ = setup
    assert not send(console, 1.0, held=True)  # no operator connected


def test_takeover_onset_wakes_the_loop_once_per_press(setup) -> None:
    _, console, _, _ = setup
    onsets: list[int] = []
    console.on_takeover_onset = lambda: onsets.append(1)
    console.connect()
    send(console, 1.0, held=True, seq=1)
    send(console, 2.0, held=True, seq=2)
    send(console, 3.0, held=False, seq=3)
    send(console, 4.0, held=True, seq=4)
    assert len(onsets) == 2


def test_modes(setup) -> None:
    _, console, expert, env = setup
    console.connect()
    send(console, 1.0, held=False, throttle=0.3)
    expert.mode = "scripted"
    assert not expert.wants_control() and expert.act(env, env._obs())[1] == "expert"
    send(console, 2.0, held=True, throttle=0.3, seq=1)
    assert not expert.wants_control(), "scripted mode ignores the person"
    expert.mode = "person_fallback"
    assert expert.wants_control() and expert.act(env, env._obs())[1] == "person"
    send(console, 3.0, held=False, seq=2)
    # the gate asks while the person is not holding: the scripted expert answers as a normal expert
    assert not expert.wants_control() and expert.act(env, env._obs())[1] == "expert"
    expert.mode = "person"
    # present and fresh but not holding: a heartbeat is not a person driving, the fallback answers the gate
    assert expert.act(env, env._obs())[1] == "fallback"
    send(console, 4.0, held=True, throttle=0.3, seq=3)
    assert expert.act(env, env._obs())[1] == "person"


def test_scripted_mode_finishes_the_scripted_experts_manoeuvre(setup) -> None:
    """With nobody at the wheel (scripted mode), a manoeuvre the simulator's expert is engaged in keeps control
    past the gate's hold, as under the headless loop; once it ends, control is the gate's again."""
    _, _, expert, env = setup
    expert.mode = "scripted"
    env.expert_engaged = lambda: True  # type: ignore[attr-defined]
    assert not expert.wants_control() and expert.act(env, env._obs())[1] == "expert"
    assert expert.wants_control(), "engaged at its last action: it keeps the wheel"
    env.expert_engaged = lambda: False  # type: ignore[attr-defined]
    expert.act(env, env._obs())
    assert not expert.wants_control()
    expert.reset()
    assert not expert.wants_control()


def test_the_fallback_finishes_its_manoeuvre_unless_the_person_takes_the_wheel(setup) -> None:
    """Nobody holding when the gate asks: the fallback drives, and mid-manoeuvre keeps the wheel past the gate's
    hold. Once the person has driven, a manoeuvre the fallback was in before is no claim on the wheel."""
    _, console, expert, env = setup
    console.connect()
    send(console, 1.0, held=False)
    env.expert_engaged = lambda: True  # type: ignore[attr-defined]
    assert not expert.wants_control() and expert.act(env, env._obs())[1] == "fallback"
    assert expert.wants_control(), "the fallback is mid-manoeuvre"
    send(console, 2.0, held=True, throttle=0.3, seq=1)
    assert expert.wants_control() and expert.act(env, env._obs())[1] == "person"
    send(console, 3.0, held=False, seq=2)
    assert not expert.wants_control(), "the person let go: control is the gate's, not the fallback's old manoeuvre"


def test_control_desk_issues_one_token_at_a_time() -> None:
    desk = ControlDesk()
    first, second = object(), object()
    token = desk.claim(first)
    assert token is not None and desk.claim(first) == token  # claiming again is harmless
    assert desk.claim(second) is None
    assert desk.check(first, token) and not desk.check(second, token) and not desk.check(first, token + "x")
    assert not desk.release(second) and desk.holder() is first
    assert desk.release(first)
    new = desk.claim(second)
    assert new is not None and new != token and not desk.check(first, token)


def test_input_mapping_table_and_fallback_by_action_space() -> None:
    ugv = to_action(mapping_for("ugv", BOX2), BOX2, throttle=0.5, steer=1.0)
    assert ugv.dtype == np.float32 and np.allclose(ugv, [0.5, 1.0])
    highway = to_action(mapping_for("highway", BOX2), BOX2, throttle=0.5, steer=1.0)
    assert np.allclose(highway, [1.0, 0.5])  # sage/Highway-v0 takes [steer, acceleration], left positive
    sumo = to_action(mapping_for("sumo", gym.spaces.Box(-3.0, 2.0, (1,))), gym.spaces.Box(-3.0, 2.0, (1,)), 0.0, 1.0)
    assert np.allclose(sumo, [-0.5])  # scaled into [-3, 2]: the middle of the range, steering ignored
    assert mapping_for("unknown", BOX2) == InputMapping(0, 1)
    assert mapping_for("unknown", gym.spaces.Box(-1, 1, (1,))).steer_index is None
    discrete = gym.spaces.Discrete(3)
    assert [int(to_action(InputMapping(0, None), discrete, t, 0.0)) for t in (-1.0, 0.0, 1.0)] == [0, 1, 2]
    with pytest.raises(TypeError, match="MultiBinary"):
        to_action(InputMapping(0, 1), gym.spaces.MultiBinary(2), 0.0, 0.0)


class FullRight:
    """A policy whose every action is far from the person's: full speed, steering hard right."""

    def act(self, obs: np.ndarray, deterministic: bool = False) -> np.ndarray:
        return np.array([1.0, 1.0], np.float32)


def test_handover_person_to_policy_and_back_moves_at_most_a_quarter_of_the_range_per_step() -> None:
    """The hand-back to the policy once jumped 0.32 of the steering range in one step (the page showed "max
    handover jump 32%"): the person's actions were ramped, the policy's first ones were not. Driven through the
    live loop: policy, person (hard left, stopped), policy again, person again."""
    from app.live import LiveConfig, LiveLoop
    from app.policies import LoadedPolicy
    from core.loop import NoGate
    from tests.app.test_live_finetune import toy_env_factory

    clock = Clock()
    console = OperatorConsole(clock=clock, timeout=0.2)
    records = []
    loop = LiveLoop(
        LiveConfig(sim="toy", policy="right", expert_mode="person"),
        env_factory=toy_env_factory,
        policy_loader=lambda choice, env: LoadedPolicy(FullRight(), NoGate(), "right", {}),
        console=console,
        publish=lambda text: None,
        start_paused=True,
    )
    loop.world.runner.step_listeners.append(records.append)
    console.connect()
    seq = 0
    for held, steps in ((False, 4), (True, 10), (False, 10), (True, 10)):
        for _ in range(steps):
            seq += 1
            send(console, 1000.0 + seq, held=held, throttle=-1.0, steer=-1.0, seq=seq)
            loop._step_once()
    actors = [r.actor for r in records]
    assert "person" in actors and actors[-1] == "person"
    assert actors[:4] == ["agent"] * 4 and "agent" in actors[14:24]
    actions = np.array([np.asarray(r.action, np.float64) for r in records])
    assert records[0].episode == records[-1].episode  # one episode: every change below is a step of one drive
    span = BOX2.high - BOX2.low
    changes = np.abs(np.diff(actions, axis=0)) / span
    assert changes.max() <= 0.25 + 1e-6, (changes.max(axis=1), actors)
    assert np.allclose(actions[23], [1.0, 1.0])  # the policy drives its own action again once the ramp is over
    assert all(np.allclose(r.a_rl, [1.0, 1.0]) for r in records)  # its proposal is recorded unramped
    stats = loop.world.expert.handover_stats()
    assert stats["handovers"] >= 3 and stats["handover_jump_max"] <= 0.25 + 1e-6


def test_coaching_labels_the_agents_steps_with_the_persons_controls_only_while_they_coach_and_answer(setup) -> None:
    clock, console, expert, env = setup
    console.connect()
    obs = env._obs()

    def coach(ts: float, seq: int, held: bool = False, on: bool = True) -> None:
        console.accept_input(seq=seq, ts=ts, held=held, throttle=0.5, steer=-0.25, source="keyboard", coach=on)

    send(console, 1.0, held=False, throttle=0.5, steer=-0.25)
    assert expert.coach(env, obs) is None  # steering without coaching on is not a label
    coach(2.0, 1)
    label = expert.coach(env, obs)
    assert label is not None and np.allclose(label, [0.5, -0.25])
    assert not expert.wants_control(), "coaching never takes the wheel"
    coach(3.0, 2, held=True)  # holding the takeover: the person drives, nothing is a label
    assert expert.coach(env, obs) is None and expert.wants_control()
    coach(4.0, 3)
    clock.now += 0.201  # silent: no longer answering, so no label
    assert expert.coach(env, obs) is None
    coach(5.0, 4)
    expert.mode = "scripted"  # the person's input is ignored in scripted mode, labels too
    assert expert.coach(env, obs) is None
    expert.mode = "person_fallback"
    assert expert.coach(env, obs) is not None
    coach(6.0, 5, on=False)
    assert expert.coach(env, obs) is None
