"""The live loop: the one :meth:`core.loop.Runner.step` at wall-clock rate in a background thread.

Its parts, one job each:

- :mod:`app.clock`: when the next step is due (dt / speed, no bursts, re-phased when a takeover starts);
- :mod:`app.commands`: what may change the loop (pause, one step, speed, simulator / scenario / policy /
  expert mode, version), typed, dispatched by class, applied in the loop's own thread between two steps so
  the runner is never touched by two threads;
- :mod:`app.counters`: the session's counters, read from the runner's own tallies;
- :mod:`app.versions`: which fine-tuned version drives (a worker process learns from the session while the
  loop runs; a new version takes over only at an episode boundary).

Replay is not the loop's business: each page replays on its own (:mod:`app.replay`) while the loop runs on.
Each step is recorded by the session writer, streamed to every page (one JSON text built here, off the
asyncio loop) and its scene handed to the viser drawing thread.
"""

from __future__ import annotations

import concurrent.futures
import functools
import json
import logging
import math
import queue
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from app import commands as c
from app.clock import RateClock
from app.commands import CommandError, CommandRegistry
from app.counters import SessionCounters
from app.input_map import mapping_for
from app.messages import ExpertMode
from app.operator import OperatorConsole, PersonExpert
from app.policies import LoadedPolicy
from app.versions import FinetuneSettings, VersionFollower, labelled_loader
from core.loop import EpisodeSummary, NoGate, Runner, StepRecord, takeover_cause
from core.promotion import reached_goal
from core.protocol import simulator
from core.scene import Scene
from core.sessions import SessionStore, SessionWriter

__all__ = ["CommandError", "FinetuneSettings", "LiveConfig", "LiveLoop", "PolicyLoader", "World", "dumps", "json_safe"]

log = logging.getLogger(__name__)

EnvFactory = Callable[[str, "str | None"], gym.Env[Any, Any]]
"""Builds simulator ``sim`` on a scenario name (None: its default), as :func:`app.server.make_env`."""
PolicyLoader = Callable[[str, gym.Env[Any, Any]], LoadedPolicy]
Publish = Callable[[str], None]

HISTORY = 600
"""Step messages kept for a page that connects late (its charts start full)."""
EPISODE_LOG = 300
"""Episodes kept for the page's takeover-rate-per-version chart."""


@dataclass(frozen=True)
class LiveConfig:
    sim: str = "ugv"
    scenario: str | None = None
    """A scenario name of the simulator (None: its default)."""
    policy: str = "scripted"
    expert_mode: ExpertMode = "person"
    speed: float = 1.0
    seed: int = 0


def safe_action(sim: str, action_space: gym.Space[Any]) -> np.ndarray | None:
    """The simulator's safe action (stop or brake) from its descriptor; None for an unregistered env."""
    import sims

    try:
        return sims.descriptor(sim).safe(action_space)
    except ValueError:
        return None


def control_period(sim: str, env: gym.Env[Any, Any]) -> float:
    """Seconds of simulated time per step: the simulator descriptor's ``dt`` (an unregistered env, such as a
    test's toy simulator, may say it as ``env.unwrapped.dt``; otherwise 0.1 s)."""
    import sims

    try:
        return sims.descriptor(sim).dt
    except ValueError:
        value = getattr(env.unwrapped, "dt", None)
        return float(value) if isinstance(value, int | float) and value > 0 else 0.1


def json_safe(value: Any) -> Any:
    """JSON-safe: NaN/inf become None, numpy scalars become Python numbers."""
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(v) for v in value]
    return value


def dumps(message: object) -> str:
    return json.dumps(message, separators=(",", ":"), allow_nan=False, default=str)


def _is_agent(config: LiveConfig, loaded: LoadedPolicy) -> bool:
    """A trained agent loaded from a checkpoint (the scripted expert and test stand-ins are not fine-tuned)."""
    return bool(loaded.meta.get("method")) and Path(config.policy).exists()


