"""The process-backed SUMO env: same episodes as in-process, SUMO errors and dead workers reported clearly."""

from __future__ import annotations

import os
import signal
from collections.abc import Callable
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import sims.sumo  # noqa: F401  # registers sage/Sumo-v0
from sims.sumo import SumoEnv, SumoError
from sims.sumo.process import SumoProcessEnv


def test_process_env_runs_the_same_episode_and_survives_a_dead_worker(make_env: Callable[..., SumoEnv]) -> None:
    local = make_env(route=2, special_vehicles=True)
    remote = gym.make("sage/Sumo-v0", process=True, route=2, special_vehicles=True).unwrapped
    assert isinstance(remote, SumoProcessEnv)
    try:
        obs_local, _ = local.reset(seed=7)
        obs_remote, info = remote.reset(seed=7)
        assert info["phase"] == "C2"
        np.testing.assert_array_equal(obs_local, obs_remote)  # SUMO is deterministic given the seed
        for _ in range(30):
            a_remote, a_local = remote.expert_action(), local.expert_action()
            np.testing.assert_array_equal(a_remote, a_local)
            step_remote = remote.step(a_remote)
            step_local = local.step(a_local)
            np.testing.assert_array_equal(step_remote[0], step_local[0])
            assert step_remote[1:4] == step_local[1:4] and step_remote[4]["expert_drove"]
        assert remote.metrics() == local.metrics()
        first, second = remote.scene(), remote.scene()  # the second one reuses the cached static part
        assert second["static"] == first["static"] and len(first["static"]) > 50
        assert len(first["movers"]) > 0 and first["labels"]["phase"] == "C2"

        pid = remote.worker_pid
        assert pid is not None
        os.kill(pid, signal.SIGKILL)
        remote._process.join(5.0)  # the kill lands before the next call (a CI run met this order by chance)
        with pytest.raises(SumoError, match=rf"\(pid {pid}\) died before 'step' \(exit code -9\)"):
            remote.step(np.zeros(1, np.float32))
        obs, _ = remote.reset(seed=8)
        assert remote.worker_pid not in (None, pid) and obs.shape == (29,)
        remote.set_scenario(route=1, special_vehicles=False)
        _, info = remote.reset(seed=8)
        assert (info["route"], info["phase"]) == (1, "C1")
    finally:
        remote.close()
    assert remote.worker_pid is None


def test_process_env_reports_sumo_errors_from_the_worker(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="missing"):
        SumoProcessEnv(net_file=str(tmp_path / "missing.net.xml"))  # in the caller, before any worker starts
    empty = tmp_path / "empty.net.xml"
    empty.write_text('<?xml version="1.0"?>\n<net version="1.20"></net>\n')
    env = SumoProcessEnv(net_file=str(empty))
    try:
        with pytest.raises(SumoError, match="SUMO could not start"):
            env.reset(seed=0)
        with pytest.raises(ValueError, match="unknown reset option"):
            env.reset(seed=0, options={"colour": "red"})
    finally:
        env.close()
