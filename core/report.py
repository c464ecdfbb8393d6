"""Aggregate per-episode metric rows into the paper's tables (mean ± std, rates as percentages)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

RATE_KEYS = ("success", "collision", "timeout", "red_light", "off_road")
"""Binary per-episode outcomes, reported as a count and a percentage."""


def aggregate(rows: Sequence[Mapping[str, Any]], columns: Sequence[str]) -> dict[str, tuple[float, float, int]]:
    """For each column: (mean, std, n) over the rows that carry a finite value for it."""
    out: dict[str, tuple[float, float, int]] = {}
    for col in columns:
        values = [float(r[col]) for r in rows if col in r and r[col] is not None and math.isfinite(float(r[col]))]
        if values:
            out[col] = (float(np.mean(values)), float(np.std(values)), len(values))
        else:
            out[col] = (math.nan, math.nan, 0)
    return out


def format_cell(col: str, mean: float, std: float, n: int) -> str:
    if n == 0:
        return "-"
    if col in RATE_KEYS:
        return f"{round(mean * n)}/{n} ({100 * mean:.0f}%)"
    return f"{mean:.3f} ± {std:.3f}"


def format_table(named_rows: Mapping[str, Sequence[Mapping[str, Any]]], columns: Sequence[str]) -> str:
    """A plain-text table: one line per name (method, run, scenario), one column per metric."""
    header = ["", *columns]
    lines = [header]
    for name, rows in named_rows.items():
        agg = aggregate(rows, columns)
        lines.append([name, *(format_cell(c, *agg[c]) for c in columns)])
    widths = [max(len(str(line[i])) for line in lines) for i in range(len(header))]
    text = []
    for k, line in enumerate(lines):
        text.append("  ".join(str(cell).ljust(w) for cell, w in zip(line, widths, strict=True)).rstrip())
        if k == 0:
            text.append("  ".join("-" * w for w in widths))
    return "\n".join(text)
