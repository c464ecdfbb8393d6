"""The README's summary of ``docs/generalisation.md``: one row per simulator, unseen against seen ground.

Made from the generalisation document itself (each simulator's section as :func:`studies.generalisation.render`
wrote it), so that the README repeats what the document measured and nothing typed by hand:

- fear's AUROC for "a violation within the label's horizon" on the unseen ground, and on the seen ground;
- the gate with the scripted expert on the unseen ground: episodes with a violation and the takeover rate (and on
  the seen ground);
- curiosity's AUROC for telling an unseen step from a seen one, and the mean τ on each ground (the threshold falls
  where curiosity rises);
- the episodes a ground and the commit its section was measured at;
- the unseen ground again on a fresh draw of its test seeds (the section's extra ground titled :data:`FRESH_TITLE`),
  where the document holds one: a block of seeds no adoption rule or choice has read.

``python -m studies.generalisation`` refreshes the block whenever it writes the project's document;
``python -m studies.generalisation_summary`` refreshes it alone.
"""

from __future__ import annotations

import argparse
import re
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from studies.readme import replace_block

README = Path("README.md")
DOC = Path("docs/generalisation.md")
KEY = "generalisation"
"""The README's block: between ``<!-- generalisation -->`` and ``<!-- /generalisation -->``."""
HEADING = "## Results"
FRESH_TITLE = "A fresh draw of the test seeds (from 11,000,000), which no choice has read"
"""The title of each simulator's extra ground measured on ``studies.generalisation.FRESH_SEED``'s block (defined here,
where the summary reads it; the generator attaches the subsection under it)."""
COMMAND = "python -m studies.generalisation_summary"

_SECTION = re.compile(r"^## (?P<sim>[^:\n]+): (?P<run>.+)$", re.MULTILINE)
_MADE_BY = re.compile(r"at commit `(?P<commit>[0-9a-f]+)`")
_NOVELTY = re.compile(r"Telling a step on unseen ground.*?: curiosity (?P<auroc>[0-9.]+|–)")


@dataclass
class Ground:
    """The cells of one ground's row that the summary shows."""

    episodes: str
    fear_auroc: str
    tau: str
    gate: str
    takeover: str


@dataclass
class SimSummary:
    sim: str
    heading: str
    unseen_name: str
    unseen: Ground
    seen: Ground | None
    curiosity_auroc: str
    commit: str
    fresh: Ground | None = None
    """The unseen ground on a fresh draw of its test seeds (the section's subsection of that title), if measured."""


def anchor(heading: str) -> str:
    """The anchor a markdown renderer (GitHub's) gives a heading: lower case, punctuation dropped, spaces to '-'."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def _cells(line: str) -> list[str]:
    return [cell.strip() for cell in line.strip().strip("|").split("|")]


def _ground(cells: list[str]) -> Ground:
    # the columns of studies.generalisation._table
    episodes = cells[2].split(" ")[0]
    fear = cells[4].split(" ")[0]
    gate = cells[9]
    if gate != "–":  # "9 of 300 (3%) [2%, 6%]": the count and the interval
        count, _, rest = gate.partition(" (")
        interval = rest.partition(") ")[2]
        gate = f"{count} {interval}".strip()
    return Ground(episodes, fear, cells[8], gate, cells[10])


def parse(doc_text: str) -> list[SimSummary]:
    """Every simulator section of the document with an unseen row, in the document's order."""
    summaries = []
    matches = list(_SECTION.finditer(doc_text))
    for i, match in enumerate(matches):
        body = doc_text[match.end() : matches[i + 1].start() if i + 1 < len(matches) else len(doc_text)]
        fresh = _fresh_row(body)
        body = body.split("\n### ", 1)[0]  # the section's own table, not its subsections
        rows = [_cells(line) for line in body.splitlines() if line.startswith("| unseen") or line.startswith("| seen")]
        unseen = next((r for r in rows if r[0].startswith("unseen")), None)
        if unseen is None or len(unseen) < 11:
            continue
        seen = next((r for r in rows if r[0].startswith("seen") and len(r) >= 11), None)
        commit = _MADE_BY.search(body)
        novelty = _NOVELTY.search(body)
        summaries.append(
            SimSummary(
                sim=match["sim"].strip(),
                heading=f"{match['sim']}: {match['run']}",
                unseen_name=unseen[1],
                unseen=_ground(unseen),
                seen=None if seen is None else _ground(seen),
                curiosity_auroc=novelty["auroc"] if novelty else "–",
                commit=commit["commit"] if commit else "–",
                fresh=fresh,
            )
        )
    return summaries


