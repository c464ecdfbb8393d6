"""Continual adaptation: fine-tune the deployed policy on what the loop recorded and publish numbered versions.

The paper's closing loop: deploy → the gate hands risky moments to the expert → the takeovers become targeted
supervision → the deployed policy improves, cycle after cycle. Here one *round* of fine-tuning is
:meth:`Finetuner.round`, the one function that both faces call: the live server's background worker
(:mod:`core.worker`, its own process) and ``sage cycles`` (in-process, between deployment cycles).

A round
  1. reads the session's episodes that are over (finished, or followed by a later one) from the session store
     (:class:`core.sessions.SessionStore`; SQLite in WAL mode, so reading while the loop writes is safe) into
     the learner's real replay buffer: the agent's own transitions and the takeover segments, whose rows carry
     the expert's action (Ξ = 1, the intervention samples the value-weighted imitation draws from);
  2. refits the world model on that buffer (so that fear and curiosity learn the new ground; the gate of the
     next version is built on it);
  3. runs ``updates`` gradient updates of the learner (for SAGE: fear-regularised SAC plus value-weighted
     imitation of the takeovers, :mod:`core.sage.sac`), each one guarded: an update whose losses or weights
     come out NaN or infinite is undone (:func:`guarded_update`), as if it had never run;
  4. publishes a new version when the round stayed healthy (all weights finite, at most
     ``max_skipped_fraction`` of its updates undone). A failed round publishes nothing, so the last good
     version stays the latest.

Versions (:class:`VersionStore`) live in one folder, ``<run>/versions/vNNNN/`` with ``checkpoint.pt`` (the
checkpoint format of :mod:`core.agents`, loadable with ``load_agent(folder)``) and ``metrics.json`` (the round's
losses and data). ``v0000`` is the deployed starting policy. A version folder appears in one ``os.replace`` of a
fully written temporary folder, so a reader never sees a half-written version, and a crash mid-write leaves only a
``.tmp-*`` folder that listing ignores and the next writer removes.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
import re
import secrets
import shutil
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from core.agents import AgentMeta, load_checkpoint, meta_of, resolve_checkpoint, save_checkpoint
from core.learners import make_learner
from core.promotion import is_promoted, read_verdict
from core.protocol import StepRecord
from core.sage.config import AgentConfig, apply_overrides, from_dict
from core.sage.learner import BaseLearner
from core.sessions import SessionStore

VERSION_DIR = re.compile(r"^v(\d{4,})$")
CHECKPOINT_FILE = "checkpoint.pt"
METRICS_FILE = "metrics.json"
TMP_PREFIX = ".tmp-"

Progress = Callable[[dict[str, Any]], None]
"""Receives progress events: ``{"phase": ..., "update": k, "updates": n, "losses": {...}}``."""
ShouldStop = Callable[[], bool]


class FinetuneError(RuntimeError):
    """A fine-tuning set-up that cannot work (no such version, a policy of other dimensions, ...)."""


@dataclass
class FinetuneConfig:
    """One round of fine-tuning on recorded session data (the learner's own settings come from the checkpoint)."""

    updates: int = 400
    """Gradient updates per round (critic + actor with value-weighted imitation, for SAGE)."""
    min_new_episodes: int = 1
    """Episodes that must have ended since the last round before the next one starts."""
    min_steps: int = 200
    """Recorded steps needed before the first round: a version fine-tuned on a single short episode (22 takeover
    samples, measured) collided more than the one it replaced."""
    min_takeover_samples: int = 50
    """Takeover (expert-labelled) steps needed before the first round: they are what imitation learns from."""
    refit_world_model: bool = True
    """Refit the world model on the session's data at every round (fear and curiosity learn the new ground)."""
    wm_min_steps: int = 100
    """Steps in the buffer before the world model is refitted (a fit on fewer overfits the hold-out split)."""
    max_skipped_fraction: float = 0.25
    """A round that had to undo more than this share of its updates (non-finite losses) publishes nothing."""
    report_every: int = 20
    """Updates between progress events."""
    overrides: tuple[str, ...] = ()
    """``key=value`` edits of the checkpoint's :class:`~core.sage.config.AgentConfig` (``bc_weight=2``)."""
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


# -- versions --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Version:
    number: int
    path: Path
    """The version folder (what :func:`core.agents.load_agent` takes)."""
    metrics: dict[str, Any]

    @property
    def name(self) -> str:
        return version_name(self.number)

    @property
    def parent(self) -> int | None:
        parent = self.metrics.get("parent")
        return int(parent) if isinstance(parent, int) else None

    def summary(self) -> dict[str, Any]:
        """The JSON-ready line the dashboard lists."""
        m = self.metrics
        return {
            "number": self.number,
            "name": self.name,
            "parent": self.parent,
            "created": m.get("created"),
            "updates": m.get("updates", 0),
            "skipped": m.get("skipped", 0),
            "episodes": m.get("episodes_total", 0),
            "takeover_samples": m.get("takeover_samples", 0),
            "losses": m.get("losses", {}),
            "promotion": self.verdict(),
        }

    def verdict(self) -> dict[str, Any] | None:
        """Whether this version may drive (:mod:`core.promotion`): ``promoted``, ``reason``, ``evaluation``."""
        if self.number == 0:
            return read_verdict(self.path) or {"promoted": True, "reason": "the policy deployed by the operator"}
        return read_verdict(self.path)

    @property
    def promoted(self) -> bool:
        return is_promoted(self.path, self.number)


def version_name(number: int) -> str:
    return f"v{number:04d}"


def _write_json_atomic(path: Path, data: dict[str, Any]) -> None:
    tmp = path.with_name(f"{TMP_PREFIX}{path.name}.{secrets.token_hex(3)}")
    tmp.write_text(json.dumps(data, indent=2, default=_json_default) + "\n")
    os.replace(tmp, path)


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, Path):
        return str(value)
    return str(value)


