"""The session store: every step the loop ran, durably on disk, indexed by episode and takeover segment.

One session is one SQLite file ``<root>/<session_id>.sqlite`` in WAL mode, so a reader (the dashboard,
an exporter, the fine-tuning worker) can read while the loop writes, and a crash loses at most the
last commit window. Tables:

``session``   one row: id, creation time, simulator, scenario, policy, expert mode, free-form meta (JSON)
``episodes``  one row per episode: step count, return, cost, takeovers, mean fear/curiosity, the
              simulator's metrics (JSON), error, the episode's static scene (JSON, for replay)
``steps``     one row per step: who acted, both actions, obs/next_obs (float32 blobs), fear, curiosity,
              threshold, reward, cost, flags, the takeover segment it belongs to, an optional scene
              snapshot (zlib-compressed JSON) for replay

Writing: :class:`SessionWriter` is a :class:`core.loop.Runner` step and episode listener. It turns a record
into a row in the caller's thread (microseconds) and hands it to its own writer thread, which commits in
batches, so a 10 Hz loop never waits on the disk. Reading: :class:`SessionStore` lists sessions and
episodes and returns an episode's steps as numpy arrays, or a pyarrow table for CSV/Parquet export.
"""

from __future__ import annotations

import json
import math
import queue
import re
import secrets
import sqlite3
import threading
import time
import zlib
from collections.abc import Callable, Iterator, Mapping
from contextlib import closing, contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from core.protocol import EpisodeSummary, StepRecord

SCHEMA = """
CREATE TABLE IF NOT EXISTS session (
    id TEXT PRIMARY KEY,
    created REAL NOT NULL,
    sim TEXT NOT NULL,
    scenario TEXT,
    policy TEXT,
    expert_mode TEXT,
    meta TEXT NOT NULL DEFAULT '{}'
);
CREATE TABLE IF NOT EXISTS episodes (
    episode INTEGER PRIMARY KEY,
    started REAL NOT NULL,
    ended REAL,
    steps INTEGER NOT NULL DEFAULT 0,
    ret REAL,
    cost REAL,
    takeovers INTEGER,
    takeover_events INTEGER,
    mean_fear REAL,
    mean_curiosity REAL,
    metrics TEXT,
    error TEXT,
    static_scene TEXT,
    end_reason TEXT
);
CREATE TABLE IF NOT EXISTS steps (
    episode INTEGER NOT NULL,
    t INTEGER NOT NULL,
    wall_time REAL NOT NULL,
    actor TEXT NOT NULL,
    takeover INTEGER NOT NULL,
    segment INTEGER,
    gate_fired INTEGER NOT NULL,
    fear REAL,
    threshold REAL,
    curiosity REAL,
    reward REAL NOT NULL,
    cost REAL NOT NULL,
    violation INTEGER NOT NULL,
    terminated INTEGER NOT NULL,
    truncated INTEGER NOT NULL,
    a_rl BLOB NOT NULL,
    a_expert BLOB,
    action BLOB NOT NULL,
    obs BLOB NOT NULL,
    next_obs BLOB NOT NULL,
    scene BLOB,
    horizon TEXT,
    conflict INTEGER,
    PRIMARY KEY (episode, t)
);
CREATE INDEX IF NOT EXISTS steps_by_segment ON steps (episode, segment);
"""

STEP_COLUMNS = (
    "episode, t, wall_time, actor, takeover, segment, gate_fired, fear, threshold, curiosity, reward, cost, "
    "violation, terminated, truncated, a_rl, a_expert, action, obs, next_obs, scene"
)
_NEW_EPISODE = "INSERT OR IGNORE INTO episodes (episode, started) VALUES (?, ?)"
_SESSION_ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,127}$")


class SessionError(LookupError):
    """A session or episode that does not exist, or a malformed session id."""


def _finite_or_none(x: float) -> float | None:
    return float(x) if x is not None and math.isfinite(x) else None


def _blob(array: np.ndarray | None) -> bytes | None:
    if array is None:
        return None
    return np.asarray(array, dtype=np.float32).reshape(-1).tobytes()


