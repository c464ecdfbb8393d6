"""A recorded session exported as a Minari dataset loads back with the same contents."""

from __future__ import annotations

from pathlib import Path

import minari
import numpy as np
import pytest
from typer.testing import CliRunner

from app.cli import app as cli
from core.experts import ScriptedExpert
from core.export import dataset_id_for, export_minari
from core.loop import GateDecision, Runner
from core.sessions import SessionStore
from tests.core.line_env import LineEnv


class Wobble:
    def __init__(self) -> None:
        self.k = 0

    def act(self, obs: np.ndarray, deterministic: bool = False) -> np.ndarray:
        self.k += 1
        return np.array([0.1 * (self.k % 3) - 0.1], np.float32)


class EveryThird:
    def reset(self) -> None:
        self.t = 0

    def decide(self, obs: np.ndarray, a_rl: np.ndarray) -> GateDecision:
        self.t = getattr(self, "t", 0) + 1
        return GateDecision(fear=0.1 * self.t, threshold=0.5, fired=self.t % 3 == 0)

    def observe(self, obs: np.ndarray, action: np.ndarray, next_obs: np.ndarray) -> float:
        return float(abs(next_obs[0] - obs[0]))


@pytest.fixture
def recorded(tmp_path: Path) -> tuple[SessionStore, str]:
    store = SessionStore(tmp_path / "sessions")
    writer = store.create("line", scenario=1, policy="wobble", expert_mode="scripted")
    runner = Runner(LineEnv(horizon=7), Wobble(), EveryThird(), ScriptedExpert(), seed=3)
    writer.attach(runner)
    for _ in range(2):
        runner.run_episode()
    runner.reset()
    runner.step()  # a third episode left open, as when a server stops mid-episode
    runner.step()
    writer.close()
    return store, writer.session_id


def test_minari_round_trip_matches_the_session(recorded: tuple[SessionStore, str], tmp_path: Path) -> None:
    store, session_id = recorded
    root = tmp_path / "minari"
    export_minari(store, session_id, "sage/line/demo", datasets_root=root)
    import os

    os.environ["MINARI_DATASETS_PATH"] = str(root)
    try:
        dataset = minari.load_dataset("sage/line/demo-v0")
        episodes = list(dataset.iterate_episodes())
    finally:
        os.environ.pop("MINARI_DATASETS_PATH")
    steps = store.steps(session_id)
    assert len(episodes) == 3 and dataset.total_steps == len(steps["t"]) == 16
    for ep in episodes:
        mask = steps["episode"] == ep.id
        np.testing.assert_allclose(ep.observations[:-1], steps["obs"][mask])
        np.testing.assert_allclose(ep.observations[-1], steps["next_obs"][mask][-1])
        np.testing.assert_allclose(ep.actions, steps["action"][mask])
        np.testing.assert_allclose(ep.rewards, steps["reward"][mask])
        np.testing.assert_array_equal(ep.infos["takeover"][1:, 0], steps["takeover"][mask])
        np.testing.assert_allclose(ep.infos["fear"][1:, 0], steps["fear"][mask])
        np.testing.assert_allclose(ep.infos["a_rl"][1:], steps["a_rl"][mask])
        expert_rows = steps["takeover"][mask]
        np.testing.assert_allclose(ep.infos["a_expert"][1:][expert_rows], steps["a_expert"][mask][expert_rows])
        assert np.isnan(ep.infos["a_expert"][1:][~expert_rows]).all()
    full, open_ep = episodes[0], episodes[2]
    assert full.truncations[-1] and len(full.actions) == 7 and full.infos["takeover"][1:, 0].sum() == 2
    assert len(open_ep.actions) == 2 and open_ep.truncations[-1], "the open episode is kept, marked truncated"


def test_bad_names_and_unknown_sessions_get_clear_errors(recorded: tuple[SessionStore, str]) -> None:
    store, _ = recorded
    with pytest.raises(ValueError, match="invalid Minari dataset name"):
        dataset_id_for("a b/c")
    assert dataset_id_for("sage/ugv/x") == "sage/ugv/x-v0" and dataset_id_for("x-v3") == "x-v3"
    result = CliRunner().invoke(
        cli, ["export", "20990101-000000-nope-abcd", "--minari", "x", "--sessions", str(store.root)]
    )
    assert result.exit_code == 2 and "no session" in result.output


def test_export_command_writes_the_dataset(recorded: tuple[SessionStore, str], tmp_path: Path) -> None:
    store, session_id = recorded
    root = tmp_path / "minari"
    result = CliRunner().invoke(
        cli, ["export", session_id, "--minari", "sage/line/cli", "--sessions", str(store.root), "--root", str(root)]
    )
    assert result.exit_code == 0, result.output
    assert "3 episodes, 16 steps" in result.output
    assert (root / "sage" / "line" / "cli-v0").is_dir()
