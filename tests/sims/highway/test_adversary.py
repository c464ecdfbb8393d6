"""CAT-style adversarial resampling: what it changes in a log, and that it makes the set harder."""

from __future__ import annotations

import numpy as np
import pytest

import sims
from sims.highway.adversary import resample
from sims.highway.config import DEFAULT
from sims.highway.env import predict_ego_path
from sims.highway.scenarios import load_log
from sims.highway.traffic import Paths
from studies.highway import PAPER_COLUMNS, interaction_table, paper_table
from studies.highway_evaluate import evaluate
from tests.sims.highway.conftest import FEW_TEST_IDS, LaneKeeper


def _mean(rows: list[dict[str, float]], key: str) -> float:
    return float(np.mean([r[key] for r in rows]))


def test_resampled_opponent_keeps_its_log_until_the_event_then_cuts_in_or_brakes() -> None:
    log = load_log(FEW_TEST_IDS[1])
    base = Paths.from_log(log)
    plan, _ = predict_ego_path(log, base, DEFAULT, None)
    adv, events = resample(base, plan, log.spec.layout, DEFAULT, np.random.default_rng(0))
    assert len(events) == DEFAULT.adversary.opponents == 1
    ev = events[0]
    i, f0 = ev.vehicle, ev.frame
    changed = np.flatnonzero(np.any(adv.state != base.state, axis=(0, 2)))
    assert changed.tolist() == [i] and adv.adversarial.tolist() == [k == i for k in range(base.count)]
    assert np.array_equal(adv.state[:f0, i], base.state[:f0, i])  # the log, up to the event
    assert np.allclose(adv.state[f0, i, :2], base.state[f0, i, :2])  # no jump at the event
    steps = np.hypot(np.diff(adv.x[f0:, i]), np.diff(adv.y[f0:, i]))
    assert steps.max() <= adv.speed[f0:, i].max() * adv.dt + 1e-6  # moves no faster than its own speed
    lane_after = log.spec.layout.lane_of(adv.y[-1, i])
    ego_lane = log.spec.layout.lane_of(plan[min(f0 + 20, log.frames - 1), 1])
    assert lane_after == ego_lane  # it ends up in the lane the ego was predicted to use
    assert ev.risk > 0.5 and ev.candidates > 1
    assert base.state is not adv.state and not base.adversarial.any()  # the base paths are untouched
    again, events_again = resample(Paths.from_log(log), plan, log.spec.layout, DEFAULT, np.random.default_rng(0))
    assert events_again == events and np.array_equal(again.state, adv.state)  # same seed, same variant


def test_the_ego_predictor_is_rolled_to_target_the_current_policy() -> None:
    calls: list[int] = []

    def policy(obs: np.ndarray) -> np.ndarray:
        calls.append(1)
        return LaneKeeper().act(obs)

    env = sims.make("highway", scenario_id=FEW_TEST_IDS[1], mode="adversarial", ego_predictor=policy)
    _, info = env.reset(seed=0)
    assert len(calls) > 50 and info["adversary_events"]
    # a deterministic ego that is its own predictor drives exactly the predicted path until the event
    log = env.unwrapped.log
    plan, _ = predict_ego_path(log, Paths.from_log(log), DEFAULT, policy)
    event_frame = info["adversary_events"][0]["frame"]
    obs = env.reset(seed=0)[0]
    every = round(log.dt / DEFAULT.dt)
    for step in range(1, event_frame * every + 1):
        obs, *_ = env.step(policy(obs))
        if step % every == 0:
            assert np.allclose(env.unwrapped.world.ego_state, plan[step // every])
    with pytest.raises(ValueError, match="unknown ego_predictor"):
        sims.make("highway", scenario_id=FEW_TEST_IDS[1], mode="adversarial", ego_predictor="oracle").reset(seed=0)


def test_adversarial_set_is_harder_for_the_same_simple_policy() -> None:
    """The paper's check: smaller gaps, lower time to collision, and more collisions than log replay."""
    keeper = LaneKeeper()
    n = len(FEW_TEST_IDS)
    normal = evaluate(keeper, "test", "normal", episodes=n)
    adversarial = evaluate(keeper, "test", "adversarial", episodes=n)
    assert [r["scenario_id"] for r in normal] == [r["scenario_id"] for r in adversarial] == FEW_TEST_IDS
    assert all(r["adversary_events"] >= 1 for r in adversarial)
    assert _mean(adversarial, "mean_gap") < _mean(normal, "mean_gap")
    assert _mean(adversarial, "min_ttc") < _mean(normal, "min_ttc") - 2.0
    assert _mean(adversarial, "collision") >= _mean(normal, "collision") + 0.25
    results = {"keeper": {("test", "normal"): normal, ("test", "adversarial"): adversarial}}
    table = paper_table(results)
    assert all(f"adversarial {title}" in table for _, title in PAPER_COLUMNS) and "keeper" in table
    assert "min_ttc" in interaction_table(results)
