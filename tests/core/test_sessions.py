"""The session store: what the loop ran comes back intact, per episode and takeover segment, and exports."""

from __future__ import annotations

import io
import math
import sqlite3
from typing import Any

import gymnasium as gym
import numpy as np
import pyarrow.csv as pacsv
import pyarrow.parquet as pq
import pytest

from core.experts import ScriptedExpert
from core.loop import GateDecision, Runner, StepRecord
from core.sessions import SessionError, SessionStore


class PlaneEnv(gym.Env[np.ndarray, np.ndarray]):
    """A point in the plane moved by a 2-d action; cost beyond x > 2; 3-d observation (x, y, t)."""

    observation_space = gym.spaces.Box(-np.inf, np.inf, (3,), np.float32)
    action_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)

    def __init__(self, horizon: int = 8) -> None:
        self.horizon = horizon
        self.pos = np.zeros(2)
        self.t = 0

    def _obs(self) -> np.ndarray:
        return np.array([*self.pos, self.t], np.float32)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        self.pos, self.t = np.zeros(2), 0
        return self._obs(), {}

    def step(self, action: np.ndarray):
        self.t += 1
        self.pos = self.pos + np.asarray(action, dtype=float).reshape(2)
        cost = float(self.pos[0] > 2)
        return self._obs(), 1.0, False, self.t >= self.horizon, {"cost": cost, "violation": cost > 0}

    def expert_action(self) -> np.ndarray:
        return np.array([1.0, 0.0], np.float32)

    def scene(self) -> dict[str, Any]:
        return {
            "sim": "plane",
            "bounds": [-5, -5, 5, 5],
            "static_key": "walls",
            "static": [{"kind": "box", "x": 0, "y": 0, "yaw": 0, "length": 10, "width": 0.1, "color": "#888888"}],
            "movers": [],
            "ego": {
                "kind": "box",
                "x": float(self.pos[0]),
                "y": float(self.pos[1]),
                "yaw": 0.0,
                "length": 0.5,
                "width": 0.3,
                "color": "#00ff00",
            },
        }

    def metrics(self) -> dict[str, float]:
        return {"final_x": float(self.pos[0]), "nan_metric": math.nan}


class Still:
    def act(self, obs: np.ndarray, deterministic: bool = False) -> np.ndarray:
        return np.array([0.0, 0.5], np.float32)


class FiresAt:
    def __init__(self, steps: set[int]) -> None:
        self.steps, self.t = steps, 0

    def reset(self) -> None:
        self.t = 0

    def decide(self, obs: np.ndarray, a_rl: np.ndarray) -> GateDecision:
        fired = self.t in self.steps
        self.t += 1
        return GateDecision(fear=0.1 * self.t, threshold=0.5, fired=fired)

    def observe(self, obs: np.ndarray, action: np.ndarray, next_obs: np.ndarray) -> float:
        return 0.2


def run_session(store: SessionStore, episodes: int = 2, fires: set[int] | None = None) -> tuple[str, list[StepRecord]]:
    env = PlaneEnv()
    runner = Runner(env, Still(), FiresAt(fires if fires is not None else {1, 2, 5}), ScriptedExpert())
    writer = store.create(
        "plane",
        scenario=1,
        policy="still",
        expert_mode="scripted",
        scene_source=lambda: env.scene(),
        commit_interval=0.05,
    )
    writer.attach(runner)
    records: list[StepRecord] = []
    runner.step_listeners.append(records.append)
    for _ in range(episodes):
        runner.run_episode()
    writer.close()
    assert writer.error is None
    return writer.session_id, records


def test_steps_come_back_as_arrays_with_both_actions_and_observations(tmp_path) -> None:
    store = SessionStore(tmp_path)
    sid, records = run_session(store)
    arrays = store.steps(sid, 1)
    ep1 = [r for r in records if r.episode == 1]
    assert arrays["obs"].shape == (8, 3) and arrays["obs"].dtype == np.float32
    np.testing.assert_array_equal(arrays["obs"], np.stack([r.obs for r in ep1]))
    np.testing.assert_array_equal(arrays["next_obs"], np.stack([r.next_obs for r in ep1]))
    np.testing.assert_array_equal(arrays["a_rl"][0], [0.0, 0.5])
    # the expert acted at steps 1, 2 and 5 only: a_expert is NaN elsewhere, the executed action follows it
    assert np.isnan(arrays["a_expert"][0]).all() and not np.isnan(arrays["a_expert"][1]).any()
    np.testing.assert_array_equal(arrays["action"][1], [1.0, 0.0])
    assert list(arrays["actor"][:3]) == ["agent", "expert", "expert"]
    assert list(arrays["segment"]) == [-1, 0, 0, -1, -1, 1, -1, -1]
    assert arrays["threshold"][0] == pytest.approx(0.5) and arrays["curiosity"][3] == pytest.approx(0.2)
    assert arrays["truncated"][-1] and not arrays["truncated"][0]
    assert arrays["violation"].sum() == sum(r.violation for r in ep1)


