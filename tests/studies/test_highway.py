"""Closed-loop adversarial training on highway (the hook, inside the real trainer) and the paper's table."""

from __future__ import annotations

import re
from typing import Any

import numpy as np
import pytest
import torch

import sims
from core.loop import Runner
from core.sage.config import for_method
from core.train import RunConfig, Trainer
from studies.envs import env_factory
from studies.highway import ClosedLoopAdversary, evaluate_policy, paper_table, parse_modes, parse_sets

torch.set_num_threads(1)


class Cruise:
    """Keeps the wheel straight and the speed: a fixed, cheap policy."""

    def act(self, obs: np.ndarray, deterministic: bool = False) -> np.ndarray:
        return np.zeros(2, np.float32)


def tiny(method: str) -> Any:
    cfg = for_method(method, hidden=16, batch_size=8, learning_starts=10)
    return cfg


def test_the_adversary_is_aimed_at_the_current_policy_before_every_episode() -> None:
    hook = ClosedLoopAdversary(adversarial_ratio=1.0, seed=0)
    run = RunConfig(sim="highway", scenarios=["train"], episodes=3, seed=0, max_episode_steps=8, checkpoint_every=0)
    trainer = Trainer(run, tiny("sac"), env_factory("highway"), None, False, [hook])
    inner = trainer.envs["train"].unwrapped
    calls: list[tuple[int, Any]] = []
    original = inner.set_ego_predictor

    def spy(predictor: Any) -> None:
        calls.append((trainer.learner.env_steps, predictor))
        original(predictor)

    inner.set_ego_predictor = spy
    try:
        result = trainer.train()
    finally:
        trainer.close()
    assert [predictor for _, predictor in calls] == [trainer.learner] * 3  # the learner, i.e. the current policy
    assert [steps for steps, _ in calls] == [0, 8, 16]  # once before each episode, after the previous one
    assert [row["adversarial"] for row in result.rows] == [1.0, 1.0, 1.0]
    assert hook.modes == ["adversarial"] * 3


def test_the_mode_mix_follows_the_ratio_and_the_seed() -> None:
    env = sims.make("highway", split="train")
    runner = Runner(env, Cruise())
    try:
        for ratio, expected in ((0.0, {"normal"}), (1.0, {"adversarial"})):
            hook = ClosedLoopAdversary(ratio, seed=1)
            for episode in range(6):
                hook(episode, runner)
            runner.reset()  # the mode reaches the env as a reset option
            assert set(hook.modes) == expected and env.unwrapped.current_mode in expected
        draws = [ClosedLoopAdversary(0.5, seed=3) for _ in range(2)]
        for hook in draws:
            for episode in range(40):
                hook(episode, runner)
        assert draws[0].modes == draws[1].modes and 10 < draws[0].modes.count("adversarial") < 30
    finally:
        env.close()
    with pytest.raises(ValueError, match="in \\[0, 1\\]"):
        ClosedLoopAdversary(1.5)


def test_the_hook_refuses_a_simulator_without_adversaries() -> None:
    env = sims.make("sumo")
    try:
        with pytest.raises(TypeError, match="set_ego_predictor"):
            ClosedLoopAdversary(0.5)(0, Runner(env, Cruise()))
    finally:
        env.close()


def test_paper_table_puts_normal_and_adversarial_side_by_side() -> None:
    def rows(success: list[float], speed: list[float]) -> list[dict[str, float]]:
        pairs = zip(success, speed, strict=True)
        return [{"success": s, "collision": 1.0 - s, "speed_mean": v, "acc_mean": 1.0} for s, v in pairs]

    results = {
        "sac": {("test", "normal"): rows([1, 1, 1, 0], [8, 10, 8, 10]), ("test", "adversarial"): rows([1, 0], [6, 8])},
        "sage": {("train", "normal"): rows([1], [9]), ("train", "adversarial"): rows([0], [7])},
    }
    lines = paper_table(results).splitlines()
    header = lines[0]
    for mode in ("normal", "adversarial"):
        for title in ("S.R.(%)", "C.R.(%)", "Speed (m/s)", "Acc. (m/s²)"):
            assert f"{mode} {title}" in header
    assert header.index("normal S.R.(%)") < header.index("adversarial S.R.(%)")
    train_line, test_line = lines[2], lines[3]  # the train set first, as in the paper
    assert train_line.split()[:2] == ["train", "sage"]
    assert test_line.split()[:3] == ["test", "sac", "2/4"]
    cells = [cell.strip() for cell in re.split(r"\s{2,}", test_line)]
    assert cells[3:] == ["75.0", "25.0", "9.00 ± 1.00", "1.00 ± 0.00", "50.0", "50.0", "7.00 ± 1.00", "1.00 ± 0.00"]


def test_set_and_mode_lists_are_checked() -> None:
    assert parse_sets("train,test") == ["train", "test"] and parse_modes("adversarial") == ["adversarial"]
    with pytest.raises(ValueError, match="choose from train, test"):
        parse_sets("val")
    with pytest.raises(ValueError, match="choose from normal, adversarial"):
        parse_modes("normal,hard")


def test_evaluation_pools_seeds_and_aims_adversaries_at_the_policy() -> None:
    results = evaluate_policy(Cruise(), ["test"], ["normal", "adversarial"], episodes=2, seeds=[0, 1])
    assert set(results) == {("test", "normal"), ("test", "adversarial")}
    normal, adversarial = results[("test", "normal")], results[("test", "adversarial")]
    assert [r["seed"] for r in normal] == [0, 0, 1, 1]
    assert [r["adversarial"] for r in adversarial] == [1.0] * 4 and [r["adversarial"] for r in normal] == [0.0] * 4
    # the logged replay does not depend on the seed; both seeds drove the same two scenarios
    assert [r["scenario_id"] for r in normal[:2]] == [r["scenario_id"] for r in normal[2:]]
    assert [r["speed_mean"] for r in normal[:2]] == [r["speed_mean"] for r in normal[2:]]
    assert sum(r["adversary_events"] for r in adversarial) > 0
