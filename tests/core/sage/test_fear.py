"""Fear, curiosity and threshold: the fast gate path equals the reference, fear reads UGV danger, τ moves
against curiosity."""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import pytest
import torch

from core.sage.calibration import calibrate
from core.sage.config import GateConfig, WorldModelConfig, set_field
from core.sage.fear import GateKernel, fear, rollout
from core.sage.networks import Actor
from core.sage.threshold import CuriosityThreshold
from core.sage.world_model import EnsembleWorldModel

torch.set_num_threads(1)


def random_model(obs_dim: int = 6, act_dim: int = 2, seed: int = 0) -> tuple[EnsembleWorldModel, Actor]:
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    model = EnsembleWorldModel(obs_dim, act_dim, WorldModelConfig(hidden=32, max_updates_per_fit=50))
    s = rng.normal(size=(300, obs_dim)).astype(np.float32)
    a = rng.uniform(-1, 1, (300, act_dim)).astype(np.float32)
    model.fit(s, a, s + 0.1 * rng.normal(size=s.shape).astype(np.float32), rng.random(300).astype(np.float32), rng)
    actor = Actor(obs_dim, act_dim, 32, 2, -torch.ones(act_dim) * 2, torch.ones(act_dim) * 2)  # scaled actions
    calibrate(model, actor.deterministic, torch.as_tensor(s), 5)
    return model, actor


@pytest.mark.parametrize("aggregate", ["max", "discounted_mean"])
def test_gate_kernel_equals_the_reference_fear(aggregate: str) -> None:
    model, actor = random_model()
    cfg = GateConfig(aggregate=aggregate, beta=0.3)
    kernel = GateKernel(model.folded(), actor.deterministic_layers(), actor.action_scale, actor.action_bias, cfg)
    for seed in range(5):
        g = torch.Generator().manual_seed(seed)
        obs, action = torch.randn(1, 6, generator=g), torch.rand(1, 2, generator=g) * 4 - 2
        with torch.inference_mode():
            value, cost, sigma = kernel(obs, action)
            reference = fear(model.folded(), actor.deterministic, obs, action, cfg)
        assert value == pytest.approx(float(reference.fear), abs=1e-5)
        assert cost == pytest.approx(float(reference.cost), abs=1e-5)
        assert sigma == pytest.approx(float(reference.sigma), abs=1e-5)
        nxt = obs + 0.1
        with torch.inference_mode():
            c_fast = kernel.curiosity(obs, action, nxt)
        with torch.no_grad():
            assert c_fast == pytest.approx(float(model.curiosity(obs, action, nxt)), rel=1e-4)


def test_kernel_follows_actor_updates_in_place() -> None:
    model, actor = random_model()
    cfg = GateConfig()
    kernel = GateKernel(model.folded(), actor.deterministic_layers(), actor.action_scale, actor.action_bias, cfg)
    obs, action = torch.randn(1, 6), torch.zeros(1, 2)
    with torch.no_grad():
        for p in actor.parameters():
            p.add_(0.5)
    with torch.inference_mode():
        assert kernel(obs, action)[0] == pytest.approx(
            float(fear(model.folded(), actor.deterministic, obs, action, cfg).fear), abs=1e-5
        )


def test_fear_is_bounded_and_differentiable_wrt_the_action_only() -> None:
    model, actor = random_model()
    obs = torch.randn(16, 6)
    action = torch.zeros(16, 2, requires_grad=True)
    terms = fear(model.folded(), actor.deterministic, obs, action, GateConfig())
    assert bool(((terms.fear >= 0) & (terms.fear <= 1)).all())
    terms.fear.sum().backward()
    assert action.grad is not None and float(action.grad.abs().sum()) > 0
    assert all(p.grad is None for p in model.parameters())


def test_multi_step_disagreement_grows_along_the_rollout() -> None:
    model, actor = random_model()
    with torch.no_grad():
        ro = rollout(model.folded(), actor.deterministic, torch.randn(64, 6), torch.zeros(64, 2), 5)
    divergence = (ro.states - ro.states.mean(1, keepdim=True)).pow(2).mean(dim=(1, 2, 3))
    assert float(divergence[0]) < 1e-12 and bool((divergence[1:].diff() > 0).all())


