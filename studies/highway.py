"""The paper's Waymo study on the highway pool: closed-loop adversarial training and the normal/adversarial table.

Training (CAT-style, closed loop). Before every training episode :class:`ClosedLoopAdversary` draws the
episode's mode (adversarial with probability ``adversarial_ratio``, else the logged replay) and points the
env's adversary at the current policy (``env.unwrapped.set_ego_predictor(runner.policy)``): an adversarial
reset rolls the policy as it is now through the scenario and resamples opponents towards risk around the
path it drives, so the adversaries follow the policy as it learns.

Evaluation. :func:`evaluate_policy` runs a policy once per scenario of a split, per mode and seed, through
:func:`studies.highway_evaluate.evaluate` with ``predictor="policy"`` (adversaries aimed at the evaluated policy), and
:func:`paper_table` prints the paper's layout: per run and set, success rate, collision rate, speed mean ± std
and acceleration mean ± std, normal and adversarial side by side.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, TypeVar, cast

import numpy as np

from core.loop import Policy, Runner
from core.report import aggregate

if TYPE_CHECKING:  # the highway sim is imported where it runs, not with this module
    from sims.highway.env import Mode
    from sims.highway.families import Split

MODES: tuple[Mode, ...] = ("normal", "adversarial")
SPLITS: tuple[Split, ...] = ("train", "test")
PAPER_COLUMNS: tuple[tuple[str, str], ...] = (
    ("success", "S.R.(%)"),
    ("collision", "C.R.(%)"),
    ("speed_mean", "Speed (m/s)"),
    ("acc_mean", "Acc. (m/s²)"),
)
"""The paper's table columns: metric key, heading."""
RATE_COLUMNS = frozenset({"success", "collision"})


@dataclass
class ClosedLoopAdversary:
    """A ``core.train`` episode hook: the episode's mode, and the adversary aimed at the current policy."""

    adversarial_ratio: float = 0.5
    """Probability that a training episode is an adversarial variant (else the logged replay)."""
    seed: int = 0
    modes: list[str] = field(default_factory=list)
    """The mode drawn for every episode so far (the metrics rows carry it too, as ``adversarial``)."""

    def __post_init__(self) -> None:
        if not 0.0 <= self.adversarial_ratio <= 1.0:
            raise ValueError(f"adversarial ratio must be in [0, 1], got {self.adversarial_ratio}")
        self.rng = np.random.default_rng(self.seed)

    def __call__(self, episode: int, runner: Runner) -> None:
        inner = runner.env.unwrapped
        setter = getattr(inner, "set_ego_predictor", None)
        if not callable(setter):
            raise TypeError(f"{type(inner).__name__} has no set_ego_predictor(): closed-loop adversaries need highway")
        mode = "adversarial" if self.rng.random() < self.adversarial_ratio else "normal"
        runner.set_next_reset_options({"mode": mode})
        setter(runner.policy)  # CAT: the resampling rolls the policy as it is now
        self.modes.append(mode)


_Choice = TypeVar("_Choice", bound=str)


def _parse_list(value: str | Sequence[str], allowed: Sequence[_Choice], what: str) -> list[_Choice]:
    items = [s.strip() for s in value.split(",")] if isinstance(value, str) else [str(s).strip() for s in value]
    items = [s for s in items if s]
    bad = [s for s in items if s not in allowed]
    if bad or not items:
        raise ValueError(f"{what} {', '.join(bad) or '(none)'}: choose from {', '.join(allowed)}")
    return cast(list[_Choice], items)  # every item is one of ``allowed`` (checked above)


def parse_sets(value: str | Sequence[str]) -> list[Split]:
    return _parse_list(value, SPLITS, "set")


def parse_modes(value: str | Sequence[str]) -> list[Mode]:
    return _parse_list(value, MODES, "mode")


def evaluate_policy(
    policy: Policy,
    sets: Iterable[Split] = ("test",),
    modes: Iterable[Mode] = MODES,
    episodes: int | None = None,
    seeds: Sequence[int] = (0,),
    on_episode: Callable[[dict[str, Any]], None] | None = None,
) -> dict[tuple[str, str], list[dict[str, Any]]]:
    """Rows per (set, mode), pooled over ``seeds``: one episode per scenario of the set (its first ``episodes``).

    The policy acts deterministically and alone (no gate, no expert), as the paper evaluates. In the adversarial
    mode the adversaries are aimed at this policy; the seed draws the adversarial resampling (normal replays are
    the same for every seed).
    """
    from studies.highway_evaluate import evaluate

    results: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for split in sets:
        for mode in modes:
            rows: list[dict[str, Any]] = []
            for seed in seeds:
                for row in evaluate(
                    policy,
                    split,
                    mode,
                    episodes=episodes,
                    seed=seed,
                    predictor="policy",
                    on_episode=on_episode,
                ):
                    rows.append(dict(row, seed=seed))
            results[(split, mode)] = rows
    return results


