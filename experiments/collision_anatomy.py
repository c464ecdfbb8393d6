"""Why do episodes with the gate and the scripted expert still end in a collision? (issue #60)

The policy with its own gate and the scripted expert on a ground (by default ``ugv-fields:train:2+``: train fields
with two or more movers; never a test seed), on the evaluation seeds. For every episode with a collision it reads the
last ``--window`` seconds before the first contact, step by step, and says:

- who drove at contact and in the window (the policy; the expert because fear was over τ, in the gate's hold, in
  its release hysteresis, or finishing its own manoeuvre: :func:`core.loop.takeover_cause`);
- when the gate first fired in the window (lead time in steps before contact), and how long the expert's last streak
  of control had lasted at contact, or how many steps the policy had driven since it was handed back;
- fear over τ over the window (its peak, and at 10, 5 and 1 steps before contact);
- the true time to contact with a mover at the first firing and the gap at contact (``conflict.report``; a gap well
  over zero at contact: a static obstacle);
- whether the scripted expert alone, from the start of the same seed, collides.

Each collision is put in one class: ``expert, late`` (the expert had the wheel at contact, its streak shorter than
``--enough`` seconds: the warning came late), ``expert, in time`` (it had the wheel at least that long and still hit),
``policy after hand-back`` (the expert drove in the window and handed back before contact), ``policy, fear over
τ_min only`` (the gate never fired in the window but fear reached τ_min) and ``policy, unforeseen`` (fear stayed
under τ_min). Prints a markdown report (command and commit at its top); ``--out FILE`` writes it there too.

    .venv/bin/python -m experiments.collision_anatomy [--run policies/ugv-default] [--scenario ugv-fields:train:2+] \
        [--episodes 200] [--window 2] [--enough 1] [--set gate.KEY=VALUE ...] [--out docs/notes/FILE.md]

Not a unit test: about 3 minutes of one core for 100 episodes.
"""

from __future__ import annotations

import argparse
import math
import subprocess
import sys
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from core.agents import load_agent
from core.experts import ExpertPolicy, ScriptedExpert
from core.loop import NoGate, Runner, StepRecord, takeover_cause
from studies.calibrate import EVAL_SEED

CLASSES = (
    "expert, late",
    "expert, in time",
    "policy after hand-back",
    "policy, fear over τ_min only",
    "policy, unforeseen",
)


@dataclass
class Step:
    """What one step of a gated episode leaves for the anatomy."""

    t: int
    driver: str  # "policy" or the takeover cause: fear, hold, hysteresis, manoeuvre
    fear: float
    threshold: float
    violation: bool
    ttc: float
    """The true time to contact with a mover (s) in the state the gate decided in (the step before's report)."""
    gap: float
    """The gap to the nearest mover (m) after the step."""


@dataclass
class Collision:
    """One episode's first collision, read over the window before it."""

    seed: int
    contact_t: int
    driver: str
    window_drivers: dict[str, int]
    first_fire_lead: int | None
    """Steps from the first firing in the window to contact (None: the gate did not fire in the window)."""
    expert_streak: int
    """Steps the expert had driven without a break up to contact (0: the policy drove at contact)."""
    since_hand_back: int | None
    """With the policy at contact: steps since the expert last drove (None: not in the window)."""
    ratio_peak: float
    ratio_at: dict[int, float]
    ttc_at_first_fire: float
    ttc_before: float
    """The true time to contact 1 s (10 steps) before contact, in the state decided in."""
    gap_at_contact: float
    tau_min_reached: bool
    expert_alone_collides: bool | None
    kind: str = ""


def classify(c: Collision, enough_steps: int) -> str:
    """The collision's class (:data:`CLASSES`)."""
    if c.driver != "policy":
        return CLASSES[0] if c.expert_streak < enough_steps else CLASSES[1]
    if c.since_hand_back is not None:
        return CLASSES[2]
    return CLASSES[3] if c.tau_min_reached else CLASSES[4]


def _tau_min(gate: Any) -> float:
    threshold = getattr(getattr(gate, "inner", gate), "threshold", None)
    return float(getattr(threshold, "tau_min", math.nan))


