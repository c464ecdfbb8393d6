"""The fear-regularised SAC: penalty c*, dual λ, bounded ω, the fear gradient, and the baselines' updates."""

from __future__ import annotations

import copy
import dataclasses
import itertools
import math

import numpy as np
import pytest
import torch

from core.learners import make_learner
from core.sage.config import for_method
from core.sage.hg_dagger import HGDAgger
from core.sage.sac import SAC, advantage_weights, penalty_c_star, penalty_condition_holds
from core.sage.td3 import TD3

torch.set_num_threads(1)
OBS, ACT = 6, 2


def filled(method: str, n: int = 600, seed: int = 0, **overrides: object) -> SAC | TD3 | HGDAgger:
    """A learner whose buffer holds random transitions (every 5th an expert takeover) and, when it has a
    world model, a fitted one."""
    cfg = for_method(method, hidden=32, batch_size=64, bc_batch_size=32, **overrides)
    cfg.world_model_config.hidden = 32
    cfg.world_model_config.max_updates_per_fit = 100
    learner = make_learner(cfg.method, cfg, OBS, ACT, seed=seed)
    rng = np.random.default_rng(seed)
    s = rng.normal(size=(n + 1, OBS)).astype(np.float32)
    for i in range(n):
        a = rng.uniform(-1, 1, ACT).astype(np.float32)
        expert = np.clip(-s[i, :ACT], -1, 1).astype(np.float32)
        takeover = i % 5 == 0
        learner.buffer.add(
            s[i],
            expert if takeover else a,
            float(-np.abs(s[i]).sum()),
            s[i + 1],
            False,
            cost=float(rng.random()),
            violation=bool(i % 50 == 7),
            takeover=takeover,
            a_rl=a,
            a_expert=expert if takeover else None,
        )
    learner.warm = True
    if learner.world_model is not None:
        learner.fit_world_model()
    return learner


# -- c* -------------------------------------------------------------------------------------------
def test_c_star_satisfies_the_papers_inequality_for_random_bounds() -> None:
    rng = np.random.default_rng(0)
    for _ in range(2000):
        low, high = sorted(rng.uniform(-100, 100, 2))
        gamma, horizon, lam = rng.uniform(0.8, 0.999), int(rng.integers(1, 50)), rng.uniform(0, 50)
        c = penalty_c_star(low, high, gamma, horizon, lam)
        assert math.isfinite(c) and c >= 0
        assert penalty_condition_holds(c, low, high, gamma, horizon, lam)


def test_the_papers_formula_alone_can_break_the_inequality_and_ours_does_not() -> None:
    low, high, gamma, horizon, lam = 0.5, 1.0, 0.99, 10, 0.0  # all-positive rewards, narrow range
    gh = gamma**horizon
    paper = (high - low) / (gh * (1 - gamma)) + lam / gh - high / (1 - gamma)
    assert not penalty_condition_holds(paper, low, high, gamma, horizon, lam)
    assert penalty_condition_holds(penalty_c_star(low, high, gamma, horizon, lam), low, high, gamma, horizon, lam)
    # where eq:penalty is sufficient (UGV-like bounds) it is what we use
    assert penalty_c_star(-1.0, 1.5, 0.99, 10, 2.0) == pytest.approx(2.5 / (gamma**10 * 0.01) + 2.0 / gamma**10 - 150.0)


def test_a_violation_gets_the_terminal_target_minus_c_star() -> None:
    learner = filled("sage")
    batch = learner.buffer.sample(64, np.random.default_rng(1))
    batch.violation[:] = 0
    batch.violation[:5] = 1
    y = learner.critic_target_values(batch)
    assert torch.allclose(y[:5], torch.full((5,), -learner.c_star()))
    assert bool((y[5:] != -learner.c_star()).all())
    low, high = learner.reward_bounds()
    assert penalty_condition_holds(
        learner.c_star(), low, high, learner.cfg.gamma, learner.cfg.safety_horizon, learner.lam
    )


def test_c_star_is_a_real_penalty_whenever_rewards_are_bounded() -> None:
    """eq:penalty gives 0 for a flat reward range with λ = 0 (highway at the start); our c* does not."""
    assert penalty_c_star(0.0, 0.0, 0.99, 5, 0.0) < 1e-3
    learner = filled("sage", n=60)
    learner.buffer.set_rewards(np.arange(learner.buffer.size), 0.0)
    learner.buffer.set_rewards(3, -10.0, terminated=True)  # a terminal off-road penalty, outside the live bounds
    assert learner.c_star() >= 10.0
    learner.buffer.set_rewards(3, 0.0)
    assert learner.c_star() >= learner.cfg.c_star_floor > 0.0


# -- λ --------------------------------------------------------------------------------------------
def test_lambda_rises_while_fear_exceeds_the_budget_and_never_goes_negative() -> None:
    learner = filled("sage", fear_budget=0.0, fear_budget_from_data=False, lambda_init=0.5, lambda_lr=0.05)
    lams = [learner.lam]
    for _ in range(10):
        lams.append(learner.update()["lam"])
    assert all(b > a for a, b in itertools.pairwise(lams))
    learner.cfg.fear_budget = 1.0  # fear is always below: λ falls, and stops at 0
    for _ in range(200):
        lams.append(learner.update()["lam"])
        assert lams[-1] >= 0.0
    assert lams[-1] == 0.0 and min(lams) == 0.0


