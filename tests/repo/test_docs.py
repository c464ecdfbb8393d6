"""The documents a newcomer reads: a short README whose links resolve, generated tables that are what their
generators write from the committed folders, and a bench/ of speed benchmarks only."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from studies.readme import SUMMARY_KEY, included, section, summary_table

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
RESULTS_DOC = ROOT / "docs" / "results.md"
CALIBRATION_DOC = ROOT / "docs" / "calibration.md"
LINKED = [README, ROOT / "ARCHITECTURE.md", *sorted((ROOT / "docs").glob("*.md")), ROOT / "experiments" / "README.md"]
SPEED_BENCHES = {
    "bench_baselines.py",
    "bench_ego_kernel.py",  # the compiled contact test at a commit against now
    "bench_finetune.py",
    "bench_gate.py",
    "gate_side_by_side.py",  # the deployed gate with the code at a commit against now, one process per core
    "gpu_check.py",  # the CPU-vs-GPU update ratios, for a session with a GPU
    "bench_highway.py",
    "bench_pedestrian.py",
    "bench_replay.py",  # the buffer's reads per update, kept indices against scans
    "bench_sac.py",
    "bench_server.py",
    "bench_sumo.py",
    "bench_ugv.py",
}
"""What bench/ holds: speed and memory benchmarks. An investigation (arms compared, a report written into a
document) belongs in experiments/."""

_LINK = re.compile(r"\]\(([^)\s]+)\)")


_BLOCK = re.compile(r"<!-- (?P<key>[^/ ][^ ]*) -->\n(?P<body>.*?)\n<!-- /(?P=key) -->", re.DOTALL)


def _blocks(text: str) -> dict[str, str]:
    return {m["key"]: m["body"] for m in _BLOCK.finditer(text)}


def _prose_words(markdown: str) -> int:
    """Words a reader reads line by line: outside code blocks, tables and comments (a table is scanned, not read)."""
    prose = re.sub(r"```.*?```", "", markdown, flags=re.DOTALL)
    lines = [line for line in prose.splitlines() if not line.lstrip().startswith(("|", "<!--"))]
    return sum(len(line.split()) for line in lines)


def test_the_readme_is_short_enough_to_read_in_five_minutes() -> None:
    text = README.read_text()
    # about 200-250 words a minute, with the tables and commands scanned besides
    assert _prose_words(text) <= 1000
    assert len(text.splitlines()) <= 200


def test_prose_words_skip_code_tables_and_comments() -> None:
    text = "one two\n```bash\nthree four\n```\n| five | six |\n<!-- seven -->\neight"
    assert _prose_words(text) == 3


@pytest.mark.parametrize("document", LINKED, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_every_relative_link_and_image_resolves(document: Path) -> None:
    broken = []
    for target in _LINK.findall(document.read_text()):
        if re.match(r"[a-z]+:|#|/", target):
            continue
        if not (document.parent / target.split("#", 1)[0]).exists():
            broken.append(target)
    assert not broken, f"{document.relative_to(ROOT)} links to what is not there: {broken}"


def test_the_readme_summary_is_what_its_generator_makes_from_the_results_document() -> None:
    block = _blocks(README.read_text())[SUMMARY_KEY]
    assert block == summary_table(RESULTS_DOC, README), "run `python -m studies.readme` to refresh the summary"


def test_every_study_table_is_what_its_results_folder_writes() -> None:
    blocks = {key.removeprefix("results:"): body for key, body in _blocks(RESULTS_DOC.read_text()).items()}
    assert len(blocks) >= 5
    for name, body in blocks.items():
        folder = re.search(r"^Results folder: \[`[^`]*`\]\(([^)]+)\)", body, re.MULTILINE)
        assert folder, name
        assert body == f"### {name}\n\n{section(name, RESULTS_DOC.parent / folder[1], RESULTS_DOC)}", name


def test_every_calibration_table_is_a_committed_report_as_included() -> None:
    reports = sorted((ROOT / "docs" / "notes").glob("*/README.md"))
    made = {included(CALIBRATION_DOC, report) for report in reports}
    blocks = _blocks(CALIBRATION_DOC.read_text())
    assert len(blocks) >= 5
    assert not [key for key, body in blocks.items() if body not in made]


def test_bench_holds_only_speed_benchmarks() -> None:
    scripts = {p.name for p in (ROOT / "bench").glob("*.py")}
    assert scripts <= SPEED_BENCHES, f"not a speed benchmark (move it to experiments/): {scripts - SPEED_BENCHES}"
    writers = [name for name in scripts if re.search(r"--readme|studies\.readme", (ROOT / "bench" / name).read_text())]
    assert not writers, f"these write reports into documents, which experiments do: {writers}"


def test_the_generalisation_tables_extra_grounds_are_what_the_generator_attaches(tmp_path: Path) -> None:
    from studies.generalisation import DEFAULT_OUT, EXTRA_GROUNDS, attach_extras

    committed = (ROOT / DEFAULT_OUT).read_text()
    made = tmp_path / "generalisation.md"
    made.write_text(committed)
    for sim in EXTRA_GROUNDS:
        attach_extras(made, sim, root=ROOT)
    assert made.read_text() == committed, "run `python -m studies.generalisation --sim ugv --extras-only`"
