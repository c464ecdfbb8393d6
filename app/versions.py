"""The version follower: which fine-tuned version of the policy drives the live loop, and when it changes.

A fine-tuning worker process (:class:`core.worker.FinetuneService`) learns from the session while the loop runs
and publishes numbered versions (``<runs>/<session id>/versions/vNNNN``, v0000 = the policy deployed); each is
evaluated before it may drive (:mod:`core.promotion`). The follower takes a new version only at an episode
boundary (``Runner.set_policy_at_boundary`` with a gate bound to the new policy), lets the operator pin a
version, follow the newest or roll back, and reports each finished episode so a promoted version that does
worse live is rolled back.
"""

from __future__ import annotations

import functools
import threading
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import gymnasium as gym

from app.commands import CommandError
from app.policies import LoadedPolicy
from core.finetune import FinetuneConfig, FinetuneError, VersionStore, drive_alone
from core.loop import Runner
from core.promotion import PromotionConfig, evaluate_version
from core.worker import FinetuneService, WorkerSpec


@dataclass(frozen=True)
class FinetuneSettings:
    """Background fine-tuning of a trained policy on the session it drives (see the module docstring)."""

    runs: Path
    """Fine-tuning runs go to ``<runs>/<session id>/versions/``."""
    config: FinetuneConfig = field(default_factory=FinetuneConfig)
    backoff: tuple[float, float] = (1.0, 30.0)
    """First and longest wait (s) before restarting a worker that died."""
    promotion: PromotionConfig = field(default_factory=PromotionConfig)
    """How a new version is evaluated before it may drive, and watched live once it does."""
    nice: int = 10
    """Added to the worker's scheduling niceness (:attr:`core.worker.WorkerSpec.nice`): the loop wins a contended
    core; 0 where the worker should keep its share beside other busy processes."""


class VersionFollower:
    """One session's fine-tuning service and the version in control (loop thread, except ``on_change``)."""

    def __init__(self, service: FinetuneService) -> None:
        self.service = service
        self.version: int | None = 0
        """The version in control (v0000, the policy deployed, to begin with)."""

    @classmethod
    def start(
        cls,
        settings: FinetuneSettings,
        sessions_root: Path,
        session_id: str,
        policy: str,
        make_env: Callable[[], gym.Env[Any, Any]],
        load: Callable[[Path], LoadedPolicy],
        on_change: Callable[[], None],
        scenario_env: Callable[[str], gym.Env[Any, Any]] | None = None,
        scenario: str | None = None,
    ) -> VersionFollower:
        """Start the session's fine-tuning worker, with ``policy`` as version 0."""
        versions = VersionStore(settings.runs / session_id / "versions")
        versions.ensure_initial(policy)
        # a new version is evaluated headless (scripted expert, fixed seeds) beside the one in control before it
        # may drive: the worker builds the session's env itself, so the factory must cross the spawn boundary
        spec = WorkerSpec(
            versions.root,
            sessions_root,
            session_id,
            settings.config,
            # the regression test (promotion.regression_scenarios) drives each of its scenarios: scenario_env
            evaluator=functools.partial(evaluate_version, make_env=make_env, scenario_env=scenario_env),
            promotion=settings.promotion,
            nice=settings.nice,
            # the base policy's own drives beside the session's takeovers in every round (core.finetune.drive_alone)
            prior=None if scenario_env is None else functools.partial(drive_alone, make_env=scenario_env),
            # the version alone on the session's own scenario (FinetuneConfig.practice_episodes; off by default)
            practice=None
            if scenario_env is None or scenario is None
            else functools.partial(drive_alone, make_env=scenario_env, scenarios=[scenario]),
        )
        return cls(FinetuneService(spec, load, backoff=settings.backoff, on_change=on_change).start())

    def stop(self, background: bool = False) -> None:
        if background:  # a replaced session's worker ends in the background (it may take a second)
            threading.Thread(target=self.service.stop, name="finetune-stop", daemon=True).start()
        else:
            self.service.stop()

    def take_at_boundary(self, runner: Runner, adopt: Callable[[LoadedPolicy], None]) -> LoadedPolicy | None:
        """Between episodes: hand the runner a newly promoted or chosen version, if there is one. ``adopt`` is
        called with it before the version number changes, so that a reader of (version, policy label) from
        another thread never sees the new number with the old policy."""
        pending = self.service.take_pending()
        if pending is None:
            return None
        number, loaded = pending
        # the runner swaps the policy when it resets for the next episode; the gate must watch that policy
        runner.set_policy_at_boundary(loaded.policy, loaded.gate)
        adopt(loaded)
        self.version = number
        self.service.mark_deployed(number)
        return loaded

    def episode_ended(self, collided: bool, takeover_rate: float, reached: bool | None = None) -> str | None:
        """Report a finished episode (``reached``: the goal; None where the simulator did not end it); returns the
        reason when the version in control was rolled back."""
        if self.version is None:
            return None
        return self.service.record_episode(self.version, collided, takeover_rate, reached)

    def choose(self, action: str, number: int | None) -> dict[str, Any]:
        service = self.service
        try:
            if action == "pin":
                service.pin(int(number))  # type: ignore[arg-type]
            elif action == "rollback":
                service.rollback(int(number))  # type: ignore[arg-type]
            elif action == "follow":
                service.follow()
            else:
                raise CommandError(f"unknown version action {action!r}")
        except FinetuneError as exc:
            raise CommandError(str(exc)) from None
        status = service.status()
        return {"pinned": status["pinned"], "pending": status["pending"], "in_control": status["in_control"]}

    def status(self, episodes: list[dict[str, Any]]) -> dict[str, Any]:
        return {**self.service.status(), "episodes": episodes}


def labelled_loader(
    policy_loader: Callable[[str, gym.Env[Any, Any]], LoadedPolicy], env: gym.Env[Any, Any], base_label: str
) -> Callable[[Path], LoadedPolicy]:
    """Loads a version folder as a policy for ``env``, labelled with the version (runs on the service's thread)."""

    def load(path: Path) -> LoadedPolicy:
        loaded = policy_loader(str(path), env)
        return replace(loaded, label=f"{base_label} · {path.name}")

    return load
