"""Does fear predict danger? ``sage calibrate``: measure the self-awareness signals against what happened.

The policy drives with its SAGE gate and **no expert**, so danger plays out. Every step is labelled "a violation
happens within the next H seconds" (1 s by default; H / dt steps from the simulator's descriptor). Then:

- AUROC and average precision of fear F, of its parts ĉ (predicted violation probability) and σ̂ (normalised
  uncertainty), and of curiosity C (the one observed on arriving at the state) for that label;
- the gate's firing rate on pre-violation steps against the other steps;
- the share of violations preceded by a firing within H, and the lead time (first firing -> violation);
- a reliability diagram: predicted ĉ against the observed rate of violations within the model's horizon;
- the gate's operating curve (:func:`operating_curve`): with the gate and the scripted expert, episodes with a
  violation against the takeover rate, sweeping a scale on τ; beside random gating and curiosity-only gating
  swept over their own knobs, so that the three are compared at equal takeover rates.

:func:`expert_lead` asks the question the gate has to answer in time: how much warning does the expert need? It
replays each of the policy's violations with the expert taking over a given time before it, beside how long
before it the gate first fired.
"""

from __future__ import annotations

import json
import math
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

import gymnasium as gym
import numpy as np

from core.agents import load_agent
from core.experts import ScriptedExpert
from core.loop import TAKEOVER_CAUSES, Gate, GateDecision, Runner, StepRecord, takeover_cause
from core.metrics import auroc, average_precision, difference_interval, reliability, wilson_interval
from core.sage.gate import SageGate

EVAL_SEED = 3_000_000
"""Calibration episodes use seeds apart from training (episode i: EVAL_SEED + i)."""

CURVE_SCALES = (0.15, 0.3, 0.5, 0.7, 1.0, 1.4)
"""The scales on τ that the fear curve sweeps."""


@dataclass
class SignalScore:
    auroc: float
    average_precision: float


@dataclass
class CalibrationReport:
    """What :func:`calibrate_run` measured."""

    run: str
    sim: str
    scenario: str
    episodes: int
    steps: int
    horizon_s: float
    horizon_steps: int
    violations: int
    """Episodes that ended in (or contained) a violation."""
    positives: int
    """Steps labelled "violation within H"."""
    scores: dict[str, SignalScore]
    """fear, cost (ĉ), sigma (σ̂), curiosity."""
    fire_rate_before_violation: float
    fire_rate_elsewhere: float
    violations_warned: float
    """Share of violations with a gate firing within H before them."""
    mean_lead_time_s: float
    """Mean time from the first firing in that window to the violation (warned violations only)."""
    reliability: list[tuple[float, float, int]] = field(default_factory=list)
    curve: dict[str, list[dict[str, float]]] = field(default_factory=dict)
    early_warning: list[dict[str, float]] = field(default_factory=list)
    """How early fear warns, whatever τ: per firing share (:func:`early_warning`), the share of violations it warned of
    :data:`EARLY_LEAD_S` to twice that ahead at a threshold crossed on that share of the steps far from any."""

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    def summary(self) -> str:
        lines = [
            f"{self.run} on {self.sim} {self.scenario}: {self.episodes} episodes, {self.steps} steps, "
            f"{self.violations} with a violation; label: violation within {self.horizon_s:g} s "
            f"({self.horizon_steps} steps), {self.positives} positive steps",
            "",
            "| signal | AUROC | average precision |",
            "|---|---|---|",
        ]
        for name, score in self.scores.items():
            lines.append(f"| {name} | {_fmt(score.auroc)} | {_fmt(score.average_precision)} |")
        lines += [
            "",
            f"gate firing rate: {_pct(self.fire_rate_before_violation)} of pre-violation steps, "
            f"{_pct(self.fire_rate_elsewhere)} of the others",
            f"violations preceded by a firing within {self.horizon_s:g} s: {_pct(self.violations_warned)}, "
            f"mean lead time {_fmt(self.mean_lead_time_s)} s",
        ]
        if self.early_warning:
            lead = self.early_warning[0]["lead_s"]
            pairs = ", ".join(f"{w['firing']:.0%} → {_pct(w['warned'])}" for w in self.early_warning)
            lines.append(
                f"violations fear warned of {lead:g}-{2 * lead:g} s ahead at equal firing (share of the steps more "
                f"than {2 * lead:g} s from a violation over the threshold → violations warned): {pairs}"
            )
        for name, points in self.curve.items():
            pairs = ", ".join(f"{p['takeover_rate']:.0%}→{p['violation_rate']:.0%}" for p in points)
            lines.append(f"operating curve {name} (takeover → episodes with a violation): {pairs}")
        for against in ("random", "curiosity only"):
            if self.curve.get(against):
                v = compare_curves(self.curve, against)
                lines.append(
                    f"fear against {against} at equal takeover (95% interval of the difference): {v['better']} better, "
                    f"{v['tied']} tied, {v['worse']} worse, {v['unmatched']} without a point within 5 points"
                )
        return "\n".join(lines)


def _fmt(value: float) -> str:
    return "–" if value is None or not math.isfinite(value) else f"{value:.3f}"


def _pct(value: float) -> str:
    return "–" if not math.isfinite(value) else f"{value:.0%}"


@dataclass
class _Step:
    episode: int
    fear: float
    cost: float
    sigma: float
    curiosity_in: float
    fired: bool
    violation: bool


def labels_within(violation: np.ndarray, episode: np.ndarray, steps: int) -> np.ndarray:
    """1 where a violation happens at this step or within the next ``steps - 1`` steps of the same episode."""
    n = len(violation)
    out = np.zeros(n, bool)
    next_violation = -1
    for i in range(n - 1, -1, -1):
        if i + 1 < n and episode[i + 1] != episode[i]:
            next_violation = -1
        if violation[i]:
            next_violation = i
        out[i] = next_violation >= 0 and next_violation - i < steps
    return out


EARLY_LEAD_S = 1.5
""":func:`early_warning`'s lead [s]: a warning this far ahead, or up to twice that, counts as early (the scripted
highway expert avoided, by a steady manoeuvre, every collision of a replayed handful from 2 s before the takeover and
few from the takeover itself, ``docs/notes/calibration_history.md``)."""
EARLY_FIRING = (0.2, 0.3, 0.45, 0.55)
"""The firing shares :func:`early_warning` compares at."""


def early_warning(
    fear: np.ndarray,
    violation: np.ndarray,
    episode: np.ndarray,
    dt: float,
    lead_s: float = EARLY_LEAD_S,
    firing: Sequence[float] = EARLY_FIRING,
) -> list[dict[str, float]]:
    """How early a signal warns of the violations, compared at equal firing rather than at a gate's own τ (two world
    models' fears on different scales compare fairly): for each share f of ``firing``, the threshold that ``fear``
    exceeds on f of the steps more than 2 · ``lead_s`` from a violation (their (1 - f) quantile), and the share of
    violation steps at which fear exceeded it on some step ``lead_s`` to 2 · ``lead_s`` before, within the episode."""
    lead = max(1, round(lead_s / dt))
    # steps where the gate computed no fear (NaN) neither set a threshold nor warn
    far = ~labels_within(violation, episode, 2 * lead) & np.isfinite(fear)
    hits = np.flatnonzero(violation)
    rows = []
    for share in firing:
        threshold = float(np.quantile(fear[far], 1.0 - share)) if far.any() else math.nan
        warned = 0
        for i in hits:
            window = np.arange(max(0, i - 2 * lead), i - lead + 1)
            window = window[episode[window] == episode[i]]
            warned += bool((np.nan_to_num(fear[window], nan=-np.inf) > threshold).any())
        rows.append(
            {
                "firing": float(share),
                "lead_s": float(lead_s),
                "threshold": threshold,
                "warned": warned / len(hits) if len(hits) else math.nan,
            }
        )
    return rows