def with_predictable_violations(n: int = 1500, seed: int = 0, **overrides: object) -> SAC:
    """A SAGE learner whose buffer ends an episode in a violation wherever the first channel exceeds 1.3 (about
    a tenth of the states), its world model fitted on it."""
    cfg = for_method("sage", hidden=32, batch_size=128, **overrides)
    cfg.world_model_config.hidden = 32
    cfg.world_model_config.max_updates_per_fit = 600
    cfg.world_model_config.violation_steps = 1
    learner = make_learner(cfg.method, cfg, OBS, ACT, seed=seed)
    assert isinstance(learner, SAC)
    rng = np.random.default_rng(seed)
    for _ in range(n):
        s = rng.normal(size=OBS).astype(np.float32)
        violation = bool(s[0] > 1.3)
        a = rng.uniform(-1, 1, ACT).astype(np.float32)
        nxt = (s + 0.1 * np.concatenate([a, np.zeros(OBS - ACT)])).astype(np.float32)
        learner.buffer.add(s, a, -1.0 if violation else 0.0, nxt, violation, cost=float(violation), violation=violation)
    learner.warm = True
    learner.fit_world_model()
    return learner


def test_the_fear_budget_is_measured_at_each_fit_on_the_familiar_states() -> None:
    learner = with_predictable_violations()
    sample = learner.last_calibration
    assert sample is not None and 0 < int((~sample.familiar).sum()) < len(sample) // 2
    measured = learner.fear_budget()
    assert measured == learner.measured_fear_budget != learner.cfg.fear_budget
    with torch.no_grad():
        fear_all = learner.real_fear(torch.from_numpy(sample.obs)).numpy()
    dangerous = sample.obs[:, 0] > 1.3
    # fear knows where the violations are: the budget, the fear of familiar states, sits under the mean fear of the
    # real states, so that the dual variable rises while the policy goes where they are
    assert fear_all[dangerous].mean() > 2 * fear_all[~dangerous].mean()
    assert measured < float(fear_all.mean())
    assert measured == pytest.approx(float(fear_all[sample.familiar].mean()), rel=0.15)
    # the budget moves with the fear of the states it is measured on
    quiet = dataclasses.replace(sample, familiar=~dangerous & (sample.obs[:, 0] < 0.0))
    tense = dataclasses.replace(sample, familiar=(sample.obs[:, 0] > 0.8) & ~dangerous)
    learner.measure_fear_budget(quiet)
    low = learner.fear_budget()
    learner.measure_fear_budget(tense)
    assert learner.fear_budget() > low


def test_lambda_rises_against_the_measured_budget_where_a_constant_one_lets_it_fall_to_zero() -> None:
    lams = {}
    for from_data in (True, False):
        learner = with_predictable_violations(fear_budget_from_data=from_data, lambda_init=0.5, lambda_lr=0.5)
        budget = learner.fear_budget()
        fears = [learner.update()["fear_real"] for _ in range(40)]
        lams[from_data] = learner.lam
        said = learner.describe_fear_term()
        assert said is not None
        if from_data:
            assert budget < float(np.mean(fears))  # the real states carry more fear than the familiar ones
            assert "(measured at the last world-model fit)" in said and "adds nothing" not in said
        else:
            assert budget == 0.2 > max(fears)  # the constant lies above every batch's fear
            assert "(configured)" in said and "λ is 0: the fear term adds nothing now" in said
    assert lams[False] == 0.0 and lams[True] > 0.5


def test_a_measured_fear_budget_travels_with_the_checkpoint() -> None:
    learner = with_predictable_violations(n=600)
    state = learner.state_dict()
    fresh = make_learner(learner.cfg.method, learner.cfg, OBS, ACT, seed=1)
    assert math.isnan(fresh.measured_fear_budget) and fresh.fear_budget() == learner.cfg.fear_budget
    assert "fear_budget" in fresh.load_state_dict(state)
    assert fresh.fear_budget() == pytest.approx(learner.fear_budget())


# -- ω ----------------------------------------------------------------------------------------------
def test_omega_is_larger_when_the_expert_action_has_the_higher_value() -> None:
    q_agent = torch.tensor([10.0, 10.0, 10.0])
    q_expert = torch.tensor([15.0, 10.0, 5.0])
    omega = advantage_weights(q_expert, q_agent, q_scale=10.0, temperature=0.5, clip=3.0)
    assert float(omega[0]) > float(omega[1]) > float(omega[2])
    assert float(omega[1]) == pytest.approx(1.0)


def test_omega_stays_finite_and_bounded_for_huge_value_gaps() -> None:
    q_agent = torch.tensor([0.0, 0.0, 1e30, -1e30])
    q_expert = torch.tensor([1e30, -1e30, 0.0, 1e30])
    omega = advantage_weights(q_expert, q_agent, q_scale=1.0, temperature=0.1, clip=3.0)
    assert bool(torch.isfinite(omega).all())
    assert float(omega.max()) == pytest.approx(math.exp(3.0)) and float(omega.min()) == pytest.approx(math.exp(-3.0))


def test_imitation_pulls_the_policy_to_the_expert_where_the_expert_is_better() -> None:
    learner = filled("sage")
    imitation = learner.buffer.sample_takeovers(64, np.random.default_rng(2))
    assert imitation is not None
    batch = learner.buffer.sample(64, np.random.default_rng(3))
    _, _, stats = learner.actor_loss(batch, imitation)
    assert stats["bc_loss"] > 0 and math.isfinite(stats["omega_mean"])
    before = (learner.actor.deterministic(imitation.obs) - imitation.a_expert).pow(2).sum(-1).mean().item()
    learner.cfg.bc_weight = 50.0
    for _ in range(250):
        learner.actor_step(batch)
    after = (learner.actor.deterministic(imitation.obs) - imitation.a_expert).pow(2).sum(-1).mean().item()
    assert after < 0.5 * before