def test_listing_and_episode_summaries(tmp_path) -> None:
    store = SessionStore(tmp_path)
    sid, _ = run_session(store, episodes=3)
    [info] = store.list_sessions()
    assert info.id == sid and info.sim == "plane" and info.scenario == "1" and info.episodes == 3
    assert info.steps == 24 and info.takeover_steps == 9
    episodes = store.episodes(sid)
    assert [e["episode"] for e in episodes] == [0, 1, 2]
    assert all(e["finished"] and e["steps"] == 8 and e["takeover_events"] == 2 for e in episodes)
    assert episodes[0]["metrics"]["final_x"] == pytest.approx(3.0) and episodes[0]["metrics"]["nan_metric"] is None
    assert episodes[0]["takeover_rate"] == pytest.approx(3 / 8)


def test_scenes_are_stored_for_replay(tmp_path) -> None:
    store = SessionStore(tmp_path)
    sid, records = run_session(store, episodes=1)
    static, scenes = store.scenes(sid, 0)
    assert static is not None and static["static_key"] == "walls" and len(static["static"]) == 1
    assert len(scenes) == 8 and all(s is not None and "static" not in s for s in scenes)
    assert [s["ego"]["x"] for s in scenes if s] == [float(r.next_obs[0]) for r in records]


def test_csv_and_parquet_exports_hold_every_step(tmp_path) -> None:
    store = SessionStore(tmp_path)
    sid, _ = run_session(store, episodes=2)
    table = pq.read_table(io.BytesIO(store.export(sid, "parquet")))
    assert table.num_rows == 16 and {"obs_0", "obs_2", "a_expert_1", "fear", "actor"} <= set(table.column_names)
    csv = pacsv.read_csv(io.BytesIO(store.export(sid, "csv", episode=1)))
    assert csv.num_rows == 8 and csv.column("episode").to_pylist() == [1] * 8
    with pytest.raises(ValueError, match="xlsx"):
        store.export(sid, "xlsx")


def test_unknown_or_malformed_ids_raise_clear_errors(tmp_path) -> None:
    store = SessionStore(tmp_path)
    sid, _ = run_session(store, episodes=1)
    with pytest.raises(SessionError, match="no session"):
        store.steps("20990101-000000-x-0000")
    with pytest.raises(SessionError, match="malformed"):
        store.steps("../etc/passwd")
    with pytest.raises(SessionError, match="no episode 7"):
        store.steps(sid, 7)


def test_readers_see_committed_rows_while_the_writer_is_open_and_wal_is_on(tmp_path) -> None:
    store = SessionStore(tmp_path)
    env = PlaneEnv(horizon=50)
    runner = Runner(env, Still())
    writer = store.create("plane", commit_interval=0.02).attach(runner)
    runner.reset()
    for _ in range(5):
        runner.step()
    writer.flush()
    assert store.info(writer.session_id).steps == 5  # readable mid-episode, before any summary
    assert store.episodes(writer.session_id)[0]["finished"] is False
    with sqlite3.connect(store.path(writer.session_id)) as conn:
        assert conn.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    writer.close()


def test_a_damaged_file_is_skipped_when_listing(tmp_path) -> None:
    store = SessionStore(tmp_path)
    run_session(store, episodes=1)
    (tmp_path / "zzz-broken.sqlite").write_bytes(b"not a database at all" * 10)
    assert len(store.list_sessions()) == 1


def test_takeover_segments_and_takeover_only_steps_for_fine_tuning(tmp_path) -> None:
    store = SessionStore(tmp_path)
    sid, _ = run_session(store, episodes=2)
    segments = store.segments(sid)
    assert [(s["episode"], s["segment"], s["t_start"], s["t_end"]) for s in segments] == [
        (0, 0, 1, 2),
        (0, 1, 5, 5),
        (1, 0, 1, 2),
        (1, 1, 5, 5),
    ]
    assert segments[0]["actors"] == {"expert": 2} and store.segments(sid, episode=1)[0]["episode"] == 1
    only = store.steps(sid, takeover_only=True)
    assert len(only["t"]) == 6 and only["takeover"].all() and not np.isnan(only["a_expert"]).any()


