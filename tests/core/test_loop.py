"""The one step loop: who acts, what is recorded, and that a crashing simulator never stops it."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

from core.experts import ScriptedExpert
from core.loop import GateDecision, Runner, StepRecord
from tests.core.line_env import LineEnv


class Still:
    def act(self, obs: np.ndarray, deterministic: bool = False) -> np.ndarray:
        return np.array([0.0], np.float32)


class FiresAtStep:
    """Fires exactly at the given steps (no hold), so the loop's own logic is what is tested."""

    def __init__(self, steps: set[int]) -> None:
        self.steps, self.t = steps, 0

    def reset(self) -> None:
        self.t = 0

    def decide(self, obs: np.ndarray, a_rl: np.ndarray) -> GateDecision:
        fired = self.t in self.steps
        self.t += 1
        return GateDecision(fear=1.0 if fired else 0.0, threshold=0.5, fired=fired)

    def observe(self, obs: np.ndarray, action: np.ndarray, next_obs: np.ndarray) -> float:
        return 0.25


def test_gate_hands_control_to_expert_and_both_actions_are_recorded() -> None:
    runner = Runner(LineEnv(), Still(), FiresAtStep({2, 3}), ScriptedExpert())
    records: list[StepRecord] = []
    runner.step_listeners.append(records.append)
    summary = runner.run_episode()
    assert [r.takeover for r in records] == [False, False, True, True] + [False] * 6
    assert [r.actor for r in records[:4]] == ["agent", "agent", "expert", "expert"]
    assert records[2].a_expert is not None and records[2].a_rl[0] == 0.0 and records[2].action[0] == 1.0
    assert records[0].a_expert is None
    assert summary.takeovers == 2 and summary.takeover_events == 1 and summary.steps == 10
    assert summary.metrics == {"x": 2.0}
    assert summary.mean_curiosity == pytest.approx(0.25)


class ManoeuvringLineEnv(LineEnv):
    """The expert's manoeuvre lasts while x < 3: it says so through the protocol's ``expert_engaged``."""

    def expert_engaged(self) -> bool:
        return self.x < 3


@pytest.mark.parametrize("finish", [True, False])
def test_the_scripted_expert_finishes_its_manoeuvre_before_handing_back(finish: bool) -> None:
    """The gate fires at step 1 only; the expert, engaged until x reaches 3, keeps the wheel until then (as a
    person holds the takeover key) and hands back at once after. Without finishing, it hands back with the gate.
    A simulator without ``expert_engaged`` (LineEnv) is never held: the first test above."""
    runner = Runner(ManoeuvringLineEnv(), Still(), FiresAtStep({1, 7}), ScriptedExpert(finish_manoeuvres=finish))
    records: list[StepRecord] = []
    runner.step_listeners.append(records.append)
    runner.run_episode()
    # the expert moves x by 1 a step and is engaged when it acts from x = 0, 1, 2: its action from x = 3 is its last
    held = [False, True, True, True, True] if finish else [False, True, False, False, False]
    assert [r.takeover for r in records] == held + [False] * 2 + [True] + [False] * 2
    assert records[-1].obs[0] == (4.0 if finish else 1.0) + 1.0


def test_without_expert_the_gate_cannot_take_over() -> None:
    runner = Runner(LineEnv(), Still(), FiresAtStep({0, 1, 2}), expert=None)
    summary = runner.run_episode()
    assert summary.takeovers == 0 and summary.metrics["x"] == 0.0


def test_simulator_crash_ends_episode_with_error_and_loop_goes_on() -> None:
    runner = Runner(LineEnv(crash_at=3), Still())
    summary = runner.run_episode()
    assert summary.error is not None and "simulator crashed" in summary.error
    assert summary.steps == 2
    runner.env.unwrapped.crash_at = None  # the next episode runs normally
    assert runner.run_episode().error is None


def test_policy_swap_waits_for_episode_boundary() -> None:
    class Push:
        def act(self, obs: np.ndarray, deterministic: bool = False) -> np.ndarray:
            return np.array([0.5], np.float32)

    runner = Runner(LineEnv(horizon=4), Still())
    runner.reset()
    runner.step()
    runner.set_policy_at_boundary(Push())
    while (rec := runner.step()) is not None and not rec.done:
        pass
    assert runner.env.unwrapped.x == 0.0  # the old policy finished its episode
    assert runner.run_episode().metrics["x"] == pytest.approx(2.0)


def test_message_is_json_ready_with_nan_as_none() -> None:
    runner = Runner(LineEnv(), Still())
    runner.reset()
    record = runner.step()
    assert record is not None
    message = record.to_message()
    assert message["fear"] is None and message["action"] == [0.0] and not math.isnan(message["reward"])


