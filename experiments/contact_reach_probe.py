"""Does imagined contact past the gate's horizon show before the collisions it was meant for? (issue #60)

Replays chosen episodes of gate + scripted expert (``--run`` with ``gate.contact_horizon`` set, e.g.
``runs/ugv-contact-horizon-10``) on ``ugv-fields:train:2+`` (train fields only) and prints, for each of the last
``--window`` steps before the first contact, fear over τ, the true time to contact, and the share of ensemble members
imagining contact within the learned horizon (steps 1 to ``gate.horizon``) and past it (the most at any later step):
whether the longer reach saw the mover coming, or the world model's imagined scans never reached a contact floor.
With ``gate.contact_extrapolation`` set, also the fastest closing the gate read from the real scans after the step
(:meth:`core.sage.gate.SageGate.closing_rate`, range units a step; – where it reads none).

    .venv/bin/python -m experiments.contact_reach_probe --run runs/ugv-contact-horizon-10 --seeds 3000001,3000057

Not a unit test: a few seconds an episode.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from core.agents import load_agent
from core.experts import ScriptedExpert
from core.loop import Runner, StepRecord, takeover_cause


def probe(run: str, scenario: str, seed: int, window: int) -> list[dict[str, Any]]:
    """The last ``window`` steps before the first contact of episode ``seed`` (none: the episode did not collide)."""
    import sims

    agent = load_agent(run)
    gate = agent.make_gate()
    horizon = gate.cfg.horizon
    env = sims.descriptor("ugv").make(scenario, **{"conflict.report": True})
    rows: list[dict[str, Any]] = []
    before = [math.nan]

    def watch(r: StepRecord) -> None:
        kernel = gate.kernel()
        costs = kernel.last_member_costs() if kernel is not None else np.zeros((1, 1))
        contact = costs >= 1.0  # set to exactly 1 where a member's imagined scan is at a contact floor
        within = float(contact[:horizon].mean(1).max())
        past = float(contact[horizon:].mean(1).max()) if len(contact) > horizon else math.nan
        ttc = before[0] if r.t > 0 else math.nan
        before[0] = float(r.info.get("ttc", math.nan))
        ratio = r.fear / r.threshold if r.threshold else math.nan
        rate = gate.closing_rate() if gate.cfg.contact_extrapolation else None
        rows.append(
            {
                "t": r.t,
                "driver": takeover_cause(r, gate) or "policy",
                "fear/τ": ratio,
                "ttc": ttc,
                "within": within,
                "past": past,
                "closing": math.nan if rate is None else float(rate.min()),
                "violation": bool(r.violation),
            }
        )

    try:
        runner = Runner(env, agent.policy, gate, ScriptedExpert(), seed=seed, deterministic=True)
        runner.step_listeners.append(watch)
        runner.run_episode()
    finally:
        env.close()
    hit = next((i for i, row in enumerate(rows) if row["violation"]), None)
    return [] if hit is None else rows[max(0, hit - window + 1) : hit + 1]


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", default="runs/ugv-contact-horizon-10")
    parser.add_argument("--scenario", default="ugv-fields:train:2+")
    parser.add_argument("--seeds", required=True, help="episode seeds, a comma list")
    parser.add_argument("--window", type=int, default=15)
    args = parser.parse_args(argv)
    if ":test" in args.scenario:
        parser.error("a test ground is not probed: train fields only")
    for seed in (int(s) for s in args.seeds.split(",")):
        rows = probe(args.run, args.scenario, seed, args.window)
        print(f"\nseed {seed}: " + ("no collision" if not rows else f"contact at step {rows[-1]['t']}"))
        if rows:
            closing = any(math.isfinite(row["closing"]) for row in rows)
            extra = (" fastest closing |", "---|") if closing else ("", "")
            print("| step | driver | fear/τ | ttc (s) | members in contact ≤ horizon | past it |" + extra[0])
            print("|---|---|---|---|---|---|" + extra[1])
            for row in rows:
                rate = f" {row['closing']:.3f} |" if closing else ""
                print(
                    f"| {row['t']} | {row['driver']} | {row['fear/τ']:.2f} | {row['ttc']:.2f} | {row['within']:.1f} "
                    f"| {row['past']:.1f} |" + rate
                )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