def collect(
    make_env: Callable[[], gym.Env[Any, Any]],
    run: str | Path,
    episodes: int,
    max_steps: int | None = None,
    gate_settings: Mapping[str, Any] | None = None,
) -> tuple[list[_Step], Any]:
    """Run the policy with its gate (``gate_settings`` over its own) and no expert; record every step's signals."""
    agent = load_agent(run)
    gate = agent.make_gate(**(gate_settings or {}))
    env = make_env()
    steps: list[_Step] = []
    previous_curiosity = [math.nan]
    try:
        runner = Runner(env, agent.policy, gate, None, seed=EVAL_SEED, deterministic=True)

        def record(r: StepRecord) -> None:
            d = gate.detail
            steps.append(
                _Step(r.episode, r.fear, d.cost, d.sigma, previous_curiosity[0], r.gate_fired, bool(r.violation))
            )
            previous_curiosity[0] = r.curiosity if not r.done else math.nan

        runner.step_listeners.append(record)
        for _ in range(episodes):
            previous_curiosity[0] = math.nan
            runner.run_episode(max_steps=max_steps)
    finally:
        env.close()
    return steps, agent


def calibrate_run(
    run: str | Path,
    make_env: Callable[[], gym.Env[Any, Any]],
    dt: float,
    *,
    sim: str = "",
    scenario: str = "",
    episodes: int = 20,
    horizon_s: float = 1.0,
    max_steps: int | None = None,
    curve_episodes: int = 0,
    curve_scales: Sequence[float] = CURVE_SCALES,
    gate_settings: Mapping[str, Any] | None = None,
    curve_cpus: int | None = None,
    curve_address: str | None = None,
) -> CalibrationReport:
    """Measure how well fear predicts "violation within ``horizon_s``" (see the module docstring); the gate is
    the run's own, with ``gate_settings`` (:class:`~core.sage.config.GateConfig` fields) over it; the operating curve's
    points run as Ray tasks with ``curve_cpus`` or ``curve_address`` (:func:`operating_curve`)."""
    steps, agent = collect(make_env, run, episodes, max_steps, gate_settings)
    if not steps:
        raise ValueError("no steps were recorded: every episode failed (see the log)")
    h = max(1, round(horizon_s / dt))
    episode = np.array([s.episode for s in steps])
    violation = np.array([s.violation for s in steps])
    label = labels_within(violation, episode, h)
    fired = np.array([s.fired for s in steps])
    signals = {
        "fear": np.array([s.fear for s in steps]),
        "cost": np.array([s.cost for s in steps]),
        "sigma": np.array([s.sigma for s in steps]),
        "curiosity": np.array([s.curiosity_in for s in steps]),
    }
    scores = {k: SignalScore(auroc(v, label), average_precision(v, label)) for k, v in signals.items()}
    warned, leads = 0, []
    violation_idx = np.flatnonzero(violation)
    for i in violation_idx:
        window = [j for j in range(max(0, i - h + 1), i + 1) if episode[j] == episode[i]]
        firing = [j for j in window if fired[j]]
        if firing:
            warned += 1
            leads.append((i - firing[0]) * dt)
    model_steps = agent.config.world_model_config.violation_steps
    model_label = labels_within(violation, episode, model_steps)
    report = CalibrationReport(
        run=str(run),
        sim=sim,
        scenario=scenario,
        episodes=episodes,
        steps=len(steps),
        horizon_s=horizon_s,
        horizon_steps=h,
        violations=len(set(episode[violation_idx].tolist())),
        positives=int(label.sum()),
        scores=scores,
        fire_rate_before_violation=float(fired[label].mean()) if label.any() else math.nan,
        fire_rate_elsewhere=float(fired[~label].mean()) if (~label).any() else math.nan,
        violations_warned=warned / len(violation_idx) if len(violation_idx) else math.nan,
        mean_lead_time_s=float(np.mean(leads)) if leads else math.nan,
        reliability=reliability(signals["cost"], model_label),
        early_warning=early_warning(signals["fear"], violation, episode, dt),
    )
    if curve_episodes > 0:
        report.curve = operating_curve(
            run,
            make_env,
            curve_episodes,
            curve_scales,
            max_steps,
            gate_settings,
            cpus=curve_cpus,
            address=curve_address,
        )
    return report


# -- the operating curve ------------------------------------------------------------------------------------------
class HoldGate:
    """Fires by its own rule and holds control for ``hold`` steps, as the SAGE gate does."""

    def __init__(self, inner: Gate, hold: int) -> None:
        self.inner, self.hold, self.remaining = inner, hold, 0
        self.last_curiosity = math.nan

    def reset(self) -> None:
        self.inner.reset()
        self.remaining = 0
        self.last_curiosity = math.nan

    def rule(self, decision: GateDecision, held: bool) -> bool:
        """Whether to (re)start the hold; ``held``: the expert holds control now."""
        raise NotImplementedError

    def decide(self, obs: np.ndarray, a_rl: np.ndarray) -> GateDecision:
        decision = self.inner.decide(obs, a_rl)
        if self.rule(decision, self.remaining > 0):
            self.remaining = self.hold
        fired = self.remaining > 0
        if fired:
            self.remaining -= 1
        return GateDecision(decision.fear, decision.threshold, fired)

    def observe(self, obs: np.ndarray, action: np.ndarray, next_obs: np.ndarray) -> float:
        self.last_curiosity = float(self.inner.observe(obs, action, next_obs))
        return self.last_curiosity


class ScaledFearGate(HoldGate):
    """SAGE's rule with τ scaled: fire when F > scale · τ; while the expert holds control, keep it while
    F > scale · the SAGE gate's release level (its hysteresis, :meth:`SageGate.release_level`)."""

    def __init__(self, inner: SageGate, hold: int, scale: float) -> None:
        super().__init__(inner, hold)
        self.sage, self.scale = inner, scale

    def rule(self, decision: GateDecision, held: bool) -> bool:
        if not math.isfinite(decision.fear):
            return False
        level = self.sage.release_level(decision.threshold) if held else decision.threshold
        return decision.fear > self.scale * level


class RandomGate(HoldGate):
    """Fires with probability ``p`` at each step, whatever the state."""

    def __init__(self, inner: Gate, hold: int, p: float, seed: int = 0) -> None:
        super().__init__(inner, hold)
        self.p, self.rng = p, np.random.default_rng(seed)

    def rule(self, decision: GateDecision, held: bool) -> bool:
        return bool(self.rng.random() < self.p)


