"""Does a live dashboard session make the policy better alone? (issue #62: "a session of five minutes of takeovers
on UGV 3 promotes a version that does better alone")

A headless stand-in for a person at the dashboard. It builds the dashboard's own loop object,
:class:`app.live.LiveLoop` (the one ``sage serve`` builds, minus the web server, the viser scene view and the page),
with the dashboard's env factory (:func:`app.server.make_env`), policy loader (:func:`app.policies.load_policy`), an
idle operator console and a session store, and its fine-tuning settings as ``sage serve`` passes them
(:class:`app.versions.FinetuneSettings` with :class:`core.finetune.FinetuneConfig` and
:class:`core.promotion.PromotionConfig` at their defaults, the rounds' sampling seeded with the session seed). So the
same :class:`core.worker.FinetuneService` worker process learns from the recorded session in the background, judges
every version before it may drive and publishes it, and the loop takes promoted versions at episode boundaries and
watches them live, all as on the dashboard. The expert mode is ``scripted``: the scripted expert answers every gate
firing in place of the person. The loop runs at wall-clock rate (``--speed``, 1.0 as on the dashboard by default)
for ``--steps`` steps of simulated driving (3000 = five minutes at the UGV's 0.1 s step), or until ``--wall-cap``
seconds have passed.

Then the version in control when the session ends and ``v0000`` (the policy deployed) drive ALONE (no gate, no
expert, deterministic) on the same ``--alone-episodes`` seeds of the session's scenario and of an unseen one of the
same kind (UGV 4 for UGV 3), through the cycles study's own measurement (:func:`studies.cycles.drive_alone_rates`, one
seed at a time so that the outcomes pair episode by episode). The report (``--out`` folder: ``report.md`` and
``report.json``, command and commit at the top) lists the versions published with the promotion rule's verdict, the
takeover share over the session in 1-minute bins of simulated time, and alone success of v0 against the final
version with 95% Wilson intervals and an exact paired test (McNemar's, on the seeds where exactly one succeeded).

    python -m experiments.live_session --seed 0 --out docs/notes/live_session/s0

Not a unit test: about 5 minutes of driving plus the alone episodes (``tests/experiments/test_live_session.py``
runs it on a small budget).
"""

from __future__ import annotations

import argparse
import json
import math
import shlex
import subprocess
import sys
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from core.dotted import Section, route_settings

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_POLICY = "policies/ugv-default"
ALONE_SEED = 9_000_000
"""The cycles study's first policy-alone seed (studies.cycles.CyclesConfig.alone_seed): the same situations."""
BIN_SECONDS = 60.0


@dataclass(frozen=True)
class SessionPlan:
    """One headless live session and its alone evaluation."""

    seed: int = 0
    """The session's episode seeds (``LiveConfig.seed``) and the rounds' sampling seed (``FinetuneConfig.seed``)."""
    steps: int = 3000
    """Steps of simulated driving (3000: five minutes at the UGV's 0.1 s)."""
    wall_cap: float = 1200.0
    """Seconds of wall clock after which the session ends whatever the steps driven."""
    speed: float = 1.0
    """The dashboard's speed multiplier (1.0: real time, as a person drives)."""
    sim: str = "ugv"
    scenario: str = "3"
    unseen: str = "4"
    policy: str = DEFAULT_POLICY
    alone_episodes: int = 20
    alone_seed: int = ALONE_SEED
    alone_max_steps: int | None = None
    """Cut each alone episode here (None: the scenario's own time limit, as the cycles study)."""
    finetune_settings: tuple[str, ...] = ()
    """``key=value`` edits of the live FinetuneConfig (none for the measured runs)."""
    learner_settings: tuple[str, ...] = ()
    """``key=value`` edits of the fine-tuning rounds' learner (:class:`core.sage.config.AgentConfig` field paths,
    ``fear_regularisation=false``, ``gate.horizon=5``), applied after SAGE's switches
    (``FinetuneConfig.overrides``). They reach the fine-tuned versions only, their gate included (a version's gate
    is built from its checkpoint's configuration); ``v0000`` is the policy deployed, as it was trained."""