# -- the fear gradient -------------------------------------------------------------------------------
def actor_grads(learner: SAC, lam: float) -> tuple[list[torch.Tensor], float]:
    learner.lam = lam
    batch = learner.buffer.sample(64, np.random.default_rng(5))
    torch.manual_seed(7)  # the same action samples for both λ
    loss, _, stats = learner.actor_loss(batch, None)
    learner.actor.zero_grad(set_to_none=True)
    loss.backward()
    return [p.grad.clone() for p in learner.actor.parameters()], stats.get("fear_real", math.nan)


def test_the_actor_gradient_carries_the_fear_term_through_the_frozen_world_model() -> None:
    learner = filled("sage", imitation=False)
    assert learner.world_model is not None
    before = {k: v.clone() for k, v in learner.world_model.state_dict().items()}
    g0, _ = actor_grads(learner, 0.0)
    g1, fear_value = actor_grads(learner, 5.0)
    assert math.isfinite(fear_value)
    difference = sum(float((a - b).abs().sum()) for a, b in zip(g0, g1, strict=True))
    assert difference > 1e-3
    assert all(p.grad is None for p in learner.world_model.parameters())
    for _ in range(5):
        learner.update()
    for key, value in learner.world_model.state_dict().items():
        assert torch.equal(value, before[key]), key


def fear_share_at_the_action(learner: SAC, q_units: float) -> float:
    """|∂(wF)/∂a| / (|∂(-Q)/∂a| + |∂(wF)/∂a|), mean over the batch's states, in the actor's own loss at λ = 1, the
    critic's output layer scaled so that the batch's mean |Q| is about ``q_units`` (rewards in other units)."""
    critic = copy.deepcopy(learner.critic)
    batch = learner.buffer.sample(64, np.random.default_rng(5))
    with torch.no_grad():
        base = learner.critic(batch.obs, batch.action).min(0).values.abs().mean()
        critic.out.weight.mul_(q_units / base)
        critic.out.bias.mul_(q_units / base)
    scaled = copy.copy(learner)
    scaled.critic = critic
    sample = scaled.actor.sample
    grads = []
    for lam in (0.0, 1.0):
        kept: list[torch.Tensor] = []

        def keep(obs: torch.Tensor, sample=sample, kept=kept) -> tuple[torch.Tensor, torch.Tensor]:
            action, log_prob = sample(obs)
            action.retain_grad()
            kept.append(action)
            return action, log_prob

        scaled.actor.sample = keep  # type: ignore[method-assign]
        scaled.lam = lam
        torch.manual_seed(7)  # the same actions for both λ
        loss, _, _ = scaled.actor_loss(batch, None)
        loss.backward()
        grads.append(kept[0].grad.clone())
    scaled.actor.sample = sample  # type: ignore[method-assign]
    value, fear_term = grads[0].norm(dim=1).mean(), (grads[1] - grads[0]).norm(dim=1).mean()
    return float(fear_term / (value + fear_term))


def test_fear_scale_q_makes_the_fear_share_at_the_action_independent_of_the_reward_units() -> None:
    # α fixed near 0, so that the loss's remaining action gradient is -Q's
    learner = filled("sage", imitation=False, virtual_ratio=0.0, autotune_alpha=False, init_alpha=1e-8)
    assert isinstance(learner, SAC) and learner.fear_active()
    shares = {}
    for scale in ("none", "q"):
        learner.cfg.fear_scale = scale
        shares[scale] = [fear_share_at_the_action(learner, units) for units in (10.0, 100.0, 1000.0)]
    # "q": the same share whatever the units of Q (λ = 1 weighs fear like the batch's value) ...
    assert max(shares["q"]) == pytest.approx(min(shares["q"]), rel=0.02)
    # ... and on this batch a share where both act (the band of the decision rule in docs/notes/adaptation_probe.md)
    assert 0.05 < shares["q"][0] < 0.5
    # "none": fear's share falls as Q's units grow (about 100 times less from 10 to 1000)
    assert shares["none"][2] < shares["none"][0] / 30
    assert shares["none"][0] < shares["q"][0]


def test_fear_scale_none_is_the_loss_as_it_was() -> None:
    learner = filled("sage", virtual_ratio=0.0)
    assert isinstance(learner, SAC) and learner.cfg.fear_scale == "none" and learner.fear_active()
    learner.lam = 2.0
    batch = learner.buffer.sample(64, np.random.default_rng(5))
    imitation = learner.buffer.sample_takeovers(32, np.random.default_rng(6))
    torch.manual_seed(7)
    loss, _, stats = learner.actor_loss(batch, imitation)
    # the loss written out as before fear_scale: α log π - Q + λF + w_bc max(1, mean|Q|) L_BC
    torch.manual_seed(7)
    action, log_prob = learner.actor.sample(batch.obs)
    q = learner.critic(batch.obs, action).min(0).values
    fear_values = learner.learner_fear(batch.obs, action)
    q_scale = q.detach().abs().mean().clamp_min(1.0)
    written = (learner.alpha * log_prob - q).mean() + 2.0 * fear_values.mean()
    written = written + learner.cfg.bc_weight * q_scale * stats["bc_loss"]
    assert loss.item() == pytest.approx(written.item(), rel=1e-5, abs=1e-6)
    # "q" adds (max(1, mean|Q|) - 1) λ F to the same loss
    learner.cfg.fear_scale = "q"
    torch.manual_seed(7)
    scaled, _, _ = learner.actor_loss(batch, imitation)
    extra = ((q_scale - 1.0) * 2.0 * fear_values.mean()).item()
    assert scaled.item() - loss.item() == pytest.approx(extra, rel=1e-4, abs=1e-5)


