"""``gate.mover_model = "cartesian"`` (:mod:`core.sage.movers`): the scan's small moving objects tracked as points in
the plane over three real scans, ego motion compensated, and moved at constant velocity into each member's imagined
poses in the contact test. Synthetic scans cast on circles and walls in the UGV's sector layout (range units): a mover
crossing in front of a robot driving forward is imagined in contact at the step it reaches the robot's path and not
before; a static world, a receding mover, one passing behind and an edge that newly appears give no contact or no
velocity; the gate and the calibration read the same velocities; the settings are checked with one clear line."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

from core.agents import fear_shape_moved
from core.motion import EgoScanStep
from core.replay import ReplayBuffer
from core.sage.calibration import CalibrationSample, calibrate
from core.sage.compiled_gate import CompiledGateKernel
from core.sage.config import AgentConfig, GateConfig, WorldModelConfig, parse_gate_settings, validate
from core.sage.fear import GateKernel, contact_reach, contact_terms, fear_of, rollout
from core.sage.gate import SageGate
from core.sage.model_trainer import buffer_mover_velocities
from core.sage.movers import mover_contact, mover_velocities
from core.sage.networks import Actor
from core.sage.world_model import EnsembleWorldModel
from sims.ugv.descriptor import contact_floors
from sims.ugv.env import ego_motion_layout

torch.set_num_threads(1)

SECTORS = 54
LAYOUT = ego_motion_layout()
STEP = EgoScanStep.of(dataclasses.replace(WorldModelConfig(), **LAYOUT), SECTORS + 2, 2)
assert STEP is not None
FLOORS = torch.tensor(contact_floors(), dtype=torch.float32)
SPEED, SIZE, NOISE, HISTORY = 0.02, 0.12, 0.002, 4  # GateConfig's defaults (range units: the UGV's reach, 10 Hz)
FORWARD = np.array([1.0, 0.0])  # full speed ahead: 0.006 range units (6 cm) a step
STILL = np.array([-1.0, 0.0])


@dataclasses.dataclass
class World:
    """Circles (x, y, radius) moving at (vx, vy) a step, and static wall segments, in world range units."""

    circles: list[tuple[float, float, float, float, float]]
    walls: list[tuple[float, float, float, float]] = dataclasses.field(default_factory=list)

    def at(self, t: int) -> list[tuple[float, float, float]]:
        return [(x + t * vx, y + t * vy, r) for x, y, r, vx, vy in self.circles]


def cast(world: World, t: int, pose: tuple[float, float, float]) -> np.ndarray:
    """The scan at ``pose`` (x, y, heading) of the world at step t: each sector the nearest hit of its rays."""
    px, py, heading = pose
    scan = np.ones(SECTORS)
    for i in range(SECTORS):
        for q in range(STEP.rays):
            bearing = heading + STEP.start + (i + q / STEP.rays) * STEP.width
            ux, uy = math.cos(bearing), math.sin(bearing)
            for cx, cy, r in world.at(t):
                dx, dy = cx - px, cy - py
                along = dx * ux + dy * uy
                miss = dx * dx + dy * dy - along * along
                if along > 0 and miss <= r * r:
                    scan[i] = min(scan[i], along - math.sqrt(r * r - miss))
            for ax, ay, bx, by in world.walls:
                ex, ey = bx - ax, by - ay
                den = ux * ey - uy * ex
                if abs(den) < 1e-12:
                    continue
                rx, ry = ax - px, ay - py
                hit = (rx * ey - ry * ex) / den
                across = (rx * uy - ry * ux) / den
                if hit > 0 and 0 <= across <= 1:
                    scan[i] = min(scan[i], hit)
    return scan


def drive(world: World, actions: list[np.ndarray]) -> tuple[np.ndarray, list[tuple[float, float, float]]]:
    """The scans along the robot's path from the origin under ``actions`` (the ego step's arc), and its poses."""
    pose = (0.0, 0.0, 0.0)
    poses, scans = [pose], [cast(world, 0, pose)]
    for t, action in enumerate(actions):
        distance = action[0] * STEP.forward_scale + STEP.forward_offset
        turn = action[1] * STEP.turn_scale
        half = 0.5 * turn
        chord = distance * (math.sin(half) / half if abs(half) > 1e-6 else 1.0)
        x, y, heading = pose
        pose = (x + chord * math.cos(heading + half), y + chord * math.sin(heading + half), heading + turn)
        poses.append(pose)
        scans.append(cast(world, t + 1, pose))
    return np.array(scans), poses


def velocities(scans: np.ndarray, actions: list[np.ndarray]) -> np.ndarray:
    return mover_velocities(STEP, scans[-HISTORY - 1 :], np.array(actions[-HISTORY:]), SPEED, SIZE, NOISE)


def imagined_contact(scan: np.ndarray, velocity: np.ndarray, steps: int = 20) -> np.ndarray:
    """(steps,) whether the movers are imagined in contact at each step ahead of driving on at full speed."""
    actions = torch.tensor(FORWARD, dtype=torch.float32).expand(steps, 1, 1, 2)
    obs = torch.from_numpy(scan.astype(np.float32)).unsqueeze(0)
    return mover_contact(STEP, obs, torch.from_numpy(velocity).float().unsqueeze(0), actions, FLOORS)[:, 0, 0].numpy()


def footprint_overlaps(world: World, t: int, pose: tuple[float, float, float]) -> bool:
    """Whether a mover's circle overlaps the robot's 0.5 x 0.4 m body at ``pose`` (range units)."""
    px, py, heading = pose
    for cx, cy, r in world.at(t):
        dx, dy = cx - px, cy - py
        lx, ly = math.cos(heading) * dx + math.sin(heading) * dy, math.cos(heading) * dy - math.sin(heading) * dx
        nearest = (min(max(lx, -0.025), 0.025), min(max(ly, -0.02), 0.02))
        if math.hypot(lx - nearest[0], ly - nearest[1]) <= r:
            return True
    return False


def test_a_mover_crossing_in_front_is_imagined_in_contact_when_it_reaches_the_path_and_not_before() -> None:
    """A 0.25 m walker crossing from the left at 0.8 m/s, 1.2 m ahead of a robot driving at 0.6 m/s: the velocity read
    from three scans is the walker's, and the imagined contact starts within a step of the real overlap."""
    world = World([(0.12, 0.1, 0.025, 0.0, -0.008)])
    actions = [FORWARD] * HISTORY
    scans, poses = drive(world, actions)
    velocity = velocities(scans, actions)
    moving = np.abs(velocity).sum(-1) > 0
    assert moving.any()
    np.testing.assert_allclose(velocity[moving], [[0.0, -0.008]] * int(moving.sum()), atol=0.003)
    ahead = imagined_contact(scans[-1], velocity)
    first = int(np.argmax(ahead)) + 1
    assert ahead.any()
    # the truth: the robot driving on at full speed, the walker on its course
    truth = next(
        k for k in range(1, 40) if footprint_overlaps(world, HISTORY + k, (poses[-1][0] + 0.006 * k, 0.0, 0.0))
    )
    assert abs(first - truth) <= 1
    assert not ahead[: truth - 2].any()
    # the per-sector contact of today's gate (the ego-moved scan, no movers) sees nothing that close: the scan's own
    # nearest return is far above every floor
    assert float(scans[-1].min()) > 2 * float(FLOORS.max())


