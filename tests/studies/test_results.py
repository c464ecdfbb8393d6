"""The results folder: per-seed rows, mean ± CI table with the paper beside, summary, figures."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from studies.budgets import budget
from studies.results import write_results

ROWS = [
    {"split": "test", "method": method, "condition": "adversarial", "seed": seed, "collision_rate_pct": value}
    for method, values in (("sage", [10.0, 12.0, 14.0]), ("sac", [40.0, 44.0, 48.0]))
    for seed, value in enumerate(values)
]


def test_results_folder_has_rows_table_paper_and_figure(tmp_path: Path) -> None:
    table = write_results(
        tmp_path,
        "highway",
        ROWS,
        keys=("split", "method", "condition"),
        metrics=("collision_rate_pct",),
        budget=budget("smoke"),
        wall_s=90.0,
        commit="abc1234",
        plot=("collision_rate_pct",),
        notes=("full budget not run here: 2 cores",),
    )
    with (tmp_path / "seeds.csv").open() as f:
        assert len(list(csv.DictReader(f))) == 6
    text = table.read_text()
    # sage: mean 12, half-width t(2) * 2 / sqrt(3) = 4.303 * 1.1547 = 4.969; the paper's 13.2 beside it
    assert "| test | sage | adversarial | 3 | 12.000 ± 4.969 | 13.2 |" in text
    assert "| test | sac | adversarial | 3 | 44.000 ± 9.937 | 43.8 |" in text
    assert "commit `abc1234`" in text and "`smoke`" in text and "full budget not run here" in text
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["rows"][0]["metrics"]["collision_rate_pct"]["paper"]["mean"] == 13.2
    assert (tmp_path / "collision_rate_pct.png").stat().st_size > 1000


def test_rows_missing_a_metric_are_refused(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="lacks"):
        write_results(tmp_path, "highway", [{"method": "sage", "seed": 0}], ("method",), ("x",), budget("smoke"), 1.0)
    with pytest.raises(ValueError, match="no result rows"):
        write_results(tmp_path, "highway", [], ("method",), ("x",), budget("smoke"), 1.0)


def test_the_header_states_what_was_run_and_planner_rows_their_spread(tmp_path: Path) -> None:
    """A planner is not trained: its seeds only draw other evaluation episodes, and its row says so; a study that
    spends its budget otherwise (cycles) states what it ran instead of steps and evaluation episodes it never used."""
    rows = [
        {"method": method, "seed": seed, "success": value}
        for method, values in (("sage", [0.5, 0.7]), ("teb", [0.9, 1.0]))
        for seed, value in enumerate(values)
    ]
    text = write_results(
        tmp_path, "ugv", rows, ("method",), ("success",), budget("smoke"), 1.0, commit="abc", untrained=("teb",)
    ).read_text()
    assert "| sage | 2 |" in text and "| teb | 2 eval |" in text
    assert "teb: not trained" in text and "spread over evaluation episodes" in text
    from studies.cycles_study import STUDY as CYCLES

    assert CYCLES.budget_text is not None
    said = CYCLES.budget_text(budget("small"), CYCLES.settings)
    text = write_results(
        tmp_path, "cycles", rows[:2], ("method",), ("success",), budget("small"), 1.0, commit="abc", budget_text=said
    ).read_text()
    assert "9 cycles of 666 deployment steps per method and seed" in text  # 6,000 steps over 9 cycles
    # its evaluation episodes are the versions alone in every cycle, and the header says so
    assert "alone on 10 evaluation episodes of the scenario and of an unseen one" in text
    assert "6000 environment steps per method" not in text


def test_the_header_states_the_wall_time_and_the_device_or_that_it_was_not_recorded(tmp_path: Path) -> None:
    """A table says where it ran (summary.json too); a folder written before tables named the device says, in the
    results document, that it was not recorded, rather than nothing."""
    from studies.readme import section

    rows = [{"method": "sage", "seed": seed, "x": float(seed)} for seed in range(2)]
    text = write_results(
        tmp_path / "new", "toy", rows, ("method",), ("x",), budget("smoke"), 150.0, commit="abc", device="the CPU (Z80)"
    ).read_text()
    assert "commit `abc`, wall time 2.5 min on the CPU (Z80). " in text
    assert json.loads((tmp_path / "new" / "summary.json").read_text())["device"] == "the CPU (Z80)"
    doc = tmp_path / "results.md"
    assert "wall time 2.5 min on the CPU (Z80). " in section("toy", tmp_path / "new", doc)
    unknown = write_results(tmp_path / "unknown", "toy", rows, ("method",), ("x",), budget("smoke"), 150.0, commit="a")
    assert "wall time 2.5 min (device not recorded). " in unknown.read_text()
    old = tmp_path / "old"
    old.mkdir()
    (old / "table.md").write_text("# toy\n\nBudget `smoke` (...), commit `abc`, wall time 2.5 min. Paper columns ...\n")
    shown = section("toy", old, doc)
    assert "wall time 2.5 min (device not recorded). Paper columns" in shown and shown.count("not recorded") == 1


def test_a_metric_that_does_not_apply_is_shown_as_a_dash_and_a_partial_one_with_its_seeds(tmp_path: Path) -> None:
    nan = float("nan")
    rows = [
        *({"method": "sac", "seed": s, "takeover_change": nan, "collision": 0.5} for s in range(3)),
        *(
            {"method": "sage", "seed": s, "takeover_change": v, "collision": 0.2}
            for s, v in enumerate([-0.2, -0.4, nan])
        ),
    ]
    table = write_results(tmp_path, "route-shift", rows, ("method",), ("takeover_change", "collision"),
                          budget("smoke"), 1.0, commit="abc1234")  # fmt: skip
    lines = table.read_text().splitlines()
    sac = next(line for line in lines if line.startswith("| sac |"))
    sage = next(line for line in lines if line.startswith("| sage |"))
    assert sac.startswith("| sac | 3 | – | — | 0.500 ± 0.000 |")
    assert sage.startswith("| sage | 3 | -0.300 ± 1.271 (n=2) | — |")  # t(1) * 0.1414 = 12.706 * 0.1