def test_the_timeline_matches_the_takeovers_and_violations_in_the_store(tmp_path) -> None:
    store = SessionStore(tmp_path)
    sid, records = run_session(store, episodes=1)
    events = store.events(sid, 0)
    kinds = [(e["t"], e["kind"]) for e in events]
    # the gate fired at steps 1, 2 and 5: two takeover segments (1-2 and 5), each opened by a gate firing
    assert [(t, k) for t, k in kinds if k in ("gate", "takeover_start", "takeover_end")] == [
        (1, "gate"), (1, "takeover_start"), (3, "takeover_end"), (5, "gate"), (5, "takeover_start"),
        (6, "takeover_end"),
    ]  # fmt: skip
    segments = store.segments(sid, 0)
    starts = [e for e in events if e["kind"] == "takeover_start"]
    assert [e["t"] for e in starts] == [s["t_start"] for s in segments]
    assert all(e["actor"] == "expert" for e in starts)
    onsets = [r.t for i, r in enumerate(records) if r.violation and (i == 0 or not records[i - 1].violation)]
    assert [e["t"] for e in events if e["kind"] == "violation"] == onsets and onsets
    assert events[-1] == {"t": 7, "kind": "end", "reason": "truncated"}
    with pytest.raises(SessionError, match="no episode 3"):
        store.events(sid, 3)


def test_the_timeline_marks_where_a_coach_labelled_the_agents_steps(tmp_path) -> None:
    from core.experts import CoachingExpert

    class CoachesFrom:
        """Coaches every agent step from its third (t 2) on with the expert's label; the expert drives where the gate
        fires."""

        def __init__(self) -> None:
            self.inner, self.t = ScriptedExpert(), 0

        def reset(self) -> None:
            self.t = 0

        def wants_control(self) -> bool:
            return False

        def act(self, env: Any, obs: np.ndarray) -> Any:
            return self.inner.act(env, obs)

        def coach(self, env: Any, obs: np.ndarray) -> np.ndarray | None:
            self.t += 1
            return CoachingExpert(self.inner, 1.0).coach(env, obs) if self.t > 2 else None

    store = SessionStore(tmp_path)
    env = PlaneEnv()
    runner = Runner(env, Still(), FiresAt({5}), CoachesFrom())
    writer = store.create("plane", scenario=1, policy="still", expert_mode="person", commit_interval=0.05)
    writer.attach(runner)
    records: list[StepRecord] = []
    runner.step_listeners.append(records.append)
    runner.run_episode()
    writer.close()
    coached = [r.t for r in records if r.coached]
    assert coached and not records[5].coached and records[5].takeover
    kinds = [(e["t"], e["kind"]) for e in store.events(writer.session_id, 0)]
    # coached from t 2, paused by the takeover at t 5, coached again after it
    assert [(t, k) for t, k in kinds if k.startswith("coach")] == [
        (2, "coach_start"), (5, "coach_end"), (6, "coach_start"),
    ]  # fmt: skip
    arrays = store.steps(writer.session_id, 0)
    assert np.isfinite(arrays["a_expert"][2]).all() and not arrays["takeover"][2]  # the label, stored, not taken over


def test_the_timeline_marks_a_new_policy_version_at_the_episode_it_took_over(tmp_path) -> None:
    store = SessionStore(tmp_path)
    env = PlaneEnv()
    runner = Runner(env, Still(), FiresAt(set()), ScriptedExpert())
    versions = iter([0, 0, 1])
    runner.episode_listeners.append(lambda s: s.metrics.update(policy_version=float(next(versions))))
    writer = store.create("plane", scenario=1, scene_source=lambda: env.scene(), commit_interval=0.05)
    writer.attach(runner)
    for _ in range(3):
        runner.run_episode()
    writer.close()
    marks = [[e for e in store.events(writer.session_id, ep) if e["kind"] == "version"] for ep in range(3)]
    assert marks == [[{"t": 0, "kind": "version", "version": 0}], [], [{"t": 0, "kind": "version", "version": 1}]]


def test_a_session_recorded_before_the_conflict_column_reads_back_with_no_conflicts(tmp_path) -> None:
    """Sessions written before the simulator's conflict flag was stored stay readable (fine-tuning, export,
    replay): the flag reads 0 there."""
    store = SessionStore(tmp_path)
    sid, records = run_session(store, episodes=1)
    with sqlite3.connect(store.path(sid)) as conn:
        conn.execute("ALTER TABLE steps DROP COLUMN conflict")
    arrays = store.steps(sid)
    assert len(arrays["t"]) == len(records) and arrays["conflict"].tolist() == [0.0] * len(records)
    assert store.table(sid).num_rows == len(records)
