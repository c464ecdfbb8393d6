"""sage gate evaluate: labels, scores and the operating curve on the point world."""

from __future__ import annotations

import functools
import itertools
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from core.loop import GateDecision
from studies.calibrate import calibrate_run, labels_within, write_figures
from tests.core.sage import envs
from tests.core.test_finetune import deployed  # noqa: F401  (the module fixture)

torch.set_num_threads(1)


def test_labels_mark_the_steps_before_a_violation_within_the_episode() -> None:
    violation = np.array([0, 0, 0, 1, 0, 0, 1, 0, 0, 0], bool)
    episode = np.array([0, 0, 0, 0, 1, 1, 1, 2, 2, 2])
    assert labels_within(violation, episode, 2).tolist() == [0, 0, 1, 1, 0, 1, 1, 0, 0, 0]
    # a violation never labels the previous episode's steps
    assert labels_within(violation, episode, 5).tolist() == [1, 1, 1, 1, 1, 1, 1, 0, 0, 0]


def test_early_warning_counts_the_violations_fear_rose_before_in_time_at_equal_firing() -> None:
    from studies.calibrate import early_warning

    episode = np.repeat([0, 1, 2], 100)
    violation = np.zeros(300, bool)
    violation[[60, 160]] = True
    fear = np.full(300, 0.1)
    fear[200:] = np.linspace(0.0, 0.5, 100)  # an episode without a violation: ordinary fear, graded
    fear[35:40] = 0.9  # episode 0: fear rose 2.1-2.5 s before its violation (dt 0.1)
    fear[155:161] = 0.9  # episode 1: only in the last half second
    fear[95:100] = 0.9  # the end of episode 0, before episode 1's: never a warning of it
    rows = early_warning(fear, violation, episode, dt=0.1, lead_s=1.5, firing=(0.05, 0.5))
    assert [r["warned"] for r in rows] == [0.5, 0.5]
    # the thresholds are fear's quantiles over the steps far from a violation: more firing, a lower threshold
    assert rows[0]["threshold"] > rows[1]["threshold"] and rows[1]["threshold"] < 0.3
    # a 0.5-1 s window finds episode 1's late rise and misses episode 0's early one; a 3-6 s one neither
    assert early_warning(fear, violation, episode, dt=0.1, lead_s=0.5, firing=(0.05,))[0]["warned"] == 0.5
    assert early_warning(fear, violation, episode, dt=0.1, lead_s=3.0, firing=(0.05,))[0]["warned"] == 0.0
    # steps without a fear (the gate computed none) neither set the threshold nor warn
    gaps = fear.copy()
    gaps[[0, 31, 150, 250]] = np.nan
    with_gaps = early_warning(gaps, violation, episode, dt=0.1, lead_s=1.5, firing=(0.05, 0.5))
    assert [r["warned"] for r in with_gaps] == [0.5, 0.5] and all(math.isfinite(r["threshold"]) for r in with_gaps)


def test_calibrate_scores_fear_against_what_happened(deployed: Path, tmp_path: Path) -> None:  # noqa: F811
    report = calibrate_run(
        deployed,
        functools.partial(envs.make, "dynamic"),
        dt=0.1,
        sim="point",
        scenario="dynamic",
        episodes=16,
        horizon_s=0.5,
        curve_episodes=3,
        curve_scales=(0.5, 1.0, 2.0),
    )
    assert report.horizon_steps == 5 and report.steps > 100
    assert set(report.scores) == {"fear", "cost", "sigma", "curiosity"}
    assert report.violations > 0, "the statically trained policy should meet the moving obstacle"
    assert report.positives > 0
    for score in report.scores.values():
        assert 0.0 <= score.auroc <= 1.0 and 0.0 < score.average_precision <= 1.0
    assert 0.0 <= report.fire_rate_elsewhere <= 1.0 and not math.isnan(report.fire_rate_before_violation)
    assert sum(n for _, _, n in report.reliability) == report.steps
    assert [w["firing"] for w in report.early_warning] == [0.2, 0.3, 0.45, 0.55]
    assert all(0.0 <= w["warned"] <= 1.0 for w in report.early_warning)
    sage = report.curve["fear (SAGE)"]
    assert len(sage) == 3 and len(report.curve["random"]) == 3 and len(report.curve["curiosity only"]) == 3
    # a lower threshold scale hands over more
    by_knob = {p["knob"]: p["takeover_rate"] for p in sage}
    assert by_knob[0.5] >= by_knob[2.0]
    paths = write_figures(report, tmp_path)
    assert [p.name for p in paths] == ["reliability.png", "operating_curve.png"]
    assert all(p.read_bytes()[:4] == b"\x89PNG" for p in paths) and (tmp_path / "report.json").is_file()
    assert "AUROC" in report.summary()


