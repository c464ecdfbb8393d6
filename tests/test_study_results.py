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
