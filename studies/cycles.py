"""Deployment / fine-tuning cycles, headless: the paper's continual-adaptation field test (Fig. field_test_1).

Each cycle deploys the current policy version for ``episodes_per_cycle`` episodes of the same scenario, on the one
step loop (:class:`core.loop.Runner`) with its SAGE gate and the scripted expert taking over when the gate fires;
a session store records every step. Between cycles, :meth:`core.finetune.Finetuner.round` (the very function the
live server's background worker runs) learns from what the session recorded (the takeover segments through
value-weighted imitation, the agent's own transitions through the fear-regularised critic) and publishes the next
version, which the runner takes at the episode boundary. Every cycle drives the same ``episodes_per_cycle``
situations (episode seeds ``seed, seed + 1, ...``), so cycles compare like with like.

The run folder holds ``sessions/`` (the recorded session: replayable in the dashboard), ``versions/`` (v0000 = the
deployed starting policy, then one version per round), ``cycles.json`` (per-episode rows, per-cycle table, rounds)
and the figures drawn by :mod:`studies.cycles_figures`.
"""

from __future__ import annotations

import dataclasses
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
from core.experts import ScriptedExpert
from core.finetune import FinetuneConfig, Finetuner, VersionStore
from core.loop import Gate, NoGate, Runner
from core.protocol import simulator
from core.sessions import SessionStore

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
    seed: int = 0
    """Episode ``e`` of every cycle uses the seed ``seed + e``: each cycle meets the same situations."""
    deterministic: bool = True
    """Deploy the deterministic policy (its mean action), as a fielded policy runs; False samples it."""
    max_episode_steps: int | None = None
    """Cut episodes at this many steps (None: the scenario's time limit)."""
    fine_tune: bool = True
    """Fine-tune between cycles; False deploys the first version throughout (the control: the same situations,
    gate and expert, no learning)."""
    finetune: FinetuneConfig = field(default_factory=lambda: FinetuneConfig(min_steps=1, min_takeover_samples=0))
    """Each cycle is the unit of data the study chose, so its round runs whatever its size (the live worker's
    minimum-data rule guards rounds that nobody asked for)."""

    def __post_init__(self) -> None:
        if self.cycles < 1 or self.episodes_per_cycle < 1:
            raise ValueError("--cycles and --episodes-per-cycle must be at least 1")


@dataclass
class CyclesResult:
    out: Path
    session: str
    episodes: list[dict[str, Any]]
    cycles: list[dict[str, Any]]
    rounds: list[dict[str, Any]]
    seconds: float

    def as_dict(self) -> dict[str, Any]:
        return {
            "session": self.session,
            "episodes": self.episodes,
            "cycles": self.cycles,
            "rounds": self.rounds,
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


def cycle_rows(episodes: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per cycle: takeover rate over all its steps, mean takeover events per episode, success and
    collision rates, mean fear, mean return."""
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
                "takeover_events": mean("takeover_events"),
                "success": mean("success"),
                "collision": mean("collision"),
                "mean_fear": mean("mean_fear"),
                "return": mean("return"),
            }
        )
    return rows


def format_cycle_table(rows: list[dict[str, Any]], rounds: list[dict[str, Any]] | None = None) -> str:
    """A Markdown table of the cycles (rates in %), with the fine-tuning round that followed each cycle."""
    by_cycle = {int(r["after_cycle"]): r for r in rounds or [] if r.get("after_cycle") is not None}
    header = [
        "cycle",
        "version",
        "episodes",
        "takeover rate",
        "takeovers / ep",
        "success",
        "collision",
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
            expert_mode="scripted",
            meta={"study": "cycles", "dt": dt, "seed": cfg.seed, "episodes_per_cycle": cfg.episodes_per_cycle},
            scene_source=_scene_without_rays(env),
        )
        runner = Runner(
            env, agent.policy, gate_for(agent), ScriptedExpert(), seed=cfg.seed, deterministic=cfg.deterministic
        )
        writer.attach(runner)
        finetuner = Finetuner(versions, store, writer.session_id, cfg.finetune)
        episodes: list[dict[str, Any]] = []
        rounds: list[dict[str, Any]] = []
        version = v0.number
        try:
            for cycle in range(1, cfg.cycles + 1):
                runner.reseed(cfg.seed - (runner.episode + 1))  # episode e of every cycle gets seed + e
                for _ in range(cfg.episodes_per_cycle):
                    summary = runner.run_episode(cfg.max_episode_steps)
                    episodes.append({**summary.as_row(), "cycle": cycle, "version": version})
                cycle_row = cycle_rows([e for e in episodes if e["cycle"] == cycle])[0]
                say(f"cycle {cycle}/{cfg.cycles} (v{version:04d}): " + _cycle_line(cycle_row))
                if cycle == cfg.cycles or not cfg.fine_tune:
                    continue
                writer.flush()
                result = finetuner.round()
                rounds.append({**result.as_dict(), "after_cycle": cycle})
                if result.version is None:
                    say(f"  fine-tuning published nothing: {result.reason}")
                    continue
                agent = load_agent(result.version.path)
                # the runner is between episodes: the new policy and its gate start with the next one
                runner.set_policy_at_boundary(agent.policy, gate_for(agent))
                version = result.version.number
                say(
                    f"  fine-tuned v{version:04d}: {result.updates} updates ({result.skipped} skipped), "
                    f"{result.ingested.takeovers} takeover samples, {result.seconds:.1f} s"
                )
        finally:
            writer.close()
    finally:
        env.close()
    result_rows = CyclesResult(out, writer.session_id, episodes, cycle_rows(episodes), rounds, time.time() - started)
    payload = {"config": _config_dict(cfg), **result_rows.as_dict()}
    (out / RESULT_FILE).write_text(json.dumps(payload, indent=2, default=_json_default) + "\n")
    return result_rows


def _cycle_line(row: dict[str, Any]) -> str:
    success, collision = row["success"] or 0.0, row["collision"] or 0.0
    return f"takeover {100 * row['takeover_rate']:.1f}%, success {100 * success:.0f}%, collision {100 * collision:.0f}%"


def _config_dict(cfg: CyclesConfig) -> dict[str, Any]:
    data = dataclasses.asdict(cfg)
    data["finetune"] = dataclasses.asdict(cfg.finetune)
    return data


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
