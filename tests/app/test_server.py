"""The dashboard server without a browser: stream, control token, commands, replay, REST, viser proxy."""

from __future__ import annotations

import io
import json
import time
import urllib.error
import urllib.request
from collections.abc import Callable
from typing import Any

import pyarrow.csv as pacsv
import pyarrow.parquet as pq
import pytest
from websockets.sync.client import ClientConnection, connect

from core.loop import Runner
from tests.app.conftest import LiveServer, start_server, stop_server, toy_settings


def ws(live: LiveServer) -> ClientConnection:
    """A client that, like a browser, keeps reading frames whether or not the test reads its messages
    (``max_queue=None``): a bounded queue stops the reader when full, so a viewer left unread for 20 s on a loaded
    machine missed its keepalive pongs and was closed (1011) though the server was answering."""
    return connect(f"ws://127.0.0.1:{live.port}/ws", open_timeout=10, max_size=None, max_queue=None)


def until(conn: ClientConnection, pred: Callable[[dict[str, Any]], bool], timeout: float = 10.0) -> dict[str, Any]:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        msg = json.loads(conn.recv(timeout=max(0.01, deadline - time.monotonic())))
        if pred(msg):
            return msg
    raise AssertionError("expected message did not arrive")


def claim(conn: ClientConnection) -> str:
    conn.send(json.dumps({"type": "claim"}))
    return until(conn, lambda m: m["type"] == "control")["token"]


def get(live: LiveServer, path: str) -> tuple[int, bytes]:
    try:
        with urllib.request.urlopen(live.url + path, timeout=20) as response:
            return response.status, response.read()
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read()


@pytest.fixture
def fast_server(tmp_path, monkeypatch):
    calls = {"n": 0}
    original = Runner.step

    def counting(self: Runner):
        calls["n"] += 1
        return original(self)

    monkeypatch.setattr(Runner, "step", counting)  # every live step must be the one Runner.step
    live, thread = start_server(toy_settings(tmp_path, speed=20.0))
    live.calls = calls  # type: ignore[attr-defined]
    try:
        yield live
    finally:
        stop_server(live, thread)


def test_stream_is_made_of_runner_steps_and_a_late_page_gets_history(fast_server) -> None:
    with ws(fast_server) as conn:
        welcome = json.loads(conn.recv(timeout=10))
        assert welcome["type"] == "welcome" and welcome["state"]["config"]["sim"] == "toy"
        steps = [until(conn, lambda m: m["type"] == "step") for _ in range(20)]
    assert fast_server.calls["n"] >= steps[-1]["t"] + 1  # type: ignore[attr-defined]
    assert {
        "fear",
        "threshold",
        "curiosity",
        "takeover",
        "actor",
        "a_rl",
        "action",
        "reward",
        "cost",
        "counters",
        "ego",
    } <= set(steps[0])
    with ws(fast_server) as late:
        welcome = json.loads(late.recv(timeout=10))
        assert len(welcome["history"]) >= 20 and welcome["history"][-1]["type"] == "step"