class CuriosityGate(HoldGate):
    """Fires when the curiosity of the last transition exceeds ``level`` (curiosity alone, no fear); ``seen`` keeps
    every curiosity it observed (an infinite level makes it a pilot that never fires)."""

    def __init__(self, inner: Gate, hold: int, level: float) -> None:
        super().__init__(inner, hold)
        self.level = level
        self.seen: list[float] = []

    def rule(self, decision: GateDecision, held: bool) -> bool:
        return math.isfinite(self.last_curiosity) and self.last_curiosity > self.level

    def observe(self, obs: np.ndarray, action: np.ndarray, next_obs: np.ndarray) -> float:
        curiosity = super().observe(obs, action, next_obs)
        if math.isfinite(curiosity):
            self.seen.append(curiosity)
        return curiosity


class InfoGate(HoldGate):
    """Fires when ``danger(info)`` holds for the info dict of the last step (a privileged reference gating: what the
    simulator knows and the policy's world model must infer, e.g. highway's true time to contact and gaps), with the
    SAGE gate's hold. Feed it the steps: :func:`run_gated`'s ``listeners`` (its :meth:`watch`)."""

    def __init__(self, inner: Gate, hold: int, danger: Callable[[Mapping[str, Any]], bool]) -> None:
        super().__init__(inner, hold)
        self.danger = danger
        self.info: Mapping[str, Any] = {}

    def reset(self) -> None:
        super().reset()
        self.info = {}  # an episode's first step has no last step: nothing to read yet

    def watch(self, record: StepRecord) -> None:
        self.info = record.info

    def rule(self, decision: GateDecision, held: bool) -> bool:
        return bool(self.info) and bool(self.danger(self.info))


def firing_share(rate: float, hold: int) -> float:
    """The per-step firing probability p at which independent firing with a ``hold``-step hold takes over a share
    ``rate`` of the steps: rate = k p / (1 + (k - 1) p)."""
    return min(max(rate / max(hold - (hold - 1) * rate, 1e-9), 0.0), 1.0)


def level_for_share(curiosities: Sequence[float], share: float) -> float:
    """The curiosity level exceeded by a ``share`` of ``curiosities`` (above all of them for a share of 0)."""
    values = np.sort(np.asarray(curiosities, dtype=float))
    if len(values) == 0 or share <= 0.0:
        return math.inf
    index = int(np.clip(math.ceil((1.0 - share) * len(values)) - 1, 0, len(values) - 1))
    return float(values[index])


def _tau_min(gate: Gate) -> float:
    """The lowest threshold the SAGE gate inside ``gate`` can reach (its τ_min), NaN for other gates."""
    inner = getattr(gate, "inner", gate)
    threshold = getattr(inner, "threshold", None)
    return float(getattr(threshold, "tau_min", math.nan))


def run_gated(
    agent: Any,
    make_env: Callable[[], gym.Env[Any, Any]],
    gate: Gate,
    episodes: int,
    max_steps: int | None,
    warn_steps: int = 10,
    listeners: Sequence[Callable[[StepRecord], None]] = (),
    first_seed: int = EVAL_SEED,
) -> dict[str, float]:
    """The policy with ``gate`` and the scripted expert over ``episodes`` (the evaluation seeds, from ``first_seed``):
    see :func:`gate_with_expert` for what it returns; ``listeners`` also see every step (e.g.
    :meth:`InfoGate.watch`)."""
    env = make_env()
    tau_min = _tau_min(gate)
    try:
        runner = Runner(env, agent.policy, gate, ScriptedExpert(), seed=first_seed, deterministic=True)
        # per episode: the first violation's (expert driving?, steps the expert had been driving up to it, and the
        # last ``warn_steps`` steps' (fear, gate fired) up to it)
        first: list[tuple[bool, int, list[tuple[float, bool]]] | None] = [None]
        streak = [0]
        recent: deque[tuple[float, bool]] = deque(maxlen=max(1, warn_steps))
        expert_steps = dict.fromkeys(TAKEOVER_CAUSES, 0)
        # fear over the threshold the gate compares it with (τ, times the curve's scale for a scaled fear gate) over
        # the last 2 · warn_steps steps, and its peak over those before the expert's present streak began
        scale = float(getattr(gate, "scale", 1.0))
        ratios: deque[float] = deque(maxlen=2 * max(1, warn_steps))
        peak_before_streak = [math.nan]
        peaks: list[float] = []

        def watch(r: StepRecord) -> None:
            streak[0] = streak[0] + 1 if r.takeover else 0
            if streak[0] == 1:
                peak_before_streak[0] = max((v for v in ratios if math.isfinite(v)), default=math.nan)
            level = scale * r.threshold
            ratios.append(r.fear / level if math.isfinite(r.fear) and math.isfinite(level) and level > 0 else math.nan)
            recent.append((r.fear, bool(r.gate_fired or r.takeover)))
            if r.violation and first[0] is None:
                first[0] = (bool(r.takeover), streak[0], list(recent))
                if r.takeover:
                    peaks.append(peak_before_streak[0])
            cause = takeover_cause(r, gate)
            if cause is not None:
                expert_steps[cause] += 1

        runner.step_listeners.append(watch)
        runner.step_listeners.extend(listeners)
        takeovers = steps = 0
        violations: list[tuple[bool, int, list[tuple[float, bool]]]] = []
        for _ in range(episodes):
            first[0], streak[0] = None, 0
            recent.clear()
            ratios.clear()
            summary = runner.run_episode(max_steps=max_steps)
            if first[0] is not None:
                violations.append(first[0])
            takeovers += summary.takeovers
            steps += summary.steps
    finally:
        env.close()
    under_expert = [n for expert, n, _ in violations if expert]
    # the others, with the policy driving: had the gate fired in the last warn_steps (and handed back), did fear
    # at least reach τ_min (a threshold within the gate's own range would have fired), or was the danger unforeseen
    handed_back = under_threshold = unforeseen = 0
    for expert, _, window in violations:
        if expert:
            continue
        peak = max((f for f, _ in window if math.isfinite(f)), default=math.nan)
        if any(fired for _, fired in window):
            handed_back += 1
        elif math.isfinite(peak) and math.isfinite(tau_min) and peak >= tau_min:
            under_threshold += 1
        else:
            unforeseen += 1
    return {
        "takeover_rate": takeovers / max(steps, 1),
        **{f"takeover_{cause}": n / max(steps, 1) for cause, n in expert_steps.items()},
        "violation_rate": len(violations) / episodes,
        "episodes": float(episodes),
        "steps": float(steps),
        "violations_under_expert": float(len(under_expert)),
        "expert_steps_before_violation": float(np.mean(under_expert)) if under_expert else float("nan"),
        "fear_before_handoff": float(np.nanmedian(peaks)) if any(math.isfinite(p) for p in peaks) else float("nan"),
        "violations_handed_back": float(handed_back),
        "violations_under_threshold": float(under_threshold),
        "violations_unforeseen": float(unforeseen),
    }


