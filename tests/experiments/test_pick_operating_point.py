"""experiments.pick_operating_point: the operating-point rule of docs/notes/generalisation.md read off two
choose-scale JSON files."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from experiments.pick_operating_point import main, pick_scale


def row(scale: float, violations: int, takeover: float, episodes: int = 150) -> dict[str, Any]:
    return {
        "scale": scale,
        "scenario": "ugv-fields:train:2+",
        "violations": violations,
        "episodes": episodes,
        "takeover_rate": takeover,
        "met": False,
    }


def test_the_fewest_violations_within_the_baseline_takeover_are_chosen() -> None:
    rows = [row(1.0, 12, 0.51), row(0.9, 9, 0.56), row(0.8, 6, 0.60), row(0.7, 5, 0.66)]
    assert pick_scale(rows, 0.58) == 0.9  # 0.8 and 0.7 collide less but take over more than the baseline
    assert pick_scale(rows, 0.70) == 0.7


def test_a_tie_goes_to_the_larger_scale_and_none_within_is_no_choice() -> None:
    assert pick_scale([row(1.0, 12, 0.51), row(0.9, 8, 0.55), row(0.8, 8, 0.57)], 0.58) == 0.9
    assert pick_scale([row(1.0, 12, 0.61), row(0.9, 8, 0.65)], 0.58) is None


def write(path: Path, rows: list[dict[str, Any]]) -> Path:
    path.write_text(json.dumps({"rows": rows, "scale": 1.0}))
    return path


def test_main_prints_the_table_and_the_scale(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    base = write(tmp_path / "base.json", [row(1.0, 13, 0.58)])
    sweep = write(tmp_path / "sweep.json", [row(1.0, 12, 0.51), row(0.9, 9, 0.56), row(0.8, 6, 0.60)])
    assert main(["--baseline", str(base), "--sweep", str(sweep)]) == 0
    out = capsys.readouterr().out
    assert "| tau_scale 0.9 | 9 of 150" in out and "chosen: gate.tau_scale=0.9," in out
    assert main(["--baseline", str(base), "--sweep", str(sweep), "--scale-only"]) == 0
    assert capsys.readouterr().out.strip() == "0.9"
    none_within = write(tmp_path / "none.json", [row(0.9, 9, 0.66)])
    assert main(["--baseline", str(base), "--sweep", str(none_within), "--scale-only"]) == 0
    assert capsys.readouterr().out.strip() == "1"


def test_rows_of_another_ground_are_one_error_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    base = write(tmp_path / "base.json", [row(1.0, 13, 0.58, episodes=100)])
    sweep = write(tmp_path / "sweep.json", [row(1.0, 12, 0.51)])
    assert main(["--baseline", str(base), "--sweep", str(sweep)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "same scenario and episodes" in err[0]
    assert main(["--baseline", str(tmp_path / "missing.json"), "--sweep", str(sweep)]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
