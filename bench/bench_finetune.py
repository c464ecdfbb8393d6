"""Live loop rate with and without the fine-tuning worker training beside it (measured side by side, one run).

Runs the real live loop (:class:`app.live.LiveLoop`: the one ``Runner.step`` at wall-clock rate, session
recording) on UGV scenario 3 with the committed default policy and its SAGE gate, the scripted expert answering
takeovers, three ways in turn:

* ``alone``: fine-tuning off;
* ``worker``: the fine-tuning worker process (``core.worker``) training on the session the loop records; the
  measurement starts once the worker is inside a round (``training``) and the round is long enough to last it;
* ``alone`` again, to show the machine's load did not drift.

For each: achieved loop rate (steps/s against the 10 Hz target), the time inside one step (p50 / p95 / max),
and the lateness of steps against the 100 ms schedule (p95 / max), then the free-running rate (speed x50, no
waiting: how much of the core the loop gets) with and without the worker.

    python bench/bench_finetune.py [--seconds 20] [--policy policies/ugv-default]
"""

from __future__ import annotations

import argparse
import contextlib
import sys
import tempfile
import time
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.commands import SetSpeed  # noqa: E402
from app.live import FinetuneSettings, LiveConfig, LiveLoop  # noqa: E402
from app.operator import OperatorConsole  # noqa: E402
from app.policies import load_policy  # noqa: E402
from app.server import make_env  # noqa: E402
from core.finetune import FinetuneConfig  # noqa: E402
from core.sessions import SessionStore  # noqa: E402


def build(policy: str, sessions: Path, finetune: FinetuneSettings | None, speed: float) -> LiveLoop:
    config = LiveConfig(sim="ugv", scenario="3", policy=policy, expert_mode="scripted", speed=speed)
    loop = LiveLoop(
        config,
        env_factory=make_env,
        policy_loader=load_policy,
        console=OperatorConsole(),
        publish=lambda text: None,
        store=SessionStore(sessions),
        finetune=finetune,
    )
    loop.step_costs = deque(maxlen=1_000_000)
    loop.step_times = deque(maxlen=1_000_000)
    return loop


def measure(loop: LiveLoop, seconds: float, speed: float) -> dict[str, float]:
    loop.submit(SetSpeed(speed)).result(10)
    loop.step_costs.clear()
    loop.step_times.clear()
    time.sleep(seconds)
    costs = np.array(loop.step_costs) * 1000
    times = np.array(loop.step_times)
    period = loop.world.dt / speed
    gaps = np.diff(times) if len(times) > 1 else np.array([np.nan])
    late = np.maximum(gaps - period, 0.0) * 1000
    rate = (len(times) - 1) / (times[-1] - times[0]) if len(times) > 2 else float("nan")
    return {
        "rate": rate,
        "target": 1.0 / period,
        "step_p50": float(np.percentile(costs, 50)),
        "step_p95": float(np.percentile(costs, 95)),
        "step_max": float(costs.max()),
        "late_p95": float(np.percentile(late, 95)),
        "late_max": float(late.max()),
        "steps": float(len(times)),
    }


def line(name: str, r: dict[str, float]) -> str:
    return (
        f"  {name:<16} {r['rate']:7.2f} steps/s (target {r['target']:.0f})  step p50 {r['step_p50']:5.2f} ms  "
        f"p95 {r['step_p95']:5.2f} ms  max {r['step_max']:6.2f} ms  late p95 {r['late_p95']:5.1f} ms  "
        f"max {r['late_max']:6.1f} ms  ({r['steps']:.0f} steps)"
    )


def wait_for_training(loop: LiveLoop, timeout: float) -> dict[str, Any]:
    """Run the loop fast until the worker is inside a round (it needs one finished episode first)."""
    loop.submit(SetSpeed(20.0)).result(10)
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        status = loop.world.versions.service.status() if loop.world.versions else {}
        if status.get("phase") == "training":
            return status
        time.sleep(0.2)
    raise SystemExit(f"the worker did not start training within {timeout:.0f} s: {status}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=20.0, help="measurement window per run")
    parser.add_argument("--policy", default=str(ROOT / "policies" / "ugv-default"), help="run folder or checkpoint")
    args = parser.parse_args()
    torch.set_num_threads(1)
    if not Path(args.policy).exists():
        raise SystemExit(f"no policy at {args.policy}: give --policy a trained UGV run")
    tmp = Path(tempfile.mkdtemp(prefix="bench-finetune-"))
    # a round long enough to outlast the measurement: the worker trains throughout
    settings = FinetuneSettings(tmp / "finetune", FinetuneConfig(updates=1_000_000, report_every=50))
    results: dict[str, dict[str, float]] = {}
    print(f"bench_finetune: UGV scenario 3, policy {args.policy}, {args.seconds:.0f} s per run, 2 cores shared")
    for name, finetune in (("alone", None), ("worker training", settings), ("alone again", None)):
        loop = build(args.policy, tmp / name.replace(" ", "-"), finetune, speed=1.0)
        loop.start()
        try:
            if finetune is not None:
                status = wait_for_training(loop, timeout=300)
                print(f"  (worker pid {status['pid']} training, round of {status['progress'].get('updates')} updates)")
            results[name] = measure(loop, args.seconds, speed=1.0)
            results[name + ", free"] = measure(loop, args.seconds / 2, speed=50.0)
            if finetune is not None:
                versions = loop.world.versions
                assert versions is not None  # a trained policy on a recorded session: fine-tuning runs
                status = versions.service.status()
                assert status["phase"] == "training" and status["alive"], status
                done = status["progress"].get("update")
                print(f"  (worker still training: its round stood at update {done})")
        finally:
            with contextlib.suppress(Exception):
                loop.stop()
    print("\n  10 Hz live loop (wall clock):")
    for name in ("alone", "worker training", "alone again"):
        print(line(name, results[name]))
    print("  free-running (speed x50, how much CPU the loop gets):")
    for name in ("alone", "worker training", "alone again"):
        print(line(name, results[name + ", free"]))

    def alone(key: str, suffix: str = "") -> float:  # the mean of the runs before and after: load drift cancels
        return (results["alone" + suffix][key] + results["alone again" + suffix][key]) / 2

    busy, free = results["worker training"], results["worker training, free"]
    print(
        f"\n  ratios worker / alone (mean of both alone runs): 10 Hz rate {busy['rate'] / alone('rate'):.3f}, "
        f"step p95 {busy['step_p95'] / alone('step_p95'):.2f}x, late p95 {busy['late_p95'] / alone('late_p95'):.2f}x, "
        f"free-running rate {free['rate'] / alone('rate', ', free'):.2f}"
    )


if __name__ == "__main__":
    main()
