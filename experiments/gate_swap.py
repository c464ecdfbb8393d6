"""Whose gate is quiet? Fine-tuned versions of a live session on the promotion check's episodes, judged by their own
gate, by the base's gate, and alone (issue #62: the fine-tuned versions' own gates hand over on few supervised steps
and the versions collide; docs/notes/adaptation_probe.md, "which of the two candidate causes quiets the gate").

For each version named (default: every published one) of a session's versions folder (``runs/live-.../finetune/
SESSION/versions``, what :mod:`experiments.live_session` leaves), on the promotion check's own episodes
(:class:`core.promotion.PromotionConfig`: 15 seeds from 7,000,000, 600 steps at most, the mean action, the scripted
expert), three ways:

- ``own``: the version with its own gate (its world model, τ bounds and actor in the imagined steps): what the
  promotion check ran (:func:`core.promotion.evaluate_version`);
- ``base``: the version's actions judged by ``v0000``'s gate (``v0000``'s world model, τ bounds and actor in the
  imagined steps after the first action, which is the version's): a gate whose rollout policy was never trained on
  the session, so neither against its fear nor to imitate the expert;
- ``alone``: no gate, no expert (the same episodes, for the collisions the policy makes by itself).

Per version and way: the share of steps handed over, the episodes with a collision, the episodes reaching the goal.
The report (``--out``: ``report.md``, ``report.json``) names its command and commit.

    python -m experiments.gate_swap runs/live-nofear-s0/finetune/SESSION/versions \
        --out docs/notes/live_session/gate_swap/no_fear_s0
"""

from __future__ import annotations

import argparse
import collections
import json
import math
import shlex
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

WAYS = ("own", "base", "alone")
MOVER_GAP = 0.05
LOOKBACK = 20
"""Steps before a collision that its summary looks back over (2 s on the UGV)."""
"""A collision within this many metres of a mover (by the footprint's circles, which only approximate the body the
simulator collides) counts as a collision with the mover."""


@dataclass
class Outcome:
    """One version driven one way over the promotion check's episodes."""

    way: str
    takeover_share: float
    collisions: int
    successes: int
    episodes: int
    mover_gaps: list[float]
    """Per collided episode, the gap to the nearest mover at the first colliding step (metres; 0 in contact by the
    footprint's circles, privileged: ``interaction_stats``); inf on a layout without movers or a simulator without
    the measure."""

    speed_before: list[float]
    """Per collided episode, the executed forward command's mean over the last ``LOOKBACK`` steps up to the first
    colliding one, as a share of full speed ((a0 + 1) / 2 on the UGV's [-1, 1] command): near 1 the robot drove
    into it, near 0 it stood and was hit."""
    handed_over_before: list[bool]
    """Per collided episode, whether the expert held control at any of the last ``LOOKBACK`` steps up to it."""
    peak_fear_ratio: list[float]
    """Per collided episode, the largest F/τ of the last ``LOOKBACK`` steps up to it (NaN without a gate): near 1 or
    above the gate came close or fired; far below it saw nothing."""

    @property
    def mover_collisions(self) -> int:
        """Collided episodes whose first colliding step was within ``MOVER_GAP`` of a mover."""
        return sum(gap <= MOVER_GAP for gap in self.mover_gaps)