SET_SECTIONS: dict[str, Section] = {
    "finetune": Section("finetune"),
    "learner": Section("learner"),
    "world_model": Section("learner", "world_model_config."),
    "gate": Section("learner", "gate."),
}
"""The ``--set`` sections this experiment takes: ``finetune.`` (the rounds' FinetuneConfig), ``learner.`` and
``world_model.`` (the rounds' learner, as ``sage cycles`` reads them) and ``gate.`` (the fine-tuned versions' gate,
the learner's ``gate.`` fields)."""


@dataclass
class SessionLog:
    """What the stand-in saw of the session, step by step (a listener on the loop's runner)."""

    takeover: list[bool] = field(default_factory=list)
    version: list[int] = field(default_factory=list)
    episodes: list[dict[str, Any]] = field(default_factory=list)


def current_commit() -> str:
    out = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True)
    return out.stdout.strip() or "unknown"


def split_set(pairs: list[str]) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """``--set`` pairs as (FinetuneConfig settings, learner overrides), by :data:`SET_SECTIONS`; a pair of another
    section or not of the form ``section.key=value`` is a ValueError naming the sections taken."""
    routed = route_settings(pairs, SET_SECTIONS)
    return tuple(routed.get("finetune", [])), tuple(routed.get("learner", []))


def round_config(plan: SessionPlan) -> Any:
    """The rounds' :class:`core.finetune.FinetuneConfig`: the defaults, seeded with the session seed, the plan's
    settings and learner overrides. Each is checked here (a ValueError names the bad one), so that a typo is one line
    before the session, not a worker that fails minutes into it."""
    from core.finetune import FinetuneConfig, adaptation_config
    from core.sage.config import apply_overrides

    rounds = FinetuneConfig(seed=plan.seed, overrides=plan.learner_settings).with_settings(plan.finetune_settings)
    if plan.learner_settings:
        from core.agents import load_checkpoint
        from core.sage.config import from_dict

        # on the configuration the rounds will edit (the policy's, with SAGE's switches), as the Finetuner does
        trained = from_dict(load_checkpoint(plan.policy)["agent_config"])
        apply_overrides(adaptation_config(trained) if rounds.adapt_as_sage else trained, list(plan.learner_settings))
    return rounds


