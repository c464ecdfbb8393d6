"""SAGE: world-model ensemble, fear, curiosity, threshold, gate and the fear-regularised learners.

Pure torch and numpy: nothing here imports a simulator or the web app.

- :mod:`core.sage.world_model` ensemble of probabilistic MLPs over (Δstate, cost)
- :mod:`core.sage.fear` short-horizon fear, curiosity, curiosity-modulated threshold
- :mod:`core.sage.calibration` κ and the threshold bounds set from real states, and the sample a run keeps for it
- :mod:`core.sage.gate` the SAGE gate (:class:`core.protocol.Gate`)
- :mod:`core.sage.sac` SAC / FNI-RL / SAGE-SAC; :mod:`core.sage.td3`; :mod:`core.sage.hg_dagger`
- :mod:`core.sage.config` typed configuration and the per-method presets

Learners are built by name from the registry, :func:`core.learners.make_learner`.
"""

from __future__ import annotations
