"""``sage gate`` from the command line: the committed UGV default, a few short episodes, its printed report and
its figures; the simulator read from the run folder; and bad input answered with one clear line and exit code 2,
nothing written."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from typer.testing import CliRunner

from app.cli import app

torch.set_num_threads(1)
ROOT = Path(__file__).resolve().parents[2]
UGV_DEFAULT = str(ROOT / "policies" / "ugv-default")
HIGHWAY_DEFAULT = str(ROOT / "policies" / "highway-default")


def test_gate_evaluate_prints_the_report_and_writes_its_figures(tmp_path: Path) -> None:
    out = tmp_path / "calib"
    result = CliRunner().invoke(
        app,
        [
            "gate", "evaluate", UGV_DEFAULT, "--scenario", "4", "--episodes", "4", "--max-steps", "120",
            "--curve-episodes", "1", "--out", str(out),
        ],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    # the scenario-4 cut-in meets the policy within 120 steps: the label has positives, so fear gets a score
    assert "| fear |" in result.output and "label: violation within 1 s (10 steps)" in result.output
    for gating in ("fear (SAGE)", "random", "curiosity only", "expert alone"):
        assert f"operating curve {gating}" in result.output
    assert {p.name for p in out.iterdir()} == {"report.json", "reliability.png", "operating_curve.png"}
    report = json.loads((out / "report.json").read_text())
    assert report["sim"] == "ugv" and report["scenario"] == "4"
    assert 0.0 <= report["scores"]["fear"]["auroc"] <= 1.0
    assert [len(points) for points in report["curve"].values()] == [6, 6, 6, 1]


def test_gate_evaluate_says_how_much_warning_the_expert_needs(tmp_path: Path) -> None:
    result = CliRunner().invoke(
        app,
        ["gate", "evaluate", UGV_DEFAULT, "--sim", "ugv", "--scenario", "4", "--episodes", "3", "--max-steps", "120",
         "--expert-lead", "--out", str(tmp_path)],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    # the cut-in meets the policy in every one of these episodes; the expert, taking over 3 s ahead, avoids it
    assert "the policy alone had a violation in 3 of 3 episodes" in result.output
    left = result.output.split("violations left: ")[1].splitlines()[0]
    assert left.startswith("0.5 s: ") and left.endswith("3 s: 0")
    assert "warning the expert needs: " in result.output
    saved = json.loads((tmp_path / "expert_lead.json").read_text())
    assert saved["violations"] == 3 and saved["left"][-1] == 0 and saved["needed_s"] <= 3.0


def test_gate_evaluate_replays_the_gated_violations_with_steady_manoeuvres(tmp_path: Path) -> None:
    result = CliRunner().invoke(
        app,
        ["gate", "evaluate", UGV_DEFAULT, "--scenario", "3", "--episodes", "8", "--max-steps", "100",
         "--escape", "--out", str(tmp_path)],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    saved = json.loads((tmp_path / "escape.json").read_text())
    # the crossing mover meets the gated policy in some of these episodes; pymunk replays them exactly
    assert saved["episodes"] == 8 and saved["violations"] > 0 and saved["drifted"] == 0
    assert saved["replayed"] == saved["violations"] and saved["manoeuvres"] == 25  # 5 x 5 over (v, w)
    assert 0 <= saved["from_takeover"] <= saved["warned"] <= saved["violations"]
    # two seconds ahead of the crossing, stopping (or turning away) clears the mover in every one of them
    assert saved["escapable_before"][-1] == saved["violations"]
    assert f"{saved['violations']} of 8 episodes with a violation" in result.output


def test_gate_evaluate_refuses_bad_input_with_one_line(tmp_path: Path) -> None:
    out = tmp_path / "calib"
    cases = {
        "ugv scenario '9'": [UGV_DEFAULT, "--sim", "ugv", "--scenario", "9"],
        "no run folder or checkpoint file": [str(tmp_path / "missing"), "--sim", "ugv"],
        "--sim warp: the run was trained on ugv": [UGV_DEFAULT, "--sim", "warp"],
        "unknown config field 'nope'": [UGV_DEFAULT, "--sim", "ugv", "--set", "gate.nope=1"],
        "gate.release must be in [0, 1]": [UGV_DEFAULT, "--set", "gate.release=2"],
        "names no section this command takes: gate.KEY=VALUE": [UGV_DEFAULT, "--set", "release=2"],
        "--gate-set is now --set gate.KEY=VALUE: --set gate.release=0": [UGV_DEFAULT, "--gate-set", "release=0"],
        "sage gate evaluate drives one scenario, not 3, 4": [UGV_DEFAULT, "--scenario", "3,4"],
    }
    for message, args in cases.items():
        result = CliRunner().invoke(app, ["gate", "evaluate", *args, "--episodes", "1", "--out", str(out)])
        assert result.exit_code == 2, result.output
        assert message in result.output and len(result.output.strip().splitlines()) == 1, result.output
    assert not out.exists()


def test_choose_scale_prints_the_rows_the_choice_and_how_to_deploy_it(tmp_path: Path) -> None:
    out = tmp_path / "choice.json"
    result = CliRunner().invoke(
        app,
        ["gate", "choose-scale", UGV_DEFAULT, "--scenario", "4", "--episodes", "2", "--max-steps", "60",
         "--scale", "0.001", "--scale", "100", "--violation-share", "1", "--set", "gate.release=0",
         "--out", str(out)],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    # every share of violations meets this target: the largest scale (the least takeover) is chosen at once
    assert "chosen: gate.tau_scale=100," in result.output and "| 0.001 |" not in result.output
    # measured with release=0 over the policy's own gate (release=1): deploying the scale alone would not be it
    assert "--set gate.release=0 --set gate.tau_scale=100 " in result.output
    saved = json.loads(out.read_text())
    assert saved["scale"] == 100 and saved["met"] and [r["scenario"] for r in saved["rows"]] == ["4"]
    assert saved["gate_settings"] == {"release": 0.0}
    assert saved["rows"][0]["takeover_rate"] == 0.0  # τ a hundred times its bounds: fear never reaches it
    assert saved["rows"][0]["takeover_fear"] == 0.0 and "| 0 · 0 · 0 · 0 | met |" in result.output


def test_choose_scale_refuses_bad_input_with_one_line(tmp_path: Path) -> None:
    for args, says in (
        ([], "give the scenarios to choose on"),
        (["--scenario", "no-such-scenario"], "no-such-scenario"),
        (["--scenario", "4", "--scale", "-1"], "scales must be"),
        (["--scenario", "4", "--set", "gate.tau_scale"], "key=value"),
    ):
        out = tmp_path / "choice.json"
        result = CliRunner().invoke(app, ["gate", "choose-scale", UGV_DEFAULT, "--out", str(out), *args])
        assert result.exit_code == 2 and says in result.output, (args, result.output)
        assert not out.exists()


def test_gate_evaluate_hands_the_curve_to_ray_when_given_cores(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``--cpus`` / ``--address`` reach the curve (its points as Ray tasks: tests/studies/test_calibrate.py)."""
    import studies.calibrate

    seen: dict[str, object] = {}

    def spy(*args: object, **kwargs: object) -> object:
        seen.update(kwargs)
        raise ValueError("stopped by the test")

    monkeypatch.setattr(studies.calibrate, "calibrate_run", spy)
    for flags, cpus, address in ((["--cpus", "3"], 3, None), (["--address", "head:6379"], None, "head:6379")):
        result = CliRunner().invoke(
            app, ["gate", "evaluate", UGV_DEFAULT, "--scenario", "4", "--curve-episodes", "5", *flags]
        )
        assert result.exit_code == 2 and "error: stopped by the test" in result.output
        assert seen["curve_cpus"] == cpus and seen["curve_address"] == address and seen["curve_episodes"] == 5


