"""Multi-Hug RL: the supervisor steps in on its own judgement, the agent's last action before an intervention is
penalised, and supervised training episodes on the UGV collide less than unsupervised ones from the same start."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from core.experts import CostSupervisor
from core.finetune import ingest
from core.learners import make_learner, preset
from core.loop import StepRecord
from core.sage.multi_hug import MultiHug
from core.sessions import SessionStore
from studies.spec import TrainSpec
from studies.training import run_training
from tests.core.test_export import recorded  # noqa: F401 (a fixture)


def record(t: int, cost: float = 0.0, takeover: bool = False, episode: int = 0, reward: float = 1.0) -> StepRecord:
    action = np.zeros(2, np.float32)
    return StepRecord(
        episode=episode, t=t, obs=np.full(3, t, np.float32), a_rl=action, a_expert=action if takeover else None,
        action=action, takeover=takeover, gate_fired=False, actor="expert" if takeover else "agent", fear=math.nan,
        threshold=math.nan, curiosity=math.nan, reward=reward, cost=cost, violation=False, terminated=False,
        truncated=False, next_obs=np.full(3, t + 1, np.float32), wall_time=0.0,
    )  # fmt: skip


class Nobody:
    def reset(self) -> None:
        pass

    def wants_control(self) -> bool:
        return False

    def act(self, env: object, obs: np.ndarray) -> tuple[np.ndarray, str]:
        return np.zeros(2, np.float32), "expert"


def test_the_supervisor_steps_in_on_a_costly_step_and_holds() -> None:
    supervisor = CostSupervisor(Nobody(), threshold=0.5, hold_steps=3)
    supervisor.reset()
    wants = []
    for t, cost in enumerate([0.1, 0.4, 0.6, 0.0, 0.0, 0.0, 0.0, 0.7, 0.0]):
        supervisor.observe(record(t, cost))
        wants.append(supervisor.wants_control())
    assert wants == [False, False, True, True, True, False, False, True, True]
    supervisor.reset()
    assert not supervisor.wants_control()


def test_the_agents_last_action_before_an_intervention_is_penalised() -> None:
    cfg = preset("multi-hug", intervention_penalty=10.0)
    learner = make_learner("multi-hug", cfg, 3, 2, seed=0)
    assert isinstance(learner, MultiHug) and cfg.takeover_rule == "supervisor" and not cfg.world_model
    steps = [
        record(0),
        record(1),
        record(2, takeover=True),
        record(3, takeover=True),
        record(4),
        record(5, takeover=True),
    ]
    steps += [record(0, episode=1, takeover=True)]  # a new episode that starts under the expert: nothing to blame
    for step in steps:
        learner.store(step)
    assert learner.buffer.reward[:7].tolist() == [1.0, -9.0, 1.0, 1.0, -9.0, 1.0, 1.0]
    assert learner.shaped == 2


def test_a_sage_learner_shapes_the_action_before_a_gate_takeover_only_when_asked() -> None:
    """The shaping is every learner's store: SAGE's rows (the gate called the expert) lose the penalty at each
    takeover onset when ``intervention_penalty`` is set, and keep their rewards when it is not (the paper's SAGE)."""
    steps = [record(0), record(1, takeover=True), record(2, takeover=True), record(3), record(4, takeover=True)]
    rewards = {}
    for penalty in (0.0, 4.0):
        learner = make_learner("sage", preset("sage", intervention_penalty=penalty), 3, 2, seed=0)
        for step in steps:
            learner.store(step)
        rewards[penalty] = learner.buffer.reward[:5].tolist()
        assert learner.shaped == (2 if penalty else 0)
    assert rewards[0.0] == [1.0] * 5
    assert rewards[4.0] == [-3.0, 1.0, 1.0, -3.0, 1.0]


def test_supervised_training_on_the_ugv_collides_less_than_unsupervised(tmp_path: Path) -> None:
    """The same warm start, the same seeds, no gradient updates (what differs is only who drives when): the
    stand-in supervisor's interventions save crossings that the policy alone runs into."""
    collisions = {}
    for method in ("multi-hug", "sac"):
        spec = TrainSpec(
            sim="ugv",
            scenario="3",
            method=method,
            seed=0,
            episodes=6,
            init=str(Path(__file__).resolve().parents[2] / "policies" / "ugv-default"),
            checkpoint_every=0,
            out=str(tmp_path / method),
            overrides=["updates_per_step=0"],
        )
        rows = run_training(spec).result.rows
        collisions[method] = sum(int(row["collision"]) for row in rows)
        if method == "multi-hug":
            assert sum(row["takeovers"] for row in rows) > 0
    assert collisions["sac"] >= 3, collisions
    assert collisions["multi-hug"] <= collisions["sac"] - 3, collisions


def test_live_takeovers_ingested_for_fine_tuning_are_shaped_too(recorded: tuple[SessionStore, str]) -> None:  # noqa: F811
    """Fine-tuning from a dashboard session goes through the learner's own store: the person's interventions
    penalise the agent's action before each of them, as headless supervision does."""
    store, session_id = recorded
    steps = store.steps(session_id)
    learner = make_learner("multi-hug", preset("multi-hug", intervention_penalty=10.0), 1, 1, seed=0)
    assert isinstance(learner, MultiHug)
    ingested = ingest(learner, store, session_id, sorted(set(steps["episode"].tolist())))
    onsets = sum(
        1
        for i in range(1, len(steps["t"]))
        if steps["takeover"][i] and not steps["takeover"][i - 1] and steps["episode"][i] == steps["episode"][i - 1]
    )
    assert ingested.takeovers > 0 and onsets > 0
    assert learner.shaped == onsets
    shaped_rows = np.isclose(learner.buffer.reward[: learner.buffer.size], steps["reward"].astype(np.float32) - 10.0)
    assert int(shaped_rows.sum()) == onsets
