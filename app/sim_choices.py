"""What the dashboard's scenario picker offers for each simulator, and how a choice builds the env.

Each simulator names its variants differently (the UGV takes ``scenario=1..4``, highway a ``split`` and a
``mode``, SUMO a ``route``), so the page shows numbered choices and this table turns a number into the
keyword arguments of ``sims.make``. A simulator missing here gets ``scenario=<number>`` passed through.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class ScenarioChoice:
    id: int
    label: str
    kwargs: dict[str, Any] = field(default_factory=dict)


SCENARIO_CHOICES: dict[str, list[ScenarioChoice]] = {
    "ugv": [
        ScenarioChoice(1, "1 · narrow passage", {"scenario": 1}),
        ScenarioChoice(2, "2 · detour", {"scenario": 2}),
        ScenarioChoice(3, "3 · crossing", {"scenario": 3}),
        ScenarioChoice(4, "4 · cut-in", {"scenario": 4}),
    ],
    "highway": [
        ScenarioChoice(1, "test logs · normal", {"split": "test", "mode": "normal"}),
        ScenarioChoice(2, "test logs · adversarial", {"split": "test", "mode": "adversarial"}),
        ScenarioChoice(3, "train logs · normal", {"split": "train", "mode": "normal"}),
        ScenarioChoice(4, "train logs · adversarial", {"split": "train", "mode": "adversarial"}),
    ],
    "sumo": [
        ScenarioChoice(1, "route 1", {"route": 1}),
        ScenarioChoice(2, "route 2 (route shift)", {"route": 2}),
        ScenarioChoice(3, "route 1 · special vehicles", {"route": 1, "special_vehicles": True}),
    ],
}


def make_kwargs(sim: str, scenario: int | None) -> dict[str, Any]:
    """Keyword arguments for ``sims.make(sim, ...)`` for the picked scenario number."""
    if scenario is None:
        return {}
    for choice in SCENARIO_CHOICES.get(sim, []):
        if choice.id == scenario:
            return dict(choice.kwargs)
    if sim in SCENARIO_CHOICES:
        known = ", ".join(str(c.id) for c in SCENARIO_CHOICES[sim])
        raise ValueError(f"{sim} has no scenario {scenario}; choose one of {known}")
    return {"scenario": scenario}


def listed(sim: str) -> list[dict[str, Any]]:
    return [{"id": c.id, "label": c.label} for c in SCENARIO_CHOICES.get(sim, [])]
