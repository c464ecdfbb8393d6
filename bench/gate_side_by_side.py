"""The deployed gate's step with the code at a git revision against the code now, measured side by side.

    .venv/bin/python -m bench.gate_side_by_side --before REV [--policy policies/ugv-default] [--runs 5] [--rounds 8]

A change to the gate's compiled kernels cannot be timed against its predecessor in one process (numba compiles each
module once), and this host's speed drifts by 10-15% within minutes, so runs before and after a change do not compare.
Here the recording of ``bench_gate.py --policy`` (the policy driving with its gate and no expert, ``--record`` steps
of ``--scenario``, seed 0) is made once by the code now, then replayed through the deployed gate by two processes at
once, one on the code now and one on a worktree checked out at ``--before`` (``git worktree``, removed afterwards),
each on its own core (``os.sched_setaffinity`` where there are two), ``--runs`` times: the host's load falls on both.
Each process reports its median CPU time per step (the policy's action, ``decide`` and ``observe``) over ``--rounds``
replays, and whether its fears equal the recording's bit for bit. Printed: each run's pair and ratio.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def save_recording(path: Path, policy: str, scenario: str | None, steps: int) -> str:
    """Record with the code now (``bench_gate.record``) into ``path`` (npz); the scenario recorded."""
    import torch

    from bench.bench_gate import default_scenario, record
    from core.agents import load_agent

    torch.set_num_threads(1)
    agent = load_agent(policy)
    scenario = scenario or default_scenario(agent.meta.sim)
    rec = record(agent, scenario, steps)
    np.savez(
        path,
        first=np.array([s.first for s in rec]),
        obs=np.stack([s.obs for s in rec]),
        a_rl=np.stack([s.a_rl for s in rec]),
        action=np.stack([s.action for s in rec]),
        next_obs=np.stack([s.next_obs for s in rec]),
        fear=np.array([s.fear for s in rec]),
    )
    return scenario


def replay_worker(recording: Path, policy: str, rounds: int, core: int | None) -> dict[str, float]:
    """In the tree this process imports from: the deployed gate over the recording; median CPU ms per step and the
    largest difference of its fears from the recorded ones."""
    if core is not None and hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {core})
    import torch

    torch.set_num_threads(1)
    from bench.bench_gate import Transition, replay
    from core.agents import load_agent

    data = np.load(recording)
    rec = [
        Transition(bool(data["first"][i]), data["obs"][i], data["a_rl"][i], data["action"][i], data["next_obs"][i],
                   float(data["fear"][i]))
        for i in range(len(data["first"]))
    ]  # fmt: skip
    agent = load_agent(policy)
    gate = agent.make_gate()
    fears = replay(agent.policy, gate, rec)  # warm: compiles, or reads numba's cache
    cpu: list[float] = []
    for _ in range(rounds):
        clocks: list[list[float]] = [[], []]
        replay(agent.policy, gate, rec, clocks)
        cpu += clocks[0]
    difference = float(np.nanmax(np.abs(np.array(fears) - data["fear"])))
    return {"median_ms": statistics.median(cpu) * 1e3, "fear_difference": difference}


def side_by_side(before: str, policy: str, scenario: str | None, steps: int, runs: int, rounds: int) -> list[str]:
    """The report's lines: each run's medians (now, before) and their ratio."""
    with tempfile.TemporaryDirectory(prefix="gate-side-by-side-") as tmp:
        recording = Path(tmp) / "recording.npz"
        scenario = save_recording(recording, policy, scenario, steps)
        tree = Path(tmp) / "before"
        subprocess.run(["git", "worktree", "add", "--detach", str(tree), before], cwd=ROOT, check=True,
                       capture_output=True)  # fmt: skip
        try:
            two_cores = (os.cpu_count() or 1) >= 2
            lines = [
                f"`python -m bench.gate_side_by_side --before {before}` ({policy}, {steps} steps of `{scenario}` "
                f"recorded by the code now; {rounds} replays a process; CPU ms per step, median); "
                f"load average {', '.join(f'{x:.2f}' for x in os.getloadavg())} at the start",
                "",
                "| run | now | before | now / before | fears vs the recording (now, before) |",
                "|---|---|---|---|---|",
            ]
            ratios = []
            for run in range(runs):
                procs = {}
                for side, cwd, core in (("now", ROOT, 0), ("before", tree, 1 if two_cores else None)):
                    command = [
                        sys.executable, str(Path(__file__).resolve()), "--replay", str(recording), "--policy",
                        str(Path(policy).resolve()), "--rounds", str(rounds),
                        *(["--core", str(core)] if core is not None and two_cores else []),
                    ]  # fmt: skip
                    env = {**os.environ, "PYTHONPATH": str(cwd)}
                    procs[side] = subprocess.Popen(command, cwd=cwd, env=env, stdout=subprocess.PIPE, text=True)
                out = {}
                for side, proc in procs.items():
                    stdout, _ = proc.communicate()
                    if proc.returncode != 0:
                        raise RuntimeError(f"the {side} replay failed (exit {proc.returncode})")
                    out[side] = json.loads(stdout.strip().splitlines()[-1])
                ratio = out["now"]["median_ms"] / out["before"]["median_ms"]
                ratios.append(ratio)
                lines.append(
                    f"| {run + 1} | {out['now']['median_ms']:.3f} | {out['before']['median_ms']:.3f} | {ratio:.3f} | "
                    f"{out['now']['fear_difference']:.1e}, {out['before']['fear_difference']:.1e} |"
                )
            lines += ["", f"now / before: {min(ratios):.3f}-{max(ratios):.3f} (median {statistics.median(ratios):.3f})"]
            lines.append(f"load average at the end: {', '.join(f'{x:.2f}' for x in os.getloadavg())}")
            return lines
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(tree)], cwd=ROOT, capture_output=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--before", help="the git revision to time against the code now")
    parser.add_argument("--policy", default="policies/ugv-default")
    parser.add_argument("--scenario", help="the scenario recorded (default: bench_gate.py --policy's)")
    parser.add_argument("--record", type=int, default=400, help="steps recorded and replayed")
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--rounds", type=int, default=8, help="replays of the recording a process, after a warm one")
    parser.add_argument("--replay", type=Path, help=argparse.SUPPRESS)  # a worker: replay this recording, print JSON
    parser.add_argument("--core", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.replay:
        print(json.dumps(replay_worker(args.replay, args.policy, args.rounds, args.core)))
        return
    if not args.before:
        parser.error("give --before REV")
    start = time.time()
    print("\n".join(side_by_side(args.before, args.policy, args.scenario, args.record, args.runs, args.rounds)))
    print(f"({time.time() - start:.0f} s)")


if __name__ == "__main__":
    main()