def test_gate_with_expert_says_who_was_driving_at_each_violation(deployed: Path) -> None:  # noqa: F811
    from core.agents import load_agent
    from studies.calibrate import RandomGate, run_gated

    agent = load_agent(deployed)
    make_env = functools.partial(envs.make, "dynamic")
    never = run_gated(agent, make_env, RandomGate(agent.make_gate(), hold=1, p=0.0), 8, None)
    assert never["takeover_rate"] == 0.0 and never["violation_rate"] > 0
    assert never["violations_under_expert"] == 0 and math.isnan(never["expert_steps_before_violation"])
    # with the policy always driving and the gate never firing, each violation was either within the threshold's
    # reach (fear over τ_min in the last second) or unforeseen, never handed back
    assert never["violations_handed_back"] == 0
    policy_driving = never["violations_under_threshold"] + never["violations_unforeseen"]
    assert policy_driving == round(never["violation_rate"] * 8)
    always = run_gated(agent, make_env, RandomGate(agent.make_gate(), hold=1, p=1.0), 8, None)
    assert always["takeover_rate"] == 1.0
    # the expert drives every step, so every violation happens under it, after it drove the whole episode so far
    assert always["violations_under_expert"] == round(always["violation_rate"] * 8)
    assert (
        always["violations_handed_back"] == always["violations_under_threshold"] == always["violations_unforeseen"] == 0
    )
    if always["violations_under_expert"]:
        assert always["expert_steps_before_violation"] >= 1


class _ScriptedGate:
    """A gate that plays one decision per step of each episode from ``script``: (fear, fired), with τ 0.5 and a
    release level of 0.3 (read from ``detail.level``, as the SAGE gate keeps it)."""

    def __init__(self, script: list[tuple[float, bool]]) -> None:
        self.script, self.t = script, 0
        self.detail = type("Detail", (), {"level": 0.3})()

    def reset(self) -> None:
        self.t = 0

    def decide(self, obs: np.ndarray, a_rl: np.ndarray) -> GateDecision:
        fear, fired = self.script[self.t % len(self.script)]
        self.t += 1
        return GateDecision(fear, 0.5, fired)

    def observe(self, obs: np.ndarray, action: np.ndarray, next_obs: np.ndarray) -> float:
        return 0.0


def test_the_takeover_rate_is_split_by_why_the_expert_drove(deployed: Path) -> None:  # noqa: F811
    from core.agents import load_agent
    from studies.calibrate import TAKEOVER_CAUSES, run_gated

    agent = load_agent(deployed)
    # per 8 steps: 1 over τ, 2 in the hysteresis (under τ, over the release level), 3 of the hold counting down,
    # 2 with the policy driving
    script = [
        (0.9, True),
        (0.4, True),
        (0.35, True),
        (0.1, True),
        (0.2, True),
        (0.25, True),
        (0.1, False),
        (0.6, False),
    ]
    steps: list[int] = []
    point = run_gated(
        agent,
        functools.partial(envs.make, "dynamic"),
        _ScriptedGate(script),
        6,
        None,
        listeners=[lambda r: steps.append(r.t)],
    )
    whole_cycles = sum(1 for t in steps if t % 8 == 7)  # episodes end mid-cycle too: count whole ones, then check
    assert whole_cycles > 0
    parts = {cause: point[f"takeover_{cause}"] * len(steps) for cause in TAKEOVER_CAUSES}
    counts = {
        "fear": sum(1 for t in steps if t % 8 == 0),
        "hysteresis": sum(1 for t in steps if t % 8 in (1, 2)),
        "hold": sum(1 for t in steps if t % 8 in (3, 4, 5)),
        "manoeuvre": 0,  # the point world's expert never asks to keep the wheel
    }
    assert parts == pytest.approx(counts)
    assert sum(point[f"takeover_{c}"] for c in TAKEOVER_CAUSES) == pytest.approx(point["takeover_rate"])


def test_an_expert_that_keeps_the_wheel_counts_as_its_manoeuvre(deployed: Path) -> None:  # noqa: F811
    from core.agents import load_agent
    from studies.calibrate import run_gated

    def engaged_env() -> object:
        env = envs.make("dynamic")
        env.unwrapped.expert_engaged = lambda: True  # always mid-manoeuvre: once given the wheel, it keeps it
        return env

    agent = load_agent(deployed)
    point = run_gated(agent, engaged_env, _ScriptedGate([(0.9, True)] + [(0.1, False)] * 7), 4, None)
    assert point["takeover_rate"] == pytest.approx(1.0)
    assert point["takeover_fear"] > 0 and point["takeover_manoeuvre"] > point["takeover_fear"]
    assert point["takeover_hold"] == point["takeover_hysteresis"] == 0


