"""Safety-gated promotion: a fine-tuned version drives only if it is no worse than the one in control."""

from __future__ import annotations

import functools
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from core.agents import load_checkpoint
from core.finetune import CHECKPOINT_FILE, FinetuneConfig, Finetuner, VersionStore
from core.promotion import (
    Evaluation,
    LiveWatch,
    PromotionConfig,
    decide,
    evaluate_version,
    is_promoted,
    read_verdict,
    write_verdict,
)
from core.sessions import SessionStore
from core.worker import FinetuneService, WorkerSpec, judge
from tests.core.sage import envs
from tests.core.test_finetune import deployed, record  # noqa: F401  (the module fixture)

torch.set_num_threads(1)

CFG = PromotionConfig(episodes=4, max_steps=60)
EVALUATOR = functools.partial(evaluate_version, make_env=functools.partial(envs.make, "static"))


def evaluation(violations: int, takeover: float, episodes: int = 5) -> Evaluation:
    return Evaluation(episodes, violations, takeover, 1.0 - violations / episodes, 100, 0.1)


def test_decide_refuses_more_collisions_or_more_takeovers_and_promotes_a_candidate_no_worse() -> None:
    cfg = PromotionConfig()
    assert not decide(evaluation(1, 0.05), evaluation(0, 0.30), cfg).promoted
    refused = decide(evaluation(0, 0.31), evaluation(0, 0.30), cfg)
    assert not refused.promoted and "31%" in refused.reason
    assert decide(evaluation(0, 0.30), evaluation(0, 0.30), cfg).promoted
    assert decide(evaluation(0, 0.35), evaluation(0, 0.30), PromotionConfig(takeover_margin=0.1)).promoted


def broken_copy(versions: VersionStore, source: Path) -> int:
    """A version that lost its world model (so no gate asks for help) and drives straight at full speed."""
    payload = load_checkpoint(source)
    state = payload["state"]
    state.pop("world_model", None)
    state.pop("gate", None)
    actor = state["actor"]
    actor["mean.weight"] = torch.zeros_like(actor["mean.weight"])
    actor["mean.bias"] = torch.tensor([10.0, 0.0])  # tanh -> full speed along +x, into the obstacle
    payload["meta"]["has_world_model"] = False
    number = versions.latest().number + 1  # type: ignore[union-attr]
    folder = versions.root / f"v{number:04d}"
    folder.mkdir()
    torch.save({k: v for k, v in payload.items() if k != "file"}, folder / CHECKPOINT_FILE)
    (folder / "metrics.json").write_text('{"parent": 0}')
    return number


def test_a_broken_version_that_collides_more_is_never_promoted(deployed: Path, tmp_path: Path) -> None:  # noqa: F811
    versions = VersionStore(tmp_path / "versions")
    versions.ensure_initial(deployed)
    good = evaluate_version(versions.get(0).path, CFG, make_env=functools.partial(envs.make, "static"))
    assert good.episodes == 4 and 0.0 <= good.takeover_rate <= 1.0

    broken = broken_copy(versions, versions.get(0).path)
    verdict = judge(versions, broken, EVALUATOR, CFG)
    assert not verdict["promoted"], verdict
    assert verdict["evaluation"]["violation_episodes"] > verdict["incumbent"]["violation_episodes"]
    assert "collided" in verdict["reason"]
    assert not is_promoted(versions.get(broken).path, broken)
    assert read_verdict(versions.get(0).path)["evaluation"]["episodes"] == 4  # the incumbent's record is cached

    # the follower never offers it; a copy of the good policy is promoted and offered
    service = FinetuneService(WorkerSpec(versions.root, tmp_path, "session", promotion=CFG), in_control=0)
    service._scan_versions()
    assert service.take_pending() is None
    assert service.status()["versions"][broken]["promotion"]["promoted"] is False

    clone = versions.latest().number + 1  # type: ignore[union-attr]
    shutil.copytree(versions.get(0).path, versions.root / f"v{clone:04d}")
    (versions.root / f"v{clone:04d}" / "promotion.json").unlink()
    assert judge(versions, clone, EVALUATOR, CFG)["promoted"]
    service._scan_versions()
    pending = service.take_pending()
    assert pending is not None and pending[0] == clone


