"""experiments/fear_budget.py's comparison of two results folders: per-seed outcomes averaged over the rows, the
heading it is given, Welch's test."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from experiments import fear_budget


def _folder(root: Path, name: str, collisions: dict[int, tuple[float, float]], commit: str) -> Path:
    folder = root / name
    folder.mkdir()
    lines = ["split,method,condition,seed,collision_rate_pct"]
    for seed, (normal, adversarial) in collisions.items():
        lines += [f"train,sage,normal,{seed},{normal}", f"train,sage,adversarial,{seed},{adversarial}"]
        lines.append(f"train,sac,normal,{seed},99")  # another method's rows stay out
    (folder / "seeds.csv").write_text("\n".join(lines) + "\n")
    (folder / "summary.json").write_text(json.dumps({"study": "highway", "commit": commit}))
    return folder


def test_two_folders_compared_per_seed_under_the_heading_given(tmp_path: Path) -> None:
    arm = _folder(tmp_path, "arm", {0: (30, 50), 1: (20, 40), 2: (40, 40)}, "bbbbbbb")
    control = _folder(tmp_path, "control", {0: (10, 30), 1: (0, 20), 2: (10, 30)}, "aaaaaaa")
    text = fear_budget.report(arm, control, "sage", ("collision_rate_pct",), title="the expert, two commits")
    assert text.startswith("### highway: the expert, two commits")
    assert "--title 'the expert, two commits'" in text and "arm at commit bbbbbbb, control at aaaaaaa" in text
    # per seed the mean of its two rows: arm 40, 30, 40; control 20, 10, 20; the run folders absent: –
    assert "| arm (arm) | 1 | – | – | – | – | 30 |" in text
    row = next(line for line in text.splitlines() if line.startswith("| collision_rate_pct"))
    assert row.startswith("| collision_rate_pct | 36.667") and float(row.split("|")[4]) < 0.05
    default = fear_budget.report(arm, control, "sage", ("collision_rate_pct",))
    assert "measured budget against a constant one" in default and "--title" not in default


def test_an_outcome_the_folders_lack_is_refused(tmp_path: Path) -> None:
    arm = _folder(tmp_path, "arm", {0: (1, 2)}, "b")
    with pytest.raises(ValueError, match="no success_rate_pct"):
        fear_budget.report(arm, arm, "sage", ("success_rate_pct",))
