"""Deployment / fine-tuning cycles, headless: the paper's continual-adaptation field test (Fig. field_test_1).

Each cycle deploys the current policy version for ``episodes_per_cycle`` episodes (or exactly ``steps_per_cycle``
environment steps) of the same scenario, on the one step loop (:class:`core.loop.Runner`) with its SAGE gate and the
scripted expert taking over when the gate fires; a session store records every step. Between cycles,
:meth:`core.finetune.Finetuner.round` (the very function the live server's background worker runs) learns from what
the session recorded (as fear-regularised SAGE whatever the base was trained as: the takeover segments through
value-weighted imitation, the agent's own transitions through the fear-regularised critic, the base policy's own
drives on its training scenarios beside them) and publishes the next version, which the runner takes at the episode
boundary. Every cycle drives the same situations (episode seeds ``seed, seed + 1, ...``), so cycles compare like
with like.

Supervised, the expert hides what the policy cannot do, so every cycle also measures the deployed version ALONE
(no gate, no expert; ``alone_episodes`` fixed seeds) on the cycle's scenario and on an unseen one of the same kind
(``unseen_scenario``: transfer, or forgetting).

The run folder holds ``sessions/`` (the recorded session: replayable in the dashboard), ``versions/`` (v0000 = the
deployed starting policy, then one version per round), ``cycles.json`` (per-episode rows, per-cycle table, rounds,
the policy-alone rows) and the figures drawn by :mod:`studies.cycles_figures`.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from core.agents import LoadedAgent, load_agent
from core.experts import CoachingExpert, ScriptedExpert
from core.finetune import FinetuneConfig, Finetuner, VersionStore, drive_alone
from core.loop import Gate, NoGate, Runner
from core.planners import PlannerExpert
from core.promotion import PromotionConfig, evaluate_version
from core.protocol import Expert, simulator
from core.sessions import SessionStore
from core.worker import judge

RESULT_FILE = "cycles.json"


@dataclass
class CyclesConfig:
    """A deploy → takeover → fine-tune study on one scenario."""

    sim: str
    scenario: str
    policy: str
    """Run folder or checkpoint deployed in the first cycle (``v0000``)."""
    cycles: int = 9
    """Deployment cycles (fine-tuning rounds happen between them: ``cycles - 1`` of them)."""
    episodes_per_cycle: int = 3
    """Episodes deployed per cycle (unless ``steps_per_cycle`` is set)."""
    steps_per_cycle: int | None = None
    """Deploy exactly this many environment steps a cycle (episodes of seeds ``seed, seed + 1, ...`` until the budget
    is spent, the last one cut at it), in place of ``episodes_per_cycle``: a budget in environment steps, the same
    for every method and every cycle, whatever their episodes' lengths."""
    alone_episodes: int = 10
    """Per cycle, episodes the deployed version drives ALONE (deterministic, no gate, no expert) on the cycle's
    scenario and on ``unseen_scenario``: whether the policy itself got better (its supervised success is the
    expert's too). Seeds ``alone_seed + i``, the same for every cycle and method. 0: none."""
    alone_seed: int = 9_000_000
    """Seed of the first policy-alone episode (apart from the deployment seeds)."""
    unseen_scenario: str | None = None
    """A scenario of the same kind never deployed in the cycles (transfer and forgetting; default:
    :func:`unseen_of` the scenario, e.g. UGV 4 for UGV 3; "" for none)."""
    seed: int = 0
    """Episode ``e`` of every cycle uses the seed ``seed + e``: each cycle meets the same situations."""
    deterministic: bool = True
    """Deploy the deterministic policy (its mean action), as a fielded policy runs; False samples it."""
    max_episode_steps: int | None = None
    """Cut episodes at this many steps (None: the scenario's time limit)."""
    expert: str = "scripted"
    """Who takes over when the gate fires: ``scripted``, the simulator's privileged expert (it knows where the movers
    will go), or a planner's name (``teb`` on the UGV: it decides from the robot's own sensing, as a person at the
    dashboard must)."""
    coach_share: float = 0.0
    """Coaching (:class:`core.experts.CoachingExpert`): on this share of the steps the agent drives, the scripted
    expert's action is recorded as a label and imitated, not executed. 0 (default): takeovers only, the paper's."""
    fine_tune: bool = True
    """Fine-tune between cycles; False deploys the first version throughout (the control: the same situations,
    gate and expert, no learning)."""
    promotion: PromotionConfig | None = None
    """Judge every fine-tuned version as the live worker does before it may drive (:mod:`core.promotion`: beside
    the version in control, on the cycle's scenario with gate and expert, on the promotion's own seeds): a
    version not promoted is not deployed, and the next round continues from the version in control. With
    ``regression_scenarios`` the version must also drive alone on those scenarios no worse than ``v0000`` (the
    regression test). None: every published version is deployed in the next cycle."""
    finetune: FinetuneConfig = field(default_factory=lambda: FinetuneConfig(min_steps=1, min_takeover_samples=0))
    """Each cycle is the unit of data the study chose, so its round runs whatever its size (the live worker's
    minimum-data rule guards rounds that nobody asked for)."""

    def __post_init__(self) -> None:
        if self.cycles < 1 or self.episodes_per_cycle < 1:
            raise ValueError("--cycles and --episodes-per-cycle must be at least 1")
        if self.steps_per_cycle is not None and self.steps_per_cycle < 1:
            raise ValueError("--steps-per-cycle must be at least 1")
        if self.alone_episodes < 0:
            raise ValueError("--alone-episodes must be at least 0")
        if not 0.0 <= self.coach_share <= 1.0:
            raise ValueError(f"--coach-share must be in [0, 1], got {self.coach_share}")
        problem = expert_problem(self.sim, self.expert, self.coach_share)
        if problem is not None:
            raise ValueError(f"--expert {self.expert}: {problem}")
        if self.unseen_scenario is None:
            self.unseen_scenario = unseen_of(self.sim, self.scenario)