def test_fear_before_a_late_handoff_is_read_against_the_threshold(deployed: Path) -> None:  # noqa: F811
    """fear_before_handoff: for the violations with the expert driving, fear's peak over τ in the steps before the
    expert's last takeover began (median); NaN where the expert drove at no violation."""
    from core.agents import load_agent
    from studies.calibrate import RandomGate, run_gated

    def make_env() -> object:
        env = envs.make("dynamic")
        inner = env.unwrapped
        # an expert blind to the obstacle, heading straight for the goal: it meets the obstacle as the policy does
        inner.expert_action = lambda: (lambda d: (d / np.linalg.norm(d)).astype(np.float32))(envs.GOAL - inner.pos)
        return env

    agent = load_agent(deployed)
    # fear steady at 0.1 or 0.4 of τ = 0.5 while the gate hands the expert 5 of every 8 steps whatever fear says
    low = run_gated(agent, make_env, _ScriptedGate([(0.05, False)] * 3 + [(0.05, True)] * 5), 8, None)
    high = run_gated(agent, make_env, _ScriptedGate([(0.2, False)] * 3 + [(0.2, True)] * 5), 8, None)
    assert low["violations_under_expert"] > 0 and high["violations_under_expert"] > 0
    assert low["fear_before_handoff"] == pytest.approx(0.1) and high["fear_before_handoff"] == pytest.approx(0.4)
    never = run_gated(agent, make_env, RandomGate(agent.make_gate(), hold=1, p=0.0), 4, None)
    assert never["violations_under_expert"] == 0 and math.isnan(never["fear_before_handoff"])


class _SteadyFear:
    """A gate that never fires and reports the same fear at every step, with a τ_min of 0.2."""

    def __init__(self, fear: float) -> None:
        self.fear = fear
        self.threshold = type("Threshold", (), {"tau_min": 0.2})()

    def reset(self) -> None:
        pass

    def decide(self, obs: np.ndarray, a_rl: np.ndarray) -> GateDecision:
        return GateDecision(self.fear, 0.9, False)

    def observe(self, obs: np.ndarray, action: np.ndarray, next_obs: np.ndarray) -> float:
        return 0.0


def test_a_violation_the_gate_missed_is_unforeseen_only_when_fear_stayed_under_tau_min(
    deployed: Path,  # noqa: F811
) -> None:
    from core.agents import load_agent
    from studies.calibrate import run_gated

    agent = load_agent(deployed)
    make_env = functools.partial(envs.make, "dynamic")
    seen = run_gated(agent, make_env, _SteadyFear(0.5), 6, None)
    blind = run_gated(agent, make_env, _SteadyFear(0.1), 6, None)
    bad = round(seen["violation_rate"] * 6)
    assert bad > 0 and blind["violation_rate"] == seen["violation_rate"]
    assert seen["violations_under_threshold"] == bad and seen["violations_unforeseen"] == 0
    assert blind["violations_unforeseen"] == bad and blind["violations_under_threshold"] == 0


def test_curves_are_compared_at_equal_takeover_with_intervals() -> None:
    from studies.calibrate import compare_curves

    def point(takeover: float, violations: int, episodes: int = 20) -> dict[str, float]:
        return {"takeover_rate": takeover, "violation_rate": violations / episodes, "episodes": episodes}

    curve = {
        "fear (SAGE)": [point(0.10, 0), point(0.20, 4), point(0.30, 12), point(0.45, 2, 10), point(0.60, 0)],
        "random": [point(0.11, 15), point(0.21, 6), point(0.29, 2), point(0.46, 7, 10)],
    }
    # 0/20 vs 15/20: better; 4/20 vs 6/20: tied; 12/20 vs 2/20: worse; nothing near 60%. 2/10 vs 7/10 is better
    # although the two Wilson intervals overlap (0.06-0.51 and 0.40-0.89): the difference's interval excludes 0
    assert compare_curves(curve, "random") == {"better": 2, "tied": 1, "worse": 1, "unmatched": 1}
    assert compare_curves(curve, "curiosity only")["unmatched"] == 5


def test_operating_curve_figure_draws_intervals_at_zero_and_all_episodes(tmp_path: Path) -> None:
    """Rates of 0 and 1 (where the Wilson bound equals the rate up to rounding) still draw."""
    from studies.calibrate import CalibrationReport, SignalScore

    def point(takeover: float, violations: int) -> dict[str, float]:
        return {"takeover_rate": takeover, "violation_rate": violations / 10, "episodes": 10, "knob": 1.0}

    report = CalibrationReport(
        run="r", sim="point", scenario="s", episodes=10, steps=100, horizon_s=1.0, horizon_steps=10, violations=3,
        positives=30, scores={"fear": SignalScore(0.9, 0.5)}, fire_rate_before_violation=0.5,
        fire_rate_elsewhere=0.1, violations_warned=0.5, mean_lead_time_s=0.3,
        curve={"fear (SAGE)": [point(0.1, 10), point(0.3, 0)], "random": [point(0.1, 10), point(0.3, 7)]},
    )  # fmt: skip
    paths = write_figures(report, tmp_path)
    assert (tmp_path / "operating_curve.png") in paths
    assert "1 better, 1 tied, 0 worse" in report.summary()


