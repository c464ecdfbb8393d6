"""The calibration bench's gate table: which scenarios it counts towards issue #11's target, and its verdict line."""

from __future__ import annotations

from experiments.calibration import GateRow, aliases, table_scenarios, target_summary


def _row(scenario: str, violations: int, takeover: float, beyond: bool = False) -> GateRow:
    sim = scenario.split(" ", 1)[0]
    return GateRow(
        policy=f"{sim}-default",
        sim=sim,
        scenario=scenario,
        beyond=beyond,
        violations=violations,
        episodes=300,
        takeover_rate=takeover,
        takeover_parts=(takeover, 0.0, 0.0, 0.0),
        under_expert=violations,
        expert_held_s=0.5,
        handed_back=0,
        under_threshold=0,
        unforeseen=0,
        seconds=1.0,
    )


def test_a_scenario_under_two_names_is_counted_once() -> None:
    assert aliases("sumo") == {"1": "c1"}  # route 1 is the route-shift study's C1: the same settings
    assert "1" not in table_scenarios("sumo") and "c1" in table_scenarios("sumo")
    assert aliases("ugv") == {} and table_scenarios("ugv")[:4] == ["1", "2", "3", "4"]


def test_the_verdict_counts_rows_as_read_and_as_their_intervals_decide() -> None:
    rows = [
        _row("sumo c1", 0, 0.10),  # under, decided
        _row("sumo c2", 15, 0.20),  # 5.0% as read: met, undecided
        _row("ugv 4", 2, 0.36),  # missed on takeover, decided under on violations
        _row("highway test-adversarial", 40, 0.15),  # over, decided
        _row("ugv traffic.yaml", 30, 0.5, beyond=True),  # not one of the built-in scenarios
    ]
    text = target_summary(rows)
    assert "met on 2 of the 4 built-in scenarios" in text
    assert "missed on: ugv 4 2/300 at 36.0%; highway test-adversarial 40/300 at 15.0%." in text
    assert "2 lie wholly at or under 5%, 1 wholly over it (highway test-adversarial" in text
    assert "and 1 are undecided" in text
    assert "The layouts beyond them: 0 of 1 as read" in text
