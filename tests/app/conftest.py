"""A live dashboard server in a background thread, and Debian's chromium driven by Playwright."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import uvicorn

from app.server import ServerSettings, create_app
from tests.app.fakesim import toy_catalogue, toy_env_factory, toy_policy_loader

ROOT = Path(__file__).resolve().parents[2]
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]


class ThreadedServer(uvicorn.Server):
    def install_signal_handlers(self) -> None:  # the test runner owns the signals
        pass


@dataclass
class LiveServer:
    url: str
    port: int
    app: Any
    server: ThreadedServer

    @property
    def dash(self) -> Any:
        return self.app.state.dash

    def state(self) -> dict[str, Any]:
        return self.dash.live.state()


def start_server(settings: ServerSettings, port: int = 0) -> tuple[LiveServer, threading.Thread]:
    app = create_app(settings)
    server = ThreadedServer(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning", lifespan="on"))
    thread = threading.Thread(target=server.run, name="test-uvicorn", daemon=True)
    thread.start()
    deadline = time.monotonic() + 30
    while not server.started:
        if time.monotonic() > deadline or not thread.is_alive():
            raise RuntimeError("the dashboard server did not start")
        time.sleep(0.02)
    port = server.servers[0].sockets[0].getsockname()[1]
    return LiveServer(f"http://127.0.0.1:{port}", port, app, server), thread


def stop_server(live: LiveServer, thread: threading.Thread) -> None:
    live.server.should_exit = True
    thread.join(timeout=15)


def toy_settings(tmp: Path, **overrides: Any) -> ServerSettings:
    values: dict[str, Any] = {
        "sim": "toy",
        "scenario": "1",
        "policy": "wave",
        "sessions": tmp / "sessions",
        "policy_roots": [tmp / "policies"],
        "env_factory": toy_env_factory,
        "policy_loader": toy_policy_loader,
        "catalogue": toy_catalogue,
        "port": 0,
    }
    values.update(overrides)
    return ServerSettings(**values)


@pytest.fixture
def live_server(tmp_path: Path) -> Iterator[LiveServer]:
    live, thread = start_server(toy_settings(tmp_path))
    try:
        yield live
    finally:
        stop_server(live, thread)


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    if not Path(CHROMIUM).exists():
        pytest.skip("Debian's chromium is not installed (scripts/setup.sh --browser)")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS, headless=True)
        try:
            yield browser
        finally:
            browser.close()
