"""The fine-tuning worker: :meth:`core.finetune.Finetuner.round` in its own process, restarted when it dies.

The live loop steps at 10 Hz on a 2-core machine, so training must never share its interpreter (the GIL) or its
core budget: the worker is a separate process (``multiprocessing`` spawn, ``torch.set_num_threads(1)``, a lower
scheduling priority). It watches the session the loop records, runs a round whenever new episodes are over, and
publishes numbered versions (:class:`core.finetune.VersionStore`). Every version is judged against the version in
control before it may drive (:func:`judge`, :mod:`core.promotion`); a round after a rejected version starts again
from the version in control (:meth:`core.finetune.Finetuner.round`), so rejected versions never form a line.

:class:`FinetuneService` lives in the loop's process. Its monitor thread reads the worker's events (phase,
progress, losses, rounds), restarts a worker that died (exponential backoff, reset once a worker has lived a
while; a restarted worker rebuilds its buffer from the session and continues from the latest version), loads each
new version off the loop's thread (``loader``) and offers it to the loop, which takes it at the next episode
boundary (:meth:`FinetuneService.take_pending`). The operator can pin a version (new versions are then only
listed), follow the newest again, or roll back: deploy an older version and continue fine-tuning from it.

Spawn starts a fresh interpreter that imports the parent's main module: a script that starts the live server
(and so this service) must keep its work under ``if __name__ == "__main__":``, as ``sage`` and pytest do.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import multiprocessing as mp
import os
import pickle
import queue
import signal
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)

Loader = Callable[[Path], Any]
"""Turns a version folder into what the loop runs (the app passes its policy loader: policy + gate)."""


@dataclass(frozen=True)
class WorkerSpec:
    """Everything the worker process needs (picklable: it crosses the spawn boundary)."""

    versions: Path
    """The versions folder (``v0000`` must exist: :meth:`core.finetune.VersionStore.ensure_initial`)."""
    sessions: Path
    """The session store's folder."""
    session_id: str
    config: Any = None
    """A :class:`core.finetune.FinetuneConfig` (None: its defaults)."""
    base: int | None = None
    """Version to continue from (None: the latest)."""
    poll_seconds: float = 1.0
    """How often an idle worker looks for new episodes."""
    nice: int = 10
    """Added to the worker's scheduling niceness, so that the loop wins a contended core."""
    threads: int = 1
    evaluator: Any = None
    """A :data:`core.promotion.Evaluator` (picklable, e.g. a partial of :func:`core.promotion.evaluate_version`):
    every published version is evaluated beside the version in control before it may drive. None: versions are
    marked "not evaluated" and promoted as they come (headless tools only; the live server always passes one)."""
    promotion: Any = None
    """A :class:`core.promotion.PromotionConfig` (None: its defaults)."""
    prior: Any = None
    """A :data:`core.finetune.PriorSource` (picklable, e.g. a partial of :func:`core.finetune.drive_alone` with the
    simulator's ``make_env``): the base policy's own drives, kept beside the session's data in every round. None:
    the session's data only."""
    practice: Any = None
    """A :data:`core.finetune.PriorSource` driving the version in control alone on the session's scenario
    (``FinetuneConfig.practice_episodes``; a partial of :func:`core.finetune.drive_alone`). None: no practice."""
    parent_pid: int | None = None
    """The process that started the worker (set by :class:`FinetuneService`): the worker ends when it is gone,
    even if that happened while the worker was still starting."""


# -- the worker process -------------------------------------------------------------------------------------------
def worker_main(spec: WorkerSpec, events: Any, commands: Any) -> None:
    """Entry point of the worker process: rounds whenever there is new data, until told to stop.

    Any error ends the process after reporting it (``{"kind": "error"}``); the service restarts it. The worker
    also ends when its parent dies (a ``kill -9`` of the server leaves no orphan training on)."""
    # Ctrl+C in a terminal reaches the whole process group: the parent stops this worker itself (a stop command,
    # then terminate), and a KeyboardInterrupt here only printed a traceback under the server's last line
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _watch_parent(spec.parent_pid or os.getppid())
    try:
        _work(spec, events, commands)
    except BaseException as exc:
        with contextlib.suppress(Exception):
            events.put({"kind": "error", "error": f"{type(exc).__name__}: {exc}", "pid": os.getpid()})
            events.close()
            events.join_thread()  # the report must reach the pipe before the process ends
        raise