def test_one_operator_viewers_are_refused_and_commands_apply(fast_server) -> None:
    with ws(fast_server) as operator, ws(fast_server) as viewer:
        token = claim(operator)
        viewer.send(json.dumps({"type": "claim"}))
        refusal = until(viewer, lambda m: m["type"] == "error")
        assert refusal["op"] == "claim" and "viewer" in refusal["error"]
        viewer.send(json.dumps({"type": "control", "token": "x" * 32, "op": "pause"}))
        assert "refused" in until(viewer, lambda m: m["type"] == "error")["error"]
        assert not fast_server.state()["paused"]

        operator.send(json.dumps({"type": "control", "token": token, "op": "pause"}))
        until(operator, lambda m: m["type"] == "ack")
        assert fast_server.state()["paused"]
        t_paused = fast_server.dash.live.world.runner.t
        operator.send(json.dumps({"type": "control", "token": token, "op": "step"}))
        until(operator, lambda m: m["type"] == "ack")
        assert fast_server.dash.live.world.runner.t in (t_paused + 1, 0)  # one step (or a new episode)

        session = fast_server.state()["session"]
        operator.send(json.dumps({"type": "configure", "token": token, "expert_mode": "scripted"}))
        until(operator, lambda m: m["type"] == "ack")
        assert fast_server.state()["session"] == session, "changing who answers needs no new session"
        assert fast_server.dash.live.world.expert.mode == "scripted"
        operator.send(json.dumps({"type": "configure", "token": token, "scenario": "2"}))
        until(operator, lambda m: m["type"] == "ack")
        assert fast_server.state()["session"] != session and fast_server.state()["config"]["scenario"] == "2"

        operator.send(json.dumps({"type": "configure", "token": token, "sim": "sumo"}))
        assert "not available" in until(operator, lambda m: m["type"] == "error")["error"]
        operator.send(json.dumps({"type": "configure", "token": token, "policy": "/no/such/run"}))
        assert "no policy" in until(operator, lambda m: m["type"] == "error")["error"]
        assert fast_server.state()["config"]["policy"] == "wave"  # a failed switch keeps the old world

        operator.send(json.dumps({"type": "release", "token": token}))
        until(operator, lambda m: m["type"] == "control" and not m["granted"])
        assert claim(viewer)  # control is free again


def test_rest_lists_sessions_episodes_and_exports(fast_server) -> None:
    deadline = time.monotonic() + 30
    while fast_server.state()["counters"]["episodes"] < 1 and time.monotonic() < deadline:
        time.sleep(0.05)
    status, body = get(fast_server, "/api/sessions")
    sessions = json.loads(body)
    assert status == 200 and len(sessions) == 1 and sessions[0]["sim"] == "toy"
    sid = sessions[0]["id"]
    status, body = get(fast_server, f"/api/sessions/{sid}/episodes")
    episodes = json.loads(body)
    assert status == 200 and episodes[0]["finished"] and episodes[0]["steps"] == 200
    status, body = get(fast_server, f"/api/sessions/{sid}/export.parquet?episode=0")
    table = pq.read_table(io.BytesIO(body))
    assert status == 200 and table.num_rows == 200 and "obs_0" in table.column_names
    status, body = get(fast_server, f"/api/sessions/{sid}/export.csv")
    assert status == 200 and pacsv.read_csv(io.BytesIO(body)).num_rows >= 200
    status, body = get(fast_server, f"/api/sessions/{sid}/segments?episode=0")
    segments = json.loads(body)
    assert status == 200 and segments and all(s["episode"] == 0 and s["t_end"] >= s["t_start"] for s in segments)
    assert get(fast_server, f"/api/sessions/{sid}/export.xlsx")[0] == 400
    assert get(fast_server, "/api/sessions/20990101-000000-x-0000/episodes")[0] == 404
    assert get(fast_server, f"/api/sessions/{sid}/export.csv?episode=999")[0] == 404
    options = json.loads(get(fast_server, "/api/options")[1])
    assert [s["name"] for s in options["sims"]] == ["toy", "sumo"] and options["expert_modes"][0] == "person"