def test_a_promoted_version_that_does_worse_live_is_rolled_back() -> None:
    watch = LiveWatch(PromotionConfig(live_window=3))
    for _ in range(3):
        assert watch.record(0, collided=False, takeover_rate=0.2) is None
    watch.deployed(1, replaced=0)
    assert watch.record(1, collided=False, takeover_rate=0.2) is None
    assert watch.record(1, collided=True, takeover_rate=0.2) is None  # not judged before the window is full
    reason = watch.record(1, collided=False, takeover_rate=0.2)
    assert reason is not None and "v0001" in reason and "v0000" in reason
    assert watch.record(1, collided=True, takeover_rate=0.2) is None  # judged once

    calm = LiveWatch(PromotionConfig(live_window=2))
    calm.deployed(1, replaced=0, evaluation=evaluation(0, 0.30))
    assert calm.record(1, False, 0.35) is None and calm.record(1, False, 0.35) is None  # within the live margin
    worse = LiveWatch(PromotionConfig(live_window=2))
    worse.deployed(1, replaced=0, evaluation=evaluation(0, 0.10))
    worse.record(1, False, 0.5)
    assert "asked for help" in (worse.record(1, False, 0.5) or "")


def test_a_promoted_version_that_stands_still_live_is_rolled_back() -> None:
    """Never handed over, never colliding, never arriving: the collision and takeover tests pass it, the goal does
    not. Episodes a person ended (no outcome) decide nothing."""
    watch = LiveWatch(PromotionConfig(live_window=3))
    for _ in range(3):
        watch.record(0, collided=False, takeover_rate=0.2, reached=True)
    watch.deployed(1, replaced=0)
    for _ in range(2):
        assert watch.record(1, collided=False, takeover_rate=0.0, reached=False) is None
    reason = watch.record(1, collided=False, takeover_rate=0.0, reached=False)
    assert reason is not None and "reached the goal in none of its first 3" in reason and "100% (live)" in reason

    reset_by_hand = LiveWatch(PromotionConfig(live_window=2))
    reset_by_hand.deployed(1, replaced=0, evaluation=evaluation(0, 0.2))  # its evaluation reached the goal: 100%
    assert reset_by_hand.record(1, False, 0.0, reached=None) is None
    assert reset_by_hand.record(1, False, 0.0, reached=False) is None  # one outcome unknown: not judged on it
    slow_start = LiveWatch(PromotionConfig(live_window=2))
    slow_start.deployed(1, replaced=0, evaluation=evaluation(0, 0.2))
    slow_start.record(1, False, 0.0, reached=False)
    assert slow_start.record(1, False, 0.0, reached=True) is None  # it arrived once: not standing still
    stalled = LiveWatch(PromotionConfig(live_window=2))
    stalled.deployed(1, replaced=0, evaluation=evaluation(0, 0.2))
    stalled.record(1, False, 0.0, reached=False)
    assert "100% (evaluation)" in (stalled.record(1, False, 0.0, reached=False) or "")


def test_a_rollback_does_not_bounce_back_to_the_version_it_undid(deployed: Path, tmp_path: Path) -> None:  # noqa: F811
    """Measured live (experiments/live_session.py, seed 1): v0002 replaced v0000, collided more live and was rolled
    back; v0000, deployed again, was then judged against v0002's live record, "rolled back" in turn (its lower
    takeover rate) and v0002 drove on, with both versions marked rolled back."""
    versions = VersionStore(tmp_path / "versions")
    versions.ensure_initial(deployed)
    shutil.copytree(versions.get(0).path, versions.root / "v0001")
    write_verdict(versions.get(1).path, {"promoted": True, "reason": "passed"})
    service = FinetuneService(WorkerSpec(versions.root, tmp_path, "session", promotion=PromotionConfig(live_window=2)))
    for _ in range(2):
        assert service.record_episode(0, collided=False, takeover_rate=0.4) is None
    service.mark_deployed(1)
    assert service.record_episode(1, collided=True, takeover_rate=0.1) is None
    reason = service.record_episode(1, collided=True, takeover_rate=0.1)
    assert reason is not None and "collided" in reason
    pending = service.take_pending()
    assert pending is not None and pending[0] == 0
    service.mark_deployed(0)
    for _ in range(4):  # asks for more help than v0001 did live: it is where the rollback went, not judged again
        assert service.record_episode(0, collided=False, takeover_rate=0.6) is None
    assert service.take_pending() is None and service.status()["in_control"] == 0
    assert not (read_verdict(versions.get(0).path) or {}).get("rolled_back")
    assert read_verdict(versions.get(1).path)["rolled_back"]