@dataclass(frozen=True)
class GateTarget:
    """Issue #11's target for the gate with the scripted expert on a scenario: a violation in at most
    ``violation_share`` of the episodes (1 of 20), at a takeover rate of at most ``takeover_rate``."""

    violation_share: float = 0.05
    takeover_rate: float = 0.35

    def met(self, violations: int, episodes: int, takeover_rate: float) -> bool:
        """Whether a measured row meets the target as read (its point estimates)."""
        if episodes <= 0:
            raise ValueError("a gate row needs at least one episode")
        return violations <= self.violation_share * episodes and takeover_rate <= self.takeover_rate

    def decided(self, violations: int, episodes: int) -> Literal["under", "over", "undecided"]:
        """What the row's episodes can tell about its violation share: ``"under"`` (the 95% Wilson interval lies
        at or under the target's share), ``"over"`` (wholly above it) or ``"undecided"`` (it straddles it: more
        episodes would be needed to say)."""
        low, high = wilson_interval(violations, episodes)
        if high <= self.violation_share:
            return "under"
        if low > self.violation_share:
            return "over"
        return "undecided"


def gate_with_expert(
    run: str | Path,
    make_env: Callable[[], gym.Env[Any, Any]],
    episodes: int,
    max_steps: int | None = None,
    warn_steps: int = 10,
    **gate_overrides: Any,
) -> dict[str, float]:
    """The product as it runs: the policy with its own SAGE gate (its τ, unscaled; ``gate_overrides``: any
    :class:`~core.sage.config.GateConfig` field, e.g. ``release=1.0``) and the scripted expert.
    Returns the share of episodes with a violation and the takeover rate, on the evaluation seeds, the takeover
    rate's parts by why the expert drove (``takeover_<cause>``: :func:`core.loop.takeover_cause`), and where each
    episode's first violation comes from:

    - ``violations_under_expert``: the expert was driving (the gate warned; the expert could not avoid it from
      there), and for how many steps it had been driving by then (``expert_steps_before_violation``, their mean);
      ``fear_before_handoff``: over those, the median of fear's peak over the threshold it was compared with (τ; for
      a :class:`ScaledFearGate`, τ times its scale) in the ``2 · warn_steps`` steps before the expert's last takeover
      began. Well under 1: fear rose suddenly, and a lower threshold would have handed over little earlier; near 1:
      it hovered just under the threshold, which a lower one would have caught sooner;
    - with the policy driving, judged on the last ``warn_steps`` steps up to the violation (1 s by default at
      10 Hz): ``violations_handed_back`` (the gate had fired and its hold ran out), ``violations_under_threshold``
      (it had not, but fear reached τ_min, the lowest threshold curiosity can set: the threshold's place was the
      lever) and ``violations_unforeseen`` (fear stayed below τ_min throughout: the world model did not see it
      coming, and no threshold in the gate's range would have fired).
    """
    agent = load_agent(run)
    return run_gated(agent, make_env, agent.make_gate(**gate_overrides), episodes, max_steps, warn_steps)


DEFAULT_SCALES: tuple[float, ...] = (1.0, 0.7, 0.5, 0.35, 0.25)
"""Candidate values of ``gate.tau_scale`` for :func:`choose_tau_scale`, about equal ratios apart: none above 1, so that
the choice only ever lowers τ from the bounds the fear of familiar states set (asks for help earlier). A higher τ
buys less takeover with safety, judged on a few hundred training episodes that may not hold the danger met later:
that trade is the user's, who may pass larger scales."""


@dataclass
class ScaleChoice:
    """What :func:`choose_tau_scale` measured and chose."""

    run: str
    sim: str
    scenarios: list[str]
    episodes: int
    target: GateTarget
    rows: list[dict[str, Any]]
    """One per (scale, scenario) driven: ``scale``, ``scenario``, ``violations`` (episodes with one),
    ``episodes``, ``takeover_rate`` and its parts by why the expert drove (``takeover_<cause>``), ``met``."""
    scale: float
    """The chosen ``gate.tau_scale``: where none met the target, the run's own, unchanged."""
    met: bool
    """Whether the chosen scale met the target on every scenario (False: none did, and the run's scale stays)."""
    gate_settings: dict[str, Any] = field(default_factory=dict)
    """The gate settings every row ran with over the run's own (``tau_scale`` apart): a choice holds with them
    only, so deploying it sets them too (:meth:`deploy_settings`)."""

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    def deploy_settings(self) -> dict[str, Any]:
        """The gate settings to deploy the choice with: those the rows ran with, and the chosen scale."""
        return {**self.gate_settings, "tau_scale": self.scale}

    def summary(self) -> str:
        t = self.target
        lines = [
            f"{self.run} on {self.sim} {', '.join(self.scenarios)}: gate + scripted expert, {self.episodes} episodes "
            f"per scenario and scale; target: a violation in at most {t.violation_share:.0%} of the episodes at "
            f"most {t.takeover_rate:.0%} takeover, on every scenario"
            + ("; gate " + ", ".join(f"{k}={v}" for k, v in self.gate_settings.items()) if self.gate_settings else ""),
            "",
            "| tau_scale | scenario | episodes with a violation (95% interval) | takeover rate "
            "| why the expert drove: fear over τ · hold · hysteresis · manoeuvre (% of steps) | target |",
            "|---|---|---|---|---|---|",
        ]
        for r in self.rows:
            low, high = wilson_interval(int(r["violations"]), int(r["episodes"]))
            # rows saved before the parts were measured have none
            parts = " · ".join(
                f"{100 * r[f'takeover_{c}']:.0f}" if f"takeover_{c}" in r else "–" for c in TAKEOVER_CAUSES
            )
            lines.append(
                f"| {r['scale']:g} | {r['scenario']} | {r['violations']}/{r['episodes']} ({low:.0%}-{high:.0%}) | "
                f"{r['takeover_rate']:.1%} | {parts} | {'met' if r['met'] else 'missed'} |"
            )
        lines.append("")
        if self.met:
            lines.append(
                f"chosen: gate.tau_scale={self.scale:g}, the largest scale that met the target on every scenario"
            )
        else:
            lines.append(
                f"no scale met the target on every scenario: the run's own gate.tau_scale={self.scale:g} stays (the "
                "rows say what each would give)"
            )
        return "\n".join(lines)


def scaled_gate_row(
    run: str | Path,
    scenario: str,
    make_env: Callable[[], gym.Env[Any, Any]],
    episodes: int,
    gate_kwargs: Mapping[str, Any],
    target: GateTarget,
    max_steps: int | None = None,
) -> dict[str, Any]:
    """One row of :func:`choose_tau_scale`: the policy with its gate (``gate_kwargs``, ``tau_scale`` among them)
    and the scripted expert on ``scenario``; a Ray task of its own where the rows run at once."""
    agent = load_agent(run)
    point = run_gated(agent, make_env, agent.make_gate(**gate_kwargs), episodes, max_steps)
    violations = round(point["violation_rate"] * episodes)
    return {
        "scale": float(gate_kwargs["tau_scale"]),
        "scenario": scenario,
        "violations": violations,
        "episodes": episodes,
        "takeover_rate": point["takeover_rate"],
        **{f"takeover_{cause}": point[f"takeover_{cause}"] for cause in TAKEOVER_CAUSES},
        "met": target.met(violations, episodes, point["takeover_rate"]),
    }


