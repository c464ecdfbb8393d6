"""Fine-tuning on recorded sessions: versions, atomic publishing, NaN guards, learning from takeovers."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from core.agents import load_agent, load_checkpoint
from core.experts import ScriptedExpert
from core.finetune import (
    CHECKPOINT_FILE,
    FinetuneConfig,
    FinetuneError,
    Finetuner,
    VersionStore,
    guarded_update,
    ingest,
    ready_episodes,
)
from core.loop import Runner
from core.sessions import SessionStore
from core.train import RunConfig, train
from tests.core.sage import envs
from tests.core.test_export import EveryThird
from tests.core.test_train import small

torch.set_num_threads(1)


def point_env(scenario: str) -> Any:
    return envs.make(scenario)


@pytest.fixture(scope="module")
def deployed(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small SAGE policy for the point world (trained on the static obstacle only)."""
    out = tmp_path_factory.mktemp("runs") / "point-sage"
    run = RunConfig(sim="point", scenarios=["static"], episodes=4, seed=3, demo_episodes=4, checkpoint_every=0)
    train(run, small("sage"), point_env, out, progress=False)
    return out


def record(store: SessionStore, policy: str | Path, episodes: int, seed: int = 0, session_id: str | None = None) -> str:
    """Deploy ``policy`` with its gate and the scripted expert on the moving obstacle; record the session."""
    agent = load_agent(policy)
    env = point_env("dynamic")
    writer = store.create("point", scenario="dynamic", session_id=session_id)
    runner = Runner(env, agent.policy, agent.make_gate(), ScriptedExpert(), seed=seed, deterministic=True)
    writer.attach(runner)
    for _ in range(episodes):
        runner.run_episode()
    writer.close()
    return writer.session_id


@pytest.fixture
def setup(deployed: Path, tmp_path: Path) -> tuple[VersionStore, SessionStore, str]:
    versions = VersionStore(tmp_path / "versions")
    versions.ensure_initial(deployed)
    store = SessionStore(tmp_path / "sessions")
    session = record(store, versions.get(0).path, episodes=4)
    return versions, store, session


def fast(**overrides: Any) -> FinetuneConfig:
    values: dict[str, Any] = {
        "updates": 60,
        "min_steps": 16,
        "min_takeover_samples": 4,
        "wm_min_steps": 40,
        "report_every": 10,
        "updates_per_step": None,  # a fixed number of updates: the tests count them
        "holdout_share": 0.0,
        "round_keep": 1.0,  # the round's own weights: the tests read what a round learned (round_keep: its own test)
    }
    values.update(overrides)
    return FinetuneConfig(**values)


def test_v0_is_the_deployed_policy_and_rounds_publish_numbered_loadable_versions(setup, deployed: Path) -> None:
    versions, store, session = setup
    v0 = versions.get(0)
    assert (v0.path / CHECKPOINT_FILE).read_bytes() == (deployed / "checkpoint.pt").read_bytes()
    assert versions.ensure_initial(deployed).number == 0  # idempotent: never a second v0
    events: list[dict[str, Any]] = []
    finetuner = Finetuner(versions, store, session, fast())
    assert finetuner.ready()
    result = finetuner.round(progress=events.append)
    assert result.version is not None and result.version.number == 1 and result.updates == 60
    assert [v.number for v in versions.versions()] == [0, 1]
    metrics = json.loads((result.version.path / "metrics.json").read_text())
    assert metrics["parent"] == 0 and metrics["episodes"] == [0, 1, 2, 3] and metrics["updates"] == 60
    assert all(math.isfinite(v) for v in metrics["losses"].values()) and "bc_loss" in metrics["losses"]
    # the fear term ran against a budget measured at the round's refit of the world model, not the constant
    assert metrics["losses"]["fear_budget"] != finetuner.learner.cfg.fear_budget and "lam" in metrics["losses"]
    assert [e["update"] for e in events if e["phase"] == "training"] == [10, 20, 30, 40, 50, 60]
    # a plain tensor checkpoint: loads with weights_only=True and drives with its (refitted) gate
    raw = torch.load(result.version.path / CHECKPOINT_FILE, map_location="cpu", weights_only=True)
    assert raw["meta"]["extra"]["finetune"]["parent"] == 0
    assert float(raw["state"]["fear_budget"]) == pytest.approx(metrics["losses"]["fear_budget"])
    agent = load_agent(result.version.path)
    assert agent.has_world_model and agent.make_gate() is not None
    before = load_checkpoint(v0.path)["state"]["actor"]
    after = load_checkpoint(result.version.path)["state"]["actor"]
    assert any(not torch.equal(before[k], after[k]) for k in before)
    # nothing new recorded: not ready for another round
    assert not finetuner.ready()


def test_a_round_imitates_the_expert_where_it_took_over(setup) -> None:
    versions, store, session = setup
    takeovers = store.steps(session, takeover_only=True)
    assert len(takeovers["t"]) > 10, "the deployed policy should have been taken over on the moving obstacle"

    def imitation_error(path: Path) -> float:
        actor = load_agent(path).actor
        with torch.no_grad():
            action = actor.deterministic(torch.from_numpy(takeovers["obs"]))
        return float((action - torch.from_numpy(takeovers["a_expert"])).pow(2).sum(-1).mean())

    result = Finetuner(versions, store, session, fast(updates=150, refit_world_model=False)).round()
    assert result.version is not None
    assert imitation_error(result.version.path) < 0.8 * imitation_error(versions.get(0).path)