def expert_problem(sim: str, expert: str, coach_share: float) -> str | None:
    """Why ``expert`` cannot take over in cycles on ``sim`` with ``coach_share`` (None: it can): an unknown planner,
    one for another simulator, or coaching, which is the scripted expert's."""
    if expert == "scripted":
        return None
    import sims  # noqa: F401 (registers the simulators' planners)
    from core.planners import checked_entry

    try:
        checked_entry(expert, sim)
    except ValueError as error:
        return str(error)
    if coach_share > 0:
        return "coaching (--coach-share, study.coach_share) is the scripted expert's: it needs --expert scripted"
    return None


#: A scenario of the same kind as each built-in one (two movers crossing the robot's path), for transfer.
UNSEEN: dict[tuple[str, str], str] = {("ugv", "3"): "4", ("ugv", "4"): "3"}


def unseen_of(sim: str, scenario: str) -> str:
    """The unseen scenario of the same kind as ``scenario`` ("" where none is known)."""
    return UNSEEN.get((sim, str(scenario)), "")


@dataclass
class CyclesResult:
    out: Path
    session: str
    episodes: list[dict[str, Any]]
    cycles: list[dict[str, Any]]
    rounds: list[dict[str, Any]]
    seconds: float
    alone: list[dict[str, Any]] = field(default_factory=list)
    """Per cycle and scenario, the deployed version alone: ``cycle``, ``version``, ``scenario``, ``seen``,
    ``episodes``, ``success``, ``collision``, ``steps``."""

    def as_dict(self) -> dict[str, Any]:
        return {
            "session": self.session,
            "episodes": self.episodes,
            "cycles": self.cycles,
            "rounds": self.rounds,
            "alone": self.alone,
            "seconds": round(self.seconds, 2),
        }


def gate_for(agent: LoadedAgent) -> Gate:
    """The SAGE gate on the agent's world model and policy (no gate when it trained no world model)."""
    return agent.make_gate() if agent.has_world_model else NoGate()


def _scene_without_rays(env: gym.Env[Any, Any]) -> Callable[[], dict[str, Any] | None]:
    def source() -> dict[str, Any] | None:
        scene = simulator(env).scene()
        return {k: v for k, v in scene.items() if k != "rays"}  # rays are redrawn live, not needed for paths

    return source


def _finite(value: Any) -> float | None:
    try:
        value = float(value)
    except (TypeError, ValueError):
        return None
    return value if math.isfinite(value) else None