def test_a_gate_step_after_loading_weights_leaves_the_learner_trainable() -> None:
    learner = filled("sage")
    learner.load_state_dict(learner.state_dict())  # new model version: the gate rebuilds the folded weights first
    gate = learner.make_gate()
    gate.decide(np.zeros(OBS, np.float32), np.zeros(ACT, np.float32))
    assert "fear_real" in learner.update()


def test_plain_sac_has_no_fear_and_no_model() -> None:
    learner = filled("sac")
    stats = learner.update()
    assert learner.world_model is None and "fear_real" not in stats and "bc_loss" not in stats
    assert not learner.fear_active()


def test_fni_rl_has_fear_without_takeover_or_imitation() -> None:
    learner = filled("fni-rl")
    stats = learner.update()
    assert "fear_real" in stats and "bc_loss" not in stats and not learner.cfg.takeover


def test_actor_batches_mix_real_and_virtual_states() -> None:
    learner = filled("sage")
    assert learner.virtual is not None and len(learner.virtual) > 0
    batch = learner.buffer.sample(64, np.random.default_rng(0))
    states, n_real = learner.actor_states(batch)
    assert len(states) == 64 and n_real == 64 - round(64 * learner.cfg.virtual_ratio)
    assert torch.equal(states[:n_real], batch.obs[:n_real])


# -- the threshold's calibration -------------------------------------------------------------------
def test_the_tau_bounds_come_from_every_state_of_a_buffer_smaller_than_the_calibration_sample() -> None:
    from core.sage.calibration import calibrate
    from core.sage.model_trainer import familiar_for_bounds

    learner = filled("sage")  # 600 states, under calibration_states: the fit calibrates on all of them
    wm = learner.world_model
    assert wm is not None and learner.cfg.gate.calibration_states > len(learner.buffer)
    fitted = wm.tau_bounds.clone(), wm.sigma_scale.clone()
    obs = torch.from_numpy(learner.buffer.arrays()["obs"])
    safe = torch.from_numpy(familiar_for_bounds(learner.buffer, wm.cfg.violation_steps, learner.cfg.gate.horizon))
    motion = torch.from_numpy(learner.buffer.previous_deltas(wm.motion_lag, wm.scan)) if wm.motion else None
    calibrate(wm, learner.rollout_policy, obs, learner.cfg.gate.horizon, cfg=learner.cfg.gate, safe=safe, motion=motion)
    assert torch.equal(wm.tau_bounds, fitted[0]) and torch.equal(wm.sigma_scale, fitted[1])


def test_a_larger_buffer_is_calibrated_on_distinct_states() -> None:
    from core.sage.calibration import calibrate

    learner = filled("sage")
    learner.cfg.gate.calibration_states = 200
    learner.fit_world_model()
    sample = learner.last_calibration
    assert sample is not None and len(sample) == 200
    assert len(np.unique(sample.obs, axis=0)) == 200  # drawn without replacement
    # and they are the states the bounds were set on
    wm = learner.world_model
    assert wm is not None
    fitted = wm.tau_bounds.clone()
    motion = None if sample.motion is None else torch.from_numpy(sample.motion)
    calibrate(wm, learner.rollout_policy, torch.from_numpy(sample.obs), learner.cfg.gate.horizon, cfg=learner.cfg.gate,
              safe=torch.from_numpy(sample.familiar), motion=motion)  # fmt: skip
    assert torch.equal(wm.tau_bounds, fitted)


def test_a_refit_learns_the_buffers_conflicts_and_keeps_them_out_of_the_bounds(monkeypatch: pytest.MonkeyPatch) -> None:
    """fit_world_model hands the buffer's conflict flags to the world model's fit, and with conflict_label_weight
    above 0 the calibration of τ's bounds leaves the conflict states out of its familiar ones."""
    learner = filled("sage")
    wm = learner.world_model
    assert wm is not None
    wm.cfg.conflict_label_weight = 0.5
    n = len(learner.buffer)
    learner.buffer.conflict[:n] = (np.arange(n) % 7 == 3).astype(np.float32)
    learner.buffer.cost[:n] = 0.0  # only the conflicts (and the violations ahead) make a state unfamiliar
    fitted: list[np.ndarray] = []
    real_fit = wm.fit
    monkeypatch.setattr(wm, "fit", lambda *a, **k: fitted.append(k["conflict"]) or real_fit(*a, **k))
    learner.fit_world_model()
    assert np.array_equal(fitted[0], learner.buffer.conflict[:n])
    # the buffer is under calibration_states: the bounds see every state, in the buffer's order
    sample = learner.last_calibration
    assert sample is not None and np.array_equal(sample.obs, learner.buffer.obs[:n])
    assert not sample.familiar[learner.buffer.conflict[:n] > 0].any() and bool(sample.familiar.any())


