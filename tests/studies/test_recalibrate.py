"""``sage gate refit-bounds``: the τ bounds measured again for another fear, β chosen from data, and a gate that would
read bounds measured on another fear refused."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from core.agents import load_agent, load_checkpoint
from core.sage.calibration import CALIBRATION_FILE, CalibrationSample
from core.train import RunConfig, train
from studies.recalibrate import BETA_CANDIDATES, RECALIBRATION_FILE, choose_beta, mean_auroc, recalibrate_run
from tests.core.test_train import point_env, small

torch.set_num_threads(1)
DT = 0.1


@pytest.fixture(scope="module")
def policy(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small SAGE policy with a world model on the point env."""
    out = tmp_path_factory.mktemp("recalibrate") / "policy"
    run = RunConfig(sim="point", scenarios=["static", "dynamic"], episodes=4, seed=3, demo_episodes=3,
                    checkpoint_every=0)  # fmt: skip
    train(run, small("sage"), point_env, out, progress=False)
    return out


def test_choose_beta_takes_the_best_mean_ranking_and_breaks_ties_towards_the_runs_own() -> None:
    scores = {"a": {"0.5": 0.90, "0.7": 0.95, "1.0": 0.93}, "b": {"0.5": 0.90, "0.7": 0.91, "1.0": 0.93}}
    assert mean_auroc(scores) == pytest.approx({"0.5": 0.90, "0.7": 0.93, "1.0": 0.93})
    assert choose_beta(scores, current=0.5) == 0.7  # 0.7 and 1.0 tie: the nearer to 0.5
    assert choose_beta(scores, current=0.9) == 1.0
    assert choose_beta({"a": {"0.2": 0.8, "0.8": 0.7}}, current=0.8) == 0.2


def test_recalibrated_bounds_are_the_fear_quantiles_of_the_drives_states(policy: Path, tmp_path: Path) -> None:
    """The same drives (fixed seeds) measured for two β: each folder's bounds are what its own sample and fear
    give, they differ with β, and nothing but κ, the bounds and the disagreement reference moved in the model."""
    source = load_agent(policy)
    outs = {}
    for beta in (0.5, 0.9):
        out = tmp_path / f"beta{beta}"
        result = recalibrate_run(policy, point_env, ["static", "dynamic"], 3, out, DT, gate_settings={"beta": beta})
        assert result.beta == beta and result.bounds_before == pytest.approx(source.world_model.tau_bounds.tolist())
        assert result.steps > 0 and set(result.violation_episodes) == {"static", "dynamic"}
        outs[beta] = out
        agent = load_agent(out)
        assert agent.config.gate.beta == beta
        assert json.loads((out / "config.json").read_text())["agent"]["gate"]["beta"] == beta
        assert json.loads((out / RECALIBRATION_FILE).read_text())["bounds"] == pytest.approx(result.bounds)
        model = agent.world_model
        stored = model.tau_bounds.clone()
        assert stored.tolist() == pytest.approx(result.bounds, abs=1e-6)
        CalibrationSample.load(out / CALIBRATION_FILE).calibrate(model, agent.learner.rollout_policy, agent.config.gate)
        torch.testing.assert_close(model.tau_bounds, stored, atol=1e-5, rtol=0)
        before, after = source.world_model.state_dict(), agent.world_model.state_dict()
        moved = {name for name in before if not torch.equal(before[name], after[name])}
        assert moved <= {"sigma_scale", "tau_bounds", "disagreement_ref"}, moved  # what a calibration measures
        for name, value in source.learner.actor.state_dict().items():
            assert torch.equal(value, agent.learner.actor.state_dict()[name]), name
        assert agent.make_gate() is not None
    first, second = (CalibrationSample.load(outs[b] / CALIBRATION_FILE) for b in (0.5, 0.9))
    np.testing.assert_array_equal(first.obs, second.obs)  # the same states ...
    assert load_agent(outs[0.5]).world_model.tau_bounds.tolist() != pytest.approx(
        load_agent(outs[0.9]).world_model.tau_bounds.tolist(), abs=1e-4
    )  # ... another fear, other bounds
    with pytest.raises(ValueError, match="already holds"):
        recalibrate_run(policy, point_env, ["static"], 1, outs[0.5], DT)


