"""The SUMO env in its own process: parallel simulations, and SUMO steps that never hold the caller's GIL.

libsumo runs one simulation per process and holds the GIL during ``simulationStep``, so a thread that steps it
blocks every other thread of its process (an asyncio event loop included) for the step's duration.
:class:`SumoProcessEnv` owns a spawned worker process that owns one :class:`~sims.sumo.env.SumoEnv`; the two
speak a small pipe protocol:

    parent -> worker   (method, args, kwargs)        method in reset, step, expert_action, scene, metrics,
                                                     set_scenario, close
    worker -> parent   ("ok", result) | ("error", exception type, message, traceback)

Waiting on the pipe releases the GIL. A SUMO error inside the worker comes back as :class:`SumoError` (the worker
lives on and the next reset starts a fresh simulation); a worker that died or stopped answering is replaced by a
new one at the next reset. The static part of ``scene()`` crosses the pipe only when its key changes.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import signal
import traceback
from dataclasses import replace
from multiprocessing.connection import Connection
from typing import Any

import gymnasium as gym
import numpy as np

from core.scene import Scene
from sims.sumo.engine import SumoError
from sims.sumo.env import CONFIG_FIELDS, OBS_SIZE, SumoConfig, SumoEnv

PASSED_THROUGH: dict[str, type[Exception]] = {
    "ValueError": ValueError,
    "TypeError": TypeError,
    "RuntimeError": RuntimeError,
    "FileNotFoundError": FileNotFoundError,
}
"""Caller mistakes raised in the worker come back as the same type; everything else as SumoError."""
WORKER_METHODS = frozenset({"reset", "step", "expert_action", "scene", "metrics", "set_scenario", "close"})


def _worker(conn: Connection, config: dict[str, Any]) -> None:
    """The worker's loop (the spawn target): one SumoEnv, one request at a time, until ``close`` or EOF."""
    # Ctrl+C in a terminal reaches the whole process group: the parent closes this worker (or its EOF ends it);
    # a KeyboardInterrupt here only printed a traceback
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    env = SumoEnv(SumoConfig(**config))
    try:
        while True:
            try:
                method, args, kwargs = conn.recv()
            except (EOFError, OSError):
                return
            if method not in WORKER_METHODS:
                conn.send(("error", "ValueError", f"unknown worker method {method!r}", ""))
                continue
            try:
                if method == "step" and kwargs.pop("expert", False) and env.pending_expert_action is not None:
                    args = (env.pending_expert_action,)  # the parent passed on the expert's own array
                if method == "scene":
                    known_key = kwargs.pop("known_static_key", None)
                    result: Any = env.scene()
                    if known_key is not None and result["static_key"] == known_key:
                        result = {**result, "static": None}
                else:
                    result = getattr(env, method)(*args, **kwargs)
            except Exception as exc:
                conn.send(("error", type(exc).__name__, str(exc), traceback.format_exc()))
                continue
            conn.send(("ok", result))
            if method == "close":
                return
    finally:
        env.close()
        conn.close()