def test_a_refit_with_conflict_steps_learns_the_conflicts_ahead(monkeypatch: pytest.MonkeyPatch) -> None:
    """world_model_config.conflict_steps k: the fit's conflict label is "a conflict within the next k steps" of the
    buffer (ReplayBuffer.conflict_soon), and those states are not familiar to τ's bounds either."""
    learner = filled("sage")
    wm = learner.world_model
    assert wm is not None
    wm.cfg.conflict_label_weight = 1.0
    wm.cfg.conflict_steps = 3
    n = len(learner.buffer)
    learner.buffer.conflict[:n] = (np.arange(n) % 11 == 5).astype(np.float32)
    learner.buffer.cost[:n] = 0.0
    fitted: list[np.ndarray] = []
    real_fit = wm.fit
    monkeypatch.setattr(wm, "fit", lambda *a, **k: fitted.append(k["conflict"]) or real_fit(*a, **k))
    learner.fit_world_model()
    ahead = learner.buffer.conflict_soon(3)
    assert np.array_equal(fitted[0], ahead)
    assert ahead.sum() > learner.buffer.conflict[:n].sum()  # the steps before each conflict are labelled too
    sample = learner.last_calibration
    assert sample is not None and not sample.familiar[ahead > 0].any() and bool(sample.familiar.any())


# -- baselines -----------------------------------------------------------------------------------------
def test_td3_updates_critic_every_step_and_actor_every_other() -> None:
    learner = filled("td3")
    first = learner.update()
    learner.updates = 1  # the learner counts updates in observe(); odd counts skip the actor
    second = learner.update()
    assert "actor_loss" in first and "critic_loss" in second and "actor_loss" not in second
    noisy = [learner.act(np.zeros(OBS, np.float32)) for _ in range(5)]
    assert len({tuple(a) for a in noisy}) > 1  # exploration noise
    assert all(np.all(np.abs(a) <= 1.0) for a in noisy)


def test_hg_dagger_regresses_onto_the_aggregated_expert_labels() -> None:
    learner = filled("hg-dagger")
    losses = [learner.update()["bc_loss"] for _ in range(150)]
    assert np.mean(losses[-10:]) < 0.5 * np.mean(losses[:10])
    obs = np.zeros(OBS, np.float32)
    assert np.array_equal(learner.act(obs), learner.act(obs))  # deterministic, no exploration noise


# -- the distillation anchor on a base policy's own drives (fine-tuning's prior rows) ------------------
def with_prior_rows(learner: SAC, rows: int = 200, seed: int = 9) -> tuple[SAC, torch.Tensor, torch.Tensor]:
    """``learner`` whose buffer is a fine-tuning buffer: its rows beside ``rows`` drives of a base policy whose
    action is a fixed function of the state; returns the learner, the prior states and the base's actions."""
    from core.finetune import SharedReplayBuffer

    old = learner.buffer
    shared = SharedReplayBuffer(OBS, ACT, old.capacity, prior_share=0.5)
    rng = np.random.default_rng(seed)
    states = rng.normal(size=(rows + 1, OBS)).astype(np.float32)
    base_actions = np.tanh(states[:, ACT:] * 2.0).astype(np.float32)[:, :ACT]
    shared.adding_prior = True
    for i in range(rows):
        a = base_actions[i]
        shared.add(states[i], a, float(-np.abs(states[i]).sum()), states[i + 1], False, a_rl=a)
    shared.adding_prior = False
    for i in range(old.size):
        shared.add(
            old.obs[i], old.action[i], float(old.reward[i]), old.next_obs[i], bool(old.terminated[i]),
            takeover=bool(old.takeover[i]), a_rl=old.a_rl[i], a_expert=old.a_expert[i] if old.takeover[i] else None,
        )  # fmt: skip
    learner.buffer = shared
    return learner, torch.from_numpy(states[:rows]), torch.from_numpy(base_actions[:rows])


def test_a_prior_distillation_anchor_holds_the_actor_to_the_base_actions_on_its_states() -> None:
    # no virtual states in the actor batch, so that the test can rebuild its Q scale
    learner, states, base_actions = with_prior_rows(filled("sage", virtual_ratio=0.0))  # type: ignore[arg-type]
    assert isinstance(learner, SAC) and learner.prior_distill == 0.0
    rng_before = learner.rng.bit_generator.state
    assert learner.anchor_batch() is None and learner.rng.bit_generator.state == rng_before  # 0: nothing drawn

    # the term: prior_distill · max(1, mean|Q|) · mean ||μ(s) - a_base||² on prior rows only
    learner.prior_distill = 2.0
    scaled = copy.deepcopy(learner)  # Q values of tens, so that the scale max(1, mean|Q|) is not 1
    with torch.no_grad():
        scaled.critic.out.weight.mul_(300.0)
        scaled.critic.out.bias.mul_(300.0)
    anchor = scaled.anchor_batch()
    assert anchor is not None and bool(scaled.buffer.prior[: len(states)].all())
    torch.testing.assert_close(anchor.a_rl, torch.tanh(anchor.obs[:, ACT:] * 2.0)[:, :ACT])  # every row a prior one
    batch = scaled.buffer.sample(64, np.random.default_rng(3))
    imitation = scaled.buffer.sample_takeovers(32, np.random.default_rng(2))
    torch.manual_seed(7)
    without, _, _ = scaled.actor_loss(batch, imitation)
    torch.manual_seed(7)
    with_anchor, _, stats = scaled.actor_loss(batch, imitation, anchor)
    torch.manual_seed(7)
    states_used, _ = scaled.actor_states(batch)
    q_scale = scaled.critic(states_used, scaled.actor.sample(states_used)[0]).min(0).values.abs().mean().clamp_min(1)
    distill = (scaled.actor.deterministic(anchor.obs) - anchor.a_rl).pow(2).sum(-1).mean()
    assert stats["prior_distill_loss"] == pytest.approx(distill.item(), rel=1e-5)
    assert q_scale > 5.0
    assert (with_anchor - without).item() == pytest.approx((2.0 * q_scale * distill).item(), rel=1e-4)

    # trained, the actor moves toward the base's actions on the prior states; without the anchor it does not
    def distance(sac: SAC) -> float:
        with torch.no_grad():
            return (sac.actor.deterministic(states) - base_actions).pow(2).sum(-1).mean().item()

    anchored, free = copy.deepcopy(learner), copy.deepcopy(learner)
    anchored.prior_distill, free.prior_distill = 5.0, 0.0
    before = distance(learner)
    for _ in range(200):
        anchored.actor_step(anchored.buffer.sample(64, anchored.rng))
        free.actor_step(free.buffer.sample(64, free.rng))
    assert distance(anchored) < 0.5 * before
    assert distance(anchored) < 0.5 * distance(free)


