"""Bagging world models over refits: the merged ensemble keeps every member's function, is calibrated on the
runs' own states, and refuses what cannot be merged."""

from __future__ import annotations

import copy
import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from core.agents import load_agent, load_checkpoint
from core.merge import MERGE_FILE, merge_runs
from core.motion import approach_rate
from core.sage.calibration import CALIBRATION_FILE, CalibrationSample, calibrate
from core.sage.config import WorldModelConfig
from core.sage.fear import rollout
from core.sage.world_model import EnsembleWorldModel, merge_ensembles, with_approach_input
from core.train import RunConfig, train
from tests.core.sage.test_world_model import ACT, OBS, known_system
from tests.core.test_train import point_env, small

torch.set_num_threads(1)


def fitted(seed: int, scale: float, members: int = 3) -> EnsembleWorldModel:
    """A model fitted on the known system, its states scaled (so each model has normalisers of its own)."""
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    s, a, nxt, cost = known_system(400, rng)
    model = EnsembleWorldModel(OBS, ACT, WorldModelConfig(members=members, hidden=16, max_updates_per_fit=200))
    model.fit(s * scale + seed, a, nxt * scale + seed, cost, rng)
    return model


def test_a_merged_ensemble_keeps_every_members_function() -> None:
    """Each member of the merged ensemble predicts what it predicted in its own model, though the models had
    different normalisers; so the merged ĉ along a rollout is the members-weighted mean of the models' ĉ."""
    first, second = fitted(0, 1.0, members=3), fitted(1, 2.5, members=2)
    assert not torch.allclose(first.in_mean, second.in_mean)
    merged = merge_ensembles([first, second])
    assert merged.members == 5 and merged.cfg.members == 5
    probe_s, probe_a, _, _ = known_system(64, np.random.default_rng(9))
    obs, act = torch.as_tensor(probe_s), torch.as_tensor(probe_a)
    with torch.no_grad():
        both = merged.predict(obs, act)[0]
        torch.testing.assert_close(both[:3], first.predict(obs, act)[0], atol=1e-4, rtol=1e-4)
        torch.testing.assert_close(both[3:], second.predict(obs, act)[0], atol=1e-4, rtol=1e-4)

        def policy(states: torch.Tensor) -> torch.Tensor:
            return torch.tanh(states[:, :ACT])

        costs = [rollout(m.folded(), policy, obs, policy(obs), 4).cost for m in (first, second, merged)]
    weighted = (3 * costs[0].mean(1) + 2 * costs[1].mean(1)) / 5
    torch.testing.assert_close(costs[2].mean(1), weighted, atol=1e-4, rtol=1e-4)
    # κ and τ belong to the new ensemble: left unset until it is calibrated
    assert bool(torch.isnan(merged.tau_bounds).all())
    assert float(merged.curiosity_ref) == pytest.approx(float((first.curiosity_ref + second.curiosity_ref) / 2))
    # the inputs are untouched
    torch.testing.assert_close(first.predict(obs, act)[0], both[:3], atol=1e-4, rtol=1e-4)


def moving(seed: int, scale: float, approach: tuple[int, int] | None) -> EnsembleWorldModel:
    """A model with the motion input (and the approach rates of ``approach``, None: without), fitted on the known
    system with its last change of state as the motion; its first channels read as ranges in (0, 1]."""
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    s, a, nxt, cost = known_system(400, rng, low=0.05, high=1.0)
    layout = {} if approach is None else {"approach_start": approach[0], "approach_stop": approach[1]}
    cfg = WorldModelConfig(members=2, hidden=16, max_updates_per_fit=200, motion_input=True, **layout)
    model = EnsembleWorldModel(OBS, ACT, cfg)
    motion = np.concatenate([np.zeros((1, OBS), np.float32), np.diff(s, axis=0)]).astype(np.float32)
    model.fit(s * scale, a, nxt * scale, cost, rng, motion=motion * scale)
    return model