def test_fine_tuning_waits_for_enough_takeover_samples(deployed: Path, tmp_path: Path) -> None:  # noqa: F811
    with pytest.raises(ValueError):
        FinetuneConfig(min_takeover_samples=-1)
    versions = VersionStore(tmp_path / "versions")
    versions.ensure_initial(deployed)
    store = SessionStore(tmp_path / "sessions")
    session = record(store, versions.get(0).path, episodes=3)
    takeovers = sum(r["takeovers"] for r in store.episodes(session))
    assert takeovers > 0
    short = Finetuner(
        versions, store, session, FinetuneConfig(updates=5, min_steps=1, min_takeover_samples=takeovers + 1)
    )
    assert not short.ready()
    result = short.round()
    assert result.version is None and "takeover samples" in (result.reason or "")
    enough = Finetuner(versions, store, session, FinetuneConfig(updates=5, min_steps=1, min_takeover_samples=takeovers))
    assert enough.ready()


def paired(takeovers: list[float], collided: int = 0) -> Evaluation:
    n = len(takeovers)
    return Evaluation(
        n, collided, sum(takeovers) / n, 1.0, 100 * n, 0.1, list(range(n)), takeovers, [i < collided for i in range(n)]
    )


def test_the_takeover_test_is_a_paired_sign_test_over_the_episodes() -> None:
    cfg = PromotionConfig()
    incumbent = paired([0.3, 0.3, 0.3, 0.3, 0.3])
    # less help on 3 seeds, more on 2: passes, although its overall rate is higher
    better_mostly = paired([0.2, 0.2, 0.2, 0.9, 0.9])
    assert better_mostly.takeover_rate > incumbent.takeover_rate and decide(better_mostly, incumbent, cfg).promoted
    worse_mostly = paired([0.1, 0.1, 0.4, 0.4, 0.4])
    refused = decide(worse_mostly, incumbent, cfg)
    assert not refused.promoted and "3 of 5 paired episodes" in refused.reason
    # differences inside the margin are ties
    assert decide(worse_mostly, incumbent, PromotionConfig(takeover_margin=0.2)).promoted
    assert not decide(paired([0.1] * 5, collided=1), incumbent, cfg).promoted  # collisions first


def test_a_version_that_stands_still_is_refused_though_it_asks_for_no_help_and_never_collides() -> None:
    """The stall the cycles study showed (arm K, docs/notes/forgetting_anatomy.md): supervised success 0, takeover
    near 0. Collisions and takeover alone would promote it; the progress test does not."""
    cfg = PromotionConfig()
    incumbent = paired([0.2] * 15)
    incumbent.episode_succeeded = [i != 3 for i in range(15)]  # reaches the goal in 14 of 15
    stalled = paired([0.0] * 15)
    stalled.episode_succeeded, stalled.success_rate = [False] * 15, 0.0
    refused = decide(stalled, incumbent, cfg)
    assert not refused.promoted and "reached the goal in 0/15" in refused.reason and "14/15" in refused.reason
    # the same record without per-episode outcomes (a verdict kept from before them) is judged as it was
    legacy = paired([0.0] * 15)
    assert decide(legacy, incumbent, cfg).promoted
    # a version that misses the goal on two seeds the incumbent finished is within the slack; on three it is not
    for missed, promoted in ((2, True), (3, False)):
        close = paired([0.1] * 15)
        close.episode_succeeded = [i >= missed and i != 3 for i in range(15)]
        decision = decide(close, incumbent, cfg)
        assert decision.promoted is promoted, decision.reason
        assert ("goal reached" in decision.reason) if promoted else ("finished 0 it missed" in decision.reason)
    assert decide(close, incumbent, PromotionConfig(success_slack=3)).promoted
    with pytest.raises(ValueError, match="success_slack"):
        PromotionConfig(success_slack=-1)


def test_evaluate_version_records_each_episodes_outcome_for_the_progress_test(deployed: Path) -> None:  # noqa: F811
    record = EVALUATOR(deployed, CFG)
    assert len(record.episode_succeeded) == CFG.episodes
    assert sum(record.episode_succeeded) == round(record.success_rate * CFG.episodes)


