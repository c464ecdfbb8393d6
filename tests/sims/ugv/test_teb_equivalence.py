"""The TEB planner's speed-ups change no decision. References recorded by the planner before them (commit c00700f,
``data/teb_reference.npz``):

- the band's residuals and Jacobian on solver problems met while driving scenarios 1-4 (pure functions: equal up to
  rounding);
- the planner's state while the robot is driven along recorded episodes: its costmap, global path and tracked
  movers (deterministic: equal up to rounding), and its commands. MINPACK's Levenberg-Marquardt (scipy 1.17.1)
  does not return the same bits for the same problem from one call to the next (it depends on the process's heap;
  the residuals and Jacobian do not), so the reference's own commands, recomputed in a fresh process, agree with
  the recording on only 78-98% of steps per scenario (measured) and leave it by up to 1 on the others. On another
  processor of this machine kind (2026-11-29) the unchanged code at 682ce2c agreed on 39-76% of steps and the tracked
  movers' sums differed by up to 1e-4 relative (their regressions sum in an order the processor's SIMD width sets),
  so the commands are not compared: the solver's decisions are held by the residual and Jacobian test above.

Regenerate (only with the reference code checked out): ``python -m tests.sims.ugv.test_teb_equivalence``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

import sims
from sims.ugv.teb import Band, TebConfig, TebOptimizer, TebPlanner

SCENARIOS = ("1", "2", "3", "4")
STEPS = 150
"""Most steps recorded per scenario: whole episodes here."""
SEED = 1000
REFERENCE = Path(__file__).parent / "data" / "teb_reference.npz"
PROBLEMS_PER_SCENARIO = 8
STATE_COLUMNS = slice(7, 11)
"""Columns of a trace row that are the planner's deterministic state (costmap, path, the movers' count)."""
MOVER_COLUMNS = slice(11, None)
"""The tracked movers' point and velocity sums: equal up to the summation order of their regressions."""
MOVER_RTOL = 1e-3
"""Ten times the largest relative difference measured between two processors (1e-4); a changed tracker moves them
by the movers' own scale."""


def trace(
    scenario: str, driven: np.ndarray | None = None, steps: int = STEPS, solved: list[Any] | None = None
) -> np.ndarray:
    """Per step: the command (2), the band's first free pose (x, y, θ), its first interval and its pose count, then
    the occupied cells, the global path's points and their sum, the movers and the sums of their points and velocities.
    ``driven``: actions to step the robot with (a recorded trace's first two columns) instead of the planner's.
    ``solved``: collects each band solve's inputs."""
    env = sims.make("ugv", scenario=scenario)
    planner = TebPlanner(env)
    if solved is not None:
        solve = planner.optimizer.solve

        def recording(band: Band, v0: float, w0: float, obstacles: np.ndarray) -> tuple[Band, float]:
            solved.append((band.poses.copy(), band.dts.copy(), v0, w0, obstacles.copy()))
            return solve(band, v0, w0, obstacles)

        planner.optimizer.solve = recording  # type: ignore[method-assign]
    obs, _ = env.reset(seed=SEED)
    rows = []
    for t in range(steps if driven is None else len(driven)):
        action = planner.act(obs)
        assert planner.band is not None and planner.costmap is not None
        band, path, movers = planner.band, planner.path, planner.tracker.movers()
        rows.append(
            [
                *action, *band.poses[1], band.dts[0], len(band.poses),
                planner.costmap.occupied.sum(), 0 if path is None else len(path), 0.0 if path is None else path.sum(),
                len(movers), sum(float(p.sum()) for p, _ in movers), sum(float(v.sum()) for _, v in movers),
            ]
        )  # fmt: skip
        obs, _, terminated, truncated, _ = env.step(action if driven is None else driven[t].astype(np.float32))
        if terminated or truncated:
            break
    return np.asarray(rows, dtype=np.float64)