def test_an_update_with_a_nan_loss_is_undone(setup) -> None:
    versions, store, session = setup
    finetuner = Finetuner(versions, store, session, fast())
    learner = finetuner.learner
    ingest(learner, store, session, ready_episodes(store, session))
    original = learner.buffer.sample

    def poisoned(batch_size: int, rng: np.random.Generator) -> Any:
        batch = original(batch_size, rng)
        batch.reward[0] = math.nan
        return batch

    before = {k: v.clone() for k, v in learner.state_dict()["actor"].items()}
    critic_before = {k: v.clone() for k, v in learner.critic.state_dict().items()}
    lam, alpha = learner.lam, float(learner.log_alpha.detach())
    learner.buffer.sample = poisoned  # type: ignore[method-assign]
    stats, applied = guarded_update(learner)
    assert not applied and not math.isfinite(stats["critic_loss"])
    assert all(torch.equal(before[k], v) for k, v in learner.actor.state_dict().items())
    assert all(torch.equal(critic_before[k], v) for k, v in learner.critic.state_dict().items())
    assert learner.lam == lam and float(learner.log_alpha.detach()) == alpha
    learner.buffer.sample = original  # type: ignore[method-assign]
    stats, applied = guarded_update(learner)
    assert applied and math.isfinite(stats["critic_loss"])
    assert any(not torch.equal(before[k], v) for k, v in learner.actor.state_dict().items())


def test_a_round_full_of_nan_losses_never_replaces_the_last_good_version(setup) -> None:
    versions, store, session = setup
    good = Finetuner(versions, store, session, fast()).round().version
    assert good is not None and good.number == 1
    good_bytes = (good.path / CHECKPOINT_FILE).read_bytes()
    finetuner = Finetuner(versions, store, session, fast(refit_world_model=False))
    original = finetuner.learner.buffer.sample
    calls = {"n": 0}

    def poisoned(batch_size: int, rng: np.random.Generator) -> Any:
        calls["n"] += 1
        batch = original(batch_size, rng)
        if calls["n"] % 2:  # half the updates blow up: far above max_skipped_fraction
            batch.reward[:] = math.inf
        return batch

    finetuner.learner.buffer.sample = poisoned  # type: ignore[method-assign]
    result = finetuner.round()
    assert result.version is None and result.skipped >= 25 and "non-finite" in result.reason
    assert versions.latest() == versions.get(1) and (good.path / CHECKPOINT_FILE).read_bytes() == good_bytes


def test_a_few_nan_updates_are_skipped_and_the_round_still_publishes(setup) -> None:
    versions, store, session = setup
    finetuner = Finetuner(versions, store, session, fast(refit_world_model=False))
    original = finetuner.learner.buffer.sample
    calls = {"n": 0}

    def once(batch_size: int, rng: np.random.Generator) -> Any:
        calls["n"] += 1
        batch = original(batch_size, rng)
        if calls["n"] == 3:
            batch.obs[0, 0] = math.nan
        return batch

    finetuner.learner.buffer.sample = once  # type: ignore[method-assign]
    result = finetuner.round()
    assert result.version is not None and result.skipped == 1 and result.updates == 59
    state = load_checkpoint(result.version.path)["state"]
    assert all(bool(torch.isfinite(t).all()) for part in ("actor", "critic") for t in state[part].values())


def test_a_partially_written_version_never_becomes_one(setup, monkeypatch: pytest.MonkeyPatch) -> None:
    versions, store, session = setup
    finetuner = Finetuner(versions, store, session, fast(updates=5, refit_world_model=False))
    real_save = torch.save

    def crash_halfway(obj: Any, f: Any, *args: Any, **kwargs: Any) -> None:
        real_save(obj, f, *args, **kwargs)
        path = Path(f)
        path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])  # the disk filled up half way
        raise OSError("No space left on device")

    monkeypatch.setattr(torch, "save", crash_halfway)
    with pytest.raises(OSError, match="No space"):
        finetuner.round()
    monkeypatch.undo()
    assert [v.number for v in versions.versions()] == [0]
    assert not any(p.name.startswith(".tmp-") for p in versions.root.iterdir())
    # a writer killed mid-write (no chance to clean up) leaves a temporary folder: never listed, cleaned later
    leftover = versions.root / ".tmp-v0001-999-abcdef"
    leftover.mkdir()
    (leftover / CHECKPOINT_FILE).write_bytes(b"\x80\x02half a checkpoint")
    (leftover / "metrics.json").write_text("{}")
    assert [v.number for v in versions.versions()] == [0] and versions.latest().number == 0
    published = Finetuner(versions, store, session, fast(updates=5, refit_world_model=False)).round().version
    assert published is not None and published.number == 1 and not leftover.exists()
    load_agent(published.path)


def test_ingest_keeps_takeover_labels_and_drops_rows_that_are_not_finite(deployed: Path, tmp_path: Path) -> None:
    from core.loop import EpisodeSummary, StepRecord
    from core.sessions import SessionWriter

    store = SessionStore(tmp_path)
    writer: SessionWriter = store.create("point", session_id="glitch")
    obs = np.zeros(8, np.float32)

    def step(t: int, takeover: bool, bad: bool = False, done: bool = False) -> StepRecord:
        o = obs.copy()
        if bad:
            o[2] = math.nan  # a sensor glitch
        return StepRecord(  # the last step was a near miss the simulator reported (info["conflict"])
            0,
            t,
            o,
            np.zeros(2),
            np.ones(2) if takeover else None,
            np.zeros(2),
            takeover,
            takeover,
            "expert" if takeover else "agent",
            0.1,
            0.3,
            0.2,
            1.0,
            0.0,
            False,
            False,
            done,
            o,
            0.0,
            {"conflict": done},
        )

    for t, (takeover, bad) in enumerate([(False, False), (True, False), (True, True), (False, False)]):
        writer.on_step(step(t, takeover, bad, done=t == 3))
    writer.on_episode(EpisodeSummary(0, 4, 4.0, 0.0, 2, 1, 0.1, 0.2, {}))
    writer.close()
    assert ready_episodes(store, "glitch") == [0]
    finetuner_cfg = load_checkpoint(deployed)
    from core.learners import make_learner
    from core.sage.config import from_dict

    agent_cfg = from_dict(finetuner_cfg["agent_config"])
    learner = make_learner(agent_cfg.method, agent_cfg, 8, 2)
    got = ingest(learner, store, "glitch", [0])
    assert (got.steps, got.takeovers, got.dropped) == (3, 1, 1)
    assert learner.buffer.takeover_count() == 1 and np.allclose(learner.buffer.a_expert[1], 1.0)
    # the near miss of step 3 (the buffer's third row, after the glitch was dropped) reaches the world model's label
    assert learner.buffer.arrays()["conflict"].tolist() == [0.0, 0.0, 1.0]


