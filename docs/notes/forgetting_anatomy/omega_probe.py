"""Value-weighted imitation's ω at the last cycle's labelled states and at its takeover onsets, as the last round's
critic (version 8, trained on cycles 1-8) weighs them in cycle 9 (issue 62; docs/notes/forgetting_anatomy.md).

    python docs/notes/forgetting_anatomy/omega_probe.py results/cycles-small-anatomy-c1 [...]

ω = exp(clip((Q(s,a_E) - Q(s,a_RL)) / (T · max(1, mean|Q|)), ±clip)) with the learner's defaults T = 0.1, clip = 3
(mean|Q| over the episode's labelled states, where the learner takes it over its batch).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[3]))

from core.agents import load_agent
from core.sessions import SessionStore
from core.versions import VersionStore
from studies.cycles import read_cycles


def probe(arm: Path, cycle: int = 9, version: int = 8) -> str:
    every: list[float] = []
    at_onsets: list[float] = []
    for trial in sorted((arm / "runs").glob("sage-s*")):
        run = read_cycles(trial)
        episodes = [int(e["episode"]) for e in run["episodes"] if int(e["cycle"]) == cycle]
        critic = load_agent(VersionStore(trial / "versions").get(version).path).learner.critic  # type: ignore[attr-defined]
        store = SessionStore(trial / "sessions")
        session = store.list_sessions()[0].id
        for episode in episodes:
            s = store.steps(session, episode=episode)
            take = s["takeover"]
            idx = np.flatnonzero(~np.isnan(s["a_expert"]).any(1))
            if len(idx) == 0:
                continue
            obs = torch.as_tensor(s["obs"][idx])
            with torch.no_grad():
                q_expert = critic(obs, torch.as_tensor(s["a_expert"][idx])).min(0).values
                q_agent = critic(obs, torch.as_tensor(s["a_rl"][idx])).min(0).values
            scale = 0.1 * max(1.0, float(q_agent.abs().mean()))
            omega = torch.exp(((q_expert - q_agent) / scale).clamp(-3, 3)).numpy()
            onset = np.array([take[i] and (i == 0 or not take[i - 1]) for i in idx])
            every += omega.tolist()
            at_onsets += omega[onset].tolist()
    w, o = np.array(every), np.array(at_onsets)
    return (
        f"{arm.name}: labelled rows {len(w)}, mean ω {w.mean():.2f}, under 0.5 {np.mean(w < 0.5):.2f} | "
        f"takeover onsets {len(o)}, mean ω {o.mean():.2f}, under 0.5 {np.mean(o < 0.5):.2f}"
    )


if __name__ == "__main__":
    for folder in sys.argv[1:]:
        print(probe(Path(folder)))