PARENT_POLL_SECONDS = 0.25


def _watch_parent(parent: int) -> None:
    """A daemon thread that ends this process as soon as ``parent`` is gone (re-parented: getppid changes).

    It must not wait for the main thread, which may be inside a long torch operation: ``os._exit``."""

    def watch() -> None:
        while True:
            if os.getppid() != parent:
                os._exit(0)
            time.sleep(PARENT_POLL_SECONDS)

    threading.Thread(target=watch, name="parent-watch", daemon=True).start()


def _work(spec: WorkerSpec, events: Any, commands: Any) -> None:
    import torch

    torch.set_num_threads(spec.threads)
    with contextlib.suppress(OSError, AttributeError):
        os.nice(spec.nice)
    from core.finetune import FinetuneConfig, Finetuner, VersionStore
    from core.sessions import SessionStore

    def emit(event: dict[str, Any]) -> None:
        events.put({**event, "pid": os.getpid(), "at": time.time()})

    held: list[tuple[str, Any]] = []

    def next_command(timeout: float = 0.0) -> tuple[str, Any] | None:
        if held:
            return held.pop(0)
        try:
            return commands.get(timeout=timeout) if timeout > 0 else commands.get_nowait()
        except queue.Empty:
            return None

    def interrupted() -> bool:
        command = next_command()
        if command is None:
            return False
        held.append(command)  # acted on by the main loop once the round has returned
        return True

    versions = VersionStore(spec.versions)
    store = SessionStore(spec.sessions)
    config = spec.config or FinetuneConfig()
    finetuner = Finetuner(versions, store, spec.session_id, config, spec.base, prior=spec.prior, practice=spec.practice)
    emit({"kind": "ready", "base": finetuner.base.number})
    waiting_said = False
    while True:
        command = next_command()
        if command is not None:
            op, arg = command
            if op == "stop":
                emit({"kind": "stopped"})
                return
            if op == "rebase":
                finetuner = Finetuner(
                    versions, store, spec.session_id, config, int(arg), prior=spec.prior, practice=spec.practice
                )
                emit({"kind": "ready", "base": finetuner.base.number})
                waiting_said = False
            continue
        if not finetuner.ready():
            if not waiting_said:
                emit({"kind": "phase", "phase": "waiting for episodes"})
                waiting_said = True
            command = next_command(spec.poll_seconds)
            if command is not None:
                held.append(command)
            continue
        waiting_said = False
        emit(
            {
                "kind": "phase",
                "phase": f"starting a round ({finetuner.method})",
                "base": finetuner.base.number,
                "method": finetuner.method,
            }
        )
        result = finetuner.round(progress=lambda e: emit({"kind": "progress", **e}), should_stop=interrupted)
        emit({"kind": "round", **result.as_dict(), "base": finetuner.base.number})
        if result.version is not None:
            emit({"kind": "phase", "phase": f"evaluating {result.version.name} before it may drive"})
            verdict = judge(versions, result.version.number, spec.evaluator, spec.promotion)
            emit({"kind": "promotion", "version": result.version.number, **verdict})
            if not verdict.get("promoted"):
                # the next round starts from the version in control, not from this one (Finetuner.round)
                against = verdict.get("against")
                then = f": the next round continues from v{against:04d}" if isinstance(against, int) else ""
                emit({"kind": "phase", "phase": f"{result.version.name} not promoted{then}"})