def choose_tau_scale(
    run: str | Path,
    make_envs: Mapping[str, Callable[[], gym.Env[Any, Any]]],
    episodes: int,
    scales: Sequence[float] = DEFAULT_SCALES,
    target: GateTarget = GateTarget(),
    *,
    sim: str = "",
    max_steps: int | None = None,
    gate_settings: Mapping[str, Any] | None = None,
    on_row: Callable[[dict[str, Any]], None] | None = None,
    cpus: int | None = None,
    address: str | None = None,
) -> ScaleChoice:
    """The gate's operating point for a risk target, chosen on the given scenarios (those the policy was trained
    on: the choice is then judged on others): ``gate.tau_scale`` multiplies τ's bounds, and this drives the policy
    with its own gate at each candidate scale and the scripted expert, as the product runs, ``episodes`` per
    scenario on the evaluation seeds.

    The largest scale (the least takeover) that meets ``target`` as read on every scenario is chosen. Where none
    does, nothing is chosen: the run's own scale stays (``met`` False), since a trade between violations and
    takeover beyond the target is the user's to make, from the rows. Scales are absolute values of ``tau_scale``,
    replacing the run's own.

    In this process the scales are driven largest first and the sweep stops at the first that meets the target;
    ``on_row`` sees each row as it is measured (a sweep of a few hundred episodes takes minutes). With ``cpus`` or
    ``address`` every (scale, scenario) row runs at once as a Ray task (:func:`studies.sweep.run_tasks`, local Ray
    on ``cpus`` cores or the cluster at ``address``) and the same rule reads them all; ``on_row`` then sees them at
    the end.
    """
    if episodes < 1:
        raise ValueError("choosing a scale needs at least one episode per scenario")
    if not make_envs:
        raise ValueError("choosing a scale needs at least one scenario")
    candidates = sorted({float(s) for s in scales}, reverse=True)
    if not candidates or any(not (math.isfinite(s) and s > 0.0) for s in candidates):
        raise ValueError(f"scales must be finite numbers > 0, got {list(scales)}")
    agent = load_agent(run)
    settings = {k: v for k, v in (gate_settings or {}).items() if k != "tau_scale"}
    own_scale = agent.gate_config(**settings).tau_scale  # a setting the gate refuses stops here, before any episode
    calls = [
        {
            "run": str(run),
            "scenario": scenario,
            "make_env": make_env,
            "episodes": episodes,
            "gate_kwargs": {**settings, "tau_scale": scale},
            "target": target,
            "max_steps": max_steps,
        }
        for scale in candidates
        for scenario, make_env in make_envs.items()
    ]
    rows: list[dict[str, Any]] = []
    if cpus is not None or address is not None:
        from studies.sweep import run_tasks

        labels = [f"tau_scale {c['gate_kwargs']['tau_scale']:g} on {c['scenario']}" for c in calls]
        rows = run_tasks(scaled_gate_row, calls, labels, address=address, cpus=cpus)
        for row in rows:
            if on_row is not None:
                on_row(row)
    else:
        for call in calls:
            rows.append(scaled_gate_row(**call))
            if on_row is not None:
                on_row(rows[-1])
            scale = rows[-1]["scale"]
            done = [r for r in rows if r["scale"] == scale]
            if len(done) == len(make_envs) and all(r["met"] for r in done):
                break  # the choice is the largest scale that meets the target: none below it can be chosen
    meeting = [s for s in candidates if _meets_everywhere(rows, s, len(make_envs))]
    chosen = meeting[0] if meeting else own_scale
    return ScaleChoice(str(run), sim, list(make_envs), episodes, target, rows, chosen, bool(meeting), dict(settings))


def _meets_everywhere(rows: Sequence[Mapping[str, Any]], scale: float, scenarios: int) -> bool:
    at = [r for r in rows if r["scale"] == scale]
    return len(at) == scenarios and all(r["met"] for r in at)


EXPERT_ALONE = "expert alone"
"""The curve's floor: the scripted expert driving every step of the same episodes (takeover rate 1). Every gating
that hands it more of the steps tends towards it; where the points of two gatings both lie near it, neither can lie
clearly above the other."""

CurveCall = dict[str, Any]
"""One point's work: ``kind`` (``fear``, ``pilot``, ``random``, ``curiosity only`` or :data:`EXPERT_ALONE`) and its
``knob`` (τ's scale), ``rate`` (the takeover rate to match) and ``pilot`` (curiosities met with no gating)."""


@dataclass(frozen=True)
class CurvePlan:
    """The operating curve as independent pieces of work, so that a caller can run each on its own core (Ray tasks:
    ``experiments/calibration.py``): first the fear points, the curiosity pilot and the expert alone (:meth:`first`),
    then random and curiosity-only gating at the takeover rates the fear points reached (:meth:`second`). Run each
    call with :func:`curve_point`; :meth:`curve` puts the results together. :func:`operating_curve` runs them in
    turn."""

    scales: Sequence[float] = CURVE_SCALES

    def first(self) -> list[CurveCall]:
        return [{"kind": "fear", "knob": s} for s in self.scales] + [{"kind": "pilot"}, {"kind": EXPERT_ALONE}]

    def second(self, first: Sequence[Any]) -> list[CurveCall]:
        fear, pilot, _ = self._split(first)
        rates = sorted(p["takeover_rate"] for p in fear)
        return [
            {"kind": kind, "rate": rate} | ({"pilot": pilot} if kind == "curiosity only" else {})
            for rate in rates
            for kind in ("random", "curiosity only")
        ]

    def curve(self, first: Sequence[Any], second: Sequence[Any]) -> dict[str, list[dict[str, float]]]:
        fear, _, alone = self._split(first)
        calls = self.second(first)
        curve: dict[str, list[dict[str, float]]] = {"fear (SAGE)": list(fear), "random": [], "curiosity only": []}
        for call, point in zip(calls, second, strict=True):
            curve[call["kind"]].append(point)
        for points in curve.values():
            points.sort(key=lambda q: q["takeover_rate"])
        curve[EXPERT_ALONE] = [alone]
        return curve

    def _split(self, first: Sequence[Any]) -> tuple[list[dict[str, float]], list[float], dict[str, float]]:
        if len(first) != len(self.scales) + 2:
            raise ValueError(f"{len(first)} results for the {len(self.scales) + 2} calls of the curve's first stage")
        return list(first[: len(self.scales)]), list(first[-2]), first[-1]


