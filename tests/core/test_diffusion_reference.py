"""Diffusion-QL's speed-ups change no number: a seeded learner's offline updates and its sampled actions equal the
ones the code before them recorded (commit c00700f, ``data/diffusion_ql_reference.npz``; float32, so equal up to
rounding). Regenerate only with the reference code checked out: ``python -m tests.core.test_diffusion_reference``."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch

from core.learners import make_learner, preset
from core.loop import StepRecord
from core.sage.diffusion import DiffusionPolicy

REFERENCE = Path(__file__).parent / "data" / "diffusion_ql_reference.npz"
OBS, ACT, UPDATES = 6, 2, 12


def outputs() -> dict[str, np.ndarray]:
    """Per parameter of the denoiser and the critics, its sum and first entries after ``UPDATES`` updates; the
    losses of each update; the actions it then takes on fixed states (best of the candidates, and the raw sampler)."""
    torch.manual_seed(0)
    cfg = preset("diffusion-ql", hidden=32, batch_size=64, **{"diffusion.hidden": 32})
    policy = make_learner("diffusion-ql", cfg, OBS, ACT, -np.ones(ACT), np.ones(ACT), seed=3)
    assert isinstance(policy, DiffusionPolicy)
    rng = np.random.default_rng(0)
    for t in range(300):
        obs, action = rng.normal(size=OBS).astype(np.float32), rng.uniform(-1, 1, ACT).astype(np.float32)
        policy.store(
            StepRecord(
                episode=0, t=t, obs=obs, a_rl=action, a_expert=action, action=action, takeover=True, gate_fired=False,
                actor="expert", fear=math.nan, threshold=math.nan, curiosity=math.nan, reward=float(rng.normal()),
                cost=0.0, violation=False, terminated=bool(t % 50 == 49), truncated=False,
                next_obs=rng.normal(size=OBS).astype(np.float32), wall_time=0.0,
            )
        )  # fmt: skip
    losses = []
    for _ in range(UPDATES):
        stats = policy.update()
        losses.append([stats["bc_loss"], stats["critic_loss"], stats["q_loss"]])
    out = {"losses": np.array(losses)}
    for prefix, module in (("denoiser", policy.denoiser), ("critic", policy.critic)):
        for name, value in module.state_dict().items():
            flat = value.detach().double().flatten()
            out[f"{prefix}.{name}"] = np.concatenate([[float(flat.sum())], flat[:8].numpy()])
    states = np.random.default_rng(1).normal(size=(5, OBS)).astype(np.float32)
    out["actions"] = np.stack([policy.act(s, True) for s in states])
    with torch.no_grad():
        out["samples"] = policy.sample(torch.from_numpy(states)).numpy()
    return out


def test_diffusion_ql_updates_and_acts_as_the_reference() -> None:
    with np.load(REFERENCE) as data:
        reference = dict(data)
    now = outputs()
    assert sorted(now) == sorted(reference)
    for key, value in now.items():
        assert np.allclose(value, reference[key], rtol=1e-5, atol=1e-6), key


if __name__ == "__main__":
    REFERENCE.parent.mkdir(exist_ok=True)
    np.savez_compressed(REFERENCE, **outputs())
