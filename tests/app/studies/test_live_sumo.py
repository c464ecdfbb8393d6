"""SUMO on the live dashboard: the process-backed env, and a crashed SUMO ending the episode with a clear error
while the session goes on (no browser: the page is a view of the same stream)."""

from __future__ import annotations

import json
import os
import signal
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from websockets.sync.client import ClientConnection, connect

from app.server import ServerSettings
from sims.sumo.process import SumoProcessEnv
from tests.app.conftest import start_server, stop_server


def until(conn: ClientConnection, pred: Callable[[dict[str, Any]], bool], timeout: float = 60.0) -> dict[str, Any]:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        message = json.loads(conn.recv(timeout=max(0.01, deadline - time.monotonic())))
        if pred(message):
            return message
    raise AssertionError("the expected message did not arrive")


def test_a_crashed_sumo_ends_the_episode_with_an_error_and_the_session_goes_on(tmp_path: Path) -> None:
    settings = ServerSettings(
        sim="sumo", scenario=1, policy="scripted", speed=20.0, sessions=tmp_path / "sessions", policy_roots=[tmp_path]
    )
    live, thread = start_server(settings)
    try:
        env = live.dash.live.world.env.unwrapped
        assert isinstance(env, SumoProcessEnv)  # SUMO steps in its own process, never on the server's GIL
        with connect(f"ws://127.0.0.1:{live.port}/ws", open_timeout=10, max_size=None) as conn:
            first = until(conn, lambda m: m.get("type") == "step" and m["t"] >= 5)
            assert env.worker_pid is not None
            os.kill(env.worker_pid, signal.SIGKILL)
            ended = until(conn, lambda m: m.get("type") == "episode" and m.get("error"))
            assert ended["episode"] == first["episode"]
            # "died before 'step'" or "died during 'step'", as the kill landed between calls or within one
            assert "SUMO worker process" in ended["error"] and " died " in ended["error"]
            nxt = until(conn, lambda m: m.get("type") == "step" and m["episode"] > first["episode"] and m["t"] >= 3)
            assert nxt["session"] == first["session"]  # the same recorded session goes on, with a new worker
        state = live.state()
        assert "SUMO worker process" in (state["error"] or "")
        assert env.worker_pid is not None
    finally:
        stop_server(live, thread)