def read_collision(steps: Sequence[Step], seed: int, window: int, tau_min: float) -> Collision | None:
    """The anatomy of the episode's first collision (None: it had none)."""
    contact = next((i for i, s in enumerate(steps) if s.violation), None)
    if contact is None:
        return None
    seen = steps[max(0, contact - window + 1) : contact + 1]
    at = steps[contact]
    fired = [s for s in seen if s.driver == "fear"]
    streak = 0
    for s in reversed(steps[: contact + 1]):
        if s.driver == "policy":
            break
        streak += 1
    since = None
    if at.driver == "policy":
        last_expert = next((s for s in reversed(seen) if s.driver != "policy"), None)
        since = None if last_expert is None else at.t - last_expert.t

    def ratio(s: Step) -> float:
        ok = math.isfinite(s.fear) and math.isfinite(s.threshold) and s.threshold > 0
        return s.fear / s.threshold if ok else math.nan

    ratios = [ratio(s) for s in seen]
    ratio_at = {k: ratio(steps[contact - k]) if contact - k >= 0 else math.nan for k in (10, 5, 1, 0)}
    return Collision(
        seed=seed,
        contact_t=at.t,
        driver=at.driver,
        window_drivers=dict(Counter(s.driver for s in seen)),
        first_fire_lead=at.t - fired[0].t if fired else None,
        expert_streak=streak,
        since_hand_back=since,
        ratio_peak=max((r for r in ratios if math.isfinite(r)), default=math.nan),
        ratio_at=ratio_at,
        ttc_at_first_fire=fired[0].ttc if fired else math.nan,
        ttc_before=steps[contact - 10].ttc if contact >= 10 else math.nan,
        gap_at_contact=at.gap,
        tau_min_reached=any(math.isfinite(s.fear) and s.fear >= tau_min for s in seen),
        expert_alone_collides=None,
    )


def expert_alone_collides(make_env: Any, seed: int) -> bool:
    """Whether the scripted expert alone, from the start of episode seed ``seed``, collides."""
    env = make_env()
    try:
        runner = Runner(env, ExpertPolicy(env), NoGate(), None, seed=seed, deterministic=True)
        collided = [False]
        runner.step_listeners.append(lambda r: collided.__setitem__(0, collided[0] or r.violation))
        runner.run_episode()
    finally:
        env.close()
    return collided[0]


def anatomy(
    run: str | Path,
    scenario: str,
    episodes: int,
    *,
    window_s: float = 2.0,
    enough_s: float = 1.0,
    first_seed: int = EVAL_SEED,
    gate_settings: dict[str, Any] | None = None,
    counterfactual: bool = True,
) -> tuple[list[Collision], dict[str, float]]:
    """Gate + scripted expert over ``episodes`` of ``scenario``; the collisions' anatomy and the run's totals."""
    import sims

    descriptor = sims.descriptor("ugv")
    window = max(1, round(window_s / descriptor.dt))
    enough = max(1, round(enough_s / descriptor.dt))

    def make_env() -> Any:
        return descriptor.make(scenario, **{"conflict.report": True})

    agent = load_agent(run)
    gate = agent.make_gate(**(gate_settings or {}))
    tau_min = _tau_min(gate)
    env = make_env()
    steps: list[Step] = []

    before = [math.nan]  # the time to contact reported after the previous step: that of the state decided in

    def watch(r: StepRecord) -> None:
        cause = takeover_cause(r, gate)
        ttc = before[0] if r.t > 0 else math.nan
        before[0] = float(r.info.get("ttc", math.nan))
        gap = float(r.info.get("nearest_gap", math.nan))
        steps.append(Step(r.t, cause or "policy", r.fear, r.threshold, r.violation, ttc, gap))

    collisions: list[Collision] = []
    takeovers = total = 0
    try:
        runner = Runner(env, agent.policy, gate, ScriptedExpert(), seed=first_seed, deterministic=True)
        runner.step_listeners.append(watch)
        for i in range(episodes):
            steps.clear()
            summary = runner.run_episode()
            takeovers += summary.takeovers
            total += summary.steps
            c = read_collision(steps, first_seed + i, window, tau_min)
            if c is not None:
                collisions.append(c)
    finally:
        env.close()
    for c in collisions:
        if counterfactual:
            c.expert_alone_collides = expert_alone_collides(make_env, c.seed)
        c.kind = classify(c, enough)
    totals = {
        "episodes": float(episodes),
        "collisions": float(len(collisions)),
        "takeover": takeovers / max(total, 1),
        "window": float(window),
        "enough": float(enough),
        "tau_min": tau_min,
    }
    return collisions, totals


