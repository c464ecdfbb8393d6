"""How much of the gate's problem is fear's? The gate + scripted expert table with the deployed fear gate beside
gates that read what the simulator knows and the world model must infer, with the deployed gate's hold
(:class:`studies.calibrate.InfoGate`):

- highway: the true time to contact with the vehicle ahead in the ego's lane footprint and the gap to the nearest
  vehicle (``info["ttc"]``, ``info["nearest_gap"]``, :func:`sims.highway.sensing.interaction_stats`);
- ugv: the true time to contact with a mover holding the last command (the movers on their scripted paths) and the
  gap to the nearest mover (the same keys with ``conflict.report`` on, :mod:`sims.ugv.interaction`).

A privileged gate that meets issue #11's target (a violation in at most 5% of the episodes, at most 35% takeover)
where fear does not says the policy, the expert and the hold leave the target within reach, and the warning is
what is missing; one that does not says the target asks more than any warning from these states can give.

    .venv/bin/python -m experiments.oracle_gate [--sim highway|ugv] [--episodes 300] [--ttc S [S ...]] [--gap M] \
        [--scenario NAME ...] [--out DIR] [--readme docs/notes/calibration_history.md] [--cpus N | --address HOST:PORT]

The thresholds are conventional, not swept to fit: on highway a time to contact under 3 s is the traffic-conflict
literature's usual line for a conflict (1.5 s for a serious one) and 1.5 m to the nearest vehicle about half a
lane's width beside the ego's own; on the UGV the defaults are the warning the scripted expert needs (1 s, the
calibration bench's warning table on every built-in UGV scenario) and the label horizon of its world model (2 s),
and the margin the expert keeps to movers (0.12 m). Rows: the gate table's (``experiments/calibration.py``, its
seeds, so the deployed rows reproduce its table at the same commit), or the scenarios ``--scenario`` names (a
family's split, e.g. ``highway-shift:test`` or ``ugv-fields:test:2+``: ground no model or threshold was fitted on).
Each row is a Ray task (:func:`studies.sweep.run_tasks`). Not a unit test: about 20 minutes of one core at 300
episodes on highway.
"""

from __future__ import annotations

import argparse
import re
import subprocess
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import torch

import sims
from core.metrics import wilson_interval
from experiments.calibration import table_scenarios
from studies.readme import publish
from studies.sweep import run_tasks

ROOT = Path(__file__).resolve().parents[1]
POLICIES = {"highway": ROOT / "policies" / "highway-default", "ugv": ROOT / "policies" / "ugv-default"}
DEFAULTS: dict[str, tuple[list[float], float]] = {"highway": ([3.0], 1.5), "ugv": ([1.0, 2.0], 0.12)}
"""Per simulator: the times to contact (s) and the gap (m) of the privileged gates (see the module doc)."""
ENV_OVERRIDES: dict[str, dict[str, Any]] = {"highway": {}, "ugv": {"conflict.report": True}}
"""What makes each simulator put the time to contact and the gap in its info."""


def danger_rule(ttc: float | None, gap: float | None) -> Callable[[Mapping[str, Any]], bool]:
    """The privileged rule: fire when the true time to contact is under ``ttc`` s or the nearest vehicle is within
    ``gap`` m (None: that part left out)."""

    def danger(info: Mapping[str, Any]) -> bool:
        return (ttc is not None and float(info["ttc"]) < ttc) or (gap is not None and float(info["nearest_gap"]) < gap)

    return danger


def row(sim: str, scenario: str, episodes: int, ttc: float | None = None, gap: float | None = None) -> dict[str, float]:
    """One Ray task: gate + scripted expert on a scenario of ``sim`` with its default policy, with the deployed fear
    gate (no ``ttc`` and no ``gap``) or the privileged gate."""
    from core.agents import load_agent
    from studies.calibrate import InfoGate, gate_with_expert, run_gated

    torch.set_num_threads(1)
    descriptor = sims.descriptor(sim)
    overrides = ENV_OVERRIDES[sim] if ttc is not None or gap is not None else {}

    def make_env() -> Any:
        return descriptor.make(scenario, **overrides)

    if ttc is None and gap is None:
        return gate_with_expert(POLICIES[sim], make_env, episodes)
    agent = load_agent(POLICIES[sim])
    gate = InfoGate(agent.make_gate(), agent.gate_config().hold, danger_rule(ttc, gap))
    return run_gated(agent, make_env, gate, episodes, None, listeners=[gate.watch])


def chosen_scenarios(sim: str, names: list[str] | None) -> list[str]:
    """The rows' scenarios: ``names`` (comma lists split; each checked against the simulator: an unknown one is a
    clear error before any episode runs), or the gate table's (:func:`experiments.calibration.table_scenarios`)."""
    if not names:
        return table_scenarios(sim)
    chosen = [name.strip() for entry in names for name in entry.split(",") if name.strip()]
    descriptor = sims.descriptor(sim)
    for name in chosen:
        try:
            descriptor.scenario_kwargs(name)
        except ValueError as err:
            raise SystemExit(f"--scenario {name!r}: {err}") from err
    return chosen


