"""The ensemble world model learns a known system and knows where it has not been trained."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from core.sage.config import GateConfig, WorldModelConfig
from core.sage.fear import rollout
from core.sage.world_model import EnsembleWorldModel

torch.set_num_threads(1)

OBS, ACT = 4, 2
A = np.array([[0.0, 1.0, 0.0, 0.0], [-1.0, 0.0, 0.5, 0.0], [0.0, 0.0, 0.0, 1.0], [0.3, 0.0, -1.0, 0.0]])
B = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 0.0], [0.0, 1.0]])
NOISE = 0.01


def known_system(n: int, rng: np.random.Generator, low: float = -1.0, high: float = 1.0):
    """s' = s + 0.1 tanh(A s) + 0.2 B a + noise; cost = clip(s_0, 0, 1)."""
    s = rng.uniform(low, high, (n, OBS)).astype(np.float32)
    a = rng.uniform(-1, 1, (n, ACT)).astype(np.float32)
    nxt = s + 0.1 * np.tanh(s @ A.T) + 0.2 * a @ B.T + NOISE * rng.standard_normal((n, OBS))
    cost = np.clip(s[:, 0], 0.0, 1.0)
    return s, a, nxt.astype(np.float32), cost.astype(np.float32)


@pytest.fixture(scope="module")
def trained() -> tuple[EnsembleWorldModel, object]:
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    model = EnsembleWorldModel(OBS, ACT, WorldModelConfig(max_epochs=80, max_updates_per_fit=2500, patience=8))
    report = model.fit(*known_system(3000, rng), rng)
    return model, report


def test_heldout_nll_falls_and_error_is_small(trained) -> None:
    model, report = trained
    assert report.holdout_nll < report.holdout_nll_before - 1.0
    assert report.holdout_history[-1] < report.holdout_history[0]
    rng = np.random.default_rng(1)
    s, a, nxt, cost = known_system(1000, rng)
    with torch.no_grad():
        mean, _ = model.predict(torch.as_tensor(s), torch.as_tensor(a))
    predicted = s + mean[..., :OBS].mean(0).numpy()
    rmse = float(np.sqrt(((predicted - nxt) ** 2).mean()))
    assert rmse < 3 * NOISE  # the signal (Δs) has std ~0.1: only the noise is left
    # the cost channel is a (prior-corrected) classifier: its probability matches the soft label
    assert float(np.abs(torch.sigmoid(mean[..., OBS]).mean(0).numpy() - cost).mean()) < 0.05


def test_spread_is_larger_off_the_training_distribution(trained) -> None:
    model, _ = trained
    rng = np.random.default_rng(2)
    on, a_on, _, _ = known_system(500, rng)
    off, a_off, _, _ = known_system(500, rng, low=3.0, high=5.0)
    with torch.no_grad():
        sigma_on = model.predictive_std(torch.as_tensor(on), torch.as_tensor(a_on))
        sigma_off = model.predictive_std(torch.as_tensor(off), torch.as_tensor(a_off))
        mean_off, _ = model.predict(torch.as_tensor(off), torch.as_tensor(a_off))
        mean_on, _ = model.predict(torch.as_tensor(on), torch.as_tensor(a_on))
    assert float(sigma_off.mean()) > 3 * float(sigma_on.mean())
    # the members disagree off-distribution: the epistemic part, not just their own variances
    assert float(mean_off.std(0).mean()) > 5 * float(mean_on.std(0).mean())


def test_folded_weights_give_the_same_predictions(trained) -> None:
    model, _ = trained
    rng = np.random.default_rng(3)
    s, a, _, _ = known_system(64, rng)
    obs, act = torch.as_tensor(s), torch.as_tensor(a)
    with torch.no_grad():
        mean, _ = model.predict(obs, act)
        ro = rollout(model.folded(), lambda x: torch.zeros(x.shape[0], ACT), obs, act, 1)
    torch.testing.assert_close(ro.states[1], obs + mean[..., :OBS], atol=1e-5, rtol=1e-4)
    probability = torch.sigmoid(mean[..., OBS])
    torch.testing.assert_close(ro.cost[0], probability, atol=1e-5, rtol=1e-4)
    # σ_raw: the members' disagreement about the violation probability
    torch.testing.assert_close(ro.sigma_raw[0], probability.std(0, unbiased=False), atol=1e-5, rtol=1e-3)