def _num(x: float | None, digits: int = 2) -> str:
    return "–" if x is None or not math.isfinite(x) else f"{x:.{digits}f}"


def render(collisions: Sequence[Collision], totals: dict[str, float], command: str, commit: str) -> str:
    """The report: a summary by class and one row per collision."""
    window, enough = int(totals["window"]), int(totals["enough"])
    lines = [
        f"Made by `{command}` at commit `{commit}`.",
        "",
        f"{int(totals['collisions'])} of {int(totals['episodes'])} episodes with a collision at "
        f"{100 * totals['takeover']:.0f}% takeover (gate + scripted expert); window {window} steps before contact, "
        f"'late' = the expert's streak at contact under {enough} steps; τ_min {_num(totals['tau_min'], 3)}.",
        "",
        "| class | collisions | expert alone also collides | median lead of the first firing (steps) |",
        "|---|---|---|---|",
    ]
    for kind in CLASSES:
        of = [c for c in collisions if c.kind == kind]
        alone = sum(bool(c.expert_alone_collides) for c in of)
        leads = [c.first_fire_lead for c in of if c.first_fire_lead is not None]
        lead = _num(float(np.median(leads)), 1) if leads else "–"
        lines.append(f"| {kind} | {len(of)} | {alone} | {lead} |")
    lines += [
        "",
        "| seed | contact step | class | driver at contact | drivers in the window | first firing, steps before "
        "| expert streak | policy steps since hand-back | fear/τ peak | fear/τ at -10, -5, -1, 0 | ttc at first firing "
        "(s) | ttc 1 s before contact (s) | gap at contact (m) | expert alone collides |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for c in collisions:
        drivers = ", ".join(f"{k} {v}" for k, v in sorted(c.window_drivers.items()))
        at = " / ".join(_num(c.ratio_at[k]) for k in (10, 5, 1, 0))
        alone_mark = "–" if c.expert_alone_collides is None else ("yes" if c.expert_alone_collides else "no")
        lead = "never" if c.first_fire_lead is None else str(c.first_fire_lead)
        since = "–" if c.since_hand_back is None else str(c.since_hand_back)
        lines.append(
            f"| {c.seed} | {c.contact_t} | {c.kind} | {c.driver} | {drivers} | {lead} | {c.expert_streak} | {since} "
            f"| {_num(c.ratio_peak)} | {at} | {_num(c.ttc_at_first_fire)} | {_num(c.ttc_before)} "
            f"| {_num(c.gap_at_contact)} | {alone_mark} |"
        )
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m experiments.collision_anatomy", description=__doc__.split("\n")[0])
    parser.add_argument("--run", default="policies/ugv-default")
    parser.add_argument("--scenario", default="ugv-fields:train:2+")
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--window", type=float, default=2.0, help="seconds before contact read (default 2)")
    parser.add_argument("--enough", type=float, default=1.0, help="an expert streak this long is not 'late' (s)")
    parser.add_argument("--set", action="append", default=[], metavar="gate.KEY=VALUE")
    parser.add_argument("--no-counterfactual", action="store_true", help="skip the expert-alone replays")
    parser.add_argument("--out", type=Path)
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error("--episodes must be at least 1")
    if ":test" in args.scenario:
        parser.error("diagnose on train ground only: a test scenario is measured, never read for a choice")
    from studies.generalisation import gate_settings_of

    try:
        settings = gate_settings_of(args.set, "ugv")
        collisions, totals = anatomy(
            args.run,
            args.scenario,
            args.episodes,
            window_s=args.window,
            enough_s=args.enough,
            gate_settings=settings,
            counterfactual=not args.no_counterfactual,
        )
    except (ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    command = "python -m experiments.collision_anatomy " + " ".join(argv if argv is not None else sys.argv[1:])
    text = render(collisions, totals, command.strip(), commit or "unknown")
    print(text)
    if args.out:
        args.out.write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
