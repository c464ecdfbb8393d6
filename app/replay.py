"""Replay of a recorded episode, per viewer: the live loop and every other page go on undisturbed.

A page opens an episode of the session store; its frames (the recorded scene, the step's labels) and the
whole episode's signal series go to that page only. The page draws the replayed scene itself (the 3D view is
one viser scene shared by every page, and it keeps showing the live run). Any connected page may replay, with
or without the control token: replaying changes nothing but that page's view.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from core.sessions import SessionError, SessionStore, SessionWriter

SERIES = (
    "t",
    "fear",
    "threshold",
    "curiosity",
    "takeover",
    "actor",
    "reward",
    "cost",
    "violation",
    "action",
    "a_rl",
)
"""The per-step signals a replay sends with its first message (the charts draw the whole episode at once)."""


class ReplayError(ValueError):
    """A replay request that cannot be served (no store, unknown session or episode, nothing open)."""


@dataclass
class ReplaySession:
    """One page's open replay: the episode's scenes and signals, and where the page is in it."""

    session: str
    episode: int
    static: dict[str, Any] | None
    scenes: list[dict[str, Any] | None]
    series: dict[str, list[Any]]
    events: list[dict[str, Any]]
    """The episode's timeline (:meth:`core.sessions.SessionStore.events`)."""
    t: int = 0

    @property
    def length(self) -> int:
        return len(self.scenes)

    def opened(self) -> dict[str, Any]:
        """The first message: the whole series, the static geometry of the scene and the ego's path."""
        trail = [
            [scene["ego"]["x"], scene["ego"]["y"]] if scene and scene.get("ego") else None for scene in self.scenes
        ]
        return {
            "type": "replay",
            "session": self.session,
            "episode": self.episode,
            "series": self.series,
            "static": self.static,
            "trail": trail,
            "events": self.events,
        }

    def seek(self, t: int) -> dict[str, Any]:
        """Move to step ``t`` (clamped to the episode) and return its frame message."""
        self.t = max(0, min(int(t), self.length - 1))
        scene = self.scenes[self.t]
        return {
            "type": "replay_frame",
            "t": self.t,
            "length": self.length,
            "labels": (scene or {}).get("labels"),
            "scene": scene,
        }


def open_replay(
    store: SessionStore | None, session: str, episode: int, live_writer: SessionWriter | None = None
) -> ReplaySession:
    """Read an episode for replay (blocking: call it off the event loop). ``live_writer`` is the session being
    recorded now, flushed first so that its latest steps are there."""
    if store is None:
        raise ReplayError("this server records no sessions, so there is nothing to replay")
    if live_writer is not None and live_writer.session_id == session:
        live_writer.flush()
    try:
        static, scenes = store.scenes(session, episode)
        arrays = store.steps(session, episode)
        events = store.events(session, episode)
    except (LookupError, SessionError) as exc:
        raise ReplayError(str(exc)) from None
    if not scenes:
        raise ReplayError(f"episode {episode} of {session} has no steps")
    series = {key: arrays[key].tolist() for key in SERIES}
    series["horizon"] = store.horizons(session, episode)
    return ReplaySession(session, episode, static, scenes, series, events)