def test_a_static_world_has_no_movers_whatever_the_robot_does() -> None:
    """Posts, a box-sized post near the path and a wall, the robot driving forward and turning: no velocity."""
    world = World(
        [(0.2, 0.05, 0.03, 0.0, 0.0), (0.1, -0.06, 0.02, 0.0, 0.0), (0.35, -0.2, 0.04, 0.0, 0.0)],
        walls=[(-0.1, 0.15, 0.6, 0.15)],
    )
    for actions in ([FORWARD] * 6, [np.array([0.5, 0.6])] * 6, [np.array([-1.0, -1.0])] * 6):
        scans, _ = drive(world, actions)
        for t in range(2, 7):
            assert not velocities(scans[: t + 1], actions[:t]).any()


def test_a_receding_mover_and_one_passing_behind_are_never_imagined_in_contact() -> None:
    receding = World([(0.12, 0.05, 0.025, 0.0, 0.008)])  # from beside the path, away to the left
    behind = World([(-0.06, 0.15, 0.025, 0.0, -0.008)])  # crossing behind the robot, which drives away
    for world in (receding, behind):
        actions = [FORWARD] * HISTORY
        scans, _ = drive(world, actions)
        velocity = velocities(scans, actions)
        assert not imagined_contact(scans[-1], velocity, 30).any()