def test_a_model_widened_to_the_approach_input_computes_what_it_computed() -> None:
    narrow = moving(0, 1.0, None)
    wide = with_approach_input(narrow, (0, 3))
    assert wide.approach == (0, 3) and wide.cfg.approach_stop == 3 and narrow.approach is None
    rng = np.random.default_rng(4)
    s, a, _, _ = known_system(64, rng, low=0.05, high=1.0)
    obs, act = torch.as_tensor(s), torch.as_tensor(a)
    motion = torch.as_tensor(rng.uniform(-0.2, 0.2, s.shape).astype(np.float32))  # some channels closing
    assert bool((approach_rate(obs, motion, 0, 3) > 0).any())
    with torch.no_grad():
        for got, expected in zip(wide.predict(obs, act, motion), narrow.predict(obs, act, motion), strict=True):
            torch.testing.assert_close(got, expected, atol=1e-6, rtol=1e-6)
    with pytest.raises(ValueError, match="already reads"):
        with_approach_input(wide, (0, 3))
    with pytest.raises(ValueError, match="motion input"):
        with_approach_input(EnsembleWorldModel(OBS, ACT, WorldModelConfig(motion_input=False)), (0, 3))


def test_models_with_and_without_the_approach_input_merge_into_one_that_reads_it() -> None:
    narrow, wide = moving(0, 1.0, None), moving(1, 2.0, (0, 3))
    merged = merge_ensembles([narrow, wide])
    assert merged.approach == (0, 3) and merged.members == 4
    rng = np.random.default_rng(5)
    s, a, _, _ = known_system(64, rng, low=0.05, high=1.0)
    obs, act = torch.as_tensor(s), torch.as_tensor(a)
    motion = torch.as_tensor(rng.uniform(-0.2, 0.2, s.shape).astype(np.float32))
    with torch.no_grad():
        both = merged.predict(obs, act, motion)[0]
        torch.testing.assert_close(both[:2], narrow.predict(obs, act, motion)[0], atol=1e-4, rtol=1e-4)
        torch.testing.assert_close(both[2:], wide.predict(obs, act, motion)[0], atol=1e-4, rtol=1e-4)
    with pytest.raises(ValueError, match="different channels"):
        merge_ensembles([wide, moving(2, 1.0, (1, 3))])


def test_merging_refuses_models_that_do_not_fit_together() -> None:
    first = fitted(0, 1.0)
    with pytest.raises(ValueError, match="at least two"):
        merge_ensembles([first])
    other = EnsembleWorldModel(OBS, ACT, dataclasses.replace(first.cfg, hidden=8))
    with pytest.raises(ValueError, match="hidden"):
        merge_ensembles([first, other])
    with pytest.raises(ValueError, match="never fitted"):
        merge_ensembles([first, EnsembleWorldModel(OBS, ACT, first.cfg)])
    with pytest.raises(ValueError, match="predicts"):
        merge_ensembles([first, EnsembleWorldModel(OBS + 1, ACT, first.cfg)])


@pytest.fixture(scope="module")
def refits(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[Path]]:
    """A small SAGE policy on the point env, then two world-model-only refits of it with different seeds."""
    root = tmp_path_factory.mktemp("merge")
    policy = root / "policy"
    first = RunConfig(sim="point", scenarios=["static", "dynamic"], episodes=4, seed=3, demo_episodes=3,
                      checkpoint_every=0)  # fmt: skip
    train(first, small("sage"), point_env, policy, progress=False)
    runs = []
    for seed in (5, 6):
        out = root / f"refit-{seed}"
        run = RunConfig(sim="point", scenarios=["dynamic"], episodes=3, seed=seed, init=str(policy), checkpoint_every=0,
                        world_model_only=True)  # fmt: skip
        train(run, small("sage"), point_env, out, progress=False)
        runs.append(out)
    return policy, runs


