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


TABLE = """# Generalisation: seen against unseen ground

## ugv: policies/ugv-default

| ground | scenarios | episodes (steps) | e | f | c | g | cm | t | gate + expert | takeover |
|---|---|---|---|---|---|---|---|---|---|---|
| unseen (ugv-fields:test) | ugv-fields:test | 300 | 1 | 2 | 3 | 4 | 5 | 6 | 13 of 300 (4%) [3%, 7%] | 46% |
| seen (training scenarios) | 1, 2 | 300 | 1 | 2 | 3 | 4 | 5 | 6 | 5 of 300 (2%) [1%, 4%] | 32% |

### Test fields with two or more movers

| unseen (ugv-fields:test:2+) | ugv-fields:test:2+ | 100 | 1 | 2 | 3 | 4 | 5 | 6 | 16 of 200 (8%) [5%, 13%] | 59% |

## highway: policies/highway-default

| unseen (ugv-fields:test) | ugv-fields:test | 60 | 1 | 2 | 3 | 4 | 5 | 6 | 2 of 30 (7%) [2%, 21%] | 54% |
"""


def test_the_baseline_rows_are_read_from_its_own_section_of_the_table() -> None:
    from experiments.generalisation_rule import table_point

    run = "policies/ugv-default"
    assert table_point(TABLE, run, "unseen", ["ugv-fields:test"]) == (13, 300, pytest.approx(0.46))
    assert table_point(TABLE, run, "seen", ["1", "2"]) == (5, 300, pytest.approx(0.32))
    assert table_point(TABLE, run, "unseen", ["ugv-fields:test:2+"]) == (16, 200, pytest.approx(0.59))
    assert table_point(TABLE, run, "seen", ["1"]) is None  # other scenarios: not the same ground
    # another simulator's section is read for its own run only
    assert table_point(TABLE, "policies/highway-default", "unseen", ["ugv-fields:test"]) == (2, 30, pytest.approx(0.54))
    assert table_point(TABLE, "policies/highway-default", "seen", ["1", "2"]) is None


class _Row:
    def __init__(self, violations: int, episodes: int, takeover: float) -> None:
        self.gate = {"episodes": episodes, "takeover_rate": takeover}
        self.gate_violations = (violations, episodes)


def _read_against_the_table(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, candidate: _Row
) -> tuple[int, str, str]:
    import experiments.generalisation_rule as rule

    table = tmp_path / "generalisation.md"
    table.write_text(TABLE)
    monkeypatch.setattr(rule, "generalisation_table", lambda *args, **kwargs: [candidate])
    argv = ["--candidate", "runs/c", "--candidate-cache", str(tmp_path / "c.json"), "--baseline-table", str(table)]
    code = main([*argv, "--baseline-cache", str(tmp_path / "absent.json")])
    out, err = capsys.readouterr()
    return code, out, err


def test_the_rule_reads_the_baseline_from_the_table_without_its_cache(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    code, out, err = _read_against_the_table(tmp_path, capsys, monkeypatch, _Row(12, 300, 0.30))
    assert code == 0 and not err
    assert "| unseen | 300 | 13 (46%) | 12 (30%) |" in out and out.rstrip().endswith("| pass |")


def test_a_reading_the_tables_rounding_could_flip_is_undecided(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    # 5 points under the rounded 46%: a pass at 46.0%, undecided at 45.5%
    code, out, _ = _read_against_the_table(tmp_path, capsys, monkeypatch, _Row(12, 300, 0.41))
    assert code == 0 and "undecided (the baseline's takeover is rounded: pass / undecided)" in out


def test_a_table_without_the_baseline_row_is_one_error_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    import experiments.generalisation_rule as rule

    table = tmp_path / "generalisation.md"
    table.write_text(TABLE)
    monkeypatch.setattr(rule, "generalisation_table", lambda *args, **kwargs: [_Row(1, 100, 0.3)])
    argv = ["--candidate", "runs/c", "--candidate-cache", str(tmp_path / "c.json"), "--baseline-table", str(table)]
    assert main([*argv, "--episodes", "100"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no unseen gate row of 100 episodes" in err[0]
