"""Live server benchmark: loop and stream rates with 3 viewers, and key press to applied action latency.

Runs the real dashboard server (UGV, its committed default policy when present) in this process on a
free loopback port, connects three viewer websockets and one operator websocket, and measures:

* loop rate (steps/s achieved vs the wall-clock target) and the cost of one live step, at 1x and at the
  highest speed multiplier (to show the headroom),
* stream rate: step messages per second received by each viewer,
* the imagined horizon (the gate's per-member rollout streamed and recorded with each step) against none, side
  by side at 20x: loop rate and live step cost (it must not lower the loop rate),
* hostile messages: 1,000 malformed, oversized, deeply nested, mistyped or cross-typed messages from one
  connection, while the loop runs at 1x: internal errors (target 0) and the loop rate beside a quiet run,
* key press to applied action (page timestamp of the input -> wall time of the env step that used it):
  - takeover onset (Space pressed): the loop wakes at once, target p95 <= 50 ms,
  - a steering change during a takeover: waits for the next control tick, so bounded by the control
    period (100 ms at 10 Hz).

    python bench/bench_server.py [--seconds 8] [--samples 30] [--policy RUN]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import random
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
import uvicorn
import websockets

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.commands import Configure, SetSpeed  # noqa: E402
from app.server import ServerSettings, create_app  # noqa: E402


class _Server(uvicorn.Server):
    def install_signal_handlers(self) -> None:
        pass


def start(settings: ServerSettings) -> tuple[_Server, threading.Thread, int, Any]:
    app = create_app(settings)
    server = _Server(uvicorn.Config(app, host="127.0.0.1", port=0, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    while not server.started:
        time.sleep(0.02)
    return server, thread, server.servers[0].sockets[0].getsockname()[1], app


def pct(values: list[float], q: float) -> float:
    return float(np.percentile(values, q)) if values else float("nan")


async def viewer(url: str, counts: list[int], ready: asyncio.Event, stop: asyncio.Event) -> None:
    async with websockets.connect(url, max_size=None) as ws:
        await ws.recv()  # the welcome
        ready.set()
        while not stop.is_set():
            try:
                msg = await asyncio.wait_for(ws.recv(decode=True), 0.5)  # the server sends text frames
            except TimeoutError:
                continue
            if msg.startswith('{"episode"') or '"type":"step"' in msg[:400]:
                counts.append(1)


async def measure_rates(port: int, app: Any, seconds: float) -> dict[str, Any]:
    url = f"ws://127.0.0.1:{port}/ws"
    stop = asyncio.Event()
    counts: list[list[int]] = [[], [], []]
    ready = [asyncio.Event() for _ in counts]
    tasks = [asyncio.create_task(viewer(url, c, r, stop)) for c, r in zip(counts, ready, strict=True)]
    for r in ready:
        await r.wait()
    live = app.state.dash.live
    steps0, received0 = live.world.counts()["steps"], [len(c) for c in counts]
    t0 = time.monotonic()
    await asyncio.sleep(seconds)
    elapsed = time.monotonic() - t0
    steps = live.world.counts()["steps"] - steps0
    received = [len(c) - r for c, r in zip(counts, received0, strict=True)]
    stop.set()
    await asyncio.gather(*tasks)
    costs = [1000 * c for c in live.step_costs]
    return {
        "target": live.speed / live.world.dt,
        "loop": steps / elapsed,
        "stream": [r / elapsed for r in received],
        "step_ms_p50": pct(costs, 50),
        "step_ms_p95": pct(costs, 95),
    }


async def measure_latency(port: int, samples: int) -> dict[str, list[float]]:
    """An operator websocket acting like the page: 20 Hz heartbeat, presses and steering changes."""
    onset: list[float] = []
    steer: list[float] = []
    async with websockets.connect(f"ws://127.0.0.1:{port}/ws", max_size=None) as ws:
        await ws.send(json.dumps({"type": "claim"}))
        token = None
        while token is None:
            msg = json.loads(await ws.recv())
            if msg["type"] == "control" and msg.get("granted"):
                token = msg["token"]
        seq = 0
        state = {"held": False, "steer": 0.0}

        async def send() -> tuple[int, float]:
            nonlocal seq
            seq += 1
            ts = time.time() * 1000.0
            await ws.send(
                json.dumps(
                    {
                        "type": "input",
                        "token": token,
                        "seq": seq,
                        "ts": ts,
                        "held": state["held"],
                        "throttle": 0.3,
                        "steer": state["steer"],
                    }
                )
            )
            return seq, ts

        async def heartbeat() -> None:
            while True:
                await send()
                await asyncio.sleep(0.05)

        async def applied(after_seq: int) -> float:
            while True:
                msg = json.loads(await ws.recv())
                if msg["type"] == "step" and msg.get("actor") == "person" and msg.get("input_seq", -1) >= after_seq:
                    return float(msg["applied_ms"])

        beat = asyncio.create_task(heartbeat())
        try:
            for _ in range(samples):
                await asyncio.sleep(random.uniform(0.25, 0.45))  # released: the agent drives
                state["held"] = True
                k, ts = await send()
                onset.append(await applied(k) - ts)
                for _ in range(2):  # steering changes while holding
                    await asyncio.sleep(random.uniform(0.03, 0.2))
                    state["steer"] = -state["steer"] if state["steer"] else 0.5
                    k, ts = await send()
                    steer.append(await applied(k) - ts)
                state["held"] = False
                await send()
        finally:
            beat.cancel()
    return {"onset": onset, "steer": steer}


def hostile_messages(rng: random.Random, n: int) -> list[str]:
    """Messages no page sends: malformed, oversized, deeply nested, mistyped, unknown, huge numbers."""
    shapes = [
        lambda: "[" * rng.randint(9, 20_000),
        lambda: '{"type": "ping", "ts": ' + "9" * rng.randint(33, 6000) + "}",
        lambda: json.dumps({"type": "input", "token": "x" * 16, "seq": 1, "ts": 1.0, "held": "yes"}),
        lambda: json.dumps({"type": rng.choice(["", "eval", None, 3])}),
        lambda: json.dumps({"type": "speed", "token": "x" * 16, "value": rng.choice([0, 1e308, "fast"])}),
        lambda: "".join(chr(rng.randint(0, 0x2FFF)) for _ in range(rng.randint(0, 200))),
        lambda: '{"type": "input", "a": ' + '{"b": ' * 30 + "1" + "}" * 30 + "}",
        lambda: '"' + "x" * 20_000 + '"',
    ]
    return [rng.choice(shapes)() for _ in range(n)]


async def measure_hostile(port: int, app: Any, count: int) -> dict[str, float]:
    """The loop rate while one connection sends ``count`` hostile messages, and how they were answered."""
    live = app.state.dash.live
    internal = answered = 0
    async with websockets.connect(f"ws://127.0.0.1:{port}/ws", max_size=None) as ws:
        await ws.recv()  # the welcome
        steps0, t0 = live.world.counts()["steps"], time.monotonic()
        for raw in hostile_messages(random.Random(0), count):
            await ws.send(raw)
        while answered < count and time.monotonic() - t0 < 60:
            try:
                msg = json.loads(await asyncio.wait_for(ws.recv(), 5))
            except TimeoutError:
                break
            if msg.get("type") == "error":
                answered += 1
                internal += int("internal" in str(msg.get("error", "")))
        await asyncio.sleep(max(0.0, 3.0 - (time.monotonic() - t0)))
        elapsed = time.monotonic() - t0
        loop = (live.world.counts()["steps"] - steps0) / elapsed
    return {"internal": internal, "answered": answered, "loop": loop, "target": live.speed / live.world.dt}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=8.0, help="measurement window per rate run")
    parser.add_argument("--samples", type=int, default=30, help="key presses to time")
    parser.add_argument("--policy", default=None, help="run folder or checkpoint (default: policies/ugv-default)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    random.seed(0)
    sessions = Path(tempfile.mkdtemp(prefix="bench-server-"))
    settings = ServerSettings(
        sim="ugv", scenario="3", sessions=sessions, policy=args.policy, policy_roots=[ROOT / "policies", ROOT / "runs"]
    )
    server, thread, port, app = start(settings)
    try:
        live = app.state.dash.live
        period_ms = live.world.dt * 1000
        print(f"bench_server: UGV scenario 3, policy {live.world.loaded.label}, control period {period_ms:.0f} ms")
        for speed in (1.0, 20.0):
            live.submit(SetSpeed(speed)).result(timeout=10)
            r = asyncio.run(measure_rates(port, app, args.seconds))
            print(
                f"  speed {speed:>4.0f}x: loop {r['loop']:6.1f} steps/s (target {r['target']:.0f}, "
                f"ratio {r['loop'] / r['target']:.2f}); stream to 3 viewers "
                + ", ".join(f"{s:.1f}" for s in r["stream"])
                + f" msg/s (ratio {min(r['stream']) / r['loop']:.2f} of the loop); live step p50 "
                f"{r['step_ms_p50']:.2f} ms, p95 {r['step_ms_p95']:.2f} ms"
            )
        # the imagined horizon (streamed and recorded with every step) against none, side by side, at 20x
        rates: dict[bool, list[dict[str, Any]]] = {}
        for on in (False, True, False, True):
            live.imagined_horizon = on
            rates.setdefault(on, []).append(asyncio.run(measure_rates(port, app, args.seconds / 2)))
        with_h, without = (max(r["loop"] for r in rates[k]) for k in (True, False))
        p50_on, p50_off = (min(r["step_ms_p50"] for r in rates[k]) for k in (True, False))
        print(
            f"  imagined horizon at 20x: loop {with_h:.1f} steps/s with it, {without:.1f} without (ratio "
            f"{with_h / without:.2f}); live step p50 {p50_on:.2f} ms vs {p50_off:.2f} ms"
        )
        live.imagined_horizon = True
        live.submit(SetSpeed(1.0)).result(timeout=10)
        quiet = asyncio.run(measure_rates(port, app, 3.0))
        h = asyncio.run(measure_hostile(port, app, 1000))
        print(
            f"  1,000 hostile messages: {h['answered']} validation errors, {h['internal']} internal errors "
            f"(target 0); loop {h['loop']:.1f} steps/s beside {quiet['loop']:.1f} quiet (target {h['target']:.0f})"
        )
        live.submit(Configure(expert_mode="person")).result(timeout=10)
        lat = asyncio.run(measure_latency(port, args.samples))
        for name, label, target in (
            ("onset", "key press (takeover onset) -> applied action", "target p95 <= 50 ms"),
            ("steer", "steering change during a takeover -> applied action", "bounded by the control period"),
        ):
            values = lat[name]
            print(
                f"  {label}: n={len(values)} p50 {pct(values, 50):.1f} ms, p95 {pct(values, 95):.1f} ms, "
                f"max {max(values):.1f} ms, mean {statistics.fmean(values):.1f} ms  ({target})"
            )
    finally:
        server.should_exit = True
        thread.join(timeout=15)


if __name__ == "__main__":
    main()