def test_refit_bounds_for_state_novelty_keeps_its_reference_set_in_the_run(policy: Path, tmp_path: Path) -> None:
    settings = {"curiosity_signal": "novelty", "curiosity_reference": "fitted"}
    assert load_agent(policy).world_model.novelty_reference() is None
    result = recalibrate_run(policy, point_env, ["static"], 3, tmp_path / "novelty", DT, gate_settings=settings)
    agent = load_agent(tmp_path / "novelty")
    model = agent.world_model
    assert model.novelty_reference() is not None and len(model.novelty_states) > 0
    assert result.curiosity_reference == pytest.approx(float(model.novelty_ref)) and result.curiosity_reference > 0
    assert "read against its mean on these states" in result.summary()
    gate = agent.make_gate()
    assert gate.cfg.curiosity_signal == "novelty" and gate.threshold.ema == pytest.approx(float(model.novelty_ref))


def test_novelty_scenarios_join_the_reference_set_and_leave_the_bounds_alone(policy: Path, tmp_path: Path) -> None:
    """``--novelty-scenario``: another scenario's drives become familiar ground for the state novelty (its states
    score lower than without them) while κ and the τ bounds are those of the bounds' scenarios alone."""
    from core.prior import drive_alone
    from core.sage.novelty import novelty_features

    settings = {"curiosity_signal": "novelty", "curiosity_reference": "fitted"}
    only = recalibrate_run(policy, point_env, ["static"], 3, tmp_path / "only", DT, gate_settings=settings)
    wide = recalibrate_run(
        policy, point_env, ["static"], 3, tmp_path / "wide", DT, gate_settings=settings, novelty_scenarios=["dynamic"]
    )
    assert wide.novelty_scenarios == ["dynamic"] and only.novelty_scenarios == []
    assert wide.bounds == pytest.approx(only.bounds, abs=1e-6) and wide.steps == only.steps
    narrow_model, wide_model = (load_agent(tmp_path / name).world_model for name in ("only", "wide"))
    assert len(wide_model.novelty_states) >= len(narrow_model.novelty_states)
    # states of the added scenario: nearer the wide reference set than the narrow one
    sample = CalibrationSample.load(tmp_path / "wide" / CALIBRATION_FILE)
    steps = drive_alone(policy, 2, 7, make_env=point_env, scenarios=["dynamic"])
    dynamic = torch.from_numpy(np.stack([r.obs for r in steps]).astype(np.float32))
    assert len(sample) == only.calibration_states  # the saved sample is the bounds' own

    def novelty(model, obs: torch.Tensor) -> float:
        reference = model.novelty_reference()
        return float(reference(novelty_features(obs, None, model.motion)).mean())

    assert novelty(wide_model, dynamic) < novelty(narrow_model, dynamic)
    with pytest.raises(ValueError, match="curiosity_signal=novelty"):
        recalibrate_run(policy, point_env, ["static"], 1, tmp_path / "bad", DT, novelty_scenarios=["dynamic"])


def test_keep_bounds_measures_only_the_curiositys_reference(policy: Path, tmp_path: Path) -> None:
    """``--keep-bounds``: κ and the τ bounds are the run's own, the novelty's reference is measured; a setting that
    changes fear cannot keep them."""
    source = load_agent(policy).world_model
    settings = {"curiosity_signal": "novelty", "curiosity_reference": "fitted"}
    result = recalibrate_run(
        policy, point_env, ["static"], 3, tmp_path / "kept", DT, gate_settings=settings, keep_bounds=True
    )
    model = load_agent(tmp_path / "kept").world_model
    assert torch.equal(model.tau_bounds, source.tau_bounds) and torch.equal(model.sigma_scale, source.sigma_scale)
    assert result.bounds == pytest.approx(result.bounds_before) and result.kept_bounds
    assert model.novelty_reference() is not None and "kept" in result.summary()
    refit = load_agent(
        recalibrate_run(policy, point_env, ["static"], 3, tmp_path / "refit", DT, gate_settings=settings).out
    ).world_model
    assert not torch.equal(refit.tau_bounds, source.tau_bounds)  # without it the same drives move the bounds
    with pytest.raises(ValueError, match="change fear itself"):
        recalibrate_run(
            policy, point_env, ["static"], 1, tmp_path / "beta", DT, gate_settings={"beta": 0.8}, keep_bounds=True
        )


