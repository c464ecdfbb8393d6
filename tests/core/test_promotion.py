"""Safety-gated promotion: a fine-tuned version drives only if it is no worse than the one in control."""

from __future__ import annotations

import functools
import shutil
from pathlib import Path

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