def test_replay_is_per_page_and_the_live_loop_runs_on_for_everyone(fast_server) -> None:
    """Any page may replay (no control token); its frames go to that page only, and the live loop keeps
    stepping for the other pages (and for this one, whose live stream keeps coming)."""
    deadline = time.monotonic() + 30
    while fast_server.state()["counters"]["episodes"] < 1 and time.monotonic() < deadline:
        time.sleep(0.05)
    sid = fast_server.state()["session"]
    # the store's writer thread may still be flushing the episode's last scenes (seen at load 14)
    while len(stored := fast_server.dash.store.scenes(sid, 0)[1]) < 200 and time.monotonic() < deadline + 30:
        time.sleep(0.05)
    with ws(fast_server) as replaying, ws(fast_server) as watching:
        until(watching, lambda m: m["type"] == "welcome")
        replaying.send(json.dumps({"type": "replay_open", "session": sid, "episode": 0}))
        replay = until(replaying, lambda m: m["type"] == "replay")
        assert len(replay["series"]["t"]) == 200 and len(replay["series"]["fear"]) == 200
        assert until(replaying, lambda m: m["type"] == "replay_frame")["t"] == 0
        steps_before = fast_server.state()["counters"]["steps"]
        replaying.send(json.dumps({"type": "replay_seek", "t": 150}))
        frame = until(replaying, lambda m: m["type"] == "replay_frame" and m["t"] == 150)
        assert frame["length"] == 200 and frame["scene"]["ego"] == stored[150]["ego"]  # the page draws it
        replaying.send(json.dumps({"type": "replay_seek", "t": 5000}))
        assert until(replaying, lambda m: m["type"] == "replay_frame")["t"] == 199  # clamped
        # meanwhile the live run goes on: the other page gets new steps, and no replay message
        seen: list[dict[str, Any]] = []
        until(watching, lambda m: seen.append(m) or (m["type"] == "step" and m["t"] >= 0 and len(seen) > 20))
        assert not any(m["type"].startswith("replay") for m in seen)
        # the step messages seen may have been queued before the count was read: wait for the loop's next steps
        deadline = time.monotonic() + 10
        while fast_server.state()["counters"]["steps"] <= steps_before and time.monotonic() < deadline:
            time.sleep(0.05)
        assert fast_server.state()["counters"]["steps"] > steps_before, "the live loop runs on during a replay"
        until(replaying, lambda m: m["type"] == "step")  # the replaying page's live stream keeps coming too
        replaying.send(json.dumps({"type": "replay_open", "session": sid, "episode": 99}))
        assert "no episode 99" in until(replaying, lambda m: m["type"] == "error")["error"]
        replaying.send(json.dumps({"type": "replay_close"}))
        until(replaying, lambda m: m["type"] == "replay_closed")
        replaying.send(json.dumps({"type": "replay_seek", "t": 3}))
        assert "no replay is open" in until(replaying, lambda m: m["type"] == "error")["error"]
        # the operator may replay too, with its token
        token = claim(watching)
        watching.send(json.dumps({"type": "replay_open", "token": token, "session": sid, "episode": 0}))
        assert until(watching, lambda m: m["type"] == "replay_frame")["t"] == 0


def test_viser_is_served_and_relayed_on_the_same_origin(fast_server) -> None:
    status, body = get(fast_server, "/viser/")
    assert status == 200 and b"Viser" in body
    import viser

    with connect(f"ws://127.0.0.1:{fast_server.port}/viser", subprotocols=[f"viser-v{viser.__version__}"]) as conn:
        assert conn.subprotocol == f"viser-v{viser.__version__}"
        assert isinstance(conn.recv(timeout=10), bytes)  # viser's own msgpack messages come through


def test_a_policy_that_crashes_is_reported_and_the_loop_goes_on(tmp_path) -> None:
    from app.policies import LoadedPolicy
    from core.loop import NoGate
    from tests.app.fakesim import toy_policy_loader

    class Flaky:
        def __init__(self) -> None:
            self.calls = 0

        def act(self, obs, deterministic=False):
            self.calls += 1
            if self.calls == 5:
                raise RuntimeError("policy exploded")
            return [0.2, 0.0]

    def loader(choice, env):
        return LoadedPolicy(Flaky(), NoGate(), "flaky", {}) if choice == "flaky" else toy_policy_loader(choice, env)

    live, thread = start_server(toy_settings(tmp_path, policy="flaky", policy_loader=loader, speed=20.0))
    try:
        deadline = time.monotonic() + 20
        while live.state()["counters"]["steps"] < 20 and time.monotonic() < deadline:
            time.sleep(0.05)
        state = live.state()
        assert state["counters"]["steps"] >= 20 and "policy exploded" in state["error"]
    finally:
        stop_server(live, thread)


