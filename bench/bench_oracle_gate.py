"""How much of highway's gate problem is fear's? The gate + scripted expert table with the deployed fear gate beside
gates that read what the simulator knows and the world model must infer: the true time to contact with the vehicle
ahead in the ego's lane footprint and the gap to the nearest vehicle (``info["ttc"]``, ``info["nearest_gap"]``,
:func:`sims.highway.sensing.interaction_stats`), with the deployed gate's hold (:class:`studies.calibrate.InfoGate`).

A privileged gate that meets issue #11's target (a violation in at most 5% of the episodes, at most 35% takeover)
where fear does not says the policy, the expert and the hold leave the target within reach, and the warning is
what is missing; one that does not says the target asks more than any warning from these states can give.

    .venv/bin/python bench/bench_oracle_gate.py [--episodes 300] [--ttc 3] [--gap 1.5] [--out DIR] \
        [--readme docs/calibration_history.md] [--cpus N | --address HOST:PORT]

The thresholds are conventional, not swept here: a time to contact under 3 s is the traffic-conflict literature's
usual line for a conflict (1.5 s for a serious one); 1.5 m to the nearest vehicle is about half a lane's width
beside the ego's own. Rows: the gate table's (``bench/bench_calibration.py``, its seeds, so the deployed rows
reproduce its table at the same commit). Each row is a Ray task (:func:`studies.sweep.run_tasks`). Not a unit test:
about 20 minutes of one core at 300 episodes.
"""

from __future__ import annotations

import argparse
import subprocess
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import torch
from bench_calibration import table_scenarios  # the sibling bench (this folder is on the path when run as a script)

import sims
from core.metrics import wilson_interval
from studies.readme import publish
from studies.sweep import run_tasks

ROOT = Path(__file__).resolve().parents[1]
POLICY = ROOT / "policies" / "highway-default"


def danger_rule(ttc: float | None, gap: float | None) -> Callable[[Mapping[str, Any]], bool]:
    """The privileged rule: fire when the true time to contact is under ``ttc`` s or the nearest vehicle is within
    ``gap`` m (None: that part left out)."""

    def danger(info: Mapping[str, Any]) -> bool:
        return (ttc is not None and float(info["ttc"]) < ttc) or (gap is not None and float(info["nearest_gap"]) < gap)

    return danger


def row(scenario: str, episodes: int, ttc: float | None = None, gap: float | None = None) -> dict[str, float]:
    """One Ray task: gate + scripted expert on a highway scenario, with the deployed fear gate (no ``ttc`` and no
    ``gap``) or the privileged gate."""
    from core.agents import load_agent
    from studies.calibrate import InfoGate, gate_with_expert, run_gated

    torch.set_num_threads(1)
    descriptor = sims.descriptor("highway")

    def make_env() -> Any:
        return descriptor.make(scenario)

    if ttc is None and gap is None:
        return gate_with_expert(POLICY, make_env, episodes)
    agent = load_agent(POLICY)
    gate = InfoGate(agent.make_gate(), agent.gate_config().hold, danger_rule(ttc, gap))
    return run_gated(agent, make_env, gate, episodes, None, listeners=[gate.watch])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--episodes", type=int, default=300, help="episodes per scenario and gate")
    parser.add_argument("--ttc", type=float, default=3.0, help="the privileged gate's time to contact [s]")
    parser.add_argument("--gap", type=float, default=1.5, help="the privileged gate's gap to the nearest vehicle [m]")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "oracle_gate_highway")
    parser.add_argument("--readme", type=Path, help="also copy the result into this README's section")
    parser.add_argument("--cpus", type=int, help="cores for local Ray (default: all of them)")
    parser.add_argument("--address", help="join the Ray cluster at this address instead of starting one")
    args = parser.parse_args()
    if args.episodes < 1 or args.ttc <= 0 or args.gap <= 0:
        parser.error("--episodes, --ttc and --gap must be positive")
    gates: list[tuple[str, dict[str, float | None]]] = [
        ("fear (deployed)", {"ttc": None, "gap": None}),
        (f"time to contact < {args.ttc:g} s", {"ttc": args.ttc, "gap": None}),
        (f"nearest gap < {args.gap:g} m", {"ttc": None, "gap": args.gap}),
        ("either", {"ttc": args.ttc, "gap": args.gap}),
    ]
    scenarios = table_scenarios("highway")
    cases = [(scenario, name, rule) for scenario in scenarios for name, rule in gates]
    results = run_tasks(
        row,
        [{"scenario": scenario, "episodes": args.episodes, **rule} for scenario, _, rule in cases],
        [f"{name} on highway {scenario}" for scenario, name, _ in cases],
        address=args.address,
        cpus=args.cpus,
    )
    measured = {(scenario, name): result for (scenario, name, _), result in zip(cases, results, strict=True)}
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True)
    header = "| scenario | " + " | ".join(f"{name}: violations | takeover" for name, _ in gates) + " |"
    lines = [
        "# Highway's gate beside gates that read the true time to contact and gaps",
        "",
        f"Generated by `python bench/bench_oracle_gate.py --episodes {args.episodes} --ttc {args.ttc:g} --gap "
        f"{args.gap:g}` at commit {commit.stdout.strip()}. `policies/highway-default` with the scripted expert, "
        "the calibration bench's seeds; each gate holds control as the deployed one does once it fires (1 s). "
        "Violations: episodes with one, with the 95% Wilson interval; takeover: the share of steps the expert "
        "drove; either: time to contact or gap.",
        "",
        header,
        "|---|" + "---|---|" * len(gates),
    ]
    for scenario in scenarios:
        cells = []
        for name, _ in gates:
            point = measured[scenario, name]
            bad = round(point["violation_rate"] * args.episodes)
            low, high = wilson_interval(bad, args.episodes)
            cells.append(f"{bad}/{args.episodes} ({low:.0%}-{high:.0%}) | {point['takeover_rate']:.1%}")
        lines.append(f"| highway {scenario} | " + " | ".join(cells) + " |")
    publish(lines, args.out, args.readme, "oracle-gate-highway", "## Calibration of fear")


if __name__ == "__main__":
    main()
