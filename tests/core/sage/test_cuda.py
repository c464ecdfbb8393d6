"""On a machine with CUDA (skipped elsewhere, CI included): the SAGE-SAC and D3QN updates replayed from their CUDA
graphs compute what the eager updates compute on the same card, across a world-model refit; a run trained with
``--device cuda`` and ``learner.cuda_graph`` writes a device-free checkpoint that acts on the CPU.

These are the checks ``bench/gpu_check.py`` times; run them there with
``python -m pytest -q -o addopts= tests/core/sage/test_cuda.py``."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import torch

from core.agents import load_agent, resolve_checkpoint
from core.sage.captured import WARMUP_UPDATES
from core.sage.learner import BaseLearner
from core.train import RunConfig, train
from tests.core.sage.test_captured import EGO_LAYOUT, OBS, d3qn_learner, sage_learner
from tests.core.test_train import point_env, small

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")


def refill(learner: BaseLearner, seed: int) -> None:
    """More drives and a refit: the graph must read the new world model's weights (copied into its buffers)."""
    rng = np.random.default_rng(seed)
    s = rng.normal(size=(101, OBS)).astype(np.float32)
    for i in range(100):
        a = learner.encode_action(np.array([i % 3], np.float32)) if learner.cfg.method == "sage-d3qn" else None
        a = rng.uniform(-1, 1, learner.act_dim).astype(np.float32) if a is None else a
        learner.buffer.add(s[i], a, 0.0, s[i + 1], False, cost=float(i % 11 == 0), violation=i % 11 == 0)
    learner.fit_world_model()


def assert_graph_replays_eager(build: Callable[..., BaseLearner], updates: int = WARMUP_UPDATES + 4) -> None:
    eager, graphed = build(device="cuda"), build(device="cuda", cuda_graph=True)
    assert graphed.captures and not eager.captures and eager.fear_active()
    for phase in range(2):
        if phase:  # the refit measures F_0 on sampled actions: both from the same torch seed
            for learner in (eager, graphed):
                torch.manual_seed(3)
                refill(learner, 1)
        for _ in range(updates):
            torch.manual_seed(7)
            expected = eager.update()
            torch.manual_seed(7)
            got = graphed.update()
            assert set(got) == set(expected)
            for key, value in expected.items():  # float32 on one card: the replay runs the same kernels
                assert got[key] == pytest.approx(value, rel=1e-3, abs=1e-4), (phase, key)
    assert graphed._captured is not None and graphed._captured.graphs  # it did record and replay a graph
    for name in eager.declared_state().modules:
        for key, value in getattr(eager, name).state_dict().items():
            torch.testing.assert_close(getattr(graphed, name).state_dict()[key], value, rtol=1e-3, atol=1e-4)


@pytest.mark.parametrize("virtual_ratio", [0.25, 0.0])
def test_the_sage_sac_graph_replays_the_eager_update(virtual_ratio: float) -> None:
    assert_graph_replays_eager(lambda **kw: sage_learner(virtual_ratio=virtual_ratio, **kw))


def test_the_sage_sac_graph_over_the_ego_step_replays_the_eager_update() -> None:
    pytest.importorskip("numba")
    ego = {f"world_model_config.{k}": v for k, v in EGO_LAYOUT.items()}
    assert_graph_replays_eager(lambda **kw: sage_learner(**ego, **kw))


def test_the_d3qn_graph_replays_the_eager_update() -> None:
    assert_graph_replays_eager(d3qn_learner)


def test_a_run_on_cuda_with_a_graph_writes_a_checkpoint_that_acts_on_the_cpu(tmp_path: Path) -> None:
    run = RunConfig(sim="point", scenarios=["static"], episodes=2, seed=1, demo_episodes=2, device="cuda")
    train(run, small("sage", cuda_graph=True), point_env, tmp_path / "cuda", progress=False)
    assert json.loads((tmp_path / "cuda" / "config.json").read_text())["run"]["device"] == "cuda"
    payload = torch.load(resolve_checkpoint(tmp_path / "cuda"), map_location="cpu", weights_only=True)
    assert all(t.device.type == "cpu" for t in payload["state"]["actor"].values())
    agent = load_agent(tmp_path / "cuda")
    assert np.isfinite(agent.policy.act(np.zeros(agent.meta.obs_dim, np.float32), deterministic=True)).all()
