"""The settings of a fine-tuning round (:class:`FinetuneConfig`), apart from the round itself (:mod:`core.finetune`,
which re-exports them): every field carries what it does and, where a measurement chose its default, which."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any, Literal

TauBoundsRule = Literal["hold", "refit", "drift"]


@dataclass
class FinetuneConfig:
    """One round of fine-tuning on recorded session data (the learner's hyperparameters come from the checkpoint;
    with ``adapt_as_sage`` its method becomes SAGE's)."""

    adapt_as_sage: bool = True
    """Adapt as fear-regularised SAGE whatever the base was trained as: the checkpoint's configuration with SAGE's
    switches on (fear regularisation, the c* penalty, virtual rollouts, value-weighted imitation; its
    hyperparameters kept), so a policy trained as plain SAC adapts as SAGE-SAC and one trained as D3QN as SAGE-D3QN
    (:data:`SAGE_COUNTERPART`). A method without a SAGE counterpart (TD3, HG-DAgger, diffusion) keeps its own and
    the round says so. False: continue the checkpoint's own configuration (the behaviour before this field)."""
    updates_per_step: float | None = 1.0
    """Update-to-data ratio: gradient updates per environment step the round ingested (updates per step; RLPD and
    HIL-SERL scale updates to the data this way), at most ``updates``. None: exactly ``updates`` a round."""
    updates: int = 2000
    """Gradient updates per round: the cap of ``updates_per_step`` (a round's wall time stays bounded), or the
    round's fixed number when ``updates_per_step`` is None."""
    prior_share: float = 0.5
    """Share of every sampled batch (critic, actor, virtual-rollout starts) drawn from the base policy's own
    drives (:func:`drive_alone`, when the fine-tuner is given a ``prior`` source), the rest from the session's data
    (takeovers and the agent's own steps): RLPD / HIL-SERL's equal shares, so that what the base learned on its
    own scenarios stays in every update instead of being forgotten. Ignored while either part is empty."""
    prior_episodes: int = 8
    """Episodes the base policy (``v0000``) drives alone, deterministic, over its training scenarios in turn, to
    fill the prior part of the buffer (once per fine-tuner; 0: none)."""
    holdout_share: float = 0.2
    """Share of the session's episodes with takeovers whose takeover rows are held out of imitation (every
    ``round(1 / share)``-th such episode, in recording order) to measure how imitation transfers to takeover
    states it did not train on. 0: no held-out takeovers, no early stopping."""
    early_stop_every: int = 50
    """Updates between measurements of the held-out takeovers' imitation error, mean ||π(s) - a_E||² (the
    squared distance in the learner's action encoding)."""
    early_stop_patience: int = 4
    """Measurements without a new lowest held-out error before the round stops; the weights of the lowest
    measurement (the round's starting weights count as the first) are the ones published."""
    critic_warmup: int = 0
    """Updates at the start of every round that train the critics only (the actor, α and λ held; the anchors'
    critic warm-up), so that the actor is not pushed by a critic that has not yet seen the round's new data (and,
    in the first round, SAGE's fear-regularised target on a base trained as plain SAC). Counted within the round's
    planned updates (the round's cost is unchanged; the actor gets the rest); early stopping measures only after it.
    A learner without a separate critic step (D3QN: its whole update is the value network) runs its usual update.
    0: none (the behaviour before this field)."""
    prior_distill: float = 0.5
    """Weight of a distillation anchor on the base policy's own drives: the actor's loss gains
    ``prior_distill · max(1, mean|Q|) · mean ||μ_θ(s) - a_base||²`` over a batch of ``bc_batch_size`` prior rows, a_base
    the action the base (``v0000``) took there (its deterministic action: the drives run deterministic, no gate). The
    weight is dimensionless, on the imitation term's scale (``bc_weight · max(1, mean|Q|) · mean ω||μ_θ(s) - a_E||²``):
    1.0 pulls toward the base's actions on its own states as hard as imitation pulls toward the expert's at ω = 1.
    The prior rows otherwise train only the critic; this holds the actor to what the base did there (forgetting of
    the static scenarios). Actor-critic SAC learners only (a learner without it runs without, and says so once). 0:
    none (the behaviour before this field). 0.5 with ``anchor_relabel`` is the default since 2026-11-29, adopted by
    the rule of docs/notes/forgetting_anatomy.md (arm C, confirmed on UGV 4: static scenarios alone after nine cycles
    0.31 -> 0.76 on UGV 3, 0.32 -> 0.68 on UGV 4, the crossing kept)."""
    anchor_relabel: bool = True
    """With ``prior_distill`` > 0: before every round the version in control drives the prior drives' situations
    alone (the same episodes: scenarios and seeds, deterministic, no gate), and the anchor holds the actor, on the
    situations the base drove to success, to the base's deterministic action at the base's states *and* at the states
    the versions reached there (DAgger's relabelling with the base as teacher; the rows accumulate over the rounds).
    The situations the base failed (e.g. its own collisions among movers) are left out of the anchor. Measured before
    it (docs/notes/forgetting_anatomy.md): the base's static skill breaks under a turn bias of 0.05, the versions'
    failures lie off the prior rows, and the prior rows alone do not hold the actor. False: the anchor draws the
    buffer's prior rows (the behaviour before this field). Without the base's drives (``prior_episodes`` 0, or no
    prior source) there is nothing to relabel and the anchor draws no rows."""
    anchor_drives_learn: bool = False
    """With ``anchor_relabel``: the version's drives of the prior situations (driven before every round for the
    anchor) also join the buffer's prior part as the agent's own steps, collisions included, so that the critic and
    the world model see what the version's drift does where the base's skill is narrow (a turn bias of 0.05 breaks
    the static scenarios: docs/notes/forgetting_anatomy.md) instead of only the base's successful drives there. No
    extra simulation: the drives are the anchor's. False: the drives only label the anchor (the behaviour before
    this field)."""
    round_keep: float = 0.5
    """Share of a round's change of the actor's and the critics' weights that its version keeps: published weights
    ``start + round_keep · (end - start)``, start the version in control, end the round's kept weights (a Polyak
    average with the version in control, each element; so across rounds an exponential average of the rounds'
    results). α, λ and the optimiser states are the round's. 1.0: the round's weights (before this field). 0.5 was
    chosen by a five-seed UGV 3 cycles arm under a rule written before it (docs/notes/adaptation_probe.md)."""
    base_first: bool = False
    """Publish versions that let the base policy drive first (:mod:`core.familiar`): each version carries v0000's
    acting weights beside its own and acts as v0000 wherever its gate, watching v0000's action, would not ask for
    help; where it would (where v0000 is out of its depth, where the takeovers were recorded) the version's own actor
    acts, and the loop's gate judges that as always. What the rounds learn then acts only there, so the base's skills
    elsewhere are not forgotten (issue 62). False: the version acts alone (the behaviour before this field)."""
    practice_episodes: int = 0
    """Before every round that trains, the version in control drives this many episodes of the session's scenario
    alone in simulation (deterministic, no gate, no expert; new seeds each round, apart from every evaluation's), and
    their steps, collisions included, join the round's buffer as the agent's own: under supervision the expert
    replaces the agent's action where fear is high, so the critic and the world model never see what that action led
    to (docs/notes/route_shift_budget.md); here they do, without a robot crashing (issue 62, item 3). Needs a practice
    source (``Finetuner(practice=...)``: the cycles study and the live worker give one); these steps are not
    deployment steps and are reported apart (``practice_steps``). 0: none (the behaviour before this field)."""
    tau_bounds: TauBoundsRule = "hold"
    """What a world-model refit does to the gate's threshold bounds (τ_min, τ_max, measured on the fear of
    familiar states): ``hold`` keeps the base's within the run of rounds, so that a change in takeover rate is the
    policy's, not the gate's; ``refit`` takes the refit's every round (the behaviour before this field); ``drift``
    takes the refit's only when its τ_max differs from the held one by more than ``tau_drift`` (relative)."""
    tau_drift: float = 0.5
    """With ``tau_bounds="drift"``: the relative change of τ_max (|new - held| / held) that adopts new bounds."""
    carry_optimizer: bool = True
    """Continue the checkpoint's optimiser states (Adam's moments and step count) where it holds them, rather than
    a fresh Adam whose first steps are the largest. False: fresh optimisers."""
    min_new_episodes: int = 1
    """Episodes that must have ended since the last round before the next one starts."""
    min_steps: int = 200
    """Recorded steps needed before the first round: a version fine-tuned on a single short episode (22 takeover
    samples, measured) collided more than the one it replaced."""
    min_takeover_samples: int = 50
    """Takeover (expert-labelled) steps needed before the first round: they are what imitation learns from."""
    refit_world_model: bool = True
    """Refit the world model on the buffer (the base's drives and the session's) at every round, so that fear and
    curiosity learn the new ground (the τ bounds then follow ``tau_bounds``)."""
    wm_min_steps: int = 100
    """Steps in the buffer before the world model is refitted (a fit on fewer overfits the hold-out split)."""
    max_skipped_fraction: float = 0.25
    """A round that had to undo more than this share of its updates (non-finite losses) publishes nothing."""
    report_every: int = 20
    """Updates between progress events."""
    overrides: tuple[str, ...] = ()
    """``key=value`` edits of the round's :class:`~core.sage.config.AgentConfig` (``bc_weight=2``), applied after
    the SAGE switches."""
    seed: int = 0
    """Seeds the learner's sampling (torch and numpy)."""
    device: str = "auto"
    """Where the rounds' updates run (``auto``, ``cpu``, ``cuda``: :func:`core.device.resolve_device`)."""

    def __post_init__(self) -> None:
        if self.updates < 0 or self.min_new_episodes < 1 or self.min_steps < 1 or self.report_every < 1:
            raise ValueError("updates >= 0, min_new_episodes >= 1, min_steps >= 1 and report_every >= 1 are needed")
        if self.min_takeover_samples < 0:
            raise ValueError(f"min_takeover_samples must be >= 0, got {self.min_takeover_samples}")
        if not 0.0 <= self.max_skipped_fraction <= 1.0:
            raise ValueError(f"max_skipped_fraction must be in [0, 1], got {self.max_skipped_fraction}")
        if self.updates_per_step is not None and not (
            math.isfinite(self.updates_per_step) and self.updates_per_step > 0
        ):
            raise ValueError(f"updates_per_step must be a number > 0 or None, got {self.updates_per_step}")
        if not 0.0 <= self.prior_share < 1.0:
            raise ValueError(f"prior_share must be in [0, 1), got {self.prior_share}")
        if not 0.0 <= self.holdout_share <= 0.5:
            raise ValueError(f"holdout_share must be in [0, 0.5], got {self.holdout_share}")
        if not (math.isfinite(self.prior_distill) and self.prior_distill >= 0):
            raise ValueError(f"prior_distill must be a number >= 0, got {self.prior_distill}")
        if not (math.isfinite(self.round_keep) and 0.0 < self.round_keep <= 1.0):
            raise ValueError(f"round_keep must be in (0, 1], got {self.round_keep}")
        if self.critic_warmup < 0:
            raise ValueError(f"critic_warmup must be >= 0, got {self.critic_warmup}")
        if self.prior_episodes < 0 or self.early_stop_every < 1 or self.early_stop_patience < 1:
            raise ValueError("prior_episodes >= 0, early_stop_every >= 1 and early_stop_patience >= 1 are needed")
        if self.tau_bounds not in ("hold", "refit", "drift"):
            raise ValueError(f"tau_bounds must be hold, refit or drift, got {self.tau_bounds!r}")
        if not self.tau_drift > 0:
            raise ValueError(f"tau_drift must be > 0, got {self.tau_drift}")

    @classmethod
    def legacy(cls, **overrides: Any) -> FinetuneConfig:
        """The rounds as they were before these fields (issue 62), for comparisons: the checkpoint's own method,
        400 updates a round whatever the data, the session's data only, no held-out takeovers, τ bounds refitted
        every round. The optimiser states were carried then too."""
        values: dict[str, Any] = {
            "adapt_as_sage": False,
            "updates_per_step": None,
            "updates": 400,
            "prior_episodes": 0,
            "holdout_share": 0.0,
            "tau_bounds": "refit",
            "round_keep": 1.0,
            "prior_distill": 0.0,
            "anchor_relabel": False,
        }
        return cls(**{**values, **overrides})

    def with_settings(self, pairs: Iterable[str]) -> FinetuneConfig:
        """A copy with ``key=value`` settings of these fields (``updates_per_step=2``; ``none`` for None), checked as
        the constructor checks them; an unknown field or an unreadable value is a ValueError naming it."""
        from core.sage.config import set_field

        edited = dataclasses.replace(self)
        for pair in pairs:
            if "=" not in pair:
                raise ValueError(f"fine-tuning setting {pair!r} is not of the form key=value")
            key, value = (part.strip() for part in pair.split("=", 1))
            if key == "overrides":
                raise ValueError("learner overrides are --set learner settings, not finetune.overrides")
            set_field(edited, key, value)
        return dataclasses.replace(edited)  # runs __post_init__'s checks on the edited values

    def round_updates(self, new_steps: int) -> int:
        """The updates a round runs after ingesting ``new_steps`` environment steps."""
        if self.updates_per_step is None:
            return self.updates
        return min(self.updates, math.ceil(self.updates_per_step * new_steps))