def test_normalisers_are_refitted_with_the_data_and_keep_the_function() -> None:
    """A model first fitted on a narrow range keeps learning on a wider one: its normalisers follow the data,
    and the change of variables leaves what the network predicts unchanged."""
    rng = np.random.default_rng(4)
    model = EnsembleWorldModel(OBS, ACT, WorldModelConfig(max_updates_per_fit=300))
    model.fit(*known_system(500, rng), rng)
    probe_s, probe_a, _, _ = known_system(64, np.random.default_rng(9))
    obs, act = torch.as_tensor(probe_s), torch.as_tensor(probe_a)
    with torch.no_grad():
        mean_before, logvar_before = model.predict(obs, act)
    in_mean, in_std, out_std, version = (
        model.in_mean.clone(),
        model.in_std.clone(),
        model.out_std.clone(),
        model.version,
    )
    wide = known_system(500, rng, low=-2.0, high=2.0)
    inputs = model.inputs(torch.as_tensor(wide[0]), torch.as_tensor(wide[1]))
    targets = torch.as_tensor(np.concatenate([wide[2] - wide[0], wide[3][:, None]], axis=1))
    model.renormalise(inputs, targets)
    assert not torch.equal(model.in_mean, in_mean) and not torch.equal(model.in_std, in_std)
    assert not torch.equal(model.out_std, out_std)
    with torch.no_grad():
        mean_after, logvar_after = model.predict(obs, act)
    torch.testing.assert_close(mean_after, mean_before, atol=1e-4, rtol=1e-4)
    # log-variances are in normalised units: in state units they are unchanged
    before = logvar_before[..., :OBS] + 2 * torch.log(out_std[:OBS])
    after = logvar_after[..., :OBS] + 2 * torch.log(model.out_std[:OBS])
    torch.testing.assert_close(after, before, atol=1e-4, rtol=1e-4)
    report = model.fit(*wide, rng)
    assert model.version > version  # cached inference weights are invalidated
    assert report.holdout_nll <= report.holdout_nll_before


def test_the_violation_head_learns_a_rare_predictable_violation_from_violation_free_beginnings() -> None:
    """A rare binary violation that the state predicts: a first fit sees none; once they appear, the refitted
    classifier ranks the pre-violation states far above the others (a Gaussian cost head with frozen
    normalisers predicted ~0 everywhere)."""
    rng = np.random.default_rng(5)

    def data(n: int) -> tuple[np.ndarray, ...]:
        s, a, nxt, _ = known_system(n, rng, low=-2.0, high=2.0)
        soon = ((s[:, 0] > 1.7) & (s[:, 1] > 0.5)).astype(np.float32)  # ~2% of states: danger ahead
        return s, a, nxt, soon

    model = EnsembleWorldModel(OBS, ACT, WorldModelConfig(max_updates_per_fit=600))
    s, a, nxt, soon = data(1500)
    safe = soon < 0.5
    model.fit(s[safe], a[safe], nxt[safe], soon[safe], rng, violation_soon=soon[safe])
    s2, a2, nxt2, soon2 = data(3000)
    assert 20 < soon2.sum() < 150
    model.fit(
        np.concatenate([s[safe], s2]),
        np.concatenate([a[safe], a2]),
        np.concatenate([nxt[safe], nxt2]),
        np.concatenate([soon[safe], soon2]),
        rng,
        violation_soon=np.concatenate([soon[safe], soon2]),
    )
    ts, ta, _, tsoon = data(4000)
    with torch.no_grad():
        mean, _ = model.predict(torch.as_tensor(ts), torch.as_tensor(ta))
    p = torch.sigmoid(mean[..., OBS]).mean(0).numpy()
    from core.metrics import auroc

    assert auroc(p, tsoon) > 0.9
    assert 0.3 * tsoon.mean() < p.mean() < 3.0 * tsoon.mean()  # calibrated in the mean, not inflated by balancing


def test_fit_refuses_too_little_data() -> None:
    model = EnsembleWorldModel(OBS, ACT, WorldModelConfig())
    with pytest.raises(ValueError, match="at least 10"):
        model.fit(*known_system(5, np.random.default_rng(0)), np.random.default_rng(0))