def test_the_operating_curves_scaled_gate_keeps_the_sage_gates_hysteresis() -> None:
    """The curve's fear points are the SAGE gate itself at ``gate.tau_scale``: τ and the release level scaled."""
    from tests.core.sage.test_gate import fitted_gate

    # τ = 0.5, τ_min = 0.15, scale 0.8: fires over 0.4, and once fired holds while fear is over 0.8 · 0.15
    fears = [0.3, 0.45, 0.3, 0.2, 0.1, 0.1, 0.3]
    obs, action = np.zeros(3, np.float32), np.zeros(2, np.float32)
    for release, expected in (
        (1.0, [False, True, True, True, True, False, False]),
        (0.0, [False, True, True, False, False, False, False]),
    ):
        gate = fitted_gate(2, list(fears), release=release)
        gate.cfg.tau_scale = 0.8  # the config its threshold reads too
        gate.threshold.set_bounds((0.15, 0.85))  # scaled: 0.12 and 0.68
        gate.threshold.threshold = gate.threshold.neutral()  # 0.8 · 0.5
        assert [gate.decide(obs, action).fired for _ in fears] == expected


def test_a_reference_gating_holds_and_hands_back_control_as_the_sage_gate_does() -> None:
    """One hold (:class:`core.sage.gate.TakeoverHold`): a reference gating whose rule is the SAGE gate's own (fear
    over τ) takes control and hands it back at the same steps as the SAGE gate, whatever the hold, also after a
    reset."""
    from studies.calibrate import HoldGate
    from tests.core.sage.test_gate import fitted_gate

    class FearOverTau(HoldGate):
        def rule(self, decision: GateDecision) -> bool:
            return decision.fear > decision.threshold

    fears = [float(f) for f in np.random.default_rng(0).uniform(0.0, 0.9, 60)]  # τ = 0.5
    obs, action = np.zeros(3, np.float32), np.zeros(2, np.float32)
    for k in (1, 2, 3, 5):
        sage = fitted_gate(k, list(fears), release=0.0)
        reference = FearOverTau(fitted_gate(k, list(fears), release=0.0), hold=k)
        taken: list[list[bool]] = []
        for gate in (sage, reference):
            fired = [gate.decide(obs, action).fired for _ in range(30)]
            gate.reset()
            taken.append(fired + [gate.decide(obs, action).fired for _ in range(30)])
        assert taken[0] == taken[1]
        # both take control, hand it back, and hold past a step with fear under τ (for k > 1)
        assert any(taken[0]) and not all(taken[0])
        if k > 1:
            assert any(on and f <= 0.5 for on, f in zip(taken[0], fears, strict=True))


def test_gate_with_expert_runs_the_gate_with_the_settings_it_is_given(deployed: Path) -> None:  # noqa: F811
    from studies.calibrate import gate_with_expert

    make_env = functools.partial(envs.make, "dynamic")
    fixed = {"tau_from_data": False, "use_curiosity": False}
    deaf = gate_with_expert(deployed, make_env, 4, tau_min=1.0, tau_max=1.0, **fixed)  # fear never exceeds 1
    eager = gate_with_expert(deployed, make_env, 4, tau_min=0.0, tau_max=0.0, **fixed)
    assert deaf["takeover_rate"] == 0.0 and eager["takeover_rate"] > 0.9


def test_calibration_runs_the_gate_with_the_settings_it_is_given(deployed: Path) -> None:  # noqa: F811
    """``sage gate evaluate --set gate.KEY=VALUE``: the watching gate, its operating curve and the lead replay all
    take them."""
    from studies.calibrate import expert_lead

    make_env = functools.partial(envs.make, "dynamic")
    fixed = {"tau_from_data": False, "use_curiosity": False}
    eager, deaf = fixed | {"tau_min": 0.0, "tau_max": 0.0}, fixed | {"tau_min": 1.0, "tau_max": 1.0}
    common = dict(dt=0.1, sim="point", scenario="dynamic", episodes=4, curve_episodes=2, curve_scales=(1.0,))
    asking = calibrate_run(deployed, make_env, gate_settings=eager, **common)
    silent = calibrate_run(deployed, make_env, gate_settings=deaf, **common)  # fear never exceeds 1
    assert asking.fire_rate_elsewhere == 1.0 and silent.fire_rate_elsewhere == 0.0
    assert asking.curve["fear (SAGE)"][0]["takeover_rate"] == 1.0
    assert silent.curve["fear (SAGE)"][0]["takeover_rate"] == 0.0
    assert any(expert_lead(deployed, make_env, 0.1, episodes=4, gate_settings=eager).gate_warning_s)
    assert not any(expert_lead(deployed, make_env, 0.1, episodes=4, gate_settings=deaf).gate_warning_s)


