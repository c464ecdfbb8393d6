"""experiments/live_session.py: the dashboard's loop and worker driven headless, end to end on a small budget (no
learning claim: 200 steps are too few for a round), and its paired test."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from experiments.live_session import (
    SessionLog,
    SessionPlan,
    main,
    mcnemar_exact,
    round_config,
    split_set,
    supervised_summary,
    takeover_bins,
)


def test_a_short_session_writes_its_report_with_every_field(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    argv = ["--steps", "200", "--speed", "20", "--alone-episodes", "2", "--alone-max-steps", "30"]
    argv += ["--work", str(tmp_path / "work"), "--out", str(out)]
    assert main(argv) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["command"].startswith("python -m experiments.live_session --steps 200")
    assert report["commit"] and report["commit"] != "unknown"
    assert report["steps"] >= 200 and report["session"]
    # the dashboard's worker ran beside the loop: v0000 is listed with its verdict, whatever was published since
    assert report["versions"][0]["number"] == 0 and report["versions"][0]["promoted"]
    assert report["published"] == len(report["versions"]) - 1
    assert report["worker"]["phase"] and report["finetune_config"]["adapt_as_sage"]
    assert sum(row["steps"] for row in report["takeover_bins"]) == report["steps"]
    assert all(0.0 <= row["takeover_share"] <= 1.0 for row in report["takeover_bins"])
    assert [c["scenario"] for c in report["comparison"]] == ["3", "4"]
    for c in report["comparison"]:
        assert c["episodes"] == 2 and 0 <= c["v0_success"] <= 2
        low, high = c["v0_interval"]
        assert 0.0 <= low <= high <= 1.0
    assert isinstance(report["target_met"], bool)
    text = (out / "report.md").read_text()
    assert "Command: `python -m experiments.live_session" in text and "| minute |" in text
    assert main(argv) == 2  # the work folder already holds a session: one line, no second session in it
    assert "already holds a session" in capsys.readouterr().err


def test_the_paired_test_counts_only_discordant_seeds() -> None:
    ours = [True] * 8 + [False] * 12
    theirs = [False] * 20
    result = mcnemar_exact(ours, theirs)
    assert (result["only_ours"], result["only_theirs"]) == (8, 0)
    assert result["p_two_sided"] == pytest.approx(2 / 2**8)  # 8 of 8 discordant pairs one way
    assert mcnemar_exact(theirs, theirs)["p_two_sided"] == 1.0
    assert mcnemar_exact([True, False], [False, True])["p_two_sided"] == 1.0


def test_takeover_bins_are_minutes_of_simulated_time() -> None:
    log = SessionLog(takeover=[True] * 300 + [False] * 900 + [True] * 50, version=[0] * 700 + [2] * 550)
    rows = takeover_bins(log, dt=0.1)
    assert [row["steps"] for row in rows] == [600, 600, 50]
    assert rows[0]["takeover_share"] == pytest.approx(0.5) and rows[1]["takeover_share"] == 0.0
    assert rows[1]["versions"] == [0, 2] and rows[2]["takeover_share"] == 1.0


def test_set_routes_learner_world_model_and_gate_settings_to_the_rounds_learner() -> None:
    finetune, learner = split_set(
        ["finetune.round_keep=1", "learner.fear_regularisation=false", "world_model.epochs=3", "gate.horizon=5"]
    )
    assert finetune == ("round_keep=1",)
    assert learner == ("fear_regularisation=false", "world_model_config.epochs=3", "gate.horizon=5")
    rounds = round_config(SessionPlan(finetune_settings=finetune[:1], learner_settings=learner[:1]))
    assert rounds.overrides == ("fear_regularisation=false",) and rounds.round_keep == 1.0
    with pytest.raises(ValueError, match="names no section"):
        split_set(["env.speed=2"])


@pytest.mark.parametrize(
    ("pair", "says"),
    [
        ("env.speed=2", "names no section"),
        ("learner.no_such_field=1", "unknown config field 'no_such_field'"),
        ("gate.no_such_field=1", "unknown config field 'gate.no_such_field'"),
        ("learner.imitation=perhaps", "cannot read 'perhaps'"),
        ("finetune.round_keep=7", "round_keep must be in"),
    ],
)
def test_a_bad_set_is_one_error_line_before_any_session(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], pair: str, says: str
) -> None:
    assert main(["--set", pair, "--work", str(tmp_path / "work"), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: --set") and says in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "work").exists()


def test_the_supervised_summary_is_of_the_fine_tuned_versions_judged() -> None:
    def row(number: int, share: float | None, hits: int | None) -> dict[str, object]:
        return {
            "number": number,
            "supervised_takeover": share,
            "supervised_collisions": hits,
            "supervised_episodes": 15,
        }

    summary = supervised_summary(
        [row(0, 0.36, 1), row(1, 0.10, 6), row(2, 0.02, 2), row(3, 0.30, 4), row(4, None, None)]
    )
    assert summary["fine_tuned_judged"] == 3 and (summary["v0_takeover"], summary["v0_collisions"]) == (0.36, 1)
    assert summary["takeover_median"] == pytest.approx(0.10) and summary["takeover_range"] == [0.02, 0.30]
    assert summary["collisions_median"] == 4 and summary["collisions_range"] == [2, 6]
    assert supervised_summary([row(0, 0.36, 1)])["takeover_median"] is None