class SumoProcessEnv(gym.Env[np.ndarray, np.ndarray]):
    """:class:`SumoEnv` behind a pipe to a spawned worker process (same spaces, methods and metrics).

    ``timeout`` bounds every request (seconds): a worker that does not answer in time is killed and the request
    raises :class:`SumoError`.
    """

    metadata: dict[str, Any] = {"render_modes": []}  # noqa: RUF012 - gymnasium's class attribute

    def __init__(self, config: SumoConfig | None = None, *, timeout: float = 120.0, **overrides: Any) -> None:
        super().__init__()
        unknown = set(overrides) - CONFIG_FIELDS
        if unknown:
            raise TypeError(f"unknown SumoEnv option(s): {', '.join(sorted(unknown))}")
        self.config = replace(config or SumoConfig(), **overrides)
        SumoEnv._check_inputs(self.config)  # a bad path fails here, in the caller's process, naming the file
        self.timeout = timeout
        self.observation_space = gym.spaces.Box(-1.0, 1.0, (OBS_SIZE,), np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
        self._ctx = mp.get_context("spawn")
        self._process: Any = None
        self._conn: Connection | None = None
        self._static: tuple[str, list[Any]] | None = None
        self._last_expert: np.ndarray | None = None

    # -- worker management ---------------------------------------------------------------------
    @property
    def worker_pid(self) -> int | None:
        return self._process.pid if self._process is not None else None

    def _alive(self) -> bool:
        return self._process is not None and self._process.is_alive() and self._conn is not None

    def _start_worker(self) -> None:
        self._stop_worker()
        parent, child = self._ctx.Pipe()
        self._process = self._ctx.Process(
            target=_worker, args=(child, self.config.to_dict()), name="sage-sumo-worker", daemon=True
        )
        self._process.start()
        child.close()
        self._conn = parent

    def _stop_worker(self) -> None:
        conn, process = self._conn, self._process
        self._conn, self._process = None, None
        if conn is not None:
            try:
                if process is not None and process.is_alive():
                    conn.send(("close", (), {}))
                    if conn.poll(5.0):
                        conn.recv()
            except (EOFError, OSError, BrokenPipeError):
                pass
            conn.close()
        if process is not None:
            process.join(5.0)
            if process.is_alive():
                process.kill()
                process.join(5.0)

    def _call(self, method: str, *args: Any, **kwargs: Any) -> Any:
        if self._process is not None and self._conn is not None and not self._process.is_alive():
            # it died since the last call (killed, crashed): said as such, not as a worker never started
            raise self._died(f"before {method!r}")
        if not self._alive():
            raise SumoError("the SUMO worker process is not running: call reset() to start a new one")
        assert self._conn is not None and self._process is not None
        try:
            self._conn.send((method, args, kwargs))
            if not self._conn.poll(self.timeout):
                pid = self._process.pid
                self._process.kill()
                raise SumoError(f"the SUMO worker process (pid {pid}) did not answer {method!r} in {self.timeout} s")
            reply = self._conn.recv()
        except (EOFError, OSError, BrokenPipeError) as exc:
            raise self._died(f"during {method!r}") from exc
        if reply[0] == "ok":
            return reply[1]
        _status, kind, message, remote_traceback = reply
        error_type = PASSED_THROUGH.get(kind, SumoError)
        plain = kind in PASSED_THROUGH or kind == "SumoError"
        error = error_type(message if plain else f"{kind} in the SUMO worker: {message}")
        if remote_traceback:
            error.add_note(f"in the SUMO worker process:\n{remote_traceback}")
        raise error

    def _died(self, when: str) -> SumoError:
        """The error for a worker found dead (``when``: before or during which call), its pipe closed and the worker
        forgotten, so that the next reset starts a new one."""
        process, conn = self._process, self._conn
        assert process is not None and conn is not None
        process.join(1.0)
        conn.close()
        self._conn, self._process = None, None
        return SumoError(f"the SUMO worker process (pid {process.pid}) died {when} (exit code {process.exitcode})")

    # -- gymnasium -----------------------------------------------------------------------------
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        if not self._alive():
            self._start_worker()
        obs, info = self._call("reset", seed=seed, options=options)
        if options:
            self.config = replace(self.config, **options)
        return obs, info

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        expert = self._last_expert is not None and action is self._last_expert
        self._last_expert = None
        return self._call("step", np.asarray(action, dtype=np.float32), expert=expert)

    def close(self) -> None:
        self._stop_worker()

    def __del__(self) -> None:  # a forgotten env must not leave a worker behind
        with contextlib.suppress(Exception):
            self._stop_worker()

    # -- the simulator protocol ----------------------------------------------------------------
    def expert_action(self) -> np.ndarray:
        """SUMO's driver model; passing this very array to ``step`` lets SUMO drive that step (as in SumoEnv)."""
        self._last_expert = self._call("expert_action")
        return self._last_expert

    def scene(self) -> Scene:
        known = self._static[0] if self._static is not None else None
        result = self._call("scene", known_static_key=known)
        if result["static"] is None and self._static is not None:
            result["static"] = self._static[1]
        else:
            self._static = (result["static_key"], result["static"])
        return result

    def metrics(self) -> dict[str, float]:
        return self._call("metrics")

    def set_scenario(self, route: int | None = None, special_vehicles: bool | None = None) -> None:
        """Switch route and/or special vehicles from the next ``reset`` on (a new worker starts with them too)."""
        changes = {k: v for k, v in (("route", route), ("special_vehicles", special_vehicles)) if v is not None}
        updated = replace(
            self.config,
            route=self.config.route if route is None else route,
            special_vehicles=self.config.special_vehicles if special_vehicles is None else special_vehicles,
        )
        SumoEnv._check_inputs(updated)
        if self._alive():
            self._call("set_scenario", **changes)
        self.config = updated