def test_a_return_that_newly_appears_or_jumps_gets_no_velocity() -> None:
    """A walker stepping out from behind a wall (in view for fewer scans than the track), and a return that jumps
    further than a mover moves in a step (an occlusion edge), read no velocity; a walker seen all along does."""
    actions = [STILL] * HISTORY
    wall = [(0.1, 0.05, 0.1, 0.3)]  # a wall to the left, 1 m ahead, hiding what is behind it
    # a walker stepping out from behind the wall's end: in view for the last two steps, not the whole track
    appearing = World([(0.14, 0.094, 0.02, 0.0, -0.008)], walls=wall)
    scans, _ = drive(appearing, actions)
    hidden = cast(World([], walls=wall), 0, (0.0, 0.0, 0.0))
    assert np.array_equal(scans[1], hidden) and not np.array_equal(scans[2], hidden)
    assert not velocities(scans, actions).any()
    still = cast(World([(0.2, 0.0, 0.02, 0.0, 0.0)]), 0, (0.0, 0.0, 0.0))
    scans = np.array([still] * HISTORY + [cast(World([(0.2, 0.06, 0.02, 0.0, 0.0)]), 0, (0.0, 0.0, 0.0))])
    assert not velocities(scans, actions).any()
    steady, _ = drive(World([(0.2, 0.06, 0.02, 0.0, -0.008)]), actions)
    assert velocities(steady, actions).any()


def fitted() -> tuple[EnsembleWorldModel, Actor, np.ndarray]:
    """A briefly fitted model with the UGV's ego step on scans of one street (the model's own predictions matter
    little here: the movers enter ĉ through the contact test)."""
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    obs_dim = SECTORS + 2
    model = EnsembleWorldModel(obs_dim, 2, WorldModelConfig(hidden=32, max_updates_per_fit=20, **LAYOUT))
    s = np.concatenate([rng.uniform(0.3, 1.0, (200, SECTORS)), rng.uniform(-1, 1, (200, 2))], axis=1)
    s = s.astype(np.float32)
    a = rng.uniform(-1, 1, (200, 2)).astype(np.float32)
    with torch.no_grad():  # a static world: the next scan is the ego step's, with a little noise
        moved = model.base(torch.from_numpy(s), torch.from_numpy(a)).numpy()
    nxt = np.clip(moved + 0.002 * rng.normal(size=s.shape).astype(np.float32), 0.01, 1.0)
    model.fit(s, a, nxt, np.zeros(200, np.float32), rng)
    actor = Actor(obs_dim, 2, 32, 2, -torch.ones(2), torch.ones(2))
    calibrate(model, actor.deterministic, torch.as_tensor(s), 5)
    return model, actor, s


def gate_cfg(model: str, **more: object) -> GateConfig:
    return GateConfig(
        imagined_contact=True,
        contact_floors=[float(f) for f in FLOORS],
        contact_horizon=10,
        mover_model=model,  # type: ignore[arg-type]
        tau_from_data=False,
        tau_min=0.3,
        tau_max=0.6,
        **more,  # type: ignore[arg-type]
    )


def crossing_episode(steps: int) -> tuple[np.ndarray, np.ndarray]:
    """Observations (scan, 2 channels) and actions of a robot driving at full speed towards a walker's crossing."""
    world = World([(0.12, 0.08, 0.025, 0.0, -0.008)])
    actions = [FORWARD] * steps
    scans, _ = drive(world, actions)
    obs = np.concatenate([scans, np.zeros((len(scans), 2))], axis=1).astype(np.float32)
    return obs, np.array(actions, np.float32)


