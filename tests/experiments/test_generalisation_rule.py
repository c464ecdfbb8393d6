"""experiments.generalisation_rule: the adoption rule of docs/notes/generalisation.md read off two gate rows."""

from __future__ import annotations

from pathlib import Path

import pytest

from experiments.generalisation_rule import main, verdict


def test_fewer_violations_pass_on_unseen_ground_only_at_a_takeover_within_the_rule() -> None:
    (_, high), rise, reading = verdict("unseen", (1, 300, 0.30), (20, 300, 0.46))
    assert high < 0 and rise == pytest.approx(-16.0) and reading == "pass"
    assert verdict("unseen", (1, 300, 0.40), (20, 300, 0.46))[2] == "fail"  # takeover over 35%
    assert verdict("unseen", (1, 300, 0.30), (20, 300, 0.24))[2] == "fail"  # takeover up 6 points
    assert verdict("unseen", (20, 300, 0.40), (1, 300, 0.40))[2] == "fail"  # more violations
    assert verdict("unseen", (12, 300, 0.45), (13, 300, 0.46))[2] == "undecided"
    assert verdict("unseen", (12, 300, 0.40), (13, 300, 0.46))[2] == "pass"  # equal share, 6 points less takeover


def test_the_seen_ground_fails_when_it_gets_worse() -> None:
    assert verdict("seen", (6, 300, 0.33), (5, 300, 0.32))[2] == "pass"
    assert verdict("seen", (30, 300, 0.33), (5, 300, 0.32))[2] == "fail"
    assert verdict("seen", (5, 300, 0.40), (5, 300, 0.32))[2] == "fail"


def test_a_cache_without_the_rows_is_one_error_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    empty = tmp_path / "empty.json"
    argv = ["--candidate", "runs/none", "--candidate-cache", str(empty), "--baseline-cache", str(empty)]
    assert main([*argv, "--episodes", "10"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "has 0 of 10 unseen gate episodes" in err[0]
