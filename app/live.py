"""The live loop: the one :meth:`core.loop.Runner.step` at wall-clock rate in a background thread.

Everything that changes the loop (pause, single step, speed, simulator / scenario / policy / expert mode,
replay) arrives as a command and is applied in the loop's own thread between two steps, so the runner is
never touched by two threads. Each step is recorded by the session writer, streamed to every page (one
JSON text built here, off the asyncio loop) and its scene handed to the viser drawing thread.

When the operator starts holding the takeover key the loop steps at once and re-phases its clock, so
a takeover does not wait up to a whole control period; the control rate itself never changes.

Continual adaptation: when the policy is a trained agent (a checkpoint) and the session is recorded, a
fine-tuning worker process (:class:`core.worker.FinetuneService`) learns from the session while the loop
runs and publishes numbered versions (``<runs>/<session id>/versions/vNNNN``, v0000 = the policy deployed).
The loop takes a new version only at an episode boundary: ``Runner.set_policy_at_boundary`` with a new gate
bound to the new policy. The operator can pin a version, follow the newest, or roll back (``version``).
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

from app.input_map import mapping_for
from app.messages import ExpertMode
from app.operator import OperatorConsole, PersonExpert
from app.policies import LoadedPolicy
from core.finetune import FinetuneConfig, FinetuneError, VersionStore
from core.loop import EpisodeSummary, NoGate, Runner, StepRecord
from core.promotion import PromotionConfig, evaluate_version
from core.protocol import simulator
from core.sessions import SessionStore, SessionWriter
from core.worker import FinetuneService, WorkerSpec

log = logging.getLogger(__name__)

EnvFactory = Callable[[str, "int | None"], gym.Env[Any, Any]]
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


def _clean(value: Any) -> Any:
    """JSON-safe: NaN/inf become None, numpy scalars become Python numbers."""
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {str(k): _clean(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_clean(v) for v in value]
    return value


def dumps(message: dict[str, Any]) -> str:
    return json.dumps(message, separators=(",", ":"), allow_nan=False, default=str)


def _is_agent(config: LiveConfig, loaded: LoadedPolicy) -> bool:
    """A trained agent loaded from a checkpoint (the scripted expert and test stand-ins are not fine-tuned)."""
    return bool(loaded.meta.get("method")) and Path(config.policy).exists()


class CommandError(RuntimeError):
    """A command the loop refused (unknown simulator, policy that does not load, ...)."""


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


@dataclass
class Counters:
    episodes: int = 0
    steps: int = 0
    takeover_steps: int = 0
    person_steps: int = 0
    fallback_steps: int = 0
    takeover_events: int = 0
    collisions: int = 0
    violations: int = 0
    episode_steps: int = 0
    episode_takeovers: int = 0
    episode_return: float = 0.0
    episode_cost: float = 0.0
    _prev_takeover: bool = False
    _prev_violation: bool = False

    def add(self, record: StepRecord) -> None:
        if record.t == 0:
            self.episode_steps, self.episode_takeovers = 0, 0
            self.episode_return, self.episode_cost = 0.0, 0.0
            self._prev_takeover = self._prev_violation = False
        self.steps += 1
        self.episode_steps += 1
        self.episode_return += record.reward
        self.episode_cost += record.cost
        if record.takeover:
            self.takeover_steps += 1
            self.episode_takeovers += 1
            self.takeover_events += int(not self._prev_takeover)
        self.person_steps += int(record.actor == "person")
        self.fallback_steps += int(record.actor == "fallback")
        self.violations += int(record.violation and not self._prev_violation)
        self._prev_takeover, self._prev_violation = record.takeover, record.violation

    def as_dict(self) -> dict[str, Any]:
        out = {k: v for k, v in asdict(self).items() if not k.startswith("_")}
        out["takeover_rate"] = self.takeover_steps / self.steps if self.steps else 0.0
        out["episode_takeover_rate"] = self.episode_takeovers / self.episode_steps if self.episode_steps else 0.0
        return out


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
    counters: Counters = field(default_factory=Counters)
    finetune: FinetuneService | None = None
    version: int | None = None
    """The policy version in control (None when nothing is fine-tuned)."""
    episode_log: deque[dict[str, Any]] = field(default_factory=lambda: deque(maxlen=EPISODE_LOG))
    """Per finished episode: the version that drove it and its takeover rate (the page's adaptation chart)."""
    base_label: str = ""

    @property
    def session_id(self) -> str | None:
        return self.writer.session_id if self.writer else None


@dataclass
class Replay:
    session: str
    episode: int
    static: dict[str, Any] | None
    scenes: list[dict[str, Any] | None]
    series: dict[str, list[Any]]
    t: int = 0

    @property
    def length(self) -> int:
        return len(self.scenes)


class LiveLoop:
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
        self.replay: Replay | None = None
        self.history: deque[str] = deque(maxlen=HISTORY)
        self.trail: deque[tuple[float, float]] = deque(maxlen=600)
        self.scene: dict[str, Any] | None = None
        self.last_error: str | None = None
        self.step_times: deque[float] = deque(maxlen=200)
        """Wall-clock instants of recent steps (for the achieved rate)."""
        self.step_costs: deque[float] = deque(maxlen=200)
        """Seconds spent inside each recent step (policy, gate, env, listeners)."""
        self._commands: queue.SimpleQueue[tuple[str, dict[str, Any], concurrent.futures.Future[Any]]] = (
            queue.SimpleQueue()
        )
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

    def stop(self, timeout: float = 5.0) -> None:
        self._stop = True
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout)
        if self.world.finetune is not None:
            self.world.finetune.stop()
        if self.world.writer is not None:
            self.world.writer.close()
        self.world.env.close()

    def submit(self, op: str, **args: Any) -> concurrent.futures.Future[Any]:
        """Queue a command for the loop thread; the future holds its result or its :class:`CommandError`."""
        future: concurrent.futures.Future[Any] = concurrent.futures.Future()
        self._commands.put((op, args, future))
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
        return _clean(
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
                "counters": world.counters.as_dict(),
                "replay": None
                if self.replay is None
                else {
                    "session": self.replay.session,
                    "episode": self.replay.episode,
                    "t": self.replay.t,
                    "length": self.replay.length,
                },
                "error": self.last_error,
                "store_error": world.writer.error if world.writer else None,
            }
        )

    def welcome(self, client_id: int, options: dict[str, Any]) -> str:
        """The first message a page gets: who it is, the state, the options and the recent history."""
        head = dumps({"type": "welcome", "client": client_id, "state": self.state(), "options": _clean(options)})
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
                world.finetune = self._start_finetune(world)
                world.version = 0
            except Exception as exc:  # the loop drives on without fine-tuning, and says why
                log.exception("fine-tuning could not start")
                self.last_error = f"fine-tuning is off: {exc}"
        runner.step_listeners.append(lambda r: expert.note_executed(r.action, r.actor, r.takeover))
        runner.step_listeners.append(self._capture_scene)
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
        old, self.world = self.world, world
        if old.finetune is not None:  # the old session's worker ends in the background (it may take a second)
            threading.Thread(target=old.finetune.stop, name="finetune-stop", daemon=True).start()
        if old.writer is not None:
            old.writer.close()
        old.env.close()
        self.history.clear()
        self.trail.clear()
        self.scene = None
        if self.scene_view is not None:
            self.scene_view.reset_trail()

    # -- listeners (loop thread) -----------------------------------------------------------------------
    def _capture_scene(self, record: StepRecord) -> None:
        try:
            self.scene = simulator(self.world.env).scene()
        except Exception as exc:
            self.scene = None
            self.last_error = f"scene() failed: {exc}"

    def _on_step(self, record: StepRecord) -> None:
        world = self.world
        world.counters.add(record)
        message = record.to_message()
        message["type"] = "step"
        message["session"] = world.session_id
        message["version"] = world.version
        message["request_person"] = bool(record.gate_fired and world.expert.mode == "person")
        operator = self.console.snapshot()
        message["operator_held"] = operator.held and operator.answering
        message["counters"] = {**world.counters.as_dict(), **world.expert.handover_stats()}
        person_input = world.expert.last_input if record.actor == "person" else None
        if person_input is not None:
            message["input_seq"] = person_input.seq
            message["input_ts"] = person_input.ts
            message["input_source"] = person_input.source
        message["applied_ms"] = record.wall_time * 1000.0
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
        text = dumps(_clean(message))
        self.history.append(text)
        self.publish(text)

    def _on_episode(self, summary: EpisodeSummary) -> None:
        world = self.world
        world.counters.episodes += 1
        collision = summary.metrics.get("collision", summary.metrics.get("collisions", 0))
        collided = bool(collision) and not (isinstance(collision, float) and math.isnan(collision))
        world.counters.collisions += int(collided)
        if world.finetune is not None and world.version is not None:
            reason = world.finetune.record_episode(world.version, collided, summary.takeover_rate)
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
        row = {"type": "episode", "session": world.session_id, "version": world.version, **summary.as_row()}
        self.publish(dumps(_clean(row)))
        if summary.error:
            self.last_error = f"episode {summary.episode}: {summary.error}"

    # -- the thread --------------------------------------------------------------------------------------
    def _takeover_onset(self) -> None:
        self._onset = True
        self._wake.set()

    def _run(self) -> None:
        next_at = self.clock()
        while not self._stop:
            self._drain_commands()
            if self._stop:
                break
            if self.paused or self.replay is not None:
                self._wake.wait(0.1)
                self._wake.clear()
                next_at = self.clock()
                continue
            now = self.clock()
            onset = self._onset
            if now < next_at and not onset:
                self._wake.wait(next_at - now)
                self._wake.clear()
                continue
            self._onset = False
            self._step_once()
            period = self.world.dt / self.speed
            after = self.clock()
            # keep the rate without bursts: never catch up more than one missed period; a takeover re-phases
            next_at = after + period if onset else max(next_at + period, after - period)

    def _step_once(self) -> None:
        started = time.perf_counter()
        if self.world.finetune is not None and self.world.runner.obs is None:
            self._take_version(self.world)  # between episodes: the only moment a new version may take over
        try:
            self.world.runner.step()
        except Exception as exc:  # a policy or gate bug: report it, keep the loop alive, start over
            self.last_error = f"step failed: {type(exc).__name__}: {exc}"
            log.exception("live step failed")
            self.world.runner.end_episode(error=f"{type(exc).__name__}: {exc}")
        self.step_costs.append(time.perf_counter() - started)
        self.step_times.append(time.monotonic())

    def _drain_commands(self) -> None:
        while True:
            try:
                op, args, future = self._commands.get_nowait()
            except queue.Empty:
                return
            if not future.set_running_or_notify_cancel():
                continue
            try:
                result = self._apply(op, args)
            except CommandError as exc:
                future.set_exception(exc)
            except Exception as exc:
                log.exception("command %s failed", op)
                future.set_exception(CommandError(f"{op} failed: {type(exc).__name__}: {exc}"))
            else:
                future.set_result(result)
            self.publish(dumps(self.state()))

    # -- commands (loop thread) ------------------------------------------------------------------------
    def _apply(self, op: str, args: dict[str, Any]) -> Any:
        world = self.world
        if op == "pause":
            self.paused = True
        elif op == "resume":
            self.paused = False
        elif op == "step":
            if self.replay is not None:
                raise CommandError("leave the replay before stepping the live loop")
            self.paused = True
            self._step_once()
        elif op == "new_episode":
            world.runner.end_episode()  # recorded with its summary; the next step starts a new episode
        elif op == "speed":
            self.speed = float(args["value"])
        elif op == "configure":
            changes = {k: v for k, v in args.items() if v is not None}
            if "sim" in changes and changes["sim"] != world.config.sim:
                changes.setdefault("scenario", args.get("scenario"))
                if "policy" not in changes:
                    changes["policy"] = args.get("default_policy") or "scripted"
            changes.pop("default_policy", None)
            config = replace(world.config, **changes)
            if config == world.config:
                return asdict(config)
            if {k for k in changes if getattr(world.config, k) != changes[k]} == {"expert_mode"}:
                world.expert.mode = config.expert_mode  # no rebuild: the same episode goes on
                world.config = config
            else:
                self._replace_world(config)
            return asdict(self.world.config)
        elif op == "version":
            return self._version_command(str(args["action"]), args.get("number"))
        elif op == "replay_open":
            return self._open_replay(str(args["session"]), int(args["episode"]))
        elif op == "replay_seek":
            return self._seek(int(args["t"]))
        elif op == "replay_close":
            self._close_replay()
        elif op == "stop":
            self._stop = True
        else:
            raise CommandError(f"unknown command {op!r}")
        return None

    # -- fine-tuning ---------------------------------------------------------------------------------------
    def _start_finetune(self, world: World) -> FinetuneService:
        settings, store, writer = self.finetune, self.store, world.writer
        assert settings is not None and store is not None and writer is not None
        versions = VersionStore(settings.runs / writer.session_id / "versions")
        versions.ensure_initial(world.config.policy)
        # every new version is evaluated headless (scripted expert, fixed seeds) beside the one in control before
        # it may drive: the worker builds the session's env itself, so the factory must cross the spawn boundary
        make_env = functools.partial(self.env_factory, world.config.sim, world.config.scenario)
        evaluator = functools.partial(evaluate_version, make_env=make_env)
        spec = WorkerSpec(
            versions.root,
            store.root,
            writer.session_id,
            settings.config,
            evaluator=evaluator,
            promotion=settings.promotion,
        )
        env, base_label = world.env, world.loaded.label

        def load(path: Path) -> LoadedPolicy:  # runs on the service's thread, never the loop's
            loaded = self.policy_loader(str(path), env)
            return replace(loaded, label=f"{base_label} · {path.name}")

        def changed() -> None:
            if self.world is world:
                self.publish(dumps(_clean({"type": "finetune", **self._finetune_state(world)})))

        return FinetuneService(spec, load, backoff=settings.backoff, on_change=changed).start()

    def _finetune_state(self, world: World) -> dict[str, Any] | None:
        if world.finetune is None:
            return None
        return {**world.finetune.status(), "episodes": list(world.episode_log)}

    def _take_version(self, world: World) -> None:
        assert world.finetune is not None
        pending = world.finetune.take_pending()
        if pending is None:
            return
        number, loaded = pending
        # the runner swaps the policy when it resets for the next episode; the gate must watch that policy
        world.runner.set_policy_at_boundary(loaded.policy, loaded.gate)
        world.loaded = loaded
        world.version = number
        world.finetune.mark_deployed(number)
        self.publish(dumps(self.state()))

    def _version_command(self, action: str, number: int | None) -> dict[str, Any]:
        service = self.world.finetune
        if service is None:
            raise CommandError("no fine-tuning here: it runs for a trained policy on a recorded session")
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

    def _open_replay(self, session: str, episode: int) -> dict[str, Any]:
        if self.store is None:
            raise CommandError("this server records no sessions, so there is nothing to replay")
        if self.world.writer is not None and self.world.writer.session_id == session:
            self.world.writer.flush()
        try:
            static, scenes = self.store.scenes(session, episode)
            arrays = self.store.steps(session, episode)
        except LookupError as exc:
            raise CommandError(str(exc)) from None
        if not scenes:
            raise CommandError(f"episode {episode} of {session} has no steps")
        series = {
            "t": arrays["t"].tolist(),
            "fear": arrays["fear"].tolist(),
            "threshold": arrays["threshold"].tolist(),
            "curiosity": arrays["curiosity"].tolist(),
            "takeover": arrays["takeover"].tolist(),
            "actor": arrays["actor"].tolist(),
            "reward": arrays["reward"].tolist(),
            "cost": arrays["cost"].tolist(),
            "violation": arrays["violation"].tolist(),
            "action": arrays["action"].tolist(),
            "a_rl": arrays["a_rl"].tolist(),
        }
        self.replay = Replay(session, episode, static, scenes, series)
        self.publish(dumps(_clean({"type": "replay", "session": session, "episode": episode, "series": series})))
        self._seek(0)
        return {"session": session, "episode": episode, "length": len(scenes)}

    def _seek(self, t: int) -> dict[str, Any]:
        replay = self.replay
        if replay is None:
            raise CommandError("no replay is open")
        t = max(0, min(t, replay.length - 1))
        replay.t = t
        scene = replay.scenes[t]
        if self.scene_view is not None and scene is not None:
            trail = [(s["ego"]["x"], s["ego"]["y"]) for s in replay.scenes[: t + 1] if s and s.get("ego")]
            self.scene_view.show(scene, static=replay.static, trail=False)
            self.scene_view.reset_trail(trail)
        labels = (scene or {}).get("labels")
        self.publish(dumps(_clean({"type": "replay_frame", "t": t, "length": replay.length, "labels": labels})))
        return {"t": t}

    def _close_replay(self) -> None:
        self.replay = None
        if self.scene_view is not None:
            self.scene_view.reset_trail(list(self.trail))
            if self.scene is not None:
                self.scene_view.show(self.scene, trail=False)
        self.publish(dumps({"type": "replay_closed"}))
