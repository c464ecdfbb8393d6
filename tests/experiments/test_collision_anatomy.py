"""experiments/collision_anatomy.py: each collision read over the window before contact and put in one class; a
tiny run on train fields renders its report; a test ground is refused."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from experiments import collision_anatomy as ca


def _steps(drivers: list[str], fear: list[float], contact: int) -> list[ca.Step]:
    return [
        ca.Step(t, d, f, 0.3, t == contact, ttc=float(contact - t) / 10, gap=0.0 if t == contact else 1.0)
        for t, (d, f) in enumerate(zip(drivers, fear, strict=True))
    ]


def test_an_expert_that_took_the_wheel_two_steps_before_contact_is_late() -> None:
    drivers = ["policy"] * 8 + ["fear", "fear", "fear"]
    fear = [0.1] * 8 + [0.6, 0.9, 0.9]
    c = ca.read_collision(_steps(drivers, fear, 10), seed=7, window=20, tau_min=0.16)
    assert c is not None and c.seed == 7 and c.contact_t == 10
    assert c.first_fire_lead == 2 and c.expert_streak == 3 and c.since_hand_back is None
    assert c.ratio_peak == pytest.approx(3.0) and c.ttc_at_first_fire == pytest.approx(0.2)
    assert ca.classify(c, enough_steps=10) == "expert, late"
    assert ca.classify(c, enough_steps=3) == "expert, in time"


def test_the_policy_driving_after_a_hand_back_and_a_gate_that_never_fired() -> None:
    drivers = ["policy", "fear", "hold", "hold", "policy", "policy", "policy"]
    c = ca.read_collision(_steps(drivers, [0.1, 0.5, 0.1, 0.1, 0.1, 0.1, 0.1], 6), seed=0, window=20, tau_min=0.16)
    assert c is not None and c.since_hand_back == 3 and c.expert_streak == 0
    assert ca.classify(c, 10) == "policy after hand-back"
    quiet = ca.read_collision(_steps(["policy"] * 5, [0.1, 0.1, 0.2, 0.1, 0.1], 4), seed=0, window=20, tau_min=0.16)
    assert quiet is not None and quiet.first_fire_lead is None and math.isnan(quiet.ttc_at_first_fire)
    assert ca.classify(quiet, 10) == "policy, fear over τ_min only"
    unforeseen = ca.read_collision(_steps(["policy"] * 5, [0.1] * 5, 4), seed=0, window=20, tau_min=0.16)
    assert unforeseen is not None and ca.classify(unforeseen, 10) == "policy, unforeseen"
    assert ca.read_collision(_steps(["policy"] * 3, [0.1] * 3, 99), seed=0, window=20, tau_min=0.16) is None


def test_a_tiny_run_on_train_fields_renders_its_report(tmp_path: Path) -> None:
    out = tmp_path / "report.md"
    assert ca.main(["--episodes", "1", "--no-counterfactual", "--out", str(out)]) == 0
    text = out.read_text()
    assert "episodes with a collision at" in text and "| expert, late |" in text
    assert text.startswith("Made by `python -m experiments.collision_anatomy --episodes 1")


def test_a_test_ground_is_refused() -> None:
    with pytest.raises(SystemExit):
        ca.main(["--scenario", "ugv-fields:test:2+", "--episodes", "1"])
