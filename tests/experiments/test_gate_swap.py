"""experiments/gate_swap.py: a version driven with its own gate, the base's gate and alone (a tiny budget)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from core.versions import VersionStore
from experiments.gate_swap import main


def test_each_version_is_driven_each_way_and_v0000_not_by_its_own_gate_twice(tmp_path: Path) -> None:
    store = VersionStore(tmp_path / "versions")
    store.ensure_initial("policies/ugv-default")
    out = tmp_path / "out"
    assert main([str(store.root), "--episodes", "1", "--max-steps", "20", "--out", str(out)]) == 0
    report = json.loads((out / "report.json").read_text())
    (row,) = report["rows"]
    assert row["number"] == 0 and set(row) == {"number", "own", "alone"}
    assert row["alone"]["takeover_share"] == 0.0  # no gate: nobody hands over
    assert 0 <= row["alone"]["mover_collisions"] <= row["alone"]["collisions"] == len(row["alone"]["mover_gaps"])
    assert 0.0 <= row["own"]["takeover_share"] <= 1.0 and row["own"]["episodes"] == 1
    assert "| v0000 |" in (out / "report.md").read_text() and " mover), " in (out / "report.md").read_text()


def test_a_folder_without_versions_or_an_unknown_version_is_one_error_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main([str(tmp_path), "--out", str(tmp_path / "out")]) == 2
    assert "holds no v0000" in capsys.readouterr().err
    store = VersionStore(tmp_path / "versions")
    store.ensure_initial("policies/ugv-default")
    assert main([str(store.root), "--only", "3", "--out", str(tmp_path / "out")]) == 2
    assert "no version [3]" in capsys.readouterr().err


@pytest.mark.parametrize(("pair", "says"), [("gate.no_such=1", "unknown config field"), ("env.x=1", "only gate.")])
def test_a_bad_gate_setting_is_one_error_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], pair: str, says: str
) -> None:
    assert main([str(tmp_path), "--set", pair, "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: --set") and says in err and len(err.strip().splitlines()) == 1


def test_a_gate_setting_the_versions_bounds_do_not_fit_is_one_error_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    store = VersionStore(tmp_path / "versions")
    store.ensure_initial("policies/ugv-default")
    argv = [str(store.root), "--set", "gate.contact_extrapolation=true", "--episodes", "1", "--max-steps", "5"]
    assert main([*argv, "--out", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: v0000 own:") and "recalibrate" in err and len(err.strip().splitlines()) == 1