def cycle_rows(episodes: list[dict[str, Any]], alone: list[dict[str, Any]] | None = None) -> list[dict[str, Any]]:
    """One row per cycle: takeover rate over all its steps, mean takeover events per episode, success and
    collision rates under supervision, mean fear, mean return; with ``alone``, the policy-alone success and
    collision rates on the cycle's scenario (``alone_*``) and on the unseen one (``unseen_*``; None without)."""
    by_cycle: dict[tuple[int, bool], dict[str, Any]] = {(int(a["cycle"]), bool(a["seen"])): a for a in alone or []}
    rows = []
    for cycle in sorted({int(e["cycle"]) for e in episodes}):
        group = [e for e in episodes if e["cycle"] == cycle]
        steps = sum(int(e["steps"]) for e in group)

        def mean(key: str, group: list[dict[str, Any]] = group) -> float | None:
            values = [v for v in (_finite(e.get(key)) for e in group) if v is not None]
            return float(np.mean(values)) if values else None

        rows.append(
            {
                "cycle": cycle,
                "version": group[0]["version"],
                "episodes": len(group),
                "steps": steps,
                "takeover_rate": sum(int(e["takeovers"]) for e in group) / max(steps, 1),
                "coached_rate": sum(int(e.get("coached", 0)) for e in group) / max(steps, 1),
                "takeover_events": mean("takeover_events"),
                "success": mean("success"),
                "collision": mean("collision"),
                "mean_fear": mean("mean_fear"),
                "return": mean("return"),
                "alone_success": by_cycle.get((cycle, True), {}).get("success"),
                "alone_collision": by_cycle.get((cycle, True), {}).get("collision"),
                "unseen_success": by_cycle.get((cycle, False), {}).get("success"),
                "unseen_collision": by_cycle.get((cycle, False), {}).get("collision"),
            }
        )
    return rows


def drive_alone_rates(
    path: Path,
    make_env: Callable[[str], gym.Env[Any, Any]],
    scenario: str,
    episodes: int,
    seed: int,
    max_steps: int | None,
) -> dict[str, Any]:
    """The version at ``path`` alone (deterministic, no gate, no expert) over ``episodes`` seeds of ``scenario``."""
    agent = load_agent(path)
    env = make_env(scenario)
    success = collision = steps = 0
    try:
        runner = Runner(env, agent.policy, NoGate(), ScriptedExpert(), seed=seed, deterministic=True)
        for _ in range(episodes):
            summary = runner.run_episode(max_steps)
            success += int(_flag(summary.metrics.get("success")))
            collision += int(_flag(summary.metrics.get("collision")))
            steps += summary.steps
    finally:
        env.close()
    return {"episodes": episodes, "success": success / episodes, "collision": collision / episodes, "steps": steps}


def _flag(value: Any) -> bool:
    number = _finite(value)
    return number is not None and number > 0


def format_cycle_table(rows: list[dict[str, Any]], rounds: list[dict[str, Any]] | None = None) -> str:
    """A Markdown table of the cycles (rates in %), with the fine-tuning round that followed each cycle: takeover,
    success and collision under supervision (gate and expert), then the version alone on the cycle's scenario and
    on the unseen one."""
    by_cycle = {int(r["after_cycle"]): r for r in rounds or [] if r.get("after_cycle") is not None}
    header = [
        "cycle",
        "version",
        "episodes",
        "takeover rate",
        "takeovers / ep",
        "success (supervised)",
        "collision (supervised)",
        "alone: success",
        "alone: collision",
        "unseen alone: success",
        "mean fear",
        "return",
        "then fine-tuned",
    ]
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]

    def pct(v: float | None) -> str:
        return "-" if v is None else f"{100 * v:.1f}%"

    def num(v: float | None, digits: int = 2) -> str:
        return "-" if v is None else f"{v:.{digits}f}"

    for row in rows:
        tuned = by_cycle.get(int(row["cycle"]))
        if tuned is None:
            then = "-"
        elif tuned.get("version") is None:
            then = f"no version ({tuned.get('reason')})"
        else:
            then = f"v{tuned['version']:04d}: {tuned['updates']} updates, {tuned['takeovers']} takeover samples"
            if tuned.get("coached"):
                then += f", {tuned['coached']} coached"
        lines.append(
            "| "
            + " | ".join(
                [
                    str(row["cycle"]),
                    f"v{row['version']:04d}",
                    str(row["episodes"]),
                    pct(row["takeover_rate"]),
                    num(row["takeover_events"], 1),
                    pct(row["success"]),
                    pct(row["collision"]),
                    pct(row.get("alone_success")),
                    pct(row.get("alone_collision")),
                    pct(row.get("unseen_success")),
                    num(row["mean_fear"], 3),
                    num(row["return"], 1),
                    then,
                ]
            )
            + " |"
        )
    return "\n".join(lines)


