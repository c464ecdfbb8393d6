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
  3. with ``learner.ibrl``, clones the expert's rows into IBRL's imitation policy (``SAC.fit_imitation_policy``);
     then runs ``updates_per_step`` gradient updates per new step (at most ``updates``) of the learner: with
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
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from core.agents import AgentMeta, load_checkpoint, meta_of
from core.familiar import STATE_KEY as BASE_FIRST_KEY
from core.finetune_config import FinetuneConfig as FinetuneConfig
from core.finetune_config import TauBoundsRule as TauBoundsRule
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
from core.sage.learner import CRITIC_DISTIL_UPDATES, BaseLearner
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
            "coached": self.ingested.coached,
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
        self._store_alone(steps, prior=True)
        self.prior_steps = len(steps)
        episodes = split_episodes(steps)
        self.prior_success = [succeeded(episode) for episode in episodes]
        if self._relabelling():
            # the base's own rows of the situations it solved: its recorded (deterministic) actions are the labels
            self._add_anchor_rows([r for ok, ep in zip(self.prior_success, episodes, strict=True) if ok for r in ep])
        return self.prior_steps

    def _store_alone(self, steps: list[StepRecord], *, prior: bool) -> None:
        """Store drives made alone (no gate, no expert) as the agent's own steps: no takeover, no expert label (their
        encoding is the learner's own); ``prior``: in the buffer's prior part, beside the base's drives."""
        self.buffer.adding_prior = prior
        try:
            for record in steps:
                self.learner.store(dataclasses.replace(record, takeover=False, a_expert=None))
        finally:
            self.buffer.adding_prior = False

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
            self._store_alone(steps, prior=True)  # the version's own steps there, as the base's drives are stored
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
        self._store_alone(steps, prior=False)
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
        """Ingest the episodes one by one, holding the labelled rows (takeovers, coached steps) of every
        ``round(1 / holdout_share)``-th episode with labels out of imitation (kept for the critic and the world
        model)."""
        total = Ingested()
        every = round(1 / self.cfg.holdout_share) if self.cfg.holdout_share > 0 else 0
        for episode in episodes:
            got = ingest(self.learner, self.store, self.session_id, [episode])
            total.episodes += got.episodes
            total.steps += got.steps
            total.takeovers += got.takeovers
            total.coached += got.coached
            total.dropped += got.dropped
            if got.takeovers + got.coached == 0 or every == 0:
                continue
            self._takeover_episodes += 1
            if self._takeover_episodes % every:
                continue
            rows = (self.buffer.pos - 1 - np.arange(got.steps)) % self.buffer.capacity
            rows = rows[self.buffer.takeover[rows]]
            self.heldout_obs = np.concatenate([self.heldout_obs, self.buffer.obs[rows]])
            self.heldout_expert = np.concatenate([self.heldout_expert, self.buffer.a_expert[rows]])
            self.buffer.unlabel(rows)  # not imitated: measured
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
        distil = getattr(learner, "distil_critic", None)
        if distil is not None and learner.critic_teacher is not None:
            # critics of another shape than the base's (layer norms, more members): fitted to the base's before any
            # update, the critic warm-up's included, reads them
            report({"phase": "fitting the layer-normed critics to the base's"})
            distilled = distil(CRITIC_DISTIL_UPDATES)
            if distilled is not None:
                wm_stats["critic_distil_loss"] = distilled
        fit_imitation = getattr(learner, "fit_imitation_policy", None)
        if fit_imitation is not None and learner.cfg.ibrl:
            # IBRL's π_IL on every takeover so far, before the updates whose TD targets and actions read it
            report({"phase": "cloning the expert for IBRL's imitation policy"})
            wm_stats.update(fit_imitation(learner.cfg.ibrl_updates, self.heldout_obs, self.heldout_expert))
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