@pytest.mark.parametrize("method", ["sac", "td3"])
def test_layer_normed_critics_are_scale_free_in_their_hidden_layers_and_still_learn(method: str) -> None:
    """``critic_layer_norm``: the hidden features are normalised, so scaling a hidden layer's weights and bias by a
    positive factor leaves Q unchanged (it does not without the norms), and the critic still fits its targets."""
    torch.manual_seed(0)
    obs, action = torch.randn(64, OBS), torch.rand(64, ACT) * 2 - 1
    normed, plain = filled(method, critic_layer_norm=True), filled(method)
    for learner, invariant in ((normed, True), (plain, False)):
        critic = copy.deepcopy(learner.critic)
        with torch.no_grad():
            q = critic(obs, action)
            critic.hidden[0].weight.mul_(7.0)
            critic.hidden[0].bias.mul_(7.0)
            scaled = critic(obs, action)
        assert torch.allclose(q, scaled, atol=1e-4) is invariant
    assert normed.critic.layer_norm and not plain.critic.layer_norm
    losses = [normed.update()["critic_loss"] for _ in range(200)]
    assert all(math.isfinite(v) for v in losses) and np.mean(losses[-20:]) < np.mean(losses[:20])


def test_a_critic_ensemble_with_a_drawn_target_subset_takes_the_minimum_of_the_drawn_critics_only() -> None:
    """``critic_target_subset`` (REDQ, RLPD): the TD target's minimum runs over critics drawn anew every update, so with
    critic z valued z it is the smaller of the two drawn, not 0; the actor reads the critics' mean."""
    from core.sage.sac import ensemble_value

    learner = filled("sac", critics=10, critic_target_subset=2)
    for critic in (learner.critic, learner.critic_target):
        with torch.no_grad():
            critic.out.weight.zero_()
            critic.out.bias.copy_(torch.arange(10.0).view(10, 1, 1))
    batch = learner.buffer.sample(64, learner.rng)
    learner.cfg.critic_target_subset = None
    torch.manual_seed(5)
    everyone = learner.critic_target_values(batch)
    drawn: set[float] = set()
    for seed in range(5, 45):
        learner.cfg.critic_target_subset = 2
        torch.manual_seed(seed)
        subset = learner.critic_target_values(batch)
        learner.cfg.critic_target_subset = None
        torch.manual_seed(seed)
        base = learner.critic_target_values(batch)
        live = (1.0 - batch.terminated) * (1.0 - batch.violation) > 0.5
        gap = ((subset - base)[live] / learner.cfg.gamma).round(decimals=3).unique()
        assert len(gap) == 1 and 0.0 <= float(gap[0]) <= 8.0 + 1e-4
        drawn.add(round(float(gap[0]), 3))
    assert len(drawn) > 3 and torch.isfinite(everyone).all()
    q = torch.arange(10.0).view(10, 1).expand(10, 3)
    assert ensemble_value(q, mean=True).tolist() == [4.5] * 3 and ensemble_value(q, mean=False).tolist() == [0.0] * 3


def test_a_critic_target_subset_is_refused_where_it_cannot_be_read() -> None:
    with pytest.raises(ValueError, match="critic_target_subset"):
        for_method("sac", critics=2, critic_target_subset=3)
    with pytest.raises(ValueError, match="critic_target_subset"):
        for_method("sac", critics=10, critic_target_subset=2, cuda_graph=True)
    with pytest.raises(ValueError, match="critic_target_subset"):
        make_learner("td3", for_method("td3", critics=10, critic_target_subset=2), OBS, ACT)


# -- the conservative critic term (CQL(H), Cal-QL) ---------------------------------------------------
def narrow(method: str, seed: int = 0, n: int = 300, reward: float | None = None, **overrides: object) -> SAC:
    """A learner whose buffer holds one episode of a narrow behaviour (the recorded action a fixed function of the
    state, as a base policy's or an expert's drive), rewards random or ``reward`` each step."""
    cfg = for_method(method, hidden=32, batch_size=64, **overrides)
    learner = make_learner(cfg.method, cfg, OBS, ACT, seed=seed)
    rng = np.random.default_rng(seed)
    s = rng.normal(size=(n + 1, OBS)).astype(np.float32)
    for i in range(n):
        recorded = np.clip(0.5 * s[i, :ACT], -0.3, 0.3).astype(np.float32)
        r = float(rng.normal()) if reward is None else reward
        learner.buffer.add(s[i], recorded, r, s[i + 1], False, violation=bool(i == 150))
    learner.warm = True
    assert isinstance(learner, SAC)
    return learner