def drive(
    version: Path,
    base: Path,
    way: str,
    episodes: int,
    seed: int,
    max_steps: int | None,
    sim: str,
    scenario: str,
    gate_settings: dict[str, Any] | None = None,
) -> Outcome:
    """``version`` on ``episodes`` seeds from ``seed`` with the gate ``way`` names (see the module docstring)."""
    from app.server import make_env
    from core.agents import load_agent
    from core.experts import ScriptedExpert
    from core.loop import Gate, NoGate, Runner, StepRecord

    agent = load_agent(version)
    gate: Gate = NoGate()
    if way == "own":
        gate = agent.make_gate(**(gate_settings or {}))
    elif way == "base":
        gate = load_agent(base).make_gate(
            **(gate_settings or {})
        )  # the base's model, bounds and actor; the runner's a_RL is the version's
    env = make_env(sim, scenario)  # the env the promotion check builds (the dashboard's, live options on)
    taken = steps = collisions = successes = 0
    violated = [False]
    gaps: list[float] = []
    speeds: list[float] = []
    handed: list[bool] = []
    peaks: list[float] = []
    recent: collections.deque[tuple[float, bool, float]] = collections.deque(maxlen=LOOKBACK)
    stats = getattr(env.unwrapped, "interaction_stats", None)

    def watch(record: StepRecord) -> None:
        speed = (float(np.asarray(record.action).reshape(-1)[0]) + 1.0) / 2.0
        ratio = record.fear / record.threshold if record.threshold > 0 else math.nan
        recent.append((speed, bool(record.takeover), ratio))
        if record.violation and not violated[0]:
            gaps.append(float(stats()[1]) if stats is not None else float("inf"))
            speeds.append(sum(v for v, _, _ in recent) / len(recent))
            handed.append(any(taken for _, taken, _ in recent))
            ratios = [r for _, _, r in recent if math.isfinite(r)]
            peaks.append(max(ratios) if ratios else math.nan)
        violated[0] = violated[0] or record.violation

    try:
        runner = Runner(env, agent.policy, gate, ScriptedExpert(), seed=seed, deterministic=True)
        runner.step_listeners.append(watch)
        for _ in range(episodes):
            violated[0] = False
            recent.clear()
            summary = runner.run_episode(max_steps=max_steps)
            collisions += int(violated[0] or bool(summary.metrics.get("collision", False)))
            successes += int(bool(summary.metrics.get("success", False)))
            taken += summary.takeovers
            steps += summary.steps
    finally:
        env.close()
    return Outcome(way, taken / max(steps, 1), collisions, successes, episodes, gaps, speeds, handed, peaks)


def _cell(outcome: dict[str, Any] | None) -> str:
    if outcome is None:
        return "-"
    n = outcome["episodes"]
    share, hits, movers = 100 * outcome["takeover_share"], outcome["collisions"], outcome["mover_collisions"]
    return f"{share:.0f}%, {hits}/{n} ({movers} mover), {outcome['successes']}/{n}"


