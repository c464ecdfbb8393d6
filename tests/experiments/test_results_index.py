"""experiments/results_index.py: every folder under results/ in one generated page, the README's headline folders
first, each with its section of docs/results.md and the scripts that name it; and the committed page lists every
folder that is there."""

from __future__ import annotations

import json
from pathlib import Path

from experiments import results_index

ROOT = Path(__file__).resolve().parents[2]


def _study_folder(root: Path, name: str, study: str, commit: str, changed: str = "") -> None:
    folder = root / name
    folder.mkdir(parents=True)
    summary = {"study": study, "budget": "small", "commit": commit, "wall_s": 90.0, "device": "the CPU (X)", "rows": []}
    (folder / "summary.json").write_text(json.dumps(summary))
    table = "Budget `small`.\n"
    if changed:
        table += f"- Settings changed from the study's defaults: {changed}.\n"
    (folder / "table.md").write_text(table)


def _section(name: str, folder: str) -> str:
    return (
        f"<!-- results:{name} -->\n### {name}\n\n| t |\n\n"
        f"Results folder: [`../results/{folder}`](../results/{folder}) (per-seed rows in `seeds.csv`).\n"
        f"<!-- /results:{name} -->\n"
    )


def test_the_page_sorts_headline_folders_arms_and_records(tmp_path: Path) -> None:
    results = tmp_path / "results"
    _study_folder(results, "cycles-small", "cycles", "aaaaaaa")
    _study_folder(results, "cycles-small-coach", "cycles", "bbbbbbb", changed="coach_share=1.0")
    _study_folder(results, "ugv-small", "ugv", "ccccccc")
    (results / "generalisation").mkdir()
    (results / "stopped-run" / "trials").mkdir(parents=True)
    # a script naming the longer folder must not count as naming its prefix
    (results / "arm.sh").write_text("sage study cycles --out results/cycles-small-coach\n")
    (results / "control.sh").write_text("sage study cycles --out results/cycles-small --section x\n")
    (results / "arm.log").write_text("")
    (results / "read.py").write_text("")
    doc = "<!-- readme-sections: cycles-defaults ugv -->\n" + _section("cycles-defaults", "cycles-small")
    doc += _section("cycles-coach", "cycles-small-coach") + _section("ugv", "ugv-small")

    folders, files = results_index.collect(results, doc)
    by_name = {f.name: f for f in folders}
    assert by_name["cycles-small"].headline and by_name["ugv-small"].headline
    assert not by_name["cycles-small-coach"].headline
    assert by_name["cycles-small"].scripts == ["control.sh"]
    assert by_name["cycles-small-coach"].scripts == ["arm.sh"]
    assert by_name["cycles-small-coach"].changed == "coach_share=1.0"
    assert not by_name["stopped-run"].finished and not by_name["generalisation"].finished

    page = results_index.render(folders, files, "cmd", "abc1234", "../docs/results.md")
    headline, arms = (
        page.index("## The README's headline folders (2)"),
        page.index("## cycles: arms and earlier runs (1)"),
    )
    assert headline < page.index("[cycles-small](cycles-small/)") < arms
    assert arms < page.index("[cycles-small-coach](cycles-small-coach/)")
    assert "[cycles-coach](../docs/results.md#cycles-coach)" in page
    assert "| 1.5 min | CPU (X) | coach_share=1.0 | [arm.sh](arm.sh) |" in page
    assert "## ugv:" not in page  # its only folder is a headline one
    assert "- [stopped-run](stopped-run/)" in page
    assert "`*.sh`, 2:" in page and "`*.log`, 1:" in page and "`*.py`, 1:" in page


def test_the_committed_page_lists_every_folder_under_results() -> None:
    page = (ROOT / "results" / "README.md").read_text()
    missing = [
        p.name for p in sorted((ROOT / "results").iterdir()) if p.is_dir() and f"[{p.name}]({p.name}/)" not in page
    ]
    assert not missing, f"results/README.md is stale: run `python -m experiments.results_index` ({missing})"