def test_gate_evaluate_reads_the_simulator_from_the_run_folder(tmp_path: Path) -> None:
    """``sage gate evaluate policies/highway-default`` with no --sim drives highway (it once drove the UGV and died
    on the observation's size); a --sim that contradicts the run is one line."""
    result = CliRunner().invoke(
        app, ["gate", "evaluate", HIGHWAY_DEFAULT, "--episodes", "1", "--max-steps", "15", "--out", str(tmp_path)]
    )
    assert result.exit_code == 0, result.output
    assert "highway-default on highway train: 1 episodes, 15 steps" in result.output
    assert json.loads((tmp_path / "report.json").read_text())["sim"] == "highway"
    result = CliRunner().invoke(app, ["gate", "evaluate", HIGHWAY_DEFAULT, "--sim", "ugv", "--episodes", "1"])
    assert result.exit_code == 2 and "--sim ugv: the run was trained on highway" in result.output


def test_gate_scenarios_are_repeatable_and_take_comma_lists(monkeypatch: pytest.MonkeyPatch) -> None:
    import studies.calibrate

    seen: dict[str, object] = {}

    def spy(run: str, factories: dict[str, object], *args: object, **kwargs: object) -> object:
        seen.update(scenarios=list(factories), sim=kwargs["sim"])
        raise ValueError("stopped by the test")

    monkeypatch.setattr(studies.calibrate, "choose_tau_scale", spy)
    result = CliRunner().invoke(app, ["gate", "choose-scale", UGV_DEFAULT, "--scenario", "1,2", "--scenario", "4"])
    assert result.exit_code == 2 and "error: stopped by the test" in result.output
    assert seen == {"scenarios": ["1", "2", "4"], "sim": "ugv"}
