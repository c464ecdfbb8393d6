"""One fine-tuning round of a cycles run replayed with parts of the round switched off (issue 62, forgetting
anatomy): how far each variant's published version moves the actor on the static scenarios' states.

    PYTHONPATH=$PWD OMP_NUM_THREADS=1 python docs/notes/forgetting_anatomy/rounds.py RUN_FOLDER CYCLE [variants] [seed]

The round after cycle CYCLE is rebuilt as the run made it: the base's prior drives (seed 5,000,000), the
session's episodes of cycles 1..CYCLE-1 ingested (held-out bookkeeping as in the run), the fine-tuner rebased on
the version that drove cycle CYCLE, then one round on cycle CYCLE's episodes, published into a scratch copy.
"""

from __future__ import annotations

import functools
import json
import shutil
import sys
import tempfile
import types
from pathlib import Path
from typing import Any

import numpy as np
import torch

from core.agents import load_agent
from core.finetune import FinetuneConfig, Finetuner
from core.prior import drive_alone
from core.sessions import SessionStore
from core.versions import VersionStore
from studies.cycles import drive_alone_rates
from studies.envs import env_factory

sys.path.insert(0, str(Path(__file__).parent))
from anatomy import EPISODES, SEED, drive, mu

MAKE_ENV = env_factory("ugv")

VARIANTS: dict[str, tuple[str, ...]] = {
    "default": (),
    "no_imitation": ("imitation=false",),
    "no_fear": ("fear_regularisation=false",),
    "no_virtual": ("virtual_rollouts=false",),
    "no_cstar": ("violation_penalty=false",),
    "no_actor_rl": (),  # patched: the actor's loss without -Q and α log π (imitation and fear only)
    "base_critic": (),  # patched: the critics are not updated (the actor follows the base's critic)
}


def _actor_loss_without_rl(self: Any, batch: Any, imitation: Any, anchor: Any = None) -> Any:
    """SAC.actor_loss (core/sage/sac.py) with its RL part, mean(α log π - min Q), left out: fear and imitation."""
    from core.sage.sac import actor_fear_weight, advantage_weights, expert_and_agent_q

    cfg = self.cfg
    states, n_real = self.actor_states(batch)
    others = [rows.obs for rows in (imitation, anchor) if rows is not None]
    action, log_prob, modes = self.actor.sample_with_modes(states, *others)
    with torch.no_grad():
        q = self.critic(states, action).min(0).values
    loss = torch.zeros((), device=states.device)
    stats: dict[str, float] = {}
    q_scale = q.abs().mean().clamp_min(1.0)
    if self.fear_active():
        fear_values = self.learner_fear(states, action)
        loss = loss + actor_fear_weight(self.lam, q_scale, cfg.fear_scale) * fear_values.mean()
        stats["fear_real"] = fear_values[:n_real].mean().item()
        stats["fear_budget"] = self.fear_budget()
    if imitation is not None:
        with torch.no_grad():
            q_expert, q_agent = expert_and_agent_q(self.critic, imitation)
            omega = advantage_weights(q_expert, q_agent, q_scale, cfg.advantage_temperature, cfg.advantage_clip)
        bc = (omega * (modes[0] - imitation.a_expert).pow(2).sum(-1)).mean()
        loss = loss + cfg.bc_weight * q_scale * bc
        stats.update(bc_loss=bc.item(), omega_mean=omega.mean().item())
    return loss, log_prob, stats


def main() -> None:
    run, cycle = Path(sys.argv[1]), int(sys.argv[2])
    names = sys.argv[3].split(",") if len(sys.argv) > 3 else list(VARIANTS)
    seed = int(sys.argv[4]) if len(sys.argv) > 4 else 0  # the round's sampling seed (the run's: its training seed)
    payload = json.loads((run / "cycles.json").read_text())
    session = payload["session"]
    by_cycle: dict[int, list[int]] = {}
    for e in payload["episodes"]:
        by_cycle.setdefault(int(e["cycle"]), []).append(int(e["episode"]))
    drove = int(next(r for r in payload["cycles"] if int(r["cycle"]) == cycle)["version"])
    base = load_agent(run / "versions" / "v0000")
    start = load_agent(run / "versions" / f"v{drove:04d}")
    static = {s: np.concatenate([e["obs"] for e in drive(base, s)]) for s in ("1", "2")}
    out: dict[str, Any] = {"cycle": cycle, "start_version": drove}
    for name in names:
        with tempfile.TemporaryDirectory() as tmp:
            vroot = Path(tmp) / "versions"
            vroot.mkdir()
            for v in range(drove + 1):
                shutil.copytree(run / "versions" / f"v{v:04d}", vroot / f"v{v:04d}")
            versions = VersionStore(vroot)
            cfg = FinetuneConfig(min_steps=1, min_takeover_samples=0, seed=seed, overrides=VARIANTS[name])
            prior = functools.partial(drive_alone, make_env=MAKE_ENV, max_steps=None)
            ft = Finetuner(versions, SessionStore(run / "sessions"), session, cfg, base=0, prior=prior)
            ft.collect_prior()
            for c in range(1, cycle):
                ft.done.extend(ft._ingest(by_cycle[c]).episodes)
            ft.done.extend(e for c, eps in by_cycle.items() if c > cycle for e in eps)
            ft.rebase(drove)
            learner = ft.learner
            if name == "no_actor_rl":
                learner.actor_loss = types.MethodType(_actor_loss_without_rl, learner)
            if name == "base_critic":
                learner.critic_step = lambda batch: {}
            torch.manual_seed(seed)
            result = ft.round()
            assert result.version is not None, result.reason
            new = load_agent(result.version.path)
            losses = {k: round(v, 4) for k, v in result.losses.items()}
            row: dict[str, Any] = {"updates": result.updates, "losses": losses}
            for s, obs in static.items():
                d = mu(new, obs) - mu(start, obs)
                d0 = mu(new, obs) - mu(base, obs)
                row[f"static{s}_step_drift"] = float(np.linalg.norm(d, axis=1).mean())
                row[f"static{s}_step_delta_dim"] = d.mean(0).round(3).tolist()
                row[f"static{s}_drift_from_base"] = float(np.linalg.norm(d0, axis=1).mean())
                row[f"static{s}_alone"] = drive_alone_rates(result.version.path, MAKE_ENV, s, EPISODES, SEED, None)
            take = learner.buffer.takeover[: len(learner.buffer)]
            tobs = learner.buffer.obs[: len(learner.buffer)][take]
            row["takeover_states_drift"] = float(np.linalg.norm(mu(new, tobs) - mu(start, tobs), axis=1).mean())
            row["alone3"] = drive_alone_rates(result.version.path, MAKE_ENV, "3", EPISODES, SEED, None)
            out[name] = row
            print(name, json.dumps(row), file=sys.stderr, flush=True)
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
