"""The live dashboard: FastAPI serves the page, the stream and the session store; viser draws the scene.

Routes
  ``/``                         the dashboard page (app/frontend, no CDN)
  ``/ws``                       the live stream and the operator's controls (see :mod:`app.messages`)
  ``/viser/``, ``/viser``       viser's viewer and its websocket, relayed on the same origin
  ``/api/state``                loop state; ``/api/options`` simulators, scenarios, policies, expert modes
  ``/api/sessions``             recorded sessions; ``/api/sessions/{id}/episodes`` their episodes
  ``/api/sessions/{id}/segments[?episode=N]``  takeover segments (first/last step, who acted)
  ``/api/sessions/{id}/events?episode=N``       the episode's timeline (gate, takeovers, violations, end)
  ``/api/sessions/{id}/export.{csv|parquet}[?episode=N]``  download steps

viser runs in this process on its own loopback port (``port=0``); the live loop runs the one
:meth:`core.loop.Runner.step` in a background thread (:mod:`app.live`). A trained policy driving a recorded
session is fine-tuned on it by a worker process (``ServerSettings.finetune``); the page shows its versions.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import functools
import io
import json
import logging
from collections.abc import AsyncIterator, Awaitable, Callable
from contextlib import asynccontextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final, Protocol

import gymnasium as gym
from fastapi import FastAPI, HTTPException, Query, WebSocket
from fastapi.responses import FileResponse, JSONResponse, Response
from fastapi.staticfiles import StaticFiles

from app import commands as c
from app import messages as m
from app.hub import Client, Hub
from app.live import CommandError, FinetuneSettings, LiveConfig, LiveLoop, PolicyLoader, dumps, json_safe
from app.operator import ControlDesk, OperatorConsole
from app.origin import OriginGuard, allowed_hosts
from app.policies import SCRIPTED, LoadedPolicy, default_policy, discover, load_policy
from app.replay import ReplayError, ReplaySession, open_replay
from app.viser_proxy import ViserProxy
from core.finetune import FinetuneConfig
from core.promotion import PromotionConfig
from core.sessions import SessionError, SessionStore

log = logging.getLogger(__name__)

FRONTEND = Path(__file__).resolve().parent / "frontend"
COMMAND_TIMEOUT = 60.0
"""Seconds a page waits for the loop to apply a command (building a SUMO world takes a few)."""


def make_env(sim: str, scenario: str | None) -> gym.Env[Any, Any]:
    """The live env of a named scenario, with the simulator's live options (its descriptor says which)."""
    import sims

    return sims.make(sim, scenario, live=True)


def sim_catalogue() -> dict[str, dict[str, Any]]:
    """Every registered simulator, whether its package imports, and its scenarios by name (from its descriptor)."""
    import sims

    out: dict[str, dict[str, Any]] = {}
    for name in sims.names():
        try:
            d = sims.descriptor(name)
        except Exception as exc:  # a broken simulator is shown as unavailable, not fatal
            log.warning("simulator %s failed to import: %s", name, exc)
            out[name] = {"name": name, "title": name, "env_id": "", "available": False, "scenarios": []}
            continue
        scenarios = [{"id": s.name, "label": s.label} for s in d.scenarios]
        out[name] = {
            "name": name,
            "title": d.title,
            "env_id": d.env_id,
            "available": True,
            "scenarios": scenarios,
            "default_scenario": d.default_scenario,
        }
    return out


class GateSettingLoader(Protocol):
    """A :data:`app.live.PolicyLoader` that also takes the gate's settings (as :func:`app.policies.load_policy`):
    :meth:`ServerSettings.loader` passes them when ``gate_settings`` holds any."""

    def __call__(
        self, choice: str, env: gym.Env[Any, Any], gate_overrides: dict[str, Any] | None = None
    ) -> LoadedPolicy: ...