def test_env_without_protocol_is_refused_clearly() -> None:
    with pytest.raises(TypeError, match="expert_action"):
        Runner(gym.make("CartPole-v1"), Still())


def test_ending_an_episode_early_reports_it_once_and_starts_afresh() -> None:
    runner = Runner(LineEnv(horizon=10), Still())
    summaries = []
    runner.episode_listeners.append(summaries.append)
    runner.reset()
    runner.step()
    runner.step()
    runner.end_episode()
    runner.end_episode()  # between episodes: nothing more to report
    assert len(summaries) == 1 and summaries[0].steps == 2 and summaries[0].error is None
    record = runner.step()
    assert record is not None and record.episode == 1 and record.t == 0


def test_a_policy_that_raises_ends_the_episode_not_the_loop() -> None:
    class Flaky:
        calls = 0

        def act(self, obs: np.ndarray, deterministic: bool = False) -> np.ndarray:
            Flaky.calls += 1
            if Flaky.calls == 3:
                raise ConnectionResetError("simulator worker died")
            return np.array([0.0], np.float32)

    runner = Runner(LineEnv(horizon=5), Flaky())
    summary = runner.run_episode()
    assert summary.error is not None and "worker died" in summary.error and summary.steps == 2
    assert runner.run_episode().error is None


def test_policy_and_gate_swap_together_at_the_boundary_and_reset_options_reach_the_env() -> None:
    from core.sage.gate import AlwaysGate
    from tests.core.sage import envs

    env = envs.make("static")
    seen: list[dict | None] = []
    original_reset = env.reset

    def spy(*, seed=None, options=None):  # type: ignore[no-untyped-def]
        seen.append(options)
        return original_reset(seed=seed, options=options)

    env.reset = spy  # type: ignore[method-assign]

    class Still:
        def act(self, obs, deterministic=False):  # type: ignore[no-untyped-def]
            return np.zeros(2, np.float32)

    first, second = Still(), Still()
    runner = Runner(env, first, None, None, seed=0)
    runner.reset()
    runner.step()
    runner.set_policy_at_boundary(second, AlwaysGate())
    runner.set_next_reset_options({"mode": "x"})
    runner.step()
    assert runner.policy is first and not isinstance(runner.gate, AlwaysGate)  # never mid-episode
    runner.end_episode()
    runner.step()  # the next episode starts with both
    assert runner.policy is second and isinstance(runner.gate, AlwaysGate)
    assert seen[-1] == {"mode": "x"} and seen[0] is None
    runner.end_episode()
    runner.step()
    assert seen[-1] is None  # options are for one reset only


def test_a_coaching_expert_labels_the_agents_steps_without_taking_the_wheel() -> None:
    from core.experts import CoachingExpert

    runner = Runner(LineEnv(), Still(), FiresAtStep({2}), CoachingExpert(ScriptedExpert(), share=1.0))
    records: list[StepRecord] = []
    runner.step_listeners.append(records.append)
    summary = runner.run_episode()
    agent = [r for r in records if not r.takeover]
    assert len(agent) == 9 and records[2].takeover and not records[2].coached
    for r in agent:  # the label is the expert's (+1), what ran is the agent's own (0), and the agent is the actor
        assert r.coached and r.actor == "agent" and r.a_expert is not None and r.a_expert[0] == 1.0
        assert r.action[0] == 0.0 and r.to_message()["coached"] is True
    assert summary.takeovers == 1 and summary.coached == 9 and summary.as_row()["coached"] == 9


def test_coaching_draws_its_share_from_its_own_stream_and_a_share_of_zero_is_no_coach() -> None:
    from core.experts import CoachingExpert

    def coached_steps(expert: object, episodes: int = 30) -> list[tuple[int, int]]:
        runner = Runner(LineEnv(), Still(), FiresAtStep(set()), expert)  # type: ignore[arg-type]
        records: list[StepRecord] = []
        runner.step_listeners.append(records.append)
        for _ in range(episodes):
            runner.run_episode()
        return [(r.episode, r.t) for r in records if r.coached]

    first = coached_steps(CoachingExpert(ScriptedExpert(), share=0.3, seed=5))
    assert 0.2 < len(first) / 300 < 0.4
    assert coached_steps(CoachingExpert(ScriptedExpert(), share=0.3, seed=5)) == first
    assert coached_steps(CoachingExpert(ScriptedExpert(), share=0.3, seed=6)) != first
    runner = Runner(LineEnv(), Still(), FiresAtStep(set()), CoachingExpert(ScriptedExpert(), share=0.0))
    assert "coached" not in runner.run_episode().as_row()  # the rows of a run without a coach stay as they were
    with pytest.raises(ValueError, match="share"):
        CoachingExpert(ScriptedExpert(), share=1.5)