def _connect(path: Path) -> sqlite3.Connection:
    conn = sqlite3.connect(path, timeout=10.0, check_same_thread=False)
    conn.execute("PRAGMA journal_mode=WAL")
    conn.execute("PRAGMA synchronous=NORMAL")  # durable at each WAL checkpoint; no fsync per commit
    return conn


def new_session_id(sim: str) -> str:
    """Sortable by time, readable, and unique: ``20250101-120000-ugv-3f9a``."""
    safe_sim = re.sub(r"[^A-Za-z0-9]+", "", sim) or "sim"
    return f"{time.strftime('%Y%m%d-%H%M%S')}-{safe_sim}-{secrets.token_hex(2)}"


@dataclass(frozen=True)
class SessionInfo:
    id: str
    created: float
    sim: str
    scenario: str | None
    policy: str | None
    expert_mode: str | None
    meta: dict[str, Any]
    episodes: int
    steps: int
    takeover_steps: int

    def as_dict(self) -> dict[str, Any]:
        return {
            "id": self.id,
            "created": self.created,
            "sim": self.sim,
            "scenario": self.scenario,
            "policy": self.policy,
            "expert_mode": self.expert_mode,
            "meta": self.meta,
            "episodes": self.episodes,
            "steps": self.steps,
            "takeover_steps": self.takeover_steps,
        }