def slug(name: str) -> str:
    """A scenario name as a folder and block name's part (``ugv-fields:test:2+`` -> ``ugv-fields-test-2plus``)."""
    return re.sub(r"[^a-z0-9]+", "-", name.lower().replace("+", "plus")).strip("-")


def _gating(ttc: float | None, gap: float | None) -> dict[str, float | None]:
    """One gating's thresholds (None: that signal is not used)."""
    return {"ttc": ttc, "gap": gap}


def gates(ttcs: list[float], gap: float) -> list[tuple[str, dict[str, float | None]]]:
    """The table's gatings, named: the deployed fear gate, each time to contact alone, the gap alone, and each time
    to contact or the gap."""
    return [
        ("fear (deployed)", _gating(None, None)),
        *[(f"time to contact < {ttc:g} s", _gating(ttc, None)) for ttc in ttcs],
        (f"nearest gap < {gap:g} m", _gating(None, gap)),
        *[(f"either{f' ({ttc:g} s)' if len(ttcs) > 1 else ''}", _gating(ttc, gap)) for ttc in ttcs],
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--sim", choices=sorted(POLICIES), default="highway", help="whose default policy and scenarios")
    parser.add_argument("--episodes", type=int, default=300, help="episodes per scenario and gate")
    parser.add_argument("--ttc", type=float, nargs="+", help="the privileged gates' times to contact [s]")
    parser.add_argument("--gap", type=float, help="the privileged gate's gap to the nearest vehicle or mover [m]")
    parser.add_argument(
        "--scenario",
        action="append",
        help="a scenario for the rows instead of the gate table's (repeatable, comma lists; e.g. highway-shift:test)",
    )
    parser.add_argument("--out", type=Path, help="the report's folder (default: docs/notes/oracle_gate_<sim>)")
    parser.add_argument(
        "--readme",
        type=Path,
        help="also copy the result into this document's block (e.g. docs/notes/calibration_history.md)",
    )
    parser.add_argument("--cpus", type=int, help="cores for local Ray (default: all of them)")
    parser.add_argument("--address", help="join the Ray cluster at this address instead of starting one")
    args = parser.parse_args()
    sim = args.sim
    ttcs = args.ttc or DEFAULTS[sim][0]
    gap = args.gap if args.gap is not None else DEFAULTS[sim][1]
    if args.episodes < 1 or gap <= 0 or any(ttc <= 0 for ttc in ttcs):
        parser.error("--episodes, --ttc and --gap must be positive")
    named = gates(ttcs, gap)
    scenarios = chosen_scenarios(sim, args.scenario)
    cases = [(scenario, name, rule) for scenario in scenarios for name, rule in named]
    results = run_tasks(
        row,
        [{"sim": sim, "scenario": scenario, "episodes": args.episodes, **rule} for scenario, _, rule in cases],
        [f"{name} on {sim} {scenario}" for scenario, name, _ in cases],
        address=args.address,
        cpus=args.cpus,
    )
    measured = {(scenario, name): result for (scenario, name, _), result in zip(cases, results, strict=True)}
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True)
    header = "| scenario | " + " | ".join(f"{name}: violations | takeover" for name, _ in named) + " |"
    command = (
        f"python -m experiments.oracle_gate{' --sim ugv' if sim != 'highway' else ''} --episodes {args.episodes} "
        f"--ttc {' '.join(f'{ttc:g}' for ttc in ttcs)} --gap {gap:g}"
        + "".join(f" --scenario {name}" for name in (scenarios if args.scenario else []))
    )
    what = {
        "highway": "Highway's gate beside gates that read the true time to contact and gaps",
        "ugv": "The UGV's gate beside gates that read the true time to contact with movers and the gap to them",
    }[sim]
    lines = [
        f"# {what}",
        "",
        f"Generated by `{command}` at commit {commit.stdout.strip()}. `{POLICIES[sim].relative_to(ROOT)}` with the "
        "scripted expert, the calibration bench's seeds; each gate holds control as the deployed one does once it "
        "fires (1 s). Violations: episodes with one, with the 95% Wilson interval; takeover: the share of steps the "
        "expert drove; either: time to contact or gap.",
        "",
        header,
        "|---|" + "---|---|" * len(named),
    ]
    for scenario in scenarios:
        cells = []
        for name, _ in named:
            point = measured[scenario, name]
            bad = round(point["violation_rate"] * args.episodes)
            low, high = wilson_interval(bad, args.episodes)
            cells.append(f"{bad}/{args.episodes} ({low:.0%}-{high:.0%}) | {point['takeover_rate']:.1%}")
        lines.append(f"| {sim} {scenario} | " + " | ".join(cells) + " |")
    suffix = "" if not args.scenario else "-" + "-".join(slug(name) for name in scenarios)
    out = args.out or ROOT / "docs" / "notes" / f"oracle_gate_{sim}{suffix.replace('-', '_')}"
    publish(lines, out, args.readme, f"oracle-gate-{sim}{suffix}", "## Calibration of fear")


if __name__ == "__main__":
    main()