def test_threshold_falls_as_curiosity_rises() -> None:
    # a frozen average and no smoothing isolate ρ
    cfg = GateConfig(tau_min=0.2, tau_max=0.8, curiosity_ema=0.0, curiosity_smoothing=1.0)
    threshold = CuriosityThreshold(cfg, reference=1.0)
    taus = [threshold.update(c) for c in (0.0, 0.5, 1.0, 2.0, 10.0, 1e6)]
    assert taus[0] == pytest.approx(0.8) and taus[2] == pytest.approx(0.5)
    assert all(a > b for a, b in itertools.pairwise(taus))
    assert taus[-1] == pytest.approx(0.2, abs=1e-4) and min(taus) >= 0.2


def test_geometric_threshold_moves_tau_by_equal_ratios_between_the_same_bounds() -> None:
    """Bounds a factor 10 apart (SUMO's): the linear τ at typical curiosity sits at their mean, the geometric one
    at their geometric mean; both run from τ_max to τ_min and fall as curiosity rises."""
    curiosities = (0.0, 0.5, 1.0, 2.0, 10.0, 1e6)
    taus = {}
    for how in ("linear", "geometric"):
        cfg = GateConfig(tau_min=0.05, tau_max=0.5, curiosity_ema=0.0, curiosity_smoothing=1.0, tau_interpolation=how)
        threshold = CuriosityThreshold(cfg, reference=1.0)
        taus[how] = [threshold.update(c) for c in curiosities]
        assert taus[how][0] == pytest.approx(0.5) and taus[how][-1] == pytest.approx(0.05, rel=1e-3)
        assert all(a > b for a, b in itertools.pairwise(taus[how]))
        assert CuriosityThreshold(cfg, reference=1.0).neutral() == pytest.approx(taus[how][2])
    assert taus["linear"][2] == pytest.approx(0.275)
    assert taus["geometric"][2] == pytest.approx(0.05**0.5 * 0.5**0.5)
    # equal steps of ρ, equal ratios of τ: ρ = 0.2 (C = 0.5) and 0.5 (C = 1) are 0.3 apart, as are 0.5 and 0.8
    ratio_low = taus["geometric"][1] / taus["geometric"][2]
    ratio_high = taus["geometric"][2] / taus["geometric"][3]
    assert ratio_low == pytest.approx(ratio_high)
    with pytest.raises(ValueError, match="tau_interpolation"):
        set_field(GateConfig(), "tau_interpolation", "cubic")


def test_smoothed_curiosity_keeps_tau_from_jumping_step_to_step() -> None:
    rng = np.random.default_rng(0)
    noisy = np.exp(rng.normal(0.0, 0.8, size=400))  # everyday curiosity: log-normal noise around its average
    jumps = {}
    for alpha in (1.0, 0.3):
        cfg = GateConfig(tau_min=0.2, tau_max=0.8, curiosity_ema=0.0, curiosity_smoothing=alpha)
        threshold = CuriosityThreshold(cfg, reference=1.0)
        taus = np.array([threshold.update(float(c)) for c in noisy])
        jumps[alpha] = float(np.abs(np.diff(taus)).mean())
    assert jumps[0.3] < 0.5 * jumps[1.0], jumps
    # a sustained surprise still moves τ within a few steps
    cfg = GateConfig(tau_min=0.2, tau_max=0.8, curiosity_ema=0.0, curiosity_smoothing=0.3)
    threshold = CuriosityThreshold(cfg, reference=1.0)
    taus = [threshold.update(c) for c in (1.0, 1.0, 6.0, 6.0, 6.0, 6.0)]
    assert taus[-1] < 0.3 < taus[1]