def test_a_sessions_coached_steps_reach_the_round_as_labels_on_the_agents_own_transitions(
    deployed: Path, tmp_path: Path
) -> None:
    from core.experts import CoachingExpert
    from core.learners import make_learner
    from core.sage.config import from_dict

    store = SessionStore(tmp_path / "sessions")
    agent = load_agent(deployed)
    writer = store.create("point", scenario="static", session_id="coached")
    runner = Runner(
        point_env("static"), agent.policy, agent.make_gate(), CoachingExpert(ScriptedExpert(), 0.5, seed=1), seed=0
    )
    writer.attach(runner)
    summaries = [runner.run_episode() for _ in range(2)]
    writer.close()
    coached, takeovers = sum(s.coached for s in summaries), sum(s.takeovers for s in summaries)
    assert coached > 0 and takeovers > 0
    agent_cfg = from_dict(load_checkpoint(deployed)["agent_config"])
    learner = make_learner(agent_cfg.method, agent_cfg, agent.meta.obs_dim, agent.meta.act_dim)
    got = ingest(learner, store, "coached", [0, 1])
    assert (got.coached, got.takeovers) == (coached, takeovers)
    rows = np.flatnonzero(learner.buffer.coached[: learner.buffer.size])
    assert len(rows) == coached and learner.buffer.takeover_count() == coached + takeovers
    # a coached row ran the agent's own action; its label is the expert's, which differs from it
    np.testing.assert_allclose(learner.buffer.action[rows], learner.buffer.a_rl[rows])
    assert not np.allclose(learner.buffer.a_expert[rows], learner.buffer.a_rl[rows])


def test_bad_setups_are_refused_by_name(deployed: Path, tmp_path: Path) -> None:
    versions = VersionStore(tmp_path / "versions")
    store = SessionStore(tmp_path / "sessions")
    with pytest.raises(FinetuneError, match="no version"):
        Finetuner(versions, store, "s", fast())
    versions.ensure_initial(deployed)
    with pytest.raises(FinetuneError, match="v0007"):
        Finetuner(versions, store, "s", fast(), base=7)
    with pytest.raises(FinetuneError, match="overrides"):
        Finetuner(versions, store, "s", fast(overrides=("gamma=2",)))
    with pytest.raises(ValueError, match="max_skipped_fraction"):
        FinetuneConfig(max_skipped_fraction=2.0)
    with pytest.raises(ValueError, match="not a readable"):
        VersionStore(tmp_path / "other").ensure_initial(_broken(tmp_path))
    assert not Finetuner(versions, store, "not-recorded-yet", fast()).ready()


def _broken(tmp: Path) -> Path:
    path = tmp / "broken.pt"
    path.write_bytes(b"not a checkpoint")
    return path


def test_fine_tuning_says_what_it_runs(setup, caplog: pytest.LogCaptureFixture) -> None:
    """A SAGE checkpoint fine-tunes as fear-regularised SAGE; switching fear regularisation off is named aloud."""
    versions, store, session = setup
    sage = Finetuner(versions, store, session, fast())
    assert sage.method == "sage: fear-regularised SAGE (the paper's fine-tuning)"
    with caplog.at_level("WARNING", logger="core.finetune"):
        plain = Finetuner(versions, store, session, fast(overrides=("fear_regularisation=false",)))
    assert "NOT the paper's fear-regularised SAGE, without fear regularisation" in plain.method
    assert plain.method in caplog.text
    published = plain.round().version
    assert published is not None
    assert published.metrics["method"] == plain.method


def record_every_third(versions: VersionStore, store: SessionStore) -> str:
    """Two episodes of v0000 on the moving obstacle under a stand-in gate that hands over every third step (so there
    are takeover onsets, the agent driving between) with fear rising 0.1 a step against τ 0.5; the session's id."""
    agent = load_agent(versions.get(0).path)
    writer = store.create("point", scenario="dynamic")
    runner = Runner(point_env("dynamic"), agent.policy, EveryThird(), ScriptedExpert(), seed=0, deterministic=True)
    writer.attach(runner)
    for _ in range(2):
        runner.run_episode()
    writer.close()
    return writer.session_id


def test_a_rounds_intervention_cost_shapes_the_sessions_takeover_onsets(setup) -> None:
    """``--set learner.intervention_penalty=...`` reaches the round's learner (after SAGE's switches, which set it
    to 0): the agent's step before each recorded takeover onset loses the penalty (without it none does:
    tests/core/test_multi_hug.py)."""
    versions, store, _ = setup
    session = record_every_third(versions, store)
    steps = store.steps(session)
    onsets = sum(
        1
        for i in range(1, len(steps["t"]))
        if steps["takeover"][i] and not steps["takeover"][i - 1] and steps["episode"][i] == steps["episode"][i - 1]
    )
    tuner = Finetuner(versions, store, session, fast(overrides=("intervention_penalty=5",), updates=10))
    assert tuner.learner.cfg.intervention_penalty == 5 and onsets > 0
    tuner.round()
    assert tuner.learner.shaped == onsets


def test_a_rounds_refused_proposals_come_from_the_session_and_reach_the_critic(setup) -> None:
    """``--set learner.refused_weight=...`` reaches the round's learner; the rows it reads are exactly the session's
    takeover steps whose fear was over τ (the gate judged the agent's proposal there), not the hold's others."""
    versions, store, _ = setup
    session = record_every_third(versions, store)  # takeovers under τ (t = 3) and over it (t = 6, 9, ...)
    steps = store.steps(session)
    takeovers = np.asarray(steps["takeover"], bool)
    judged = takeovers & (np.asarray(steps["fear"]) > np.asarray(steps["threshold"]))
    assert 0 < judged.sum() < takeovers.sum()
    tuner = Finetuner(versions, store, session, fast(overrides=("refused_weight=1",), updates=10))
    assert tuner.learner.cfg.refused_weight == 1
    result = tuner.round()
    assert result.updates > 0 and tuner.learner.buffer.refused_count() == judged.sum()
    assert np.isfinite(result.losses["refused_loss"])  # the term was in the round's critic updates