def problem_outputs(optimizer: TebOptimizer, problem: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Residuals and Jacobian (as J v and uᵀ J for fixed u, v) at the problem's band and at a perturbed band that
    breaks more limits."""
    poses, dts, vw, obstacles = problem["poses"], problem["dts"], problem["vw"], problem["obstacles"]
    n = len(poses)
    z = optimizer.pack(Band(poses, dts))
    args = (poses[0], poses[-1, :2], n, float(vw[0]), float(vw[1]), obstacles)
    out = {}
    for name, at in (("at", z), ("moved", z + problem["shift"])):
        jacobian = optimizer.jacobian(at, *args)
        u = np.cos(np.arange(jacobian.shape[0]))
        v = np.sin(np.arange(jacobian.shape[1]) + 1.0)
        out[f"{name}_residuals"] = optimizer.residuals(at, *args)
        out[f"{name}_jv"], out[f"{name}_uj"] = jacobian @ v, u @ jacobian
        out[f"{name}_shape"] = np.array(jacobian.shape)
    return out


def record() -> None:
    data: dict[str, np.ndarray] = {}
    optimizer = TebOptimizer(TebConfig(), 0.6, 1.0)
    rng = np.random.default_rng(0)
    for scenario in SCENARIOS:
        solved: list[Any] = []
        data[f"trace_{scenario}"] = trace(scenario, solved=solved)
        picks = np.linspace(0, len(solved) - 1, PROBLEMS_PER_SCENARIO).round().astype(int)
        for k, pick in enumerate(picks):
            poses, dts, v0, w0, obstacles = solved[pick]
            n = len(poses)
            problem = {
                "poses": poses, "dts": dts, "vw": np.array([v0, w0]), "obstacles": obstacles,
                "shift": rng.normal(0.0, 0.3, 2 * (n - 2) + 2 * (n - 1)),
            }  # fmt: skip
            key = f"problem_{scenario}_{k}"
            data.update({f"{key}/{name}": value for name, value in problem.items()})
            data.update({f"{key}/{name}": value for name, value in problem_outputs(optimizer, problem).items()})
    np.savez_compressed(REFERENCE, **data)


@pytest.fixture(scope="module")
def reference() -> dict[str, np.ndarray]:
    with np.load(REFERENCE) as data:
        return dict(data)


@pytest.mark.parametrize("scenario", SCENARIOS)
def test_the_bands_residuals_and_jacobian_are_the_references(reference: dict[str, np.ndarray], scenario: str) -> None:
    optimizer = TebOptimizer(TebConfig(), 0.6, 1.0)
    for k in range(PROBLEMS_PER_SCENARIO):
        key = f"problem_{scenario}_{k}"
        problem = {name: reference[f"{key}/{name}"] for name in ("poses", "dts", "vw", "obstacles", "shift")}
        for name, value in problem_outputs(optimizer, problem).items():
            expected = reference[f"{key}/{name}"]
            assert value.shape == expected.shape, (key, name)
            assert np.allclose(value, expected, rtol=1e-12, atol=1e-12), (key, name)


@pytest.mark.parametrize("scenario", SCENARIOS)
def test_the_planners_state_is_the_references_along_its_recorded_episode(
    reference: dict[str, np.ndarray], scenario: str
) -> None:
    recorded = reference[f"trace_{scenario}"]
    now = trace(scenario, driven=recorded[:, :2])
    assert now.shape == recorded.shape
    assert np.allclose(now[:, STATE_COLUMNS], recorded[:, STATE_COLUMNS], rtol=1e-12, atol=1e-9)
    assert np.allclose(now[:, MOVER_COLUMNS], recorded[:, MOVER_COLUMNS], rtol=MOVER_RTOL, atol=1e-6)


if __name__ == "__main__":
    record()


def test_a_blocked_path_is_what_the_dilated_costmap_says() -> None:
    """The local look-up around the path's cells answers as the whole costmap dilated by the inflation did."""
    from scipy import ndimage

    env = sims.make("ugv", scenario="1")
    planner = TebPlanner(env)
    obs, _ = env.reset(seed=SEED)
    planner.act(obs)
    costmap = planner.costmap
    assert costmap is not None
    ny, nx = costmap.occupied.shape
    rng = np.random.default_rng(4)
    answers = []
    for _ in range(300):
        costmap.occupied = rng.random((ny, nx)) < rng.uniform(0.0005, 0.02)
        # a wandering path, from anywhere on the grid (or just off it) in any direction
        start = np.array(
            [costmap.x0 + rng.uniform(-0.5, nx * costmap.res + 0.5), costmap.y0 + rng.uniform(0, ny * 0.1)]
        )
        heading = rng.uniform(-np.pi, np.pi) + np.cumsum(rng.normal(0.0, 0.3, 40))
        planner.path = start + np.cumsum(0.1 * np.column_stack([np.cos(heading), np.sin(heading)]), axis=0)
        x, y = planner.path[rng.integers(0, 10)] + rng.normal(0.0, 0.05, 2)
        ahead = planner._path_ahead(x, y, 3.0)
        iy, ix, inside = costmap.cells(ahead)
        reach = max(1, int(planner.cfg.planner_inflation / costmap.res))
        near = ndimage.binary_dilation(costmap.occupied, iterations=reach)
        expected = bool(inside.any()) and bool(near[iy[inside], ix[inside]][3:].any())
        assert planner._path_blocked(x, y) == expected
        answers.append(expected)
    assert 0.2 < np.mean(answers) < 0.8  # both answers are exercised


def test_the_compiled_kernels_refuse_arrays_that_do_not_fit_the_band() -> None:
    """Their writes are unchecked (numba): a layout or obstacle array of the wrong size is an error, not a write past
    an array's end."""
    from sims.ugv import _teb_kernel

    optimizer = TebOptimizer(TebConfig(), 0.6, 1.0)
    n, m = 4, 2
    z = np.zeros(2 * (n - 2) + 2 * (n - 1))
    args = (np.zeros(3), np.ones(2), n, 0.0, 0.0, np.ones((n - 1, m, 2)))
    terms = optimizer._terms(z, *args)
    with pytest.raises(ValueError, match="layout"):
        _teb_kernel.band_jacobian(*terms, optimizer._weights, np.zeros(3, dtype=np.int64), (10, 10))
    with pytest.raises(ValueError, match="obstacles"):
        optimizer._terms(z, *args[:-1], np.ones((n - 2, m, 2)))