def test_a_run_folder_keeps_the_states_its_last_fit_calibrated_on(refits) -> None:
    _, runs = refits
    agent = load_agent(runs[0])
    sample = CalibrationSample.load(runs[0] / CALIBRATION_FILE)
    assert 0 < len(sample) <= agent.config.gate.calibration_states and sample.familiar.dtype == bool
    assert sample.obs.shape[1] == agent.meta.obs_dim and sample.motion is not None
    assert bool(sample.familiar.any())
    # they are the states the stored bounds came from: calibrating the stored model on them gives its bounds back
    model = agent.world_model
    stored = model.tau_bounds.clone()
    calibrate(model, agent.learner.rollout_policy, torch.from_numpy(sample.obs), agent.config.gate.horizon,
              cfg=agent.config.gate, safe=torch.from_numpy(sample.familiar),
              motion=torch.from_numpy(sample.motion))  # fmt: skip
    torch.testing.assert_close(model.tau_bounds, stored, atol=2e-3, rtol=0)  # float16 weights, float32 states


def test_merged_refits_make_one_policy_with_all_their_members(refits, tmp_path: Path) -> None:
    policy, runs = refits
    out = tmp_path / "merged"
    result = merge_runs(runs, out)
    agents = [load_agent(run) for run in runs]
    merged = load_agent(out)
    members = sum(a.world_model.members for a in agents)
    assert result.members == merged.world_model.members == merged.config.world_model_config.members == members
    for name, value in agents[0].learner.actor.state_dict().items():
        assert torch.equal(value, merged.learner.actor.state_dict()[name]), name
    # calibrated on the union of the runs' samples: the same bounds as calibrating it there ourselves
    union = CalibrationSample.concat([CalibrationSample.load(r / CALIBRATION_FILE) for r in runs])
    assert result.calibration_states == len(union) == len(CalibrationSample.load(out / CALIBRATION_FILE))
    model = merged.world_model
    bounds = model.tau_bounds.clone()
    assert bool(torch.isfinite(bounds).all()) and bounds[1] > bounds[0]
    calibrate(model, merged.learner.rollout_policy, torch.from_numpy(union.obs), merged.config.gate.horizon,
              cfg=merged.config.gate, safe=torch.from_numpy(union.familiar),
              motion=torch.from_numpy(union.motion))  # fmt: skip
    torch.testing.assert_close(model.tau_bounds, bounds, atol=2e-3, rtol=0)
    assert merged.make_gate() is not None
    record = json.loads((out / MERGE_FILE).read_text())
    assert record["runs"] == [str(r) for r in runs] and record["members"] == members
    config = json.loads((out / "config.json").read_text())
    assert config["agent"]["world_model_config"]["members"] == members and config["merged_from"] == record["runs"]
    # a merged folder is a run like any other: refitted with its own config (as `sage train --init` takes it), it
    # warm-starts with all its members
    refit = tmp_path / "refit"
    result_refit = train(RunConfig(sim="point", scenarios=["dynamic"], episodes=1, seed=9, init=str(out),
                                   checkpoint_every=0, world_model_only=True),
                         merged.config, point_env, refit, progress=False)  # fmt: skip
    assert "world_model" in result_refit.learner.load_state_dict(load_checkpoint(out)["state"], strict=False)
    assert load_agent(refit).world_model.members == members
    with pytest.raises(ValueError, match="already holds"):
        merge_runs(runs, out)
    # float16, as for committed policies: every tensor of the file halved, the same model to float16's precision
    half = merge_runs(runs, tmp_path / "half", dtype="float16").out
    stored = torch.load(half / "checkpoint.pt", map_location="cpu", weights_only=True)["state"]
    assert {t.dtype for part in ("actor", "world_model") for t in stored[part].values() if t.is_floating_point()} == {
        torch.float16
    }
    reference = load_agent(out).world_model.state_dict()
    for name, value in load_agent(half).world_model.state_dict().items():
        if value.is_floating_point():
            torch.testing.assert_close(value, reference[name].half().float(), atol=0, rtol=0)
    del policy