def test_the_promotion_rule_passes_a_better_version_in_most_rounds_and_a_worse_one_almost_never() -> None:
    from core.promotion import collision_pass_probability, success_pass_probability, takeover_pass_probability

    episodes = PromotionConfig().episodes
    # the numbers the module docstring states, from the rule itself (exact binomial)
    assert takeover_pass_probability(0.7, 0.3, episodes) == pytest.approx(0.95, abs=0.005)
    assert takeover_pass_probability(0.3, 0.7, episodes) == pytest.approx(0.05, abs=0.005)
    assert takeover_pass_probability(0.7, 0.3, 5) == pytest.approx(0.84, abs=0.005)
    assert takeover_pass_probability(0.3, 0.7, 5) == pytest.approx(0.16, abs=0.005)
    assert collision_pass_probability(0.3, 0.1, episodes) == pytest.approx(0.95, abs=0.005)
    assert collision_pass_probability(0.3, 0.5, episodes) == pytest.approx(0.17, abs=0.005)
    slack = PromotionConfig().success_slack
    assert success_pass_probability(0.9, 0.9, episodes, slack) == pytest.approx(0.94, abs=0.005)
    assert success_pass_probability(0.8, 0.8, episodes, slack) == pytest.approx(0.88, abs=0.005)
    assert success_pass_probability(0.9, 0.6, episodes, slack) == pytest.approx(0.18, abs=0.005)
    assert success_pass_probability(0.9, 0.0, episodes, slack) < 1e-9
    assert success_pass_probability(0.9, 0.9, episodes, 0) == pytest.approx(0.62, abs=0.01)
    # an equal version passes the sign test half the time (15 episodes: wins and losses cannot tie)
    assert takeover_pass_probability(0.5, 0.5, episodes) == pytest.approx(0.5)
    assert takeover_pass_probability(0.5, 0.5, 4) > 0.5  # an even count: a tie of wins and losses passes
    # the calculation against the rule: simulate rounds of decide() on random paired episodes
    rng = np.random.default_rng(0)
    incumbent = paired([0.5] * episodes)
    cfg = PromotionConfig()

    def passes(p_win: float) -> float:
        shares = lambda: [0.4 if rng.random() < p_win else 0.6 for _ in range(episodes)]  # noqa: E731
        return float(np.mean([decide(paired(shares()), incumbent, cfg).promoted for _ in range(2000)]))

    assert passes(0.7) == pytest.approx(takeover_pass_probability(0.7, 0.3, episodes), abs=0.02)
    assert passes(0.3) == pytest.approx(takeover_pass_probability(0.3, 0.7, episodes), abs=0.02)


def alone(successes: dict[str, int], episodes: int = 10, supervised: Evaluation | None = None) -> Evaluation:
    """An evaluation whose regression record succeeds alone in ``successes[scenario]`` of ``episodes`` episodes."""
    record = supervised or Evaluation(0, 0, 0.0, 0.0, 0, 0.1)
    record.regression = {s: [i < n for i in range(episodes)] for s, n in successes.items()}
    record.regression_seed = PromotionConfig().regression_seed
    return record


def test_the_regression_test_rejects_a_candidate_worse_alone_than_the_base_and_promotes_one_no_worse() -> None:
    cfg = PromotionConfig(supervised=False, regression_scenarios=("1", "2"))
    base = alone({"1": 10, "2": 9})
    worse = decide(alone({"1": 10, "2": 8}), None, cfg, base)
    assert not worse.promoted and "regression" in worse.reason and "scenario 2" in worse.reason
    assert "8/10" in worse.reason and "9/10" in worse.reason
    kept = decide(alone({"1": 10, "2": 9}), None, cfg, base)
    assert kept.promoted and "no worse alone" in kept.reason
    # with the supervised tests on, both must pass: a version no worse alone but colliding more is still refused
    both = PromotionConfig(regression_scenarios=("1", "2"))
    assert not decide(alone({"1": 10, "2": 9}, supervised=evaluation(2, 0.1)), evaluation(0, 0.1), both, base).promoted
    assert decide(alone({"1": 10, "2": 10}, supervised=evaluation(0, 0.1)), evaluation(0, 0.1), both, base).promoted
    assert not decide(alone({"1": 9, "2": 10}, supervised=evaluation(0, 0.0)), evaluation(0, 0.1), both, base).promoted
    with pytest.raises(ValueError, match="regression_scenarios"):
        PromotionConfig(supervised=False)  # no test at all