def render(report: dict[str, Any]) -> str:
    lines = [
        f"# Gate swap, {report['sim']} {report['scenario']}: {report['versions_root']}",
        "",
        f"Command: `{report['command']}`  ",
        f"Commit: `{report['commit']}`",
        "",
        *([f"Gate settings over every gate: `{report['gate_settings']}`.", ""] if report.get("gate_settings") else []),
        f"The promotion check's episodes (seeds {report['seed']}..{report['seed'] + report['episodes'] - 1}, at most "
        f"{report['max_steps']} steps, the mean action, the scripted expert). own: the version's own gate; base: "
        "v0000's gate (its world model, τ bounds and actor in the imagined steps) on the version's actions; alone: no "
        "gate. Cells: takeover share, collisions (of them, at the first colliding step within "
        f"{MOVER_GAP} m of a mover by the footprint's circles), goals reached.",
        "",
        "| version | own | base | alone |",
        "|---|---|---|---|",
    ]
    for row in report["rows"]:
        cells = [_cell(row.get(way)) for way in WAYS]
        lines.append(f"| v{row['number']:04d} | " + " | ".join(cells) + " |")
    lines += ["", *summary_lines(report["rows"])]
    lines += [
        "",
        f"The collided episodes: the mean forward command over the last {LOOKBACK} steps up to the first colliding one "
        "(share of full speed; mean over the episodes), and in how many the expert held control at any of those steps.",
        "",
        "| version | own | base | alone |",
        "|---|---|---|---|",
    ]
    for row in report["rows"]:
        cells = [_before(row.get(way)) for way in WAYS]
        lines.append(f"| v{row['number']:04d} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def summary_lines(rows: list[dict[str, Any]]) -> list[str]:
    """Per way, over the fine-tuned versions (v0000 left out): the median takeover share and collisions, and over all
    their collided episodes pooled, how many had the expert in control in the steps before and the mean speed."""
    import statistics

    lines = []
    for way in WAYS:
        outcomes = [row[way] for row in rows if row["number"] > 0 and row.get(way)]
        if not outcomes:
            continue
        shares = [o["takeover_share"] for o in outcomes]
        hits = [o["collisions"] for o in outcomes]
        handed = [h for o in outcomes for h in o["handed_over_before"]]
        speeds = [v for o in outcomes for v in o["speed_before"]]
        peaks = [r for o in outcomes for r in o.get("peak_fear_ratio", []) if r is not None and math.isfinite(r)]
        lines.append(
            f"- {way}, {len(outcomes)} fine-tuned versions: takeover median {100 * statistics.median(shares):.0f}% "
            f"({100 * min(shares):.0f}-{100 * max(shares):.0f}%), collisions median {statistics.median(hits):g}/"
            f"{outcomes[0]['episodes']} ({min(hits)}-{max(hits)}); of their {len(handed)} collided episodes, "
            f"{sum(handed)} with the expert in control in the {LOOKBACK} steps before"
            + (f", mean speed then {sum(speeds) / len(speeds):.2f} of full" if speeds else "")
            + (
                f", peak F/τ then median {statistics.median(peaks):.2f} ({sum(r >= 1 for r in peaks)} at ≥ 1)"
                if peaks
                else ""
            )
            + "."
        )
    return lines


def _before(outcome: dict[str, Any] | None) -> str:
    if outcome is None or not outcome.get("speed_before"):
        return "-"
    speeds, handed = outcome["speed_before"], outcome["handed_over_before"]
    return f"speed {sum(speeds) / len(speeds):.2f}, expert {sum(handed)}/{len(handed)}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0] if __doc__ else None)
    parser.add_argument("versions", type=Path, help="A session's versions folder (v0000, v0001, ...).")
    parser.add_argument("--only", type=int, nargs="*", default=None, help="Version numbers (default: all).")
    parser.add_argument("--sim", default="ugv")
    parser.add_argument("--scenario", default="3")
    parser.add_argument("--episodes", type=int, default=None, help="Default: the promotion check's (tests: fewer).")
    parser.add_argument("--max-steps", type=int, default=None, help="Default: the promotion check's.")
    parser.add_argument(
        "--set", dest="gate", action="append", default=[], help="gate.KEY=VALUE over every gate driven (repeatable)."
    )
    parser.add_argument("--out", type=Path, required=True, help="Folder for report.md and report.json.")
    parser.add_argument("--rerender", action="store_true", help="Only write --out's report.md again from its json.")
    args = parser.parse_args(argv)
    if args.rerender:
        if not (args.out / "report.json").is_file():
            print(f"error: no report.json in {args.out}", file=sys.stderr)
            return 2
        (args.out / "report.md").write_text(render(json.loads((args.out / "report.json").read_text())))
        return 0
    from core.promotion import PromotionConfig
    from core.sage.config import parse_gate_settings
    from core.versions import VersionStore
    from experiments.live_session import current_commit

    try:
        if any(not pair.startswith("gate.") for pair in args.gate):
            raise ValueError("only gate.KEY=VALUE settings are taken")
        gate_settings = parse_gate_settings([pair.removeprefix("gate.") for pair in args.gate])
    except ValueError as exc:
        print(f"error: --set: {exc}", file=sys.stderr)
        return 2
    if not (args.versions / "v0000").is_dir():
        print(f"error: {args.versions} holds no v0000 (give a session's versions folder)", file=sys.stderr)
        return 2
    store = VersionStore(args.versions)
    numbers = [v.number for v in store.versions()]
    chosen = numbers if args.only is None else args.only
    unknown = sorted(set(chosen) - set(numbers))
    if unknown:
        print(f"error: no version {unknown} in {args.versions} (it holds {numbers})", file=sys.stderr)
        return 2
    import torch

    torch.set_num_threads(1)
    check = PromotionConfig()
    cfg = PromotionConfig(episodes=args.episodes or check.episodes, max_steps=args.max_steps or check.max_steps)
    command = "python -m experiments.gate_swap " + " ".join(shlex.quote(a) for a in (argv or sys.argv[1:]))
    report: dict[str, Any] = {
        "command": command,
        "commit": current_commit(),
        "versions_root": str(args.versions),
        "sim": args.sim,
        "scenario": args.scenario,
        "seed": cfg.seed,
        "episodes": cfg.episodes,
        "max_steps": cfg.max_steps,
        "gate_settings": gate_settings,
        "rows": [],
    }
    base = store.get(0).path
    for number in chosen:
        path = store.get(number).path
        row: dict[str, Any] = {"number": number}
        for way in WAYS if number else ("own", "alone"):  # v0000's own gate is the base's
            try:
                o = drive(
                    path, base, way, cfg.episodes, cfg.seed, cfg.max_steps, args.sim, args.scenario, gate_settings
                )
            except ValueError as exc:  # e.g. a gate setting that changes fear on bounds measured without it
                print(f"error: v{number:04d} {way}: {exc}", file=sys.stderr)
                return 1
            row[way] = {**vars(o), "mover_collisions": o.mover_collisions}
            print(
                f"v{number:04d} {way}: {o.takeover_share:.0%} handed over, {o.collisions} collisions "
                f"({o.mover_collisions} with a mover)",
                flush=True,
            )
        report["rows"].append(row)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "report.json").write_text(json.dumps(report, indent=2) + "\n")
    (args.out / "report.md").write_text(render(report))
    print(render(report))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
