"""Continual adaptation: fine-tune the deployed policy on what the loop recorded and publish numbered versions.

The paper's closing loop: deploy → the gate hands risky moments to the expert → the takeovers become targeted
supervision → the deployed policy improves, cycle after cycle. Here one *round* of fine-tuning is
:meth:`Finetuner.round`, the one function that both faces call: the live server's background worker
(:mod:`core.worker`, its own process) and ``sage cycles`` (in-process, between deployment cycles).

A round
  0. starts from the promoted line: when the version the last round published was rejected by the promotion check
     (:mod:`core.promotion`) or rolled back, it continues from the newest version not rejected instead
     (:func:`line_head`), keeping the data;
  1. reads the session's episodes that are over (finished, or followed by a later one) from the session store
     (:class:`core.sessions.SessionStore`; SQLite in WAL mode, so reading while the loop writes is safe) into
     the learner's real replay buffer: the agent's own transitions and the takeover segments, whose rows carry
     the expert's action (Ξ = 1, the intervention samples the value-weighted imitation draws from). Beside them
     lie the base policy's own drives (``prior``, collected once: what it learned on its training scenarios, so
     that it is not forgotten), and every sampled batch takes ``prior_share`` of its rows from those
     (:class:`SharedReplayBuffer`). The takeover rows of some episodes are held out of imitation to measure it;
  2. refits the world model on that buffer (so that fear and curiosity learn the new ground; the gate of the
     next version is built on it), the τ bounds held or refitted by ``tau_bounds``;
  3. runs ``updates_per_step`` gradient updates per new step (at most ``updates``) of the learner: with
     ``adapt_as_sage`` (the default) fear-regularised SAGE with value-weighted imitation of the takeovers whatever
     the base was trained as (:func:`adaptation_config`), its optimiser states continued; each update guarded (an
     update whose losses or weights come out NaN or infinite is undone, :func:`guarded_update`), the first
     ``critic_warmup`` of them on the critics alone (:func:`critic_only_update`), the round stopped
     early when the held-out takeovers' imitation error stops falling, and the weights of its lowest error kept
     (with ``round_keep`` < 1, only that share of their change from the version in control: a Polyak average);
  4. publishes a new version when the round stayed healthy (all weights finite, at most
     ``max_skipped_fraction`` of its updates undone). A failed round publishes nothing, so the last good
     version stays the latest.

Versions (:class:`VersionStore`, numbered folders written atomically) live in :mod:`core.versions`.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
import torch

from core.agents import AgentMeta, load_checkpoint, meta_of
from core.familiar import STATE_KEY as BASE_FIRST_KEY
from core.ingest import Ingested as Ingested
from core.ingest import ingest as ingest
from core.ingest import ready_episodes as ready_episodes
from core.learners import make_learner
from core.prior import PriorSource as PriorSource
from core.prior import SharedReplayBuffer as SharedReplayBuffer
from core.prior import drive_alone as drive_alone
from core.protocol import StepRecord
from core.replay import ReplayBuffer
from core.round_updates import critic_only_update as critic_only_update
from core.round_updates import guarded_update as guarded_update
from core.round_updates import keep_share_of_change as keep_share_of_change
from core.round_updates import weights_finite as weights_finite
from core.sage.config import AgentConfig, apply_overrides, from_dict
from core.sage.learner import BaseLearner
from core.sessions import SessionStore
from core.versions import CHECKPOINT_FILE as CHECKPOINT_FILE
from core.versions import METRICS_FILE as METRICS_FILE
from core.versions import FinetuneError as FinetuneError
from core.versions import Version as Version
from core.versions import VersionStore as VersionStore
from core.versions import line_head as line_head
from core.versions import rejected as rejected
from core.versions import version_name as version_name

Progress = Callable[[dict[str, Any]], None]
"""Receives progress events: ``{"phase": ..., "update": k, "updates": n, "losses": {...}}``."""
ShouldStop = Callable[[], bool]


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


def split_episodes(steps: list[StepRecord]) -> list[list[StepRecord]]:
    """Consecutive steps cut into episodes after each step that ends one (a trailing unfinished one kept)."""
    episodes: list[list[StepRecord]] = [[]]
    for record in steps:
        episodes[-1].append(record)
        if record.done:
            episodes.append([])
    return [episode for episode in episodes if episode]


def succeeded(episode: list[StepRecord]) -> bool:
    """Whether an episode ended in success: its last step's ``info["success"]`` where the simulator reports it,
    else terminated without a violation."""
    last = episode[-1]
    if "success" in last.info:
        return bool(last.info["success"])
    return last.terminated and not last.violation


# -- the fine-tuner --------------------------------------------------------------------------------------------
@dataclass
class RoundResult:
    version: Version | None
    """The published version; None when the round published nothing (see ``reason``)."""
    reason: str = ""
    updates: int = 0
    skipped: int = 0
    losses: dict[str, float] = field(default_factory=dict)
    ingested: Ingested = field(default_factory=Ingested)
    seconds: float = 0.0

    def as_dict(self) -> dict[str, Any]:
        return {
            "version": None if self.version is None else self.version.number,
            "reason": self.reason,
            "updates": self.updates,
            "skipped": self.skipped,
            "losses": self.losses,
            "episodes": self.ingested.episodes,
            "steps": self.ingested.steps,
            "takeovers": self.ingested.takeovers,
            "dropped": self.ingested.dropped,
            "seconds": round(self.seconds, 3),
        }


_log = logging.getLogger(__name__)

#: The parts that make fine-tuning the paper's fear-regularised SAGE (AgentConfig switch -> words).
SAGE_PARTS: dict[str, str] = {
    "fear_regularisation": "fear regularisation",
    "violation_penalty": "the c* violation penalty",
    "virtual_rollouts": "virtual rollouts",
    "imitation": "imitation of takeovers",
}


def missing_sage_parts(cfg: AgentConfig) -> list[str]:
    """The parts of fear-regularised SAGE that ``cfg`` switches off, in words (empty: all of them run)."""
    return [words for name, words in SAGE_PARTS.items() if not getattr(cfg, name)]


#: The SAGE method each base method adapts as (``FinetuneConfig.adapt_as_sage``): the same learner class, SAGE's
#: switches. Methods not here (TD3, HG-DAgger, diffusion policies) have no SAGE counterpart and keep their own.
SAGE_COUNTERPART: dict[str, str] = {
    "sage": "sage",
    "sac": "sage",
    "fni-rl": "sage",
    "multi-hug": "sage",
    "sage-d3qn": "sage-d3qn",
    "d3qn": "sage-d3qn",
}


def adaptation_config(cfg: AgentConfig) -> AgentConfig:
    """``cfg`` with the switches of its SAGE counterpart (:data:`SAGE_COUNTERPART`), every hyperparameter kept;
    ``cfg`` itself (a copy) where the method has none."""
    from core.learners import preset

    target = SAGE_COUNTERPART.get(cfg.method)
    if target is None:
        return from_dict(dataclasses.asdict(cfg))
    return preset(target, base=cfg)


def describe_method(cfg: AgentConfig, base_method: str | None = None) -> str:
    """What a fine-tuning round on ``cfg`` runs, in words, naming every SAGE part it leaves out (and the method the
    base was trained as, where it differs), so that a round that is not SAGE never passes silently as SAGE."""
    missing = missing_sage_parts(cfg)
    trained = f" on a base trained as {base_method}" if base_method and base_method != cfg.method else ""
    if not missing:
        return f"{cfg.method}: fear-regularised SAGE (the paper's fine-tuning){trained}"
    return f"{cfg.method}: NOT the paper's fear-regularised SAGE, without {', '.join(missing)}{trained}"


class Finetuner:
    """Fine-tunes one base version on one session's data. See the module docstring for what a round does.

    ``base``: the version to continue from (default: :func:`line_head`, the newest version not rejected). Before
    every round the line is checked: when the version the last round published was rejected by the promotion check
    (or rolled back), the round starts again from the line's head, the version in control, keeping the data.
    ``prior``: where the base policy's own drives come from (:data:`PriorSource`); None: the session's data only.
    """

    def __init__(
        self,
        versions: VersionStore,
        store: SessionStore,
        session_id: str,
        cfg: FinetuneConfig | None = None,
        base: int | None = None,
        prior: PriorSource | None = None,
        practice: PriorSource | None = None,
    ) -> None:
        self.versions, self.store, self.session_id = versions, store, session_id
        self.practice = practice
        """``practice(version_folder, episodes, seed) -> steps``: the version alone on the session's scenario
        (``FinetuneConfig.practice_episodes``)."""
        self.practice_steps = 0
        """Steps of practice drives in the buffer, over all rounds."""
        self.practice_drives = 0
        """Practice drives made so far: each takes the next seeds, also after a round that published nothing."""
        self.cfg = cfg or FinetuneConfig()
        versions.clean()
        start = line_head(versions) if base is None else versions.get(base)
        if start is None:
            raise FinetuneError(f"{versions.root} holds no version to fine-tune (call ensure_initial first)")
        self.base = start
        payload = load_checkpoint(start.path)
        self.meta = meta_of(payload)
        trained: AgentConfig = from_dict(payload["agent_config"])
        agent_cfg = adaptation_config(trained) if self.cfg.adapt_as_sage else trained
        try:
            apply_overrides(agent_cfg, list(self.cfg.overrides))
        except ValueError as exc:
            raise FinetuneError(f"fine-tuning overrides: {exc}") from None
        self.method = describe_method(agent_cfg, trained.method)
        """What the rounds run (the checkpoint's configuration, SAGE's switches, the overrides), in words."""
        if missing_sage_parts(agent_cfg):
            _log.warning("fine-tuning %s runs %s", start.path, self.method)
        torch.manual_seed(self.cfg.seed)
        low = np.asarray(self.meta.action_low, np.float32)
        high = np.asarray(self.meta.action_high, np.float32)
        self.learner = make_learner(
            agent_cfg.method,
            agent_cfg,
            self.meta.obs_dim,
            self.meta.act_dim,
            low,
            high,
            self.cfg.seed,
            device=self.cfg.device,
        )
        old = self.learner.buffer
        # sampled batches go where the learner's updates run, as the buffer it replaces sent them
        self.buffer = SharedReplayBuffer(old.obs_dim, old.act_dim, old.capacity, self.cfg.prior_share, old.device)
        self.learner.buffer = self.buffer
        self._load(payload, start)
        if hasattr(self.learner, "prior_distill"):
            self.learner.prior_distill = self.cfg.prior_distill
        elif self.cfg.prior_distill > 0:
            _log.info(
                "prior_distill has no effect on %s (no actor to anchor): the rounds run without it", agent_cfg.method
            )
        self.prior = prior
        self.prior_steps: int | None = None
        self.prior_success: list[bool] = []
        """Per prior episode, whether the base's drive ended in success (``anchor_relabel``'s situations)."""
        """Steps of the base policy's own drives in the buffer (None until collected)."""
        self.prior_error: str | None = None
        """Why the base policy's drives could not be collected (the rounds then learn from the session alone)."""
        self.anchor_drive_steps = 0
        """With ``anchor_drives_learn``: the version's anchor drives stored in the buffer, steps over all rounds."""
        self.anchor_drive_violations = 0
        """With ``anchor_drives_learn``: those drives that ended in a violation, over all rounds."""
        self._base_actor: BaseLearner | None = None
        """v0000's learner, built for acting (``anchor_relabel``'s teacher; loaded at the first relabelling)."""
        self.base_first_state: dict[str, Any] | None = None
        """What every version carries with ``base_first``: v0000's acting weights (read once, :meth:`base_weights`)."""
        self.done: list[int] = []
        self.rounds = 0
        self.session_meta = {"episodes_total": 0, "takeover_samples": 0}
        self._takeover_episodes = 0
        self.heldout_obs = np.zeros((0, self.meta.obs_dim), np.float32)
        self.heldout_expert = np.zeros((0, old.act_dim), np.float32)
        """Takeover rows held out of imitation (observations, the expert's encoded actions)."""

    def _load(self, payload: dict[str, Any], version: Version) -> None:
        state = payload["state"]
        if not self.cfg.carry_optimizer:
            state = {k: v for k, v in state.items() if k != "optimizers"}
        try:
            self.learner.load_state_dict(state, strict=False)
        except RuntimeError as exc:
            raise FinetuneError(f"{version.path}: weights do not match their config: {exc}") from None

    def rebase(self, number: int) -> None:
        """Continue from version ``number`` (its weights, optimisers, λ, world model and τ bounds), keeping the data
        recorded so far: the next round starts from it."""
        version = self.versions.get(number)
        payload = load_checkpoint(version.path)
        self._load(payload, version)
        self.meta = meta_of(payload)
        self.base = version

    # -- data ------------------------------------------------------------------------------------------------
    def pending_episodes(self) -> list[int]:
        """Episodes over but not yet learned from (empty while the session does not exist yet)."""
        try:
            return ready_episodes(self.store, self.session_id, self.done)
        except LookupError:
            return []

    def session_steps(self) -> int:
        return len(self.buffer) - self.buffer.prior_count()

    def ready(self) -> bool:
        """Whether a round has enough new data to run."""
        pending = self.pending_episodes()
        if len(pending) < self.cfg.min_new_episodes:
            return False
        buffer = self.buffer
        if self.session_steps() >= self.cfg.min_steps and buffer.takeover_count() >= self.cfg.min_takeover_samples:
            return True
        rows = [r for r in self.store.episodes(self.session_id) if r["episode"] in set(pending)]
        steps = self.session_steps() + sum(r["steps"] for r in rows)
        takeovers = buffer.takeover_count() + sum(r["takeovers"] for r in rows)
        return steps >= self.cfg.min_steps and takeovers >= self.cfg.min_takeover_samples

    def collect_prior(self) -> int:
        """Fill the prior part of the buffer with the base policy's own drives (once); returns its steps."""
        if self.prior_steps is not None:
            return self.prior_steps
        self.prior_steps = 0
        if self.prior is None or self.cfg.prior_episodes == 0 or self.cfg.prior_share == 0:
            return 0
        try:
            steps = self.prior(self.versions.get(0).path, self.cfg.prior_episodes, self.cfg.seed + 5_000_000)
        except Exception as exc:  # a scenario that no longer builds must not stop adaptation: the session's data
            self.prior_error = f"{type(exc).__name__}: {exc}"
            _log.warning("the base policy's own drives are missing from fine-tuning: %s", self.prior_error)
            return 0
        self.buffer.adding_prior = True
        try:
            for record in steps:
                # a step of the base alone: no takeover, no expert label (its encoding is the learner's own)
                self.learner.store(dataclasses.replace(record, takeover=False, a_expert=None))
        finally:
            self.buffer.adding_prior = False
        self.prior_steps = len(steps)
        episodes = split_episodes(steps)
        self.prior_success = [succeeded(episode) for episode in episodes]
        if self._relabelling():
            # the base's own rows of the situations it solved: its recorded (deterministic) actions are the labels
            self._add_anchor_rows([r for ok, ep in zip(self.prior_success, episodes, strict=True) if ok for r in ep])
        return self.prior_steps

    def _relabelling(self) -> bool:
        return self.cfg.anchor_relabel and self.cfg.prior_distill > 0 and hasattr(self.learner, "anchor_rows")

    def _add_anchor_rows(self, records: list[StepRecord], labels: np.ndarray | None = None) -> None:
        """Add ``records``' states to the learner's anchor rows, labelled ``labels`` (default: their ``a_rl``)."""
        learner: Any = self.learner
        if learner.anchor_rows is None:
            old = self.buffer
            learner.anchor_rows = ReplayBuffer(old.obs_dim, old.act_dim, min(old.capacity, 50_000), old.device)
        for i, record in enumerate(records):
            label = record.a_rl if labels is None else labels[i]
            learner.anchor_rows.add(record.obs, label, 0.0, record.obs, False, a_rl=label)

    def relabel(self) -> int:
        """With ``anchor_relabel``: the version in control drives the prior episodes' situations alone; its states on
        the situations the base solved join the anchor rows, labelled with the base's deterministic action. Returns
        the rows added (0 when off, or when the drives fail: the round then anchors on what it has)."""
        if not self._relabelling() or self.prior is None or not self.prior_steps or self.base.number == 0:
            return 0  # v0000 drives deterministic: its states there are the base's own rows, already anchored
        from core.agents import load_agent

        try:
            steps = self.prior(self.base.path, self.cfg.prior_episodes, self.cfg.seed + 5_000_000)
        except Exception as exc:  # as collect_prior: a scenario that no longer builds must not stop adaptation
            _log.warning("the version's drives for the anchor are missing: %s: %s", type(exc).__name__, exc)
            return 0
        episodes = split_episodes(steps)
        if self.cfg.anchor_drives_learn:
            self.buffer.adding_prior = True
            try:
                for record in steps:  # the version's own steps there, as the base's drives are stored
                    self.learner.store(dataclasses.replace(record, takeover=False, a_expert=None))
            finally:
                self.buffer.adding_prior = False
            self.anchor_drive_steps += len(steps)
            self.anchor_drive_violations += sum(any(r.violation for r in episode) for episode in episodes)
        kept = [r for ok, ep in zip(self.prior_success, episodes, strict=False) if ok for r in ep]
        if not kept:
            return 0
        if self._base_actor is None:
            self._base_actor = load_agent(self.versions.get(0).path).learner
        with torch.no_grad():
            obs = torch.from_numpy(np.stack([r.obs for r in kept]).astype(np.float32))
            labels = self._base_actor.rollout_policy(obs).cpu().numpy()
        self._add_anchor_rows(kept, labels)
        return len(kept)

    def practise(self) -> dict[str, float]:
        """``practice_episodes`` drives of the version in control alone on the session's scenario, stored as the
        agent's own steps (no takeover, no expert label), seeds new each time. Returns their steps and the episodes
        with a violation (empty when the drives fail: the round then learns from what it has, as without practice)."""
        n = self.cfg.practice_episodes
        assert self.practice is not None
        try:
            steps = self.practice(self.base.path, n, self.cfg.seed + 7_000_000 + self.practice_drives * n)
            self.practice_drives += 1
        except Exception as exc:  # as collect_prior: a scenario that no longer builds must not stop adaptation
            _log.warning("the version's practice drives are missing: %s: %s", type(exc).__name__, exc)
            return {}
        for record in steps:
            self.learner.store(dataclasses.replace(record, takeover=False, a_expert=None))
        self.practice_steps += len(steps)
        episodes = split_episodes(steps)
        violated = sum(any(r.violation for r in episode) for episode in episodes)
        return {"practice_steps": float(len(steps)), "practice_violations": float(violated)}

    def base_weights(self) -> dict[str, Any] | None:
        """With ``base_first``: v0000's acting weights, the part of every published version that drives first."""
        if self.cfg.base_first and self.base_first_state is None:
            acting = load_checkpoint(self.versions.get(0).path)["state"][self.learner.acting_module]
            self.base_first_state = {"acting": {name: value.detach().cpu().clone() for name, value in acting.items()}}
        return self.base_first_state

    def _ingest(self, episodes: list[int]) -> Ingested:
        """Ingest the episodes one by one, holding the takeover rows of every ``round(1 / holdout_share)``-th
        episode with takeovers out of imitation (kept for the critic and the world model)."""
        total = Ingested()
        every = round(1 / self.cfg.holdout_share) if self.cfg.holdout_share > 0 else 0
        for episode in episodes:
            got = ingest(self.learner, self.store, self.session_id, [episode])
            total.episodes += got.episodes
            total.steps += got.steps
            total.takeovers += got.takeovers
            total.dropped += got.dropped
            if got.takeovers == 0 or every == 0:
                continue
            self._takeover_episodes += 1
            if self._takeover_episodes % every:
                continue
            rows = (self.buffer.pos - 1 - np.arange(got.steps)) % self.buffer.capacity
            rows = rows[self.buffer.takeover[rows]]
            self.heldout_obs = np.concatenate([self.heldout_obs, self.buffer.obs[rows]])
            self.heldout_expert = np.concatenate([self.heldout_expert, self.buffer.a_expert[rows]])
            self.buffer.takeover[rows] = False  # not imitated: measured
        return total

    def heldout_error(self) -> float | None:
        """Mean ||π(s) - a_E||² over the held-out takeover rows (None when there are none)."""
        if len(self.heldout_obs) == 0:
            return None
        with torch.no_grad():
            action = self.learner.rollout_policy(torch.from_numpy(self.heldout_obs))
        return float((action - torch.from_numpy(self.heldout_expert)).pow(2).sum(-1).mean())

    def _refit_world_model(self) -> dict[str, float]:
        """Refit the world model; keep or take the τ bounds by ``tau_bounds``."""
        learner, wm = self.learner, self.learner.world_model
        assert wm is not None
        held = wm.tau_bounds.detach().clone()
        fit = learner.fit_world_model()
        if fit is None:
            return {}
        stats = {"wm_holdout_nll": fit.holdout_nll, "wm_holdout_mse": fit.holdout_mse}
        new = wm.tau_bounds.detach().clone()
        stats["tau_min_refit"], stats["tau_max_refit"] = (float(v) for v in new)  # what the refit measured
        keep_held = bool(torch.isfinite(held).all()) and (
            self.cfg.tau_bounds == "hold"
            or (
                self.cfg.tau_bounds == "drift"
                and abs(float(new[1] - held[1])) <= self.cfg.tau_drift * abs(float(held[1]))
            )
        )
        if keep_held:
            wm.tau_bounds.copy_(held)
            wm.touch()
        stats["tau_min"], stats["tau_max"] = (float(v) for v in wm.tau_bounds)
        stats["tau_refitted"] = float(not keep_held)
        return stats

    # -- a round -------------------------------------------------------------------------------------------------
    def round(self, progress: Progress | None = None, should_stop: ShouldStop | None = None) -> RoundResult:
        """Ingest the new episodes, refit the world model, run the guarded updates, publish if healthy."""
        started = time.time()
        report = progress or (lambda event: None)
        stop = should_stop or (lambda: False)
        cfg, learner = self.cfg, self.learner
        if rejected(self.base):
            head = line_head(self.versions)
            if head is not None and head.number != self.base.number:
                report({"phase": f"continuing from {head.name}: {self.base.name} was not promoted"})
                self.rebase(head.number)
        report({"phase": "ingesting"})
        if self.prior_steps is None:
            report({"phase": "driving the base policy alone"})
            self.collect_prior()
        ingested = self._ingest(self.pending_episodes())
        self.done.extend(ingested.episodes)
        result = RoundResult(None, ingested=ingested)
        if self.session_steps() < cfg.min_steps:
            result.reason = f"only {self.session_steps()} usable steps recorded, {cfg.min_steps} needed"
            return result
        if learner.buffer.takeover_count() < cfg.min_takeover_samples:
            result.reason = (
                f"only {learner.buffer.takeover_count()} takeover samples recorded, {cfg.min_takeover_samples} needed"
            )
            return result
        if self._relabelling():  # after the data checks: a round that waits for data drives nothing
            report({"phase": "driving the version alone for the anchor"})
            self.relabel()
        practice: dict[str, float] = {}
        if cfg.practice_episodes > 0 and self.practice is not None:
            report({"phase": "the version practising alone"})
            practice = self.practise()
        wm_stats: dict[str, float] = {}
        if cfg.refit_world_model and learner.world_model is not None and len(learner.buffer) >= cfg.wm_min_steps:
            report({"phase": "fitting world model"})
            wm_stats = self._refit_world_model()
        planned = cfg.round_updates(ingested.steps)
        warmup = min(cfg.critic_warmup, planned)
        lam_start = learner.lam
        best_error = self.heldout_error()
        best_snapshot = learner._snapshot() if best_error is not None else None
        round_start = learner._snapshot() if cfg.round_keep < 1.0 else None
        best_at, since_best, stopped_early = 0, 0, False
        virtual_every = max(1, learner.cfg.virtual_every)
        sums: dict[str, float] = {}
        counts: dict[str, int] = {}
        for k in range(planned):
            if stop():
                result.reason = "stopped"
                return result
            stats, applied = critic_only_update(learner) if k < warmup else guarded_update(learner)
            if applied:
                result.updates += 1
                for key, value in stats.items():
                    if isinstance(value, int | float) and math.isfinite(float(value)):
                        sums[key] = sums.get(key, 0.0) + float(value)
                        counts[key] = counts.get(key, 0) + 1
            else:
                result.skipped += 1
            if learner.virtual is not None and (k + 1) % virtual_every == 0:
                learner.virtual_rollout()  # imagined states under the policy as it is now, as training refreshes them
            if (k + 1) % cfg.report_every == 0 or k + 1 == planned:
                means = {key: sums[key] / counts[key] for key in sums}
                report(
                    {
                        "phase": "training",
                        "update": k + 1,
                        "updates": planned,
                        "skipped": result.skipped,
                        "losses": means,
                    }
                )
            if best_error is not None and k + 1 == warmup:
                # the actor has not moved (the same held-out error): the round's starting point is now the warmed critic
                best_at, best_snapshot = k + 1, learner._snapshot()
            if best_error is not None and k + 1 > warmup and (k + 1 - warmup) % cfg.early_stop_every == 0:
                error = self.heldout_error()
                if error is not None and error < best_error:
                    best_error, best_at, since_best = error, k + 1, 0
                    best_snapshot = learner._snapshot()
                else:
                    since_best += 1
                    if since_best >= cfg.early_stop_patience:
                        stopped_early = True
                        break
        if best_snapshot is not None and best_at != result.updates + result.skipped:
            learner._restore(best_snapshot)  # the weights of the lowest held-out imitation error
        result.losses = {key: sums[key] / counts[key] for key in sums} | wm_stats | practice
        if round_start is not None:
            # the published version keeps round_keep of the round's change (a Polyak average with the start)
            result.losses["round_actor_change"] = keep_share_of_change(learner, round_start, cfg.round_keep)
        result.losses["lam_start"], result.losses["lam_end"] = lam_start, learner.lam
        result.losses["critic_warmup_updates"] = warmup
        if best_error is not None:
            result.losses["heldout_imitation_error"] = best_error
        result.seconds = time.time() - started
        attempted = result.updates + result.skipped
        if attempted and result.skipped > cfg.max_skipped_fraction * attempted:
            result.reason = f"{result.skipped} of {attempted} updates had non-finite losses: nothing published"
            return result
        if not weights_finite(learner):
            result.reason = "weights are not finite: nothing published"
            return result
        report({"phase": "publishing"})
        self.session_meta["episodes_total"] += len(ingested.episodes)
        self.session_meta["takeover_samples"] = learner.buffer.takeover_count()
        metrics = {
            "parent": self.base.number,
            "session": self.session_id,
            "episodes": ingested.episodes,
            "episodes_total": self.session_meta["episodes_total"],
            "steps": self.session_steps(),
            "prior_steps": self.prior_steps or 0,
            "prior_error": self.prior_error,
            "anchor_rows": len(getattr(learner, "anchor_rows", None) or ()),
            "anchor_drive_steps": self.anchor_drive_steps,
            "anchor_drive_violations": self.anchor_drive_violations,
            "base_first": self.cfg.base_first,
            "takeover_samples": self.session_meta["takeover_samples"],
            "heldout_takeover_samples": len(self.heldout_obs),
            "updates_planned": planned,
            "updates": result.updates,
            "kept_update": best_at if best_snapshot is not None else result.updates + result.skipped,
            "stopped_early": stopped_early,
            "skipped": result.skipped,
            "dropped_rows": ingested.dropped,
            "losses": result.losses,
            "seconds": round(time.time() - started, 3),
            "config": dataclasses.asdict(cfg),
            "method": self.method,
        }
        base_first = self.base_weights()
        extra = None if base_first is None else {BASE_FIRST_KEY: base_first}
        result.version = self.versions.publish(learner, self._meta(ingested, result.updates), metrics, extra)
        self.base = result.version  # the next round continues this line (unless the promotion check rejects it)
        self.rounds += 1
        result.seconds = time.time() - started
        return result

    def _meta(self, ingested: Ingested, updates: int) -> AgentMeta:
        learner = self.learner
        extra = dict(self.meta.extra)
        extra["finetune"] = {"parent": self.base.number, "session": self.session_id}
        self.meta = dataclasses.replace(
            self.meta,
            episodes=self.meta.episodes + len(ingested.episodes),
            env_steps=self.meta.env_steps + ingested.steps,
            updates=self.meta.updates + updates,
            has_world_model=learner.world_model_ready(),
            extra=extra,
        )
        return self.meta