def test_the_conservative_term_values_actions_off_the_data_below_the_recorded_ones() -> None:
    def gap(learner: SAC) -> float:
        """Mean Q at uniform actions minus mean Q at the recorded actions, over the buffer's states."""
        n = learner.buffer.size
        states, recorded = torch.as_tensor(learner.buffer.obs[:n]), torch.as_tensor(learner.buffer.action[:n])
        generator = torch.Generator().manual_seed(1)
        uniform = torch.rand(recorded.shape, generator=generator) * 2 - 1
        with torch.no_grad():
            return (learner.critic(states, uniform).mean() - learner.critic(states, recorded).mean()).item()

    gaps = {}
    for weight in (0.0, 5.0):
        torch.manual_seed(0)
        learner = narrow("sac", conservative_weight=weight)
        for _ in range(600):
            stats = learner.critic_step(learner.buffer.sample(64, learner.rng))
        assert ("conservative_loss" in stats) == (weight > 0)
        gaps[weight] = gap(learner)
    assert gaps[5.0] < gaps[0.0] - 0.3, gaps


def test_the_recorded_return_counts_a_violation_as_minus_c_star_and_follows_the_rows_drawn() -> None:
    learner = narrow("sac", n=40, reward=1.0, conservative_weight=1.0, violation_penalty=True)
    gamma, c_star = learner.cfg.gamma, learner.c_star()
    rows = np.array([0, 150 % 40, 39, 10])
    batch = learner.buffer.sample(4, learner.rng)
    batch.rows = rows
    # one chain of 40 rows, all rewards 1, no violation among them (the violation is at step 150 of a longer one)
    expected = [(1 - gamma ** (40 - r)) / (1 - gamma) for r in rows]
    assert learner.recorded_returns(batch).numpy() == pytest.approx(expected, rel=1e-5)
    long = narrow("sac", n=160, reward=1.0, conservative_weight=1.0, violation_penalty=True)
    batch = long.buffer.sample(2, long.rng)
    batch.rows = np.array([149, 150])
    after = (1 - gamma**9) / (1 - gamma)  # rows 151..159
    expected = [1 + gamma * (-long.c_star() + gamma * after), -long.c_star() + gamma * after]
    assert long.recorded_returns(batch).numpy() == pytest.approx(expected, rel=1e-5)
    assert c_star > 0


def test_cal_ql_does_not_push_the_policys_values_under_the_recorded_return_as_cql_does() -> None:
    """On a drive whose returns are above the fresh critics' values, CQL(H) pushes the policy's values down while the
    TD targets pull them up; Cal-QL's floor leaves only the pull there."""
    values = {}
    for calibrated in (True, False):
        torch.manual_seed(0)
        learner = narrow("sac", n=200, reward=1.0, conservative_weight=5.0, conservative_calibrated=calibrated)
        for _ in range(300):
            learner.critic_step(learner.buffer.sample(64, learner.rng))
        states = torch.as_tensor(learner.buffer.obs[: learner.buffer.size])
        with torch.no_grad():
            values[calibrated] = learner.critic(states, learner.actor.sample(states)[0]).mean().item()
    assert values[True] > values[False] + 1.0, values


def test_a_conservative_weight_is_refused_where_it_cannot_be_read() -> None:
    with pytest.raises(ValueError, match="conservative_weight"):
        for_method("sac", conservative_weight=-1.0)
    with pytest.raises(ValueError, match="conservative_weight"):
        for_method("sac", conservative_weight=1.0, cuda_graph=True)
    with pytest.raises(ValueError, match="conservative_actions"):
        for_method("sac", conservative_weight=1.0, conservative_actions=0)
    with pytest.raises(ValueError, match="conservative_weight"):
        make_learner("td3", for_method("td3", conservative_weight=1.0), OBS, ACT)


# -- IBRL: an imitation actor beside the RL actor, its proposals ---------------------------------------
def test_ibrl_acts_with_whichever_proposal_the_critics_value_higher() -> None:
    learner = filled("sage", ibrl=True)
    assert isinstance(learner, SAC)
    with torch.no_grad():  # π_IL differs from the actor, so the two proposals differ
        for p in learner.il_actor.parameters():
            p.add_(0.3 * torch.randn_like(p))
    rng = np.random.default_rng(3)
    picks = []
    for _ in range(60):
        obs = rng.normal(size=OBS).astype(np.float32)
        acted = learner.policy_action(obs, deterministic=True)
        o = torch.as_tensor(obs).view(1, -1)
        with torch.no_grad():
            rl, il = learner.actor.deterministic(o), learner.il_actor.deterministic(o)
            q_rl, q_il = (learner.critic(o, a).min(0).values.item() for a in (rl, il))
        expected = il if q_il > q_rl else rl
        assert acted == pytest.approx(expected[0].numpy(), abs=1e-5)
        picks.append(q_il > q_rl)
    assert 0 < sum(picks) < len(picks)  # both proposals acted somewhere
    assert learner.proposals == [len(picks) - sum(picks), sum(picks)]


