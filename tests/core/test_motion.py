"""The world model's motion input with a scan turned to the current heading (:mod:`core.motion`)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from core.motion import APPROACH_RANGE_FLOOR, EgoScanStep, ScanAlignment, approach_rate, motion_between
from core.sage.config import AgentConfig, WorldModelConfig, validate

SECTORS = 36
WIDTH = np.radians(5.0)


def scene(heading: float, approach: float = 0.0) -> np.ndarray:
    """A smooth range profile over 36 sectors seen from ``heading`` (radians, left positive), then a goal
    distance and the turn channel; ``approach`` brings the sectors around bearing 0.4 rad closer."""
    bearings = (np.arange(SECTORS) - SECTORS / 2 + 0.5) * WIDTH + heading
    ranges = 0.6 + 0.3 * np.sin(3.0 * bearings) + 0.1 * np.cos(7.0 * bearings)
    ranges -= approach * np.exp(-(((bearings - heading) - 0.4) ** 2) / 0.02)
    return np.concatenate([ranges, [0.5, 0.0]]).astype(np.float32)


def turned(previous_heading: float, turn: float, per_unit: float, approach: float = 0.0) -> np.ndarray:
    """The scene after turning by ``turn`` rad, its turn channel holding turn / (per_unit sector widths)."""
    obs = scene(previous_heading + turn, approach)
    obs[-1] = turn / (per_unit * WIDTH)
    return obs


@pytest.mark.parametrize("turn_sectors", [0.3, 1.0, 1.7, -0.6, -2.2])
def test_a_pure_turn_of_a_static_scene_leaves_almost_no_motion_once_aligned(turn_sectors: float) -> None:
    """Turning on the spot slides every range sideways: the plain difference of the two frames is large, the
    aligned one is the interpolation error only (and the sectors turned in from outside the field of view)."""
    per_unit = 1.2
    align = ScanAlignment.of(SECTORS, SECTORS + 1, per_unit, SECTORS + 2)
    assert align is not None
    before = scene(0.0)
    after = turned(0.0, turn_sectors * WIDTH, per_unit)
    plain = np.abs((after - before)[:SECTORS])
    aligned = np.abs(motion_between(before, after, align)[:SECTORS])
    inner = slice(3, SECTORS - 3)  # sectors that saw the same bearings in both frames
    # linear interpolation between sectors errs by at most h^2/8 max|r''| (h one sector): the scene's
    # r = 0.6 + 0.3 sin 3b + 0.1 cos 7b has |r''| <= 0.3 * 9 + 0.1 * 49 per rad^2
    interpolation_error = (0.3 * 9 + 0.1 * 49) * WIDTH**2 / 8
    assert aligned[inner].max() <= interpolation_error + 1e-6
    assert aligned[inner].mean() < 0.2 * plain[inner].mean()
    wrong_way = ScanAlignment(SECTORS, SECTORS + 1, -per_unit)
    assert np.abs(motion_between(before, after, wrong_way)[:SECTORS])[inner].mean() > plain[inner].mean()


def test_a_mover_shows_in_the_aligned_motion_while_turning() -> None:
    """While the robot turns, the one thing that moved (ranges near bearing 0.4 shrinking) is what the aligned
    motion holds; in the plain difference it is a small part of what changed."""
    align = ScanAlignment(SECTORS, SECTORS + 1, 1.0)
    before = scene(0.0)
    turn = 0.8 * WIDTH
    after = turned(0.0, turn, 1.0, approach=0.05)
    static_after = turned(0.0, turn, 1.0)
    motion = motion_between(before, after, align)[:SECTORS]
    truth = (after - static_after)[:SECTORS]  # the mover's own change, in the current frame
    inner = slice(3, SECTORS - 3)
    plain = (after - before)[:SECTORS]
    assert np.abs(motion - truth)[inner].max() < 0.2 * np.abs(truth).max()
    assert np.abs(plain - truth)[inner].max() > np.abs(truth).max()


def test_channels_after_the_scan_are_plain_differences_and_batches_align_row_by_row() -> None:
    align = ScanAlignment(SECTORS, SECTORS + 1, 1.0)
    previous = np.stack([scene(0.0), scene(0.2)])
    current = np.stack([turned(0.0, WIDTH, 1.0), turned(0.2, -0.5 * WIDTH, 1.0)])
    batch = motion_between(previous, current, align)
    for row in range(2):
        np.testing.assert_allclose(batch[row], motion_between(previous[row], current[row], align), atol=1e-7)
    np.testing.assert_allclose(batch[:, SECTORS:], (current - previous)[:, SECTORS:], atol=1e-7)
    # an imagined rollout's (members, batch, D) tensors align the same way
    stacked = align.motion(torch.from_numpy(previous).expand(3, 2, -1), torch.from_numpy(current).expand(3, 2, -1))
    np.testing.assert_allclose(stacked[1].numpy(), batch, atol=1e-7)


def test_a_scan_layout_that_does_not_fit_is_refused_with_its_field() -> None:
    assert ScanAlignment.of(0, -1, 0.0, 10) is None
    with pytest.raises(ValueError, match="scan_sectors"):
        ScanAlignment.of(12, 11, 1.0, 10)
    with pytest.raises(ValueError, match="scan_turn_channel"):
        ScanAlignment.of(6, 3, 1.0, 10)
    with pytest.raises(ValueError, match="scan_turn_sectors"):
        ScanAlignment.of(6, 8, 0.0, 10)
    wm = WorldModelConfig(motion_lag=3, scan_sectors=6, scan_turn_channel=8, scan_turn_sectors=1.0)
    with pytest.raises(ValueError, match="motion_lag=1"):
        validate(AgentConfig(world_model_config=wm))
    without_motion = WorldModelConfig(motion_input=False, scan_sectors=6, scan_turn_channel=8, scan_turn_sectors=1.0)
    with pytest.raises(ValueError, match="motion_input=true"):
        validate(AgentConfig(world_model_config=without_motion))


def test_fear_of_a_scan_aligned_model_stays_differentiable_through_its_imagined_turns() -> None:
    """The learner's fear term back-propagates through the rollout (each imagined step's aligned motion included)
    to the first action, after the gate has run the same alignment in inference mode."""
    from core.sage.config import GateConfig
    from core.sage.fear import fear
    from core.sage.networks import Actor
    from core.sage.world_model import EnsembleWorldModel

    rng = np.random.default_rng(0)
    wm = WorldModelConfig(hidden=16, max_updates_per_fit=20, scan_sectors=6, scan_turn_channel=7, scan_turn_sectors=1.3)
    model = EnsembleWorldModel(8, 2, wm)
    s = rng.uniform(0, 1, (200, 8)).astype(np.float32)
    a = rng.uniform(-1, 1, (200, 2)).astype(np.float32)
    model.fit(s, a, s + 0.05 * a[:, :1], np.zeros(200, np.float32), rng, motion=0.1 * s)
    actor = Actor(8, 2, 16, 1, -torch.ones(2), torch.ones(2))
    obs = torch.from_numpy(s[:4])
    with torch.inference_mode():
        fear(model.folded(), actor.deterministic, obs, torch.from_numpy(a[:4]), GateConfig(), motion=obs)
    action = torch.from_numpy(a[:4]).requires_grad_(True)
    terms = fear(model.folded(), actor.deterministic, obs, action, GateConfig(), motion=obs)
    terms.fear.sum().backward()
    assert action.grad is not None and bool(torch.isfinite(action.grad).all()) and float(action.grad.abs().sum()) > 0


def test_approach_rate_is_the_inverse_time_to_contact_of_each_closing_range() -> None:
    """max(0, -Δrange) / range per step over the chosen channels only, capped at 1; an opening or still beam reads 0,
    and a beam already at contact reads the cap, not a division by zero."""
    state = torch.tensor([[9.0, 0.5, 0.5, 0.2, 0.0, 9.0]])
    motion = torch.tensor([[-5.0, -0.1, 0.1, 0.0, -0.01, -5.0]])
    rate = approach_rate(state, motion, 1, 5)
    assert rate.shape == (1, 4)
    assert rate[0].tolist() == pytest.approx([0.2, 0.0, 0.0, min(0.01 / APPROACH_RANGE_FLOOR, 1.0)])
    fast = approach_rate(torch.tensor([[0.1]]), torch.tensor([[-0.5]]), 0, 1)
    assert float(fast) == 1.0
    batch = approach_rate(torch.rand(3, 2, 6) + 0.1, -torch.rand(3, 2, 6), 2, 6)
    assert batch.shape == (3, 2, 4) and bool((batch >= 0).all()) and bool((batch <= 1).all())


def test_an_approach_layout_that_does_not_fit_is_refused_with_its_field() -> None:
    from core.sage.world_model import EnsembleWorldModel

    with pytest.raises(ValueError, match=r"approach_start\.\.approach_stop"):
        EnsembleWorldModel(4, 1, WorldModelConfig(approach_start=2, approach_stop=6))
    with pytest.raises(ValueError, match="needs motion_input"):
        validate(AgentConfig(world_model_config=WorldModelConfig(motion_input=False, approach_stop=3)))
    with pytest.raises(ValueError, match=r"approach_start\.\.approach_stop"):
        validate(AgentConfig(world_model_config=WorldModelConfig(approach_start=5, approach_stop=3)))


def ego_step(sectors: int = 36) -> EgoScanStep:
    """36 sectors of 5° from -90°, one ray each at its start; a0 in [-1, 1] drives 0 to 0.02 range units a step,
    a1 turns by up to 0.1 rad."""
    step = EgoScanStep.of(
        WorldModelConfig(
            ego_sectors=sectors,
            ego_scan_start=-sectors / 2 * float(WIDTH),
            ego_sector_width=float(WIDTH),
            ego_forward_scale=0.01,
            ego_forward_offset=0.01,
            ego_turn_scale=0.1,
        ),
        sectors + 2,
        2,
    )
    assert step is not None
    return step


RAYS = -np.pi / 2 + np.arange(SECTORS) * WIDTH
"""The bearing of each sector's ray in :func:`ego_step`."""


