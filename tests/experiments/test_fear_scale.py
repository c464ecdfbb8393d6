"""experiments/fear_scale.py: the per-term gradients of the actor's loss, measured without touching the run."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import torch

from core.learners import make_learner
from core.sage.config import for_method
from core.sage.sac import SAC
from experiments.fear_scale import Probe, actor_gradients, compare, format_summary

torch.set_num_threads(1)
OBS, ACT = 6, 2


def learner() -> SAC:
    cfg = for_method("sage", hidden=32, batch_size=64, bc_batch_size=32)
    cfg.world_model_config.hidden = 32
    cfg.world_model_config.max_updates_per_fit = 60
    sac = make_learner("sage", cfg, OBS, ACT, seed=0)
    assert isinstance(sac, SAC)
    rng = np.random.default_rng(0)
    s = rng.normal(size=(401, OBS)).astype(np.float32)
    for i in range(400):
        a = rng.uniform(-1, 1, ACT).astype(np.float32)
        takeover = i % 5 == 0
        sac.buffer.add(
            s[i], a, float(-np.abs(s[i]).sum()), s[i + 1], False, cost=float(i % 37 == 0), violation=i % 37 == 0,
            takeover=takeover, a_rl=-a, a_expert=a if takeover else None,
        )  # fmt: skip
    sac.warm = True
    sac.fit_world_model()
    with torch.no_grad():  # values of tens, as in the fine-tuning rounds (mean|Q| ≈ 40 there)
        sac.critic.out.weight.mul_(300.0)
        sac.critic.out.bias.mul_(300.0)
    return sac


def test_every_term_is_measured_and_q_gives_fear_the_larger_share() -> None:
    sac = learner()
    assert sac.fear_active()
    batch = sac.buffer.sample(64, np.random.default_rng(1))
    row = actor_gradients(sac, batch.obs, sac.buffer.sample_takeovers(32, np.random.default_rng(2)))
    for key in ("grad_q_action", "grad_fear_action", "grad_q_params", "grad_fear_params", "grad_bc_params"):
        assert math.isfinite(row[key]) and row[key] > 0.0, key
    assert row["q_scale"] > 5.0
    assert row["fear_share_action_none"] < row["fear_share_action_q"] < 1.0
    assert all(p.grad is None for p in sac.actor.parameters())  # measured, not accumulated into the update


def test_the_probe_leaves_the_runs_random_streams_alone() -> None:
    sac = learner()
    probe = Probe(every=1)
    torch.manual_seed(3)
    state = sac.rng.bit_generator.state
    probe.measure(sac)
    after = torch.rand(4)
    torch.manual_seed(3)
    assert torch.equal(after, torch.rand(4))
    assert sac.rng.bit_generator.state == state
    table = format_summary(probe.summary())
    assert table.count("\n") == 2 and "fear share at a, q" in table


def test_compare_tabulates_each_run_and_sums_each_arm(tmp_path: Path) -> None:
    for arm, seed, last in (("none", 0, 0.7), ("q", 0, 0.5), ("q", 1, 0.2)):
        folder = tmp_path / f"{arm}-s{seed}"
        folder.mkdir()
        cycles = [
            {"alone_success": a, "unseen_success": a, "takeover_rate": 0.3, "collision": 0.2, "episodes": 5}
            for a in (0.1, 0.4, last)
        ]
        overrides = [] if arm == "none" else [f"fear_scale={arm}"]
        run = {"config": {"seed": seed, "finetune": {"overrides": overrides}}, "cycles": cycles}
        (folder / "cycles.json").write_text(json.dumps(run))
        rounds = [{"lam": 1.0, "fear_mean": 0.05, f"fear_share_action_{arm}": 0.1}] * 2
        (folder / "fear_scale.json").write_text(json.dumps({"summary": rounds}))
    table = compare(sorted(tmp_path.iterdir()))
    assert "| none | 0 | 1 → 4 → 7 |" in table and "10.0%, 10.0%" in table
    assert "| q | 2 | 7/20 | 7/20 | 6/30 |" in table  # 5 + 2 of 20; one collision in each of 6 cycles
    assert "| none | 1 | 7/10 | 7/10 | 3/15 |" in table
