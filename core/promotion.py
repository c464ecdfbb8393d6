"""Safety-gated promotion of fine-tuned versions: a new version drives only after it has earned it.

A fine-tuning round publishes a *candidate* version. Before it may drive, the worker evaluates it headless on
the session's scenario, with its SAGE gate and the scripted expert, on ``episodes`` fixed seeds, beside the version
it would replace (the incumbent: the latest promoted version, evaluated on the very same seeds, so the comparison is
paired episode by episode). :func:`decide` promotes it only if it passes these tests:

- collisions: the candidate collides in no more evaluation episodes than the incumbent (ties pass);
- progress, a paired sign test: the candidate "loses" an episode in which the incumbent reached the goal on the same
  seed and it did not, "wins" the reverse; it fails with more losses than wins + ``success_slack``. Without it a
  version that stands still, never handed over and never colliding, passes the two tests around it (measured: a
  cycles line whose versions stalled from the fifth cycle, supervised success 0 and takeover 0-4%; evaluations
  recorded before the per-episode outcomes were kept skip it);
- takeover, a paired sign test: over the episodes, the candidate "wins" one where its takeover share is lower than
  the incumbent's on the same seed by more than ``takeover_margin``, "loses" one where it is higher by more than
  that; it passes with at least as many wins as losses (an evaluation recorded before the per-episode shares were
  kept falls back to the overall rates: candidate <= incumbent + ``takeover_margin``).

What the rule needs and what it risks (exact binomial, episodes independent; :func:`collision_pass_probability`
and :func:`takeover_pass_probability` compute these, ``tests/core/test_promotion.py`` checks them at the default of
15 episodes a version):

- takeover: a candidate that asks for less help than the incumbent in 70% of paired episodes (and more in 30%)
  passes in 95% of rounds; one that asks for more in 70% of them passes in 5%. With 5 episodes (the default
  before) these were 84% and 16%: a version worse by that margin slipped through one round in six;
- progress: a candidate that reaches the goal as often as the incumbent (90% of episodes each, independently)
  passes in 94% of rounds (80% each: 88%); one that reaches it in 60% against 90% passes in 18%; one that never
  does, in none. ``success_slack`` 0 would refuse more than a third of equal versions (38% at 90%);
- collisions: with the incumbent colliding in 30% of episodes, a candidate at 10% passes in 95% of rounds, one at
  50% in 17%. Ties pass, so a version no worse is never held back on collisions alone; the price is that a worse
  one gets past this test alone about one round in six at this rate. Where collisions under supervision are rare
  (the gate prevents most), the test cannot tell versions apart at all and the takeover test decides.

A regression test (off by default: ``regression_scenarios``) guards what fine-tuning may forget: the candidate drives
ALONE (deterministic, no gate, no expert) on ``regression_episodes`` fixed seeds of each of those scenarios (the base
policy's own, e.g. UGV 1-2 for the UGV default) and fails if it succeeds in fewer of them, on any scenario, than
``v0000`` (the policy the operator deployed) on the same seeds. A version that drives worse alone on the base's own
scenarios than the base does is a regression, whatever it gained under supervision. With
``regression_against="control"`` the reference is the version in control instead: on the session's own scenario, a
version that drives worse alone than the line already does is not deployed, so the line's alone driving on those seeds
never steps back (each version is driven alone once; its record is kept in its verdict). ``supervised=False`` skips
the supervised tests above, so that the regression test can be measured alone.

Otherwise the version is kept on disk, marked with the reason, and never offered to the loop by the follower, and
the next round continues from the version in control (:func:`core.finetune.line_head`), not from the rejected
one. The verdict is ``promotion.json`` in the version's folder (written atomically); ``v0000``, the policy the
operator chose to deploy, is promoted by definition.

Live, a promoted version is watched (:class:`LiveWatch`): if over its first ``window`` episodes it collides in
more episodes, or asks for help clearly more often, than the version it replaced did live, or reaches the goal in none
of them where that version reached it in at least half, it is rolled back.

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
from typing import Any, Literal

import gymnasium as gym

from core.protocol import EpisodeSummary

PROMOTION_FILE = "promotion.json"

REGRESSION_REFERENCES = ("base", "control")
"""The values of :attr:`PromotionConfig.regression_against`."""


@dataclass(frozen=True)
class PromotionConfig:
    """How a candidate version is evaluated and judged before it may drive."""

    episodes: int = 15
    """Evaluation episodes per version (the same seeds for candidate and incumbent): 15 makes the takeover sign test
    pass a version better in 70% of paired episodes in 95% of rounds and one worse in 70% of them in 5% (the
    module docstring; 5 episodes gave 84% and 16%)."""
    seed: int = 7_000_000
    """Seed of the first evaluation episode (episode i uses ``seed + i``); apart from training seeds."""
    max_steps: int | None = 600
    """Cut an evaluation episode after this many steps (None: the simulator's own time limit)."""
    takeover_margin: float = 0.0
    """A paired episode counts as a win or a loss only when the two takeover shares differ by more than this (a
    share of steps; 0: any difference counts)."""
    success_slack: int = 2
    """The progress test's allowance: the candidate fails with more paired episodes lost (the version in control
    reached the goal, it did not) than won + this (the module docstring states what 2 risks at 15 episodes)."""
    live_window: int = 5
    """Episodes a newly deployed version drives live before :class:`LiveWatch` judges it."""
    live_takeover_margin: float = 0.10
    """Live takeover rates are noisy (a person decides when to take over): roll back only beyond this margin."""
    supervised: bool = True
    """Run the supervised tests (collisions and takeover, with gate and expert, beside the version in control);
    False leaves the regression test alone to decide (it then needs ``regression_scenarios``)."""
    regression_scenarios: tuple[str, ...] = ()
    """Scenarios the candidate drives ALONE before it may drive (the regression test: it must succeed in as many of
    each one's episodes as ``v0000`` on the same seeds); empty: no regression test."""
    regression_episodes: int = 10
    """Episodes alone per regression scenario (seeds ``regression_seed + i``, the same for every version)."""
    regression_seed: int = 8_000_000
    """Seed of the first regression episode; apart from the evaluation, training and policy-alone seeds."""
    regression_against: Literal["base", "control"] = "base"
    """Whom the regression test compares the candidate with, alone on the same seeds: ``base``, ``v0000`` (the policy
    the operator deployed: nothing it drove alone is lost); ``control``, the version in control (the latest promoted
    before the candidate): a version that drives worse alone than the line already does, on the session's own
    scenario say, is not deployed, so that what the line drives alone on those seeds never steps back."""

    def __post_init__(self) -> None:
        if self.episodes < 1 or self.live_window < 1:
            raise ValueError("episodes >= 1 and live_window >= 1 are needed")
        if self.regression_episodes < 1:
            raise ValueError("regression_episodes >= 1 is needed")
        if not self.supervised and not self.regression_scenarios:
            raise ValueError("with supervised=False the regression test must run: give regression_scenarios")
        object.__setattr__(self, "regression_scenarios", tuple(str(s) for s in self.regression_scenarios))
        if self.takeover_margin < 0 or self.live_takeover_margin < 0:
            raise ValueError("takeover margins must be >= 0")
        if self.success_slack < 0:
            raise ValueError(f"success_slack must be >= 0, got {self.success_slack}")
        if self.regression_against not in REGRESSION_REFERENCES:
            raise ValueError(f"regression_against must be base or control, got {self.regression_against!r}")


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
    episode_takeover: list[float] = field(default_factory=list)
    """Each episode's share of steps under expert control, in seed order (the paired test reads these)."""
    episode_collided: list[bool] = field(default_factory=list)
    """Whether each episode had a safety violation, in seed order."""
    episode_succeeded: list[bool] = field(default_factory=list)
    """Whether each episode reached the goal, in seed order (the progress test reads these)."""
    regression: dict[str, list[bool]] = field(default_factory=dict)
    """Per regression scenario, whether each episode ALONE succeeded, in seed order (empty: no regression test)."""
    regression_seed: int | None = None
    """Seed of the first regression episode (the test compares two versions only on the same seeds)."""

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


def paired_takeover(candidate: Evaluation, incumbent: Evaluation, margin: float) -> tuple[int, int] | None:
    """(wins, losses) of the candidate over the paired episodes (see the module docstring); None when the two
    evaluations do not hold per-episode shares on the same seeds."""
    mine, theirs = candidate.episode_takeover, incumbent.episode_takeover
    if not mine or len(mine) != len(theirs) or candidate.seeds != incumbent.seeds:
        return None
    wins = sum(1 for a, b in zip(mine, theirs, strict=True) if a < b - margin - 1e-12)
    losses = sum(1 for a, b in zip(mine, theirs, strict=True) if a > b + margin + 1e-12)
    return wins, losses


def paired_success(candidate: Evaluation, incumbent: Evaluation) -> tuple[int, int] | None:
    """(wins, losses) of the candidate in reaching the goal over the paired episodes: a loss where only the
    incumbent reached it, a win where only the candidate did; None when the two evaluations do not hold per-episode
    outcomes on the same seeds."""
    mine, theirs = candidate.episode_succeeded, incumbent.episode_succeeded
    if not mine or len(mine) != len(theirs) or candidate.seeds != incumbent.seeds:
        return None
    wins = sum(1 for a, b in zip(mine, theirs, strict=True) if a and not b)
    losses = sum(1 for a, b in zip(mine, theirs, strict=True) if b and not a)
    return wins, losses


BASE_NAME = "the base policy (v0000)"


def regression_failure(
    candidate: Evaluation, base: Evaluation, cfg: PromotionConfig, reference: str = BASE_NAME
) -> str | None:
    """Why the candidate fails the regression test against ``base``, the alone record of ``reference`` (``v0000``,
    or the version in control with ``regression_against="control"``): the first scenario of
    ``cfg.regression_scenarios`` on which it succeeds alone in fewer episodes; None when it passes."""
    for scenario in cfg.regression_scenarios:
        mine, theirs = candidate.regression.get(scenario), base.regression.get(scenario)
        same_seeds = candidate.regression_seed == base.regression_seed
        if mine is None or theirs is None or len(mine) != len(theirs) or not same_seeds:
            raise ValueError(f"regression scenario {scenario}: the two evaluations do not hold the same seeds")
        if sum(mine) < sum(theirs):
            return (
                f"regression: alone on scenario {scenario} it succeeded in {sum(mine)}/{len(mine)} episodes, "
                f"{reference} in {sum(theirs)}/{len(theirs)}"
            )
    return None


def decide(
    candidate: Evaluation,
    incumbent: Evaluation | None,
    cfg: PromotionConfig,
    base: Evaluation | None = None,
    reference: str = BASE_NAME,
) -> Decision:
    """Promote only a candidate that passes the regression test against ``base``, the alone record of ``reference``
    (with ``regression_scenarios``), and, with ``supervised``, the collision and takeover tests against
    ``incumbent`` (the module docstring)."""
    regression = ""
    if cfg.regression_scenarios:
        if base is None:
            raise ValueError("the regression test needs the alone record it compares with")
        failure = regression_failure(candidate, base, cfg, reference)
        if failure is not None:
            return Decision(False, failure)
        regression = f"no worse alone than {reference} on scenarios {', '.join(cfg.regression_scenarios)}"
        if not cfg.supervised:
            return Decision(True, regression + " (supervised tests off)")
        regression = "; " + regression
    if incumbent is None:
        raise ValueError("the supervised tests need the version in control's evaluation")
    decision = _decide_supervised(candidate, incumbent, cfg)
    return Decision(decision.promoted, decision.reason + regression) if decision.promoted else decision


def _decide_supervised(candidate: Evaluation, incumbent: Evaluation, cfg: PromotionConfig) -> Decision:
    if candidate.violation_episodes > incumbent.violation_episodes:
        return Decision(
            False,
            f"collided in {candidate.violation_episodes}/{candidate.episodes} evaluation episodes, "
            f"the version in control in {incumbent.violation_episodes}/{incumbent.episodes}",
        )
    progress = paired_success(candidate, incumbent)
    if progress is not None and progress[1] > progress[0] + cfg.success_slack:
        return Decision(
            False,
            f"reached the goal in {sum(candidate.episode_succeeded)}/{candidate.episodes} evaluation episodes, the "
            f"version in control in {sum(incumbent.episode_succeeded)}/{incumbent.episodes}: it missed it in "
            f"{progress[1]} paired episodes the version in control finished, finished {progress[0]} it missed",
        )
    rates = f"takeover {candidate.takeover_rate:.0%} vs {incumbent.takeover_rate:.0%}"
    if progress is not None:
        rates += f"; goal reached {sum(candidate.episode_succeeded)} vs {sum(incumbent.episode_succeeded)}"
    paired = paired_takeover(candidate, incumbent, cfg.takeover_margin)
    if paired is not None:
        wins, losses = paired
        if losses > wins:
            return Decision(
                False,
                f"asked for more help than the version in control in {losses} of {len(candidate.seeds)} paired "
                f"episodes, less in {wins} ({rates})",
            )
        return Decision(
            True,
            f"no worse than the version in control: collisions {candidate.violation_episodes} vs "
            f"{incumbent.violation_episodes}, less help in {wins} paired episodes, more in {losses} ({rates})",
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
        f"{incumbent.violation_episodes}, {rates}",
    )


def _binomial(n: int, p: float) -> list[float]:
    return [math.comb(n, k) * p**k * (1 - p) ** (n - k) for k in range(n + 1)]


def collision_pass_probability(p_incumbent: float, p_candidate: float, episodes: int) -> float:
    """P(the candidate passes the collision test): each collides in an episode independently with its probability;
    it passes when it collides in no more of the ``episodes`` than the incumbent."""
    ours, theirs = _binomial(episodes, p_candidate), _binomial(episodes, p_incumbent)
    return sum(ours[j] * theirs[i] for i in range(episodes + 1) for j in range(i + 1))


def takeover_pass_probability(p_win: float, p_loss: float, episodes: int) -> float:
    """P(the candidate passes the takeover sign test): each paired episode is a win with ``p_win``, a loss with
    ``p_loss``, else a tie; it passes with at least as many wins as losses."""
    return sign_test_pass_probability(p_win, p_loss, episodes)


def success_pass_probability(p_incumbent: float, p_candidate: float, episodes: int, slack: int) -> float:
    """P(the candidate passes the progress test): each reaches the goal in an episode independently with its
    probability; it passes with no more losses than wins + ``slack``."""
    p_win, p_loss = p_candidate * (1 - p_incumbent), p_incumbent * (1 - p_candidate)
    return sign_test_pass_probability(p_win, p_loss, episodes, slack)


def sign_test_pass_probability(p_win: float, p_loss: float, episodes: int, slack: int = 0) -> float:
    """P(losses <= wins + ``slack``) over ``episodes`` paired episodes, each a win with ``p_win``, a loss with
    ``p_loss``, else a tie."""
    if p_win < 0 or p_loss < 0 or p_win + p_loss > 1 + 1e-12:
        raise ValueError(f"need p_win, p_loss >= 0 with p_win + p_loss <= 1, got {p_win}, {p_loss}")
    p_tie = max(0.0, 1.0 - p_win - p_loss)
    total = 0.0
    for wins in range(episodes + 1):
        for losses in range(episodes - wins + 1):
            if losses <= wins + slack:
                ties = episodes - wins - losses
                ways = math.comb(episodes, wins) * math.comb(episodes - wins, losses)
                total += ways * p_win**wins * p_loss**losses * p_tie**ties
    return total


def evaluate_version(
    path: Path,
    cfg: PromotionConfig,
    *,
    make_env: Callable[[], gym.Env[Any, Any]],
    hold_steps: int | None = None,
    scenario_env: Callable[[str], gym.Env[Any, Any]] | None = None,
) -> Evaluation:
    """Run ``path`` (a version folder or checkpoint) with its gate and the scripted expert on the fixed seeds (with
    ``cfg.supervised``), and alone on each of ``cfg.regression_scenarios`` (built by ``scenario_env(name)``, which
    the regression test needs)."""
    from core.agents import load_agent
    from core.experts import ScriptedExpert
    from core.loop import Gate, NoGate, Runner, StepRecord

    started = time.perf_counter()
    agent = load_agent(path)
    regression: dict[str, list[bool]] = {}
    if cfg.regression_scenarios:
        if scenario_env is None:
            raise ValueError("the regression test needs scenario_env, a factory of each scenario's environment")
        for scenario in cfg.regression_scenarios:
            regression[scenario] = _alone_successes(agent.policy, scenario_env(scenario), cfg)
    episodes = cfg.episodes if cfg.supervised else 0
    gate: Gate = NoGate()
    if agent.has_world_model:
        gate = agent.make_gate() if hold_steps is None else agent.make_gate(hold_steps=hold_steps)
    violations = takeovers = steps = successes = 0
    per_takeover: list[float] = []
    per_collided: list[bool] = []
    per_succeeded: list[bool] = []
    env = make_env() if episodes else None
    try:
        if env is not None:
            runner = Runner(env, agent.policy, gate, ScriptedExpert(), seed=cfg.seed, deterministic=True)
            violated: list[bool] = [False]

            def watch(record: StepRecord) -> None:
                violated[0] = violated[0] or record.violation

            runner.step_listeners.append(watch)
            for _ in range(episodes):
                violated[0] = False
                summary = runner.run_episode(max_steps=cfg.max_steps)
                collided = violated[0] or _flag(summary.metrics.get("collision"))
                violations += int(collided)
                succeeded = _flag(summary.metrics.get("success"))
                successes += int(succeeded)
                per_succeeded.append(succeeded)
                takeovers += summary.takeovers
                steps += summary.steps
                per_takeover.append(summary.takeovers / max(summary.steps, 1))
                per_collided.append(collided)
    finally:
        if env is not None:
            env.close()
    return Evaluation(
        episodes=episodes,
        violation_episodes=violations,
        takeover_rate=takeovers / max(steps, 1),
        success_rate=successes / max(episodes, 1),
        steps=steps,
        seconds=round(time.perf_counter() - started, 3),
        seeds=[cfg.seed + i for i in range(episodes)],
        episode_takeover=per_takeover,
        episode_collided=per_collided,
        episode_succeeded=per_succeeded,
        regression=regression,
        regression_seed=cfg.regression_seed if regression else None,
    )


def _alone_successes(policy: Any, env: gym.Env[Any, Any], cfg: PromotionConfig) -> list[bool]:
    """The policy ALONE (deterministic, no gate, no expert) on the regression seeds: each episode's success."""
    from core.experts import ScriptedExpert
    from core.loop import NoGate, Runner

    outcomes: list[bool] = []
    try:
        runner = Runner(env, policy, NoGate(), ScriptedExpert(), seed=cfg.regression_seed, deterministic=True)
        for _ in range(cfg.regression_episodes):
            summary = runner.run_episode(max_steps=cfg.max_steps)
            outcomes.append(_flag(summary.metrics.get("success")))
    finally:
        env.close()
    return outcomes


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
    reached: list[bool | None] = field(default_factory=list)
    """Per episode, whether it reached the goal; None where the episode did not end by the simulator (a reset)."""


class LiveWatch:
    """Judges a deployed version on its first ``live_window`` live episodes against the version it replaced.

    ``record`` is fed every finished live episode with the version that drove it; ``deployed`` says which
    version replaced which. After the window, :meth:`record` returns a rollback reason when the new version
    collided in more of its episodes than its predecessor did in its last ``live_window`` live episodes (or, with
    no live record of the predecessor, than its evaluation's violation rate allows), when its mean takeover
    rate is higher by more than ``live_takeover_margin``, or when it stands still: it reached the goal in none of
    its window's episodes (each ended by the simulator, not by a reset) where its predecessor reached it in at least
    half of its own (live, or in its evaluation). Each version is judged once, and a version returned to by
    a rollback is not judged (:meth:`returning_to`)."""

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

    def record(self, number: int, collided: bool, takeover_rate: float, reached: bool | None = None) -> str | None:
        """A live episode of version ``number`` ended; ``reached``: whether it reached the goal (None where the
        simulator did not end it). Returns the rollback reason once the window is full and the version did worse."""
        live = self._live.setdefault(number, _Live())
        live.collisions.append(bool(collided))
        live.takeover_rates.append(float(takeover_rate) if math.isfinite(takeover_rate) else 0.0)
        live.reached.append(reached)
        previous = self._predecessor.get(number)
        window = self.cfg.live_window
        if previous is None or number in self._judged or len(live.collisions) < window:
            return None
        self._judged.add(number)
        mine = _rates(live.collisions[:window], live.takeover_rates[:window])
        before = self._live.get(previous)
        if before is not None and len(before.collisions) >= window:
            theirs = _rates(before.collisions[-window:], before.takeover_rates[-window:])
            their_reach = _reach_rate(before.reached[-window:])
            source = "live"
        elif previous in self._evaluations:
            ev = self._evaluations[previous]
            theirs = (ev.violation_rate, ev.takeover_rate)
            their_reach = ev.success_rate if ev.episodes else None
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
        my_reach = _reach_rate(live.reached[:window])
        if my_reach == 0.0 and their_reach is not None and their_reach >= 0.5:
            return (
                f"v{number:04d} reached the goal in none of its first {window} live episodes, "
                f"v{previous:04d} in {their_reach:.0%} ({source})"
            )
        return None

    def predecessor(self, number: int) -> int | None:
        return self._predecessor.get(number)

    def returning_to(self, number: int) -> None:
        """``number`` drives again because the version that replaced it was rolled back: it is not judged against
        that version (whose live record is what got it rolled back), so a rollback never bounces back to the
        version it undid, and ``number`` is never marked rolled back for having been returned to."""
        self._judged.add(number)


def reached_goal(summary: EpisodeSummary) -> bool | None:
    """Whether a live episode reached the goal, for :meth:`LiveWatch.record`:
    None where the simulator did not end it (an operator's reset, a switch), whose outcome is not known."""
    if summary.reason not in ("terminated", "truncated"):
        return None
    return _flag(summary.metrics.get("success"))


def _reach_rate(reached: Sequence[bool | None]) -> float | None:
    """The share of episodes that reached the goal, when the simulator ended every one of them; else None."""
    if not reached or any(r is None for r in reached):
        return None
    return sum(bool(r) for r in reached) / len(reached)


def _rates(collisions: Sequence[bool], takeover_rates: Sequence[float]) -> tuple[float, float]:
    return sum(collisions) / len(collisions), sum(takeover_rates) / len(takeover_rates)