def with_tail(ranges: np.ndarray) -> torch.Tensor:
    return torch.as_tensor(np.concatenate([ranges, [0.3, -0.2]]).astype(np.float32))[None]


def test_the_ego_step_reads_a_wall_ahead_from_where_the_robot_drove() -> None:
    """Driving straight at full speed (0.02) towards a wall 0.5 ahead: every ray facing it reads the wall from 0.48;
    standing still changes nothing; the channels after the scan are never touched."""
    step = ego_step()
    wall = np.where(np.abs(RAYS) < 0.6, 0.5 / np.cos(RAYS), 1.0)
    obs = with_tail(wall)
    moved = step.apply(obs, torch.tensor([[1.0, 0.0]]))[0].numpy()
    facing = np.abs(RAYS) < 0.5
    assert moved[:SECTORS][facing] == pytest.approx(0.48 / np.cos(RAYS[facing]), rel=1e-4)
    assert (moved[:SECTORS][np.abs(RAYS) > 0.7] == 1.0).all()
    assert moved[SECTORS:] == pytest.approx(obs[0, SECTORS:].numpy())
    standing = step.apply(obs, torch.tensor([[-1.0, 0.0]]))  # a0 = -1: no distance, no turn
    assert torch.allclose(standing, obs)


def test_driving_along_a_wall_reads_the_same_wall() -> None:
    """A wall parallel to the heading at 0.4 to the right: driving along it, every ray still reads it where it did
    (a cloud of moved points would read each point's own range, off by up to the distance driven)."""
    step = ego_step()
    right = RAYS < -0.2
    wall = np.where(right, np.minimum(0.4 / np.maximum(np.abs(np.sin(RAYS)), 0.1), 1.0), 1.0)
    moved = step.apply(with_tail(wall), torch.tensor([[1.0, 0.0]]))[0, :SECTORS].numpy()
    assert moved[right] == pytest.approx(wall[right], abs=1e-5)


