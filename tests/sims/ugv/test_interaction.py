"""The UGV's privileged interaction statistics: the true time to contact with a mover and the gap to it."""

from __future__ import annotations

import math

import numpy as np
import pytest

import sims
from sims.ugv.config import RobotConfig
from sims.ugv.expert import footprint_radius
from sims.ugv.interaction import interaction_stats
from sims.ugv.scenario import MoverPlan

DT = 0.1
ROBOT = RobotConfig()


def disc_on_x(x0: float, speed: float, steps: int) -> tuple[list[MoverPlan], np.ndarray]:
    """A disc of radius 0.3 on the x axis at ``x0``, moving along x at ``speed`` (m/s): its plan and its poses now
    and after each of ``steps`` steps."""
    disc = MoverPlan(
        "circle",
        length=0.0,
        width=0.0,
        radius=0.3,
        path=np.zeros((1, 2)),
        speed=1.0,
        start_time=0.0,
        dwell=0.0,
        loop="once",
    )
    t = np.arange(steps + 1) * DT
    poses = np.stack([x0 + speed * t, np.zeros_like(t), np.zeros_like(t)], axis=1)[None]  # (1, 1 + T, 3)
    return [disc], poses


def test_head_on_contact_comes_when_the_gap_closes() -> None:
    """Robot at the origin driving +x at 0.5 m/s, a disc 3 m ahead coming at 0.5 m/s: the front footprint circle
    (L/3 ahead) meets the disc when 3 - L/3 - radii = 1 m/s · t."""
    movers, poses = disc_on_x(3.0, -0.5, 30)
    ttc, gap = interaction_stats((0.0, 0.0, 0.0), (0.5, 0.0), poses, movers, ROBOT, DT)
    closing = 3.0 - ROBOT.length / 3 - 0.3 - footprint_radius(ROBOT)
    assert gap == pytest.approx(closing)
    assert closing <= ttc < closing + DT + 1e-9  # the first step at or past contact


def test_no_contact_when_moving_apart_standing_aside_or_alone() -> None:
    movers, away = disc_on_x(3.0, 0.5, 30)
    assert interaction_stats((0.0, 0.0, 0.0), (0.4, 0.0), away, movers, ROBOT, DT)[0] == math.inf
    movers, coming = disc_on_x(3.0, -0.5, 30)
    # facing across the disc's line, 1 m aside: it passes in front; holding still, nothing touches
    ttc, gap = interaction_stats((1.5, -1.0, math.pi), (0.0, 0.0), coming, movers, ROBOT, DT)
    assert ttc == math.inf and gap > 0.4
    assert interaction_stats((0.0, 0.0, 0.0), (0.5, 0.0), np.zeros((0, 31, 3)), [], ROBOT, DT) == (math.inf, math.inf)
    # the same disc coming horizon-far away: beyond the 3 s looked at
    movers, far = disc_on_x(9.0, -0.5, 30)
    assert interaction_stats((0.0, 0.0, 0.0), (0.5, 0.0), far, movers, ROBOT, DT)[0] == math.inf


def test_the_env_reports_them_only_when_asked_and_flags_conflicts_by_its_rule() -> None:
    """Off by default (the step stays as cheap as before); with ``conflict.report`` every step's info carries the
    time to contact, the gap and the conflict flag of the configured rule, on the cut-in scenario some steps are
    conflicts and every one by the rule."""
    plain = sims.descriptor("ugv").make("4")
    plain.reset(seed=0)
    assert "ttc" not in plain.step(np.array([1.0, 0.0]))[4]
    env = sims.descriptor("ugv").make("4", **{"conflict.report": True, "conflict.ttc": 1.5, "conflict.gap": 0.2})
    flags = []
    for seed in range(3):
        env.reset(seed=seed)
        done = False
        while not done:
            _, _, terminated, truncated, info = env.step(np.array([1.0, 0.0]))
            done = terminated or truncated
            assert info["conflict"] == (info["ttc"] < 1.5 or info["nearest_gap"] < 0.2)
            assert info["ttc"] == math.inf or 0.0 <= info["ttc"] <= 3.0
            flags.append(info["conflict"])
    assert 0 < sum(flags) < len(flags)