def test_curiosity_levels_are_set_to_take_over_the_asked_share_of_steps() -> None:
    from studies.calibrate import firing_share, level_for_share

    curiosities = np.arange(100, dtype=float)
    for share in (0.05, 0.25, 0.5):
        level = level_for_share(curiosities, share)
        assert (curiosities > level).mean() == share
    assert level_for_share(curiosities, 0.0) == math.inf and level_for_share([], 0.3) == math.inf
    # a k-step hold turns a per-step firing share p into a takeover share k p / (1 + (k - 1) p), and back
    for p in (0.0, 0.02, 0.1, 0.5, 1.0):
        rate = 5 * p / (1 + 4 * p)
        assert math.isclose(firing_share(rate, 5), p, abs_tol=1e-9)


def test_expert_lead_replays_each_violation_with_the_expert_taking_over_before_it(deployed: Path) -> None:  # noqa: F811
    from studies.calibrate import expert_lead

    report = expert_lead(deployed, functools.partial(envs.make, "dynamic"), dt=0.1, episodes=10, leads_s=(0.0, 2.0))
    assert report.violations > 0, "the statically trained policy should meet the moving obstacle"
    assert len(report.gate_warning_s) == report.violations
    assert all(0.0 <= w <= 2.0 for w in report.gate_warning_s)
    # the replay is the same episode up to the takeover (a drifted replay would miss some collisions): taking over
    # at the very step of the contact, the expert's one action comes too late in the point world
    assert report.left[0] == report.violations
    # two seconds ahead, the expert (which knows the obstacle's future) keeps clear of every one of them
    assert report.left[1] == 0
    assert report.needed_s() == 2.0


def test_the_warning_needed_is_the_shortest_lead_that_avoided_every_violation() -> None:
    from studies.calibrate import LeadReport

    report = LeadReport(
        episodes=20, violations=4, gate_warning_s=[0.2, 0.6, 0.6, 3.0], leads_s=[0.5, 1.0, 2.0], left=[3, 1, 0]
    )
    assert report.needed_s() == 2.0
    assert "median 0.6 s" in report.summary() and "needs: 2 s" in report.summary()
    never = LeadReport(episodes=20, violations=2, gate_warning_s=[0.0, 0.0], leads_s=[0.5, 1.0], left=[2, 1])
    assert math.isnan(never.needed_s()) and "needs: more" in never.summary()
    calm = LeadReport(episodes=20, violations=0, gate_warning_s=[], leads_s=[0.5], left=[0])
    assert calm.needed_s() == 0.0 and "nothing to avoid" in calm.summary()


def test_gate_target_reads_rows_and_says_what_their_episodes_decide() -> None:
    from studies.calibrate import GateTarget

    target = GateTarget()
    assert target.met(5, 100, 0.35)
    assert not target.met(6, 100, 0.20)  # one violation too many
    assert not target.met(3, 100, 0.36)  # one point of takeover too many
    # 0/100: the Wilson interval reaches 3.7%, under 5%; 2/100 reaches 7.0%: undecided though met as read
    assert target.decided(0, 100) == "under"
    assert target.decided(2, 100) == "undecided"
    assert target.decided(2, 300) == "under"
    assert target.decided(15, 100) == "over"
    assert target.decided(7, 100) == "undecided"
    with pytest.raises(ValueError, match="episode"):
        target.met(0, 0, 0.1)


def test_a_privileged_gate_hands_over_on_the_step_after_the_simulator_reports_danger(
    deployed: Path,  # noqa: F811
) -> None:
    from core.agents import load_agent
    from studies.calibrate import InfoGate, RandomGate, run_gated

    agent = load_agent(deployed)
    make_env = functools.partial(envs.make, "dynamic")
    never = run_gated(agent, make_env, RandomGate(agent.make_gate(), hold=1, p=0.0), 8, None)
    blind = InfoGate(agent.make_gate(), 3, lambda info: False)
    unmoved = run_gated(agent, make_env, blind, 8, None, listeners=[blind.watch])
    assert unmoved["takeover_rate"] == 0.0 and unmoved["violation_rate"] == never["violation_rate"] > 0
    # the point world's info reports the obstacle's proximity as a cost: the gate reads the last step's
    near = InfoGate(agent.make_gate(), 3, lambda info: info["cost"] > 0.0)
    steps: list[tuple[int, float, bool]] = []
    gated = run_gated(
        agent,
        make_env,
        near,
        8,
        None,
        listeners=[near.watch, lambda r: steps.append((r.episode, r.info["cost"], r.takeover))],
    )
    assert 0.0 < gated["takeover_rate"] < 1.0
    pairs = [(before, after) for before, after in itertools.pairwise(steps) if before[0] == after[0]]
    assert any(before[1] > 0 for before, _ in pairs)
    for (_, cost, held), (_, _, takeover) in pairs:
        if cost > 0:
            assert takeover, "danger reported on a step: the expert drives the next"
        elif takeover and not held:
            raise AssertionError("a takeover began without danger reported on the step before it")
    # an episode's first step has no last step to read: never a takeover there
    firsts = [step for i, step in enumerate(steps) if i == 0 or steps[i - 1][0] != step[0]]
    assert not any(takeover for _, _, takeover in firsts)