class SessionStore:
    """A folder of sessions: create one for writing, list them, read episodes back."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)

    # -- paths -----------------------------------------------------------------------------------
    def path(self, session_id: str) -> Path:
        if not _SESSION_ID.match(session_id):
            raise SessionError(f"malformed session id {session_id!r}")
        return self.root / f"{session_id}.sqlite"

    def _existing(self, session_id: str) -> Path:
        path = self.path(session_id)
        if not path.is_file():
            raise SessionError(f"no session {session_id!r} in {self.root}")
        return path

    @contextmanager
    def _read(self, session_id: str) -> Iterator[sqlite3.Connection]:
        with closing(_connect(self._existing(session_id))) as conn:
            conn.row_factory = sqlite3.Row
            yield conn

    # -- writing ---------------------------------------------------------------------------------
    def create(
        self,
        sim: str,
        *,
        scenario: str | int | None = None,
        policy: str | None = None,
        expert_mode: str | None = None,
        meta: dict[str, Any] | None = None,
        session_id: str | None = None,
        scene_source: Callable[[], Mapping[str, Any] | None] | None = None,
        commit_interval: float = 0.25,
    ) -> SessionWriter:
        """Start a new session and return its writer (a Runner listener)."""
        self.root.mkdir(parents=True, exist_ok=True)
        session_id = session_id or new_session_id(sim)
        path = self.path(session_id)
        if path.exists():
            raise SessionError(f"session {session_id!r} already exists")
        with closing(_connect(path)) as conn:
            conn.executescript(SCHEMA)
            conn.execute(
                "INSERT INTO session (id, created, sim, scenario, policy, expert_mode, meta) VALUES (?,?,?,?,?,?,?)",
                (
                    session_id,
                    time.time(),
                    sim,
                    None if scenario is None else str(scenario),
                    policy,
                    expert_mode,
                    json.dumps(meta or {}),
                ),
            )
            conn.commit()
        return SessionWriter(path, session_id, scene_source=scene_source, commit_interval=commit_interval)

    # -- reading ---------------------------------------------------------------------------------
    def list_sessions(self) -> list[SessionInfo]:
        """All readable sessions, newest first. A damaged file is skipped, not fatal."""
        if not self.root.is_dir():
            return []
        infos: list[SessionInfo] = []
        for path in sorted(self.root.glob("*.sqlite"), reverse=True):
            try:
                infos.append(self.info(path.stem))
            except (sqlite3.DatabaseError, SessionError):
                continue
        return infos

    def info(self, session_id: str) -> SessionInfo:
        with self._read(session_id) as conn:
            row = conn.execute("SELECT * FROM session").fetchone()
            if row is None:
                raise SessionError(f"session {session_id!r} has no header row")
            counts = conn.execute(
                "SELECT COUNT(DISTINCT episode), COUNT(*), COALESCE(SUM(takeover), 0) FROM steps"
            ).fetchone()
        return SessionInfo(
            id=row["id"],
            created=row["created"],
            sim=row["sim"],
            scenario=row["scenario"],
            policy=row["policy"],
            expert_mode=row["expert_mode"],
            meta=json.loads(row["meta"] or "{}"),
            episodes=int(counts[0]),
            steps=int(counts[1]),
            takeover_steps=int(counts[2]),
        )

    def episodes(self, session_id: str) -> list[dict[str, Any]]:
        """Episode summaries (steps counted from the stored rows, so a crashed episode still shows)."""
        with self._read(session_id) as conn:
            rows = conn.execute(
                "SELECT e.*, (SELECT COUNT(*) FROM steps s WHERE s.episode = e.episode) AS stored_steps, "
                "(SELECT COALESCE(SUM(takeover), 0) FROM steps s WHERE s.episode = e.episode) AS stored_takeovers, "
                "(SELECT COALESCE(SUM(violation), 0) FROM steps s WHERE s.episode = e.episode) AS violations "
                "FROM episodes e ORDER BY e.episode"
            ).fetchall()
        out = []
        for row in rows:
            steps = int(row["stored_steps"])
            takeovers = int(row["stored_takeovers"])
            out.append(
                {
                    "episode": row["episode"],
                    "started": row["started"],
                    "ended": row["ended"],
                    "finished": row["ended"] is not None,
                    "steps": steps,
                    "return": row["ret"],
                    "cost": row["cost"],
                    "takeovers": takeovers,
                    "takeover_events": row["takeover_events"],
                    "takeover_rate": takeovers / steps if steps else 0.0,
                    "violations": int(row["violations"]),
                    "mean_fear": row["mean_fear"],
                    "mean_curiosity": row["mean_curiosity"],
                    "metrics": json.loads(row["metrics"]) if row["metrics"] else {},
                    "error": row["error"],
                    # sessions recorded before the column existed have no reason
                    "end_reason": row["end_reason"] if "end_reason" in row.keys() else None,  # noqa: SIM118 (Row: values)
                }
            )
        return out

    def _step_rows(self, session_id: str, episode: int | None, takeover_only: bool = False) -> list[sqlite3.Row]:
        """The rows of STEP_COLUMNS and then the simulator's conflict flag (NULL in sessions recorded before it
        was stored)."""
        where = " AND takeover = 1" if takeover_only else ""
        with self._read(session_id) as conn:
            columns = f"{STEP_COLUMNS}, " + ("conflict" if _has_column(conn, "steps", "conflict") else "NULL")
            if episode is None:
                sql = f"SELECT {columns} FROM steps WHERE 1{where} ORDER BY episode, t"
                return conn.execute(sql).fetchall()
            if conn.execute("SELECT 1 FROM episodes WHERE episode = ?", (episode,)).fetchone() is None:
                raise SessionError(f"session {session_id!r} has no episode {episode}")
            sql = f"SELECT {columns} FROM steps WHERE episode = ?{where} ORDER BY t"
            return conn.execute(sql, (episode,)).fetchall()

    def steps(self, session_id: str, episode: int | None = None, takeover_only: bool = False) -> dict[str, np.ndarray]:
        """An episode's (or the whole session's) steps as column arrays.

        Vectors (obs, next_obs, a_rl, a_expert, action) are float32 ``(T, dim)``; ``a_expert`` is NaN
        where the expert did not act. NaN fear/threshold/curiosity mean the gate computed none. ``conflict``: the
        simulator's near-miss flag (``info["conflict"]``), 0 where it reported none or the session predates it.
        ``takeover_only``: just the steps under expert control (the intervention samples fine-tuning uses).
        """
        return steps_to_arrays(self._step_rows(session_id, episode, takeover_only))

    def segments(self, session_id: str, episode: int | None = None) -> list[dict[str, Any]]:
        """The takeover segments (episode, segment number, first and last step, who acted how often)."""
        where = "WHERE segment IS NOT NULL" + ("" if episode is None else " AND episode = ?")
        params: tuple[Any, ...] = () if episode is None else (episode,)
        with self._read(session_id) as conn:
            rows = conn.execute(
                f"SELECT episode, segment, MIN(t), MAX(t), COUNT(*), GROUP_CONCAT(actor) FROM steps {where} "
                "GROUP BY episode, segment ORDER BY episode, segment",
                params,
            ).fetchall()
        out = []
        for ep, seg, t0, t1, n, actors in rows:
            counts: dict[str, int] = {}
            for actor in (actors or "").split(","):
                counts[actor] = counts.get(actor, 0) + 1
            out.append({"episode": ep, "segment": seg, "t_start": t0, "t_end": t1, "steps": n, "actors": counts})
        return out

    def horizons(self, session_id: str, episode: int) -> list[dict[str, Any] | None]:
        """Per step, the gate's imagined horizon as the live page saw it (None where there was none, and for
        sessions recorded before it was stored)."""
        with self._read(session_id) as conn:
            try:
                rows = conn.execute("SELECT horizon FROM steps WHERE episode = ? ORDER BY t", (episode,)).fetchall()
            except sqlite3.OperationalError:  # an older session: no horizon column
                count = conn.execute("SELECT COUNT(*) FROM steps WHERE episode = ?", (episode,)).fetchone()[0]
                return [None] * int(count)
        return [json.loads(r["horizon"]) if r["horizon"] else None for r in rows]

    def events(self, session_id: str, episode: int) -> list[dict[str, Any]]:
        """The episode's timeline: gate firings, takeover starts and ends (who acted), coaching starts and ends (the
        agent drove with a coach's label: ``coach_start`` / ``coach_end``), violations, a collision, and the end with
        its reason; each ``{"t", "kind", ...}`` in step order."""
        with self._read(session_id) as conn:
            head = conn.execute("SELECT * FROM episodes WHERE episode = ?", (episode,)).fetchone()
            if head is None:
                raise SessionError(f"session {session_id!r} has no episode {episode}")
            rows = conn.execute(
                "SELECT t, actor, takeover, gate_fired, violation, a_expert IS NOT NULL AS labelled FROM steps "
                "WHERE episode = ? ORDER BY t",
                (episode,),
            ).fetchall()
        events: list[dict[str, Any]] = []
        version = _policy_version(head["metrics"])
        if version is not None:  # fine-tuned versions change only between episodes: mark the episode's first step
            with self._read(session_id) as conn:
                before = conn.execute(
                    "SELECT metrics FROM episodes WHERE episode < ? ORDER BY episode DESC LIMIT 1", (episode,)
                ).fetchone()
            previous = _policy_version(before["metrics"]) if before is not None else None
            if previous != version:
                events.append({"t": 0, "kind": "version", "version": version})
        prev_gate = prev_violation = prev_coached = False
        prev_takeover: str | None = None
        for row in rows:
            t, actor = int(row["t"]), str(row["actor"])
            if row["gate_fired"] and not prev_gate:
                events.append({"t": t, "kind": "gate"})
            taking = actor if row["takeover"] else None
            if prev_takeover is not None and taking != prev_takeover:
                events.append({"t": t, "kind": "takeover_end", "actor": prev_takeover})
            if taking is not None and taking != prev_takeover:
                events.append({"t": t, "kind": "takeover_start", "actor": taking})
            coached = bool(row["labelled"]) and not row["takeover"]
            if coached != prev_coached:
                events.append({"t": t, "kind": "coach_start" if coached else "coach_end"})
            if row["violation"] and not prev_violation:
                events.append({"t": t, "kind": "violation"})
            prev_gate, prev_violation, prev_takeover = bool(row["gate_fired"]), bool(row["violation"]), taking
            prev_coached = coached
        if rows and head["ended"] is not None:
            last = int(rows[-1]["t"])
            metrics = json.loads(head["metrics"]) if head["metrics"] else {}
            if metrics.get("collision"):
                events.append({"t": last, "kind": "collision"})
            reason = head["end_reason"] if "end_reason" in head.keys() else None  # noqa: SIM118 (Row: values)
            events.append({"t": last, "kind": "end", "reason": reason or "ended"})
        return events

    def scenes(self, session_id: str, episode: int) -> tuple[dict[str, Any] | None, list[dict[str, Any] | None]]:
        """(static scene of the episode, per-step scene snapshot or None) for replay."""
        with self._read(session_id) as conn:
            row = conn.execute("SELECT static_scene FROM episodes WHERE episode = ?", (episode,)).fetchone()
            if row is None:
                raise SessionError(f"session {session_id!r} has no episode {episode}")
            static = json.loads(row["static_scene"]) if row["static_scene"] else None
            rows = conn.execute("SELECT scene FROM steps WHERE episode = ? ORDER BY t", (episode,)).fetchall()
        return static, [json.loads(zlib.decompress(r["scene"])) if r["scene"] else None for r in rows]

    def table(self, session_id: str, episode: int | None = None) -> Any:
        """A flat pyarrow table (vectors spread over ``obs_0 ...`` columns) for CSV/Parquet export."""
        import pyarrow as pa

        arrays = self.steps(session_id, episode)
        columns: dict[str, Any] = {}
        for name, values in arrays.items():
            if values.ndim == 2:
                for j in range(values.shape[1]):
                    columns[f"{name}_{j}"] = values[:, j]
            else:
                columns[name] = values
        return pa.table(columns)

    def export(self, session_id: str, fmt: str, episode: int | None = None) -> bytes:
        """The steps as CSV or Parquet bytes."""
        import pyarrow as pa
        import pyarrow.csv as pacsv
        import pyarrow.parquet as pq

        table = self.table(session_id, episode)
        sink = pa.BufferOutputStream()
        if fmt == "csv":
            pacsv.write_csv(table, sink)
        elif fmt == "parquet":
            pq.write_table(table, sink)
        else:
            raise ValueError(f"unknown export format {fmt!r}; use csv or parquet")
        return sink.getvalue().to_pybytes()


def _has_column(conn: sqlite3.Connection, table: str, column: str) -> bool:
    return any(row[1] == column for row in conn.execute(f"PRAGMA table_info({table})").fetchall())


def steps_to_arrays(rows: list[sqlite3.Row] | list[tuple[Any, ...]]) -> dict[str, np.ndarray]:
    """Column arrays of step rows: STEP_COLUMNS' values, then (optionally) the conflict flag."""
    names = [c.strip() for c in STEP_COLUMNS.split(",")]
    cols: dict[str, list[Any]] = {n: [] for n in [*names, "conflict"]}
    for row in rows:
        values = tuple(row)
        for n, v in zip(names, values[: len(names)], strict=True):
            cols[n].append(v)
        cols["conflict"].append(values[len(names)] if len(values) > len(names) else None)

    def vectors(name: str, like: str | None = None) -> np.ndarray:
        blobs = cols[name]
        dims = [len(b) // 4 for b in blobs if b is not None]
        width = max(dims) if dims else 0
        if like is not None and width == 0:
            width = vectors(like).shape[1]
        out = np.full((len(blobs), width), np.nan, dtype=np.float32)
        for i, b in enumerate(blobs):
            if b is not None:
                v = np.frombuffer(b, dtype=np.float32)
                out[i, : len(v)] = v
        return out

    def floats(name: str) -> np.ndarray:
        return np.array([np.nan if v is None else v for v in cols[name]], dtype=np.float64)

    return {
        "episode": np.array(cols["episode"], dtype=np.int64),
        "t": np.array(cols["t"], dtype=np.int64),
        "wall_time": floats("wall_time"),
        "actor": np.array(cols["actor"], dtype=str),
        "takeover": np.array(cols["takeover"], dtype=bool),
        "segment": np.array([-1 if v is None else v for v in cols["segment"]], dtype=np.int64),
        "gate_fired": np.array(cols["gate_fired"], dtype=bool),
        "fear": floats("fear"),
        "threshold": floats("threshold"),
        "curiosity": floats("curiosity"),
        "reward": floats("reward"),
        "cost": floats("cost"),
        "violation": np.array(cols["violation"], dtype=bool),
        "conflict": np.array([0.0 if v is None else float(v) for v in cols["conflict"]], dtype=np.float32),
        "terminated": np.array(cols["terminated"], dtype=bool),
        "truncated": np.array(cols["truncated"], dtype=bool),
        "a_rl": vectors("a_rl"),
        "a_expert": vectors("a_expert", like="action"),
        "action": vectors("action"),
        "obs": vectors("obs"),
        "next_obs": vectors("next_obs"),
    }


_STOP = object()


class SessionWriter:
    """Writes one session; use ``on_step`` / ``on_episode`` as Runner listeners, ``close()`` at the end.

    Rows are prepared in the caller's thread and committed by a writer thread every ``commit_interval``
    seconds. ``scene_source`` (optional) is called right after each step to snapshot what was drawn,
    so that a replay shows the scene together with the charts.
    """

    def __init__(
        self,
        path: Path,
        session_id: str,
        *,
        scene_source: Callable[[], Mapping[str, Any] | None] | None = None,
        commit_interval: float = 0.25,
    ) -> None:
        self.path = path
        self.session_id = session_id
        self.scene_source = scene_source
        self.commit_interval = commit_interval
        self.error: str | None = None
        """The last write failure (disk full, ...); the loop keeps running and the page shows it."""
        self.rows_written = 0
        self._queue: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self._segment: dict[int, int] = {}
        self._in_takeover: dict[int, bool] = {}
        self._static_key: dict[int, str] = {}
        self._closed = False
        self._thread = threading.Thread(target=self._run, name=f"session-writer-{session_id}", daemon=True)
        self._thread.start()

    # -- listeners (called in the loop's thread) -------------------------------------------------------
    def on_step(self, record: StepRecord) -> None:
        if self._closed:
            return
        ep = record.episode
        segment: int | None = None
        if record.takeover:
            if not self._in_takeover.get(ep, False):
                self._segment[ep] = self._segment.get(ep, -1) + 1
            segment = self._segment[ep]
        self._in_takeover[ep] = record.takeover
        scene_json: str | None = None
        static_json: str | None = None
        if self.scene_source is not None:
            try:
                scene = self.scene_source()
            except Exception as exc:  # a drawing problem must not lose the step
                scene, self.error = None, f"scene snapshot failed: {exc}"
            if scene is not None:
                dynamic = {k: v for k, v in scene.items() if k != "static"}
                scene_json = json.dumps(dynamic, separators=(",", ":"))
                key = str(scene.get("static_key", ""))
                if self._static_key.get(ep) != key:
                    self._static_key[ep] = key
                    static_json = json.dumps(
                        {"static_key": key, "static": scene.get("static", []), "bounds": scene.get("bounds")},
                        separators=(",", ":"),
                    )
        row = (
            ep,
            record.t,
            record.wall_time,
            record.actor,
            int(record.takeover),
            segment,
            int(record.gate_fired),
            _finite_or_none(record.fear),
            _finite_or_none(record.threshold),
            _finite_or_none(record.curiosity),
            float(record.reward),
            float(record.cost),
            int(record.violation),
            int(record.terminated),
            int(record.truncated),
            _blob(record.a_rl),
            _blob(record.a_expert),
            _blob(record.action),
            _blob(record.obs),
            _blob(record.next_obs),
            scene_json,
        )
        info = record.info if isinstance(record.info, dict) else {}
        horizon = info.get("horizon")
        horizon_json = json.dumps(horizon, separators=(",", ":")) if horizon is not None else None
        # the simulator's near-miss flag: a label the world model may learn when fine-tuning on this session
        conflict = int(bool(info["conflict"])) if "conflict" in info else None
        self._queue.put(("step", row, (static_json, horizon_json, conflict)))

    def on_episode(self, summary: EpisodeSummary) -> None:
        if self._closed:
            return
        self._queue.put(
            (
                "episode",
                (
                    time.time(),
                    summary.steps,
                    summary.ret,
                    summary.cost,
                    summary.takeovers,
                    summary.takeover_events,
                    _finite_or_none(summary.mean_fear),
                    _finite_or_none(summary.mean_curiosity),
                    json.dumps({k: _jsonable(v) for k, v in summary.metrics.items()}),
                    summary.error,
                    summary.reason,
                    summary.episode,
                ),
                summary.episode,
            )
        )

    def attach(self, runner: Any) -> SessionWriter:
        """Register as a step and episode listener of ``runner``."""
        runner.step_listeners.append(self.on_step)
        runner.episode_listeners.append(self.on_episode)
        return self

    def detach(self, runner: Any) -> None:
        if self.on_step in runner.step_listeners:
            runner.step_listeners.remove(self.on_step)
        if self.on_episode in runner.episode_listeners:
            runner.episode_listeners.remove(self.on_episode)

    def flush(self, timeout: float = 10.0) -> None:
        """Block until everything queued so far is committed."""
        done = threading.Event()
        self._queue.put(("flush", done, None))
        done.wait(timeout)

    def close(self, timeout: float = 10.0) -> None:
        if self._closed:
            return
        self._closed = True
        self._queue.put(_STOP)
        self._thread.join(timeout)

    # -- the writer thread -----------------------------------------------------------------------
    def _run(self) -> None:
        conn = _connect(self.path)
        known_episodes: set[int] = set()
        pending: list[Any] = []
        stop = False
        try:
            while not stop:
                deadline = time.monotonic() + self.commit_interval
                flushes: list[threading.Event] = []
                while True:
                    timeout = deadline - time.monotonic()
                    if timeout <= 0:
                        break
                    try:
                        item = self._queue.get(timeout=timeout)
                    except queue.Empty:
                        break
                    if item is _STOP:
                        stop = True
                        break
                    if item[0] == "flush":
                        flushes.append(item[1])
                        break
                    pending.append(item)
                if pending:
                    try:
                        self._commit(conn, pending, known_episodes)
                        self.error = None
                    except sqlite3.Error as exc:
                        self.error = f"session write failed: {exc}"
                    pending = []
                for event in flushes:
                    event.set()
        finally:
            conn.close()

    def _commit(self, conn: sqlite3.Connection, items: list[Any], known_episodes: set[int]) -> None:
        placeholders = ",".join("?" * len(STEP_COLUMNS.split(",")))
        insert = f"INSERT OR REPLACE INTO steps ({STEP_COLUMNS}, horizon, conflict) VALUES ({placeholders}, ?, ?)"
        with conn:
            for kind, payload, extra in items:
                if kind == "step":
                    ep = payload[0]
                    static_json, horizon_json, conflict = extra
                    if ep not in known_episodes:
                        conn.execute(
                            "INSERT OR IGNORE INTO episodes (episode, started) VALUES (?, ?)", (ep, payload[2])
                        )
                        known_episodes.add(ep)
                    if static_json is not None:
                        conn.execute("UPDATE episodes SET static_scene = ? WHERE episode = ?", (static_json, ep))
                    scene = payload[-1]
                    scene_blob = zlib.compress(scene.encode(), 3) if scene is not None else None
                    row = (*payload[:-1], scene_blob, horizon_json, conflict)
                    conn.execute(insert, row)
                    self.rows_written += 1
                else:
                    ep = extra
                    if ep not in known_episodes:
                        conn.execute(
                            "INSERT OR IGNORE INTO episodes (episode, started) VALUES (?, ?)", (ep, payload[0])
                        )
                        known_episodes.add(ep)
                    conn.execute(
                        "UPDATE episodes SET ended=?, steps=?, ret=?, cost=?, takeovers=?, takeover_events=?, "
                        "mean_fear=?, mean_curiosity=?, metrics=?, error=?, end_reason=? WHERE episode=?",
                        payload,
                    )


def _policy_version(metrics: str | None) -> int | None:
    """The fine-tuned version that drove an episode (recorded in its metrics by the live loop), if any."""
    value = json.loads(metrics).get("policy_version") if metrics else None
    return None if value is None else int(value)


def _jsonable(v: Any) -> Any:
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v
