"""Traffic that varies from episode to episode on the training routes: special vehicles of random behaviour and a
random traffic density, drawn from the episode's SUMO seed (the ``sumo-shift`` family's varied training splits,
:mod:`sims.sumo.families`; issue 60).

A world model fitted on the fixed C1 / C2 traffic learns its vehicles' habits (a close leader at a ramp usually
pulls away); on a route with other vehicles it does not know those habits do not hold. Here every episode draws
``flows`` special-vehicle flows, each with a vehicle type whose class and parameters are drawn from wide ranges
(:data:`KINDS`: slow heavy vehicles, emergency vehicles with the blue-light device, noisy passenger cars; spanning
SUMO's class defaults and C2's types by about half again either way) between an origin and a destination of the ego's
own route's flows (``route{N}.rou.xml``, so every pair is drivable). Nothing here is drawn from the unseen route's
files.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np

from sims.sumo.network import DATA_DIR


@dataclass(frozen=True)
class Kind:
    """A class of special vehicle and the uniform ranges its type's parameters are drawn from."""

    vclass: str
    length: tuple[float, float]
    accel: tuple[float, float]
    decel: tuple[float, float]
    max_speed: tuple[float, float]
    speed_factor: tuple[float, float]
    sigma: tuple[float, float]
    bluelight: bool = False


KINDS: dict[str, Kind] = {
    "heavy": Kind("bus", (8.0, 15.0), (0.7, 1.8), (3.0, 6.0), (12.0, 26.0), (0.7, 1.1), (0.1, 0.8)),
    "emergency": Kind("emergency", (4.5, 11.0), (1.5, 4.5), (4.0, 8.0), (25.0, 45.0), (1.0, 1.7), (0.1, 0.6), True),
    "car": Kind("passenger", (4.0, 5.5), (1.5, 4.5), (3.5, 8.0), (20.0, 40.0), (0.6, 1.5), (0.4, 0.9)),
}
"""The special vehicles' classes, drawn with equal chance, and their parameter ranges."""
FLOW_PROBABILITY = (0.004, 0.02)
"""Range of a flow's departure probability per second (C2's special flows: 0.006-0.012)."""
TRAFFIC_SCALES = (0.7, 1.5)
"""Range of the background flows' scale (SUMO's ``--scale``) when an episode draws its density."""


@cache
def route_pairs(route: int) -> tuple[tuple[str, str], ...]:
    """Origin and destination edges of the flows of ``route{route}.rou.xml`` (the background traffic of that route)."""
    root = ET.parse(DATA_DIR / f"route{route}.rou.xml").getroot()
    pairs = {(flow.attrib["from"], flow.attrib["to"]) for flow in root.iter("flow") if "from" in flow.attrib}
    if not pairs:
        raise ValueError(f"{DATA_DIR / f'route{route}.rou.xml'} has no flow with from/to edges to draw from")
    return tuple(sorted(pairs))


def _draw(rng: np.random.Generator, bounds: tuple[float, float]) -> float:
    return round(float(rng.uniform(*bounds)), 2)


def specials_xml(route: int, flows: int, seed: int) -> str:
    """The route file's text: ``flows`` special-vehicle flows of random types for an episode of ``route``."""
    rng = np.random.default_rng([seed, route, flows])
    pairs = route_pairs(route)
    names = sorted(KINDS)
    lines = ['<?xml version="1.0" encoding="UTF-8"?>', f"<!-- random special vehicles, route {route}, seed {seed} -->"]
    lines.append("<routes>")
    for k in range(flows):
        kind = KINDS[names[int(rng.integers(len(names)))]]
        speed_factor = _draw(rng, kind.speed_factor)
        attrs = (
            f'id="rnd{k}" vClass="{kind.vclass}" length="{_draw(rng, kind.length)}" accel="{_draw(rng, kind.accel)}" '
            f'decel="{_draw(rng, kind.decel)}" emergencyDecel="9.0" maxSpeed="{_draw(rng, kind.max_speed)}" '
            f'speedFactor="{speed_factor}" sigma="{_draw(rng, kind.sigma)}"'
        )
        if kind.bluelight:
            lines.append(f'    <vType {attrs}><param key="has.bluelight.device" value="true"/></vType>')
        else:
            lines.append(f"    <vType {attrs}/>")
    for k in range(flows):
        origin, destination = pairs[int(rng.integers(len(pairs)))]
        probability = round(float(rng.uniform(*FLOW_PROBABILITY)), 4)
        lines.append(
            f'    <flow id="rnd_flow{k}" type="rnd{k}" begin="0" end="7200" probability="{probability}" '
            f'from="{origin}" to="{destination}" departSpeed="max"/>'
        )
    lines.append("</routes>")
    return "\n".join(lines) + "\n"


def specials_file(route: int, flows: int, seed: int, folder: Path | None = None) -> Path:
    """:func:`specials_xml` written once to a file named by its content (safe when processes write it at once)."""
    text = specials_xml(route, flows, seed)
    folder = folder or Path(tempfile.gettempdir()) / "sage-sumo-variation"
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"r{route}-{hashlib.sha256(text.encode()).hexdigest()[:16]}.rou.xml"
    if not path.exists():
        fd, temporary = tempfile.mkstemp(dir=folder, suffix=".tmp")
        with os.fdopen(fd, "w") as handle:
            handle.write(text)
        os.replace(temporary, path)
    return path


def traffic_scale(seed: int) -> float:
    """The episode's background scale, drawn from :data:`TRAFFIC_SCALES` by its SUMO seed."""
    return round(float(np.random.default_rng([seed, 7]).uniform(*TRAFFIC_SCALES)), 3)