@dataclass
class ServerSettings:
    host: str = "127.0.0.1"
    port: int = 8000
    sim: str = "ugv"
    scenario: str | None = None
    """A scenario name of the simulator (its descriptor lists them; the UGV also takes a YAML file); None: default."""
    policy: str | None = None
    """A run folder, a checkpoint, ``"scripted"``, or None for the committed default of ``sim``."""
    expert_mode: m.ExpertMode = "person"
    speed: float = 1.0
    seed: int = 0
    sessions: Path | None = Path("sessions")
    """Where sessions are recorded; None records nothing."""
    policy_roots: list[Path] = field(default_factory=lambda: [Path("policies"), Path("runs")])
    start_paused: bool = False
    env_factory: Callable[[str, str | None], gym.Env[Any, Any]] = make_env
    policy_loader: GateSettingLoader = load_policy
    catalogue: Callable[[], dict[str, dict[str, Any]]] = sim_catalogue
    viser_host: str = "127.0.0.1"
    viser_port: int = 0
    finetune: bool = True
    """Fine-tune a trained policy on the session it drives, in a worker process (needs ``sessions``)."""
    finetune_runs: Path | None = None
    """Where fine-tuning versions go (``<runs>/<session id>/versions``); None: ``<sessions>/finetune``."""
    finetune_config: FinetuneConfig = field(default_factory=FinetuneConfig)
    finetune_nice: int = 10
    """Added to the fine-tuning worker's niceness, so that the live loop wins a contended core."""
    allow_hosts: list[str] = field(default_factory=list)
    """Host names besides the loopback ones (and ``host``) that may reach the dashboard (serving on a LAN)."""
    promotion: PromotionConfig = field(default_factory=PromotionConfig)
    """How a fine-tuned version is evaluated before it may drive (:mod:`core.promotion`)."""
    gate_settings: dict[str, Any] = field(default_factory=dict)
    """Settings of the gate over each driven policy's own (``sage serve --set gate.KEY=VALUE``, e.g. a longer hold):
    :class:`core.sage.config.GateConfig` fields, applied to every policy with a world model that this dashboard
    loads, fine-tuned versions included."""

    worker_stop_wait: float | None = None
    """Seconds shutdown waits for the fine-tuning worker to stop; None: until it has (``sage serve`` waits
    0.5 s, as the process ends right after and takes the worker with it, so that Ctrl+C is quick)."""

    def loader(self) -> PolicyLoader:
        """The policy loader with :attr:`gate_settings` applied."""
        if not self.gate_settings:
            return self.policy_loader
        return functools.partial(self.policy_loader, gate_overrides=self.gate_settings)

    def finetune_settings(self) -> FinetuneSettings | None:
        if not self.finetune or self.sessions is None:
            return None
        runs = self.finetune_runs or Path(self.sessions) / "finetune"
        return FinetuneSettings(runs, self.finetune_config, promotion=self.promotion, nice=self.finetune_nice)


class Dashboard:
    """The running pieces, held by the app between startup and shutdown."""

    def __init__(self, settings: ServerSettings) -> None:
        import viser

        self.settings = settings
        self._catalogue: dict[str, dict[str, Any]] | None = None
        self.store = SessionStore(settings.sessions) if settings.sessions is not None else None
        self.hub = Hub()
        self.replays: dict[int, ReplaySession] = {}
        """Each page's open replay, by client id."""
        self.console = OperatorConsole()
        self.desk = ControlDesk()
        # viser prints its own address box even when not verbose; the page is what users open, not viser
        with contextlib.redirect_stdout(io.StringIO()):
            self.viser = viser.ViserServer(host=settings.viser_host, port=settings.viser_port, verbose=False)
        log.info("viser on %s:%d, relayed at /viser/", settings.viser_host, self.viser.get_port())
        self.viser.gui.configure_theme(dark_mode=True, show_logo=False, show_share_button=False)
        self.viser.scene.set_up_direction("+z")
        # No environment map and no shadows: a top-down map needs neither, and without a GPU (software
        # WebGL) they make every frame several times dearer, which starves the page's input handling.
        self.viser.scene.configure_environment_map(None)
        self.viser.scene.world_axes.visible = False
        self.viser.scene.configure_default_lights(enabled=False)
        self.viser.scene.add_light_ambient("/lights/ambient", intensity=0.55)
        self.viser.scene.add_light_directional(
            "/lights/sun", intensity=1.1, position=(0.0, 0.0, 10.0), wxyz=(0.9659, 0.2588, 0.0, 0.0)
        )
        from app.scene_view import SceneView

        self.scene_view = SceneView(self.viser)
        self.proxy = ViserProxy(self.viser.get_port(), settings.viser_host)
        policy = settings.policy or default_policy(settings.policy_roots, settings.sim)
        scenario = settings.scenario
        if scenario is None:  # the simulator's default, by name, so that the page shows which one drives
            scenario = self.catalogue().get(settings.sim, {}).get("default_scenario")
        config = LiveConfig(
            sim=settings.sim,
            scenario=scenario,
            policy=policy,
            expert_mode=settings.expert_mode,
            speed=settings.speed,
            seed=settings.seed,
        )
        loop_args: dict[str, Any] = {
            "env_factory": settings.env_factory,
            "policy_loader": settings.loader(),
            "console": self.console,
            "publish": self.hub.publish,
            "store": self.store,
            "scene_view": self.scene_view,
            "start_paused": settings.start_paused,
            "finetune": settings.finetune_settings(),
        }
        try:
            self.live = LiveLoop(config, **loop_args)
        except Exception as exc:
            if settings.policy is not None or policy == SCRIPTED:
                raise  # what the user asked for explicitly fails loudly, with the reason
            # the default policy found on disk does not load: open anyway, driven by the scripted expert
            log.error("default policy %s does not load (%s); using the scripted expert", policy, exc)
            self.live = LiveLoop(dataclasses.replace(config, policy=SCRIPTED), **loop_args)
            self.live.last_error = f"default policy {policy} does not load: {exc}"

    def catalogue(self) -> dict[str, dict[str, Any]]:
        """Simulators and their scenarios (imports each package once, then cached)."""
        if self._catalogue is None:
            self._catalogue = self.settings.catalogue()
        return self._catalogue

    def options(self) -> dict[str, Any]:
        catalogue = self.catalogue()
        policies = {
            name: [c.as_dict() for c in discover(self.settings.policy_roots, name)]
            for name, entry in catalogue.items()
            if entry["available"]
        }
        return {"sims": list(catalogue.values()), "policies": policies, "expert_modes": list(m.EXPERT_MODES)}

    def close(self) -> None:
        self.live.stop(worker_timeout=self.settings.worker_stop_wait)
        self.scene_view.close()
        self.viser.stop()