def _copy_run(src: Path, dst: Path, edit: Any = None) -> Path:
    dst.mkdir(parents=True)
    for name in ("config.json", CALIBRATION_FILE):
        (dst / name).write_bytes((src / name).read_bytes())
    payload = load_checkpoint(src)
    payload.pop("file")
    if edit is not None:
        edit(payload)
    torch.save(payload, dst / "checkpoint.pt")
    return dst


def test_merge_refuses_runs_it_cannot_merge(refits, tmp_path: Path) -> None:
    policy, runs = refits
    with pytest.raises(ValueError, match="at least two"):
        merge_runs(runs[:1], tmp_path / "one")
    with pytest.raises(ValueError, match="given twice"):
        merge_runs([runs[0], runs[0]], tmp_path / "twice")

    def other_policy(payload: dict[str, Any]) -> None:
        payload["state"]["actor"] = copy.deepcopy(payload["state"]["actor"])
        next(iter(payload["state"]["actor"].values())).add_(0.01)

    moved = _copy_run(runs[1], tmp_path / "moved", other_policy)
    with pytest.raises(ValueError, match="policy"):
        merge_runs([runs[0], moved], tmp_path / "x")
    bare = _copy_run(runs[1], tmp_path / "bare")
    (bare / CALIBRATION_FILE).unlink()
    bare_too = _copy_run(runs[0], tmp_path / "bare-too")
    (bare_too / CALIBRATION_FILE).unlink()
    with pytest.raises(ValueError, match=r"none of the runs has a calibration\.npz"):
        merge_runs([bare_too, bare], tmp_path / "y")
    broken = _copy_run(runs[1], tmp_path / "broken")
    (broken / CALIBRATION_FILE).write_bytes(b"not an npz")
    with pytest.raises(ValueError, match="not a readable calibration sample"):
        merge_runs([runs[0], broken], tmp_path / "z")
    assert not any((tmp_path / name).exists() for name in ("x", "y", "z", "w"))  # nothing half-written

    # a gate setting that acts is refused by name; contact floors no gate reads (no imagined contact) are not
    def other_beta(payload: dict[str, Any]) -> None:
        payload["agent_config"]["gate"]["beta"] = 0.25

    def floors(payload: dict[str, Any]) -> None:
        gate = payload["agent_config"]["gate"]
        assert not gate["imagined_contact"]
        gate["contact_floors"] = [0.05] * load_agent(runs[1]).meta.obs_dim

    with pytest.raises(ValueError, match=r"gate config differs .* in beta"):
        merge_runs([runs[0], _copy_run(runs[1], tmp_path / "beta", other_beta)], tmp_path / "w")
    assert merge_runs([runs[0], _copy_run(runs[1], tmp_path / "floors", floors)], tmp_path / "v").members > 0
    # a folder without a sample (a committed policy's) adds its members, the others' states calibrate the union
    merged = merge_runs([bare, runs[0]], tmp_path / "one-sample")
    own = CalibrationSample.load(runs[0] / CALIBRATION_FILE)
    assert merged.calibration_states == len(own) and merged.members == 2 * load_agent(runs[0]).world_model.members
    assert json.loads((merged.out / MERGE_FILE).read_text())["calibrated_on"] == [str(runs[0])]
    del policy


def test_sage_gate_merge_reports_what_it_wrote_and_errors_clearly(refits, tmp_path: Path) -> None:
    from app.cli import app

    _, runs = refits
    out = tmp_path / "m"
    result = CliRunner().invoke(app, ["gate", "merge", *map(str, runs), "--out", str(out)])
    assert result.exit_code == 0, result.output
    members = load_agent(out).world_model.members
    assert f"{members} members" in result.output and "τ" in result.output
    failed = CliRunner().invoke(app, ["gate", "merge", str(runs[0]), "--out", str(tmp_path / "n")])
    assert failed.exit_code == 2 and "at least two" in failed.output