# -- adaptation that sticks (issue 62) ---------------------------------------------------------------------------
def as_trained_by(method: str, source: Path, folder: Path) -> Path:
    """A copy of ``source`` whose configuration says it was trained as ``method`` (same weights: same learner)."""
    from core.sage.config import for_method, from_dict, to_dict

    payload = load_checkpoint(source)
    cfg = for_method(method, base=from_dict(payload["agent_config"]))
    cfg.world_model = True  # as the committed default policies: trained as SAC, a world model fitted for the gate
    payload["agent_config"] = to_dict(cfg)
    payload["meta"]["method"] = method
    folder.mkdir(parents=True)
    torch.save({k: v for k, v in payload.items() if k != "file"}, folder / CHECKPOINT_FILE)
    return folder


def test_a_sac_trained_policy_adapts_as_sage_with_its_fear_term_acting(deployed: Path, tmp_path: Path) -> None:
    sac = as_trained_by("sac", deployed / "checkpoint.pt", tmp_path / "sac-policy")
    versions = VersionStore(tmp_path / "versions")
    versions.ensure_initial(sac)
    store = SessionStore(tmp_path / "sessions")
    session = record(store, versions.get(0).path, episodes=4)
    finetuner = Finetuner(versions, store, session, fast())
    cfg = finetuner.learner.cfg
    assert cfg.method == "sage" and cfg.fear_regularisation and cfg.violation_penalty and cfg.virtual_rollouts
    assert cfg.imitation and finetuner.method.startswith("sage: fear-regularised SAGE")
    assert "trained as sac" in finetuner.method
    lam = finetuner.learner.lam
    result = finetuner.round()
    assert result.version is not None
    losses = result.version.metrics["losses"]
    assert "fear_real" in losses and abs(losses["lam_end"] - lam) > 1e-6  # the fear term ran and λ moved
    assert load_checkpoint(result.version.path)["agent_config"]["fear_regularisation"] is True
    # the old behaviour is one switch away, and says what it is
    plain = Finetuner(versions, store, session, fast(adapt_as_sage=False), base=0)
    assert plain.learner.cfg.method == "sac" and "NOT the paper's" in plain.method


def test_a_d3qn_base_adapts_as_sage_d3qn_and_a_method_without_a_counterpart_keeps_its_own() -> None:
    from core.finetune import adaptation_config
    from core.learners import preset

    d3qn = adaptation_config(preset("d3qn"))
    assert d3qn.method == "sage-d3qn" and d3qn.fear_regularisation and d3qn.imitation and d3qn.virtual_rollouts
    tuned = preset("sac", hidden=48)
    assert adaptation_config(tuned).hidden == 48  # hyperparameters are the base's
    assert adaptation_config(preset("td3")).method == "td3"


def test_after_a_rejected_version_the_next_round_starts_from_the_promoted_one(setup) -> None:
    from core.promotion import write_verdict

    versions, store, session = setup
    finetuner = Finetuner(versions, store, session, fast(refit_world_model=False))
    first = finetuner.round().version
    assert first is not None and finetuner.base.number == 1
    write_verdict(first.path, {"promoted": False, "reason": "asked for help more often"})
    promoted_actor = load_checkpoint(versions.get(0).path)["state"]["actor"]
    at_start: dict[str, bool] = {}

    def watch(event: dict[str, Any]) -> None:
        if event["phase"] == "ingesting":
            actor = finetuner.learner.actor.state_dict()
            at_start["promoted"] = all(torch.equal(actor[k], promoted_actor[k]) for k in actor)

    second = finetuner.round(progress=watch).version
    assert at_start == {"promoted": True}
    assert second is not None and second.parent == 0 and second.number == 2
    # a fresh fine-tuner (a restarted worker) never starts from the rejected version either
    assert Finetuner(versions, store, session, fast()).base.number == 2


def test_the_base_policys_own_drives_are_sampled_in_equal_shares_with_the_session(setup) -> None:
    import functools

    from core.finetune import SharedReplayBuffer, drive_alone

    buffer = SharedReplayBuffer(2, 1, 1000, prior_share=0.5)
    buffer.adding_prior = True
    for _ in range(10):
        buffer.add(np.ones(2), np.zeros(1), 0.0, np.ones(2), False)
    buffer.adding_prior = False
    for _ in range(300):
        buffer.add(np.zeros(2), np.zeros(1), 0.0, np.zeros(2), False)
    batch = buffer.sample(256, np.random.default_rng(0))
    assert int(batch.obs[:, 0].sum()) == 128  # 10 prior rows among 310 still fill half of every batch
    elsewhere = SharedReplayBuffer(2, 1, 10, prior_share=0.5, device="meta")  # a stand-in for the learner's CUDA
    elsewhere.add(np.ones(2), np.zeros(1), 0.0, np.ones(2), False)
    assert elsewhere.sample(4, np.random.default_rng(0)).obs.device.type == "meta"

    versions, store, session = setup
    prior = functools.partial(drive_alone, make_env=point_env, scenarios=["static"])
    finetuner = Finetuner(versions, store, session, fast(prior_episodes=2), prior=prior)
    assert finetuner.buffer.device == finetuner.learner.device  # batches go where the updates run
    result = finetuner.round()
    assert result.version is not None
    assert result.version.metrics["prior_steps"] == finetuner.buffer.prior_count() > 0
    assert result.version.metrics["steps"] == result.ingested.steps  # the session's steps, counted apart

    def broken(path: Path, episodes: int, seed: int) -> list[Any]:
        raise ValueError("no scenario 'gone.yaml'")

    alone = Finetuner(versions, store, session, fast(), prior=broken).round().version  # adapts on the session alone
    assert alone is not None and alone.metrics["prior_steps"] == 0 and "gone.yaml" in alone.metrics["prior_error"]


