"""The live session's counters, read from the one loop rather than counted again.

Takeover steps and segments, return, cost and violations per episode are the :class:`core.loop.Runner`'s own
tallies (:meth:`~core.loop.Runner.progress`, the same numbers its :class:`~core.loop.EpisodeSummary` reports);
finished episodes are added up here when they end. Only what the loop does not know is counted from the
steps: who acted during a takeover (a person, or the fallback when the person was idle), and why the scripted
expert drove.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from core.loop import TAKEOVER_CAUSES, EpisodeProgress, EpisodeSummary, StepRecord, TakeoverCause


@dataclass
class SessionCounters:
    episodes: int = 0
    """Finished episodes."""
    collisions: int = 0
    """Finished episodes whose metrics report a collision."""
    person_steps: int = 0
    fallback_steps: int = 0
    coached_steps: int = 0
    """Steps the agent drove with the person's coaching label (key C): labels for the rounds, not takeovers."""
    expert_steps_by_cause: dict[str, int] = field(default_factory=lambda: dict.fromkeys(TAKEOVER_CAUSES, 0))
    """The scripted expert's steps by why it drove (:func:`core.loop.takeover_cause`), as the expert or as the
    fallback for a person who did not take hold."""
    _seen_steps: int = 0
    _done_steps: int = 0
    _done_takeovers: int = 0
    _done_events: int = 0
    _done_violations: int = 0

    def on_step(self, record: StepRecord, cause: TakeoverCause | None = None) -> None:
        """Count a step; ``cause``: why the scripted expert drove it (None: it did not)."""
        self._seen_steps += 1
        self.person_steps += int(record.actor == "person")
        self.fallback_steps += int(record.actor == "fallback")
        self.coached_steps += int(record.coached)
        if cause is not None and record.actor in ("expert", "fallback"):  # the scripted expert, either way
            self.expert_steps_by_cause[cause] += 1

    def on_episode(self, summary: EpisodeSummary, final: EpisodeProgress) -> bool:
        """Add a finished episode (its summary, and the runner's final tallies); returns whether it collided."""
        self.episodes += 1
        collision = summary.metrics.get("collision", summary.metrics.get("collisions", 0))
        collided = bool(collision) and not (isinstance(collision, float) and math.isnan(collision))
        self.collisions += int(collided)
        self._done_steps += summary.steps
        self._done_takeovers += summary.takeovers
        self._done_events += summary.takeover_events
        self._done_violations += final.violations
        return collided

    def as_dict(self, current: EpisodeProgress | None, running: bool) -> dict[str, Any]:
        """Session totals with the running episode's tallies (``running``: it has not ended yet)."""
        live = current if running and current is not None else None
        steps = self._done_steps + (live.steps if live else 0)
        takeovers = self._done_takeovers + (live.takeovers if live else 0)
        episode_steps = current.steps if current is not None else 0
        episode_takeovers = current.takeovers if current is not None else 0
        return {
            "episodes": self.episodes,
            "steps": steps,
            "takeover_steps": takeovers,
            "person_steps": self.person_steps,
            "fallback_steps": self.fallback_steps,
            "coached_steps": self.coached_steps,
            "takeover_events": self._done_events + (live.takeover_events if live else 0),
            "collisions": self.collisions,
            "violations": self._done_violations + (live.violations if live else 0),
            "episode_steps": episode_steps,
            "episode_takeovers": episode_takeovers,
            "episode_return": current.ret if current is not None else 0.0,
            "episode_cost": current.cost if current is not None else 0.0,
            "takeover_rate": takeovers / steps if steps else 0.0,
            # shares of every step seen, so that they add up to the scripted expert's part of the takeover rate
            "expert_share_by_cause": {
                cause: n / self._seen_steps if self._seen_steps else 0.0
                for cause, n in self.expert_steps_by_cause.items()
            },
            "episode_takeover_rate": episode_takeovers / episode_steps if episode_steps else 0.0,
        }