@pytest.mark.parametrize("sectors_turned", [1, 2, -3])
def test_a_turn_by_whole_sectors_slides_the_scan_the_other_way(sectors_turned: int) -> None:
    """Turning left by k sector widths on the spot: each ray reads what the ray k sectors to its left read; the k
    sectors the turn brings in from outside the field of view keep their ranges (nothing is known there)."""
    step = ego_step()
    ranges = scene(0.0)[:SECTORS]
    turn = (sectors_turned - 1e-4) * float(WIDTH) / 0.1  # a hair short: returns land clear of sector boundaries
    moved = step.apply(with_tail(ranges), torch.tensor([[-1.0, turn]]))[0, :SECTORS].numpy()
    k = sectors_turned
    if k > 0:
        assert moved[: SECTORS - k] == pytest.approx(ranges[k:], rel=1e-4)
        assert moved[SECTORS - k :] == pytest.approx(ranges[SECTORS - k :])
    else:
        assert moved[-k:] == pytest.approx(ranges[: SECTORS + k], rel=1e-4)
        assert moved[:-k] == pytest.approx(ranges[:-k])


def test_an_objects_edge_slides_into_the_sector_behind_it() -> None:
    """A box 0.3 away at 45° to the right, open space behind: driving forward, its rear edge moves back by about half
    a sector, into the sector that read nothing; a post (one return) in front of a wall hides the wall's part."""
    step = ego_step()
    ranges = np.ones(SECTORS, np.float32)
    ranges[9:12] = 0.3  # sectors at -45°, -40°, -35°
    moved = step.apply(with_tail(ranges), torch.tensor([[1.0, 0.0]]))[0, :SECTORS].numpy()
    x, y = 0.3 * np.cos(RAYS[9]) - 0.02, 0.3 * np.sin(RAYS[9])
    assert np.floor((np.arctan2(y, x) - RAYS[0]) / WIDTH) == 8
    assert moved[8] == pytest.approx(np.hypot(x, y), rel=1e-5)
    assert (moved[:8] == 1.0).all() and (moved[13:] == 1.0).all()
    wall = np.where(np.abs(RAYS) < 0.6, 0.8 / np.cos(RAYS), 1.0).astype(np.float32)
    wall[18] = 0.3  # a post straight ahead, turned to by a whole sector
    moved = step.apply(with_tail(wall), torch.tensor([[-1.0, (1 - 1e-4) * float(WIDTH) / 0.1]]))[0, :SECTORS].numpy()
    assert moved[17] == pytest.approx(0.3, rel=1e-4)
    assert moved[16] == pytest.approx(wall[17], rel=1e-4) and moved[18] == pytest.approx(wall[19], rel=1e-4)


