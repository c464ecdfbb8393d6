"""Same origin only: a foreign page or a DNS-rebinding name never reaches the dashboard or its control token."""

from __future__ import annotations

import http.client
import json

import pytest
from websockets.exceptions import InvalidStatus, WebSocketException
from websockets.sync.client import connect

from app.origin import allowed_hosts, host_name, same_origin
from tests.app.conftest import LiveServer
from tests.app.test_server import claim, until

ATTEMPTS = 20


def test_host_names_and_origins_are_parsed_as_browsers_send_them() -> None:
    assert host_name("127.0.0.1:8000") == "127.0.0.1" and host_name("[::1]:80") == "::1"
    assert host_name("Evil.Example.com") == "evil.example.com"
    hosts = allowed_hosts("0.0.0.0", ["robot.lan"])
    assert {"127.0.0.1", "localhost", "::1", "robot.lan"} <= hosts and "0.0.0.0" not in hosts

    def scope(origin: str | None, host: str = "127.0.0.1:8000") -> dict:
        headers = [(b"host", host.encode())] + ([(b"origin", origin.encode())] if origin else [])
        return {"headers": headers}

    assert same_origin(scope("http://127.0.0.1:8000"))
    assert same_origin(scope(None))  # not a browser page
    assert not same_origin(scope("https://evil.example.com"))
    assert not same_origin(scope("http://127.0.0.1:9999"))  # another local page, another port
    assert not same_origin(scope("null"))


def test_a_foreign_origin_never_gets_a_socket_or_a_token(live_server: LiveServer) -> None:
    url = f"ws://127.0.0.1:{live_server.port}/ws"
    granted = 0
    for _ in range(ATTEMPTS):
        try:
            with connect(url, origin="https://evil.example.com", open_timeout=5) as conn:  # type: ignore[arg-type]
                conn.send(json.dumps({"type": "claim"}))
                reply = json.loads(conn.recv(timeout=2))
                granted += int(reply.get("type") == "control" and bool(reply.get("token")))
        except (InvalidStatus, WebSocketException, TimeoutError, OSError):
            pass
    assert granted == 0
    for path in ("/viser", "/viser/"):
        foreign = f"ws://127.0.0.1:{live_server.port}{path}"
        with (
            pytest.raises((InvalidStatus, WebSocketException, OSError)),
            connect(foreign, origin="https://evil.example.com") as conn,
        ):  # type: ignore[arg-type]
            conn.recv(timeout=2)
    # the dashboard's own page still connects and may take control
    with connect(url, origin=f"http://127.0.0.1:{live_server.port}", open_timeout=5) as conn:  # type: ignore[arg-type]
        until(conn, lambda m: m["type"] == "welcome")
        assert claim(conn)


def test_a_rebinding_host_name_is_refused(live_server: LiveServer) -> None:
    refused = 0
    for path in ("/", "/api/state", "/api/options", "/static/app.js"):
        conn = http.client.HTTPConnection("127.0.0.1", live_server.port, timeout=10)
        conn.request("GET", path, headers={"Host": f"evil.example.com:{live_server.port}"})
        response = conn.getresponse()
        refused += int(response.status == 400 and b"not allowed" in response.read())
        conn.close()
    assert refused == 4
    granted = 0
    for _ in range(ATTEMPTS):
        try:
            headers = {"Host": f"evil.example.com:{live_server.port}"}
            with connect(f"ws://127.0.0.1:{live_server.port}/ws", additional_headers=headers, open_timeout=5) as conn:
                conn.send(json.dumps({"type": "claim"}))
                granted += int(json.loads(conn.recv(timeout=2)).get("type") == "control")
        except (InvalidStatus, WebSocketException, TimeoutError, OSError):
            pass
    assert granted == 0
    conn = http.client.HTTPConnection("127.0.0.1", live_server.port, timeout=10)
    conn.request("GET", "/api/state")
    assert conn.getresponse().status == 200
