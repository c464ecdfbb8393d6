"""The composite network: it compiles from its plain-XML source and has the study's elements."""

from __future__ import annotations

import itertools
import shutil
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
import sumolib

from sims.sumo.network import NET_FILE, NETCCFG, SOURCE_FILES, NetworkBuildError, build_network


def _read(path: Path) -> sumolib.net.Net:
    return sumolib.net.readNet(str(path), withInternal=False, withPrograms=True)


def _summary(net: sumolib.net.Net) -> dict[str, object]:
    edges = {e.getID(): (e.getFromNode().getID(), e.getToNode().getID(), e.getLaneNumber()) for e in net.getEdges()}
    connections = sorted(
        (c.getFrom().getID(), c.getFromLane().getIndex(), c.getTo().getID(), c.getToLane().getIndex(), c.getState())
        for e in net.getEdges()
        for conns in e.getOutgoing().values()
        for c in conns
    )
    programs = {
        tls.getID(): [(p.duration, p.state) for prog in tls.getPrograms().values() for p in prog.getPhases()]
        for tls in net.getTrafficLights()
    }
    junctions = {n.getID(): n.getType() for n in net.getNodes()}
    return {"edges": edges, "connections": connections, "programs": programs, "junctions": junctions}


def test_network_compiles_from_source_and_matches_the_committed_one(tmp_path: Path) -> None:
    built = build_network(tmp_path / "composite.net.xml")
    assert built.is_file()
    assert _summary(_read(built)) == _summary(_read(NET_FILE)), (
        "composite.net.xml is stale: python -m sims.sumo.network"
    )


def test_network_has_the_studys_elements() -> None:
    net = _read(NET_FILE)
    node_types = {n.getID(): n.getType() for n in net.getNodes()}
    # signalised junctions with their own fixed-time programs
    assert {t.getID() for t in net.getTrafficLights()} == {"s1", "s2"}
    assert node_types["s1"] == node_types["s2"] == "traffic_light"
    # two roundabouts of four nodes each
    rings = sorted(sorted(r.getNodes()) for r in net.getRoundabouts())
    assert rings == [sorted(["rb1_w", "rb1_s", "rb1_e", "rb1_n"]), sorted(["rb2_s", "rb2_e", "rb2_n", "rb2_w"])]
    # unsignalised priority junctions: the ego has the major road at u1a/u1b/u2b and must yield at u2a
    for node in ("u1a", "u1b", "u2a", "u2b"):
        assert node_types[node] == "priority"

    def state(src: str, dst: str) -> str:
        conns = net.getEdge(src).getOutgoing()[net.getEdge(dst)]
        return conns[0].getState()

    assert state("r1_start_to_u1a", "u1a_to_u1b") == "M"
    assert state("u1a_to_u1b", "u1b_to_rb1") == "M"
    assert state("r2_start_to_u2a", "u2a_to_u2b") == "m"
    assert state("u2a_to_u2b", "u2b_to_rb2") == "M"
    # on-ramp merges: the ramp becomes lane 0 of a three-lane section whose lane 0 then ends
    for ramp, section, after in (("ramp1", "hw_acc1", "hw_mid1"), ("ramp2", "hw_acc2", "hw_mid2")):
        ramp_conns = net.getEdge(ramp).getOutgoing()[net.getEdge(section)]
        assert [c.getToLane().getIndex() for c in ramp_conns] == [0]
        assert net.getEdge(section).getLaneNumber() == 3 and net.getEdge(after).getLaneNumber() == 2
        assert net.getEdge(section).getLanes()[0].getOutgoing() == []
    # the off-ramp leaves from the deceleration lane only
    assert [c.getFromLane().getIndex() for c in net.getEdge("hw_dec").getOutgoing()[net.getEdge("off_ramp")]] == [0]


@pytest.mark.parametrize(
    ("route", "must_pass"),
    [
        ("ego_r1", {"u1a", "u1b", "rb1_w", "rb1_e", "s1", "m1", "d"}),
        ("ego_r2", {"u2a", "u2b", "rb2_s", "rb2_w", "s2", "m2", "d"}),
    ],
)
def test_ego_routes_are_connected_composite_routes(route: str, must_pass: set[str]) -> None:
    net = _read(NET_FILE)
    routes = {
        r.get("id"): r.get("edges", "").split() for r in ET.parse(NET_FILE.parent / "common.rou.xml").iter("route")
    }
    edges = [net.getEdge(e) for e in routes[route]]
    for a, b in itertools.pairwise(edges):
        assert b in a.getOutgoing(), f"{a.getID()} does not lead to {b.getID()}"
    passed = {e.getToNode().getID() for e in edges}
    assert must_pass <= passed
    assert edges[-1].getID() == "exit"
    assert sum(e.getLength() for e in edges) > 2000.0  # a long composite route


def test_broken_source_gives_an_error_naming_the_problem(tmp_path: Path) -> None:
    for src in (*SOURCE_FILES, NETCCFG):
        shutil.copy(src, tmp_path / src.name)
    edges = tmp_path / "composite.edg.xml"
    edges.write_text(edges.read_text().replace('from="hw_w"', 'from="nowhere"'))
    with pytest.raises(NetworkBuildError, match="nowhere") as err:
        build_network(tmp_path / "out.net.xml", config=tmp_path / NETCCFG.name)
    assert "netconvert failed" in str(err.value)
    assert not (tmp_path / "out.net.xml").exists()
    with pytest.raises(NetworkBuildError, match="not found"):
        build_network(tmp_path / "out.net.xml", config=tmp_path / "missing.netccfg")
