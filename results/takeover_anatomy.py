"""Where the last cycle's takeovers come from: the policy's proposal at each takeover onset against the expert's
action, and the last version's gate monitoring (never taking over) the version and the scripted expert driving.

    python results/takeover_anatomy.py ARM_DIR [ARM_DIR ...] [--out FILE.md] [--episodes 20]

Each ARM_DIR is a ``sage study cycles --out`` folder (its ``runs/<method>-s<seed>`` trials with sessions and
versions). The reading is in ``results/cycles-twentyeighth-takeover-anatomy.sh``, written before the runs.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from core.agents import load_agent
from core.experts import ExpertPolicy
from core.loop import Runner
from core.sessions import SessionStore
from core.versions import VersionStore
from studies.cycles import gate_for, read_cycles
from studies.envs import env_factory

AGREE = 0.25
MONITOR_SEED = 9_100_000


def onsets(trial: Path) -> dict[str, Any]:
    """Takeover onsets in the last cycle: how many, and how many where the policy proposed what the expert did."""
    run = read_cycles(trial)
    last = max(int(e["cycle"]) for e in run["episodes"])
    episodes = [int(e["episode"]) for e in run["episodes"] if int(e["cycle"]) == last]
    store = SessionStore(trial / "sessions")
    session = store.list_sessions()[0].id
    n_onsets = agree = steps = takeovers = 0
    gaps: list[float] = []
    for episode in episodes:
        s = store.steps(session, episode=episode)
        take = s["takeover"]
        steps += len(take)
        takeovers += int(take.sum())
        for t in np.flatnonzero(take):
            if t > 0 and take[t - 1]:
                continue
            n_onsets += 1
            gap = float(np.nanmax(np.abs(s["a_rl"][t] - s["a_expert"][t])))
            gaps.append(gap)
            agree += int(gap <= AGREE)
    version = max(int(e["version"]) for e in run["episodes"] if int(e["cycle"]) == last)
    return {
        "last_cycle": last,
        "version": version,
        "steps": steps,
        "takeover": takeovers / max(steps, 1),
        "onsets": n_onsets,
        "agree": agree,
        "median_gap": float(np.median(gaps)) if gaps else float("nan"),
    }


def firing_share(trial: Path, version: int, scenario: str, episodes: int, expert_drives: bool) -> dict[str, Any]:
    """The version's gate monitoring ``episodes`` drives (the version's or the scripted expert's), never taking over."""
    path = VersionStore(trial / "versions").get(version).path
    agent = load_agent(path)
    make_env = env_factory(str(read_cycles(trial)["config"]["sim"]))
    env = make_env(scenario)
    fired = steps = collisions = 0
    try:
        policy = ExpertPolicy(env) if expert_drives else agent.policy
        runner = Runner(env, policy, gate_for(agent), None, seed=MONITOR_SEED, deterministic=True)

        def count(record: Any) -> None:
            nonlocal fired, steps
            fired += int(record.gate_fired)
            steps += 1

        runner.step_listeners.append(count)
        for _ in range(episodes):
            summary = runner.run_episode(None)
            collisions += int(float(summary.metrics.get("collision") or 0.0) > 0)
    finally:
        env.close()
    return {"fired": fired / max(steps, 1), "steps": steps, "collisions": collisions, "episodes": episodes}


def arm(folder: Path, episodes: int) -> dict[str, Any]:
    trials = sorted(p.parent for p in (folder / "runs").glob("*/cycles.json"))
    if not trials:
        raise SystemExit(f"{folder}: no finished trials under runs/")
    rows = []
    for trial in trials:
        row: dict[str, Any] = {"trial": trial.name, **onsets(trial)}
        scenario = str(read_cycles(trial)["config"]["scenario"])
        row["fired_version"] = firing_share(trial, row["version"], scenario, episodes, expert_drives=False)
        row["fired_expert"] = firing_share(trial, row["version"], scenario, episodes, expert_drives=True)
        rows.append(row)
        print(json.dumps(row), flush=True)
    total_onsets = sum(r["onsets"] for r in rows)
    return {
        "folder": str(folder),
        "trials": rows,
        "takeover_last": float(np.mean([r["takeover"] for r in rows])),
        "onset_agreement": sum(r["agree"] for r in rows) / max(total_onsets, 1),
        "onsets": total_onsets,
        "fired_version": float(np.mean([r["fired_version"]["fired"] for r in rows])),
        "fired_expert": float(np.mean([r["fired_expert"]["fired"] for r in rows])),
        "version_collisions": sum(r["fired_version"]["collisions"] for r in rows),
        "expert_collisions": sum(r["fired_expert"]["collisions"] for r in rows),
        "monitor_episodes": sum(r["fired_version"]["episodes"] for r in rows),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("arms", nargs="+", type=Path)
    parser.add_argument("--out", type=Path)
    parser.add_argument("--episodes", type=int, default=20)
    args = parser.parse_args()
    results = [arm(folder, args.episodes) for folder in args.arms]
    lines = [
        "| arm | takeover, last cycle | onsets | policy proposes the expert's action (within 0.25) | gate fires, "
        "version driving | gate fires, scripted expert driving | collisions monitored (version / expert) |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in results:
        lines.append(
            f"| {Path(r['folder']).name} | {r['takeover_last']:.3f} | {r['onsets']} | {r['onset_agreement']:.2f} | "
            f"{r['fired_version']:.3f} | {r['fired_expert']:.3f} | {r['version_collisions']} / "
            f"{r['expert_collisions']} of {r['monitor_episodes']} |"
        )
    table = "\n".join(lines)
    print(table)
    if args.out:
        args.out.write_text(table + "\n\n```json\n" + json.dumps(results, indent=1) + "\n```\n")


if __name__ == "__main__":
    main()
