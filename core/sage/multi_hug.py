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

from core.protocol import StepRecord
from core.sage.sac import SAC


class MultiHug(SAC):
    """SAC with supervisor-initiated interventions, value-weighted imitation and intervention reward shaping."""

    _last_row: int | None = None
    _last_key: tuple[int, int] | None = None
    shaped = 0
    """Transitions whose reward was shaped by an intervention so far."""

    def store(self, record: StepRecord) -> None:
        buffer = self.buffer
        previous_row, previous_key = self._last_row, self._last_key
        previous_was_agent = previous_row is not None and not bool(buffer.takeover[previous_row])
        same_episode = previous_key == (record.episode, record.t - 1)
        if record.takeover and previous_was_agent and same_episode and self.cfg.intervention_penalty > 0:
            assert previous_row is not None
            buffer.reward[previous_row] -= self.cfg.intervention_penalty
            self.shaped += 1
        self._last_row = buffer.pos
        super().store(record)
        self._last_key = (record.episode, record.t)


PRESET: dict[str, Any] = {
    "takeover": True,
    "imitation": True,
    "takeover_rule": "supervisor",
    "intervention_penalty": 10.0,
}
"""Multi-Hug's settings on top of plain SAC's switches (the registry's preset, :mod:`core.learners`)."""