def test_the_ego_step_config_is_checked() -> None:
    assert EgoScanStep.of(WorldModelConfig(), 10, 2) is None
    with pytest.raises(ValueError, match="ego_sectors"):
        EgoScanStep.of(WorldModelConfig(ego_sectors=12), 10, 2)
    with pytest.raises(ValueError, match="ego_sector_width > 0"):
        EgoScanStep.of(WorldModelConfig(ego_sectors=4), 10, 2)
    with pytest.raises(ValueError, match="ego_rays_per_sector"):
        EgoScanStep.of(WorldModelConfig(ego_sectors=4, ego_sector_width=0.1, ego_rays_per_sector=0), 10, 2)
    with pytest.raises(ValueError, match="ego_turn_channel"):
        EgoScanStep.of(WorldModelConfig(ego_sectors=4, ego_sector_width=0.1, ego_turn_channel=2), 10, 2)
    with pytest.raises(ValueError, match="ego_sectors must be >= 0"):
        validate(AgentConfig(world_model_config=WorldModelConfig(ego_sectors=-1)))


def test_the_ego_step_moves_any_batch_shape_and_passes_gradients_to_the_action() -> None:
    """The gate rolls (members, batch, D) states, the learner differentiates fear by the action: both shapes agree
    row for row, in chunks or not, and the action gets a gradient where the step moved a surface."""
    from core import motion

    step = ego_step()
    rng = np.random.default_rng(0)
    states = torch.as_tensor(np.concatenate([rng.uniform(0.2, 1.0, (3, 5, SECTORS)), np.zeros((3, 5, 2))], -1))
    actions = torch.as_tensor(rng.uniform(-1, 1, (3, 5, 2)), dtype=torch.float64)
    whole = step.apply(states, actions)
    rows = torch.stack([step.apply(states[i, j][None], actions[i, j][None])[0] for i in range(3) for j in range(5)])
    assert torch.allclose(whole.reshape(15, -1), rows)
    chunk, motion.EGO_CHUNK = motion.EGO_CHUNK, 4
    try:  # the tensor version (a GPU's path), in chunks of EGO_CHUNK rows
        assert torch.allclose(step._apply_tensors(states.clone().requires_grad_(True), actions), whole)
        assert torch.allclose(step.apply(states.clone().requires_grad_(True), actions), whole)  # the CPU's, with grad
    finally:
        motion.EGO_CHUNK = chunk
    action = actions[0, :1].clone().requires_grad_(True)
    step.apply(states[0, :1], action)[..., :SECTORS].sum().backward()
    assert action.grad is not None and torch.isfinite(action.grad).all() and action.grad.abs().sum() > 0