def _error(text: str, **extra: Any) -> str:
    return dumps({"type": "error", "error": text, **extra})


Handler = Callable[["Dashboard", Client, Any], Awaitable[str | None]]
_HANDLERS: dict[type, Handler] = {}


def handles(*kinds: type) -> Callable[[Handler], Handler]:
    """Register the handler of one or more message classes (as viser registers its message handlers)."""

    def register(function: Handler) -> Handler:
        for kind in kinds:
            if kind in _HANDLERS:
                raise ValueError(f"{kind.__name__} already has a handler")
            _HANDLERS[kind] = function
        return function

    return register


# Final and not tuple[type, ...]: isinstance then narrows a message that is none of these to those with a token
OPEN_TO_ANY_PAGE: Final = (m.Ping, m.Claim, m.ReplayOpen, m.ReplaySeek, m.ReplayClose)
"""Messages any page may send; every other message needs the operator's control token."""


async def _handle(dash: Dashboard, client: Client, raw: str | bytes) -> str | None:
    """One message from a page: validate, authorise, dispatch by class. Returns the reply text, if any."""
    try:
        msg = m.parse_message(raw)
    except m.MessageError as exc:
        return _error(str(exc))
    if not isinstance(msg, OPEN_TO_ANY_PAGE) and not dash.desk.check(client, msg.token):
        return _error(f"{msg.type!r} refused: only the operator holding the control token may do this", op=msg.type)
    handler = _HANDLERS.get(type(msg))
    if handler is None:  # pragma: no cover - every message class has a handler (tested)
        return _error(f"unhandled message {msg.type!r}")
    return await handler(dash, client, msg)


@handles(m.Ping)
async def _ping(dash: Dashboard, client: Client, msg: m.Ping) -> str:
    return dumps({"type": "pong", "ts": msg.ts})


@handles(m.Claim)
async def _claim(dash: Dashboard, client: Client, msg: m.Claim) -> str:
    token = dash.desk.claim(client)
    if token is None:
        return _error("control is held by another operator; this page is a viewer", op="claim")
    dash.console.connect()
    dash.hub.publish(dumps(dash.live.state()))
    return dumps({"type": "control", "granted": True, "token": token})


@handles(m.Release)
async def _release(dash: Dashboard, client: Client, msg: m.Release) -> str:
    dash.desk.release(client)
    dash.console.disconnect()
    dash.hub.publish(dumps(dash.live.state()))
    return dumps({"type": "control", "granted": False})


@handles(m.Input)
async def _input(dash: Dashboard, client: Client, msg: m.Input) -> None:
    dash.console.accept_input(
        seq=msg.seq,
        ts=msg.ts,
        held=msg.held,
        throttle=msg.throttle,
        steer=msg.steer,
        source=msg.source,
        coach=msg.coach,
    )


@handles(m.Presence)
async def _presence(dash: Dashboard, client: Client, msg: m.Presence) -> None:
    dash.console.set_presence(msg.focused, msg.visible)


CONTROL_OPS: dict[str, type[c.Pause | c.Resume | c.StepOnce | c.NewEpisode]] = {
    "pause": c.Pause,
    "resume": c.Resume,
    "step": c.StepOnce,
    "new_episode": c.NewEpisode,
}