def _fresh_row(body: str) -> Ground | None:
    """The unseen row of the section's fresh-draw subsection (:data:`FRESH_TITLE`), None where it has none."""
    head = f"\n### {FRESH_TITLE}"
    if head not in body:
        return None
    sub = body.split(head, 1)[1].split("\n### ", 1)[0]
    row = next((_cells(line) for line in sub.splitlines() if line.startswith("| unseen")), None)
    return None if row is None or len(row) < 11 else _ground(row)


def summary_table(doc_text: str, doc_link: str) -> str:
    """The README block's markdown: a table of :func:`parse`'s rows and the line that says where it comes from."""
    lines = [
        "| simulator | unseen ground (test seeds) | fear AUROC, unseen (seen) "
        "| gate + expert, unseen: episodes with a violation [95%] at takeover (seen) "
        "| the same on a fresh draw of the test seeds, fear AUROC "
        "| curiosity AUROC, an unseen step against a seen one | τ unseen / seen "
        "| episodes a ground, driving alone | commit |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for s in parse(doc_text):
        seen = s.seen
        fear = s.unseen.fear_auroc + (f" ({seen.fear_auroc})" if seen else "")
        gate = f"{s.unseen.gate} at {s.unseen.takeover}" if s.unseen.gate != "–" else "–"
        if seen and seen.gate != "–":
            gate += f" ({seen.gate} at {seen.takeover})"
        tau = s.unseen.tau + (f" / {seen.tau}" if seen else "")
        fresh = "–"
        if s.fresh is not None and s.fresh.gate != "–":
            fresh = f"{s.fresh.gate} at {s.fresh.takeover}, {s.fresh.fear_auroc}"
        link = f"[{s.sim}]({doc_link}#{anchor(s.heading)})"
        lines.append(
            f"| {link} | `{s.unseen_name}` | {fear} | {gate} | {fresh} | {s.curiosity_auroc} | {tau} "
            f"| {s.unseen.episodes} | `{s.commit}` |"
        )
    lines += [
        "",
        f"Generated by `{COMMAND}` (and by every `python -m studies.generalisation` that writes the document) from "
        f"[{DOC.name}]({doc_link}): the label is a violation within 1 s; AUROC 0.5 is chance; the gate rows are the "
        "policy with its own gate and the scripted expert; the fresh draw (episode seeds from 11,000,000) is a block "
        "of seeds that no rule or choice has read, where every other unseen figure is on the block the adoptions "
        "read.",
    ]
    return "\n".join(lines)


def update_readme(readme: Path = README, doc: Path = DOC) -> None:
    """Write :func:`summary_table` of ``doc`` into ``readme``'s block (links relative to the README)."""
    if not doc.is_file():
        raise FileNotFoundError(f"{doc} does not exist: run `python -m studies.generalisation` first")
    from studies.readme import relative_link

    replace_block(readme, KEY, summary_table(doc.read_text(), relative_link(doc, readme)), HEADING)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=COMMAND, description=__doc__.split("\n\n")[0])
    parser.add_argument("--doc", type=Path, default=DOC, help="default: %(default)s")
    parser.add_argument("--readme", type=Path, default=README, help="default: %(default)s")
    args = parser.parse_args(argv)
    try:
        update_readme(args.readme, args.doc)
    except FileNotFoundError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"the generalisation summary of {args.doc} written into {args.readme}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