def test_the_gate_fears_the_crossing_and_its_two_paths_agree() -> None:
    """Live: once it has a track the gate reads the walker's velocity, and its ĉ reaches 1 steps before the gate without
    the mover model; the generic rollout, the torch kernel and the compiled kernel give the same fears."""
    model, actor, _ = fitted()
    obs, actions = crossing_episode(10)
    records = {}
    for name, cfg in (("off", gate_cfg("none")), ("on", gate_cfg("cartesian"))):
        gates = [
            SageGate(model, actor.deterministic, cfg),
            SageGate(model, actor, cfg, compiled=False),
            SageGate(model, actor, cfg, compiled=True),
        ]
        assert [type(g.kernel()) for g in gates[1:]] == [GateKernel, CompiledGateKernel] and gates[0].kernel() is None
        rows = []
        for t in range(len(actions)):
            row = []
            for gate in gates:
                decision = gate.decide(obs[t], actions[t])
                gate.observe(obs[t], actions[t], obs[t + 1])
                row.append((decision.fear, gate.detail.cost))
            for other in row[1:]:
                np.testing.assert_allclose(other, row[0], rtol=1e-5, atol=1e-6)
            rows.append(row[0][1])
        records[name] = np.array(rows)
    early = records["on"][:HISTORY]
    assert early.max() == pytest.approx(records["off"][:HISTORY].max(), abs=1e-6)  # no track yet: no velocity
    assert (records["on"] >= records["off"] - 1e-6).all()
    # the mover model imagines the contact steps before the ego-moved scan's own contact test does
    first = {name: int(np.argmax(costs > 0.99)) for name, costs in records.items()}
    assert records["on"].max() > 0.99, records
    assert records["off"].max() <= 0.99 or first["on"] < first["off"], records
    gate = SageGate(model, actor, gate_cfg("cartesian"))
    for t in range(HISTORY):
        gate.observe(obs[t], actions[t], obs[t + 1])
    assert gate.mover_velocity() is not None
    gate.reset()
    assert gate.mover_velocity() is None  # an episode's movers do not carry into the next


def test_the_kept_segments_give_the_velocities_computed_afresh() -> None:
    """A scan's segments are kept for the next steps' tracks (``core.sage.movers._segments``): along an episode, each
    step's velocities with the kept segments are those computed with none kept (the same float64 arithmetic), and
    what is kept stays bounded."""
    from core.sage import movers

    world = World([(0.12, 0.08, 0.025, 0.0, -0.008), (0.3, -0.1, 0.03, -0.006, 0.0)], [(0.05, 0.2, 0.4, 0.2)])
    actions = [FORWARD if t % 3 else np.array([0.5, 0.4]) for t in range(14)]
    scans, _ = drive(world, actions)
    movers._SEGMENTS.clear()
    kept = [velocities(scans[: t + 2], actions[: t + 1]) for t in range(HISTORY - 1, len(actions))]
    assert 0 < len(movers._SEGMENTS) <= movers._SEGMENTS_KEPT
    fresh = []
    for t in range(HISTORY - 1, len(actions)):
        movers._SEGMENTS.clear()
        fresh.append(velocities(scans[: t + 2], actions[: t + 1]))
    assert any(v.any() for v in fresh)  # the comparison covers moving segments, not only static ones
    np.testing.assert_allclose(np.array(kept), np.array(fresh), rtol=0, atol=1e-12)


def test_a_world_where_nothing_moves_adds_no_mover_test_and_the_same_fear() -> None:
    """The gate skips the movers' contact test when no sector moves (all velocities zero): both kernels give the fear
    they give with the zero velocities passed on, and along the crossing the gate's fear is the generic rollout's
    with every step's velocities passed on, zeros included (the path before the skip)."""
    model, actor, _ = fitted()
    cfg = gate_cfg("cartesian")
    obs, actions = crossing_episode(10)
    o, a = torch.from_numpy(obs[:1]), torch.from_numpy(actions[:1])
    zeros = torch.zeros(1, SECTORS, 2)
    with torch.inference_mode():
        for kernel in (SageGate(model, actor, cfg, compiled=c).kernel() for c in (False, True)):
            assert kernel is not None
            assert kernel(o, a, None, None, zeros) == pytest.approx(kernel(o, a, None, None), abs=1e-7)
    gate = SageGate(model, actor, cfg)
    folded, counts = model.folded(), {True: 0, False: 0}
    still, _ = drive(World([(0.15, 0.03, 0.03, 0.0, 0.0)]), [FORWARD] * 10)
    still_obs = np.concatenate([still, np.zeros((len(still), 2))], axis=1).astype(np.float32)
    for obs in (crossing_episode(10)[0], still_obs):  # a walker crossing, then a post that stands still
        gate.reset()
        for t in range(len(actions)):
            velocity = gate.mover_velocity()
            decision = gate.decide(obs[t], actions[t])
            if velocity is not None:
                counts[bool(velocity.any())] += 1
                motion = gate._motion(obs[t])
                with torch.no_grad():
                    ro = rollout(
                        folded,
                        actor.deterministic,
                        torch.from_numpy(obs[t : t + 1]),
                        torch.from_numpy(actions[t : t + 1]),
                        contact_reach(cfg, cfg.horizon),
                        motion,
                        *contact_terms(cfg, motion),
                        learned_steps=cfg.horizon,
                        mover_velocity=velocity,
                    )
                assert decision.fear == pytest.approx(float(fear_of(folded, ro, cfg).fear[0]), abs=1e-5)
            gate.observe(obs[t], actions[t], obs[t + 1])
    assert counts[True] > 0 and counts[False] > 0, counts  # steps with movers and steps without both compared