def test_gate_config_default_horizon_matches_the_brief() -> None:
    assert GateConfig().horizon == 5 and WorldModelConfig().members == 5


def test_the_motion_input_makes_a_moving_obstacle_predictable() -> None:
    """Position alone cannot tell where a mover goes next; its last change of state can. The same data, fitted
    with and without the motion input: only the model that sees the motion predicts the next position."""
    rng = np.random.default_rng(6)
    n = 3000
    position = rng.uniform(-1, 1, (n, 2)).astype(np.float32)
    velocity = rng.choice([-0.1, 0.1], size=(n, 2)).astype(np.float32)  # hidden from the observation
    previous = position - velocity
    action = np.zeros((n, 1), np.float32)
    nxt = position + velocity
    cost = np.zeros(n, np.float32)
    errors = {}
    for motion_input in (False, True):
        model = EnsembleWorldModel(2, 1, WorldModelConfig(motion_input=motion_input, max_updates_per_fit=1500))
        model.fit(position, action, nxt, cost, np.random.default_rng(0), motion=position - previous)
        test = slice(0, 500)
        with torch.no_grad():
            motion = torch.as_tensor(position[test] - previous[test]) if motion_input else None
            mean, _ = model.predict(torch.as_tensor(position[test]), torch.as_tensor(action[test]), motion)
        predicted = position[test] + mean[..., :2].mean(0).numpy()
        errors[motion_input] = float(np.abs(predicted - nxt[test]).mean())
    assert errors[True] < 0.02 < 0.05 < errors[False], errors


EGO = {
    "ego_sectors": 3,
    "ego_scan_start": -0.3,
    "ego_sector_width": 0.2,
    "ego_forward_scale": 0.05,
    "ego_turn_scale": 0.2,
}
"""An ego step over the known system's first three channels (read as ranges; the step is geometry, any values do)."""


@pytest.mark.parametrize(
    ("lag", "scan", "approach", "ego"),
    [
        (1, False, False, False),
        (4, False, False, False),
        (1, True, False, False),
        (1, False, True, False),
        (1, True, True, False),
        (1, False, False, True),
        (3, False, True, True),
        (1, True, False, True),
    ],
)
def test_the_gate_kernel_agrees_with_fear_when_there_is_motion(lag: int, scan: bool, approach: bool, ego: bool) -> None:
    """The gate's preallocated kernel and the batched rollout carry the motion input alike over the imagined steps
    (for a lag k > 1: ((k - 1) m + Δ) / k; with a scan alignment, each imagined step's change with its imagined
    turn taken out of the scan; with approach rates, those of each imagined state and motion; with an ego step, Δ
    added to the state moved by each imagined action), so both give the same fear, and the kernel's curiosity is
    the model's and the folded one's."""
    from core.sage.fear import GateKernel, fear
    from core.sage.gate import curiosity_folded
    from core.sage.networks import Actor

    rng = np.random.default_rng(7)
    layout: dict[str, float] = {"scan_sectors": 3, "scan_turn_channel": 3, "scan_turn_sectors": 1.5} if scan else {}
    if approach:
        layout |= {"approach_start": 1, "approach_stop": 3}
    if ego:
        layout |= EGO
    model = EnsembleWorldModel(OBS, ACT, WorldModelConfig(max_updates_per_fit=50, motion_lag=lag, **layout))
    assert (model.folded().scan is not None) == scan
    assert (model.folded().approach is not None) == approach
    assert (model.folded().ego is not None) == ego
    s, a, nxt, cost = known_system(300, rng)
    model.fit(s, a, nxt, cost, rng, motion=0.05 * rng.standard_normal(s.shape).astype(np.float32))
    actor = Actor(OBS, ACT, 16, 2, -torch.ones(ACT), torch.ones(ACT))
    cfg = GateConfig()
    kernel = GateKernel(model.folded(), actor.deterministic_layers(), actor.action_scale, actor.action_bias, cfg)
    obs, act = torch.as_tensor(s[:1]), torch.as_tensor(a[:1])
    motion = torch.as_tensor(0.1 * rng.standard_normal((1, OBS)).astype(np.float32))
    with torch.inference_mode():
        value, cost_hat, sigma = kernel(obs, act, motion)
        reference = fear(model.folded(), actor.deterministic, obs, act, cfg, motion=motion)
        without = kernel(obs, act, None)
    assert value == pytest.approx(float(reference.fear), abs=1e-5)
    assert cost_hat == pytest.approx(float(reference.cost), abs=1e-5)
    assert without != (value, cost_hat, sigma)  # the motion input changes the prediction
    nxt_obs = obs + 0.05
    with torch.inference_mode():
        fast = kernel.curiosity(obs, act, nxt_obs, motion=motion)
        kernel(obs, act, motion)  # the gate's common case: the curiosity of the (s, a) the last rollout started from
        assert kernel.curiosity(obs, act, nxt_obs, reuse_first_step=True, motion=motion) == pytest.approx(
            fast, rel=1e-5
        )
    with torch.no_grad():
        assert fast == pytest.approx(float(model.curiosity(obs, act, nxt_obs, motion)), rel=1e-4)
        assert fast == pytest.approx(float(curiosity_folded(model, obs, act, nxt_obs, motion)[0]), rel=1e-4)
    if ego:  # the curiosity reads Δ over the moved state: with the ego step left out it would differ
        with torch.no_grad():
            mean, _ = model.predict(obs, act, motion)
            plain = ((obs + mean[..., :OBS].mean(0) - nxt_obs) / model.in_std[:OBS]).norm()
        assert abs(float(plain) - fast) > 1e-3