def test_the_default_server_opens_on_the_ugv_with_the_committed_policy(tmp_path) -> None:
    from app.policies import SCRIPTED
    from app.server import ServerSettings
    from tests.app.conftest import ROOT

    folder = ROOT / "policies" / "ugv-default"
    committed = (folder / "checkpoint.pt").is_file() or any((folder / "checkpoints").glob("*.pt"))
    default = folder if committed else None
    if default is not None:
        from core.agents import warm_gate_kernels

        # as `sage serve` does before it serves: a fresh clone compiles the gate's kernels once (numba's cache is
        # cold), which is not the loop's first step; under the parallel suite it would share the CPU with other tests
        warm_gate_kernels([str(default)])
    settings = ServerSettings(sessions=tmp_path, policy_roots=[ROOT / "policies", ROOT / "runs"])
    live, thread = start_server(settings)
    try:
        state = live.state()
        assert state["config"]["sim"] == "ugv" and state["config"]["scenario"] == "1"
        assert state["config"]["policy"] == (str(default) if default else SCRIPTED)
        assert state["has_gate"] == bool(default)
        with ws(live) as conn:
            step = until(conn, lambda m: m["type"] == "step")
        assert len(step["ego"]) == 3 and step["labels"]["scenario"] == "narrow_passage"
    finally:
        stop_server(live, thread)


def test_a_default_policy_that_does_not_load_falls_back_to_the_scripted_expert(tmp_path) -> None:
    broken = tmp_path / "policies" / "toy-default"
    broken.mkdir(parents=True)
    (broken / "checkpoint.pt").write_bytes(b"not a checkpoint")
    from app.policies import load_policy

    live, thread = start_server(toy_settings(tmp_path, policy=None, policy_loader=load_policy))
    try:
        state = live.state()
        assert state["config"]["policy"] == "scripted" and "does not load" in state["error"]
    finally:
        stop_server(live, thread)


def test_the_operator_switches_the_shared_view_and_a_viewer_cannot(fast_server) -> None:
    assert fast_server.state()["view"] == "follow"
    with ws(fast_server) as operator, ws(fast_server) as viewer:
        token = claim(operator)
        viewer.send(json.dumps({"type": "view", "mode": "overview", "token": "not-the-token"}))
        assert "only the operator" in until(viewer, lambda m: m["type"] == "error")["error"]
        operator.send(json.dumps({"type": "view", "mode": "overview", "token": token}))
        assert until(operator, lambda m: m["type"] == "ack" and m["op"] == "view")["result"] == {"view": "overview"}
        assert until(viewer, lambda m: m["type"] == "state" and m["view"] == "overview")
        assert fast_server.dash.scene_view.drawer.view == "overview"
        operator.send(json.dumps({"type": "view", "mode": "sideways", "token": token}))
        assert until(operator, lambda m: m["type"] == "error")["error"]


def test_rest_gives_an_episodes_timeline_and_refuses_a_missing_one(fast_server) -> None:
    deadline = time.monotonic() + 30
    while fast_server.state()["counters"]["episodes"] < 1 and time.monotonic() < deadline:
        time.sleep(0.05)
    sid = fast_server.state()["session"]
    status, body = get(fast_server, f"/api/sessions/{sid}/events?episode=0")
    events = json.loads(body)
    assert status == 200 and events == fast_server.dash.store.events(sid, 0) and events[-1]["kind"] == "end"
    assert get(fast_server, f"/api/sessions/{sid}/events?episode=999")[0] == 404


def test_a_coaching_operators_controls_label_the_agents_steps_and_are_counted(fast_server) -> None:
    with ws(fast_server) as operator:
        token = claim(operator)
        operator.send(json.dumps({"type": "presence", "token": token, "focused": True, "visible": True}))
        seq, coached = 0, None
        deadline = time.monotonic() + 15
        while coached is None and time.monotonic() < deadline:
            seq += 1  # an input every few steps keeps the person answering (the fail-safe's 200 ms)
            ts = time.time() * 1000
            operator.send(
                json.dumps(
                    {"type": "input", "token": token, "seq": seq, "ts": ts, "held": False, "steer": 0.5, "coach": True}
                )
            )
            msg = until(operator, lambda m: m["type"] == "step")
            if msg["coached"]:
                coached = msg
        assert coached is not None, "no coached step while the operator coached"
        assert coached["actor"] == "agent" and not coached["takeover"]  # the agent drove: coaching never takes over
        assert coached["a_expert"] is not None and coached["counters"]["coached_steps"] >= 1