def test_tau_bounds_follow_the_fear_distribution() -> None:
    """Data-driven bounds: the quantiles of fear on familiar states, so they move when that fear moves."""
    cfg = GateConfig(tau_min_quantile=0.5, tau_max_quantile=0.9)
    low, high = [], []
    for shift in (0.0, 0.3):
        model = EnsembleWorldModel(4, 2, WorldModelConfig(members=3, hidden=16, patience=20))
        rng = np.random.default_rng(0)
        s = rng.normal(size=(300, 4)).astype(np.float32)
        a = rng.uniform(-1, 1, (300, 2)).astype(np.float32)
        labels = (rng.random(300) < shift).astype(np.float32)  # more violations ahead: higher predicted ĉ
        model.fit(s, a, s + 0.1 * rng.normal(size=s.shape).astype(np.float32), labels, rng, violation_soon=labels)
        calibrate(model, lambda o: torch.zeros(o.shape[0], 2), torch.as_tensor(s), 5, cfg=cfg)
        lo, hi = (float(v) for v in model.tau_bounds)
        assert 0.0 <= lo < hi <= 1.0
        low.append(lo)
        high.append(hi)
    assert low[1] > low[0] + 0.05 and high[1] > high[0] + 0.05, (low, high)


def test_curiosity_average_adapts_and_curiosity_can_be_switched_off() -> None:
    cfg = GateConfig(tau_min=0.2, tau_max=0.8, curiosity_ema=0.2, curiosity_smoothing=1.0)
    threshold = CuriosityThreshold(cfg, reference=1.0)
    first = threshold.update(4.0)
    for _ in range(50):
        last = threshold.update(4.0)  # sustained novelty becomes the new normal
    assert first < 0.4 and last == pytest.approx(0.5, abs=0.01)
    fixed = CuriosityThreshold(dataclasses.replace(cfg, use_curiosity=False), reference=1.0)
    assert fixed.update(100.0) == fixed.update(0.0) == pytest.approx(0.5)


@pytest.mark.filterwarnings("ignore::DeprecationWarning")
def test_fear_is_higher_facing_a_near_obstacle_than_in_open_space() -> None:
    sims = pytest.importorskip("sims")
    from core.loop import Runner
    from core.protocol import simulator
    from core.replay import ReplayBuffer

    class NoisyExpert:  # the expert with random actions mixed in: near misses as well as clean driving
        def __init__(self, env, rng) -> None:  # type: ignore[no-untyped-def]
            self.env, self.rng = env, rng

        def act(self, obs: np.ndarray, deterministic: bool = False) -> np.ndarray:
            if self.rng.random() < 0.3:
                return self.rng.uniform(-1, 1, 2).astype(np.float32)
            return np.asarray(simulator(self.env).expert_action(), np.float32)

    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    buffer = ReplayBuffer(58, 2, 10_000)
    env = sims.make("ugv", scenario=1)
    runner = Runner(env, NoisyExpert(env, rng), seed=0)
    runner.step_listeners.append(buffer.add_record)
    while len(buffer) < 2500:
        runner.run_episode()
    data = buffer.arrays()
    model = EnsembleWorldModel(58, 2, WorldModelConfig(max_updates_per_fit=800))
    model.fit(data["obs"], data["action"], data["next_obs"], data["cost"], rng)
    forward = torch.tensor([[1.0, 0.0]])
    obs = torch.as_tensor(data["obs"])
    calibrate(model, lambda o: forward.expand(o.shape[0], 2), obs[:1000], 5)
    front = obs[:, 18:36].min(1).values * 10.0  # the ±45° sectors, metres
    near, open_space = obs[front < 0.7], obs[front > 3.0]
    assert len(near) > 20 and len(open_space) > 20
    with torch.no_grad():
        policy = lambda o: forward.expand(o.shape[0], 2)  # noqa: E731
        f_near = fear(model.folded(), policy, near, forward.expand(len(near), 2), GateConfig())
        f_open = fear(model.folded(), policy, open_space, forward.expand(len(open_space), 2), GateConfig())
    assert float(f_near.fear.mean()) > float(f_open.fear.mean()) + 0.1
    assert float(f_near.cost.mean()) > 0.5 > 0.1 > float(f_open.cost.mean())