def test_the_calibration_reads_the_movers_the_gate_would_have_read(tmp_path: object) -> None:
    from pathlib import Path

    model, actor, _ = fitted()
    cfg = gate_cfg("cartesian")
    obs, actions = crossing_episode(8)
    buffer = ReplayBuffer(SECTORS + 2, 2, 16)
    gate = SageGate(model, actor, cfg)
    expected = []
    for t in range(len(actions)):
        velocity = gate.mover_velocity()
        expected.append(np.zeros((SECTORS, 2), np.float32) if velocity is None else velocity[0].numpy())
        gate.observe(obs[t], actions[t], obs[t + 1])
        buffer.add(obs[t], actions[t], 0.0, obs[t + 1], t == len(actions) - 1)
    got = buffer_mover_velocities(buffer, model, cfg, np.arange(len(buffer)))
    assert got is not None and got[HISTORY:].any() and not got[:HISTORY].any()
    np.testing.assert_allclose(got, np.array(expected), atol=1e-6)
    assert buffer_mover_velocities(buffer, model, gate_cfg("none"), np.arange(len(buffer))) is None
    sample = CalibrationSample(
        obs=buffer.obs[:8], action=buffer.action[:8], next_obs=buffer.next_obs[:8], familiar=np.ones(8, bool)
    )
    loaded = CalibrationSample.load(
        dataclasses.replace(sample, mover_velocity=got).save(Path(str(tmp_path)) / "calibration.npz")
    )
    assert loaded.mover_velocity is not None
    np.testing.assert_array_equal(loaded.mover_velocity, got)
    joined = CalibrationSample.concat([sample, loaded])
    assert joined.mover_velocity is not None and not joined.mover_velocity[:8].any()
    # the fear the bounds are measured on counts the movers
    folded = model.folded()
    o = torch.from_numpy(obs[HISTORY:8])
    with torch.no_grad():
        plain = rollout(
            folded, actor.deterministic, o, o.new_tensor(actions[HISTORY:8]), 10, None, FLOORS, learned_steps=5
        )
        moved = rollout(
            folded,
            actor.deterministic,
            o,
            o.new_tensor(actions[HISTORY:8]),
            10,
            None,
            FLOORS,
            learned_steps=5,
            mover_velocity=torch.from_numpy(got[HISTORY:8]),
        )
    with_movers, without = fear_of(folded, moved, cfg).cost, fear_of(folded, plain, cfg).cost
    assert bool((with_movers >= without).all()) and bool((with_movers > without + 0.5).any())


def test_the_settings_are_read_and_checked() -> None:
    assert parse_gate_settings(["mover_model=cartesian"]) == {"mover_model": "cartesian"}
    assert fear_shape_moved(GateConfig(), dataclasses.replace(GateConfig(), mover_model="cartesian")) == ["mover_model"]
    ego = dataclasses.replace(WorldModelConfig(), **LAYOUT)
    base = dataclasses.replace(AgentConfig(), world_model_config=ego)
    cases = {
        "needs gate.imagined_contact": GateConfig(mover_model="cartesian"),
        "must be none or cartesian": dataclasses.replace(gate_cfg("none"), mover_model="polar"),  # type: ignore[arg-type]
        r"gate.mover_max_speed must be a finite number > 0": dataclasses.replace(
            gate_cfg("cartesian"), mover_max_speed=-1.0
        ),
        "must be under gate.mover_max_speed": dataclasses.replace(gate_cfg("cartesian"), mover_min_speed=0.5),
    }
    for message, gate in cases.items():
        with pytest.raises(ValueError, match=message) as caught:
            validate(dataclasses.replace(base, gate=gate))
        assert "\n" not in str(caught.value)
    with pytest.raises(ValueError, match=r"needs world_model_config\.ego_sectors"):
        validate(dataclasses.replace(AgentConfig(), gate=gate_cfg("cartesian")))
    validate(dataclasses.replace(base, gate=gate_cfg("cartesian")))
