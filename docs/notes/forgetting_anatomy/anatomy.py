"""Forgetting anatomy (issue 62): the versions of one cycles run alone on the static scenarios, their action
distance to the base along the base's and their own trajectories, and the prior rows' coverage of the failures.

    PYTHONPATH=$PWD OMP_NUM_THREADS=1 python docs/notes/forgetting_anatomy/anatomy.py RUN_FOLDER [versions] > out.json
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
import torch

from core.agents import load_agent
from core.experts import ScriptedExpert
from core.loop import NoGate, Runner
from core.prior import drive_alone
from studies.envs import env_factory

MAKE_ENV = env_factory("ugv")
SEED = 9_000_000  # the study's alone seeds
EPISODES = 10
DIVERGE = 0.2  # action distance that counts as diverged (actions in [-1, 1]^2)


def mu(agent: Any, obs: np.ndarray) -> np.ndarray:
    with torch.no_grad():
        return agent.learner.rollout_policy(torch.from_numpy(np.asarray(obs, np.float32))).cpu().numpy()


def drive(agent: Any, scenario: str) -> list[dict[str, Any]]:
    env = MAKE_ENV(scenario)
    episodes = []
    try:
        runner = Runner(env, agent.policy, NoGate(), ScriptedExpert(), seed=SEED, deterministic=True)
        for _ in range(EPISODES):
            rows: list[Any] = []
            runner.step_listeners[:] = [rows.append]
            summary = runner.run_episode(None)
            m = summary.metrics
            outcome = "success" if m.get("success") else "collision" if m.get("collision") else "timeout"
            episodes.append(
                {
                    "obs": np.stack([r.obs for r in rows]),
                    "action": np.stack([r.a_rl for r in rows]),
                    "outcome": outcome,
                }
            )
    finally:
        env.close()
    return episodes


def drift_stats(base: Any, version: Any, episodes: list[dict[str, Any]]) -> dict[str, Any]:
    obs = np.concatenate([e["obs"] for e in episodes])
    d = mu(version, obs) - mu(base, obs)
    dist = np.linalg.norm(d, axis=1)
    first = []
    for e in episodes:
        de = np.linalg.norm(mu(version, e["obs"]) - mu(base, e["obs"]), axis=1)
        hit = np.flatnonzero(de > DIVERGE)
        first.append(int(hit[0]) if len(hit) else -1)
    return {
        "mean": float(dist.mean()),
        "p90": float(np.quantile(dist, 0.9)),
        "max": float(dist.max()),
        "share_above": float((dist > DIVERGE).mean()),
        "mean_delta_dim": d.mean(0).round(3).tolist(),
        "mean_abs_dim": np.abs(d).mean(0).round(3).tolist(),
        "first_step_above": first,
        "steps": [len(e["obs"]) for e in episodes],
    }


def nn_dist(points: np.ndarray, ref: np.ndarray) -> np.ndarray:
    p = torch.from_numpy(points.astype(np.float32))
    r = torch.from_numpy(ref.astype(np.float32))
    return torch.cdist(p, r).min(1).values.numpy()


def main() -> None:
    run = Path(sys.argv[1])
    numbers = [int(v) for v in (sys.argv[2] if len(sys.argv) > 2 else "2,4,8").split(",")]
    vdir = run / "versions"
    base = load_agent(vdir / "v0000")
    prior = drive_alone(vdir / "v0000", 8, 5_000_000, make_env=MAKE_ENV)  # the fine-tuner's (seed 0) prior rows
    prior_obs = np.stack([r.obs for r in prior])
    out: dict[str, Any] = {"prior_steps": len(prior_obs)}
    base_eps = {s: drive(base, s) for s in ("1", "2")}
    for s, eps in base_eps.items():
        out[f"v0000/{s}"] = {
            "outcomes": [e["outcome"] for e in eps],
            "nn_prior_mean": float(nn_dist(np.concatenate([e["obs"] for e in eps]), prior_obs).mean()),
            "mean_action": np.concatenate([e["action"] for e in eps]).mean(0).round(3).tolist(),
        }
    for n in numbers:
        version = load_agent(vdir / f"v{n:04d}")
        out[f"v{n:04d}/prior"] = drift_stats(base, version, [{"obs": prior_obs}])
        for s in ("1", "2"):
            own = drive(version, s)
            row: dict[str, Any] = {
                "outcomes": [e["outcome"] for e in own],
                "mean_action_own": np.concatenate([e["action"] for e in own]).mean(0).round(3).tolist(),
                "on_base_traj": drift_stats(base, version, base_eps[s]),
                "on_own_traj": drift_stats(base, version, own),
            }
            # where the version's trajectory leaves the base's (same seed, same start)
            leave = []
            for b, v in zip(base_eps[s], own, strict=True):
                k = min(len(b["obs"]), len(v["obs"]))
                gap = np.linalg.norm(b["obs"][:k] - v["obs"][:k], axis=1)
                hit = np.flatnonzero(gap > 0.05)
                leave.append(int(hit[0]) if len(hit) else -1)
            row["first_state_divergence"] = leave
            # failures: the last 10 states before a collision / the last 30 of a timeout; coverage by prior rows
            fail = [e["obs"][-10 if e["outcome"] == "collision" else -30 :] for e in own if e["outcome"] != "success"]
            if fail:
                f = np.concatenate(fail)
                row["fail_nn_prior_mean"] = float(nn_dist(f, prior_obs).mean())
                row["fail_nn_base_traj_mean"] = float(
                    nn_dist(f, np.concatenate([e["obs"] for e in base_eps[s]])).mean()
                )
                dd = mu(version, f) - mu(base, f)
                row["fail_drift_mean"] = float(np.linalg.norm(dd, axis=1).mean())
                row["fail_delta_dim"] = dd.mean(0).round(3).tolist()
                row["fail_mu_version"] = mu(version, f).mean(0).round(3).tolist()
                row["fail_mu_base"] = mu(base, f).mean(0).round(3).tolist()
            out[f"v{n:04d}/{s}"] = row
        print(f"v{n:04d} done", file=sys.stderr)
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