def test_the_rollout_moves_each_state_by_the_ego_step_once_for_all_members(monkeypatch: pytest.MonkeyPatch) -> None:
    """The members start from the same state and action, so the first imagined step's ego step runs on each row
    once (the actor loss's fear sends gradients through its tensor version, the costly one), and the rollout is the
    one that moves every member's copy, gradients included; later steps, where the members part, move each (but the
    last, whose state fear reads only for contact: off here)."""
    from core.motion import EgoScanStep
    from core.sage.fear import fear

    rng = np.random.default_rng(3)
    model = EnsembleWorldModel(OBS, ACT, WorldModelConfig(max_updates_per_fit=50, **EGO))
    s, a, nxt, cost = known_system(200, rng)
    model.fit(s, a, nxt, cost, rng)
    folded, cfg, batch = model.folded(), GateConfig(), 6
    obs = torch.as_tensor(s[:batch])
    rows: list[int] = []
    apply = EgoScanStep.apply

    def counted(step: EgoScanStep, state: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        rows.append(state[..., 0].numel())
        return apply(step, state, action)

    monkeypatch.setattr(EgoScanStep, "apply", counted)
    act = torch.as_tensor(a[:batch]).requires_grad_(True)
    value = fear(folded, lambda x: torch.zeros(x.shape[0], ACT), obs, act, cfg, horizon=3).fear.sum()
    (grad,) = torch.autograd.grad(value, act)
    assert rows == [batch, folded.members * batch]  # steps 1 and 2; step 3's state is not needed
    # each member's copy moved on its own, as before: the same states, fear and gradient
    act_each = torch.as_tensor(a[:batch]).requires_grad_(True)
    expanded = act_each.unsqueeze(0).expand(folded.members, batch, ACT)
    first = apply(folded.ego, obs.unsqueeze(0).expand(folded.members, batch, OBS), expanded)
    assert folded.ego is not None and torch.equal(first[0], apply(folded.ego, obs, act_each))
    (grad_each,) = torch.autograd.grad(first.sum(), act_each)
    (grad_once,) = torch.autograd.grad(apply(folded.ego, obs, act_each).expand_as(first).sum(), act_each)
    # (float sums in another order: the same up to rounding)
    assert torch.allclose(grad_each, grad_once, rtol=1e-4, atol=1e-6) and grad.abs().sum() > 0


def test_a_world_model_over_the_ego_step_learns_a_static_scan_it_cannot_fit_alone() -> None:
    """A static world's next scan is the ego step of the current one: with the step the model learns a residual of
    zero and predicts the next scan almost exactly; the same fit without it must learn the re-binning of moved
    points and errs several times more."""
    from core.motion import EgoScanStep

    cfg = {
        "ego_sectors": 8,
        "ego_scan_start": -1.2,
        "ego_sector_width": 0.3,
        "ego_forward_scale": 0.03,
        "ego_forward_offset": 0.03,
        "ego_turn_scale": 0.3,
    }
    step = EgoScanStep.of(WorldModelConfig(**cfg), 9, 2)
    assert step is not None

    def scans(rng: np.random.Generator, n: int) -> tuple[np.ndarray, ...]:
        obs = np.concatenate([rng.uniform(0.1, 1.0, (n, 8)), rng.uniform(-1, 1, (n, 1))], axis=1).astype(np.float32)
        act = rng.uniform(-1, 1, (n, 2)).astype(np.float32)
        with torch.no_grad():
            nxt = step.apply(torch.as_tensor(obs), torch.as_tensor(act)).numpy()
        return obs, act, nxt, np.zeros(n, np.float32)

    errors = {}
    for ego in (False, True):
        torch.manual_seed(0)
        rng = np.random.default_rng(0)
        model = EnsembleWorldModel(9, 2, WorldModelConfig(hidden=32, max_updates_per_fit=400, **(cfg if ego else {})))
        model.fit(*scans(rng, 2000), rng)
        obs, act, nxt, _ = scans(np.random.default_rng(1), 500)
        with torch.no_grad():
            mean, _ = model.predict(torch.as_tensor(obs), torch.as_tensor(act))
            predicted = model.base(torch.as_tensor(obs), torch.as_tensor(act)) + mean[..., :9].mean(0)
        errors[ego] = float((predicted - torch.as_tensor(nxt)).abs().mean())
    assert errors[True] < 0.2 * errors[False], errors


def test_a_model_reads_only_weights_learned_over_its_own_ego_step() -> None:
    """A warm start keeps a world model only if it was learned over the same step (the residual means something
    else over another step, or over none); a checkpoint from before the option was learned over none."""
    plain = EnsembleWorldModel(OBS, ACT, WorldModelConfig())
    ego = EnsembleWorldModel(OBS, ACT, WorldModelConfig(**EGO))
    other = EnsembleWorldModel(OBS, ACT, WorldModelConfig(**{**EGO, "ego_turn_scale": 0.3}))
    before_the_option = {k: v for k, v in plain.state_dict().items() if k != "ego_geometry"}
    assert plain.reads(plain.state_dict()) and plain.reads(before_the_option)
    assert ego.reads(EnsembleWorldModel(OBS, ACT, WorldModelConfig(**EGO)).state_dict())
    assert not ego.reads(plain.state_dict()) and not ego.reads(before_the_option)
    assert not ego.reads(other.state_dict()) and not plain.reads(ego.state_dict())
    plain.load_state_dict(before_the_option)  # an old checkpoint still loads
    # a committed policy's file halves the weights, and load_checkpoint reads every tensor back as float32: the step's
    # numbers survive both, so a warm start from it keeps its model
    from core.agents import halved

    read_back = {k: v.float() if v.is_floating_point() else v for k, v in halved(ego.state_dict()).items()}
    assert read_back["out.weight"].dtype == torch.float32 and ego.reads(read_back)
    assert halved(ego.state_dict())["ego_geometry"].dtype == torch.float64
    rounded = {**read_back, "ego_geometry": ego.ego_geometry.half().float()}  # a file halved whole
    assert ego.reads(rounded)
    ego.load_state_dict(rounded)
    assert torch.equal(ego.ego_geometry, EnsembleWorldModel(OBS, ACT, WorldModelConfig(**EGO)).ego_geometry)


def test_approach_rates_tell_a_near_slow_approach_from_a_far_fast_one() -> None:
    """Danger here is a beam's time to contact, range / closing speed: neither the range nor its change tells it
    alone. The same data fitted with and without the approach-rate input (``approach_*``, the ratio): only the
    model that reads it ranks held-out states by the danger ahead (AUROC 0.85-0.87 without, 0.99 with, in four
    seeds of this set-up)."""
    from core.metrics import auroc

    def beams(rng: np.random.Generator, n: int) -> tuple[np.ndarray, ...]:
        ranges = rng.uniform(0.05, 1.0, (n, 4)).astype(np.float32)
        closing = (rng.uniform(0.0, 0.08, (n, 4)) * (rng.random((n, 4)) < 0.5)).astype(np.float32)
        obs = np.concatenate([rng.normal(size=(n, 2)), ranges], axis=1).astype(np.float32)
        motion = np.concatenate([rng.normal(0.0, 0.01, (n, 2)), -closing], axis=1).astype(np.float32)
        soon = (ranges < 5 * closing).any(axis=1).astype(np.float32)  # contact within 5 steps on some beam
        return obs, rng.uniform(-1, 1, (n, 1)).astype(np.float32), obs + motion, soon, motion

    scores = {}
    for approach in (False, True):
        torch.manual_seed(0)
        rng = np.random.default_rng(0)
        layout = {"approach_start": 2, "approach_stop": 6} if approach else {}
        model = EnsembleWorldModel(6, 1, WorldModelConfig(hidden=32, max_updates_per_fit=600, **layout))
        obs, act, nxt, soon, motion = beams(rng, 3000)
        model.fit(obs, act, nxt, np.zeros(len(obs), np.float32), rng, violation_soon=soon, motion=motion)
        obs, act, _, soon, motion = beams(np.random.default_rng(1), 2000)
        with torch.no_grad():
            mean, _ = model.predict(torch.as_tensor(obs), torch.as_tensor(act), torch.as_tensor(motion))
        scores[approach] = auroc(torch.sigmoid(mean[..., -1]).mean(0).numpy(), soon > 0.5)
    assert scores[True] > 0.95 and scores[True] - scores[False] > 0.05, scores


def test_the_dense_cost_joins_the_violation_label_with_its_weight() -> None:
    """cost_label_weight 1: a dense cost is a soft violation label (ĉ follows it); 0: violations alone (no violation
    in the data, so ĉ stays low where the cost is high)."""
    rng = np.random.default_rng(3)
    s, a, nxt, cost = known_system(1500, rng)  # cost = clip(s_0, 0, 1): high on half the states, no violations
    high = torch.as_tensor(s[cost > 0.8]), torch.as_tensor(a[cost > 0.8])
    predicted = {}
    for weight in (1.0, 0.0):
        model = EnsembleWorldModel(OBS, ACT, WorldModelConfig(max_updates_per_fit=600, cost_label_weight=weight))
        model.fit(s, a, nxt, cost, rng, violation_soon=np.zeros_like(cost))
        with torch.no_grad():
            mean, _ = model.predict(*high)
        predicted[weight] = float(torch.sigmoid(mean[..., OBS]).mean())
    assert predicted[1.0] > 0.6 and predicted[0.0] < 0.1, predicted


def test_conflicts_join_the_violation_label_only_with_their_weight() -> None:
    """conflict_label_weight w: the simulator's conflict flags are a label of weight w (ĉ follows them where no
    violation ever happens); 0, the default: they are ignored and ĉ stays low."""
    rng = np.random.default_rng(4)
    s, a, nxt, _ = known_system(1500, rng)
    conflict = (s[:, 0] > 0.5).astype(np.float32)  # a near miss on a quarter of the states, never a violation
    near = torch.as_tensor(s[s[:, 0] > 0.7]), torch.as_tensor(a[s[:, 0] > 0.7])
    far = torch.as_tensor(s[s[:, 0] < 0.0]), torch.as_tensor(a[s[:, 0] < 0.0])
    predicted = {}
    for weight in (1.0, 0.5, 0.0):
        model = EnsembleWorldModel(OBS, ACT, WorldModelConfig(max_updates_per_fit=600, conflict_label_weight=weight))
        zero = np.zeros(len(s), np.float32)
        model.fit(s, a, nxt, zero, rng, violation_soon=zero, conflict=conflict)
        with torch.no_grad():
            predicted[weight] = [float(torch.sigmoid(model.predict(*x)[0][..., OBS]).mean()) for x in (near, far)]
    assert predicted[1.0][0] > 0.6 and predicted[1.0][1] < 0.1, predicted
    assert 0.3 < predicted[0.5][0] < 0.7 and predicted[0.5][1] < 0.1, predicted
    assert predicted[0.0][0] < 0.1, predicted
