"""Multi-Hug RL (Wu et al. 2023): human-guided reinforcement learning from interventions, corrective demonstrations
and intervention-based reward shaping, the paper's human-guided UGV baseline.

The agent is soft actor-critic. A supervisor watches and steps in on its own judgement (``takeover_rule =
"supervisor"``): at the dashboard that is the person, who takes over with keyboard or gamepad whenever they choose;
headless, a stand-in (:class:`core.experts.CostSupervisor`) intervenes when the step's safety cost reaches
``supervisor_cost`` and the expert drives for the gate's hold (``GateConfig.hold``). Nothing here predicts danger:
there is no world model, fear or gate, which is what sets SAGE apart.

From the guidance it learns three ways:

- **interventions and corrective demonstrations** are intervention samples (Ξ = 1) of the buffer, demonstrations
  included, and the actor imitates them with the Q-advantage weight of the SAGE imitation term (Hug-DRL weights the
  human's actions by how much better the critic rates them than the agent's own);
- **intervention-based reward shaping**: the agent's last transition before each intervention loses
  ``intervention_penalty`` reward, so the critic learns that what made the person step in was bad;
- **RL** on every transition, the expert's included.
"""

from __future__ import annotations

from typing import Any

from core.sage.sac import SAC


class MultiHug(SAC):
    """SAC with supervisor-initiated interventions, value-weighted imitation and intervention reward shaping (the
    shaping itself is every learner's :meth:`~core.sage.learner.BaseLearner.store`, on with
    ``intervention_penalty`` > 0, as Multi-Hug's preset sets it)."""


PRESET: dict[str, Any] = {
    "takeover": True,
    "imitation": True,
    "takeover_rule": "supervisor",
    "intervention_penalty": 10.0,
}
"""Multi-Hug's settings on top of plain SAC's switches (the registry's preset, :mod:`core.learners`)."""
