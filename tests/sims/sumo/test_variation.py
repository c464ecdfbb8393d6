"""The sumo-shift family's varied training splits: random special vehicles and density, drawn from the SUMO seed."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

import sims
from sims.sumo import variation
from sims.sumo.config import SumoConfig
from sims.sumo.env import SumoEnv


def test_the_varied_splits_resolve_and_draw_on_their_own_routes_edges_only(tmp_path: Path) -> None:
    descriptor = sims.descriptor("sumo")
    varied1 = descriptor.scenario_kwargs("sumo-shift:varied1")
    assert varied1 == {"route": 1, "random_specials": 6, "random_density": True}
    assert descriptor.scenario_kwargs("sumo-shift:varied2")["special_vehicles"] is True
    for route in (1, 2):
        pairs = set(variation.route_pairs(route))
        for seed in range(20):
            root = ET.parse(variation.specials_file(route, 6, seed, tmp_path)).getroot()
            flows = [(f.attrib["from"], f.attrib["to"]) for f in root.iter("flow")]
            assert len(flows) == 6 and set(flows) <= pairs
            for vtype in root.iter("vType"):
                kind = next(k for k in variation.KINDS.values() if k.vclass == vtype.attrib["vClass"])
                assert kind.sigma[0] <= float(vtype.attrib["sigma"]) <= kind.sigma[1]
                assert kind.max_speed[0] <= float(vtype.attrib["maxSpeed"]) <= kind.max_speed[1]


def test_an_episodes_variation_is_its_seeds_and_differs_between_seeds(tmp_path: Path) -> None:
    first, again = variation.specials_file(1, 6, 11, tmp_path), variation.specials_file(1, 6, 11, tmp_path)
    assert first == again and first.read_text() == variation.specials_xml(1, 6, 11)
    assert variation.specials_xml(1, 6, 12) != variation.specials_xml(1, 6, 11)
    scales = {variation.traffic_scale(seed) for seed in range(50)}
    assert len(scales) > 40 and min(scales) >= 0.7 and max(scales) <= 1.5
    env = SumoEnv(SumoConfig(route=1, random_specials=6, random_density=True))
    args = env.sumo_args(11)
    assert str(variation.specials_file(1, 6, 11)) in args[args.index("--route-files") + 1]
    assert args[args.index("--scale") + 1] == repr(variation.traffic_scale(11))
    plain = SumoEnv(SumoConfig(route=1)).sumo_args(11)
    assert "sage-sumo-variation" not in plain[plain.index("--route-files") + 1]
    assert plain[plain.index("--scale") + 1] == "1.0"


def test_bad_settings_are_refused() -> None:
    for bad in (-1, 1.5, True, "3"):
        with pytest.raises(ValueError, match="random_specials"):
            SumoConfig(random_specials=bad)  # type: ignore[arg-type]


def test_the_scripted_expert_drives_a_varied_episode_with_its_random_vehicles_on_the_road() -> None:
    libsumo = pytest.importorskip("libsumo")
    env = sims.descriptor("sumo").make("sumo-shift:varied1")
    unwrapped = env.unwrapped
    seen: set[str] = set()
    try:
        env.reset(seed=5)
        done = False
        while not done:
            _, _, terminated, truncated, _ = env.step(unwrapped.expert_action())
            done = terminated or truncated
            seen |= {v for v in libsumo.vehicle.getIDList() if v.startswith("rnd")}
        assert unwrapped.metrics()["success"] == 1.0
        assert seen
    finally:
        env.close()