def test_the_scale_chosen_is_the_largest_that_meets_the_target_on_every_scenario(deployed: Path) -> None:  # noqa: F811
    """``gate.tau_scale`` as the product runs it: a scale that lifts τ over any fear leaves the policy alone (and its
    violations), one that sinks it under every fear hands every step to the expert; the choice follows the target."""
    from studies.calibrate import GateTarget, choose_tau_scale

    make_envs = {"dynamic": functools.partial(envs.make, "dynamic")}
    fixed = {"tau_from_data": False, "use_curiosity": False, "tau_min": 0.5, "tau_max": 0.5}
    deaf, eager = 4.0, 1e-6  # τ = 2 (fear never exceeds 1) and τ ≈ 0

    # any violation share will do: the largest scale is chosen and nothing below it is driven
    easy = choose_tau_scale(deployed, make_envs, 4, (eager, deaf), GateTarget(1.0, 1.0), gate_settings=fixed)
    assert easy.met and easy.scale == deaf and [r["scale"] for r in easy.rows] == [deaf]
    assert easy.rows[0]["takeover_rate"] == 0.0 and easy.rows[0]["violations"] > 0
    # the rows ran with these settings over the run's own, so the choice holds with them and deploys them
    assert easy.gate_settings == fixed and easy.deploy_settings() == {**fixed, "tau_scale": deaf}
    assert "gate tau_from_data=False" in easy.summary()

    # no violation allowed: the policy alone misses it, the expert driving throughout does better
    strict = choose_tau_scale(deployed, make_envs, 4, (deaf, eager), GateTarget(0.0, 1.0), gate_settings=fixed)
    by_scale = {r["scale"]: r for r in strict.rows}
    assert by_scale[eager]["takeover_rate"] > 0.9
    # τ about 0: the expert drives because fear is over τ, step after step, not because of the hold after it
    assert by_scale[eager]["takeover_fear"] > 0.9 and by_scale[deaf]["takeover_fear"] == 0.0
    parts = sum(by_scale[eager][f"takeover_{c}"] for c in ("fear", "hold", "hysteresis", "manoeuvre"))
    assert parts == pytest.approx(by_scale[eager]["takeover_rate"])
    assert by_scale[eager]["violations"] < by_scale[deaf]["violations"]
    assert strict.scale == eager and strict.met == (by_scale[eager]["violations"] == 0)

    # no takeover allowed and no violation: nothing meets it, so nothing is chosen: the run's own scale stays
    none = choose_tau_scale(deployed, make_envs, 4, (deaf, eager), GateTarget(0.0, 0.0), gate_settings=fixed)
    assert not none.met and none.scale == 1.0 and len(none.rows) == 2
    assert "gate.tau_scale=1 stays" in none.summary()


def test_choosing_a_scale_refuses_bad_input_before_any_episode(deployed: Path) -> None:  # noqa: F811
    from studies.calibrate import choose_tau_scale

    make_envs = {"dynamic": functools.partial(envs.make, "dynamic")}
    with pytest.raises(ValueError, match="scales"):
        choose_tau_scale(deployed, make_envs, 2, (1.0, 0.0))
    with pytest.raises(ValueError, match="scenario"):
        choose_tau_scale(deployed, {}, 2)
    with pytest.raises(ValueError, match="release"):
        choose_tau_scale(deployed, make_envs, 2, gate_settings={"release": 2.0})


