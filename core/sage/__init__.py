"""SAGE: world-model ensemble, fear, curiosity, threshold, gate and the fear-regularised learners.

Pure torch and numpy: nothing here imports a simulator or the web app.

- :mod:`core.sage.world_model` ensemble of probabilistic MLPs over (Δstate, cost)
- :mod:`core.sage.fear` short-horizon fear, curiosity, curiosity-modulated threshold
- :mod:`core.sage.gate` the SAGE gate (:class:`core.protocol.Gate`)
- :mod:`core.sage.sac` SAC / FNI-RL / SAGE-SAC; :mod:`core.sage.td3`; :mod:`core.sage.hg_dagger`
- :mod:`core.sage.config` typed configuration and the per-method presets
"""

from __future__ import annotations

import numpy as np

from core.sage.config import AgentConfig
from core.sage.learner import BaseLearner


def make_learner(
    cfg: AgentConfig,
    obs_dim: int,
    act_dim: int,
    action_low: np.ndarray | None = None,
    action_high: np.ndarray | None = None,
    seed: int = 0,
) -> BaseLearner:
    """The learner of ``cfg.method`` from the registry (:mod:`core.learners`; SAC carries sage, sac and fni-rl
    through its switches)."""
    from core.learners import make_learner as make_registered

    return make_registered(cfg.method, cfg, obs_dim, act_dim, action_low, action_high, seed)
