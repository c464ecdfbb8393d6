"""experiments/cycles_ledger.py: a cycles run's folder read into one row, each of issue 62's targets marked on its
means, the rows counted per ground, and folders that are not finished cycles runs left out by name."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from experiments import cycles_ledger as ledger


def _metric(mean: float, half: float = 0.0) -> dict[str, float | None]:
    return {"mean": mean, "ci95_half_width": half, "paper": None}


def _run_folder(
    root: Path,
    name: str,
    *,
    alone: float,
    takeover: tuple[float, float],
    change_half: float,
    static: tuple[float, float] | None,
    collision_cycles: list[float],
    changed: str = "",
    budget_scenario: str | None = None,
) -> Path:
    folder = root / name
    folder.mkdir(parents=True)
    metrics = {
        "alone_success_last": _metric(alone),
        "unseen_success_last": _metric(0.5),
        "takeover_first": _metric(takeover[0]),
        "takeover_last": _metric(takeover[1]),
        "takeover_change": _metric(takeover[1] - takeover[0], change_half),
    }
    if static is not None:
        metrics["static_success_first"] = _metric(static[0])
        metrics["static_success_last"] = _metric(static[1])
    summary = {"study": "cycles", "commit": "abc1234", "rows": [{"method": "sage", "seeds": 5, "metrics": metrics}]}
    (folder / "summary.json").write_text(json.dumps(summary))
    on = f" on ugv scenario {budget_scenario}" if budget_scenario else ""
    table = (
        f"Budget `small` (9 cycles{on}; each cycle's version alone), commit `abc1234`, wall time 12.1 min on the CPU "
        "(AMD EPYC).\n\n"
        + (f"- Settings changed from the study's defaults: {changed}.\n" if changed else "")
        + "- Before its trials, this host's reference speed: 883 UGV steps/s with the scripted expert and 94.4 SAC "
        "updates/s (batch 256, one thread).\n"
    )
    (folder / "table.md").write_text(table)
    seeds = ["method,seed,collision_cycles_above_first"] + [f"sage,{i},{c}" for i, c in enumerate(collision_cycles)]
    (folder / "seeds.csv").write_text("\n".join(seeds) + "\n")
    return folder


def test_a_run_that_meets_every_target_and_one_that_misses_each(tmp_path: Path) -> None:
    good = ledger.read_run(
        _run_folder(
            tmp_path,
            "cycles-good",
            alone=0.92,
            takeover=(0.34, 0.05),
            change_half=0.1,
            static=(1.0, 1.0),
            collision_cycles=[0, 0, 0, 0, 0],
            changed="scenario=4",
        )
    )
    assert good is not None and good.ground == "UGV 4" and good.changed == "scenario=4"
    assert good.host == "AMD EPYC, 94.4 SAC updates/s" and good.collision_cycles == 0
    assert good.meets() == {"A": True, "T": True, "C": True, "S": True}

    bad = ledger.read_run(
        _run_folder(
            tmp_path,
            "cycles-bad",
            alone=0.88,
            # At the target but the change's interval reaches 0: not decidedly below the first.
            takeover=(0.20, 0.10),
            change_half=0.15,
            static=(1.0, 0.95),
            collision_cycles=[0, 1, 0, 0, 0],
        )
    )
    assert bad is not None and bad.ground == "UGV 3" and bad.changed == ""
    assert bad.meets() == {"A": False, "T": False, "C": False, "S": False}


def test_a_field_run_without_static_scenarios_is_marked_unmeasured(tmp_path: Path) -> None:
    run = ledger.read_run(
        _run_folder(
            tmp_path,
            "cycles-field",
            alone=1.0,
            takeover=(0.30, 0.45),
            change_half=0.05,
            static=None,
            collision_cycles=[0, 0, 0],
            budget_scenario="ugv-fields:test:1",
        )
    )
    assert run is not None and run.ground == "ugv-fields:test:1" and math.isnan(run.static_last)
    assert run.meets() == {"A": True, "T": False, "C": True, "S": None}


def test_the_ledger_counts_per_ground_and_names_the_unfinished_folders(tmp_path: Path) -> None:
    results = tmp_path / "results"
    _run_folder(results, "cycles-a", alone=0.95, takeover=(0.3, 0.05), change_half=0.1, static=(1.0, 1.0),
                collision_cycles=[0, 0])  # fmt: skip
    _run_folder(results, "cycles-b", alone=0.80, takeover=(0.3, 0.05), change_half=0.1, static=(1.0, 0.9),
                collision_cycles=[1, 0])  # fmt: skip
    _run_folder(results, "cycles-c", alone=0.95, takeover=(0.3, 0.02), change_half=0.1, static=(1.0, 0.9),
                collision_cycles=[0, 0], changed="scenario=4")  # fmt: skip
    (results / "cycles-stopped").mkdir()
    (results / "cycles-stopped" / "trials").mkdir()
    out = tmp_path / "docs" / "ledger.md"
    ledger.main(["--results", str(results), "--out", str(out)])
    text = out.read_text()
    assert "| UGV 3 | 2 | 1 | 2 | 1 | 1 | 1 |" in text
    assert "| UGV 4 | 1 | 1 | 1 | 1 | 0 | 0 |" in text
    assert "not in the rows: cycles-stopped." in text
    assert "[cycles-a](../results/cycles-a/table.md)" in text


def test_no_finished_run_is_a_clear_error(tmp_path: Path) -> None:
    (tmp_path / "cycles-empty").mkdir()
    with pytest.raises(SystemExit, match="no finished cycles runs"):
        ledger.main(["--results", str(tmp_path), "--out", str(tmp_path / "x.md")])