def random_scenes(rng: np.random.Generator, rows: int, sectors: int) -> np.ndarray:
    """Scans of walls at random distances and angles, boxes, posts and open space, ranges in (0, 1]."""
    bearing = np.linspace(-2.0, 2.0, sectors)
    distance = rng.uniform(0.05, 0.9, (rows, 1)) / np.maximum(np.cos(bearing - rng.uniform(-1.5, 1.5, (rows, 1))), 0.05)
    scans = np.minimum(distance, 1.0)
    boxes = rng.random((rows, sectors)) < 0.1
    scans = np.where(boxes, rng.uniform(0.05, 1.0, (rows, sectors)), scans)
    return np.where(rng.random((rows, sectors)) < 0.15, 1.0, scans)


@pytest.mark.parametrize("layout", ["test", "ugv", "full turn"])
def test_the_compiled_step_is_the_tensor_step(layout: str) -> None:
    """Calls that need no gradient take the compiled loop (core._ego_kernel): on walls, boxes, posts and open space,
    driven by every action and beyond, it gives the tensor version's ranges in float64, and from float32 inputs the
    float64 result rounded; the channels after the scan pass through."""
    from sims.ugv.env import ego_motion_layout

    if layout == "ugv":
        step = EgoScanStep.of(WorldModelConfig(**ego_motion_layout()), 58, 2)
        assert step is not None and step.rays == 2
    elif layout == "full turn":  # 72 sectors all round from behind the robot, 3 rays each: surfaces wrap at the back
        full = {"ego_sectors": 72, "ego_scan_start": 3.0, "ego_sector_width": 2 * np.pi / 72, "ego_rays_per_sector": 3}
        step = EgoScanStep.of(WorldModelConfig(**full, ego_forward_scale=0.02, ego_turn_scale=0.2), 76, 2)
        assert step is not None
    else:
        step = ego_step()
    rng = np.random.default_rng(1)
    scans = random_scenes(rng, 3000, step.sectors)
    states = torch.as_tensor(np.concatenate([scans, rng.normal(size=(3000, 4))], -1))
    actions = torch.as_tensor(rng.uniform(-1.5, 1.5, (3000, 2)))
    compiled = step.apply(states, actions)
    tensor = step._apply_tensors(states.clone().requires_grad_(True), actions).detach()
    assert torch.equal(compiled[:, step.sectors :], states[:, step.sectors :])
    assert (compiled != states).any(dim=1).float().mean() > 0.9  # the scenes do move
    torch.testing.assert_close(compiled, tensor, rtol=0.0, atol=1e-12)
    single = step.apply(states.float(), actions.float())
    assert single.dtype == torch.float32
    assert torch.equal(single, step.apply(states.float().double(), actions.float().double()).float())


@pytest.mark.parametrize("layout", ["test", "ugv", "full turn"])
def test_the_gradient_path_gives_the_tensor_steps_value_and_gradients(layout: str) -> None:
    """On the CPU a call with gradients takes the compiled loop's choices and recomputes only the chosen candidates
    (``EgoScanStep._apply_chosen``): the same readings as the tensor version and the same gradients w.r.t. the action
    and the state, on walls, boxes, posts and open space."""
    from sims.ugv.env import ego_motion_layout

    if layout == "ugv":
        step = EgoScanStep.of(WorldModelConfig(**ego_motion_layout()), 58, 2)
    elif layout == "full turn":
        full = {"ego_sectors": 72, "ego_scan_start": 3.0, "ego_sector_width": 2 * np.pi / 72, "ego_rays_per_sector": 3}
        step = EgoScanStep.of(WorldModelConfig(**full, ego_forward_scale=0.02, ego_turn_scale=0.2), 76, 2)
    else:
        step = ego_step()
    assert step is not None
    rng = np.random.default_rng(3)
    rows = 400
    scans = random_scenes(rng, rows, step.sectors)
    states = torch.as_tensor(np.concatenate([scans, rng.normal(size=(rows, 4))], -1))
    actions = torch.as_tensor(rng.uniform(-1.5, 1.5, (rows, 2)))
    weights = torch.as_tensor(rng.normal(size=states.shape))
    results = []
    for path in (step._apply_tensors, step._apply_chosen):
        state, action = states.clone().requires_grad_(True), actions.clone().requires_grad_(True)
        out = path(state, action)
        (out * weights).sum().backward()
        results.append((out.detach(), action.grad, state.grad))
    (tensor, tensor_action, tensor_state), (chosen, chosen_action, chosen_state) = results
    assert tensor_action is not None and chosen_action is not None and tensor_state is not None
    assert tensor_action.abs().sum() > 0  # the step does move surfaces
    torch.testing.assert_close(chosen, tensor, rtol=0.0, atol=1e-12)
    torch.testing.assert_close(chosen_action, tensor_action, rtol=1e-9, atol=1e-9)
    torch.testing.assert_close(chosen_state, tensor_state, rtol=1e-9, atol=1e-9)
    # float32 inputs: the choices are the compiled loop's, in float64, as for a call without gradient (the critic's
    # target, the gate); a float32 tensor version may decide a borderline joint or hit otherwise (full turn: ~1%)
    single = step.apply(states.float().requires_grad_(True), actions.float())
    torch.testing.assert_close(single.detach(), step.apply(states.float(), actions.float()), rtol=0.0, atol=1e-5)