def test_updates_scale_with_the_data_and_stop_early_on_held_out_takeovers(setup) -> None:
    assert FinetuneConfig(updates_per_step=0.5, updates=1000).round_updates(300) == 150
    assert FinetuneConfig(updates_per_step=4.0, updates=1000).round_updates(300) == 1000  # the cap
    assert FinetuneConfig(updates_per_step=None, updates=70).round_updates(300) == 70
    with pytest.raises(ValueError, match="updates_per_step"):
        FinetuneConfig(updates_per_step=0.0)
    versions, store, session = setup
    scaled = Finetuner(versions, store, session, fast(updates_per_step=0.25, updates=10_000))
    result = scaled.round()
    assert result.updates + result.skipped == math.ceil(0.25 * result.ingested.steps)

    cfg = fast(updates=400, holdout_share=0.5, early_stop_every=10, early_stop_patience=2)
    finetuner = Finetuner(versions, store, session, cfg)
    result = finetuner.round()
    assert result.version is not None and len(finetuner.heldout_obs) > 0
    metrics = result.version.metrics
    assert metrics["heldout_takeover_samples"] == len(finetuner.heldout_obs)
    # the held-out rows are not imitated: fewer takeover samples than the session recorded
    assert metrics["takeover_samples"] + len(finetuner.heldout_obs) == result.ingested.takeovers
    # the published weights are those of the lowest held-out error measured
    with torch.no_grad():
        action = load_agent(result.version.path).actor.deterministic(torch.from_numpy(finetuner.heldout_obs))
    error = float((action - torch.from_numpy(finetuner.heldout_expert)).pow(2).sum(-1).mean())
    assert error == pytest.approx(metrics["losses"]["heldout_imitation_error"], rel=1e-4)
    assert metrics["kept_update"] <= metrics["updates_planned"]


def test_the_gates_tau_bounds_are_held_unless_a_refit_is_chosen(setup) -> None:
    versions, store, session = setup

    def bounds(path: Path) -> list[float]:
        return load_checkpoint(path)["state"]["world_model"]["tau_bounds"].tolist()

    held = Finetuner(versions, store, session, fast(tau_bounds="hold")).round().version
    assert held is not None and bounds(held.path) == bounds(versions.get(0).path)
    assert held.metrics["losses"]["tau_refitted"] == 0.0
    refit = Finetuner(versions, store, session, fast(tau_bounds="refit"), base=0).round().version
    assert refit is not None and refit.metrics["losses"]["tau_refitted"] == 1.0
    assert bounds(refit.path) != bounds(versions.get(0).path)
    with pytest.raises(ValueError, match="tau_bounds"):
        FinetuneConfig(tau_bounds="sometimes")  # type: ignore[arg-type]


def test_the_checkpoints_optimiser_states_are_carried_over(setup) -> None:
    versions, store, session = setup
    assert load_checkpoint(versions.get(0).path)["state"]["optimizers"]["actor_optimizer"]["state"]
    carried = Finetuner(versions, store, session, fast()).learner
    assert carried.actor_optimizer.state_dict()["state"]  # Adam's moments and step, not a fresh Adam
    fresh = Finetuner(versions, store, session, fast(carry_optimizer=False)).learner
    assert not fresh.actor_optimizer.state_dict()["state"]


def test_a_critic_warmup_holds_the_actor_for_its_first_updates_then_lets_it_move(setup) -> None:
    with pytest.raises(ValueError, match="critic_warmup"):
        FinetuneConfig(critic_warmup=-1)
    versions, store, session = setup
    finetuner = Finetuner(versions, store, session, fast(updates=60, critic_warmup=30, report_every=10))
    learner = finetuner.learner
    start_actor = {k: v.clone() for k, v in learner.actor.state_dict().items()}
    start_critic = {k: v.clone() for k, v in learner.critic.state_dict().items()}
    start_alpha, start_lam = float(learner.log_alpha.detach()), learner.lam
    seen: dict[int, tuple[bool, bool, bool]] = {}

    def watch(event: dict[str, Any]) -> None:
        if event.get("phase") == "training":
            actor_same = all(torch.equal(start_actor[k], v) for k, v in learner.actor.state_dict().items())
            critic_same = all(torch.equal(start_critic[k], v) for k, v in learner.critic.state_dict().items())
            held = float(learner.log_alpha.detach()) == start_alpha and learner.lam == start_lam
            seen[int(event["update"])] = (actor_same, critic_same, held)

    result = finetuner.round(progress=watch)
    assert result.version is not None and result.losses["critic_warmup_updates"] == 30
    for update in (10, 20, 30):  # the warm-up: the critics learn, the actor, α and λ do not move
        assert seen[update] == (True, False, True), update
    for update in (40, 50, 60):  # after it the actor moves
        assert not seen[update][0], update
    moved = load_agent(result.version.path).actor.state_dict()
    assert any(not torch.equal(start_actor[k], v) for k, v in moved.items())

    # early stopping measures only after the warm-up: the round cannot stop while the actor is held
    cfg = fast(updates=200, critic_warmup=120, holdout_share=0.5, early_stop_every=10, early_stop_patience=2)
    warmed = Finetuner(versions, store, session, cfg).round()
    assert warmed.version is not None and warmed.updates + warmed.skipped > 120
    assert warmed.version.metrics["kept_update"] >= 120


