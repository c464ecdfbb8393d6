"""The README's summary of the generalisation document: made from the document's own sections."""

from __future__ import annotations

from pathlib import Path

import pytest

from studies.generalisation import GroundRow, render, write_section
from studies.generalisation_summary import anchor, parse, summary_table, update_readme


def row(ground: str, fear: float, tau: float, violation_rate: float | None, takeover: float = 0.25) -> GroundRow:
    gate = {"episodes": 300, "violation_rate": violation_rate, "takeover_rate": takeover} if violation_rate else {}
    return GroundRow(
        ground=ground,
        scenarios=["ugv-fields:test"] if ground.startswith("unseen") else ["1", "2"],
        episodes=300,
        steps=40000,
        violations=120,
        positives=900,
        fear_auroc=fear,
        cost_auroc=fear,
        sigma_auroc=0.8,
        curiosity_auroc=0.6,
        fire_before_violation=0.95,
        fire_elsewhere=0.3,
        curiosity_mean=0.05,
        tau_mean=tau,
        gate=gate,
    )


def section(sim: str, rows: list[GroundRow], commit: str) -> str:
    return render(rows, sim=sim, run=f"policies/{sim}-default", horizon_s=1.0, command="python -m x", commit=commit)


def test_the_summary_repeats_each_simulators_unseen_and_seen_rows_and_replaces_itself(tmp_path: Path) -> None:
    doc, readme = tmp_path / "docs" / "generalisation.md", tmp_path / "README.md"
    unseen = row("unseen (ugv-fields:test)", 0.916, 0.279, 9 / 300, 0.48)
    seen = row("seen (training scenarios)", 0.963, 0.349, 1 / 300, 0.27)
    write_section(doc, "ugv", section("ugv", [unseen, seen], "abc1234"))
    write_section(doc, "sumo", section("sumo", [row("unseen (sumo-shift:test)", 0.5, 0.2, None)], "def5678"))
    summaries = parse(doc.read_text())
    assert [s.sim for s in summaries] == ["ugv", "sumo"]
    ugv, sumo = summaries
    assert (ugv.unseen.fear_auroc, ugv.seen.fear_auroc if ugv.seen else None) == ("0.916", "0.963")
    assert (ugv.unseen.gate, ugv.unseen.takeover, ugv.unseen.tau) == ("9 of 300 [2%, 6%]", "48%", "0.2790")
    assert ugv.commit == "abc1234"
    assert sumo.seen is None and sumo.unseen.gate == "–"
    readme.write_text("# A project\n\n## Results\n\nprose\n")
    update_readme(readme, doc)
    update_readme(readme, doc)  # refreshed in place, not appended twice
    text = readme.read_text()
    assert text.count("<!-- generalisation -->") == 1 and text.startswith("# A project")
    ugv_line = next(line for line in text.splitlines() if line.startswith("| [ugv]"))
    assert f"(docs/generalisation.md#{anchor('ugv: policies/ugv-default')})" in ugv_line
    assert "0.916 (0.963)" in ugv_line and "9 of 300 [2%, 6%] at 48% (1 of 300 [0%, 2%] at 27%)" in ugv_line
    assert "0.2790 / 0.3490" in ugv_line and "`abc1234`" in ugv_line
    assert anchor("ugv: policies/ugv-default") == "ugv-policiesugv-default"


def test_the_committed_readme_holds_the_summary_of_the_committed_document() -> None:
    """The README's block is what the command makes from docs/generalisation.md as committed (no hand edits, no
    stale rows after the study wrote the document)."""
    from studies.generalisation_summary import DOC, KEY, summary_table
    from studies.readme import relative_link

    root = Path(__file__).resolve().parents[2]
    text = (root / "README.md").read_text()
    block = text.split(f"<!-- {KEY} -->\n", 1)[1].split(f"\n<!-- /{KEY} -->", 1)[0]
    assert block == summary_table((root / DOC).read_text(), relative_link(root / DOC, root / "README.md"))


def test_the_summary_reads_a_fresh_draw_of_the_test_seeds_where_the_document_holds_one(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from studies import generalisation

    doc, fresh_file = tmp_path / "generalisation.md", tmp_path / "fresh-ugv.md"
    unseen = row("unseen (ugv-fields:test)", 0.916, 0.279, 9 / 300, 0.48)
    write_section(doc, "ugv", section("ugv", [unseen, row("seen (training scenarios)", 0.963, 0.349, 1 / 300)], "a1"))
    write_section(doc, "sumo", section("sumo", [row("unseen (sumo-shift:test)", 0.97, 0.2, 19 / 300, 0.18)], "b2"))
    assert all(s.fresh is None for s in parse(doc.read_text()))  # none measured: no fresh figure, "–" in the README
    assert "| – |" in summary_table(doc.read_text(), "docs/generalisation.md").splitlines()[2]
    fresh_row = row("unseen (ugv-fields:test)", 0.889, 0.28, 21 / 300, 0.5)
    write_section(fresh_file, "ugv", section("ugv", [fresh_row], "c3"))
    monkeypatch.setattr(generalisation, "EXTRA_GROUNDS", {"ugv": [(generalisation.FRESH_TITLE, fresh_file)]})
    generalisation.attach_extras(doc, "ugv")
    ugv, sumo = parse(doc.read_text())
    assert ugv.fresh is not None and (ugv.fresh.gate, ugv.fresh.takeover) == ("21 of 300 [5%, 10%]", "50%")
    assert ugv.unseen.gate == "9 of 300 [2%, 6%]" and ugv.commit == "a1"  # the section's own row is unchanged
    assert sumo.fresh is None
    line = next(x for x in summary_table(doc.read_text(), "d.md").splitlines() if x.startswith("| [ugv]"))
    assert "| 21 of 300 [5%, 10%] at 50%, 0.889 |" in line
