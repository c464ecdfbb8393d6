"""The session as training data: a recorded session's finished episodes read from the session store into a
learner's replay buffer (:func:`ingest`), the takeover rows with the expert's action and the coached rows with the
coach's label. Both faces of fine-tuning read it through :mod:`core.finetune`."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from core.protocol import StepRecord
from core.sage.learner import BaseLearner
from core.sessions import SessionStore


@dataclass
class Ingested:
    episodes: list[int] = field(default_factory=list)
    steps: int = 0
    takeovers: int = 0
    coached: int = 0
    """Rows the agent drove with a coach's label (imitated like takeovers; :class:`core.protocol.Coach`)."""
    dropped: int = 0
    """Rows left out because an observation or action held NaN/inf (a sensor glitch must not poison training)."""


def ready_episodes(store: SessionStore, session_id: str, done: Iterable[int] = ()) -> list[int]:
    """Episodes of the session that are over and not in ``done``: finished, or followed by a later episode
    (an episode the operator cut short never gets a summary, but its steps still count)."""
    rows = store.episodes(session_id)
    if not rows:
        return []
    last = max(r["episode"] for r in rows)
    seen = set(done)
    return [r["episode"] for r in rows if (r["finished"] or r["episode"] < last) and r["episode"] not in seen]


def ingest(learner: BaseLearner, store: SessionStore, session_id: str, episodes: Iterable[int]) -> Ingested:
    """Add the recorded steps of ``episodes`` to the learner's real buffer (takeover rows with the expert's action)."""
    out = Ingested()
    for episode in episodes:
        arrays = store.steps(session_id, episode)
        out.episodes.append(int(episode))
        n = len(arrays["t"])
        if n == 0:
            continue
        vectors = np.concatenate([arrays["obs"], arrays["next_obs"], arrays["action"], arrays["a_rl"]], axis=1)
        clean = np.isfinite(vectors).all(axis=1) & np.isfinite(arrays["reward"]) & np.isfinite(arrays["cost"])
        for i in range(n):
            if not clean[i]:
                out.dropped += 1
                continue
            a_expert = arrays["a_expert"][i]
            labelled = bool(np.isfinite(a_expert).all())
            takeover = bool(arrays["takeover"][i]) and labelled
            # a label on a step nobody took over is a coach's (core.protocol.Coach): imitated, not executed
            coached = labelled and not bool(arrays["takeover"][i])
            # through the learner's own store: it encodes actions (a discrete learner's one-hot) and may shape
            # rewards (Multi-Hug's intervention penalty), as in headless training
            learner.store(
                StepRecord(
                    episode=int(episode),
                    t=int(arrays["t"][i]),
                    obs=arrays["obs"][i],
                    a_rl=arrays["a_rl"][i],
                    a_expert=a_expert if labelled else None,
                    action=arrays["action"][i],
                    takeover=takeover,
                    gate_fired=bool(arrays["gate_fired"][i]),
                    actor=str(arrays["actor"][i]),  # type: ignore[arg-type]
                    fear=float(arrays["fear"][i]),
                    threshold=float(arrays["threshold"][i]),
                    curiosity=float(arrays["curiosity"][i]),
                    reward=float(arrays["reward"][i]),
                    cost=float(arrays["cost"][i]),
                    violation=bool(arrays["violation"][i]),
                    terminated=bool(arrays["terminated"][i]),
                    truncated=bool(arrays["truncated"][i]),
                    next_obs=arrays["next_obs"][i],
                    wall_time=float(arrays["wall_time"][i]),
                    info={
                        "conflict": bool(arrays["conflict"][i])
                    },  # the world model's near-miss label, if it learns it
                    coached=coached,
                )
            )
            out.steps += 1
            out.takeovers += int(takeover)
            out.coached += int(coached)
    return out
