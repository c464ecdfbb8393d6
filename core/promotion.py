"""Safety-gated promotion of fine-tuned versions: a new version drives only after it has earned it.

A fine-tuning round publishes a *candidate* version. Before it may drive, the worker evaluates it headless on
the session's scenario, with its SAGE gate and the scripted expert, on fixed seeds, beside the version it would
replace (the incumbent: the latest promoted version, evaluated on the very same seeds, so the comparison is
paired). :func:`decide` promotes it only if it is no worse on both counts that matter to a supervisor:

- episodes with a safety violation (collisions): candidate <= incumbent;
- takeover rate (how often the gate hands control back): candidate <= incumbent + ``takeover_margin``.

Otherwise the version is kept on disk, marked with the reason, and never offered to the loop by the follower.
The verdict is ``promotion.json`` in the version's folder (written atomically); ``v0000``, the policy the
operator chose to deploy, is promoted by definition.

Live, a promoted version is watched (:class:`LiveWatch`): if over its first ``window`` episodes it collides in
more episodes, or asks for help clearly more often, than the version it replaced did live, it is rolled back.

Nothing here imports a simulator: the evaluator receives a picklable ``make_env`` (the app passes
``functools.partial(sims.make, name, ...)``), so it runs in the worker's process.
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym

PROMOTION_FILE = "promotion.json"


@dataclass(frozen=True)
class PromotionConfig:
    """How a candidate version is evaluated and judged before it may drive."""

    episodes: int = 5
    """Evaluation episodes per version (the same seeds for candidate and incumbent)."""
    seed: int = 7_000_000
    """Seed of the first evaluation episode (episode i uses ``seed + i``); apart from training seeds."""
    max_steps: int | None = 600
    """Cut an evaluation episode after this many steps (None: the simulator's own time limit)."""
    takeover_margin: float = 0.0
    """How much higher the candidate's takeover rate may be than the incumbent's (0: no worse at all)."""
    live_window: int = 5
    """Episodes a newly deployed version drives live before :class:`LiveWatch` judges it."""
    live_takeover_margin: float = 0.10
    """Live takeover rates are noisy (a person decides when to take over): roll back only beyond this margin."""

    def __post_init__(self) -> None:
        if self.episodes < 1 or self.live_window < 1:
            raise ValueError("episodes >= 1 and live_window >= 1 are needed")
        if self.takeover_margin < 0 or self.live_takeover_margin < 0:
            raise ValueError("takeover margins must be >= 0")


@dataclass
class Evaluation:
    """One version's headless record on the evaluation seeds."""

    episodes: int
    violation_episodes: int
    """Episodes with at least one safety violation (a collision on every built-in simulator)."""
    takeover_rate: float
    """Steps under expert control / all steps, over all evaluation episodes."""
    success_rate: float
    steps: int
    seconds: float
    seeds: list[int] = field(default_factory=list)

    @property
    def violation_rate(self) -> float:
        return self.violation_episodes / max(self.episodes, 1)

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Evaluation:
        return cls(**{k: data[k] for k in cls.__dataclass_fields__ if k in data})


@dataclass(frozen=True)
class Decision:
    promoted: bool
    reason: str


Evaluator = Callable[[Path, "PromotionConfig"], Evaluation]
"""Evaluates a version folder headless (the worker calls it; it must be picklable: a partial of a module-level
function such as :func:`evaluate_version`)."""


def decide(candidate: Evaluation, incumbent: Evaluation, cfg: PromotionConfig) -> Decision:
    """Promote only a candidate no worse than the incumbent on violations and on takeover rate."""
    if candidate.violation_episodes > incumbent.violation_episodes:
        return Decision(
            False,
            f"collided in {candidate.violation_episodes}/{candidate.episodes} evaluation episodes, "
            f"the version in control in {incumbent.violation_episodes}/{incumbent.episodes}",
        )
    if candidate.takeover_rate > incumbent.takeover_rate + cfg.takeover_margin + 1e-12:
        return Decision(
            False,
            f"asked for help on {candidate.takeover_rate:.0%} of steps, "
            f"the version in control on {incumbent.takeover_rate:.0%}",
        )
    return Decision(
        True,
        f"no worse than the version in control: collisions {candidate.violation_episodes} vs "
        f"{incumbent.violation_episodes}, takeover {candidate.takeover_rate:.0%} vs {incumbent.takeover_rate:.0%}",
    )


def evaluate_version(
    path: Path, cfg: PromotionConfig, *, make_env: Callable[[], gym.Env[Any, Any]], hold_steps: int | None = None
) -> Evaluation:
    """Run ``path`` (a version folder or checkpoint) with its gate and the scripted expert on the fixed seeds."""
    from core.agents import load_agent
    from core.experts import ScriptedExpert
    from core.loop import Gate, NoGate, Runner, StepRecord

    started = time.perf_counter()
    agent = load_agent(path)
    gate: Gate = NoGate()
    if agent.has_world_model:
        gate = agent.make_gate() if hold_steps is None else agent.make_gate(hold_steps=hold_steps)
    env = make_env()
    violations = takeovers = steps = successes = 0
    try:
        runner = Runner(env, agent.policy, gate, ScriptedExpert(), seed=cfg.seed, deterministic=True)
        violated: list[bool] = [False]

        def watch(record: StepRecord) -> None:
            violated[0] = violated[0] or record.violation

        runner.step_listeners.append(watch)
        for _ in range(cfg.episodes):
            violated[0] = False
            summary = runner.run_episode(max_steps=cfg.max_steps)
            collided = violated[0] or _flag(summary.metrics.get("collision"))
            violations += int(collided)
            successes += int(_flag(summary.metrics.get("success")))
            takeovers += summary.takeovers
            steps += summary.steps
    finally:
        env.close()
    return Evaluation(
        episodes=cfg.episodes,
        violation_episodes=violations,
        takeover_rate=takeovers / max(steps, 1),
        success_rate=successes / cfg.episodes,
        steps=steps,
        seconds=round(time.perf_counter() - started, 3),
        seeds=[cfg.seed + i for i in range(cfg.episodes)],
    )


def _flag(value: Any) -> bool:
    if value is None:
        return False
    try:
        number = float(value)
    except (TypeError, ValueError):
        return bool(value)
    return not math.isnan(number) and number > 0


# -- verdicts on disk ---------------------------------------------------------------------------------------------
def read_verdict(version_dir: Path) -> dict[str, Any] | None:
    """The version's ``promotion.json`` (None when it has not been judged, or the file is unreadable)."""
    try:
        data = json.loads((Path(version_dir) / PROMOTION_FILE).read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def write_verdict(version_dir: Path, verdict: dict[str, Any]) -> None:
    """Write ``promotion.json`` atomically (a reader sees the old verdict or the new one, never half)."""
    target = Path(version_dir) / PROMOTION_FILE
    tmp = target.with_name(f".{PROMOTION_FILE}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps({**verdict, "at": time.time()}, indent=2, sort_keys=True))
    os.replace(tmp, target)


def is_promoted(version_dir: Path, number: int) -> bool:
    """``v0000`` always; any other version only with a verdict that promoted it (and was not rolled back)."""
    if number == 0:
        return True
    verdict = read_verdict(version_dir)
    return bool(verdict and verdict.get("promoted") and not verdict.get("rolled_back"))


# -- live watch ---------------------------------------------------------------------------------------------------
@dataclass
class _Live:
    collisions: list[bool] = field(default_factory=list)
    takeover_rates: list[float] = field(default_factory=list)


class LiveWatch:
    """Judges a deployed version on its first ``live_window`` live episodes against the version it replaced.

    ``record`` is fed every finished live episode with the version that drove it; ``deployed`` says which
    version replaced which. After the window, :meth:`record` returns a rollback reason when the new version
    collided in more of its episodes than its predecessor did in its last ``live_window`` live episodes (or, with
    no live record of the predecessor, than its evaluation's violation rate allows), or when its mean takeover
    rate is higher by more than ``live_takeover_margin``. Each version is judged once."""

    def __init__(self, cfg: PromotionConfig | None = None) -> None:
        self.cfg = cfg or PromotionConfig()
        self._live: dict[int, _Live] = {}
        self._predecessor: dict[int, int] = {}
        self._evaluations: dict[int, Evaluation] = {}
        self._judged: set[int] = set()

    def deployed(self, number: int, replaced: int | None, evaluation: Evaluation | None = None) -> None:
        """``number`` now drives in place of ``replaced``; ``evaluation``: the replaced version's headless record,
        the reference when it has no live record of its own."""
        if replaced is None or replaced == number:
            return
        if number not in self._judged:
            self._predecessor[number] = replaced
        if evaluation is not None:
            self._evaluations[replaced] = evaluation

    def note_evaluation(self, number: int, evaluation: Evaluation) -> None:
        self._evaluations[number] = evaluation

    def record(self, number: int, collided: bool, takeover_rate: float) -> str | None:
        live = self._live.setdefault(number, _Live())
        live.collisions.append(bool(collided))
        live.takeover_rates.append(float(takeover_rate) if math.isfinite(takeover_rate) else 0.0)
        previous = self._predecessor.get(number)
        window = self.cfg.live_window
        if previous is None or number in self._judged or len(live.collisions) < window:
            return None
        self._judged.add(number)
        mine = _rates(live.collisions[:window], live.takeover_rates[:window])
        before = self._live.get(previous)
        if before is not None and len(before.collisions) >= window:
            theirs = _rates(before.collisions[-window:], before.takeover_rates[-window:])
            source = "live"
        elif previous in self._evaluations:
            ev = self._evaluations[previous]
            theirs = (ev.violation_rate, ev.takeover_rate)
            source = "evaluation"
        else:
            return None
        if mine[0] > theirs[0] + 1e-12:
            return (
                f"v{number:04d} collided in {mine[0]:.0%} of its first {window} live episodes, "
                f"v{previous:04d} in {theirs[0]:.0%} ({source})"
            )
        if mine[1] > theirs[1] + self.cfg.live_takeover_margin:
            return (
                f"v{number:04d} asked for help on {mine[1]:.0%} of steps over its first {window} live episodes, "
                f"v{previous:04d} on {theirs[1]:.0%} ({source})"
            )
        return None

    def predecessor(self, number: int) -> int | None:
        return self._predecessor.get(number)


def _rates(collisions: Sequence[bool], takeover_rates: Sequence[float]) -> tuple[float, float]:
    return sum(collisions) / len(collisions), sum(takeover_rates) / len(takeover_rates)