def curve_point(
    run: str | Path,
    make_env: Callable[[], gym.Env[Any, Any]],
    episodes: int,
    call: CurveCall,
    max_steps: int | None = None,
    gate_settings: Mapping[str, Any] | None = None,
    first_seed: int = EVAL_SEED,
) -> Any:
    """One call of a :class:`CurvePlan` on the curve's episodes (the evaluation seeds, from ``first_seed``): a point
    (``fear``, ``random``, ``curiosity only``, :data:`EXPERT_ALONE`) as :func:`gate_with_expert` returns it with its
    ``knob``, or (``pilot``) the curiosities met with no gating. A ``random`` or ``curiosity only`` call with a
    ``knob`` (a firing share, a curiosity level) instead of a ``rate`` runs that gating at it as it is, without
    matching a rate: a measured point again on other seeds (:class:`CurveExtension`)."""
    agent = load_agent(run)
    settings = dict(gate_settings or {})
    hold = agent.gate_config(**settings).hold
    kind = call["kind"]
    # the random gate's own draws move with the episodes' seeds (0 on the curve's own, as before)
    draws = first_seed - EVAL_SEED

    def make_gate() -> SageGate:
        return agent.make_gate(**settings)

    def gated(gate: Gate) -> dict[str, float]:
        return run_gated(agent, make_env, gate, episodes, max_steps, first_seed=first_seed)

    if kind == "fear":
        return {"knob": float(call["knob"]), **gated(ScaledFearGate(make_gate(), hold, float(call["knob"])))}
    if kind == "pilot":
        pilot = CuriosityGate(make_gate(), hold, math.inf)
        gated(pilot)
        return pilot.seen
    if kind == EXPERT_ALONE:
        return {"knob": 1.0, **gated(RandomGate(make_gate(), hold, 1.0, seed=draws))}
    if kind == "random":

        def gate_for_share(share: float) -> tuple[float, Gate]:
            return share, RandomGate(make_gate(), hold, share, seed=draws)

    elif kind == "curiosity only":

        def gate_for_share(share: float) -> tuple[float, Gate]:
            level = level_for_share(call["pilot"], share)
            return level, CuriosityGate(make_gate(), hold, level)

    else:
        raise ValueError(f"unknown curve call {kind!r}: fear, pilot, random, curiosity only or {EXPERT_ALONE}")
    if "knob" in call:
        knob = float(call["knob"])
        gate = (
            RandomGate(make_gate(), hold, knob, seed=draws)
            if kind == "random"
            else CuriosityGate(make_gate(), hold, knob)
        )
        return {"knob": knob, **gated(gate)}
    return _at_rate(float(call["rate"]), hold, gate_for_share, agent, make_env, episodes, max_steps, first_seed)


def operating_curve(
    run: str | Path,
    make_env: Callable[[], gym.Env[Any, Any]],
    episodes: int,
    scales: Sequence[float] = CURVE_SCALES,
    max_steps: int | None = None,
    gate_settings: Mapping[str, Any] | None = None,
    *,
    cpus: int | None = None,
    address: str | None = None,
) -> dict[str, list[dict[str, float]]]:
    """Episodes with a violation against the takeover rate for SAGE's gate (τ scaled), random gating and
    curiosity-only gating on the same seeds, and the scripted expert alone (:data:`EXPERT_ALONE`); random and
    curiosity-only gating are set to the takeover rates that the scaled gate reached (the firing probability from the
    rate; the curiosity level from a pilot's curiosity, corrected once), so that each fear point has a counterpart at
    about its own rate. The points one after another in this process, or with ``cpus`` or ``address`` each stage's
    points at once as Ray tasks (:func:`studies.sweep.run_tasks`: local Ray on ``cpus`` cores or the cluster at
    ``address``; ``make_env`` must then pickle), with the same seeds and so the same points."""
    plan = CurvePlan(scales)

    def points(calls: list[CurveCall]) -> list[Any]:
        if cpus is None and address is None:
            return [curve_point(run, make_env, episodes, call, max_steps, gate_settings) for call in calls]
        from studies.sweep import run_tasks

        common = {"run": str(run), "make_env": make_env, "episodes": episodes, "max_steps": max_steps}
        tasks = [common | {"call": call, "gate_settings": dict(gate_settings or {})} for call in calls]
        labels = [f"curve point {c['kind']}" + (f" at {c['rate']:.0%}" if "rate" in c else "") for c in calls]
        return run_tasks(curve_point, tasks, labels, address=address, cpus=cpus)

    first = points(plan.first())
    return plan.curve(first, points(plan.second(first)))


def _at_rate(
    rate: float,
    hold: int,
    gate_for_share: Callable[[float], tuple[float, Gate]],
    agent: Any,
    make_env: Callable[[], gym.Env[Any, Any]],
    episodes: int,
    max_steps: int | None,
    first_seed: int = EVAL_SEED,
) -> dict[str, float]:
    """A comparison gating's curve point at about takeover ``rate``: ``gate_for_share`` builds it (and names its
    knob) from a per-step firing share, first the share that independent firing would need, then once more scaled
    by how far the takeover rate missed (the expert's driving changes what the gating meets); the nearer point."""
    share = firing_share(rate, hold)
    tries = []
    for _ in range(2):
        knob, gate = gate_for_share(share)
        point = {"knob": knob, **run_gated(agent, make_env, gate, episodes, max_steps, first_seed=first_seed)}
        tries.append(point)
        reached = point["takeover_rate"]
        if abs(reached - rate) <= 0.02 or reached <= 0.0:
            break
        share = min(share * rate / reached, 1.0)
    return min(tries, key=lambda q: abs(q["takeover_rate"] - rate))


def violation_interval(point: dict[str, float]) -> tuple[float, float]:
    """The 95% Wilson interval of a curve point's share of episodes with a violation."""
    return wilson_interval(*_violations(point))


def compare_curves(
    curve: dict[str, list[dict[str, float]]], against: str, name: str = "fear (SAGE)", tolerance: float = 0.05
) -> dict[str, int]:
    """Count ``name``'s points that are better, tied with or worse than ``against`` at (nearly) the same takeover
    rate: the ``against`` point nearest in takeover, if within ``tolerance``, and the 95% interval of the
    difference in the share of episodes with a violation (:func:`core.metrics.difference_interval`): better when
    it lies wholly below 0 (fewer violations), worse when wholly above. Points with no counterpart that near are
    ``unmatched``. The issue's target, "above random at every takeover rate", is ``worse == tied == 0``."""
    verdict = {"better": 0, "tied": 0, "worse": 0, "unmatched": 0}
    others = curve.get(against, [])
    for point in curve.get(name, []):
        near = min(others, key=lambda q: abs(q["takeover_rate"] - point["takeover_rate"]), default=None)
        if near is None or abs(near["takeover_rate"] - point["takeover_rate"]) > tolerance:
            verdict["unmatched"] += 1
            continue
        low, high = difference_interval(*_violations(point), *_violations(near))
        if high < 0:
            verdict["better"] += 1
        elif low > 0:
            verdict["worse"] += 1
        else:
            verdict["tied"] += 1
    return verdict


def pool_points(points: Sequence[Mapping[str, float]]) -> dict[str, float]:
    """One curve point from runs of the same gating at the same knob on disjoint seeds: counts added, rates weighted
    by the runs' steps (by their episodes where a run has no ``steps``: points measured before they were recorded),
    ``expert_steps_before_violation`` by the violations it is the mean of. ``fear_before_handoff``, a median, does
    not pool: nan."""
    if not points:
        raise ValueError("no points to pool")
    knobs = {float(p.get("knob", math.nan)) for p in points}
    if len(knobs) > 1 and not all(math.isnan(k) for k in knobs):
        raise ValueError(f"points at different knobs ({sorted(knobs)}) are not one point")
    episodes = [float(p["episodes"]) for p in points]
    counted = all("steps" in p for p in points)
    weights = [float(p["steps"]) for p in points] if counted else episodes
    total, weight = sum(episodes), sum(weights)
    pooled: dict[str, float] = {"knob": points[0].get("knob", math.nan), "episodes": total}
    if counted:
        pooled["steps"] = weight
    rates = sorted({key for p in points for key in p if key.startswith("takeover_")})
    for key in rates:
        pooled[key] = sum(float(p.get(key, 0.0)) * w for p, w in zip(points, weights, strict=True)) / max(weight, 1e-9)
    pooled["violation_rate"] = sum(_violations(dict(p))[0] for p in points) / max(total, 1.0)
    for key in (
        "violations_under_expert",
        "violations_handed_back",
        "violations_under_threshold",
        "violations_unforeseen",
    ):
        pooled[key] = sum(float(p.get(key, 0.0)) for p in points)
    under = [
        (float(p.get("violations_under_expert", 0.0)), float(p.get("expert_steps_before_violation", math.nan)))
        for p in points
    ]
    under = [(n, m) for n, m in under if n > 0 and math.isfinite(m)]
    pooled["expert_steps_before_violation"] = (
        sum(n * m for n, m in under) / sum(n for n, _ in under) if under else math.nan
    )
    pooled["fear_before_handoff"] = math.nan
    return pooled


