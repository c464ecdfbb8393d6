"""README results sections come from the results folders, replaced in place on every run."""

from __future__ import annotations

from pathlib import Path

import pytest

from studies.readme import HEADING, include, update_readme


def test_a_study_section_is_added_once_and_replaced_in_place(tmp_path: Path) -> None:
    readme = tmp_path / "README.md"
    readme.write_text("# Project\n\nintro\n")
    results = tmp_path / "results" / "toy-small"
    results.mkdir(parents=True)
    (results / "table.md").write_text("# toy, budget small, commit abc123\n\n| method | x |\n|---|---|\n| sage | 1 |\n")
    (results / "x.png").write_bytes(b"png")
    update_readme(readme, "toy", results)
    first = readme.read_text()
    assert first.count(HEADING) == 1 and "commit abc123" in first and "[x.png](results/toy-small/x.png)" in first
    (results / "table.md").write_text("# toy, budget small, commit def456\n\n| method | x |\n|---|---|\n| sage | 2 |\n")
    update_readme(readme, "toy", results)
    second = readme.read_text()
    assert second.count("<!-- results:toy -->") == 1 and "def456" in second and "abc123" not in second
    assert second.startswith("# Project\n\nintro\n")
    with pytest.raises(FileNotFoundError, match="sage study other"):
        update_readme(readme, "other", tmp_path / "nothing")


def test_a_generated_page_is_included_with_its_links_made_relative_to_the_readme(tmp_path: Path) -> None:
    readme = tmp_path / "README.md"
    readme.write_text("# Project\n\n<!-- calibration -->\nold\n<!-- /calibration -->\n\n## Speed\n")
    page = tmp_path / "docs" / "calibration" / "README.md"
    page.parent.mkdir(parents=True)
    page.write_text("# Calibration, commit abc\n\n![curve](p-3/operating_curve.png) [site](https://x.org/a)\n")
    include(readme, "calibration", page, "## Calibration")
    text = readme.read_text()
    assert "old" not in text and "### Calibration, commit abc" in text
    assert "![curve](docs/calibration/p-3/operating_curve.png)" in text and "(https://x.org/a)" in text
    assert text.endswith("<!-- /calibration -->\n\n## Speed\n") and "## Calibration\n" not in text


def test_publish_writes_the_report_and_its_readme_block(tmp_path: Path) -> None:
    from studies.readme import publish

    readme = tmp_path / "README.md"
    readme.write_text("# Project\n\n## Calibration of fear\n\n<!-- bench -->\nold\n<!-- /bench -->\n\n## After\n")
    out = tmp_path / "docs" / "bench"
    publish(["# A bench", "", "| a |", "|---|", "| 1 |"], out, readme, "bench", "## Calibration of fear")
    assert (out / "README.md").read_text() == "# A bench\n\n| a |\n|---|\n| 1 |\n"
    text = readme.read_text()
    assert "old" not in text and "### A bench" in text and text.index("| 1 |") < text.index("## After")
    publish(["# Again"], out, None, "bench", "## Calibration of fear")
    assert (out / "README.md").read_text() == "# Again\n" and "### A bench" in readme.read_text()