def test_a_gate_that_changes_fear_over_bounds_measured_on_another_is_refused(policy: Path) -> None:
    agent = load_agent(policy)
    for setting in ({"beta": 0.8}, {"horizon": 3}, {"aggregate": "discounted_mean"}, {"tau_max_quantile": 0.95}):
        with pytest.raises(ValueError, match=r"changes fear itself.*sage gate refit-bounds"):
            agent.make_gate(**setting)
    # settings that leave fear and its bounds alone still go over the run's own
    assert agent.make_gate(hold_steps=2, tau_scale=0.5, release=0.5) is not None
    assert agent.make_gate(beta=0.8, tau_from_data=False, tau_min=0.1, tau_max=0.4) is not None


def test_choosing_beta_scores_every_candidate_where_the_policy_met_a_violation(tmp_path: Path) -> None:
    """On the committed UGV policy's cluttered training field, a few episodes of the policy alone meet
    collisions: β is the candidate with the best mean ranking of the steps before them, and the folder deploys it."""
    out = tmp_path / "chosen"
    clutter = "sims/ugv/scenarios/clutter.yaml"
    import sims

    descriptor = sims.descriptor("ugv")
    result = recalibrate_run("policies/ugv-default", descriptor.make, [clutter], 8, out, descriptor.dt, choose=True)
    assert result.violation_episodes[clutter] > 0 and list(result.beta_auroc) == [clutter]
    assert list(result.beta_auroc[clutter]) == [str(b) for b in BETA_CANDIDATES]
    assert result.beta == choose_beta(result.beta_auroc, 0.5) and result.beta_before == 0.5
    assert load_agent(out).config.gate.beta == result.beta
    assert load_checkpoint(out)["meta"]["extra"]["recalibrated_from"] == "policies/ugv-default"
    with pytest.raises(ValueError, match="not both"):
        recalibrate_run("policies/ugv-default", descriptor.make, [clutter], 1, tmp_path / "x", descriptor.dt,
                        choose=True, gate_settings={"beta": 0.5})  # fmt: skip
    # β would be scored on the run's own fear, not on the one these settings make
    with pytest.raises(ValueError, match="imagined_contact change it"):
        contact = {"imagined_contact": True, "contact_floors": [0.02] * 54}
        recalibrate_run("policies/ugv-default", descriptor.make, [clutter], 1, tmp_path / "y", descriptor.dt,
                        choose=True, gate_settings=contact)  # fmt: skip
    assert not (tmp_path / "y").exists()


def test_sage_gate_refit_bounds_reports_what_it_wrote_and_errors_clearly(tmp_path: Path) -> None:
    from app.cli import app

    runner = CliRunner()
    out = tmp_path / "ugv"
    result = runner.invoke(app, ["gate", "refit-bounds", "policies/ugv-default", "--scenario", "1",
                                 "--episodes", "2", "--set", "gate.beta=0.6", "--out", str(out)])  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "β 0.5 -> 0.6" in result.output and load_agent(out).config.gate.beta == 0.6
    for args, message in (
        (["--scenario", "1", "--episodes", "1"], "--out"),
        (["--episodes", "1", "--out", str(tmp_path / "y")], "--scenario"),
        (["--scenario", "nowhere", "--out", str(tmp_path / "z")], "nowhere"),
        (["--scenario", "1", "--episodes", "1", "--out", str(out)], "already holds"),
        (["--scenario", "1", "--set", "gate.beta=2", "--out", str(tmp_path / "w")], "beta"),
    ):
        result = runner.invoke(app, ["gate", "refit-bounds", "policies/ugv-default", "--sim", "ugv", *args])
        assert result.exit_code == 2 and message in result.output, (args, result.output)
    assert not any((tmp_path / name).exists() for name in ("y", "z", "w"))