@dataclass(frozen=True)
class ExtendedPoint:
    """A point of a :class:`CurveExtension`: which gating, at which knob, near which of fear's takeover rates, and
    the curve's own measurement of it (None for a point the curve lacked)."""

    kind: str
    knob: float
    near: float
    prior: dict[str, float] | None

    def call(self) -> CurveCall:
        """The :func:`curve_point` call that measures it again."""
        return {"kind": "fear" if self.kind == "fear (SAGE)" else self.kind, "knob": self.knob}


@dataclass(frozen=True)
class CurveExtension:
    """More episodes at chosen points of a measured operating curve, on seeds the curve did not use: where its points
    at some takeover rates were left undecided against a comparison gating. For each of ``rates``, fear's point
    nearest to it and, for each gating of ``against``, that gating's point nearest to fear's (within ``tolerance``,
    :func:`compare_curves`'s rule) run again at their own knobs, so that the new episodes pool with the curve's
    (:func:`pool_points`); where a gating has no point that near, one at the knob interpolated (linearly in takeover
    rate) between its two points around fear's rate, on the new episodes alone. Each point's new episodes start
    after the curve's (:meth:`first_seed`)."""

    rates: Sequence[float]
    against: Sequence[str] = ("random", "curiosity only")
    tolerance: float = 0.05

    def points(self, curve: Mapping[str, Sequence[dict[str, float]]]) -> list[ExtendedPoint]:
        fear = list(curve.get("fear (SAGE)", []))
        if not fear:
            raise ValueError("the curve has no fear points to extend")
        chosen: list[dict[str, float]] = []
        for rate in self.rates:
            near = min(fear, key=lambda q: abs(q["takeover_rate"] - rate))
            if abs(near["takeover_rate"] - rate) > self.tolerance:
                raise ValueError(
                    f"no fear point within {self.tolerance:.0%} of {rate:.0%} takeover (the curve's: "
                    + ", ".join(f"{q['takeover_rate']:.0%}" for q in fear)
                    + ")"
                )
            if near not in chosen:
                chosen.append(near)
        out: list[ExtendedPoint] = []
        for point in chosen:
            at = float(point["takeover_rate"])
            out.append(ExtendedPoint("fear (SAGE)", float(point["knob"]), at, point))
            for kind in self.against:
                others = sorted(curve.get(kind, []), key=lambda q: q["takeover_rate"])
                near = min(others, key=lambda q: abs(q["takeover_rate"] - at), default=None)
                if near is not None and abs(near["takeover_rate"] - at) <= self.tolerance:
                    out.append(ExtendedPoint(kind, float(near["knob"]), at, near))
                    continue
                below = [q for q in others if q["takeover_rate"] <= at]
                above = [q for q in others if q["takeover_rate"] > at]
                if below and above:
                    lo, hi = below[-1], above[0]
                    t = (at - lo["takeover_rate"]) / (hi["takeover_rate"] - lo["takeover_rate"])
                    out.append(ExtendedPoint(kind, float(lo["knob"] + t * (hi["knob"] - lo["knob"])), at, None))
        return out

    @staticmethod
    def first_seed(curve: Mapping[str, Sequence[dict[str, float]]]) -> int:
        """The first evaluation seed the curve's points did not use."""
        return EVAL_SEED + max(int(q.get("episodes", 0)) for points in curve.values() for q in points)


def extension_rows(points: Sequence[ExtendedPoint], new: Sequence[dict[str, float]]) -> list[dict[str, Any]]:
    """Fear's point against each other gating's near it, on the new episodes alone and pooled with the curve's:
    each row's counts and takeover rates and the 95% interval of the difference in the share of episodes with a
    violation (fear minus the other: :func:`core.metrics.difference_interval`), and the verdict read off the pooled
    one (better: wholly below 0). ``new[i]`` is ``points[i]``'s new episodes, pooled over their runs."""
    if len(points) != len(new):
        raise ValueError(f"{len(new)} results for {len(points)} points")
    rows: list[dict[str, Any]] = []
    fear: tuple[ExtendedPoint, dict[str, float]] | None = None
    for point, fresh in zip(points, new, strict=True):
        if point.kind == "fear (SAGE)":
            fear = (point, fresh)
            continue
        if fear is None or fear[0].near != point.near:
            raise ValueError(f"{point.kind} at {point.near:.0%} has no fear point before it")
        sides = []
        for p, f in (fear, (point, fresh)):
            pooled = pool_points([p.prior, f]) if p.prior is not None else f
            sides.append({"prior": p.prior, "new": f, "pooled": pooled, "knob": p.knob})
        new_low, new_high = difference_interval(*_violations(sides[0]["new"]), *_violations(sides[1]["new"]))
        low, high = difference_interval(*_violations(sides[0]["pooled"]), *_violations(sides[1]["pooled"]))
        matched = abs(sides[0]["pooled"]["takeover_rate"] - sides[1]["pooled"]["takeover_rate"]) <= 0.05
        verdict = "unmatched" if not matched else "better" if high < 0 else "worse" if low > 0 else "tied"
        rows.append(
            {
                "near": point.near,
                "against": point.kind,
                "fear": sides[0],
                "other": sides[1],
                "new_interval": (new_low, new_high),
                "pooled_interval": (low, high),
                "verdict": verdict,
            }
        )
    return rows


def _violations(point: dict[str, float]) -> tuple[int, int]:
    """(episodes with a violation, episodes) of a curve point."""
    n = int(point.get("episodes", 0))
    return round(point["violation_rate"] * n), n