@dataclass
class World:
    """Everything built from one configuration: env, runner, expert, session writer."""

    config: LiveConfig
    env: gym.Env[Any, Any]
    runner: Runner
    expert: PersonExpert
    loaded: LoadedPolicy
    writer: SessionWriter | None
    dt: float
    counters: SessionCounters = field(default_factory=SessionCounters)
    versions: VersionFollower | None = None
    """The fine-tuned versions of the policy (None when nothing is fine-tuned)."""
    episode_log: deque[dict[str, Any]] = field(default_factory=lambda: deque(maxlen=EPISODE_LOG))
    """Per finished episode: the version that drove it and its takeover rate (the page's adaptation chart)."""
    base_label: str = ""

    @property
    def session_id(self) -> str | None:
        return self.writer.session_id if self.writer else None

    @property
    def version(self) -> int | None:
        """The policy version in control (None when nothing is fine-tuned)."""
        return self.versions.version if self.versions is not None else None

    def counts(self) -> dict[str, Any]:
        """The session's counters, with the running episode's tallies from the runner."""
        return self.counters.as_dict(self.runner.progress(), running=self.runner.obs is not None)


class LiveLoop:
    commands = CommandRegistry()

    def __init__(
        self,
        config: LiveConfig,
        *,
        env_factory: EnvFactory,
        policy_loader: PolicyLoader,
        console: OperatorConsole,
        publish: Publish,
        store: SessionStore | None = None,
        scene_view: Any = None,
        clock: Callable[[], float] = time.monotonic,
        start_paused: bool = False,
        finetune: FinetuneSettings | None = None,
    ) -> None:
        self.finetune = finetune
        self.env_factory = env_factory
        self.policy_loader = policy_loader
        self.console = console
        self.publish = publish
        self.store = store
        self.scene_view = scene_view
        self.clock = clock
        self.paused = start_paused
        self.speed = config.speed
        self.imagined_horizon = True
        """Stream (and record) the gate's imagined horizon with each step (bench_server measures its cost)."""
        self.history: deque[str] = deque(maxlen=HISTORY)
        self.trail: deque[tuple[float, float]] = deque(maxlen=600)
        self.scene: Scene | None = None
        self.last_error: str | None = None
        self.step_times: deque[float] = deque(maxlen=200)
        """Wall-clock instants of recent steps (for the achieved rate)."""
        self.step_costs: deque[float] = deque(maxlen=200)
        """Seconds spent inside each recent step (policy, gate, env, listeners)."""
        self._commands: queue.SimpleQueue[tuple[object, concurrent.futures.Future[Any]]] = queue.SimpleQueue()
        self._wake = threading.Event()
        self._onset = False
        self._stop = False
        self._thread: threading.Thread | None = None
        self.world = self._build(config)
        console.on_takeover_onset = self._takeover_onset

    # -- public, thread-safe ---------------------------------------------------------------------------
    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="live-loop", daemon=True)
        self._thread.start()

    def stop(self, timeout: float = 2.0, worker_timeout: float | None = None) -> None:
        """End the loop thread (waiting up to ``timeout``), the episode, the session and the fine-tuning worker
        (waiting up to ``worker_timeout``; None: until its own stop returned, a few seconds at most)."""
        self._stop = True
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout)
        if not self.running:  # the loop thread is gone: the running episode is ours to end, with its reason
            self.world.runner.end_episode(reason="server stopped")
        # the worker is asked to stop while the session and the env close (it may still be importing torch, or be
        # mid-round, for seconds); a process about to end need not wait: its worker ends with it (core.worker
        # watches its parent; multiprocessing ends daemonic children at exit)
        stopping = None
        if self.world.versions is not None:
            stopping = threading.Thread(target=self.world.versions.stop, name="finetune-stop", daemon=True)
            stopping.start()
        if self.world.writer is not None:
            self.world.writer.close()
        self.world.env.close()
        if stopping is not None:
            stopping.join(worker_timeout)

    def submit(self, command: c.Command) -> concurrent.futures.Future[Any]:
        """Queue a command (:mod:`app.commands`) for the loop thread; the future holds its result or its
        :class:`CommandError`."""
        future: concurrent.futures.Future[Any] = concurrent.futures.Future()
        self._commands.put((command, future))
        self._wake.set()
        return future

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def state(self) -> dict[str, Any]:
        world = self.world
        times = list(self.step_times)
        rate = (len(times) - 1) / (times[-1] - times[0]) if len(times) > 2 and times[-1] > times[0] else 0.0
        costs = list(self.step_costs)
        return json_safe(
            {
                "type": "state",
                "config": asdict(world.config) | {"speed": self.speed},
                "paused": self.paused,
                "speed": self.speed,
                "dt": world.dt,
                "target_rate": self.speed / world.dt,
                "rate": rate,
                "step_ms_p50": 1000 * float(np.median(costs)) if costs else None,
                "session": world.session_id,
                "episode": world.runner.episode,
                "policy_label": world.loaded.label,
                "has_gate": not isinstance(world.loaded.gate, NoGate),
                "version": world.version,
                "finetune": self._finetune_state(world),
                "action_dim": int(np.prod(world.env.action_space.shape or (1,))),
                "operator": self.console.connected,
                "counters": world.counts(),
                "view": getattr(self.scene_view, "view", None),
                "error": self.last_error,
                "store_error": world.writer.error if world.writer else None,
            }
        )

    def welcome(self, client_id: int, options: dict[str, Any]) -> str:
        """The first message a page gets: who it is, the state, the options and the recent history."""
        head = dumps({"type": "welcome", "client": client_id, "state": self.state(), "options": json_safe(options)})
        return head[:-1] + ',"history":[' + ",".join(list(self.history)) + "]}"

    # -- building ------------------------------------------------------------------------------------
    def _build(self, config: LiveConfig) -> World:
        env = self.env_factory(config.sim, config.scenario)
        try:
            simulator(env)
            loaded = self.policy_loader(config.policy, env)
            expert = PersonExpert(
                self.console,
                mapping_for(config.sim, env.action_space),
                env.action_space,
                config.expert_mode,
                safe=safe_action(config.sim, env.action_space),
            )
            runner = Runner(env, loaded.policy, loaded.gate, expert, seed=config.seed)
            runner.agent_action_filter = expert.hand_back  # the hand-back to the policy is bumpless too
        except Exception:
            env.close()
            raise
        writer = None
        if self.store is not None:
            writer = self.store.create(
                config.sim,
                scenario=config.scenario,
                policy=config.policy,
                expert_mode=config.expert_mode,
                meta={"policy_label": loaded.label, "seed": config.seed, "dt": control_period(config.sim, env)},
                scene_source=lambda: self.scene,
            )
        world = World(
            config, env, runner, expert, loaded, writer, control_period(config.sim, env), base_label=loaded.label
        )
        if writer is not None and self.finetune is not None and self.store is not None and _is_agent(config, loaded):
            try:
                world.versions = self._start_versions(world)
            except Exception as exc:  # the loop drives on without fine-tuning, and says why
                log.exception("fine-tuning could not start")
                self.last_error = f"fine-tuning is off: {exc}"
        runner.step_listeners.append(self._note_horizon)  # before the writer: the session stores it too
        runner.step_listeners.append(lambda r: expert.note_executed(r.action, r.actor, r.takeover))
        runner.step_listeners.append(self._capture_scene)
        # the version that drove the episode goes into its recorded metrics (the timeline marks version changes)
        runner.episode_listeners.append(self._note_version)
        if writer is not None:
            writer.attach(runner)
        runner.step_listeners.append(self._on_step)
        runner.episode_listeners.append(self._on_episode)
        return world

    def _replace_world(self, config: LiveConfig) -> None:
        try:
            world = self._build(config)
        except Exception as exc:
            raise CommandError(
                f"cannot switch to {config.sim} / scenario {config.scenario} / {config.policy}: {exc}"
            ) from exc
        # the running episode ends here, recorded as interrupted (it would otherwise stay "running" forever)
        self.world.runner.end_episode(reason=f"switched to {config.sim} / {config.scenario} / {config.policy}")
        old, self.world = self.world, world
        if old.versions is not None:
            old.versions.stop(background=True)
        if old.writer is not None:
            old.writer.close()
        old.env.close()
        self.history.clear()
        self.trail.clear()
        self.scene = None
        if self.scene_view is not None:
            self.scene_view.reset_trail()

    # -- listeners (loop thread) -----------------------------------------------------------------------
    def _note_version(self, summary: EpisodeSummary) -> None:
        if self.world.versions is not None and self.world.version is not None:
            summary.metrics["policy_version"] = float(self.world.version)

    def _note_horizon(self, record: StepRecord) -> None:
        """The gate's imagined horizon of this step (per member, per step ahead) into the record's info."""
        horizon = getattr(self.world.runner.gate, "last_horizon", None)
        if self.imagined_horizon and callable(horizon) and record.fear == record.fear:  # fear computed this step
            record.info["horizon"] = horizon()

    def _capture_scene(self, record: StepRecord) -> None:
        try:
            self.scene = simulator(self.world.env).scene()
        except Exception as exc:
            self.scene = None
            self.last_error = f"scene() failed: {exc}"

    def _on_step(self, record: StepRecord) -> None:
        world = self.world
        # why the scripted expert has the wheel this step (fear, the hold, its hysteresis, a manoeuvre to finish),
        # also when it drives as the fallback for a person who did not take hold
        scripted = record.actor in ("expert", "fallback")
        cause = takeover_cause(record, world.runner.gate) if scripted else None
        world.counters.on_step(record, cause)
        message = record.to_message()
        message["type"] = "step"
        message["session"] = world.session_id
        message["version"] = world.version
        message["request_person"] = bool(record.gate_fired and world.expert.mode == "person")
        message["takeover_cause"] = cause
        operator = self.console.snapshot()
        message["operator_held"] = operator.held and operator.answering
        message["counters"] = {**world.counts(), **world.expert.handover_stats()}
        person_input = world.expert.last_input if record.actor == "person" else None
        if person_input is not None:
            message["input_seq"] = person_input.seq
            message["input_ts"] = person_input.ts
            message["input_source"] = person_input.source
        message["applied_ms"] = record.wall_time * 1000.0
        if record.info.get("horizon") is not None:
            message["horizon"] = record.info["horizon"]
        scene = self.scene
        if scene is not None:
            ego = scene.get("ego") or {}
            if ego:
                message["ego"] = [ego.get("x"), ego.get("y"), ego.get("yaw")]
                self.trail.append((float(ego["x"]), float(ego["y"])))
            if scene.get("labels"):
                message["labels"] = scene["labels"]
            if self.scene_view is not None:
                self.scene_view.show(scene)
        text = dumps(json_safe(message))
        self.history.append(text)
        self.publish(text)

    def _on_episode(self, summary: EpisodeSummary) -> None:
        world = self.world
        collided = world.counters.on_episode(summary, world.runner.progress())
        if world.versions is not None:
            reached = reached_goal(summary)
            reason = world.versions.episode_ended(collided, summary.takeover_rate, reached)
            if reason is not None:
                self.last_error = f"rolled back automatically: {reason}"
        world.episode_log.append(
            {
                "episode": summary.episode,
                "version": world.version,
                "takeover_rate": summary.takeover_rate,
                "steps": summary.steps,
                "collision": collided,
                "success": bool(summary.metrics.get("success", False)),
            }
        )
        row = {
            "type": "episode",
            "session": world.session_id,
            "version": world.version,
            "reason": summary.reason,
            **summary.as_row(),
        }
        self.publish(dumps(json_safe(row)))
        if summary.error:
            self.last_error = f"episode {summary.episode}: {summary.error}"

    # -- the thread --------------------------------------------------------------------------------------
    def _takeover_onset(self) -> None:
        self._onset = True
        self._wake.set()

    def _run(self) -> None:
        clock = RateClock(self.clock())
        while not self._stop:
            self._drain_commands()
            if self._stop:
                break
            if self.paused:
                self._wake.wait(0.1)
                self._wake.clear()
                clock.restart(self.clock())
                continue
            onset = self._onset
            wait = clock.wait(self.clock(), onset)
            if wait > 0:
                self._wake.wait(wait)
                self._wake.clear()
                continue
            self._onset = False
            self._step_once()
            clock.stepped(self.clock(), self.world.dt / self.speed, onset)

    def _step_once(self) -> None:
        started = time.perf_counter()
        world = self.world
        if world.versions is not None and world.runner.obs is None:
            # between episodes: the only moment a new version may take over
            def adopt(loaded: LoadedPolicy) -> None:
                world.loaded = loaded

            if world.versions.take_at_boundary(world.runner, adopt) is not None:
                self.publish(dumps(self.state()))
        try:
            self.world.runner.step()
        except Exception as exc:  # a policy or gate bug: report it, keep the loop alive, start over
            self.last_error = f"step failed: {type(exc).__name__}: {exc}"
            log.exception("live step failed")
            self.world.runner.end_episode(error=f"{type(exc).__name__}: {exc}", reason="error")
        self.step_costs.append(time.perf_counter() - started)
        self.step_times.append(time.monotonic())

    def _drain_commands(self) -> None:
        while True:
            try:
                command, future = self._commands.get_nowait()
            except queue.Empty:
                return
            if not future.set_running_or_notify_cancel():
                continue
            try:
                result = self.commands.dispatch(self, command)
            except CommandError as exc:
                future.set_exception(exc)
            except Exception as exc:
                name = type(command).__name__
                log.exception("command %s failed", name)
                future.set_exception(CommandError(f"{name} failed: {type(exc).__name__}: {exc}"))
            else:
                future.set_result(result)
            self.publish(dumps(self.state()))

    # -- commands (loop thread), one handler per command class ------------------------------------------
    @commands.handles(c.Pause)
    def _pause(self, command: c.Pause) -> None:
        self.paused = True

    @commands.handles(c.Resume)
    def _resume(self, command: c.Resume) -> None:
        self.paused = False

    @commands.handles(c.StepOnce)
    def _step_command(self, command: c.StepOnce) -> None:
        self.paused = True
        self._step_once()

    @commands.handles(c.NewEpisode)
    def _new_episode(self, command: c.NewEpisode) -> None:
        self.world.runner.end_episode(reason="new episode (operator)")  # the next step starts a new episode

    @commands.handles(c.SetSpeed)
    def _speed(self, command: c.SetSpeed) -> None:
        self.speed = float(command.value)

    @commands.handles(c.Stop)
    def _stop_command(self, command: c.Stop) -> None:
        self._stop = True

    @commands.handles(c.Configure)
    def _configure(self, command: c.Configure) -> dict[str, Any]:
        world = self.world
        changes: dict[str, Any] = {
            k: v
            for k, v in (
                ("sim", command.sim),
                ("scenario", command.scenario),
                ("policy", command.policy),
                ("expert_mode", command.expert_mode),
            )
            if v is not None
        }
        if "sim" in changes and changes["sim"] != world.config.sim:
            changes.setdefault("scenario", command.scenario)
            if "policy" not in changes:
                changes["policy"] = command.default_policy or "scripted"
        config = replace(world.config, **changes)
        if config == world.config:
            return asdict(config)
        if {k for k in changes if getattr(world.config, k) != changes[k]} == {"expert_mode"}:
            world.expert.mode = config.expert_mode  # no rebuild: the same episode goes on
            world.config = config
        else:
            self._replace_world(config)
        return asdict(self.world.config)

    @commands.handles(c.ChooseVersion)
    def _choose_version(self, command: c.ChooseVersion) -> dict[str, Any]:
        versions = self.world.versions
        if versions is None:
            raise CommandError("no fine-tuning here: it runs for a trained policy on a recorded session")
        return versions.choose(command.action, command.number)

    # -- fine-tuning ---------------------------------------------------------------------------------------
    def _start_versions(self, world: World) -> VersionFollower:
        settings, store, writer = self.finetune, self.store, world.writer
        assert settings is not None and store is not None and writer is not None

        def changed() -> None:
            # the state is None exactly when the world has no versions (fine-tuning off)
            if self.world is world and (state := self._finetune_state(world)) is not None:
                self.publish(dumps(json_safe({"type": "finetune", **state})))

        make_env = functools.partial(self.env_factory, world.config.sim, world.config.scenario)
        load = labelled_loader(self.policy_loader, world.env, world.loaded.label)
        return VersionFollower.start(
            settings,
            store.root,
            writer.session_id,
            world.config.policy,
            make_env,
            load,
            changed,
            scenario_env=functools.partial(self.env_factory, world.config.sim),
            scenario=world.config.scenario,
        )

    def _finetune_state(self, world: World) -> dict[str, Any] | None:
        if world.versions is None:
            return None
        return world.versions.status(list(world.episode_log))