def test_a_run_of_no_episodes_keeps_no_fear_its_bounds_were_not_measured_on(policy: Path, tmp_path: Path) -> None:
    """A 0-episode world-model-only run fits nothing: it may rewrite the hold or the scale, but a β (or horizon)
    over the init's would keep bounds measured on another fear, so it is refused with the command that does it."""
    config = load_agent(policy).config

    def zero_run(out: Path, **gate: object) -> None:
        run = RunConfig(sim="point", scenarios=["static"], episodes=0, seed=3, init=str(policy),
                        world_model_only=True, checkpoint_every=0)  # fmt: skip
        train(run, dataclasses.replace(config, gate=dataclasses.replace(config.gate, **gate)), point_env, out,
              progress=False)  # fmt: skip

    with pytest.raises(ValueError, match="sage gate refit-bounds"):
        zero_run(tmp_path / "beta", beta=0.8)
    assert not (tmp_path / "beta" / "checkpoint.pt").exists()
    zero_run(tmp_path / "hold", hold_steps=2)
    assert load_agent(tmp_path / "hold").config.gate.hold_steps == 2


def test_imagined_contact_is_another_fear_measured_again_with_the_simulators_floors(tmp_path: Path) -> None:
    """Switching fear's imagined contact on or off changes fear, so a run's bounds must be measured again for it:
    refused over a run's own bounds (the committed UGV policy has it on), and ``sage gate refit-bounds --set
    gate.imagined_contact=false`` / ``=true`` writes a run without it / with it and the UGV's contact floors."""
    import sims
    from app.cli import app

    floors = list(sims.descriptor("ugv").contact_floors)
    committed = load_agent("policies/ugv-default")
    assert committed.config.gate.imagined_contact and committed.config.gate.contact_floors == floors
    # its contact reaches 1 s and moves the tracked movers: switching contact off says to switch those off too
    with pytest.raises(ValueError, match=r"needs gate.imagined_contact.*gate.contact_horizon=none"):
        committed.make_gate(imagined_contact=False)
    off = {"imagined_contact": False, "contact_horizon": None, "mover_model": "none"}
    with pytest.raises(ValueError, match=r"changes fear itself.*sage gate refit-bounds"):
        committed.make_gate(**off)
    without = tmp_path / "without"
    args = ["--sim", "ugv", "--scenario", "1", "--episodes", "2"]
    switch_off = ["--set", "gate.imagined_contact=false", "--out", str(without)]
    result = CliRunner().invoke(app, ["gate", "refit-bounds", "policies/ugv-default", *args, *switch_off])
    assert result.exit_code != 0 and "gate.contact_horizon=none" in result.output
    switch_off = ["--set", "gate.contact_horizon=none", "--set", "gate.mover_model=none", *switch_off]
    result = CliRunner().invoke(app, ["gate", "refit-bounds", "policies/ugv-default", *args, *switch_off])
    assert result.exit_code == 0, result.output
    agent = load_agent(without)
    assert not agent.config.gate.imagined_contact and not agent.make_gate().cfg.imagined_contact
    with pytest.raises(ValueError, match=r"changes fear itself.*sage gate refit-bounds"):
        agent.make_gate(imagined_contact=True, contact_floors=floors)
    out = tmp_path / "contact"
    result = CliRunner().invoke(
        app, ["gate", "refit-bounds", str(without), *args, "--set", "gate.imagined_contact=true", "--out", str(out)]
    )
    assert result.exit_code == 0, result.output
    recalibrated = load_agent(out)
    assert recalibrated.config.gate.imagined_contact and recalibrated.config.gate.contact_floors == floors
    assert recalibrated.make_gate().cfg.imagined_contact
    with pytest.raises(ValueError, match="contact_floors"):  # another simulator's floors are another fear
        recalibrated.make_gate(contact_floors=[0.5] * 54)
