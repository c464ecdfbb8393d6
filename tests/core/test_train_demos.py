"""Demonstrations honour --demo-noise: noisy expert actions are what is executed and recorded."""

from __future__ import annotations

import numpy as np

from core.sage.config import for_method
from core.train import RunConfig, Trainer
from tests.core.line_env import LineEnv


def _demo_actions(noise: float) -> np.ndarray:
    run = RunConfig(sim="line", scenarios=["1"], episodes=0, demo_episodes=2, demo_noise=noise, checkpoint_every=0)
    agent = for_method("sac", pretrain_bc_steps=0, pretrain_critic_steps=0)
    trainer = Trainer(run, agent, lambda _s: LineEnv(horizon=6), out=None, progress=False)
    try:
        trainer.demonstrate()
        buffer = trainer.learner.buffer
        return buffer.action[: len(buffer)].copy()
    finally:
        trainer.close()


def test_demo_noise_perturbs_the_demonstrated_actions() -> None:
    clean = _demo_actions(0.0)
    noisy = _demo_actions(0.3)
    assert clean.shape == noisy.shape == (12, 1)
    assert np.all(clean == 1.0), "the line expert always pushes +1"
    assert (noisy < 0.99).sum() >= 3 and np.all(noisy >= -1.0) and np.all(noisy <= 1.0)