async def _command(dash: Dashboard, msg: m.ClientMessage, command: c.Command) -> str:
    """Apply a loop command and answer with its result (or the reason it was refused)."""
    future = dash.live.submit(command)
    try:
        result = await asyncio.wait_for(asyncio.wrap_future(future), COMMAND_TIMEOUT)
    except CommandError as exc:
        return _error(str(exc), op=msg.type)
    except TimeoutError:
        return _error(f"{msg.type} timed out after {COMMAND_TIMEOUT:.0f} s", op=msg.type)
    return dumps({"type": "ack", "op": getattr(msg, "op", msg.type), "result": result})


@handles(m.Control)
async def _control(dash: Dashboard, client: Client, msg: m.Control) -> str:
    return await _command(dash, msg, CONTROL_OPS[msg.op]())


@handles(m.Speed)
async def _speed(dash: Dashboard, client: Client, msg: m.Speed) -> str:
    return await _command(dash, msg, c.SetSpeed(msg.value))


@handles(m.VersionControl)
async def _version(dash: Dashboard, client: Client, msg: m.VersionControl) -> str:
    return await _command(dash, msg, c.ChooseVersion(msg.op, msg.version))


@handles(m.Configure)
async def _configure(dash: Dashboard, client: Client, msg: m.Configure) -> str:
    scenario, default = msg.scenario, None
    if msg.sim is not None:
        catalogue = await asyncio.to_thread(dash.catalogue)
        if msg.sim not in catalogue or not catalogue[msg.sim]["available"]:
            return _error(f"simulator {msg.sim!r} is not available here", op="configure")
        default = default_policy(dash.settings.policy_roots, msg.sim)
        if scenario is None:
            entry = catalogue[msg.sim]
            scenario = entry.get("default_scenario") or (entry["scenarios"][0]["id"] if entry["scenarios"] else None)
    command = c.Configure(msg.sim, scenario, msg.policy, msg.expert_mode, default)
    return await _command(dash, msg, command)


@handles(m.View)
async def _view(dash: Dashboard, client: Client, msg: m.View) -> str:
    dash.scene_view.set_view(msg.mode)
    dash.hub.publish(dumps(dash.live.state()))
    return dumps({"type": "ack", "op": "view", "result": {"view": msg.mode}})


# -- replay: per page, the live loop runs on ---------------------------------------------------------------
@handles(m.ReplayOpen)
async def _replay_open(dash: Dashboard, client: Client, msg: m.ReplayOpen) -> str:
    try:
        replay = await asyncio.to_thread(open_replay, dash.store, msg.session, msg.episode, dash.live.world.writer)
    except ReplayError as exc:
        return _error(str(exc), op=msg.type)
    dash.replays[client.id] = replay
    await client.reply(dumps(json_safe(replay.opened())))
    return dumps(json_safe(replay.seek(0)))


@handles(m.ReplaySeek)
async def _replay_seek(dash: Dashboard, client: Client, msg: m.ReplaySeek) -> str:
    replay = dash.replays.get(client.id)
    if replay is None:
        return _error("no replay is open on this page", op=msg.type)
    return dumps(json_safe(replay.seek(msg.t)))


@handles(m.ReplayClose)
async def _replay_close(dash: Dashboard, client: Client, msg: m.ReplayClose) -> str:
    dash.replays.pop(client.id, None)
    return dumps({"type": "replay_closed"})