def test_a_prior_distillation_anchor_holds_the_rounds_to_the_base_policys_own_actions(setup) -> None:
    import functools

    from core.finetune import drive_alone

    with pytest.raises(ValueError, match="prior_distill"):
        FinetuneConfig(prior_distill=-1.0)
    assert FinetuneConfig().with_settings(["prior_distill=1.5"]).prior_distill == 1.5
    versions, store, session = setup
    prior = functools.partial(drive_alone, make_env=point_env, scenarios=["static"])
    anchored = Finetuner(versions, store, session, fast(prior_episodes=2, prior_distill=1.0), prior=prior)
    assert anchored.learner.prior_distill == 1.0
    anchored.collect_prior()
    # the base drove deterministic and alone: the prior rows' recorded actions are its deterministic actions there
    buffer = anchored.buffer
    rows = np.flatnonzero(buffer.prior[: buffer.size])
    base = load_agent(versions.get(0).path)
    with torch.no_grad():
        expected = base.actor.deterministic(torch.from_numpy(buffer.obs[rows]))
    torch.testing.assert_close(torch.from_numpy(buffer.a_rl[rows]), expected, rtol=1e-4, atol=1e-5)
    result = anchored.round()
    assert result.version is not None
    assert result.version.metrics["losses"]["prior_distill_loss"] >= 0.0
    assert result.version.metrics["config"]["prior_distill"] == 1.0

    plain = Finetuner(versions, store, session, fast(prior_episodes=2, prior_distill=0.0), prior=prior, base=0).round()
    assert plain.version is not None and "prior_distill_loss" not in plain.losses  # 0: the rounds as before


def test_round_keep_publishes_that_share_of_the_rounds_weight_change(setup) -> None:
    for bad in (0.0, -0.5, 1.5, float("nan")):
        with pytest.raises(ValueError, match="round_keep"):
            FinetuneConfig(round_keep=bad)
    assert FinetuneConfig().with_settings(["round_keep=0.5"]).round_keep == 0.5
    versions, store, session = setup
    finetuner = Finetuner(versions, store, session, fast(updates=40, round_keep=0.25))
    learner = finetuner.learner
    start = {n: {k: v.clone() for k, v in getattr(learner, n).state_dict().items()} for n in ("actor", "critic")}
    alpha_start = float(learner.log_alpha.detach())
    end: dict[str, dict[str, torch.Tensor]] = {}

    def watch(event: dict[str, Any]) -> None:
        if event.get("phase") == "training" and event["update"] == 40:  # the round's last update (no early stop)
            end.update({n: {k: v.clone() for k, v in getattr(learner, n).state_dict().items()} for n in start})

    result = finetuner.round(progress=watch)
    assert result.version is not None and result.losses["round_actor_change"] > 0
    assert float(learner.log_alpha.detach()) != alpha_start  # α is the round's, not averaged
    published = load_checkpoint(result.version.path)["state"]
    for name in ("actor", "critic"):
        moved = [k for k in start[name] if not torch.equal(start[name][k], end[name][k])]
        assert moved, f"the round should have moved the {name}"
        for key in moved:
            expected = start[name][key] + 0.25 * (end[name][key] - start[name][key])
            torch.testing.assert_close(published[name][key], expected, rtol=1e-5, atol=1e-6)
            assert not torch.allclose(published[name][key], end[name][key])
    # the learner continues from what was published (the next round starts from the version in control)
    for key, value in learner.actor.state_dict().items():
        torch.testing.assert_close(value, published["actor"][key])

    plain = Finetuner(versions, store, session, fast(updates=40), base=0).round()
    assert plain.version is not None and "round_actor_change" not in plain.losses  # 1.0: the rounds as before


def test_a_version_keeps_the_bases_gate_and_its_refit_measures_bounds_with_it(deployed: Path, tmp_path: Path) -> None:
    """A base deployed with its own gate settings (a refit-bounds folder: τ's scale, the fear's shape) publishes
    versions with the same gate, and a round's world-model refit measures τ's bounds on that gate's fear."""
    raw = torch.load(deployed / "checkpoint.pt", map_location="cpu", weights_only=True)
    own = {"tau_scale": 0.7, "beta": 0.8, "horizon": 3, "discount": 0.8, "hold_steps": 2}
    assert all(raw["agent_config"]["gate"][key] != value for key, value in own.items())  # not the defaults
    raw["agent_config"]["gate"].update(own)
    base = tmp_path / "base"
    base.mkdir()
    torch.save(raw, base / "checkpoint.pt")
    versions = VersionStore(tmp_path / "versions")
    versions.ensure_initial(base)
    store = SessionStore(tmp_path / "sessions")
    session = record(store, versions.get(0).path, episodes=4)
    finetuner = Finetuner(versions, store, session, fast(tau_bounds="refit", min_takeover_samples=0))
    assert finetuner.learner.model_trainer is not None
    measured_on = finetuner.learner.model_trainer.cfg.gate  # the gate the refit's calibration reads
    assert {key: getattr(measured_on, key) for key in own} == own
    result = finetuner.round()
    version = result.version
    assert version is not None, result.reason
    assert version.metrics["losses"]["tau_refitted"] == 1.0
    gate = load_checkpoint(version.path)["agent_config"]["gate"]
    assert {key: gate[key] for key in own} == own
    assert load_agent(version.path).make_gate().cfg.tau_scale == pytest.approx(0.7)