def _cell(column: str, mean: float, std: float, n: int) -> str:
    if n == 0 or not math.isfinite(mean):
        return "-"
    if column in RATE_COLUMNS:
        return f"{100.0 * mean:.1f}"
    return f"{mean:.2f} ± {std:.2f}"


def render(lines: Sequence[Sequence[str]]) -> str:
    """Plain-text columns, the first line a header underlined with dashes."""
    widths = [max(len(str(line[i])) for line in lines) for i in range(len(lines[0]))]
    text = []
    for k, line in enumerate(lines):
        text.append("  ".join(str(cell).ljust(w) for cell, w in zip(line, widths, strict=True)).rstrip())
        if k == 0:
            text.append("  ".join("-" * w for w in widths))
    return "\n".join(text)


def paper_table(results: Mapping[str, Mapping[tuple[str, str], Sequence[Mapping[str, Any]]]]) -> str:
    """The paper's table: one line per run and set, normal then adversarial columns (whichever were run).

    ``results``: run label -> (set, mode) -> rows. Rates are percentages of episodes; speed and acceleration
    are mean ± std over episodes of the per-episode means (acceleration: absolute longitudinal).
    """
    modes = [m for m in MODES if any(key[1] == m for runs in results.values() for key in runs)]
    header = ["Set", "Method", "N"]
    for mode in modes:
        header += [f"{mode} {title}" for _, title in PAPER_COLUMNS]
    lines = [header]
    for split in SPLITS:
        for label, runs in results.items():
            if not any(key[0] == split for key in runs):
                continue
            counts = {len(runs.get((split, m), ())) for m in modes}
            line = [split, label, "/".join(str(c) for c in sorted(counts))]
            for mode in modes:
                rows = runs.get((split, mode), [])
                agg = aggregate(rows, [c for c, _ in PAPER_COLUMNS])
                line += [_cell(c, *agg[c]) for c, _ in PAPER_COLUMNS]
            lines.append(line)
    return render(lines)


def interaction_table(results: Mapping[str, Mapping[tuple[str, str], Sequence[Mapping[str, Any]]]]) -> str:
    """What makes the adversarial set harder (the paper's Fig. waymo_1 b): gaps to the leader and time to collision."""
    columns = ("mean_gap", "min_ttc", "adversary_events", "off_road", "timeout")
    header = ["Set", "Method", "Mode", *columns]
    lines = [header]
    for label, runs in results.items():
        for (split, mode), rows in runs.items():
            agg = aggregate(rows, columns)
            cells = [
                f"{100 * agg[c][0]:.1f}%" if c in ("off_road", "timeout") and agg[c][2] else _cell(c, *agg[c])
                for c in columns
            ]
            lines.append([split, label, mode, *cells])
    return render(lines)


def runs_table(
    runs: Sequence[str], episodes: int, split: str, mode: str, seeds: Sequence[int], progress: bool = False
) -> tuple[str, list[dict[str, Any]]]:
    """``sage eval`` / ``compare`` on highway: the paper's table and the interaction table for run folders, and
    every episode row (tagged with its run). ``split`` and ``mode`` are comma lists; a bad one is a ValueError."""
    import functools
    from pathlib import Path

    from tqdm import tqdm

    from core.agents import load_agent
    from core.planners import is_planner, make_planner

    sets, modes = parse_sets(split), parse_modes(mode)
    results: dict[str, dict[tuple[str, str], list[dict[str, Any]]]] = {}
    all_rows: list[dict[str, Any]] = []
    total = len(runs) * len(sets) * len(modes) * len(seeds) * episodes
    with tqdm(total=total, desc="eval highway", unit="ep", disable=not progress, leave=False) as bar:
        for run in runs:
            if is_planner(str(run)):
                policy: Any = functools.partial(make_planner, str(run), sim="highway")
                label = str(run)
            else:
                policy = load_agent(run).policy
                path = Path(run)
                label = path.name if path.is_dir() else f"{path.parent.name}/{path.stem}"
            by_set = evaluate_policy(policy, sets, modes, episodes, seeds, on_episode=lambda _row: bar.update(1))
            results[label] = by_set
            all_rows += [dict(r, run=str(run)) for rows in by_set.values() for r in rows]
    return paper_table(results) + "\n\n" + interaction_table(results), all_rows
