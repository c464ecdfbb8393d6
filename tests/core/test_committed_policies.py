"""The committed policies are ready to be warm-started: a run that starts from one learns."""

from __future__ import annotations

from pathlib import Path

import pytest

from core.agents import load_checkpoint

ROOT = Path(__file__).resolve().parents[2]
POLICIES = sorted((ROOT / "policies").glob("*/checkpoint.pt"))


@pytest.mark.parametrize("checkpoint", POLICIES, ids=[p.parent.name for p in POLICIES])
def test_a_committed_policy_carries_a_learning_schedule(checkpoint: Path) -> None:
    """A warm start takes the hyperparameters of the run it starts from: a policy whose configuration says
    ``updates_per_step=0`` (e.g. left over from a world-model-only refit) would make every adaptation from it a
    silent no-op."""
    config = load_checkpoint(checkpoint)["agent_config"]
    assert config["updates_per_step"] > 0
    assert config["world_model"] is True


RELEASE = {"highway-default": 0.0}
"""The defaults whose hysteresis is not step 4's ``release=1`` (their README says which step changed it)."""


@pytest.mark.parametrize("checkpoint", POLICIES, ids=[p.parent.name for p in POLICIES])
def test_a_committed_policy_deploys_the_gate_its_readme_measured(checkpoint: Path) -> None:
    """The dashboard, ``sage eval --gate`` and the calibration bench build the gate from the checkpoint's config: the
    defaults deploy the hysteresis each README measured (``gate.release=1``; highway's step 10 switched it off, chosen
    by issue 60's rule), the 1 s hold and the geometric threshold that docs/calibration.md measured; a refit that
    rewrote them with the paper's defaults would silently change what a person supervising the robot gets."""
    from core.agents import load_agent

    gate = load_agent(checkpoint.parent).make_gate()
    release = RELEASE.get(checkpoint.parent.name, 1.0)
    assert gate.cfg.release == release
    assert gate.release_level(0.5) == pytest.approx(0.5 - release * max(0.5 - gate.threshold.tau_min, 0.0))
    assert gate.cfg.hold_seconds == 1.0
    threshold = gate.threshold
    assert 0.0 < threshold.tau_min < threshold.tau_max
    # halfway between the bounds by ratio, which the paper's linear form would put at their arithmetic mean
    assert threshold.at(0.5) == pytest.approx((threshold.tau_min * threshold.tau_max) ** 0.5)
    assert threshold.at(0.5) < (threshold.tau_min + threshold.tau_max) / 2


def test_adapting_from_the_default_ugv_policy_updates_it(tmp_path: Path) -> None:
    from studies.spec import TrainSpec
    from studies.training import run_training

    init = str(POLICIES[[p.parent.name for p in POLICIES].index("ugv-default")].parent)
    spec = TrainSpec(sim="ugv", scenario="3", method="sac", train_steps=300, init=init, checkpoint_every=0,
                     overrides=["batch_size=32"], out=str(tmp_path / "adapt"))  # fmt: skip
    assert run_training(spec).result.learner.updates > 200


@pytest.mark.parametrize("checkpoint", POLICIES, ids=[p.parent.name for p in POLICIES])
def test_a_committed_policy_deploys_the_operating_point_it_chose(checkpoint: Path) -> None:
    """``sage gate choose-scale`` ran on each default's training scenarios: its rows and choice lie beside the policy
    (``tau_scale_choice.json``, where it changed the scale) or in ``docs/notes/choose_scale/<policy>.json``. The
    checkpoint deploys the scale chosen, which met the target on every scenario it was chosen on; where none met,
    the scale the policy had (1) stays. A scale chosen by the operating-point rule on train fields
    (``experiments.pick_operating_point``, the UGV's mover-model gate) is that rule's pick from the record's rows."""
    import json

    from core.agents import load_agent

    name = checkpoint.parent.name
    beside, documented = (
        checkpoint.parent / "tau_scale_choice.json",
        ROOT / "docs" / "notes" / "choose_scale" / f"{name}.json",
    )
    assert beside.exists() != documented.exists(), f"{name}: one record of its scale's choice"
    choice = json.loads((beside if beside.exists() else documented).read_text())
    gate = load_agent(checkpoint.parent).make_gate()
    assert gate.cfg.tau_scale == pytest.approx(choice["scale"])
    if choice.get("rule") == "pick_operating_point":  # chosen on train fields against the gate it replaced
        from experiments.pick_operating_point import pick_scale

        assert choice["scale"] == pick_scale(choice["rows"], choice["baseline_takeover"])
        assert all(getattr(gate.cfg, key) == value for key, value in choice["gate_settings"].items())
        return
    chosen = [row for row in choice["rows"] if row["scale"] == choice["scale"]]
    if choice["met"]:
        assert chosen and all(row["met"] for row in chosen)
        assert sorted(row["scenario"] for row in chosen) == sorted(choice["scenarios"])
    else:
        assert choice["scale"] == 1.0 and not any(
            all(r["met"] for r in choice["rows"] if r["scale"] == s) for s in {r["scale"] for r in choice["rows"]}
        )
