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

UGV_METRICS = ("success_rate_pct", "avg_speed", "travel_distance", "path_curvature", "lateral_acc")
"""Columns of the UGV field-test table (success rate %, m/s, m, 1/m, m/s²)."""

# Paper Table ``tab:all_scenarios_results`` (four real indoor scenarios, 20 trials each): scenario -> method ->
# (successes of 20, speed, speed sd, distance, distance sd, curvature, curvature sd, lateral acc, lateral acc sd).
# The paper's "Proposed" row is SAGE-RL.
_UGV_ROWS: dict[str, dict[str, tuple[float, ...]]] = {
    "1": {
        "TEB": (20, 0.39, 0.02, 8.62, 0.19, 0.489, 0.03, 0.370, 0.01),
        "SAC": (13, 0.40, 0.04, 7.62, 1.46, 0.560, 0.15, 0.443, 0.10),
        "TD3": (12, 0.41, 0.03, 7.49, 1.48, 0.493, 0.08, 0.438, 0.09),
        "HG-DAgger": (20, 0.46, 0.05, 7.93, 0.20, 0.487, 0.09, 0.407, 0.04),
        "Diffusion-BC": (14, 0.40, 0.04, 7.21, 1.44, 0.503, 0.04, 0.405, 0.03),
        "Diffusion-QL": (16, 0.42, 0.04, 7.34, 0.81, 0.485, 0.08, 0.393, 0.06),
        "Multi-Hug RL": (20, 0.42, 0.03, 8.07, 0.22, 0.505, 0.08, 0.396, 0.04),
        "SAGE-RL": (20, 0.44, 0.04, 7.65, 0.13, 0.472, 0.09, 0.352, 0.04),
    },
    "2": {
        "TEB": (20, 0.29, 0.02, 7.52, 0.14, 0.741, 0.04, 0.409, 0.02),
        "SAC": (12, 0.41, 0.04, 5.16, 1.16, 0.608, 0.17, 0.551, 0.13),
        "TD3": (8, 0.40, 0.08, 4.92, 1.25, 0.558, 0.11, 0.479, 0.08),
        "HG-DAgger": (17, 0.38, 0.05, 6.09, 1.03, 0.662, 0.07, 0.493, 0.04),
        "Diffusion-BC": (4, 0.33, 0.06, 4.22, 1.84, 0.442, 0.08, 0.428, 0.03),
        "Diffusion-QL": (10, 0.32, 0.04, 4.97, 1.26, 0.562, 0.09, 0.524, 0.06),
        "Multi-Hug RL": (16, 0.36, 0.04, 5.66, 0.64, 0.696, 0.08, 0.592, 0.04),
        "SAGE-RL": (20, 0.35, 0.03, 5.77, 0.14, 0.642, 0.10, 0.508, 0.06),
    },
    "3": {
        "TEB": (8, 0.28, 0.02, 5.01, 1.47, 0.663, 0.17, 0.369, 0.03),
        "SAC": (11, 0.46, 0.04, 5.31, 0.67, 0.664, 0.11, 0.440, 0.06),
        "TD3": (11, 0.45, 0.04, 5.03, 1.30, 0.606, 0.08, 0.391, 0.05),
        "HG-DAgger": (16, 0.40, 0.05, 5.80, 0.67, 0.653, 0.13, 0.380, 0.03),
        "Diffusion-BC": (8, 0.34, 0.05, 5.41, 0.89, 0.588, 0.14, 0.367, 0.04),
        "Diffusion-QL": (10, 0.37, 0.03, 5.60, 1.34, 0.633, 0.13, 0.357, 0.04),
        "Multi-Hug RL": (15, 0.44, 0.04, 6.15, 1.34, 0.587, 0.05, 0.380, 0.04),
        "SAGE-RL": (20, 0.43, 0.02, 6.21, 0.09, 0.535, 0.04, 0.356, 0.02),
    },
    "4": {
        "TEB": (10, 0.33, 0.03, 5.72, 1.50, 0.625, 0.22, 0.394, 0.05),
        "SAC": (11, 0.49, 0.06, 5.02, 0.71, 0.632, 0.14, 0.482, 0.06),
        "TD3": (9, 0.51, 0.03, 5.06, 0.42, 0.619, 0.08, 0.451, 0.09),
        "HG-DAgger": (17, 0.35, 0.02, 5.58, 0.55, 0.741, 0.13, 0.348, 0.04),
        "Diffusion-BC": (7, 0.36, 0.04, 5.41, 1.01, 0.677, 0.12, 0.352, 0.07),
        "Diffusion-QL": (12, 0.34, 0.04, 5.25, 1.14, 0.669, 0.11, 0.354, 0.05),
        "Multi-Hug RL": (16, 0.38, 0.03, 6.02, 0.77, 0.622, 0.11, 0.421, 0.04),
        "SAGE-RL": (20, 0.46, 0.03, 6.14, 0.12, 0.615, 0.11, 0.367, 0.06),
    },
}


def _ugv_cells(row: tuple[float, ...]) -> dict[str, PaperCell]:
    wins, speed, speed_sd, dist, dist_sd, curv, curv_sd, lat, lat_sd = row
    return {
        "success_rate_pct": PaperCell(100.0 * wins / 20.0),
        "avg_speed": PaperCell(speed, speed_sd),
        "travel_distance": PaperCell(dist, dist_sd),
        "path_curvature": PaperCell(curv, curv_sd),
        "lateral_acc": PaperCell(lat, lat_sd),
    }


UGV: dict[tuple[str, str], dict[str, PaperCell]] = {
    (scenario, method): _ugv_cells(row) for scenario, rows in _UGV_ROWS.items() for method, row in rows.items()
}
"""Paper Table ``tab:all_scenarios_results``: ``(scenario, method) -> metric -> value``."""

# copied key by key: a dict's key type is invariant, so dict(HIGHWAY) would stay keyed by 3-tuples only
PAPER_TABLES: dict[str, dict[tuple[str, ...], dict[str, PaperCell]]] = {
    "highway": {key: row for key, row in HIGHWAY.items()},
    "ugv": {key: row for key, row in UGV.items()},
}
"""Each study's paper numbers by row key; a study without a numeric table in the paper has no entry."""

METHOD_ALIASES = {
    "sage": "SAGE-RL",
    "sac": "SAC",
    "td3": "TD3",
    "fni": "FNI-RL",
    "fni-rl": "FNI-RL",
    "hg-dagger": "HG-DAgger",
    "teb": "TEB",
    "diffusion-bc": "Diffusion-BC",
    "diffusion-ql": "Diffusion-QL",
    "multi-hug": "Multi-Hug RL",
}
"""Our learner names -> the paper's method names."""


def paper_value(study: str, key: tuple[str, ...], metric: str) -> PaperCell | None:
    """The paper's number for ``metric`` in row ``key`` of ``study`` (``None`` where it reports none)."""
    table = PAPER_TABLES.get(study)
    if table is None:
        return None
    if len(key) >= 2:
        key = (key[0], METHOD_ALIASES.get(key[1].lower(), key[1]), *key[2:])
    return table.get(key, {}).get(metric)