def run_cycles(
    cfg: CyclesConfig,
    out: Path,
    make_env: Callable[[str], gym.Env[Any, Any]],
    progress: Callable[[str], None] | None = None,
) -> CyclesResult:
    """Deploy, record, fine-tune, swap, ``cfg.cycles`` times. See the module docstring."""
    say = progress or (lambda text: None)
    started = time.time()
    out = Path(out)
    if (out / RESULT_FILE).exists() or (out / "versions").exists():
        raise FileExistsError(f"{out} already holds a cycles run; choose another --out")
    out.mkdir(parents=True, exist_ok=True)
    versions = VersionStore(out / "versions")
    v0 = versions.ensure_initial(cfg.policy)
    agent = load_agent(v0.path)
    env = make_env(cfg.scenario)
    try:
        obs_dim = int(np.prod(env.observation_space.shape or (0,)))
        act_dim = int(np.prod(env.action_space.shape or (1,)))
        if (agent.meta.obs_dim, agent.meta.act_dim) != (obs_dim, act_dim):
            raise ValueError(
                f"{cfg.policy} takes {agent.meta.obs_dim} observations / {agent.meta.act_dim} actions, "
                f"{cfg.sim} scenario {cfg.scenario} has {obs_dim} / {act_dim}"
            )
        store = SessionStore(out / "sessions")
        import sims

        dt = sims.descriptor(cfg.sim).dt
        writer = store.create(
            cfg.sim,
            scenario=cfg.scenario,
            policy=str(cfg.policy),
            expert_mode="scripted" if cfg.expert == "scripted" else f"planner:{cfg.expert}",
            meta={"study": "cycles", "dt": dt, "seed": cfg.seed, "episodes_per_cycle": cfg.episodes_per_cycle},
            scene_source=_scene_without_rays(env),
        )
        expert: Expert = ScriptedExpert() if cfg.expert == "scripted" else PlannerExpert(cfg.expert, cfg.sim)
        if cfg.coach_share > 0:
            expert = CoachingExpert(expert, cfg.coach_share, seed=cfg.seed)
        runner = Runner(env, agent.policy, gate_for(agent), expert, seed=cfg.seed, deterministic=cfg.deterministic)
        writer.attach(runner)
        prior = functools.partial(drive_alone, make_env=make_env, max_steps=cfg.max_episode_steps)
        # the version alone on the cycle's own scenario: FinetuneConfig.practice_episodes (off by default)
        practice = functools.partial(
            drive_alone, make_env=make_env, scenarios=[cfg.scenario], max_steps=cfg.max_episode_steps
        )
        finetuner = Finetuner(versions, store, writer.session_id, cfg.finetune, prior=prior, practice=practice)
        episodes: list[dict[str, Any]] = []
        rounds: list[dict[str, Any]] = []
        alone: list[dict[str, Any]] = []
        measured: dict[tuple[int, str], dict[str, Any]] = {}
        version = v0.number
        try:
            for cycle in range(1, cfg.cycles + 1):
                runner.reseed(cfg.seed - (runner.episode + 1))  # episode e of every cycle gets seed + e
                if cfg.steps_per_cycle is None:
                    for _ in range(cfg.episodes_per_cycle):
                        summary = runner.run_episode(cfg.max_episode_steps)
                        episodes.append({**summary.as_row(), "cycle": cycle, "version": version})
                else:
                    left = cfg.steps_per_cycle
                    while left > 0:
                        limit = left if cfg.max_episode_steps is None else min(left, cfg.max_episode_steps)
                        summary = runner.run_episode(limit)
                        episodes.append({**summary.as_row(), "cycle": cycle, "version": version})
                        left -= max(summary.steps, 1)
                alone += _alone(cfg, cycle, version, versions.get(version).path, make_env, measured)
                cycle_row = cycle_rows([e for e in episodes if e["cycle"] == cycle], alone)[0]
                say(f"cycle {cycle}/{cfg.cycles} (v{version:04d}): " + _cycle_line(cycle_row))
                if cycle == cfg.cycles or not cfg.fine_tune:
                    continue
                writer.flush()
                result = finetuner.round()
                rounds.append({**result.as_dict(), "after_cycle": cycle})
                if result.version is None:
                    say(f"  fine-tuning published nothing: {result.reason}")
                    continue
                say(
                    f"  fine-tuned {result.version.name}: {result.updates} updates ({result.skipped} skipped), "
                    f"{result.ingested.takeovers} takeover samples"
                    + (f", {result.ingested.coached} coached" if result.ingested.coached else "")
                    + f", {result.seconds:.1f} s"
                )
                if cfg.promotion is not None:
                    evaluator = functools.partial(
                        evaluate_version, make_env=functools.partial(make_env, cfg.scenario), scenario_env=make_env
                    )
                    verdict = judge(versions, result.version.number, evaluator, cfg.promotion)
                    rounds[-1]["promotion"] = {"promoted": verdict["promoted"], "reason": verdict["reason"]}
                    if not verdict["promoted"]:
                        say(f"  {result.version.name} not promoted ({verdict['reason']}): v{version:04d} drives on")
                        continue
                agent = load_agent(result.version.path)
                # the runner is between episodes: the new policy and its gate start with the next one
                runner.set_policy_at_boundary(agent.policy, gate_for(agent))
                version = result.version.number
        finally:
            writer.close()
    finally:
        env.close()
    result_rows = CyclesResult(
        out, writer.session_id, episodes, cycle_rows(episodes, alone), rounds, time.time() - started, alone
    )
    payload = {"config": _config_dict(cfg), "method": finetuner.method, **result_rows.as_dict()}
    (out / RESULT_FILE).write_text(json.dumps(payload, indent=2, default=_json_default) + "\n")
    return result_rows