# -- the live session ---------------------------------------------------------------------------------------------
def run_session(plan: SessionPlan, work: Path, say: Any = print) -> dict[str, Any]:
    """Drive the dashboard's loop headless with its fine-tuning worker; returns the session's record."""
    import numpy as np
    import torch

    from app.live import FinetuneSettings, LiveConfig, LiveLoop
    from app.operator import OperatorConsole
    from app.policies import load_policy
    from app.server import make_env
    from core.agents import warm_gate_kernels
    from core.promotion import PromotionConfig
    from core.sessions import SessionStore

    # the live loop samples the policy (Runner(deterministic=False), as the dashboard builds it) from the global
    # generators: seeded, a session repeats up to the worker's timing (when a version arrives is wall-clock)
    torch.manual_seed(plan.seed)
    np.random.seed(plan.seed)
    warm_gate_kernels([plan.policy])  # as `sage serve` does before its loop starts (a first compile takes seconds)
    store = SessionStore(work / "sessions")
    rounds = round_config(plan)
    settings = FinetuneSettings(work / "finetune", rounds, promotion=PromotionConfig())
    config = LiveConfig(
        sim=plan.sim,
        scenario=plan.scenario,
        policy=plan.policy,
        expert_mode="scripted",
        speed=plan.speed,
        seed=plan.seed,
    )
    loop = LiveLoop(
        config,
        env_factory=make_env,
        policy_loader=load_policy,
        console=OperatorConsole(),
        publish=lambda text: None,
        store=store,
        finetune=settings,
    )
    world = loop.world
    if world.versions is None:
        loop.stop()
        raise RuntimeError(f"the dashboard started no fine-tuning worker: {loop.last_error}")
    log = SessionLog()
    done = threading.Event()

    def on_step(record: Any) -> None:
        log.takeover.append(bool(record.takeover))
        log.version.append(int(world.version or 0))
        if len(log.takeover) >= plan.steps:
            done.set()

    def on_episode(summary: Any) -> None:
        log.episodes.append(
            {
                "episode": summary.episode,
                "version": world.version,
                "steps": summary.steps,
                "takeovers": summary.takeovers,
                "success": bool(summary.metrics.get("success", False)),
                "collision": bool(summary.metrics.get("collision", False)),
                "reason": summary.reason,
            }
        )

    world.runner.step_listeners.append(on_step)
    world.runner.episode_listeners.append(on_episode)
    started = time.monotonic()
    loop.start()
    say(f"session {world.session_id}: driving {plan.steps} steps at speed {plan.speed} (cap {plan.wall_cap:.0f} s)")
    next_report = started + 60.0
    while not done.wait(1.0):
        now = time.monotonic()
        if now - started > plan.wall_cap:
            say(f"wall-clock cap reached after {len(log.takeover)} steps")
            break
        if now >= next_report:
            status = world.versions.status([])
            say(
                f"  {now - started:.0f} s: {len(log.takeover)} steps, v{world.version or 0:04d} in control, "
                f"{len(status['versions']) - 1} published; worker: {status['phase']}"
            )
            next_report = now + 60.0
    wall = time.monotonic() - started
    status = world.versions.status(list(world.episode_log))
    step_ms = sorted(1000 * cost for cost in loop.step_costs)
    in_control = int(world.version or 0)
    versions_root = settings.runs / str(world.session_id) / "versions"
    loop.stop(worker_timeout=30.0)
    return {
        "session": world.session_id,
        "steps": len(log.takeover),
        "wall_seconds": round(wall, 1),
        "step_ms_p50_last_200": round(step_ms[len(step_ms) // 2], 2) if step_ms else None,
        "episodes": log.episodes,
        "in_control": in_control,
        "versions_root": str(versions_root),
        "worker": {k: status.get(k) for k in ("phase", "error", "starts", "restarts", "last_rollback")},
        "rounds": status.get("rounds", []),
        "finetune_config": asdict(rounds),
        "promotion_config": asdict(settings.promotion),
        "log": log,
    }


def takeover_bins(log: SessionLog, dt: float, bin_seconds: float = BIN_SECONDS) -> list[dict[str, Any]]:
    """The takeover share over the session in bins of ``bin_seconds`` of simulated time (the last may be short)."""
    per_bin = max(1, round(bin_seconds / dt))
    rows = []
    for start in range(0, len(log.takeover), per_bin):
        chunk = log.takeover[start : start + per_bin]
        versions = sorted(set(log.version[start : start + per_bin]))
        rows.append(
            {
                "minute": start // per_bin + 1,
                "steps": len(chunk),
                "takeover_share": sum(chunk) / len(chunk),
                "versions": versions,
            }
        )
    return rows


def version_rows(versions_root: Path) -> list[dict[str, Any]]:
    """Every version the worker published, with the promotion rule's verdict and reason."""
    from core.versions import VersionStore

    rows = []
    for version in VersionStore(versions_root).versions():
        metrics = version.metrics
        verdict = version.verdict() or {}
        rows.append(
            {
                "number": version.number,
                "parent": version.parent,
                "updates": metrics.get("updates"),
                "updates_planned": metrics.get("updates_planned"),
                "kept_update": metrics.get("kept_update"),
                "takeover_samples": metrics.get("takeover_samples"),
                "prior_steps": metrics.get("prior_steps"),
                "method": metrics.get("method"),
                "supervised_takeover": (verdict.get("evaluation") or {}).get("takeover_rate"),
                "supervised_collisions": (verdict.get("evaluation") or {}).get("violation_episodes"),
                "supervised_episodes": (verdict.get("evaluation") or {}).get("episodes"),
                "promoted": bool(verdict.get("promoted")),
                "may_drive": bool(verdict.get("promoted")) and not verdict.get("rolled_back"),
                "judged": "promoted" in verdict,
                "reason": verdict.get("reason", "not judged when the session ended"),
                "rolled_back": bool(verdict.get("rolled_back")),
                "rollback_reason": verdict.get("rollback_reason"),
            }
        )
    return rows


# -- alone ----------------------------------------------------------------------------------------------------------
def alone_outcomes(plan: SessionPlan, path: Path, scenario: str) -> dict[str, Any]:
    """The version at ``path`` alone on ``plan.alone_episodes`` seeds of ``scenario``, episode by episode, through
    the cycles study's own measurement (one seed a call: its episode i runs seed ``alone_seed + i`` either way)."""
    from studies.cycles import drive_alone_rates
    from studies.envs import env_factory

    make_env = env_factory(plan.sim)
    success: list[bool] = []
    collision: list[bool] = []
    for i in range(plan.alone_episodes):
        rates = drive_alone_rates(path, make_env, scenario, 1, plan.alone_seed + i, plan.alone_max_steps)
        success.append(rates["success"] > 0)
        collision.append(rates["collision"] > 0)
    return {"scenario": scenario, "episodes": plan.alone_episodes, "success": success, "collision": collision}


def mcnemar_exact(ours: list[bool], theirs: list[bool]) -> dict[str, Any]:
    """Exact McNemar test on paired outcomes: b seeds where only ``ours`` succeeded, c where only ``theirs`` did;
    the two-sided p of b against Binomial(b + c, 1/2)."""
    b = sum(1 for a, z in zip(ours, theirs, strict=True) if a and not z)
    c = sum(1 for a, z in zip(ours, theirs, strict=True) if z and not a)
    n = b + c
    if n == 0:
        return {"only_ours": b, "only_theirs": c, "p_two_sided": 1.0}
    tail = sum(math.comb(n, k) for k in range(min(b, c) + 1)) / 2**n
    return {"only_ours": b, "only_theirs": c, "p_two_sided": min(1.0, 2 * tail)}


def compare(final: dict[str, Any], base: dict[str, Any]) -> dict[str, Any]:
    """Alone success of the final version against v0 on the same seeds: Wilson intervals, the paired test, and
    whether the final one does better by the rule in docs/notes/adaptation_probe.md ("live session")."""
    from core.metrics import wilson_interval

    n = final["episodes"]
    ours, theirs = sum(final["success"]), sum(base["success"])
    ci_ours, ci_theirs = wilson_interval(ours, n), wilson_interval(theirs, n)
    paired = mcnemar_exact(final["success"], base["success"])
    apart = ci_ours[0] > ci_theirs[1]
    paired_better = paired["p_two_sided"] < 0.05 and paired["only_ours"] > paired["only_theirs"]
    return {
        "scenario": final["scenario"],
        "episodes": n,
        "final_success": ours,
        "v0_success": theirs,
        "final_interval": list(ci_ours),
        "v0_interval": list(ci_theirs),
        "final_collisions": sum(final["collision"]),
        "v0_collisions": sum(base["collision"]),
        **paired,
        "intervals_apart": apart,
        "better": apart or paired_better,
    }


def supervised_summary(versions: list[dict[str, Any]]) -> dict[str, Any]:
    """The promotion check's supervised episodes (each version with its own gate and the expert), the fine-tuned
    versions judged against ``v0000``: how often their gate handed over (median and range of the takeover share)
    and in how many episodes they collided (median and range). None where nothing of the kind was judged."""
    import statistics

    def judged(v: dict[str, Any]) -> bool:
        return v.get("supervised_takeover") is not None and v.get("supervised_collisions") is not None

    base = next((v for v in versions if v["number"] == 0 and judged(v)), None)
    tuned = [v for v in versions if v["number"] > 0 and judged(v)]
    shares = [float(v["supervised_takeover"]) for v in tuned]
    hits = [int(v["supervised_collisions"]) for v in tuned]
    return {
        "v0_takeover": None if base is None else base["supervised_takeover"],
        "v0_collisions": None if base is None else base["supervised_collisions"],
        "episodes": None if base is None else base.get("supervised_episodes"),
        "fine_tuned_judged": len(tuned),
        "takeover_median": statistics.median(shares) if shares else None,
        "takeover_range": [min(shares), max(shares)] if shares else None,
        "collisions_median": statistics.median(hits) if hits else None,
        "collisions_range": [min(hits), max(hits)] if hits else None,
    }


def version_fields(versions: list[dict[str, Any]]) -> dict[str, Any]:
    return {
        "versions": versions,
        "published": len(versions) - 1,
        "promoted": [v["number"] for v in versions if v["number"] > 0 and v["promoted"]],
        "rolled_back": [v["number"] for v in versions if v["rolled_back"]],
        "supervised": supervised_summary(versions),
    }


def target_met(final: int, versions: list[dict[str, Any]], comparisons: list[dict[str, Any]]) -> bool:
    """The rule: the version in control at the end is fine-tuned, passed the promotion check, and does better alone
    on the session's scenario (the first comparison)."""
    passed = any(v["number"] == final and v["promoted"] for v in versions)
    return final != 0 and passed and bool(comparisons) and bool(comparisons[0]["better"])


def rerender(folder: Path) -> dict[str, Any]:
    """Read ``folder/report.json`` again, its versions' verdicts from the session's versions folder when it is still
    there, and write both files anew (the run's command and commit stay; ``rendered_at`` names this commit)."""
    report = json.loads((folder / "report.json").read_text())
    root = Path(report["versions_root"])
    report.update(version_fields(version_rows(root) if root.is_dir() else report["versions"]))
    report["target_met"] = target_met(report["in_control"], report["versions"], report["comparison"])
    report["rendered_at"] = current_commit()
    (folder / "report.json").write_text(json.dumps(report, indent=2, default=str) + "\n")
    (folder / "report.md").write_text(render(report))
    return report


# -- the report -----------------------------------------------------------------------------------------------------
def experiment(plan: SessionPlan, out: Path, work: Path, command: str, say: Any = print) -> dict[str, Any]:
    """The session, the alone evaluation and the report (``out/report.json``, ``out/report.md``)."""
    import sims
    from core.versions import VersionStore

    dt = sims.descriptor(plan.sim).dt
    commit = current_commit()  # the code that runs: read before the session, not after the minutes it takes
    session = run_session(plan, work, say)
    log: SessionLog = session.pop("log")
    versions = version_rows(Path(session["versions_root"]))
    store = VersionStore(session["versions_root"])
    final = session["in_control"]
    say(f"session over: {session['steps']} steps in {session['wall_seconds']} s, v{final:04d} in control")
    alone: dict[str, Any] = {}
    comparisons = []
    for scenario in (plan.scenario, plan.unseen):
        if not scenario:
            continue
        say(f"alone on {plan.sim} {scenario}: v0000 and v{final:04d}, {plan.alone_episodes} episodes each")
        base = alone_outcomes(plan, store.get(0).path, scenario)
        ours = base if final == 0 else alone_outcomes(plan, store.get(final).path, scenario)
        alone[scenario] = {"v0": base, "final": ours}
        comparisons.append(compare(ours, base))
    # post-hoc, not in the rule: the newest version the worker published, promoted or not (did the promotion check
    # hold back a version that was better alone?)
    latest = max(v["number"] for v in versions)
    posthoc = []
    if latest not in (0, final):
        for scenario in (plan.scenario, plan.unseen):
            if not scenario:
                continue
            say(f"post-hoc: v{latest:04d} (the newest published) alone on {plan.sim} {scenario}")
            newest = alone_outcomes(plan, store.get(latest).path, scenario)
            alone[scenario]["latest"] = newest
            posthoc.append(compare(newest, alone[scenario]["v0"]))
    met = target_met(final, versions, comparisons)
    report = {
        "command": command,
        "commit": commit,
        "plan": asdict(plan),
        "dt": dt,
        **session,
        "steps_per_second": round(session["steps"] / max(session["wall_seconds"], 1e-9), 2),
        **version_fields(versions),
        "takeover_bins": takeover_bins(log, dt),
        "alone": alone,
        "comparison": comparisons,
        "latest_published": latest,
        "latest_comparison": posthoc,
        "target_met": met,
    }
    out.mkdir(parents=True, exist_ok=True)
    (out / "report.json").write_text(json.dumps(report, indent=2, default=str) + "\n")
    (out / "report.md").write_text(render(report))
    return report


def _pct(value: float) -> str:
    return f"{100 * value:.0f}%"


def render(report: dict[str, Any]) -> str:
    plan = report["plan"]
    lines = [
        f"# Live session, {plan['sim']} {plan['scenario']}, seed {plan['seed']}",
        "",
        f"Command: `{report['command']}`  ",
        f"Commit: `{report['commit']}`"
        + (f" (report rendered again at `{report['rendered_at']}`)" if report.get("rendered_at") else ""),
        "",
        f"The dashboard's loop (`app.live.LiveLoop`, expert mode scripted) from `{plan['policy']}` with its fine-tuning"
        f" worker: {report['steps']} steps of simulated driving ({report['steps'] * report['dt'] / 60:.1f} min) in "
        f"{report['wall_seconds']} s of wall clock ({report['steps_per_second']} steps/s at speed {plan['speed']}), "
        f"{len(report['episodes'])} episodes finished. Versions published: {report['published']}; promoted: "
        f"{', '.join(f'v{n:04d}' for n in report['promoted']) or 'none'}; rolled back live: "
        f"{', '.join(f'v{n:04d}' for n in report.get('rolled_back', [])) or 'none'}; in control at the end: "
        f"v{report['in_control']:04d}. Worker at the end: {report['worker']['phase']}"
        + (f" (error: {report['worker']['error']})" if report["worker"].get("error") else "")
        + ".",
        "",
        "## Versions",
        "",
        "Supervised: the version with its own gate and the scripted expert on the promotion check's episodes.",
        "",
        "| version | parent | updates (kept at) | takeover samples | supervised: takeover, collisions | promoted "
        "| the promotion rule's reason |",
        "|---|---|---|---|---|---|---|",
    ]
    for v in report["versions"]:
        reason = str(v["reason"]).replace("|", "/")
        if v["rolled_back"]:
            reason += f"; rolled back: {v['rollback_reason']}"
        parent = "-" if v["parent"] is None else f"v{v['parent']:04d}"
        updates = "-" if v["updates"] is None else f"{v['updates']} ({v['kept_update']})"
        samples = "-" if v["takeover_samples"] is None else str(v["takeover_samples"])
        promoted = "yes" if v["promoted"] else ("no" if v["judged"] else "not judged")
        if v["number"] > 0 and v["rolled_back"]:
            promoted += ", rolled back"
        share, hits = v.get("supervised_takeover"), v.get("supervised_collisions")
        supervised = "-" if share is None else f"{_pct(share)}, {hits}/{v.get('supervised_episodes')}"
        cells = [f"v{v['number']:04d}", parent, updates, samples, supervised, promoted, reason]
        lines.append("| " + " | ".join(cells) + " |")
    summary = report.get("supervised") or supervised_summary(report["versions"])
    if summary["fine_tuned_judged"] and summary["v0_takeover"] is not None:
        low, high = summary["takeover_range"]
        few, many = summary["collisions_range"]
        lines += [
            "",
            f"The {summary['fine_tuned_judged']} fine-tuned versions judged, supervised: takeover median "
            f"{_pct(summary['takeover_median'])} (range {_pct(low)}-{_pct(high)}), collisions median "
            f"{summary['collisions_median']:g}/{summary['episodes']} (range {few}-{many}); v0000: "
            f"{_pct(summary['v0_takeover'])}, {summary['v0_collisions']}/{summary['episodes']}.",
        ]
    if report["plan"].get("learner_settings"):
        lines += ["", f"Learner overrides of the rounds: `{', '.join(report['plan']['learner_settings'])}`."]
    lines += ["", "## Takeover share over the session (1-minute bins of simulated time)", ""]
    lines += ["| minute | steps | takeover share | versions driving |", "|---|---|---|---|"]
    for row in report["takeover_bins"]:
        driving = ", ".join(f"v{n:04d}" for n in row["versions"])
        lines.append(f"| {row['minute']} | {row['steps']} | {_pct(row['takeover_share'])} | {driving} |")
    header = [
        "| scenario | v0000 success | final success | v0000 collisions | final collisions | only final / only v0 "
        "| McNemar p | intervals apart | better |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    lines += [
        "",
        f"## Alone (no gate, no expert, deterministic): v0000 against v{report['in_control']:04d}",
        "",
        f"Seeds {plan['alone_seed']}..{plan['alone_seed'] + plan['alone_episodes'] - 1}, the same for both; "
        "95% Wilson intervals; exact McNemar test on the seeds where only one of the two succeeded.",
        "",
        *header,
    ]
    lines += _comparison_rows(report["comparison"])
    if report.get("latest_comparison"):
        lines += [
            "",
            f"Post-hoc, not in the rule: v{report['latest_published']:04d}, the newest version published (promoted or "
            'not), alone on the same seeds against v0000 (its "final" columns).',
            "",
            *header,
            *_comparison_rows(report["latest_comparison"]),
        ]
    lines += [
        "",
        f"Target (a promoted version in control that does better alone on {plan['sim']} {plan['scenario']}, by the rule"
        f" in docs/notes/adaptation_probe.md): **{'met' if report['target_met'] else 'not met'}** for this seed.",
        "",
    ]
    return "\n".join(lines)


def _comparison_rows(comparisons: list[dict[str, Any]]) -> list[str]:
    lines = []
    for c in comparisons:
        lo0, hi0 = c["v0_interval"]
        lo1, hi1 = c["final_interval"]
        lines.append(
            f"| {c['scenario']} | {c['v0_success']}/{c['episodes']} [{_pct(lo0)}, {_pct(hi0)}] "
            f"| {c['final_success']}/{c['episodes']} [{_pct(lo1)}, {_pct(hi1)}] | {c['v0_collisions']} "
            f"| {c['final_collisions']} | {c['only_ours']} / {c['only_theirs']} | {c['p_two_sided']:.3g} "
            f"| {'yes' if c['intervals_apart'] else 'no'} | {'yes' if c['better'] else 'no'} |"
        )
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0] if __doc__ else None)
    parser.add_argument("--seed", type=int, default=0, help="Session seed (episode seeds and the rounds' sampling).")
    parser.add_argument("--steps", type=int, default=3000, help="Steps of simulated driving (3000: 5 min on the UGV).")
    parser.add_argument("--wall-cap", type=float, default=1200.0, help="Seconds of wall clock at most.")
    parser.add_argument("--speed", type=float, default=1.0, help="The dashboard's speed multiplier (1: real time).")
    parser.add_argument("--scenario", default="3")
    parser.add_argument("--unseen", default="4", help="Scenario driven alone for transfer ('' for none).")
    parser.add_argument("--policy", default=DEFAULT_POLICY)
    parser.add_argument("--alone-episodes", type=int, default=20)
    parser.add_argument("--alone-max-steps", type=int, default=None)
    parser.add_argument(
        "--set",
        dest="settings",
        action="append",
        default=[],
        help="finetune.KEY=VALUE (the rounds), learner.KEY=VALUE / world_model.KEY=VALUE (the rounds' learner), "
        "gate.KEY=VALUE (the fine-tuned versions' gate); repeatable.",
    )
    parser.add_argument("--work", type=Path, default=None, help="Sessions and versions (default: runs/live-sSEED).")
    parser.add_argument("--out", type=Path, required=True, help="Folder for report.md and report.json.")
    parser.add_argument("--rerender", action="store_true", help="Only write --out's report again from its json.")
    args = parser.parse_args(argv)
    if args.rerender:
        if not (args.out / "report.json").is_file():
            print(f"error: no report.json in {args.out}", file=sys.stderr)
            return 2
        print(render(rerender(args.out)))
        return 0
    try:
        finetune_settings, learner_settings = split_set(args.settings)
    except ValueError as exc:
        print(f"error: --set {exc}", file=sys.stderr)
        return 2
    if args.steps < 1 or args.alone_episodes < 1 or not 0.1 <= args.speed <= 20.0:
        print("error: --steps and --alone-episodes must be >= 1, --speed in [0.1, 20]", file=sys.stderr)
        return 2
    if not Path(args.policy).exists():
        print(f"error: no policy at {args.policy!r}", file=sys.stderr)
        return 2
    work = args.work or Path("runs") / f"live-s{args.seed}"
    if (work / "sessions").exists():
        print(f"error: {work} already holds a session; choose another --work", file=sys.stderr)
        return 2
    plan = SessionPlan(
        seed=args.seed,
        steps=args.steps,
        wall_cap=args.wall_cap,
        speed=args.speed,
        scenario=args.scenario,
        unseen=args.unseen,
        policy=args.policy,
        alone_episodes=args.alone_episodes,
        alone_max_steps=args.alone_max_steps,
        finetune_settings=finetune_settings,
        learner_settings=learner_settings,
    )
    try:
        round_config(plan)
    except ValueError as exc:
        print(f"error: --set: {exc}", file=sys.stderr)
        return 2
    import torch

    torch.set_num_threads(1)
    command = "python -m experiments.live_session " + " ".join(shlex.quote(a) for a in (argv or sys.argv[1:]))
    try:
        report = experiment(plan, args.out, work, command)
    except (ValueError, RuntimeError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(render(report))
    return 0


if __name__ == "__main__":  # the worker is a spawned process: it imports this module, which must not run again
    raise SystemExit(main())