def test_states_fear_looks_past_to_a_violation_are_not_familiar_for_the_bounds() -> None:
    """The threshold bounds come from states whose fear the gate should leave alone: fear looks m rollout steps
    and then the label's window ahead, so every state within that reach of a violation is left out, and only those
    (with a low cost)."""
    from core.replay import ReplayBuffer
    from core.sage.model_trainer import familiar_for_bounds

    buffer = ReplayBuffer(1, 1, 100)
    for t in range(40):  # one episode: the violation at step 30, a dense cost of 0.5 at step 5
        violation = t == 30
        cost = 1.0 if violation else 0.5 if t == 5 else 0.0
        buffer.add([t], [0.0], 0.0, [t + 1], violation, cost=cost, violation=violation)
        if violation:
            break
    familiar = familiar_for_bounds(buffer, violation_steps=10, horizon=5)
    # rows 16-30 reach the violation within 15 steps; rows 16-20 lie beyond the label's own 10-step window
    assert not familiar[16:31].any() and not familiar[5]
    assert familiar[:5].all() and familiar[6:16].all()


def test_conflicts_are_not_familiar_for_the_bounds_where_the_model_learns_them() -> None:
    """With ``conflict_label_weight`` above 0 a conflict is a positive label, so its state is no familiar state for
    τ's bounds either; with 0 (the paper's ĉ) conflicts change nothing."""
    from core.replay import ReplayBuffer
    from core.sage.model_trainer import familiar_for_bounds

    buffer = ReplayBuffer(1, 1, 100)
    for t in range(20):  # no violation; conflicts at steps 8 and 9
        buffer.add([t], [0.0], 0.0, [t + 1], False, conflict=float(t in (8, 9)))
    assert familiar_for_bounds(buffer, violation_steps=10, horizon=5).all()
    familiar = familiar_for_bounds(buffer, violation_steps=10, horizon=5, conflict_weight=0.5)
    assert not familiar[8:10].any() and familiar[:8].all() and familiar[10:].all()


def test_tau_scale_multiplies_the_bounds_in_use_and_so_every_threshold() -> None:
    """``gate.tau_scale``: the measured bounds and the constants alike, so τ at any curiosity scales with it."""
    curiosities = (0.0, 0.5, 1.0, 3.0)
    for how in ("linear", "geometric"):
        common = dict(tau_min=0.1, tau_max=0.6, curiosity_ema=0.0, curiosity_smoothing=1.0, tau_interpolation=how)
        plain = CuriosityThreshold(GateConfig(**common), reference=1.0)
        half = CuriosityThreshold(GateConfig(tau_scale=0.5, **common), reference=1.0)
        assert (half.tau_min, half.tau_max) == pytest.approx((0.05, 0.3))
        assert [half.update(c) for c in curiosities] == pytest.approx([0.5 * plain.update(c) for c in curiosities])
        measured = CuriosityThreshold(GateConfig(tau_scale=2.0, **common), reference=1.0, bounds=(0.2, 0.4))
        assert (measured.tau_min, measured.tau_max) == pytest.approx((0.4, 0.8))
        measured.set_bounds(None)  # no measured bounds: the constants, scaled as well
        assert (measured.tau_min, measured.tau_max) == pytest.approx((0.2, 1.2))


@pytest.mark.parametrize("scale", [0.0, -1.0, math.nan, math.inf])
def test_a_tau_scale_that_is_not_a_positive_number_is_refused(scale: float) -> None:
    from core.sage.config import AgentConfig, validate

    cfg = AgentConfig()
    cfg.gate.tau_scale = scale
    with pytest.raises(ValueError, match=r"gate\.tau_scale"):
        validate(cfg)