class VersionStore:
    """The numbered policy versions of one fine-tuning run (see the module docstring for the layout)."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)

    def versions(self) -> list[Version]:
        """Every complete version, oldest first. Temporary folders and unreadable metrics are skipped."""
        if not self.root.is_dir():
            return []
        found: list[Version] = []
        for child in self.root.iterdir():
            match = VERSION_DIR.match(child.name)
            if not match or not child.is_dir() or not (child / CHECKPOINT_FILE).is_file():
                continue
            try:
                metrics = json.loads((child / METRICS_FILE).read_text())
            except (OSError, ValueError):
                metrics = {}
            found.append(Version(int(match.group(1)), child, metrics if isinstance(metrics, dict) else {}))
        return sorted(found, key=lambda v: v.number)

    def latest(self) -> Version | None:
        versions = self.versions()
        return versions[-1] if versions else None

    def get(self, number: int) -> Version:
        for version in self.versions():
            if version.number == number:
                return version
        known = ", ".join(v.name for v in self.versions()) or "none"
        raise FinetuneError(f"no version {version_name(number)} in {self.root} (there are: {known})")

    def clean(self) -> int:
        """Remove the temporary folders a crashed writer left behind; returns how many."""
        if not self.root.is_dir():
            return 0
        removed = 0
        for child in self.root.iterdir():
            if child.name.startswith(TMP_PREFIX):
                shutil.rmtree(child, ignore_errors=True) if child.is_dir() else child.unlink(missing_ok=True)
                removed += 1
        return removed

    def ensure_initial(self, policy: str | Path) -> Version:
        """``v0000``: the deployed starting policy (its checkpoint copied in), unless versions exist already."""
        latest = self.latest()
        if latest is not None:
            return latest
        source = resolve_checkpoint(policy)
        load_checkpoint(source)  # refuse anything that is not a readable SAGE checkpoint before publishing it
        metrics = {"version": 0, "parent": None, "created": time.time(), "source": str(source), "updates": 0}
        return self._publish(0, lambda folder: shutil.copyfile(source, folder / CHECKPOINT_FILE), metrics)

    def publish(self, learner: BaseLearner, meta: AgentMeta, metrics: dict[str, Any]) -> Version:
        """Write the learner as the next version (atomically: all of it appears at once, or nothing)."""
        latest = self.latest()
        number = 0 if latest is None else latest.number + 1
        metrics = {**metrics, "version": number, "created": time.time()}
        return self._publish(number, lambda folder: save_checkpoint(folder / CHECKPOINT_FILE, learner, meta), metrics)

    def _publish(self, number: int, write: Callable[[Path], Any], metrics: dict[str, Any]) -> Version:
        self.root.mkdir(parents=True, exist_ok=True)
        tmp = self.root / f"{TMP_PREFIX}{version_name(number)}-{os.getpid()}-{secrets.token_hex(3)}"
        tmp.mkdir()
        try:
            write(tmp)
            _write_json_atomic(tmp / METRICS_FILE, metrics)
            final = self.root / version_name(number)
            os.replace(tmp, final)  # a directory rename: the version appears complete or not at all
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        return Version(number, final, metrics)


# -- guarded updates ---------------------------------------------------------------------------------------------
def weights_finite(learner: BaseLearner) -> bool:
    """Whether every trained value the learner declares (and its world model) is finite."""
    return learner.weights_finite()


def guarded_update(learner: BaseLearner) -> tuple[dict[str, float], bool]:
    """One ``learner.update()``, undone when a loss or a weight comes out NaN/inf: the learner's own guarded
    update (:meth:`BaseLearner.guarded_update`, the one online training uses too). Returns (stats, applied)."""
    return learner.guarded_update()


# -- the session as training data -----------------------------------------------------------------------------
@dataclass
class Ingested:
    episodes: list[int] = field(default_factory=list)
    steps: int = 0
    takeovers: int = 0
    dropped: int = 0
    """Rows left out because an observation or action held NaN/inf (a sensor glitch must not poison training)."""


def ready_episodes(store: SessionStore, session_id: str, done: Iterable[int] = ()) -> list[int]:
    """Episodes of the session that are over and not in ``done``: finished, or followed by a later episode
    (an episode the operator cut short never gets a summary, but its steps still count)."""
    rows = store.episodes(session_id)
    if not rows:
        return []
    last = max(r["episode"] for r in rows)
    seen = set(done)
    return [r["episode"] for r in rows if (r["finished"] or r["episode"] < last) and r["episode"] not in seen]


def ingest(learner: BaseLearner, store: SessionStore, session_id: str, episodes: Iterable[int]) -> Ingested:
    """Add the recorded steps of ``episodes`` to the learner's real buffer (takeover rows with the expert's action)."""
    out = Ingested()
    for episode in episodes:
        arrays = store.steps(session_id, episode)
        out.episodes.append(int(episode))
        n = len(arrays["t"])
        if n == 0:
            continue
        vectors = np.concatenate([arrays["obs"], arrays["next_obs"], arrays["action"], arrays["a_rl"]], axis=1)
        clean = np.isfinite(vectors).all(axis=1) & np.isfinite(arrays["reward"]) & np.isfinite(arrays["cost"])
        for i in range(n):
            if not clean[i]:
                out.dropped += 1
                continue
            a_expert = arrays["a_expert"][i]
            takeover = bool(arrays["takeover"][i]) and bool(np.isfinite(a_expert).all())
            # through the learner's own store: it encodes actions (a discrete learner's one-hot) and may shape
            # rewards (Multi-Hug's intervention penalty), as in headless training
            learner.store(
                StepRecord(
                    episode=int(episode),
                    t=int(arrays["t"][i]),
                    obs=arrays["obs"][i],
                    a_rl=arrays["a_rl"][i],
                    a_expert=a_expert if takeover else None,
                    action=arrays["action"][i],
                    takeover=takeover,
                    gate_fired=bool(arrays["gate_fired"][i]),
                    actor=str(arrays["actor"][i]),  # type: ignore[arg-type]
                    fear=float(arrays["fear"][i]),
                    threshold=float(arrays["threshold"][i]),
                    curiosity=float(arrays["curiosity"][i]),
                    reward=float(arrays["reward"][i]),
                    cost=float(arrays["cost"][i]),
                    violation=bool(arrays["violation"][i]),
                    terminated=bool(arrays["terminated"][i]),
                    truncated=bool(arrays["truncated"][i]),
                    next_obs=arrays["next_obs"][i],
                    wall_time=float(arrays["wall_time"][i]),
                    info={
                        "conflict": bool(arrays["conflict"][i])
                    },  # the world model's near-miss label, if it learns it
                )
            )
            out.steps += 1
            out.takeovers += int(takeover)
    return out


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


def describe_method(cfg: AgentConfig) -> str:
    """What a fine-tuning round on ``cfg`` runs, in words, naming every SAGE part it leaves out.

    Fine-tuning continues the checkpoint's own configuration, so a policy trained as plain SAC is fine-tuned
    as plain SAC; this line says so (the worker shows it and every published version records it) instead of
    letting it pass silently as SAGE.
    """
    missing = missing_sage_parts(cfg)
    if not missing:
        return f"{cfg.method}: fear-regularised SAGE (the paper's fine-tuning)"
    return f"{cfg.method}: NOT the paper's fear-regularised SAGE, without {', '.join(missing)}"


class Finetuner:
    """Fine-tunes one base version on one session's data. See the module docstring for what a round does.

    ``base``: the version to continue from (default: the latest). After a rollback the worker is rebuilt on the
    version rolled back to, and new versions continue that line (their ``parent`` says which).
    """

    def __init__(
        self,
        versions: VersionStore,
        store: SessionStore,
        session_id: str,
        cfg: FinetuneConfig | None = None,
        base: int | None = None,
    ) -> None:
        self.versions, self.store, self.session_id = versions, store, session_id
        self.cfg = cfg or FinetuneConfig()
        versions.clean()
        start = versions.latest() if base is None else versions.get(base)
        if start is None:
            raise FinetuneError(f"{versions.root} holds no version to fine-tune (call ensure_initial first)")
        self.base = start
        payload = load_checkpoint(start.path)
        self.meta = meta_of(payload)
        agent_cfg: AgentConfig = from_dict(payload["agent_config"])
        try:
            apply_overrides(agent_cfg, list(self.cfg.overrides))
        except ValueError as exc:
            raise FinetuneError(f"fine-tuning overrides: {exc}") from None
        self.method = describe_method(agent_cfg)
        """What the rounds run (the checkpoint's configuration with the overrides), in words."""
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
        try:
            self.learner.load_state_dict(payload["state"], strict=False)
        except RuntimeError as exc:
            raise FinetuneError(f"{start.path}: weights do not match their config: {exc}") from None
        self.done: list[int] = []
        self.rounds = 0
        self.session_meta = {"episodes_total": 0, "takeover_samples": 0}

    # -- data ------------------------------------------------------------------------------------------------
    def pending_episodes(self) -> list[int]:
        """Episodes over but not yet learned from (empty while the session does not exist yet)."""
        try:
            return ready_episodes(self.store, self.session_id, self.done)
        except LookupError:
            return []

    def ready(self) -> bool:
        """Whether a round has enough new data to run."""
        pending = self.pending_episodes()
        if len(pending) < self.cfg.min_new_episodes:
            return False
        buffer = self.learner.buffer
        if len(buffer) >= self.cfg.min_steps and buffer.takeover_count() >= self.cfg.min_takeover_samples:
            return True
        rows = [r for r in self.store.episodes(self.session_id) if r["episode"] in set(pending)]
        steps = len(buffer) + sum(r["steps"] for r in rows)
        takeovers = buffer.takeover_count() + sum(r["takeovers"] for r in rows)
        return steps >= self.cfg.min_steps and takeovers >= self.cfg.min_takeover_samples

    # -- a round -------------------------------------------------------------------------------------------------
    def round(self, progress: Progress | None = None, should_stop: ShouldStop | None = None) -> RoundResult:
        """Ingest the new episodes, refit the world model, run the guarded updates, publish if healthy."""
        started = time.time()
        report = progress or (lambda event: None)
        stop = should_stop or (lambda: False)
        cfg, learner = self.cfg, self.learner
        report({"phase": "ingesting"})
        ingested = ingest(learner, self.store, self.session_id, self.pending_episodes())
        self.done.extend(ingested.episodes)
        result = RoundResult(None, ingested=ingested)
        if len(learner.buffer) < cfg.min_steps:
            result.reason = f"only {len(learner.buffer)} usable steps recorded, {cfg.min_steps} needed"
            return result
        if learner.buffer.takeover_count() < cfg.min_takeover_samples:
            result.reason = (
                f"only {learner.buffer.takeover_count()} takeover samples recorded, {cfg.min_takeover_samples} needed"
            )
            return result
        wm_stats: dict[str, float] = {}
        if cfg.refit_world_model and learner.world_model is not None and len(learner.buffer) >= cfg.wm_min_steps:
            report({"phase": "fitting world model"})
            fit = learner.fit_world_model()
            if fit is not None:
                wm_stats = {"wm_holdout_nll": fit.holdout_nll, "wm_holdout_mse": fit.holdout_mse}
        sums: dict[str, float] = {}
        counts: dict[str, int] = {}
        for k in range(cfg.updates):
            if stop():
                result.reason = "stopped"
                return result
            stats, applied = guarded_update(learner)
            if applied:
                result.updates += 1
                for key, value in stats.items():
                    if isinstance(value, int | float) and math.isfinite(float(value)):
                        sums[key] = sums.get(key, 0.0) + float(value)
                        counts[key] = counts.get(key, 0) + 1
            else:
                result.skipped += 1
            if (k + 1) % cfg.report_every == 0 or k + 1 == cfg.updates:
                means = {key: sums[key] / counts[key] for key in sums}
                report(
                    {
                        "phase": "training",
                        "update": k + 1,
                        "updates": cfg.updates,
                        "skipped": result.skipped,
                        "losses": means,
                    }
                )
        result.losses = {key: sums[key] / counts[key] for key in sums} | wm_stats
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
            "steps": len(learner.buffer),
            "takeover_samples": self.session_meta["takeover_samples"],
            "updates": result.updates,
            "skipped": result.skipped,
            "dropped_rows": ingested.dropped,
            "losses": result.losses,
            "seconds": round(time.time() - started, 3),
            "config": dataclasses.asdict(cfg),
            "method": self.method,
        }
        result.version = self.versions.publish(learner, self._meta(ingested, result.updates), metrics)
        self.base = result.version  # the next round continues this line
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
