"""``sage expert --sim ugv``: the table, the picture, and clear errors."""

from __future__ import annotations

from pathlib import Path

from typer.testing import CliRunner

from app.cli import app


def test_expert_command_prints_the_table_and_draws(tmp_path: Path) -> None:
    picture = tmp_path / "runs" / "ugv3.png"
    result = CliRunner().invoke(
        app, ["expert", "--sim", "ugv", "--scenario", "3", "--episodes", "2", "--seed", "4", "--plot", str(picture)]
    )
    assert result.exit_code == 0, result.output
    header = result.stdout.splitlines()[0].split()
    assert header[:7] == [
        "success",
        "collision",
        "timeout",
        "avg_speed",
        "travel_distance",
        "path_curvature",
        "lateral_acc",
    ]
    assert "2/2 (100%)" in result.stdout
    assert picture.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and picture.stat().st_size > 20_000


def test_expert_command_runs_a_scenario_file(tmp_path: Path) -> None:
    scenario = tmp_path / "mine.yaml"
    scenario.write_text(
        "name: mine\nbounds: [0, 0, 6, 3]\nstart: {x: 1, y: 1.5}\ngoal: {x: 5, y: 1.5}\n"
        "obstacles:\n  - {kind: box, x: 3, y: 1.2, length: 0.4, width: 1.2}\n"
    )
    result = CliRunner().invoke(app, ["expert", "--scenario", str(scenario), "--episodes", "1"])
    assert result.exit_code == 0, result.output
    assert "expert (ugv" in result.stdout and "1/1 (100%)" in result.stdout


def test_expert_command_reports_a_bad_scenario(tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: bad\nbounds: [0, 0, 4, 4]\nstart: {x: 1, y: 1}\ngoal: {x: 9, y: 1}\n")
    result = CliRunner().invoke(app, ["expert", "--sim", "ugv", "--scenario", str(bad), "--episodes", "1"])
    assert result.exit_code == 2
    assert "goal.x: 9 lies outside the map bounds" in result.output
    missing = CliRunner().invoke(app, ["expert", "--scenario", str(tmp_path / "none.yaml")])
    assert missing.exit_code == 2 and "scenario file not found" in missing.output
