"""The mover model's compiled velocities (:mod:`core.sage.compiled_movers`) are numpy's
(:func:`core.sage.movers.mover_velocities`) within float64 rounding: on the synthetic worlds of the mover model's tests
(crossing, receding, static, turning) and on real UGV scans recorded from the committed default on the movers field."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from core.sage.compiled_movers import compiled_mover_velocities
from core.sage.movers import mover_velocities
from tests.core.sage.test_mover_model import FORWARD, HISTORY, NOISE, SIZE, SPEED, STEP, STILL, World, drive

ROOT = Path(__file__).resolve().parents[3]
TOLERANCE = 1e-9
"""Float64 sums in the same order; libm's hypot and trigonometry may differ from numpy's in the last bits."""


def both(scans: np.ndarray, actions: np.ndarray, step: object = STEP, **limits: float) -> tuple[np.ndarray, np.ndarray]:
    args = (limits.get("max_speed", SPEED), limits.get("max_size", SIZE), limits.get("min_speed", NOISE))
    return mover_velocities(step, scans, actions, *args), compiled_mover_velocities(step, scans, actions, *args)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    "world",
    [
        World([(0.12, 0.08, 0.025, 0.0, -0.008)]),  # a walker crossing in front
        World([(0.1, 0.0, 0.03, 0.01, 0.0)]),  # receding
        World([(0.15, 0.03, 0.03, 0.0, 0.0)], [(0.05, 0.2, 0.4, 0.2)]),  # a post and a wall: static
        World([(0.12, 0.08, 0.025, 0.0, -0.008), (0.3, -0.1, 0.03, -0.006, 0.0)], [(0.05, 0.2, 0.4, 0.2)]),
    ],
)
def test_the_compiled_velocities_are_numpys_on_synthetic_worlds(world: World) -> None:
    actions = [FORWARD if t % 3 else np.array([0.5, 0.4]) for t in range(12)]
    actions[5] = STILL
    scans, _ = drive(world, actions)
    for end in range(HISTORY + 1, len(scans) + 1):
        window, acts = scans[end - HISTORY - 1 : end], np.array(actions[end - HISTORY - 1 : end - 1])
        reference, compiled = both(window, acts)
        np.testing.assert_allclose(compiled, reference, rtol=0, atol=TOLERANCE)


def test_the_compiled_velocities_are_numpys_on_recorded_ugv_scans() -> None:
    """Every step of real episodes with movers (the policy driving with its gate), at the default's settings and at
    looser ones that let more tracks through; some steps must show movers, or the comparison says little."""
    import sims
    from core.agents import load_agent
    from core.loop import Runner

    agent = load_agent(ROOT / "policies" / "ugv-default")
    gate, step = agent.make_gate(), agent.world_model.ego  # type: ignore[union-attr]
    assert step is not None
    env = sims.make("ugv", "sims/ugv/scenarios/movers.yaml")
    runner = Runner(env, agent.policy, gate, None, seed=3, deterministic=True)
    scans: list[np.ndarray] = []
    actions: list[np.ndarray] = []
    moving = 0
    for _ in range(160):
        record = runner.step()
        assert record is not None
        if record.t == 0:
            scans, actions = [record.obs], []
        scans.append(record.next_obs)
        actions.append(record.action)
        if len(actions) < gate.cfg.mover_history:
            continue
        window = np.array(scans[-gate.cfg.mover_history - 1 :], np.float64)
        acts = np.array(actions[-gate.cfg.mover_history :], np.float64)
        for limits in (
            {
                "max_speed": gate.cfg.mover_max_speed,
                "max_size": gate.cfg.mover_max_size,
                "min_speed": gate.cfg.mover_min_speed,
            },
            {"max_speed": 0.05, "max_size": 0.3, "min_speed": 0.001},
        ):
            reference, compiled = both(window, acts, step, **limits)
            np.testing.assert_allclose(compiled, reference, rtol=0, atol=TOLERANCE)
            moving += int(reference.any())
    env.close()
    assert moving > 5, moving


def test_the_compiled_velocities_refuse_a_short_track() -> None:
    scans, _ = drive(World([(0.12, 0.08, 0.025, 0.0, -0.008)]), [FORWARD])
    with pytest.raises(ValueError, match="L \\+ 1 >= 3"):
        compiled_mover_velocities(STEP, scans, np.array([FORWARD]), SPEED, SIZE, NOISE)


def test_the_compiled_movers_contact_is_torchs() -> None:
    """The compiled kernel's movers' contact test (:func:`core.sage.compiled_gate.movers_touching`, float32) gives the
    booleans of :func:`core.sage.movers.mover_contact` on the rollout's own actions, at every real UGV step with movers
    (some imagined in contact; at most one boolean in a thousand may round the other way), and the gate's fear is then
    the uncompiled gate's (torch kernel, numpy's movers)."""
    import torch

    import sims
    from core.agents import load_agent
    from core.loop import Runner
    from core.sage.movers import mover_contact

    agent = load_agent(ROOT / "policies" / "ugv-default")
    compiled, reference = agent.make_gate(), agent.make_gate()
    reference.compiled = False
    kernel = compiled.kernel()
    assert type(kernel).__name__ == "CompiledGateKernel"
    env = sims.make("ugv", "sims/ugv/scenarios/movers.yaml")
    runner = Runner(env, agent.policy, compiled, None, seed=5, deterministic=True)
    compared = touched = flipped = cells = 0
    for _ in range(200):
        obs = runner.obs if runner.obs is not None else runner.reset()
        velocity = compiled.mover_velocity()
        fear_reference = reference.decide(obs, agent.policy.act(obs, deterministic=True)).fear
        record = runner.step()
        assert record is not None
        reference.observe(record.obs, record.action, record.next_obs)
        if record.done:
            reference.reset()
        if velocity is None or not bool(velocity.any()):
            continue
        d, a, m = kernel.d, kernel.act_dim, kernel.m
        with torch.inference_mode():
            actions = torch.from_numpy(kernel._x[:m, :, d : d + a].copy()).unsqueeze(2)
            o = torch.from_numpy(record.obs).view(1, -1)
            expected = mover_contact(kernel.ego, o, velocity, actions, kernel.contact)[..., 0].numpy()
        # float32 in two code paths: a contact exactly at the reach may round either way on another processor
        differing = int((kernel._touching != expected).sum())
        flipped += differing
        cells += expected.size
        if differing == 0:
            assert record.fear == pytest.approx(fear_reference, abs=1e-5)
        compared += 1
        touched += int(expected.any())
    env.close()
    assert compared > 10, compared
    assert touched > 0, touched
    assert flipped <= max(1, cells // 1000), (flipped, cells)