@pytest.mark.parametrize("per_member", [False, True])
@pytest.mark.parametrize("closing", ["none", "rows", "channels"])
def test_the_compiled_contact_test_is_the_moved_state_compared_with_its_floors(per_member: bool, closing: str) -> None:
    """``EgoScanStep.contact``: member n touches where some channel of ``apply(state, action) + delta[n]`` is at or
    under its floor and ``closing`` lets that channel count, the booleans :func:`core.sage.fear.with_contact` reads from
    the state itself; states shared by the members or one per member."""
    from core.sage.fear import with_contact
    from sims.ugv.env import ego_motion_layout

    step = EgoScanStep.of(WorldModelConfig(**ego_motion_layout()), 58, 2)
    assert step is not None
    rng = np.random.default_rng(7)
    members, rows = 5, 300
    scans = random_scenes(rng, members * rows if per_member else rows, step.sectors)
    states = torch.as_tensor(np.concatenate([scans, rng.normal(size=(len(scans), 4))], -1), dtype=torch.float32)
    actions = torch.as_tensor(rng.uniform(-1, 1, (len(scans), 2)), dtype=torch.float32)
    if per_member:
        states, actions = states.reshape(members, rows, -1), actions.reshape(members, rows, -1)
    delta = torch.as_tensor(rng.normal(scale=0.08, size=(members, rows, 58)), dtype=torch.float32)
    floors = torch.full((step.sectors,), 0.1) + 0.05 * torch.rand(
        step.sectors, generator=torch.Generator().manual_seed(0)
    )
    mask = {
        "none": None,
        "rows": torch.as_tensor(rng.random((rows, step.sectors)) < 0.5),
        "channels": torch.as_tensor(rng.random(step.sectors) < 0.5),
    }[closing]
    moved = step.apply(states, actions)
    imagined = (moved if per_member else moved.expand(members, rows, -1)) + delta
    expected = with_contact(torch.zeros(1, members, rows), imagined.unsqueeze(0), floors, mask)[0].bool()
    got = step.contact(states, actions, delta[..., : step.sectors], floors, mask)
    assert 0.05 < float(expected.float().mean()) < 0.95  # some members touch, some do not: the test can fail
    assert torch.equal(got, expected)


def test_a_bound_step_reads_its_buffers_when_called() -> None:
    """The gate kernel binds its rollout's strided buffers once: each call moves what they hold then, into its
    output, as apply does."""
    step = ego_step()
    rng = np.random.default_rng(2)
    buffer = torch.zeros(3, 1, SECTORS + 2 + 2 + 5)  # rows [state, action, other] as the gate lays them out
    state, action = buffer[..., : SECTORS + 2], buffer[..., SECTORS + 2 : SECTORS + 4]
    out = torch.full((3, 1, SECTORS + 2), -1.0)
    move = step.bound(state, action, out)
    for _ in range(3):
        state[..., :SECTORS] = torch.as_tensor(random_scenes(rng, 3, SECTORS)[:, None], dtype=torch.float32)
        action.uniform_(-1.0, 1.0)
        move()
        assert torch.equal(out, step.apply(state, action))


def test_a_bound_step_that_must_read_views_refuses_rows_it_could_only_copy() -> None:
    """Every other row of a buffer cannot be viewed as rows: a loop bound to a copy would read stale states."""
    step = ego_step()
    buffer = torch.zeros(4, 3, SECTORS + 2)
    state, action = buffer[:, ::2], torch.zeros(4, 2, 2)
    with pytest.raises(ValueError, match="views of the buffers"):
        step.bound(state, action, torch.zeros(4, 2, SECTORS + 2), views=True)
    step.bound(buffer[:, 1:2], action[:, :1], torch.zeros(4, 1, SECTORS + 2), views=True)()  # one row of each: views