def test_an_imagined_state_in_contact_is_a_violation_and_the_gate_kernel_agrees() -> None:
    """``imagined_contact``: a member whose predicted state falls to a contact floor has violation probability 1 at
    that step, whatever its head says; the others keep theirs. ĉ rises with the members' share in contact, σ̂ stays
    their disagreement about the learned danger, and the fast gate path equals the reference."""
    model, actor = random_model()
    obs, action = torch.zeros(1, 6), torch.zeros(1, 2)
    off = GateConfig()
    with torch.no_grad():
        plain = rollout(model.folded(), actor.deterministic, obs, action, off.horizon)
    first = plain.states[1, :, 0, 0].sort().values  # each member's predicted channel 0 after one step
    floor = float(first[1] + first[2]) / 2  # two members under it, the others over it (none within rounding of it)
    on = dataclasses.replace(off, imagined_contact=True, contact_floors=[floor])
    with torch.no_grad():
        touched = rollout(model.folded(), actor.deterministic, obs, action, on.horizon, contact=torch.tensor([floor]))
    in_contact = plain.states[1:, :, :, 0] <= floor
    assert 0 < int(in_contact[0].sum()) < model.folded().members
    assert torch.equal(touched.cost, torch.where(in_contact, torch.ones_like(plain.cost), plain.cost))
    assert torch.equal(touched.sigma_raw, plain.sigma_raw)  # σ̂: the disagreement about the learned danger
    kernel = GateKernel(model.folded(), actor.deterministic_layers(), actor.action_scale, actor.action_bias, on)
    with torch.inference_mode():
        value, cost, sigma = kernel(obs, action)
        reference = fear(model.folded(), actor.deterministic, obs, action, on)
        without = fear(model.folded(), actor.deterministic, obs, action, off)
    assert (value, cost, sigma) == pytest.approx(
        (float(reference.fear), float(reference.cost), float(reference.sigma)), abs=1e-5
    )
    assert float(reference.cost) > float(without.cost)
    member_costs = kernel.last_member_costs()
    assert (member_costs[in_contact[:, :, 0].numpy()] == 1.0).all()  # set, not computed: exact on both paths
    # The kernel's preallocated addmm/baddbmm chain and the rollout's batched ops sum in another order, and a
    # processor's vector width changes that order again (seen: AMD EPYC): float32 agreement is a few ulps of a
    # probability in [0, 1] (eps 1.2e-7), so rtol 1e-5 / atol 1e-6 and not bit equality.
    np.testing.assert_allclose(member_costs, touched.cost[:, :, 0].numpy(), rtol=1e-5, atol=1e-6)
    with pytest.raises(ValueError, match="contact_floors"):
        fear(model.folded(), actor.deterministic, obs, action, dataclasses.replace(on, contact_floors=[0.0] * 7))


def test_imagined_contact_can_require_the_real_scan_to_be_closing_there() -> None:
    """``contact_needs_closing``: a member's imagined contact in a channel counts only where the real last step shows
    that channel falling; with it rising (or no motion given) the same imagined states count no contact, and the
    fast gate path agrees with the reference either way."""
    model, actor = random_model()
    obs, action = torch.zeros(1, 6), torch.zeros(1, 2)
    with torch.no_grad():
        plain = rollout(model.folded(), actor.deterministic, obs, action, 5)
    first = plain.states[1, :, 0, 0].sort().values
    floor = float(first[1] + first[2]) / 2
    cfg = GateConfig(imagined_contact=True, contact_floors=[floor], contact_needs_closing=True)
    kernel = GateKernel(model.folded(), actor.deterministic_layers(), actor.action_scale, actor.action_bias, cfg)
    costs = {}
    for name, change in (("closing", -0.1), ("opening", 0.1), ("no motion", None)):
        motion = None if change is None else torch.full((1, 6), change)
        with torch.inference_mode():
            value, cost, _ = kernel(obs, action, motion)
            reference = fear(model.folded(), actor.deterministic, obs, action, cfg, motion=motion)
        assert (value, cost) == pytest.approx((float(reference.fear), float(reference.cost)), abs=1e-5)
        costs[name] = cost
    with torch.inference_mode():
        unrestricted = fear(model.folded(), actor.deterministic, obs, action, dataclasses.replace(cfg,
                            contact_needs_closing=False), motion=torch.full((1, 6), -0.1))  # fmt: skip
        untouched = fear(model.folded(), actor.deterministic, obs, action, GateConfig(), motion=torch.full((1, 6), 0.1))
    assert costs["closing"] == pytest.approx(float(unrestricted.cost), abs=1e-6)
    assert costs["opening"] == pytest.approx(float(untouched.cost), abs=1e-6)
    assert costs["opening"] < costs["closing"] and costs["no motion"] < costs["closing"]
