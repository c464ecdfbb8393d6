"""What the product knows about SUMO: where its observation shows contact."""

from __future__ import annotations

from xml.etree import ElementTree

import pytest

import sims
from core.sage.config import parse_gate_settings
from sims.sumo.config import SumoConfig
from sims.sumo.descriptor import contact_floors, vehicle_length
from sims.sumo.network import DATA_DIR


def test_the_contact_floor_is_a_car_touching_the_ego_on_the_leader_channel_and_a_queue_reads_above_it() -> None:
    floors = sims.descriptor("sumo").contact_floors
    rng = SumoConfig().perception_range
    assert floors == contact_floors() and len(floors) == 1  # channel 0 only: the leader's centre distance
    assert floors[0] == pytest.approx((vehicle_length("ego") + vehicle_length("car")) / 2 / rng)
    types = ElementTree.parse(DATA_DIR / "common.rou.xml").getroot().iter("vType")
    ego = next(v for v in types if v.get("id") == "ego")
    standstill = (vehicle_length("ego") / 2 + float(ego.get("minGap", "2.5")) + vehicle_length("car") / 2) / rng
    assert standstill > floors[0] * 1.3  # stopped behind a car at SUMO's gap: no contact read
    assert contact_floors(SumoConfig(perception_range=100.0))[0] == pytest.approx(2 * floors[0])
    with pytest.raises(ValueError, match="no vehicle type"):
        vehicle_length("hovercraft")


def test_imagined_contact_on_a_sumo_gate_brings_the_simulators_floor() -> None:
    settings = parse_gate_settings(["imagined_contact=true"], sims.descriptor("sumo").contact_floors)
    assert settings == {"imagined_contact": True, "contact_floors": [pytest.approx(0.0225)]}