def _alone(
    cfg: CyclesConfig,
    cycle: int,
    version: int,
    path: Path,
    make_env: Callable[[str], gym.Env[Any, Any]],
    measured: dict[tuple[int, str], dict[str, Any]],
) -> list[dict[str, Any]]:
    """The cycle's version alone on the cycle's scenario and the unseen one (each version measured once)."""
    if cfg.alone_episodes == 0:
        return []
    rows = []
    for scenario, seen in ((cfg.scenario, True), (cfg.unseen_scenario or "", False)):
        if not scenario:
            continue
        key = (version, scenario)
        if key not in measured:
            measured[key] = drive_alone_rates(
                path, make_env, scenario, cfg.alone_episodes, cfg.alone_seed, cfg.max_episode_steps
            )
        rows.append({"cycle": cycle, "version": version, "scenario": scenario, "seen": seen, **measured[key]})
    return rows


def _cycle_line(row: dict[str, Any]) -> str:
    success, collision = row["success"] or 0.0, row["collision"] or 0.0
    line = f"takeover {100 * row['takeover_rate']:.1f}%, success {100 * success:.0f}%, collision {100 * collision:.0f}%"
    if row.get("coached_rate"):
        line += f", coached {100 * row['coached_rate']:.1f}%"
    if row.get("alone_success") is not None:
        line += f"; alone: success {100 * row['alone_success']:.0f}%"
    if row.get("unseen_success") is not None:
        line += f", unseen {100 * row['unseen_success']:.0f}%"
    return line


def _config_dict(cfg: CyclesConfig) -> dict[str, Any]:
    return dataclasses.asdict(cfg)


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return str(value)


def read_cycles(out: Path) -> dict[str, Any]:
    """The ``cycles.json`` of a finished run folder (a clear error when there is none)."""
    path = Path(out) / RESULT_FILE
    if not path.is_file():
        raise FileNotFoundError(f"{out} holds no {RESULT_FILE}: not a finished `sage cycles` run")
    return json.loads(path.read_text())