def test_ibrl_bootstraps_from_the_higher_of_the_two_next_proposals() -> None:
    learner = filled("sage", ibrl=True)
    assert isinstance(learner, SAC)
    with torch.no_grad():
        for p in learner.il_actor.parameters():
            p.add_(0.3 * torch.randn_like(p))
    batch = learner.buffer.sample(64, learner.rng)
    torch.manual_seed(2)
    with_proposal = learner.critic_target_values(batch)
    learner.cfg.ibrl = False
    torch.manual_seed(2)
    plain = learner.critic_target_values(batch)
    live = (1.0 - batch.terminated) * (1.0 - batch.violation) > 0.5
    assert torch.all(with_proposal[live] >= plain[live] - 1e-5)
    assert torch.any(with_proposal[live] > plain[live] + 1e-3)  # π_IL's next action valued higher somewhere
    assert torch.allclose(with_proposal[~live], plain[~live])


def test_ibrl_clones_the_expert_into_its_imitation_actor_only_and_keeps_the_lowest_heldout_error() -> None:
    learner = filled("sage", ibrl=True)
    assert isinstance(learner, SAC)
    actor_before = copy.deepcopy(learner.actor.state_dict())
    rng = np.random.default_rng(9)
    heldout_obs = rng.normal(size=(50, OBS)).astype(np.float32)
    heldout_expert = np.clip(-heldout_obs[:, :ACT], -1, 1).astype(np.float32)

    def error() -> float:
        with torch.no_grad():
            a = learner.il_actor.deterministic(torch.as_tensor(heldout_obs))
        return float((a - torch.as_tensor(heldout_expert)).pow(2).sum(-1).mean())

    before = error()
    stats = learner.fit_imitation_policy(600, heldout_obs, heldout_expert)
    assert stats["il_heldout_error"] == pytest.approx(error(), rel=1e-5)
    assert error() < 0.5 * before
    assert all(torch.equal(v, actor_before[k]) for k, v in learner.actor.state_dict().items())
    assert learner.fit_imitation_policy(0) == {}
    assert filled("sage").fit_imitation_policy(100) == {}  # no π_IL without ibrl


def test_an_ibrl_version_carries_its_imitation_actor_and_acts_as_the_learner(tmp_path: object) -> None:
    from pathlib import Path

    from core.agents import AgentMeta, load_agent, save_checkpoint

    learner = filled("sage", ibrl=True)
    assert isinstance(learner, SAC)
    with torch.no_grad():
        for p in learner.il_actor.parameters():
            p.add_(0.3 * torch.randn_like(p))
    meta = AgentMeta("sage", "ugv", ["x"], OBS, ACT, [-1.0] * ACT, [1.0] * ACT, has_world_model=True)
    path = save_checkpoint(Path(str(tmp_path)) / "v.pt", learner, meta)
    agent = load_agent(path)
    rng = np.random.default_rng(4)
    for _ in range(20):
        obs = rng.normal(size=OBS).astype(np.float32)
        assert agent.policy.act(obs, True) == pytest.approx(learner.policy_action(obs, True), abs=1e-5)
    assert sum(agent.learner.proposals) == 20  # type: ignore[attr-defined]
    # a base saved without π_IL: the imitation actor starts as its actor
    plain = filled("sage")
    fresh = make_learner("sage", for_method("sage", hidden=32, ibrl=True), OBS, ACT, seed=1)
    assert isinstance(fresh, SAC)
    fresh.load_state_dict(plain.state_dict(), strict=False)
    assert all(torch.equal(v, plain.actor.state_dict()[k]) for k, v in fresh.il_actor.state_dict().items())


def test_ibrl_is_refused_where_it_cannot_be_read() -> None:
    with pytest.raises(ValueError, match="ibrl"):
        for_method("sac", ibrl=True, cuda_graph=True)
    with pytest.raises(ValueError, match="ibrl_updates"):
        for_method("sac", ibrl_updates=-1)
    with pytest.raises(ValueError, match="ibrl"):
        make_learner("td3", for_method("td3", ibrl=True), OBS, ACT)


def test_ibrl_clones_its_imitation_actor_again_online_every_refit_interval() -> None:
    """``ibrl_refit_every``: in online training π_IL is cloned on the expert rows so far every that many environment
    steps (the takeovers grow the expert's data); the RL actor's updates never move it."""
    from core.protocol import StepRecord

    learner = filled("sage", ibrl=True, ibrl_refit_every=50, ibrl_updates=20, updates_per_step=0.0)
    assert isinstance(learner, SAC)
    rng = np.random.default_rng(1)
    obs = rng.normal(size=(121, OBS)).astype(np.float32)
    snapshots = []
    for t in range(120):
        a = rng.uniform(-1, 1, ACT).astype(np.float32)
        record = StepRecord(
            episode=0, t=t, obs=obs[t], a_rl=a, a_expert=None, action=a, takeover=False, gate_fired=False,
            actor="agent", fear=0.0, threshold=1.0, curiosity=0.0, reward=0.0, cost=0.0, violation=False,
            terminated=False, truncated=False, next_obs=obs[t + 1], wall_time=0.0,
        )  # fmt: skip
        learner.observe(record)
        snapshots.append(copy.deepcopy(learner.il_actor.state_dict()))
    changed = [
        t for t in range(1, 120) if any(not torch.equal(v, snapshots[t - 1][k]) for k, v in snapshots[t].items())
    ]
    steps_at = [t + 1 for t in changed]
    assert steps_at == [50, 100], steps_at
    assert learner.info["il_updates"] == 20