def test_the_curves_points_run_apart_on_ray_give_the_curve_run_in_turn(
    ray_local: None,
    deployed: Path,  # noqa: F811
) -> None:
    """Each point of a :class:`CurvePlan` stands alone (its own agent, gate and seeds): run as Ray tasks in fresh
    workers, two at a time, or here in another order, they give the curve that :func:`operating_curve` measures one
    after another, with the scripted expert alone as its floor."""
    from studies.calibrate import EXPERT_ALONE, CurvePlan, curve_point, operating_curve

    make_env = functools.partial(envs.make, "dynamic")
    scales = (2.0,)  # one fear point: five Ray tasks in two stages (two scales took eight, the suite's slowest test)
    in_turn = operating_curve(deployed, make_env, 2, scales)
    on_ray = operating_curve(deployed, make_env, 2, scales, cpus=2)
    plan = CurvePlan(scales)
    common = {"run": deployed, "make_env": make_env, "episodes": 2}
    first = [curve_point(**common, call=call) for call in reversed(plan.first())][::-1]

    def shown(curve: dict[str, list[dict[str, float]]]) -> dict[str, list[dict[str, float | None]]]:
        return {k: [{f: None if math.isnan(v) else v for f, v in p.items()} for p in ps] for k, ps in curve.items()}

    assert shown(on_ray) == shown(in_turn)
    # the first stage's points in another order: each stands alone
    second = [curve_point(**common, call=call) for call in plan.second(first)]
    assert shown(plan.curve(first, second)) == shown(in_turn)
    assert [len(points) for points in in_turn.values()] == [1, 1, 1, 1]
    alone = in_turn[EXPERT_ALONE][0]
    assert alone["takeover_rate"] == 1.0 and alone["violations_handed_back"] == alone["violations_unforeseen"] == 0
    with pytest.raises(ValueError, match="first stage"):
        plan.curve(first[:-1], second)
    with pytest.raises(ValueError, match="unknown curve call"):
        curve_point(deployed, make_env, 1, {"kind": "fearless"})


def test_a_scale_sweep_on_ray_measures_every_row_and_chooses_by_the_same_rule(
    ray_local: None,
    deployed: Path,  # noqa: F811
) -> None:
    """``cpus``/``address``: every (scale, scenario) row at once, each a Ray task in a fresh worker; the rows are the
    ones this process measures on the same seeds, and the rule reads them as it does here."""
    from studies.calibrate import GateTarget, choose_tau_scale

    make_envs = {"dynamic": functools.partial(envs.make, "dynamic"), "static": functools.partial(envs.make, "static")}
    fixed = {"tau_from_data": False, "use_curiosity": False, "tau_min": 0.5, "tau_max": 0.5}
    scales, target = (4.0, 1e-6), GateTarget(1.0, 0.5)  # any violations; takeover at most half the steps
    here = choose_tau_scale(deployed, make_envs, 3, scales, target, gate_settings=fixed)
    there = choose_tau_scale(deployed, make_envs, 3, scales, target, gate_settings=fixed, cpus=2)
    # here the sweep stops at the largest scale, which meets the target; on Ray every row was driven
    assert here.met and there.met and here.scale == there.scale == 4.0
    assert len(here.rows) == 2 and len(there.rows) == 4
    assert there.rows[:2] == here.rows
    assert [(r["scale"], r["scenario"]) for r in there.rows[2:]] == [(1e-6, "dynamic"), (1e-6, "static")]
    assert all(r["takeover_rate"] > 0.9 and not r["met"] for r in there.rows[2:])


def test_a_point_on_two_runs_of_new_seeds_pools_to_the_point_on_all_of_them(deployed: Path) -> None:  # noqa: F811
    """A curve point run again at its own knob from another first seed (:class:`CurveExtension`): two runs on
    adjacent seed ranges pool to the run over both; a comparison gating called with a knob runs at it as it is."""
    from studies.calibrate import EVAL_SEED, curve_point, pool_points

    make_env = functools.partial(envs.make, "dynamic")
    for call in (
        {"kind": "fear", "knob": 0.5},
        {"kind": "random", "knob": 0.3},
        {"kind": "curiosity only", "knob": 0.0},
    ):
        whole = curve_point(deployed, make_env, 4, call, first_seed=EVAL_SEED + 10)
        parts = [curve_point(deployed, make_env, 2, call, first_seed=EVAL_SEED + s) for s in (10, 12)]
        pooled = pool_points(parts)
        assert whole["knob"] == pooled["knob"] == call["knob"] and pooled["episodes"] == whole["episodes"] == 4
        if call["kind"] == "random":  # its own draws start again with each run's first seed: other episodes
            continue
        for key in ("steps", "takeover_rate", "violation_rate", "violations_under_expert", "violations_unforeseen"):
            assert pooled[key] == pytest.approx(whole[key]), (call, key)
    # curiosity over a level of 0 fires on nearly every step: the knob is used as given, no rate matched
    assert curve_point(deployed, make_env, 2, {"kind": "curiosity only", "knob": 0.0})["takeover_rate"] > 0.9
    # the seeds move the episodes
    fear = [
        curve_point(deployed, make_env, 3, {"kind": "fear", "knob": 0.5}, first_seed=EVAL_SEED + s) for s in (0, 50)
    ]
    assert fear[0]["steps"] != fear[1]["steps"]