def test_anchor_relabel_holds_the_actor_to_the_base_on_the_versions_own_states_where_the_base_succeeded(setup) -> None:
    import dataclasses
    import functools

    from core.finetune import drive_alone, split_episodes

    assert FinetuneConfig().with_settings(["anchor_relabel=true"]).anchor_relabel is True
    versions, store, session = setup
    driven = functools.partial(drive_alone, make_env=point_env, scenarios=["static"])

    def prior(path: Path, episodes: int, seed: int) -> list:
        """The drives with the first situation marked solved and the others failed (the test decides which)."""
        steps = split_episodes(driven(path, episodes, seed))
        marked = [
            [*ep[:-1], dataclasses.replace(ep[-1], info={**ep[-1].info, "success": k == 0})]
            for k, ep in enumerate(steps)
        ]
        return [r for ep in marked for r in ep]

    off = Finetuner(
        versions, store, session, fast(prior_episodes=2, prior_distill=1.0, anchor_relabel=False), prior=prior
    )
    assert off.round().version is not None and off.learner.anchor_rows is None  # off: the prior rows, as before

    finetuner = Finetuner(
        versions, store, session, fast(prior_episodes=2, prior_distill=1.0, anchor_relabel=True), prior=prior, base=0
    )
    result = finetuner.round()
    assert result.version is not None and finetuner.prior_success == [True, False]
    solved = split_episodes(driven(versions.get(0).path, 2, finetuner.cfg.seed + 5_000_000))[0]
    rows = finetuner.learner.anchor_rows
    # the first round starts from v0000: the anchor holds the base's own rows of the solved situation only
    assert rows is not None and len(rows) == len(solved) == result.version.metrics["anchor_rows"]
    np.testing.assert_allclose(rows.obs[: len(rows)], np.stack([r.obs for r in solved]))
    batch = finetuner.learner.anchor_batch()
    assert batch is not None and np.isin(batch.obs[:, 0].numpy(), rows.obs[: len(rows), 0]).all()

    # after the round the version in control is v0001: its drive of the solved situation is labelled by the base
    added = finetuner.relabel()
    version_steps = split_episodes(driven(result.version.path, 2, finetuner.cfg.seed + 5_000_000))[0]
    assert added == len(version_steps) and len(rows) == len(solved) + added
    new_obs = torch.from_numpy(rows.obs[len(solved) : len(rows)])
    base = load_agent(versions.get(0).path)
    version = load_agent(result.version.path)
    with torch.no_grad():
        base_action = base.actor.deterministic(new_obs)
        version_action = version.actor.deterministic(new_obs)
    labels = torch.from_numpy(rows.a_rl[len(solved) : len(rows)])
    torch.testing.assert_close(labels, base_action, rtol=1e-4, atol=1e-5)
    assert float((version_action - base_action).abs().max()) > 1e-3  # the round moved the actor: labels are not its own


def test_anchor_drives_learn_stores_the_versions_drives_of_the_prior_situations_as_prior_rows(setup) -> None:
    """``anchor_drives_learn``: the version's anchor drives (every situation, failures included) join the buffer's
    prior part as its own steps, no takeover; off, the same relabelling leaves the buffer as it was."""
    import functools

    from core.finetune import drive_alone, split_episodes

    versions, store, session = setup
    driven = functools.partial(drive_alone, make_env=point_env, scenarios=["static"])
    finetuners = {}
    for learn in (False, True):
        cfg = fast(prior_episodes=2, prior_distill=1.0, anchor_relabel=True, anchor_drives_learn=learn)
        finetuner = Finetuner(versions, store, session, cfg, prior=driven, base=0)
        first = finetuner.round()
        assert first.version is not None
        assert first.version.metrics["anchor_drive_steps"] == 0  # the first round's drives are the base's own
        prior_rows, rows, takeovers = (
            finetuner.buffer.prior_count(),
            len(finetuner.buffer),
            finetuner.buffer.takeover_count(),
        )
        finetuner.relabel()
        finetuners[learn] = (finetuner, prior_rows, rows, takeovers, first.version)
    off, prior_rows, rows, takeovers, _ = finetuners[False]
    assert (off.buffer.prior_count(), len(off.buffer), off.anchor_drive_steps) == (prior_rows, rows, 0)
    on, prior_rows, rows, takeovers, version = finetuners[True]
    expected = driven(version.path, 2, on.cfg.seed + 5_000_000)
    assert len(split_episodes(expected)) == 2 and on.anchor_drive_steps == len(expected)
    assert on.buffer.prior_count() == prior_rows + len(expected) and len(on.buffer) == rows + len(expected)
    assert on.buffer.takeover_count() == takeovers  # the version's drives carry no expert label
    stored = on.buffer.obs[rows : rows + len(expected)]
    np.testing.assert_allclose(stored, np.stack([r.obs for r in expected]), rtol=1e-6, atol=1e-6)
    assert on.buffer.prior[rows : rows + len(expected)].all()


def test_practice_drives_join_the_round_as_the_versions_own_steps_new_each_round(setup) -> None:
    """``practice_episodes``: before a round that trains, the version in control drives the session's scenario alone;
    its steps (violations included) enter the buffer as the agent's own, not as takeovers or prior rows, on new seeds
    each round, and the round reports them apart from the deployment steps."""
    import functools

    from core.finetune import drive_alone

    versions, store, session = setup
    seeds: list[int] = []
    driven = functools.partial(drive_alone, make_env=point_env, scenarios=["dynamic"])

    def practice(path: Path, episodes: int, seed: int) -> list:
        seeds.append(seed)
        return driven(path, episodes, seed)

    plain = Finetuner(versions, store, session, fast(), practice=practice)  # 0 episodes: nothing driven
    assert plain.round().version is not None and seeds == [] and plain.practice_steps == 0

    finetuner = Finetuner(versions, store, session, fast(practice_episodes=2), practice=practice, base=0)
    before = len(finetuner.buffer)
    takeovers = finetuner.buffer.takeover_count()
    result = finetuner.round()
    assert result.version is not None, result.reason
    steps = int(result.version.metrics["losses"]["practice_steps"])
    assert steps == finetuner.practice_steps > 0 and len(seeds) == 1
    expected = driven(result.version.path.parent / "v0000", 2, seeds[0])  # the same drives: deterministic
    assert steps == len(expected)
    assert "practice_violations" in result.version.metrics["losses"]
    assert result.ingested.steps + steps == len(finetuner.buffer) - before  # deployment and practice rows, apart
    assert finetuner.buffer.takeover_count() == takeovers + result.ingested.takeovers  # practice adds no takeover
    assert finetuner.buffer.prior_count() == 0  # nor prior rows

    assert finetuner.round().version is not None and len(seeds) == 2 and seeds[1] != seeds[0]  # new situations


