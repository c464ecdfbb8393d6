"""The base drives where it is competent, the adapted version where it is not (``finetune.base_first``).

Adaptation and forgetting trade through one actor: every lever measured on the UGV that kept the static scenarios
(a distillation anchor, a regression test) cost adaptation on the crossing scenario, and every round that adapted
forgot some of the static drives (``docs/notes/adaptation_probe.md``). They need not share an actor. SAGE already
tells, state by state, where a policy is out of its depth: its gate fires when the fear of the policy's action
exceeds the curiosity-modulated threshold. That is where the base asked for help, where the takeovers were recorded,
and so where the rounds' imitation and fear-regularised updates taught the version what to do.

So a version published with ``base_first`` carries the base's acting weights beside its own, and
:class:`BaseFirstPolicy` acts in two stages: the base proposes; a *watch* (the version's gate machinery, its world
model and threshold, rolled out with the base's actor from the base's action) judges the proposal as the gate would;
where the watch fires (held as the gate holds), the version acts instead. The loop's own gate then judges whichever
action is proposed, and hands the wheel to the expert as always. Nothing is fitted for the switch: it is the gate's
decision, at the gate's operating point.

The measured alternative, a state-novelty reference of the base's safe drives (the base acts on states as familiar
as 95 % of them), kept the static scenarios but left the crossing to the base: on UGV 3 the crossing's states were
as familiar to it as its own mover fields (the lead's probe in ``docs/notes/adaptation_probe.md``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from core.protocol import Gate, Policy

STATE_KEY = "base_first"
"""The checkpoint's ``state`` entry of a version that lets the base drive first: ``{"acting": the base's acting
module's weights}``."""


class BaseFirstPolicy:
    """A :class:`core.loop.Policy`: the base's action unless ``watch`` (a gate over the base's actions) fires, then
    the version's. The loop tells it where episodes start (:meth:`episode_started`) and what was executed
    (:meth:`stepped`), so that
    the watch keeps the motion history and the curiosity a gate keeps. ``last_base``: which acted on the last call."""

    def __init__(self, version: Policy, base: Policy, watch: Gate) -> None:
        self.version = version
        self.base = base
        self.watch = watch
        self.last_base = True
        self.steps = 0
        self.base_steps = 0

    def episode_started(self) -> None:
        self.watch.reset()

    def act(self, obs: np.ndarray, deterministic: bool = False) -> np.ndarray:
        proposal = np.asarray(self.base.act(obs, deterministic))
        decision = self.watch.decide(obs, proposal)
        self.last_base = not decision.fired
        self.steps += 1
        self.base_steps += int(self.last_base)
        return proposal if self.last_base else np.asarray(self.version.act(obs, deterministic))

    def stepped(self, obs: np.ndarray, action: np.ndarray, next_obs: np.ndarray) -> Any:
        return self.watch.observe(obs, action, next_obs)
