"""The paper's reported numbers as data, so a study's table can print them beside ours.

Transcribed from the paper's LaTeX source (Table ``tab:test_results``, the Waymo normal / adversarial
evaluation). The paper reports speed and acceleration as mean ± standard deviation over episodes, and success
and collision rates as plain percentages; it does not say over how many seeds. Our tables report mean ± 95%
t-interval over training seeds, so the two are shown side by side, not compared as intervals.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class PaperCell:
    """One reported value: the mean and, where the paper gives one, its ± spread (standard deviation)."""

    mean: float
    spread: float | None = None

    def format(self) -> str:
        return f"{self.mean:g}" if self.spread is None else f"{self.mean:g} ± {self.spread:g}"


HIGHWAY_METRICS = ("success_rate_pct", "collision_rate_pct", "speed_mps", "acceleration_mps2")
"""Columns of the highway table, per condition (normal, adversarial)."""

# (split, method, condition) -> metric -> value; split is the paper's "Training Set" / "Testing Set".
_HIGHWAY_ROWS: dict[tuple[str, str], tuple[tuple[float, ...], tuple[float, ...]]] = {
    # (S.R., C.R., speed, speed sd, acc, acc sd) for normal, then adversarial
    ("train", "SAC"): ((73.9, 18.9, 9.42, 3.71, 1.34, 0.38), (51.7, 39.2, 8.64, 4.29, 1.76, 0.56)),
    ("train", "TD3"): ((75.8, 18.6, 9.57, 3.84, 1.42, 0.43), (48.8, 42.1, 8.77, 4.46, 1.89, 0.63)),
    ("train", "FNI-RL"): ((86.3, 9.8, 9.05, 3.62, 1.07, 0.29), (68.4, 24.7, 8.33, 4.08, 1.39, 0.42)),
    ("train", "SAGE-RL"): ((91.5, 4.8, 8.96, 3.48, 0.93, 0.22), (83.9, 9.1, 8.21, 3.91, 1.18, 0.33)),
    ("test", "SAC"): ((71.0, 21.2, 9.26, 3.92, 1.41, 0.42), (46.8, 43.8, 8.38, 4.51, 1.91, 0.64)),
    ("test", "TD3"): ((73.4, 20.6, 9.43, 4.03, 1.50, 0.47), (44.0, 46.6, 8.52, 4.67, 2.04, 0.72)),
    ("test", "FNI-RL"): ((83.8, 12.4, 8.87, 3.84, 1.15, 0.34), (63.8, 29.0, 8.07, 4.42, 1.52, 0.49)),
    ("test", "SAGE-RL"): ((88.4, 8.8, 8.79, 3.66, 1.01, 0.27), (79.6, 13.2, 7.94, 4.21, 1.29, 0.40)),
}


def _cells(row: tuple[float, ...]) -> dict[str, PaperCell]:
    sr, cr, speed, speed_sd, acc, acc_sd = row
    return {
        "success_rate_pct": PaperCell(sr),
        "collision_rate_pct": PaperCell(cr),
        "speed_mps": PaperCell(speed, speed_sd),
        "acceleration_mps2": PaperCell(acc, acc_sd),
    }


HIGHWAY: dict[tuple[str, str, str], dict[str, PaperCell]] = {
    (split, method, condition): _cells(row)
    for (split, method), rows in _HIGHWAY_ROWS.items()
    for condition, row in zip(("normal", "adversarial"), rows, strict=True)
}
"""Paper Table ``tab:test_results``: ``(split, method, condition) -> metric -> value``."""

PAPER_TABLES: dict[str, dict[tuple[str, ...], dict[str, PaperCell]]] = {"highway": dict(HIGHWAY)}
"""Each study's paper numbers by row key; a study without a numeric table in the paper has no entry."""

METHOD_ALIASES = {"sage": "SAGE-RL", "sac": "SAC", "td3": "TD3", "fni": "FNI-RL", "fni-rl": "FNI-RL"}
"""Our learner names -> the paper's method names."""


def paper_value(study: str, key: tuple[str, ...], metric: str) -> PaperCell | None:
    """The paper's number for ``metric`` in row ``key`` of ``study`` (``None`` where it reports none)."""
    table = PAPER_TABLES.get(study)
    if table is None:
        return None
    if len(key) >= 2:
        key = (key[0], METHOD_ALIASES.get(key[1].lower(), key[1]), *key[2:])
    return table.get(key, {}).get(metric)
