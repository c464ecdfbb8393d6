"""sage serve refuses bad start-up input in one clear line, before any banner, with no unsafe advice."""

from __future__ import annotations

from pathlib import Path

from typer.testing import CliRunner

from app.cli import app


def run(*args: str) -> tuple[int, str]:
    result = CliRunner().invoke(app, ["serve", *args])
    return result.exit_code, result.output


def test_a_missing_or_corrupt_policy_is_one_line_before_any_banner(tmp_path: Path) -> None:
    code, out = run("--policy", str(tmp_path / "nowhere"))
    assert code == 2 and "dashboard on" not in out and len(out.strip().splitlines()) == 1
    assert "cannot be loaded" in out
    corrupt = tmp_path / "corrupt.pt"
    corrupt.write_bytes(b"not a checkpoint at all")
    code, out = run("--policy", str(corrupt))
    assert code == 2 and len(out.strip().splitlines()) == 1 and "weights_only" not in out
    assert "Traceback" not in out


def test_a_bad_scenario_or_simulator_is_one_line(tmp_path: Path) -> None:
    code, out = run("--scenario", "9")
    assert code == 2 and "give 1-4" in out and len(out.strip().splitlines()) == 1
    code, out = run("--sim", "carla")
    assert code == 2 and "unknown simulator" in out
    code, out = run("--scenario", str(tmp_path / "missing.yaml"))
    assert code == 2 and "scenario file not found" in out


def test_a_bad_gate_setting_is_one_line_before_any_banner() -> None:
    code, out = run("--set", "gate.nope=1")
    assert code == 2 and "nope" in out and "dashboard on" not in out and len(out.strip().splitlines()) == 1
    code, out = run("--set", "gate.release=3")  # checked against the default policy's own gate
    assert code == 2 and "release" in out and len(out.strip().splitlines()) == 1
