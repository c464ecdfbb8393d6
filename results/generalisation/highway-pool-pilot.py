"""Twenty-third session: the offline pilot of docs/notes/generalisation.md ("three world models pooled on highway's
unseen ranking"): the fear AUROC for "a violation within 1 s" of the per-step mean fear of the cached models, on the
same 100 drives of ``highway-shift:test``. Run from the repository root:

    PYTHONPATH=. .venv/bin/python results/generalisation/highway-pool-pilot.py
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from core.metrics import auroc
from studies.generalisation import labels_within

HORIZON_STEPS = 10
"""1 s at highway's policy frequency (the generalisation table's label)."""


def load(name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(episode ids, violations, fear) per step of a cache's signal parts, in seed order."""
    with Path(f"results/generalisation/{name}.json").open() as file:
        cache = json.load(file)
    parts = [cache[key] for key in sorted(k for k in cache if k.startswith("signals"))]
    episode = np.concatenate([np.asarray(p["episode"]) + 1_000_000 * i for i, p in enumerate(parts)])
    violation = np.concatenate([np.asarray(p["violation"], bool) for p in parts])
    fear = np.concatenate([np.asarray(p["fear"], float) for p in parts])
    return episode, violation, fear


def main() -> None:
    episode, violation, committed = load("highway-approach-committed")
    fears = {"committed": committed}
    for refit in ("s0", "s1"):
        other_episode, other_violation, fears[refit] = load(f"highway-approach-{refit}")
        assert (other_episode == episode).all() and (other_violation == violation).all(), "not the same drives"
    label = labels_within(violation, episode, HORIZON_STEPS)
    print("steps", len(label), "positives", int(label.sum()))
    fears["s0+s1"] = (fears["s0"] + fears["s1"]) / 2
    fears["all three"] = (fears["committed"] + fears["s0"] + fears["s1"]) / 3
    for name, fear in fears.items():
        print(f"{name:10s} {auroc(fear, label):.4f}")


if __name__ == "__main__":
    main()
