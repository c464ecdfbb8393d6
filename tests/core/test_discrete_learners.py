"""Discrete actions through the one stack: a toy value learner registered in a test, D3QN and SAGE-D3QN.

The learners fit without touching the loop, the checkpoints or the loader: ``sage train`` trains them,
``sage eval`` loads them back, the SAGE gate rolls the greedy policy on one-hot actions.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from torch import Tensor, nn
from typer.testing import CliRunner

from core.learners import register_learner, unregister_learner
from core.sage.config import AgentConfig, for_method
from core.sage.learner import BaseLearner, DeclaredState

torch.set_num_threads(1)


class ToyQ(BaseLearner):
    """A linear Q-function over (observation, 1) per action, one-step TD, ε-greedy: the smallest value learner."""

    acting_module = "table"
    encodes_actions = True

    def build_networks(self) -> None:
        self.first = round(float(self.action_low[0]))
        self.n = round(float(self.action_high[0])) - self.first + 1
        self.table = nn.Linear(self.obs_dim, self.n)
        self.optimizer = torch.optim.SGD(self.table.parameters(), lr=0.1)

    @property
    def model_action_dim(self) -> int:
        return self.n

    def encode_action(self, action: Any) -> np.ndarray:
        value = np.asarray(action, np.float32).reshape(-1)
        if value.size == self.n:
            return value
        return np.eye(self.n, dtype=np.float32)[round(float(value[0])) - self.first]

    def random_action(self) -> np.ndarray:
        return np.array([self.first + self.rng.integers(self.n)], np.int64)

    def policy_action(self, obs: np.ndarray, deterministic: bool) -> np.ndarray:
        if not deterministic and self.rng.random() < 0.2:
            return self.random_action()
        with torch.no_grad():
            q = self.table(torch.as_tensor(obs, dtype=torch.float32).view(1, -1))
        return np.array([self.first + int(q.argmax())], np.int64)

    def rollout_policy(self, obs: Tensor) -> Tensor:
        return torch.nn.functional.one_hot(self.table(obs).argmax(-1), self.n).to(obs.dtype)

    def update(self) -> dict[str, float]:
        batch = self.buffer.sample(self.cfg.batch_size, self.rng)
        with torch.no_grad():
            target = batch.reward + self.cfg.gamma * (1 - batch.terminated) * self.table(batch.next_obs).max(-1).values
        q = (self.table(batch.obs) * batch.action).sum(-1)
        loss = (q - target).pow(2).mean()
        self.optimizer.zero_grad()
        loss.backward()
        self.optimizer.step()
        return {"td_loss": loss.item()}

    def declared_state(self) -> DeclaredState:
        return DeclaredState(modules=("table",), optimizers=("optimizer",))


def toy_preset(base: AgentConfig | None = None, **overrides: Any) -> AgentConfig:
    cfg = for_method("sac", base, batch_size=16, learning_starts=20, gamma=0.9)
    cfg.method = "toy-q"
    return cfg


@pytest.fixture
def corridor(monkeypatch: pytest.MonkeyPatch) -> None:
    import sims

    monkeypatch.setitem(sims.SIMULATORS, "corridor", "tests.core.corridor_env")


@pytest.fixture
def toy_learner() -> Any:
    register_learner("toy-q", ToyQ, preset=toy_preset)
    yield
    unregister_learner("toy-q")


def test_a_toy_discrete_learner_trains_saves_and_loads_through_the_commands(
    corridor: None, toy_learner: None, tmp_path: Path
) -> None:
    from app.cli import app

    cli = CliRunner()
    out = tmp_path / "toy"
    args = ["train", "--sim", "corridor", "--method", "toy-q", "--episodes", "40", "--seed", "0"]
    result = cli.invoke(app, [*args, "--checkpoint-every", "0", "--quiet", "--out", str(out)])
    assert result.exit_code == 0, result.output
    payload = torch.load(out / "checkpoint.pt", weights_only=True)
    assert set(payload["state"]) >= {"table", "optimizers"} and "actor" not in payload["state"]
    result = cli.invoke(app, ["eval", str(out), "--episodes", "3", "--quiet", "--save", str(tmp_path / "rows.jsonl")])
    assert result.exit_code == 0, result.output
    rows = [json.loads(line) for line in (tmp_path / "rows.jsonl").read_text().splitlines()]
    assert [r["success"] for r in rows] == [1.0, 1.0, 1.0]  # it learned to walk right, and loaded back


def test_d3qn_learns_the_corridor_and_sage_d3qn_gates_on_one_hot_actions(corridor: None, tmp_path: Path) -> None:
    from core.agents import load_agent
    from studies.spec import TrainSpec
    from studies.training import run_training

    small = ["hidden=32", "batch_size=32", "learning_starts=40", "discrete.epsilon_decay_steps=300", "polyak=0.05"]
    spec = TrainSpec(sim="corridor", method="d3qn", episodes=60, checkpoint_every=0, overrides=small)
    outcome = run_training(spec.replace(out=str(tmp_path / "d3qn")))
    early = np.mean([r["success"] for r in outcome.result.rows[:10]])
    late = np.mean([r["success"] for r in outcome.result.rows[-10:]])
    assert late > early and late >= 0.9, (early, late)
    agent = load_agent(tmp_path / "d3qn")
    assert agent.policy.act(np.array([0.0, 1.0], np.float32), deterministic=True).tolist() == [2]

    sage = ["wm_min_samples=60", "wm_fit_every=100", "world_model_config.hidden=16", *small]
    outcome = run_training(TrainSpec(sim="corridor", method="sage-d3qn", episodes=12, checkpoint_every=0,
                                     demo_episodes=2, overrides=sage, out=str(tmp_path / "sage")))  # fmt: skip
    agent = load_agent(tmp_path / "sage")
    assert agent.world_model is not None and agent.world_model.act_dim == 3  # one-hot actions
    gate = agent.make_gate()
    decision = gate.decide(np.array([0.0, 1.0], np.float32), np.array([2]))
    assert np.isfinite(decision.fear) and np.isfinite(gate.observe(np.zeros(2), np.array([1]), np.zeros(2)))
    horizon = gate.last_horizon()  # the generic (policy-function) path keeps its rollout too
    assert horizon is not None and len(horizon["cost"]) == gate.cfg.horizon and len(horizon["cost"][0]) == 5
    assert outcome.result.demo_rows and outcome.result.learner.buffer.takeover_count() > 0


def test_plain_d3qn_collides_often_in_its_first_encounters_with_the_occluded_pedestrian(tmp_path: Path) -> None:
    """The long-tail premise (issue #12): without an expert, the first encounters end in collisions."""
    from studies.spec import TrainSpec
    from studies.training import run_training

    spec = TrainSpec(sim="pedestrian", scenario="crossing", method="d3qn", episodes=10, checkpoint_every=0)
    rows = run_training(spec.replace(out=str(tmp_path / "ped"))).result.rows
    assert sum(r["collision"] for r in rows) >= 7, [r["collision"] for r in rows]


def test_demonstration_noise_is_refused_for_discrete_actions(corridor: None, tmp_path: Path) -> None:
    from studies.spec import TrainSpec
    from studies.training import run_training

    spec = TrainSpec(sim="corridor", method="d3qn", episodes=1, demo_episodes=1, demo_noise=0.3)
    with pytest.raises(ValueError, match="demo-noise"):
        run_training(spec.replace(out=str(tmp_path / "x")))


def test_discrete_hg_dagger_learns_a_safe_driver_from_the_scripted_experts_takeovers(tmp_path: Path) -> None:
    """The paper's long-tail expert is trained by HG-DAgger; here from the scripted driver's labels. It learns
    to brake for the occluded pedestrian where plain D3QN's first encounters collide (test above)."""
    from core.agents import load_agent
    from core.train import evaluate
    from studies.envs import env_factory
    from studies.spec import TrainSpec
    from studies.training import run_training

    spec = TrainSpec(sim="pedestrian", scenario="crossing", method="hg-dagger-discrete", episodes=20,
                     demo_episodes=10, checkpoint_every=0, out=str(tmp_path / "hgd"))  # fmt: skip
    run_training(spec)
    rows = evaluate(load_agent(tmp_path / "hgd").policy, env_factory("pedestrian"), ["crossing"], 10, 0, progress=False)
    assert sum(r["collision"] for r in rows["crossing"]) <= 2, rows