def _point(takeover: float, violations: int, episodes: int = 1000, knob: float = 1.0) -> dict[str, float]:
    return {"knob": knob, "takeover_rate": takeover, "violation_rate": violations / episodes, "episodes": episodes}


def test_pooled_points_add_counts_and_weigh_rates_by_steps_or_episodes() -> None:
    from studies.calibrate import pool_points

    a = _point(0.4, 10) | {"violations_under_expert": 4.0, "expert_steps_before_violation": 10.0}
    b = _point(0.6, 30, 3000) | {"violations_under_expert": 6.0, "expert_steps_before_violation": 5.0}
    pooled = pool_points([a, b])
    assert pooled["episodes"] == 4000 and pooled["violation_rate"] == pytest.approx(40 / 4000)
    assert pooled["takeover_rate"] == pytest.approx(0.55)  # by episodes: neither run counted its steps
    assert pooled["violations_under_expert"] == 10 and pooled["expert_steps_before_violation"] == pytest.approx(7.0)
    stepped = pool_points([a | {"steps": 9000.0}, b | {"steps": 1000.0}])
    assert stepped["takeover_rate"] == pytest.approx(0.42) and stepped["steps"] == 10000
    with pytest.raises(ValueError, match="different knobs"):
        pool_points([a, b | {"knob": 2.0}])
    with pytest.raises(ValueError, match="no points"):
        pool_points([])


def test_an_extension_takes_fears_points_with_their_matched_counterparts_or_interpolates_one() -> None:
    from studies.calibrate import EVAL_SEED, CurveExtension

    curve = {
        "fear (SAGE)": [_point(0.23, 62, knob=1.4), _point(0.47, 25, knob=0.5), _point(0.56, 14, knob=0.3)],
        "random": [_point(0.49, 50, knob=0.068), _point(0.63, 31, knob=0.092)],
        "curiosity only": [_point(0.49, 34, knob=3.29), _point(0.58, 17, knob=2.77)],
        "expert alone": [_point(1.0, 1)],
    }
    points = CurveExtension([0.47, 0.56]).points(curve)
    assert [(p.kind, p.knob) for p in points[:3]] == [("fear (SAGE)", 0.5), ("random", 0.068), ("curiosity only", 3.29)]
    assert [p.call()["kind"] for p in points[:3]] == ["fear", "random", "curiosity only"]
    fear, random, curiosity = points[3:]
    assert fear.near == 0.56 and curiosity.knob == 2.77 and curiosity.prior is curve["curiosity only"][1]
    # no random point within 5 points of 56%: one at the share halfway from 49%'s to 63%'s, new episodes only
    assert random.prior is None and random.knob == pytest.approx(0.068 + 0.5 * (0.092 - 0.068))
    assert CurveExtension.first_seed(curve) == EVAL_SEED + 1000
    assert [p.kind for p in CurveExtension([0.23], ("curiosity only",)).points(curve)] == ["fear (SAGE)"]
    with pytest.raises(ValueError, match="no fear point within 5% of 35%"):
        CurveExtension([0.35]).points(curve)


def test_an_extensions_verdict_is_read_off_the_pooled_episodes() -> None:
    from core.metrics import difference_interval
    from studies.calibrate import CurveExtension, extension_rows

    curve = {"fear (SAGE)": [_point(0.47, 25, knob=0.5)], "curiosity only": [_point(0.49, 34, knob=3.29)]}
    points = CurveExtension([0.47], ("curiosity only",)).points(curve)
    # 25 against 34 of 1000 is undecided; 75 against 110 of 3000 more decides the pooled 100 against 144 of 4000
    rows = extension_rows(points, [_point(0.47, 75, 3000, 0.5), _point(0.49, 110, 3000, 3.29)])
    (row,) = rows
    assert row["fear"]["pooled"]["episodes"] == 4000 and row["verdict"] == "better"
    assert row["pooled_interval"][1] < 0
    assert row["new_interval"] == difference_interval(75, 3000, 110, 3000)  # the new episodes alone
    tied = extension_rows(points, [_point(0.47, 90, 3000, 0.5), _point(0.49, 100, 3000, 3.29)])
    assert tied[0]["verdict"] == "tied"
    worse = extension_rows(points, [_point(0.47, 150, 3000, 0.5), _point(0.49, 90, 3000, 3.29)])
    assert worse[0]["verdict"] == "worse"
    apart = extension_rows(points, [_point(0.47, 75, 3000, 0.5), _point(0.70, 110, 3000, 3.29)])
    assert apart[0]["verdict"] == "unmatched"  # the pooled takeover rates drifted more than 5 points apart
    with pytest.raises(ValueError, match="2 points"):
        extension_rows(points, [_point(0.47, 75, 3000)])
