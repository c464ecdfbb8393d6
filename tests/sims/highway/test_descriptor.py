"""What the product knows about highway: where its observation shows contact (the lane beams), and a gate that reads
those floors on real scans."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

import sims
from core.agents import load_agent
from core.sage.config import AgentConfig, GateConfig, parse_gate_settings, validate
from core.sage.fear import contact_floors as floor_tensor
from core.sage.fear import with_contact
from sims.highway.config import HighwayConfig, SensorConfig
from sims.highway.descriptor import contact_floors, lane_beams
from sims.highway.env import OBS_SIZE
from sims.highway.road import LANE_WIDTH
from sims.highway.sensing import box_corners, box_segments, ray_distances

ROOT = Path(__file__).resolve().parents[3]
FIRST_BEAM = OBS_SIZE - HighwayConfig().sensor.beams


def beam_reading(beam: float, x: float, y: float, cfg: HighwayConfig | None = None) -> float:
    """The normalised reading of a beam at ``beam`` (index, fractional allowed) from an ego at the origin heading +x,
    with one car of the ego's size centred at (x, y) along the road."""
    cfg = cfg or HighwayConfig()
    one = np.array
    corners = box_corners(one([x]), one([y]), one([0.0]), one([cfg.ego.length]), one([cfg.ego.width]))
    angle = np.array([2 * math.pi * beam / cfg.sensor.beams])
    return float(ray_distances(np.zeros(2), angle, box_segments(corners), cfg.sensor.range)[0] / cfg.sensor.range)


def test_the_floors_are_on_the_lane_beams_only_at_the_ego_s_bumper() -> None:
    floors = sims.descriptor("highway").contact_floors
    assert floors == contact_floors() and len(floors) == OBS_SIZE
    assert lane_beams() == (0, 36)  # straight ahead and straight behind of 72
    marked = {i: f for i, f in enumerate(floors) if f is not None}
    half_length = HighwayConfig().ego.length / 2 / HighwayConfig().sensor.range
    assert marked == {FIRST_BEAM: pytest.approx(half_length), FIRST_BEAM + 36: pytest.approx(half_length)}
    # a longer reach sees the next lane on fewer beams still; a far shorter one lets the beams beside through
    assert lane_beams(HighwayConfig(sensor=SensorConfig(range=200.0))) == (0, 36)
    assert len(lane_beams(HighwayConfig(sensor=SensorConfig(range=10.0)))) > 2
    coarse = contact_floors(HighwayConfig(sensor=SensorConfig(beams=36)))  # a sensor of other size: its own channels
    assert len(coarse) == FIRST_BEAM + 36 and [i for i, f in enumerate(coarse) if f is not None] == [
        FIRST_BEAM,
        FIRST_BEAM + 18,
    ]


@pytest.mark.parametrize("ahead", [1.0, -1.0])
def test_a_lane_beam_reads_at_the_floor_exactly_when_a_car_touches_the_bumper(ahead: float) -> None:
    cfg, floor = HighwayConfig(), contact_floors()[FIRST_BEAM]
    assert floor is not None
    beam = 0 if ahead > 0 else 36
    for gap in (0.0, 0.5, 3.0, 20.0):  # bumper to bumper
        reading = beam_reading(beam, ahead * (cfg.ego.length + gap), 0.0)
        assert reading == pytest.approx(floor + gap / cfg.sensor.range, abs=1e-6)
        assert (reading <= floor + 1e-6) == (gap == 0.0)


def test_a_car_in_the_next_lane_never_shows_on_a_lane_beam_but_does_on_the_beams_beside() -> None:
    xs = np.linspace(-60.0, 60.0, 241)
    for y in (LANE_WIDTH, -LANE_WIDTH):
        assert all(beam_reading(beam, x, y) == 1.0 for beam in (0, 36) for x in xs)
        assert min(beam_reading(beam, x, y) for beam in (1, 71) for x in xs) < 1.0  # the rule is not vacuous


def test_imagined_contact_on_a_highway_gate_brings_the_lane_floors_and_none_elsewhere() -> None:
    settings = parse_gate_settings(["imagined_contact=true"], sims.descriptor("highway").contact_floors)
    floors = settings["contact_floors"]
    assert len(floors) == OBS_SIZE and sum(f is not None for f in floors) == 2
    cfg = AgentConfig(gate=GateConfig(**settings))
    validate(cfg)
    tensor = floor_tensor(cfg.gate)
    assert tensor is not None and torch.isinf(tensor[:FIRST_BEAM]).all() and tensor[FIRST_BEAM] == pytest.approx(0.05)
    # the command line's spelling of a channel without a floor
    assert parse_gate_settings(["contact_floors=[none, 0.1, null]"])["contact_floors"] == [None, 0.1, None]
    with pytest.raises(ValueError, match="contact_floors"):
        validate(AgentConfig(gate=GateConfig(imagined_contact=True, contact_floors=[None, None])))
    with pytest.raises(ValueError, match="contact_floors"):
        validate(AgentConfig(gate=GateConfig(contact_floors=[None, -0.1])))


def test_a_channel_without_a_floor_never_shows_contact_however_fast_it_falls() -> None:
    cfg = GateConfig(imagined_contact=True, contact_floors=[None, 0.2])
    floors = floor_tensor(cfg)
    assert floors is not None
    states = torch.full((30, 5, 1, 2), -1.0)  # both channels at the bottom of the observation's range
    states[..., 1] = 0.9
    probability = torch.zeros(30, 5, 1)
    falling = torch.tensor([[-2.0, 0.0]])  # channel 0 falling as fast as an observation can
    assert not with_contact(probability, states, floors, closing_rate=falling).any()
    closing = torch.tensor([[0.0, -0.05]])  # channel 1 from 0.9 at 0.05 a step: at the floor from step 14
    marked = with_contact(probability, states, floors, closing_rate=closing)[:, 0, 0]
    assert int(torch.nonzero(marked).min()) + 1 == 14 and bool(marked[13:].all())


def test_the_highway_default_reads_the_lane_floors_on_real_scans_and_contact_only_raises_its_c_hat() -> None:
    """The committed highway policy's gate with imagined contact on the lane beams (the channels without a floor at
    -inf in every path: the compiled kernel, the torch rollout), driven over real scans beside the same gate without
    it: every ĉ finite, never lower with the contact (it only adds violations), the same σ̂."""
    agent = load_agent(ROOT / "policies" / "highway-default")
    fixed = {"tau_from_data": False}  # the committed bounds are another fear's; the test reads ĉ and σ̂, not τ
    plain = agent.make_gate(**fixed)
    lane = agent.make_gate(imagined_contact=True, contact_floors=list(contact_floors()), **fixed)
    env = sims.make("highway", scenario="train-adversarial")
    try:
        obs, _ = env.reset(seed=3)
        for gate in (plain, lane):
            gate.reset()
        for _ in range(40):
            action = agent.policy.act(obs, deterministic=True)
            parts = []
            for gate in (plain, lane):
                gate.decide(obs, action)
                parts.append((gate.detail.cost, gate.detail.sigma))
            (cost, sigma), (lane_cost, lane_sigma) = parts
            assert math.isfinite(lane_cost) and lane_cost >= cost - 1e-6
            assert lane_sigma == pytest.approx(sigma, abs=1e-5)
            next_obs, _, terminated, truncated, _ = env.step(action)
            for gate in (plain, lane):
                gate.observe(obs, action, next_obs)
            obs = next_obs
            if terminated or truncated:
                break
    finally:
        env.close()