# -- figures ------------------------------------------------------------------------------------------------------
def write_figures(report: CalibrationReport, out: Path) -> list[Path]:
    """reliability.png and (with a curve) operating_curve.png, plus report.json."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    written = []
    (out / "report.json").write_text(json.dumps(report.as_dict(), indent=1, default=float))
    fig, ax = plt.subplots(figsize=(4.6, 4.2), dpi=120)
    ax.plot([0, 1], [0, 1], color="#888", lw=1, ls="--", label="perfect calibration")
    if report.reliability:
        pred, obs, _ = zip(*report.reliability, strict=True)
        ax.plot(pred, obs, "o-", color="#d62728", label="ĉ (predicted violation probability)")
        for x, y, n in report.reliability:
            ax.annotate(str(n), (x, y), textcoords="offset points", xytext=(4, -10), fontsize=7, color="#555")
    ax.set_xlabel("predicted ĉ")
    ax.set_ylabel("observed rate of a violation ahead")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    ax.set_title(f"{report.sim} {report.scenario}: reliability of ĉ", fontsize=10)
    ax.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    fig.savefig(out / "reliability.png")
    plt.close(fig)
    written.append(out / "reliability.png")
    if report.curve:
        fig, ax = plt.subplots(figsize=(5.2, 4.2), dpi=120)
        colours = {"fear (SAGE)": "#d62728", "random": "#7f7f7f", "curiosity only": "#1f77b4", EXPERT_ALONE: "#000"}
        for name, points in report.curve.items():
            if name == EXPERT_ALONE and points:
                # the floor every gating tends towards as it hands the expert more of the steps: a level, not a curve
                y = points[0]["violation_rate"]
                ax.axhline(y, color=colours[name], lw=0.8, ls=":", label=f"scripted expert alone ({y:.1%})")
                continue
            xs = [p["takeover_rate"] for p in points]
            ys = [p["violation_rate"] for p in points]
            bounds = [violation_interval(p) for p in points]
            if all(math.isfinite(lo) for lo, _ in bounds):
                errors = [
                    # clipped at 0: at 0 or n of n the bound equals the rate up to rounding
                    [max(y - lo, 0.0) for y, (lo, _) in zip(ys, bounds, strict=True)],
                    [max(hi - y, 0.0) for y, (_, hi) in zip(ys, bounds, strict=True)],
                ]
                ax.errorbar(xs, ys, yerr=errors, fmt="o-", capsize=3, lw=1.2, label=name, color=colours.get(name))
            else:
                ax.plot(xs, ys, "o-", label=name, color=colours.get(name))
        ax.set_xlabel("takeover rate (share of steps under the expert)")
        ax.set_ylabel("episodes with a violation (95% Wilson interval)")
        ax.set_xlim(0, 1)
        # up to the highest interval's top, so that curves of a few percent are told apart
        tops = [violation_interval(p)[1] for points in report.curve.values() for p in points]
        top = min(1.0, 1.15 * max((t for t in tops if math.isfinite(t)), default=1.0)) + 0.02
        ax.set_ylim(-0.02 * top, top)
        ax.set_title(f"{report.sim} {report.scenario}: the gate's operating curve", fontsize=10)
        ax.legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(out / "operating_curve.png")
        plt.close(fig)
        written.append(out / "operating_curve.png")
    return written


# -- the warning the expert needs --------------------------------------------------------------------------------
@dataclass
class LeadReport:
    """What :func:`expert_lead` measured: the policy's violations, how early the gate saw each coming, and how many
    the expert still could not avoid when it took over a given time before them."""

    episodes: int
    violations: int
    """Episodes in which the policy alone had a violation (the gate watching, no expert)."""
    gate_warning_s: list[float]
    """Per such episode: time from the gate's first firing in the ``max(leads_s)`` before the violation to it (0:
    no firing in that window)."""
    leads_s: list[float]
    left: list[int]
    """Per lead: of those episodes, how many still had a violation with the expert driving from that long before
    the policy's violation to the end of the episode."""

    def summary(self) -> str:
        warning = f"{np.median(self.gate_warning_s):.1f} s" if self.gate_warning_s else "–"
        left = ", ".join(f"{lead:g} s: {n}" for lead, n in zip(self.leads_s, self.left, strict=True))
        needed = self.needed_s()
        return "\n".join(
            [
                f"the policy alone had a violation in {self.violations} of {self.episodes} episodes; the gate first "
                f"fired a median {warning} before it (within {max(self.leads_s, default=0.0):g} s)",
                f"the scripted expert taking over that long before each, violations left: {left or '–'}",
                "warning the expert needs: "
                + ("nothing to avoid" if self.violations == 0 else f"{needed:g} s" if math.isfinite(needed) else "more")
                + " (the shortest of those leads at which it avoided every one)",
            ]
        )

    def needed_s(self) -> float:
        """The shortest lead at which the expert avoided every one of them (NaN: none of the leads was enough; 0:
        there was nothing to avoid)."""
        if self.violations == 0:
            return 0.0
        return next((lead for lead, left in zip(self.leads_s, self.left, strict=True) if left == 0), math.nan)


class _ExpertFrom:
    """Fires from step ``start`` of the episode on (the expert drives from there to the end)."""

    def __init__(self) -> None:
        self.start, self.t = 0, 0

    def reset(self) -> None:
        self.t = 0

    def decide(self, obs: np.ndarray, a_rl: np.ndarray) -> GateDecision:
        fired = self.t >= self.start
        self.t += 1
        return GateDecision(math.nan, math.nan, fired)

    def observe(self, obs: np.ndarray, action: np.ndarray, next_obs: np.ndarray) -> float:
        return math.nan


def _episode(runner: Runner, max_steps: int | None) -> list[StepRecord]:
    """The step records of one whole episode of ``runner`` (:meth:`Runner.run_episode`)."""
    records: list[StepRecord] = []
    runner.step_listeners.append(records.append)
    try:
        runner.run_episode(max_steps=max_steps)
    finally:
        runner.step_listeners.remove(records.append)
    return records


def expert_lead(
    run: str | Path,
    make_env: Callable[[], gym.Env[Any, Any]],
    dt: float,
    episodes: int = 20,
    leads_s: Sequence[float] = (0.5, 1.0, 1.5, 2.0, 3.0),
    max_steps: int | None = None,
    gate_settings: Mapping[str, Any] | None = None,
) -> LeadReport:
    """The policy drives alone with its gate watching (as in :func:`calibrate_run`) on the evaluation seeds; each
    episode with a violation is then replayed from the same seed with the scripted expert taking over ``lead``
    seconds before the policy's first violation and driving to the end. Policy and simulator are deterministic
    given the seed, so the replay is the same episode up to the takeover; the fewest seconds at which the expert
    avoids every violation is the warning the gate has to give."""
    agent = load_agent(run)
    env = make_env()
    try:
        gate = agent.make_gate(**(gate_settings or {}))
        watching = Runner(env, agent.policy, gate, None, seed=EVAL_SEED, deterministic=True)
        window = max(1, round(max(leads_s, default=0.0) / dt))
        first: list[tuple[int, int]] = []  # (episode, step of its first violation)
        warnings: list[float] = []
        for episode in range(episodes):
            records = _episode(watching, max_steps)  # seed EVAL_SEED + episode
            step = next((i for i, r in enumerate(records) if r.violation), None)
            if step is None:
                continue
            first.append((episode, step))
            fired = [i for i in range(max(0, step - window), step + 1) if records[i].gate_fired]
            warnings.append((step - fired[0]) * dt if fired else 0.0)
        gate = _ExpertFrom()
        left = []
        for lead in leads_s:
            count = 0
            for episode, step in first:
                gate.start = max(0, step - round(lead / dt))
                # a runner's first episode has its seed: the same episode as the watched one up to the takeover
                replay = Runner(env, agent.policy, gate, ScriptedExpert(), seed=EVAL_SEED + episode, deterministic=True)
                count += any(r.violation for r in _episode(replay, max_steps))
            left.append(count)
    finally:
        env.close()
    return LeadReport(episodes, len(first), warnings, [float(lead) for lead in leads_s], left)
