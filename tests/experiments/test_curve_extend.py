"""experiments/curve_extend.py: what it refuses before any episode, and the table it writes."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from experiments import curve_extend
from studies.calibrate import CurveExtension, extension_rows


def _point(takeover: float, violations: int, episodes: int, knob: float) -> dict[str, float]:
    return {"knob": knob, "takeover_rate": takeover, "violation_rate": violations / episodes, "episodes": episodes}


CURVE = {"fear (SAGE)": [_point(0.47, 25, 1000, 0.5)], "curiosity only": [_point(0.49, 34, 1000, 3.29)]}


def _main(monkeypatch: pytest.MonkeyPatch, *argv: str) -> None:
    monkeypatch.setattr(sys, "argv", ["experiments/curve_extend.py", *argv])
    curve_extend.main()


@pytest.mark.parametrize(
    ("report", "args", "says"),
    [
        (None, ["--at-rates", "0.47", "--episodes", "10"], "no report.json"),
        (
            {"run": "x/highway-default", "sim": "highway", "scenario": "test"},
            ["--at-rates", "0.5", "--episodes", "9"],
            "no operating curve",
        ),
        (
            {"run": "x/nowhere", "sim": "highway", "scenario": "test", "curve": CURVE},
            ["--at-rates", "0.47", "--episodes", "9"],
            "no checkpoint.pt",
        ),
        (
            {"run": "x/highway-default", "sim": "highway", "scenario": "test", "curve": CURVE},
            ["--at-rates", "0.3", "--episodes", "9"],
            "no fear point within 5% of 30%",
        ),
        (
            {"run": "x/highway-default", "sim": "highway", "scenario": "test", "curve": CURVE},
            ["--at-rates", "0.47", "--episodes", "0"],
            "at least 1",
        ),
    ],
)
def test_bad_input_is_refused_before_any_episode(
    report: dict | None,
    args: list[str],
    says: str,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    if report is not None:
        (tmp_path / "report.json").write_text(json.dumps(report))
    with pytest.raises(SystemExit) as stop:
        _main(monkeypatch, str(tmp_path), *args, "--out", str(tmp_path / "out"))
    assert stop.value.code == 2 and says in capsys.readouterr().err
    assert not (tmp_path / "out").exists()  # nothing written, no task started


def test_the_table_gives_each_pair_on_the_curve_new_and_pooled_episodes() -> None:
    points = CurveExtension([0.47], ("curiosity only",)).points(CURVE)
    rows = extension_rows(points, [_point(0.46, 75, 3000, 0.5), _point(0.50, 110, 3000, 3.29)])
    report = {"sim": "highway", "scenario": "test-adversarial"}
    lines = curve_extend.table(rows, report, "python -m experiments.curve_extend X", "abc1234", 3_001_000, 3000, 9.0)
    (row,) = [line for line in lines if line.startswith("| 47%")]
    assert "25/1000 at 47.0% · 75/3000 at 46.0% · 100/4000 at 46.2%" in row
    assert "34/1000 at 49.0% · 110/3000 at 50.0% · 144/4000 at 49.8%" in row
    assert row.endswith("| better |")
    assert "seeds 3001000-3003999" in lines[2] and "abc1234" in lines[2]