def create_app(settings: ServerSettings | None = None) -> FastAPI:
    settings = settings or ServerSettings()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        dash = Dashboard(settings)
        dash.hub.bind(asyncio.get_running_loop())
        dash.live.start()
        # importing every simulator package for the picker takes seconds: do it before the first page asks
        asyncio.get_running_loop().run_in_executor(None, dash.catalogue)
        app.state.dash = dash
        try:
            yield
        finally:
            await asyncio.get_running_loop().run_in_executor(None, dash.close)

    app = FastAPI(title="SAGE live dashboard", lifespan=lifespan)
    # same origin only: unknown Host names (DNS rebinding) and cross-origin websockets are refused
    app.add_middleware(OriginGuard, hosts=allowed_hosts(settings.host, settings.allow_hosts))

    def dash_of(app: FastAPI) -> Dashboard:
        return app.state.dash

    @app.get("/", include_in_schema=False)
    async def index() -> FileResponse:
        return FileResponse(FRONTEND / "index.html", headers={"Cache-Control": "no-cache"})

    app.mount("/static", StaticFiles(directory=FRONTEND), name="static")

    @app.get("/api/state")
    async def state() -> JSONResponse:
        return JSONResponse(dash_of(app).live.state())

    @app.get("/api/options")
    async def options() -> JSONResponse:
        return JSONResponse(dash_of(app).options())

    def store() -> SessionStore:
        s = dash_of(app).store
        if s is None:
            raise HTTPException(404, "this server records no sessions")
        return s

    @app.get("/api/sessions")
    async def sessions() -> JSONResponse:
        infos = await asyncio.to_thread(store().list_sessions)
        return JSONResponse([i.as_dict() for i in infos])

    @app.get("/api/sessions/{session_id}/episodes")
    async def episodes(session_id: str) -> JSONResponse:
        dash = dash_of(app)
        writer = dash.live.world.writer
        if writer is not None and writer.session_id == session_id:
            await asyncio.to_thread(writer.flush)
        try:
            rows = await asyncio.to_thread(store().episodes, session_id)
        except SessionError as exc:
            raise HTTPException(404, str(exc)) from None
        return JSONResponse(json.loads(dumps(rows)) if rows else [])

    @app.get("/api/sessions/{session_id}/segments")
    async def segments(session_id: str, episode: int | None = Query(default=None, ge=0)) -> JSONResponse:
        try:
            rows = await asyncio.to_thread(store().segments, session_id, episode)
        except SessionError as exc:
            raise HTTPException(404, str(exc)) from None
        return JSONResponse(rows)

    @app.get("/api/sessions/{session_id}/events")
    async def events(session_id: str, episode: int = Query(ge=0)) -> JSONResponse:
        dash = dash_of(app)
        writer = dash.live.world.writer
        if writer is not None and writer.session_id == session_id:
            await asyncio.to_thread(writer.flush)
        try:
            rows = await asyncio.to_thread(store().events, session_id, episode)
        except SessionError as exc:
            raise HTTPException(404, str(exc)) from None
        return JSONResponse(rows)

    @app.get("/api/sessions/{session_id}/export.{fmt}")
    async def export(session_id: str, fmt: str, episode: int | None = Query(default=None, ge=0)) -> Response:
        if fmt not in ("csv", "parquet"):
            raise HTTPException(400, f"unknown format {fmt!r}; use csv or parquet")
        dash = dash_of(app)
        writer = dash.live.world.writer
        if writer is not None and writer.session_id == session_id:
            await asyncio.to_thread(writer.flush)
        try:
            body = await asyncio.to_thread(store().export, session_id, fmt, episode)
        except SessionError as exc:
            raise HTTPException(404, str(exc)) from None
        name = f"{session_id}{'' if episode is None else f'-ep{episode}'}.{fmt}"
        media = "text/csv" if fmt == "csv" else "application/vnd.apache.parquet"
        return Response(body, media_type=media, headers={"Content-Disposition": f'attachment; filename="{name}"'})

    @app.get("/viser", include_in_schema=False)
    @app.get("/viser/", include_in_schema=False)
    async def viser_index() -> Response:
        return await dash_of(app).proxy.http("")

    @app.get("/viser/{path:path}", include_in_schema=False)
    async def viser_files(path: str) -> Response:
        return await dash_of(app).proxy.http(path)

    @app.websocket("/viser")
    @app.websocket("/viser/")
    async def viser_socket(websocket: WebSocket) -> None:
        await dash_of(app).proxy.relay(websocket)

    @app.websocket("/ws")
    async def stream(websocket: WebSocket) -> None:
        dash = dash_of(app)
        await websocket.accept()
        loop = asyncio.get_running_loop()
        options = await loop.run_in_executor(None, dash.options)
        client = dash.hub.add()
        await client.reply(dash.live.welcome(client.id, options))  # first, and never dropped
        sender = asyncio.create_task(Hub.pump(client, websocket.send_text))
        try:
            while True:
                frame = await websocket.receive()
                if frame["type"] == "websocket.disconnect":
                    break
                raw = frame.get("text")
                if raw is None:
                    raw = frame.get("bytes") or b""
                try:
                    reply = await _handle(dash, client, raw)
                except Exception as exc:  # never let one message end the connection or the loop
                    log.exception("message handling failed")
                    reply = _error(f"internal error: {type(exc).__name__}: {exc}")
                if reply is not None:
                    # replies wait for room (a flooding page slows only itself); the stream drops instead
                    await client.reply(reply)
        finally:
            dash.hub.remove(client)
            dash.replays.pop(client.id, None)
            sender.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await sender
            if dash.desk.release(client):
                dash.console.disconnect()
                dash.hub.publish(dumps(dash.live.state()))

    return app