def test_judge_runs_the_regression_test_against_v0000_cached_and_rejects_a_forgetting_version(
    deployed: Path,  # noqa: F811
    tmp_path: Path,
) -> None:
    versions = VersionStore(tmp_path / "versions")
    versions.ensure_initial(deployed)
    forgetful, keeper = broken_copy(versions, versions.get(0).path), broken_copy(versions, versions.get(0).path)
    alone_successes = {0: 10, forgetful: 6, keeper: 10}
    calls: list[tuple[str, bool, tuple[str, ...]]] = []

    def fake(path: Path, cfg: PromotionConfig) -> Evaluation:
        calls.append((Path(path).name, cfg.supervised, cfg.regression_scenarios))
        number = int(Path(path).name[1:])
        return alone({s: alone_successes[number] for s in cfg.regression_scenarios}, cfg.regression_episodes)

    cfg = PromotionConfig(supervised=False, regression_scenarios=("1", "2"))
    rejected = judge(versions, forgetful, fake, cfg)
    assert not rejected["promoted"] and "regression" in rejected["reason"] and "6/10" in rejected["reason"]
    assert not is_promoted(versions.get(forgetful).path, forgetful)
    promoted = judge(versions, keeper, fake, cfg)
    assert promoted["promoted"], promoted
    assert [name for name, _, _ in calls] == ["v0000", f"v{forgetful:04d}", f"v{keeper:04d}"]  # v0000 once: cached
    assert read_verdict(versions.get(0).path)["regression"]["regression"]["1"] == [True] * 10


def test_judge_against_the_version_in_control_keeps_the_lines_alone_driving_from_stepping_back(
    deployed: Path,  # noqa: F811
    tmp_path: Path,
) -> None:
    """``regression_against="control"``: a candidate is compared alone with the latest promoted version, not v0000,
    so one that drives the session's scenario better than v0000 but worse than the line already does is refused."""
    versions = VersionStore(tmp_path / "versions")
    versions.ensure_initial(deployed)
    better, slipping, best = (broken_copy(versions, versions.get(0).path) for _ in range(3))
    alone_successes = {0: 1, better: 7, slipping: 5, best: 8}
    calls: list[str] = []

    def fake(path: Path, cfg: PromotionConfig) -> Evaluation:
        calls.append(Path(path).name)
        number = int(Path(path).name[1:])
        return alone({s: alone_successes[number] for s in cfg.regression_scenarios}, cfg.regression_episodes)

    cfg = PromotionConfig(supervised=False, regression_scenarios=("3",), regression_against="control")
    assert judge(versions, better, fake, cfg)["promoted"]  # 7/10 against v0000's 1/10
    refused = judge(versions, slipping, fake, cfg)
    # 5/10 is better than v0000 (the base test would pass it) but worse than the version in control
    assert not refused["promoted"] and refused["against"] == better
    assert "5/10" in refused["reason"] and f"the version in control (v{better:04d}) in 7/10" in refused["reason"]
    promoted = judge(versions, best, fake, cfg)
    assert promoted["promoted"] and promoted["against"] == better  # the refused one is not the reference
    # each version was driven alone once: the one in control's record is its own verdict's, not driven again
    assert calls == ["v0000", f"v{better:04d}", f"v{slipping:04d}", f"v{best:04d}"]
    with pytest.raises(ValueError, match="regression_against"):
        PromotionConfig(regression_scenarios=("3",), regression_against="best")  # type: ignore[arg-type]


def test_evaluate_version_drives_the_regression_scenarios_alone_on_fixed_seeds(deployed: Path) -> None:  # noqa: F811
    cfg = PromotionConfig(episodes=2, max_steps=40, supervised=False, regression_scenarios=("static",))
    scenario_env = functools.partial(envs.make)
    first = evaluate_version(deployed, cfg, make_env=functools.partial(envs.make, "static"), scenario_env=scenario_env)
    again = evaluate_version(deployed, cfg, make_env=functools.partial(envs.make, "static"), scenario_env=scenario_env)
    assert first.episodes == 0 and first.seeds == []  # the supervised tests are off
    assert len(first.regression["static"]) == cfg.regression_episodes
    assert first.regression == again.regression  # deterministic, the same seeds
    with pytest.raises(ValueError, match="scenario_env"):
        evaluate_version(deployed, cfg, make_env=functools.partial(envs.make, "static"))


def test_a_live_episodes_goal_counts_only_where_the_simulator_ended_it() -> None:
    from core.promotion import reached_goal
    from core.protocol import EpisodeSummary

    def ended(reason: str, success: object) -> EpisodeSummary:
        return EpisodeSummary(0, 10, 1.0, 0.0, 0, 0, 0.1, 0.1, {"success": success}, reason=reason)  # type: ignore[dict-item]

    assert reached_goal(ended("terminated", 1.0)) is True and reached_goal(ended("truncated", 0.0)) is False
    assert reached_goal(ended("terminated", float("nan"))) is False  # an unreadable metric is no arrival
    assert reached_goal(ended("new episode (operator)", 1.0)) is None