def judge(versions: Any, number: int, evaluator: Any, promotion: Any = None) -> dict[str, Any]:
    """Evaluate version ``number`` beside the latest promoted version before it and write its verdict.

    The incumbent's evaluation is cached in its own ``promotion.json``, so each version is evaluated once; so is the
    alone record the regression test compares with (``promotion.regression_scenarios``: ``v0000``'s, or with
    ``regression_against="control"`` the version in control's)."""
    import dataclasses

    from core.promotion import BASE_NAME, Evaluation, PromotionConfig, decide, read_verdict, write_verdict

    cfg = promotion or PromotionConfig()
    candidate = versions.get(number)
    if evaluator is None:
        verdict: dict[str, Any] = {"promoted": True, "evaluated": False, "reason": "not evaluated (no evaluator)"}
        write_verdict(candidate.path, verdict)
        return verdict
    incumbent = None
    if cfg.supervised or (cfg.regression_scenarios and cfg.regression_against == "control"):
        incumbent = next((v for v in reversed(versions.versions()) if v.number < number and v.promoted), None)
        if incumbent is None:
            incumbent = versions.get(0)
    base, reference = None, BASE_NAME
    if cfg.regression_scenarios:
        against = incumbent if cfg.regression_against == "control" and incumbent is not None else versions.get(0)
        base = _alone_record(versions, against.number, evaluator, cfg)
        if against.number != 0:
            reference = f"the version in control ({against.name})"
    before: Evaluation | None = None
    if cfg.supervised:
        assert incumbent is not None
        cached = read_verdict(incumbent.path) or {}
        record = cached.get("evaluation")
        if (
            isinstance(record, dict)
            and cached.get("evaluation_seed") == cfg.seed
            and record.get("episodes") == cfg.episodes
            and record.get("episode_takeover")  # the paired test reads each episode's share
        ):
            before = Evaluation.from_dict(cached["evaluation"])
        else:
            # the incumbent needs the supervised record only (the regression test's is apart)
            before = evaluator(incumbent.path, dataclasses.replace(cfg, regression_scenarios=()))
            base_verdict = cached or {"promoted": True, "reason": "the policy deployed by the operator"}
            write_verdict(incumbent.path, {**base_verdict, "evaluation": before.as_dict(), "evaluation_seed": cfg.seed})
    after = evaluator(candidate.path, cfg)
    decision = decide(after, before, cfg, base, reference)
    verdict = {
        "promoted": decision.promoted,
        "evaluated": True,
        "reason": decision.reason,
        "against": None if incumbent is None else incumbent.number,
        "evaluation": after.as_dict(),
        "evaluation_seed": cfg.seed,
        "incumbent": None if before is None else before.as_dict(),
    }
    if base is not None:
        verdict["base_regression"] = base.regression
        # the candidate's own alone record, for when it is in control and the next one is compared with it
        verdict["regression"] = after.as_dict()
        verdict["regression_for"] = _regression_key(cfg)
    write_verdict(candidate.path, verdict)
    return verdict


def _regression_key(cfg: Any) -> dict[str, Any]:
    """What makes two alone records comparable: the same seeds, episodes and cut."""
    return {"seed": cfg.regression_seed, "episodes": cfg.regression_episodes, "max_steps": cfg.max_steps}


def _alone_record(versions: Any, number: int, evaluator: Any, cfg: Any) -> Any:
    """Version ``number`` alone on the regression scenarios' seeds, evaluated once and cached in its
    ``promotion.json`` (``v0000``'s, or the version in control's: a candidate's verdict keeps its own)."""
    import dataclasses

    from core.promotion import Evaluation, read_verdict, write_verdict

    version = versions.get(number)
    cached = read_verdict(version.path) or {}
    key = _regression_key(cfg)
    record = cached.get("regression")
    if (
        isinstance(record, dict)
        and cached.get("regression_for") == key
        and all(scenario in record.get("regression", {}) for scenario in cfg.regression_scenarios)
    ):
        return Evaluation.from_dict(record)
    evaluation = evaluator(version.path, dataclasses.replace(cfg, supervised=False))
    if isinstance(record, dict) and cached.get("regression_for") == key:  # keep the scenarios measured before
        evaluation.regression = {**record.get("regression", {}), **evaluation.regression}
    verdict = cached or {"promoted": True, "reason": "the policy deployed by the operator"}
    write_verdict(version.path, {**verdict, "regression": evaluation.as_dict(), "regression_for": key})
    return evaluation


# -- the supervisor in the loop's process -----------------------------------------------------------------------------
@dataclass
class _Pending:
    number: int
    loaded: Any


@dataclass
class ServiceState:
    alive: bool = False
    pid: int | None = None
    starts: int = 0
    restarts: int = 0
    phase: str = "starting"
    progress: dict[str, Any] = field(default_factory=dict)
    losses: dict[str, float] = field(default_factory=dict)
    last_exit: int | None = None
    next_restart_at: float | None = None
    error: str | None = None


def _promoted(summary: dict[str, Any]) -> bool:
    """A version summary's verdict: may it drive? (:func:`core.promotion.is_promoted` on the summary's copy)."""
    verdict = summary.get("promotion") or {}
    return bool(verdict.get("promoted")) and not verdict.get("rolled_back")