def test_a_practice_source_that_fails_leaves_the_round_to_its_data(setup) -> None:
    versions, store, session = setup

    def broken(path: Path, episodes: int, seed: int) -> list:
        raise RuntimeError("the scenario no longer builds")

    result = Finetuner(versions, store, session, fast(practice_episodes=2), practice=broken).round()
    assert result.version is not None and "practice_steps" not in result.version.metrics["losses"]


def test_layer_normed_critics_on_a_base_without_them_are_fitted_to_the_bases_before_the_round(setup) -> None:
    """RLPD's critic (``critic_layer_norm``) on a base trained without it: the linear weights load, the norms are
    new, and the round's first act on the critics fits them to the base's saved critics (not a random function), then
    the versions hold the norms and load as they were saved."""
    versions, store, session = setup
    base = load_checkpoint(versions.get(0).path)["state"]["critic"]
    assert not any(key.startswith("norms.") for key in base)
    finetuner = Finetuner(versions, store, session, fast(overrides=("critic_layer_norm=true",)))
    learner = finetuner.learner
    assert learner.critic.layer_norm and learner.critic_teacher is not None
    teacher = learner.critic_teacher
    # the saved linear weights start the new critics; their optimiser starts fresh (its groups do not fit)
    assert torch.equal(learner.critic.hidden[0].weight.detach(), base["hidden.0.weight"].float())
    assert not learner.critic_optimizer.state_dict()["state"]
    rows = store.steps(session)
    obs = torch.from_numpy(rows["obs"][:200])
    action = torch.from_numpy(rows["action"][:200])
    with torch.no_grad():
        target = teacher(obs, action)
        before = float((learner.critic(obs, action) - target).pow(2).mean())
    events: list[dict[str, Any]] = []
    result = finetuner.round(progress=events.append)
    assert result.version is not None
    assert any(e["phase"] == "fitting the layer-normed critics to the base's" for e in events)
    assert learner.critic_teacher is None  # fitted once, then dropped
    distilled = result.losses["critic_distil_loss"]
    scale = float(target.pow(2).mean())
    assert distilled < 0.05 * scale and distilled < 0.1 * before, (distilled, before, scale)
    saved = load_checkpoint(result.version.path)
    assert saved["agent_config"]["critic_layer_norm"] is True
    assert any(key.startswith("norms.") for key in saved["state"]["critic"])
    again = Finetuner(versions, store, session, fast(overrides=("critic_layer_norm=true",)), base=1).learner
    assert again.critic_teacher is None  # a version with the norms loads as saved: nothing to fit
    # a critic with norms never loads a checkpoint without them by accident: strict loading refuses it
    with pytest.raises(RuntimeError):
        again.critic.load_state_dict(base)


def test_a_larger_critic_ensemble_on_a_two_critic_base_learns_the_bases_critics_member_by_member(setup) -> None:
    """RLPD's ensemble (``critics=10``, ``critic_target_subset=2``) on a base of two critics: the new members cannot
    take the saved weights, so each is fitted to saved member z mod 2 before the round's updates."""
    versions, store, session = setup
    overrides = ("critics=10", "critic_target_subset=2")
    finetuner = Finetuner(versions, store, session, fast(overrides=overrides))
    learner = finetuner.learner
    teacher = learner.critic_teacher
    assert learner.critic.members == 10 and teacher is not None and teacher.members == 2
    # Adam's saved moments are of two members' shapes: the critics' optimiser starts fresh, the actor's is carried
    assert not learner.critic_optimizer.state_dict()["state"] and learner.actor_optimizer.state_dict()["state"]
    rows = store.steps(session)
    obs, action = torch.from_numpy(rows["obs"][:200]), torch.from_numpy(rows["action"][:200])
    with torch.no_grad():
        target = teacher(obs, action)[torch.arange(10) % 2]
        before = float((learner.critic(obs, action) - target).pow(2).mean())
    result = finetuner.round()
    assert result.version is not None and learner.critic_teacher is None
    distilled = result.losses["critic_distil_loss"]
    assert distilled < 0.1 * before, (distilled, before)
    saved = load_checkpoint(result.version.path)
    assert saved["agent_config"]["critics"] == 10 and saved["state"]["critic"]["out.weight"].shape[0] == 10


def test_an_ibrl_round_clones_the_takeovers_into_its_imitation_actor_and_publishes_the_composite(setup) -> None:
    """IBRL (``learner.ibrl``) on a base without it: π_IL starts as the base's actor, the round clones the takeovers
    into it before its updates (held-out takeovers choose the weights kept), and the published version carries π_IL
    and acts with the actor proposal when loaded."""
    versions, store, session = setup
    finetuner = Finetuner(
        versions, store, session, fast(holdout_share=0.5, overrides=("ibrl=true", "ibrl_updates=200"))
    )
    learner = finetuner.learner
    base_actor = load_checkpoint(versions.get(0).path)["state"]["actor"]
    assert all(torch.equal(v, base_actor[k].float()) for k, v in learner.il_actor.state_dict().items())
    events: list[dict[str, Any]] = []
    result = finetuner.round(progress=events.append)
    assert result.version is not None
    assert any(e["phase"] == "cloning the expert for IBRL's imitation policy" for e in events)
    assert result.losses["il_updates"] == 200 and len(finetuner.heldout_obs) > 0
    heldout = torch.from_numpy(finetuner.heldout_obs)
    expert = torch.from_numpy(finetuner.heldout_expert)
    with torch.no_grad():
        il_error = float((learner.il_actor.deterministic(heldout) - expert).pow(2).sum(-1).mean())
    assert result.losses["il_heldout_error"] == pytest.approx(il_error, rel=1e-4)
    saved = load_checkpoint(result.version.path)
    assert saved["agent_config"]["ibrl"] is True and "il_actor" in saved["state"]
    agent = load_agent(result.version.path)
    obs = heldout[0].numpy()
    assert agent.policy.act(obs, True) == pytest.approx(learner.policy_action(obs, True), abs=1e-5)