class FinetuneService:
    """Runs and supervises the worker process; decides which version the loop should run next.

    Thread-safety: every public method may be called from any thread (one lock guards the state).
    """

    def __init__(
        self,
        spec: WorkerSpec,
        loader: Loader | None = None,
        *,
        in_control: int = 0,
        backoff: tuple[float, float] = (1.0, 30.0),
        stable_after: float = 60.0,
        on_change: Callable[[], None] | None = None,
        history: int = 100,
    ) -> None:
        from core.finetune import VersionStore

        self.spec = spec
        self.loader = loader
        self.store = VersionStore(spec.versions)
        self.backoff_first, self.backoff_max = backoff
        self.stable_after = stable_after
        self.on_change = on_change
        self.state = ServiceState()
        self.rounds: deque[dict[str, Any]] = deque(maxlen=history)
        self.in_control: int | None = in_control
        self.pinned: int | None = None
        self._base: int | None = spec.base
        self._pending: _Pending | None = None
        # every choice of the next version (automatic or the operator's) takes a ticket under the lock; a load
        # that finishes after a later choice was made is dropped, so a slow load never undoes a newer pin
        self._choice = 0
        self._known: set[int] = {v.number for v in self.store.versions()}
        self._versions: list[dict[str, Any]] = [v.summary() for v in self.store.versions()]
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._ctx = mp.get_context("spawn")
        self._process: Any = None
        self._events: Any = None
        self._commands: Any = None
        self._started_at = 0.0
        self._backoff = self.backoff_first
        self._thread: threading.Thread | None = None
        from core.promotion import LiveWatch

        self.watch = LiveWatch(spec.promotion)
        self._offered: set[int] = set()
        self.last_rollback: str | None = None

    # -- lifecycle ------------------------------------------------------------------------------------------
    def start(self) -> FinetuneService:
        self._spawn()
        self._thread = threading.Thread(target=self._monitor, name="finetune-monitor", daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout: float = 5.0) -> None:
        """Ask the worker to stop, then terminate it if it does not; stop the monitor."""
        self._stop.set()
        process = self._process
        if process is not None and process.is_alive():
            with contextlib.suppress(Exception):
                self._commands.put(("stop", None))
            process.join(timeout)
            if process.is_alive():
                process.terminate()
                process.join(2.0)
            if process.is_alive():
                process.kill()
                process.join(2.0)
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout)
        for channel in (self._commands, self._events):  # release their semaphores now, not at interpreter exit
            if channel is not None:
                with contextlib.suppress(Exception):
                    channel.close()
                    channel.join_thread()
        self._commands = self._events = None
        with self._lock:
            self.state.alive = False
            self.state.phase = "stopped"

    @property
    def pid(self) -> int | None:
        process = self._process
        return process.pid if process is not None else None

    def _spawn(self) -> None:
        with self._lock:
            spec = dataclasses.replace(self.spec, base=self._base, parent_pid=os.getpid())
            # fresh queues for every worker: one killed while writing may leave a queue's lock or pipe broken
            self._events = self._ctx.Queue()
            self._commands = self._ctx.Queue()
            process = self._ctx.Process(
                target=worker_main, args=(spec, self._events, self._commands), name="sage-finetune", daemon=True
            )
            process.start()
            self._process = process
            self._started_at = time.monotonic()
            self.state.alive, self.state.pid = True, process.pid
            self.state.starts += 1
            self.state.phase = "starting"
            self.state.next_restart_at = None
        log.info("fine-tuning worker started (pid %s)", process.pid)

    # -- the monitor thread ------------------------------------------------------------------------------------
    def _monitor(self) -> None:
        last_scan = 0.0
        while not self._stop.is_set():
            try:
                changed = self._drain_events(timeout=0.2)
                now = time.monotonic()
                if now - last_scan > 1.0:
                    changed |= self._scan_versions()
                    last_scan = now
                process = self._process
                if process is not None and not process.is_alive() and not self._stop.is_set():
                    changed |= self._handle_death(process)
                if changed and self.on_change is not None:
                    self.on_change()
            except Exception as exc:  # supervision must outlive any one bad event, file or listener
                log.exception("fine-tuning monitor")
                with self._lock:
                    self.state.error = f"monitor: {type(exc).__name__}: {exc}"
                time.sleep(0.2)

    def _drain_events(self, timeout: float) -> bool:
        changed = False
        events = self._events
        if events is None:  # stopped
            return False
        deadline = time.monotonic() + timeout
        while True:
            remaining = deadline - time.monotonic()
            try:
                event = events.get(timeout=max(remaining, 0.001)) if not changed else events.get_nowait()
            except queue.Empty:
                return changed
            except (EOFError, OSError, ValueError, pickle.UnpicklingError) as exc:  # a worker killed mid-message
                log.warning("fine-tuning event lost: %s", exc)
                return changed
            self._apply_event(event)
            changed = True

    def _apply_event(self, event: dict[str, Any]) -> None:
        kind = event.get("kind")
        with self._lock:
            state = self.state
            if kind == "ready":
                state.phase = f"ready (from v{event.get('base', 0):04d})"
                state.error = None
            elif kind == "phase":
                state.phase = str(event.get("phase"))
            elif kind == "progress":
                state.phase = str(event.get("phase"))
                if event.get("phase") == "training":
                    state.progress = {k: event.get(k) for k in ("update", "updates", "skipped")}
                    state.losses = dict(event.get("losses") or {})
            elif kind == "round":
                row = {k: v for k, v in event.items() if k not in ("kind", "pid")}
                self.rounds.append(row)
                state.phase = "round done" if event.get("version") is not None else f"round: {event.get('reason')}"
                if event.get("losses"):
                    state.losses = dict(event["losses"])
            elif kind == "promotion":
                number = event.get("version")
                verb = "promoted" if event.get("promoted") else "kept, not promoted"
                state.phase = f"v{number:04d} {verb}: {event.get('reason')}" if isinstance(number, int) else state.phase
            elif kind == "stopped":
                state.phase = "stopped"
            elif kind == "error":
                state.error = f"worker failed: {event.get('error')}"
                state.phase = "failed"
        if kind == "round" and event.get("version") is not None:
            self._scan_versions()

    def _scan_versions(self) -> bool:
        """Pick up versions published or judged since the last look (the folder is the truth; events may be lost).

        Following, the loop is offered the newest *promoted* version newer than the one in control: a version
        the evaluation did not promote is listed with its reason and never drives unless the operator pins it."""
        versions = self.store.versions()
        summaries = [v.summary() for v in versions]
        new = [v for v in versions if v.number not in self._known]
        with self._lock:
            changed = bool(new) or summaries != self._versions
            self._known.update(v.number for v in new)
            self._versions = summaries
            if new:
                self._base = None  # the worker's line now ends in a published version: continue from the latest
            offer: tuple[int, int] | None = None
            if self.pinned is None:
                # the summaries already hold each verdict: no second read of every promotion.json
                promoted = [
                    row["number"]
                    for row in summaries
                    if _promoted(row)
                    and row["number"] not in self._offered
                    and (self.in_control is None or row["number"] > self.in_control)
                ]
                if promoted:
                    self._offered.add(promoted[-1])
                    offer = (promoted[-1], self._claim())
        if offer is not None:
            self._offer(*offer)
        return changed

    def _handle_death(self, process: Any) -> bool:
        with self._lock:
            if self.state.alive:
                self.state.alive = False
                self.state.last_exit = process.exitcode
                reason = f"worker (pid {process.pid}) exited with code {process.exitcode}"
                failed = self.state.error if self.state.phase == "failed" else None
                self.state.error = f"{reason}: {failed}" if failed else reason
                if time.monotonic() - self._started_at > self.stable_after:
                    self._backoff = self.backoff_first
                self.state.next_restart_at = time.monotonic() + self._backoff
                self.state.phase = "restarting"
                log.warning("%s; restarting in %.1f s", self.state.error, self._backoff)
                self._backoff = min(self._backoff * 2, self.backoff_max)
                return True
            due = self.state.next_restart_at is not None and time.monotonic() >= self.state.next_restart_at
        if due and not self._stop.is_set():
            with self._lock:
                self.state.restarts += 1
            self._spawn()
            return True
        return False

    # -- versions for the loop ---------------------------------------------------------------------------------
    def _claim(self) -> int:
        """A ticket for a choice of the next version (call holding the lock, where the choice is decided). The
        choice voids the version offered before it: until its own load ends, the loop keeps the one in control."""
        self._choice += 1
        self._pending = None
        return self._choice

    def _offer(self, number: int, ticket: int) -> None:
        """Load ``number`` (off the loop's thread) and make it the version the loop takes at its next boundary,
        unless a later choice (``ticket`` is not the newest) was made meanwhile."""
        if number == self.in_control:
            return  # nothing to switch to (the choice's claim already voided what was offered before)
        loaded: Any = None
        if self.loader is not None:
            try:
                loaded = self.loader(self.store.get(number).path)
            except Exception as exc:
                with self._lock:
                    self.state.error = f"version v{number:04d} does not load: {exc}"
                log.warning("version v%04d does not load: %s", number, exc)
                return
        with self._lock:
            if ticket == self._choice:
                self._pending = _Pending(number, loaded)

    def take_pending(self) -> tuple[int, Any] | None:
        """The version to switch to now (call at an episode boundary), or None. Clears it."""
        with self._lock:
            pending, self._pending = self._pending, None
        if pending is None:
            return None
        return pending.number, pending.loaded

    def mark_deployed(self, number: int) -> None:
        from core.promotion import Evaluation

        with self._lock:
            replaced, self.in_control = self.in_control, number
        evaluation = None
        if replaced is not None:
            with contextlib.suppress(Exception):
                data = (self.store.get(replaced).verdict() or {}).get("evaluation")
                evaluation = Evaluation.from_dict(data) if isinstance(data, dict) else None
        self.watch.deployed(number, replaced, evaluation)

    def record_episode(
        self, number: int, collided: bool, takeover_rate: float, reached: bool | None = None
    ) -> str | None:
        """A live episode driven by version ``number`` ended (``reached``: the goal, None where the simulator did
        not end it). Returns the reason when it was rolled back: a promoted version that does worse live than the
        one it replaced goes back to that one (and is marked)."""
        from core.promotion import read_verdict, write_verdict

        reason = self.watch.record(number, collided, takeover_rate, reached)
        previous = self.watch.predecessor(number)
        if reason is None or previous is None:
            return None
        self.watch.returning_to(previous)  # judged against the version it replaced, it would bounce straight back
        with contextlib.suppress(Exception):
            path = self.store.get(number).path
            write_verdict(path, {**(read_verdict(path) or {}), "rolled_back": True, "rollback_reason": reason})
        with self._lock:
            self.last_rollback = reason
            # decided under the lock: an operator's pin made a moment earlier is kept, not undone
            ticket = self._rebase(previous) if self.pinned is None else None
        log.warning("automatic rollback: %s", reason)
        if ticket is not None:
            self._offer(previous, ticket)
        self._scan_versions()
        if self.on_change is not None:
            self.on_change()
        return reason

    def pin(self, number: int) -> None:
        """Run ``number`` from the next episode on and keep it, whatever the worker publishes."""
        self.store.get(number)  # a clear error for a version that does not exist
        with self._lock:
            self.pinned = number
            ticket = self._claim()
        self._offer(number, ticket)

    def follow(self) -> None:
        """Unpin: run the newest promoted version from the next episode on, and each new one as it is promoted."""
        latest = next((v for v in reversed(self.store.versions()) if v.promoted), None)
        with self._lock:
            self.pinned = None
            ticket = self._claim()
        if latest is not None:
            self._offer(latest.number, ticket)

    def rollback(self, number: int) -> None:
        """Deploy ``number`` again and continue fine-tuning from it (later versions stay on disk, listed)."""
        self.store.get(number)
        with self._lock:
            self.pinned = None
            ticket = self._rebase(number)
        self._offer(number, ticket)

    def _rebase(self, number: int) -> int:
        """Continue fine-tuning from ``number`` and claim the next version for it (call holding the lock)."""
        self._base = number
        if self._commands is not None:  # (a worker started later begins from _base anyway)
            with contextlib.suppress(Exception):
                self._commands.put(("rebase", number))
        return self._claim()

    # -- what the page shows ----------------------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        with self._lock:
            state = self.state
            restart_in = None
            if state.next_restart_at is not None:
                restart_in = max(0.0, state.next_restart_at - time.monotonic())
            return {
                "alive": state.alive,
                "pid": state.pid,
                "starts": state.starts,
                "restarts": state.restarts,
                "phase": state.phase,
                "progress": dict(state.progress),
                "losses": dict(state.losses),
                "error": state.error,
                "restart_in": restart_in,
                "in_control": self.in_control,
                "pinned": self.pinned,
                "pending": None if self._pending is None else self._pending.number,
                "base": self._base,
                "versions": list(self._versions),
                "rounds": list(self.rounds)[-20:],
                "last_rollback": self.last_rollback,
            }
