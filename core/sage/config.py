"""Typed configuration of every learner in :mod:`core.sage` (CleanRL style: one flat dataclass per concern,
every field documented where it is declared: what it means and its unit; the measurements and history behind a
value are in docs/notes/config_notes.md).

``AgentConfig`` carries the switches that turn the one SAC implementation into SAC, FNI-RL or SAGE-SAC,
plus the settings of TD3 and HG-DAgger, which live in the same code (:mod:`core.sage.td3`,
:mod:`core.sage.hg_dagger`) and share its networks, buffers, world model and gate. ``for_method`` gives the
preset of each method; ``apply_overrides`` edits a config from ``key=value`` strings (``gate.tau_max=0.7``).
"""

from __future__ import annotations

import copy
import dataclasses
import math
import types
import typing
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

Method = Literal["sage", "sac", "td3", "hg-dagger", "fni-rl"]
METHODS: tuple[str, ...] = typing.get_args(Method)
_REGISTERED_METHODS: list[str] = list(METHODS)
"""Every method name a configuration may carry: the built-ins plus those :mod:`core.learners` registers."""


def known_methods() -> tuple[str, ...]:
    """The method names :func:`validate` accepts (built-ins first, then registered ones)."""
    return tuple(_REGISTERED_METHODS)


def note_method(name: str, known: bool = True) -> None:
    """Called by :func:`core.learners.register_learner` / ``unregister_learner`` (config knows no learner)."""
    if known and name not in _REGISTERED_METHODS:
        _REGISTERED_METHODS.append(name)
    elif not known and name in _REGISTERED_METHODS and name not in METHODS:
        _REGISTERED_METHODS.remove(name)


@dataclass
class WorldModelConfig:
    """The probabilistic ensemble world model (:mod:`core.sage.world_model`) and its training."""

    members: int = 5
    """N, the number of ensemble members (each a diagonal-Gaussian MLP over (Δstate, cost))."""
    hidden: int = 64
    """Width of every hidden layer of every member (units)."""
    layers: int = 2
    """Number of hidden layers per member."""
    lr: float = 1e-3
    """Adam learning rate of the negative log-likelihood training."""
    weight_decay: float = 1e-5
    """L2 penalty on the weights (PETS uses a small one to keep members smooth off-distribution)."""
    batch_size: int = 256
    """Minibatch size of the NLL training."""
    holdout_ratio: float = 0.2
    """Fraction of the real buffer held out for early stopping and calibration (at most ``max_holdout``)."""
    max_holdout: int = 5000
    """Upper bound on the held-out set size, so that evaluation stays cheap on big buffers."""
    max_epochs: int = 60
    """Epoch cap of one fit; early stopping usually ends a fit sooner."""
    patience: int = 5
    """Epochs without a held-out improvement (of any member) before a fit stops."""
    max_updates_per_fit: int = 3000
    """Gradient-step cap of one fit, which bounds its wall time on big buffers."""
    motion_input: bool = True
    """The model also reads the last observed change of state, s_t - s_{t-1} (zero at an episode's start); in a
    rollout the next step's motion is the model's own predicted Δ."""
    motion_lag: int = 1
    """k of the motion input (s_t - s_{t-k}) / k, the mean change per step over the last k steps (fewer at an episode's
    start); in a rollout the next step's motion is ((k - 1) m + Δ) / k, Δ the model's own predicted change."""
    scan_sectors: int = 0
    """With the motion input: the first this-many channels are a range scan over evenly spaced sectors, whose previous
    frame is turned to the current heading before differencing (:mod:`core.motion`); 0: plain differences."""
    scan_turn_channel: int = -1
    """The observation channel holding the turn over the last step (the UGV's last yaw-rate command)."""
    scan_turn_sectors: float = 0.0
    """Sectors the heading turns by over one step per unit of ``scan_turn_channel`` (UGV: w_max dt / 5°)."""
    approach_start: int = 0
    """First of the range channels [approach_start, approach_stop) whose approach rate the model also reads, with the
    motion input (both 0: off)."""
    approach_stop: int = 0
    """End (exclusive) of those range channels (positive, shorter when nearer); a channel's approach rate is
    max(0, -Δrange) / range per step, capped at 1 (:func:`core.motion.approach_rate`)."""
    ego_sectors: int = 0
    """The first this-many channels are a range scan (in units of its reach) whose change under the robot's own motion
    is computed (:class:`core.motion.EgoScanStep`) and the model learns the residual; 0: off."""
    ego_scan_start: float = 0.0
    """Bearing where sector 0 begins (rad from the heading, bearings increasing to the left)."""
    ego_sector_width: float = 0.0
    """Each sector's width (rad)."""
    ego_rays_per_sector: int = 1
    """Rays per sector, evenly spaced from the sector's start; a sector reads the nearest of them."""
    ego_forward_channel: int = 0
    """The action channel that drives the robot forward in the ego step."""
    ego_forward_scale: float = 0.0
    """Distance driven over one step per unit of that action (scan range units): action * scale + offset."""
    ego_forward_offset: float = 0.0
    """Distance driven over one step at action 0 (scan range units)."""
    ego_turn_channel: int = 1
    """The action channel that turns the heading in the ego step."""
    ego_turn_scale: float = 0.0
    """Turn of the heading over one step per unit of that action (rad, positive to the left): action * scale."""
    violation_steps: int = 5
    """The violation head's label (steps): a violation at this transition or within the next this-many steps; the fear
    rollout looks m steps further along the policy's imagined path."""
    cost_label_weight: float = 1.0
    """Weight w in [0, 1] of a dense safety cost in the violation head's label, max(w · cost, violation soon): 1 takes
    the cost itself as a soft early warning, 0 violations alone."""
    conflict_label_weight: float = 0.0
    """Weight w of the simulator's conflict flag (``info["conflict"]``, a near miss) in the violation head's label,
    max(w · conflict, violation soon, ...); 0: violations alone (the paper's ĉ)."""
    conflict_steps: int = 1
    """Steps the conflict part of the label looks ahead, as ``violation_steps`` does for violations (1: a conflict at
    this transition)."""
    logvar_bound_weight: float = 0.01
    """Weight of the PETS term ``sum(max_logvar) - sum(min_logvar)`` that keeps the learnable bounds tight."""


@dataclass
class GateConfig:
    """Fear, curiosity, threshold and takeover hold (:mod:`core.sage.fear`, :mod:`core.sage.gate`)."""

    beta: float = 0.5
    """β of eq:fear, in [0, 1]: weight of the predicted cost ĉ against the normalised uncertainty σ̂ in
    F = βĉ + (1-β)σ̂."""
    horizon: int = 5
    """m, the world-model steps rolled out under the current policy for the short-horizon fear."""
    aggregate: Literal["max", "discounted_mean"] = "max"
    """How per-step ĉ_k and σ̂_k are aggregated over the m steps (each separately, then combined by β)."""
    discount: float = 0.9
    """Per-step weight decay of the ``discounted_mean`` aggregation (ignored by ``max``)."""
    tau_min: float = 0.15
    """τ_min: the threshold when curiosity is far above its recent average (most ready to ask for help)."""
    tau_max: float = 0.45
    """τ_max: the threshold when curiosity is far below its recent average (familiar ground)."""
    tau_interpolation: Literal["linear", "geometric"] = "linear"
    """How ρ places τ between its bounds: ``linear``, eq:threshold, τ = τ_max - ρ(τ_max - τ_min); ``geometric``, the
    same on log τ, τ = τ_min^ρ τ_max^(1-ρ)."""
    curiosity_ema: float = 0.02
    """Rate of the exponential moving average of curiosity that ρ compares the current curiosity with."""
    curiosity_sharpness: float = 2.0
    """p in ρ = r^p / (1 + r^p), r = C_t / EMA(C); 1 is the plain ratio C / (C + EMA)."""
    tau_from_data: bool = True
    """Take τ_min and τ_max from the fear of familiar states at every world-model fit (quantiles below), per
    simulator and per model; False uses the constants above."""
    tau_min_quantile: float = 0.90
    """τ_min = this quantile of fear on real states under the policy (most ready to ask: novel ground)."""
    tau_max_quantile: float = 0.99
    """τ_max = this quantile of fear on real states under the policy (familiar ground)."""
    tau_scale: float = 1.0
    """Multiplies both τ bounds in use (from data or the constants), and so τ and the release level: the gate's
    operating point (1: the bounds as measured)."""
    calibration_states: int = 16384
    """Real states whose fear sets κ and the τ bounds at every world-model fit, drawn from the replay buffer without
    replacement (all of them when it holds fewer)."""
    curiosity_smoothing: float = 0.3
    """Weight of the newest curiosity in the short moving average that ρ reads, so that τ does not jump with
    every noisy transition (1: no smoothing)."""
    curiosity_signal: Literal["error", "disagreement", "novelty"] = "error"
    """What curiosity is: "error", the transition's prediction error (the paper's C); "disagreement", the members'
    spread about its next state; "novelty", the new state's distance to calibration states (needs reference fitted)."""
    curiosity_reference: Literal["recent", "fitted"] = "recent"
    """What ρ compares curiosity with: "recent", its moving average (the paper's), or "fitted", the signal's mean on
    the model's calibration states, held fixed (ground that stays unfamiliar keeps τ low)."""
    use_curiosity: bool = True
    """False fixes τ at (τ_min + τ_max) / 2, the value ρ = 1/2 gives for typical curiosity (FNI-RL, ablations)."""
    hold_steps: int = 5
    """k: once the gate fires, expert control is held for this many steps (restarted by every new firing), unless
    ``hold_seconds`` is set."""
    hold_seconds: float | None = None
    """The hold as a duration (s): when set, k = round(hold_seconds / step_seconds), at least 1, in place of
    ``hold_steps``; None: ``hold_steps``."""
    step_seconds: float | None = None
    """The simulator's step (s) that ``hold_seconds`` is counted in; every training run writes it from its simulator."""
    release: float = 0.0
    """Hysteresis of the hold, in [0, 1]: while the expert holds control, fear above τ_t - release (τ_t - τ_min)
    restarts the hold; 0: hand back after k steps under τ_t (the paper's gate), 1: after k steps under τ_min."""

    imagined_contact: bool = False
    """Fear also reads the contact its imagined states show: a member whose predicted channel i is at or under
    ``contact_floors[i]`` at step k has violation probability 1 there. False: the learned head alone (the paper's)."""
    contact_needs_closing: bool = False
    """With ``imagined_contact``: a member's imagined contact in channel i counts only where the real last step shows
    channel i closing (the motion input's change below 0)."""
    contact_floors: list[float | None] | None = None
    """Per observation channel [0, n), the value at or under which it shows contact (its units), None where it shows
    none by itself; every training run writes them from its simulator (None or empty: the observation shows none)."""
    contact_horizon: int | None = None
    """Steps (> ``horizon``) that imagined contact alone reaches; ĉ and σ̂ keep ``horizon``. None: ``horizon``. The
    gate's only."""
    contact_extrapolation: bool = False
    """With ``imagined_contact``: each scan sector's closing that the robot's motion leaves unexplained, seen two steps
    running, is extrapolated over the imagined steps in the contact test. The gate's only."""
    closing_veto: float | None = None
    """Seconds: fear over τ hands over only where some ``contact_floors`` channel is observed closing on its floor
    within this time (the last two changes falling); fear and τ unchanged. None: off (the paper's). The gate's only."""
    mover_model: Literal["none", "cartesian"] = "none"
    """With ``imagined_contact``: "cartesian" also moves the scan's small movers at constant velocity into each member's
    imagined poses (:mod:`core.sage.movers`); needs the ego step. "none": off. The gate's only."""
    mover_history: int = 4
    """The mover model's track in steps (>= 2): a mover is followed back through this many + 1 real scans, its
    velocity the slope of its centroids."""
    mover_max_speed: float = 0.02
    """The mover model's largest displacement of a mover in one step, in the scan's range units (the UGV: 2 m/s at
    10 Hz over a 10 m reach; its generated movers drive at most 1 m/s): the association radius between scans."""
    mover_max_size: float = 0.12
    """The mover model's largest object, in range units (the UGV: 1.2 m, over the 0.94 m diagonal of its largest
    generated vehicle): a longer segment of returns is structure and never moves."""
    mover_min_speed: float = 0.002
    """The mover model's noise floor, in range units per step (the UGV: 0.2 m/s, above the ego step's mean error of
    0.022 m a step): slower points are static, left to the imagined contact of the ego-moved scan."""

    @property
    def hold(self) -> int:
        """k, the steps the expert holds control once the gate fires: ``hold_seconds`` in steps, or ``hold_steps``."""
        if self.hold_seconds is None:
            return self.hold_steps
        if self.step_seconds is None:
            raise ValueError("gate.hold_seconds needs gate.step_seconds, the simulator's step (a training run sets it)")
        return max(1, round(self.hold_seconds / self.step_seconds))


@dataclass
class DiscreteConfig:
    """Value-based learners on discrete actions (D3QN, SAGE-D3QN: :mod:`core.sage.d3qn`)."""

    epsilon_start: float = 1.0
    """ε of ε-greedy exploration at the first learning step (after the warm-up)."""
    epsilon_end: float = 0.05
    """ε after ``epsilon_decay_steps`` (held from then on)."""
    epsilon_decay_steps: int = 5000
    """Environment steps over which ε falls linearly (a warm-started Q-network starts at ``epsilon_end``)."""
    margin: float = 0.8
    """ℓ of the large-margin imitation loss: how far the expert's action must lead the others' Q values."""


@dataclass
class DiffusionConfig:
    """Conditional diffusion policies trained offline (Diffusion-BC, Diffusion-QL: :mod:`core.sage.diffusion`)."""

    denoising_steps: int = 10
    """T: noise levels of the training schedule (variance-preserving, cosine)."""
    sampling_steps: int = 5
    """Reverse (DDIM) steps when acting, a stride over the T levels; fewer is faster (<= denoising_steps)."""
    hidden: int = 128
    """Width of the denoiser's hidden layers (a small MLP for the CPU)."""
    layers: int = 3
    """Hidden layers of the denoiser."""
    time_embedding: int = 16
    """Width of the sinusoidal noise-level embedding."""
    lr: float = 1e-3
    """Adam learning rate of the denoiser (and of Diffusion-QL's critics)."""
    offline_steps: int = 4000
    """Gradient steps of offline training on the dataset."""
    q_weight: float = 0.0
    """η of Diffusion-QL's policy loss, BC loss - η Q(s, π(s)) / mean|Q|; 0 is Diffusion-BC."""
    candidates: int = 10
    """Diffusion-QL acts with the best of this many sampled actions by Q (1: a single sample)."""


@dataclass
class AgentConfig:
    """Everything a learner needs. Switches select the method; see :func:`for_method` for the presets."""

    method: str = "sage"
    """One of ``sage``, ``sac``, ``td3``, ``hg-dagger``, ``fni-rl`` (informational once presets are applied)."""

    # -- switches ----------------------------------------------------------------------------------
    world_model: bool = True
    """Train the ensemble world model on the real buffer (needed by fear, the gate and virtual rollouts)."""
    fear_regularisation: bool = True
    """Fear terms in the critic target (-λF_{t+1}), in the actor loss (+λF) and the dual update of λ."""
    violation_penalty: bool = True
    """A safety violation makes the transition terminal with the target -c* of eq:penalty."""
    c_star_floor: float = 1.0
    """Lower bound of c* of eq:penalty, which is also never below the largest reward magnitude recorded."""
    takeover: bool = True
    """The expert takes over while training: asked by the SAGE gate (``takeover_rule="gate"``: needs the world
    model) or of its own accord (``"supervisor"``)."""
    takeover_rule: Literal["gate", "supervisor"] = "gate"
    """Who decides a takeover: the agent's SAGE gate (self-aware), or the supervisor, a person watching (headless: a
    stand-in that intervenes when a step's safety cost reaches ``supervisor_cost``)."""
    supervisor_cost: float = 0.5
    """The headless stand-in supervisor intervenes when a step's safety cost reaches this (or on a violation) and
    keeps control for the gate's hold (``GateConfig.hold``)."""
    intervention_penalty: float = 0.0
    """Reward taken from the agent's last step before each takeover onset, whoever called the expert (Multi-Hug's
    intervention shaping, RLIF's cost; every learner's ``store``). 0: none (the paper's SAGE)."""
    refused_weight: float = 0.0
    """Weight of a critic term holding Q(s, a_RL) to -c* where the gate refused a_RL and the expert drove (a failure
    the robot never had to make; SAC learners). 0: none (the paper's SAGE)."""
    conservative_weight: float = 0.0
    """α of CQL(H)'s critic term (Cal-QL's with ``conservative_calibrated``): values of actions off the data pushed
    under the recorded action's (``SAC.conservative_loss``). 0: none (the paper's SAGE). SAC learners."""
    conservative_actions: int = 10
    """Actions of each kind (uniform, the policy's) per state in the conservative term."""
    conservative_calibrated: bool = True
    """Cal-QL: in the conservative term the policy's values are held no lower than the recorded return to go from
    the state (a violation counted as -c*). False: CQL(H) as published."""
    ibrl: bool = False
    """IBRL: π_IL, cloned on the expert's rows, proposes beside the actor; the higher-valued proposal acts and
    bootstraps the TD target (``SAC.policy_action``). False: none (the paper's SAGE). SAC learners."""
    ibrl_updates: int = 1000
    """Behaviour-cloning updates of π_IL at each fine-tuning round and each online cloning (``ibrl``)."""
    ibrl_refit_every: int = 0
    """Steps between online clonings of π_IL on the expert's rows so far (``ibrl``); 0: pretraining and rounds only."""
    lookback_labels: int = 0
    """At each takeover onset, this many of the agent's steps before it (same episode) also become imitation rows,
    labelled with the expert's onset action: the gate fired after them. 0: none (the paper's SAGE)."""
    imitation: bool = True
    """Value-weighted imitation of the expert on intervention samples (eq:bc_loss with ω of eq:qa_weight)."""
    virtual_rollouts: bool = True
    """Roll the world model from real states under the current policy into the virtual buffer (actor batches)."""

    # -- SAC backbone ------------------------------------------------------------------------------
    gamma: float = 0.99
    """Discount factor γ."""
    hidden: int = 128
    """Width of the hidden layers of actor and critics."""
    layers: int = 2
    """Number of hidden layers of actor and critics."""
    critics: int = 2
    """Z, the size of the critic ensemble (one batched forward); the target uses the minimum over targets."""
    critic_target_subset: int | None = None
    """REDQ's and RLPD's ensemble: the TD target takes the minimum over this many critics drawn at random every update,
    the actor's value (and ω's) the critics' mean. None: the minimum over all critics for both."""
    critic_layer_norm: bool = False
    """Layer norm before every hidden ReLU of the critics (RLPD, HIL-SERL), in SAC, its SAGE variants and TD3. A warm
    start from critics saved without it fits the new ones to them first (``distil_critic``)."""
    actor_lr: float = 3e-4
    """Adam learning rate of the actor."""
    critic_lr: float = 3e-4
    """Adam learning rate of the critics."""
    alpha_lr: float = 3e-4
    """Adam learning rate of SAC's log entropy temperature."""
    init_alpha: float = 0.2
    """Initial entropy temperature α."""
    autotune_alpha: bool = True
    """Tune α towards ``target_entropy`` (SAC v2); False keeps ``init_alpha``."""
    target_entropy: float | None = None
    """Entropy target; None means -dim(action)."""
    polyak: float = 0.005
    """Target network soft-update rate."""
    batch_size: int = 256
    """Minibatch size of critic and actor updates."""
    buffer_size: int = 200_000
    """Capacity of the real replay buffer."""
    learning_starts: int = 1000
    """Real transitions collected before updates start (uniform random actions until then, without ``init``)."""
    updates_per_step: float = 1.0
    """Gradient updates per environment step (fractions mean one update every 1/x steps)."""
    cuda_graph: bool = False
    """Capture the update once as a CUDA graph and replay it (``--device cuda`` only; an error elsewhere): the
    small-batch update is bound by kernel launches on a GPU, which a graph removes (:mod:`core.sage.captured`)."""
    max_grad_norm: float | None = 10.0
    """Gradient-norm clip of actor and critic updates (protects against the rare huge -c* targets); None: off."""

    # -- fear regularisation -----------------------------------------------------------------------
    fear_budget: float = 0.2
    """F_0 of eq:fear_cmdp, the tolerated mean fear on real states, where ``fear_budget_from_data`` is off, and
    until a run's first world-model fit where it is on."""
    fear_budget_from_data: bool = True
    """Measure F_0 at every world-model fit: the mean fear F(s, a), a the learner's own action, over the fit's familiar
    states (no violation within what fear looks at; the states the τ bounds come from)."""
    lambda_init: float = 1.0
    """Initial value of the dual variable λ."""
    lambda_lr: float = 0.01
    """Step size of the projected dual ascent λ ← max(0, λ + lr (mean F - F_0))."""
    lambda_max: float = 100.0
    """Upper clip of λ, so that a long run above budget cannot make the fear term swamp the return."""
    fear_scale: Literal["none", "q"] = "none"
    """Actor's fear weight: ``none`` λ (eq:actor_loss_fear), ``q`` λ·max(1, mean|Q|) (detached, as imitation's), so
    that λ = 1 weighs fear like the batch's value. The critic target's -λF stays in reward units."""
    learner_fear_horizon: int = 1
    """Rollout steps of the fear inside the learner (critic target -λF_{t+1}, actor +λF, dual update); 1 is eq:fear,
    as eq:fear_cmdp states it. The gate uses ``gate.horizon`` (m)."""
    safety_horizon: int = 10
    """H of eq:penalty: steps within which an unsafe progression surely ends in a violation."""
    reward_bounds: tuple[float, float] | None = None
    """(r̲, r̄) of eq:penalty; None estimates them from the real buffer's non-terminal rewards."""

    # -- imitation ---------------------------------------------------------------------------------
    bc_weight: float = 1.0
    """Weight of the imitation term, scaled by the batch's mean |Q| so that it keeps pace with the RL term."""
    bc_batch_size: int = 128
    """Intervention samples (Ξ = 1) drawn per update for the imitation term."""
    advantage_temperature: float = 0.1
    """ω = exp(clip(A / (temperature · max(1, mean|Q|)), ±advantage_clip)), A = Q(s,a_E) - Q(s,a_RL)."""
    advantage_clip: float = 3.0
    """Clip of the scaled advantage, so ω stays in [e^-clip, e^clip] for any Q gap."""

    # -- virtual buffer ----------------------------------------------------------------------------
    virtual_ratio: float = 0.25
    """Fraction of every actor batch drawn from the virtual buffer (the rest from the real one)."""
    virtual_every: int = 250
    """Environment steps between batched model rollouts into the virtual buffer."""
    virtual_starts: int = 256
    """Real states each virtual rollout starts from (each yields ``gate.horizon`` transitions)."""
    virtual_size: int = 50_000
    """Capacity of the virtual buffer."""

    # -- world-model schedule ----------------------------------------------------------------------
    wm_fit_every: int = 1000
    """Environment steps between world-model fits (the first fit happens at ``learning_starts``)."""
    wm_min_samples: int = 500
    """Real transitions needed before the first world-model fit."""

    # -- TD3 ---------------------------------------------------------------------------------------
    td3_exploration_noise: float = 0.1
    """Std of the Gaussian exploration noise added to TD3's deterministic action."""
    td3_policy_noise: float = 0.2
    """Std of the target policy smoothing noise."""
    td3_noise_clip: float = 0.5
    """Clip of the target policy smoothing noise."""
    td3_policy_delay: int = 2
    """Critic updates per actor (and target) update."""

    # -- HG-DAgger ---------------------------------------------------------------------------------
    dagger_lr: float = 1e-3
    """Adam learning rate of HG-DAgger's supervised regression onto the aggregated expert labels."""

    # -- demonstrations / warm start ---------------------------------------------------------------
    pretrain_bc_steps: int = 2000
    """Behaviour-cloning steps on the demonstrations collected before training (when there are any)."""
    pretrain_critic_steps: int = 2000
    """Critic-only steps on the demonstrations after cloning, so the first actor updates see a sane Q."""

    world_model_config: WorldModelConfig = field(default_factory=WorldModelConfig)
    """The world model's architecture and training."""
    gate: GateConfig = field(default_factory=GateConfig)
    """Fear, curiosity, threshold and hold."""
    discrete: DiscreteConfig = field(default_factory=DiscreteConfig)
    """Exploration and imitation of the value-based discrete-action learners."""
    diffusion: DiffusionConfig = field(default_factory=DiffusionConfig)
    """Denoiser, schedule and offline training of the diffusion policies."""


SWITCHES: tuple[str, ...] = (
    "world_model",
    "fear_regularisation",
    "violation_penalty",
    "takeover",
    "imitation",
    "virtual_rollouts",
)
"""The fields that make one method differ from another (plus ``gate.use_curiosity``)."""


def for_method(method: str, base: AgentConfig | None = None, **overrides: Any) -> AgentConfig:
    """The preset of ``method`` with optional field overrides.

    ``base``: take every hyperparameter from this config (e.g. the run a training warm-starts from) and
    only the method's switches from the preset.

    - ``sage``: everything on.
    - ``fni-rl``: the fear-regularised learner (world model, fear in critic and actor, λ, c*, virtual
      rollouts) without takeover, imitation or curiosity.
    - ``sac``: plain SAC (all SAGE extras off).
    - ``td3``: TD3 (no SAGE extras).
    - ``hg-dagger``: aggregated imitation of expert takeovers; takeovers come from the SAGE gate on its own
      world model (see :mod:`core.sage.hg_dagger`).
    """
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")
    if base is None:
        cfg = AgentConfig(method=method)
    else:
        cfg = from_dict(to_dict(base))
        cfg.method = method
        for name in SWITCHES:
            setattr(cfg, name, True)
        cfg.gate.use_curiosity = True
        cfg.takeover_rule, cfg.intervention_penalty = "gate", 0.0  # Multi-Hug's own, not a base's to pass on
    if method == "fni-rl":
        cfg.takeover = cfg.imitation = False
        cfg.gate.use_curiosity = False
    elif method in ("sac", "td3"):
        cfg.world_model = cfg.fear_regularisation = cfg.violation_penalty = False
        cfg.takeover = cfg.imitation = cfg.virtual_rollouts = False
    elif method == "hg-dagger":
        cfg.fear_regularisation = cfg.violation_penalty = cfg.virtual_rollouts = False
        cfg.imitation = True
    for key, value in overrides.items():
        set_field(cfg, key, value)
    validate(cfg)
    return cfg


def world_model_refit(cfg: AgentConfig) -> AgentConfig:
    """The schedule of a world-model-only refit of a trained policy (``sage train --init RUN --world-model-only``):
    the policy drives as it would learn (stochastic actions), no expert takes over, and only the world model is
    fitted on what it meets; actor, critics and temperature take no step. The saved checkpoint keeps ``cfg``
    (the policy's own schedule), so that adapting from the refitted policy still learns."""
    refit = copy.deepcopy(cfg)
    refit.world_model = True
    refit.updates_per_step = 0.0
    refit.pretrain_bc_steps = refit.pretrain_critic_steps = refit.diffusion.offline_steps = 0
    refit.takeover = refit.virtual_rollouts = False
    validate(refit)
    return refit


def validate(cfg: AgentConfig) -> None:
    """Refuse inconsistent settings with an error that names the field."""
    if cfg.method not in _REGISTERED_METHODS:
        raise ValueError(f"method: unknown {cfg.method!r}; choose one of {', '.join(_REGISTERED_METHODS)}")
    needs_model = [name for name in ("fear_regularisation", "virtual_rollouts") if getattr(cfg, name)]
    if cfg.takeover and cfg.takeover_rule == "gate":
        needs_model.append("takeover (takeover_rule=gate)")
    if cfg.takeover_rule not in ("gate", "supervisor"):
        raise ValueError(f"takeover_rule must be gate or supervisor, got {cfg.takeover_rule!r}")
    if cfg.fear_scale not in ("none", "q"):
        raise ValueError(f"fear_scale must be none or q, got {cfg.fear_scale!r}")
    if needs_model and not cfg.world_model:
        raise ValueError(f"{', '.join(needs_model)} need world_model=true")
    if not 0.0 <= cfg.gate.beta <= 1.0:
        raise ValueError(f"gate.beta must be in [0, 1], got {cfg.gate.beta}")
    if not 0.0 <= cfg.gate.tau_min <= cfg.gate.tau_max:
        raise ValueError(f"need 0 <= gate.tau_min <= gate.tau_max, got {cfg.gate.tau_min}, {cfg.gate.tau_max}")
    if not 0.0 <= cfg.gate.tau_min_quantile < cfg.gate.tau_max_quantile <= 1.0:
        raise ValueError("need 0 <= gate.tau_min_quantile < gate.tau_max_quantile <= 1")
    if not (math.isfinite(cfg.gate.tau_scale) and cfg.gate.tau_scale > 0.0):
        raise ValueError(f"gate.tau_scale must be a finite number > 0, got {cfg.gate.tau_scale}")
    if cfg.gate.calibration_states < 100:
        raise ValueError(f"gate.calibration_states must be >= 100, got {cfg.gate.calibration_states}")
    if not 0.0 < cfg.gate.curiosity_smoothing <= 1.0:
        raise ValueError(f"gate.curiosity_smoothing must be in (0, 1], got {cfg.gate.curiosity_smoothing}")
    if cfg.gate.curiosity_signal == "novelty" and cfg.gate.curiosity_reference != "fitted":
        raise ValueError(
            "gate.curiosity_signal=novelty is a distance to the calibration states, read against its mean on them: "
            "set gate.curiosity_reference=fitted too"
        )
    if not 0.0 <= cfg.gate.release <= 1.0:
        raise ValueError(f"gate.release must be in [0, 1], got {cfg.gate.release}")
    for name in ("bc_weight", "refused_weight", "conservative_weight"):  # a negative weight would push the other way
        if not (math.isfinite(getattr(cfg, name)) and getattr(cfg, name) >= 0.0):
            raise ValueError(f"{name} must be a finite number >= 0, got {getattr(cfg, name)}")
    counts = (("lookback_labels", 0), ("conservative_actions", 1), ("ibrl_updates", 0), ("ibrl_refit_every", 0))
    for name, least in counts:
        if not (isinstance(getattr(cfg, name), int) and getattr(cfg, name) >= least):
            raise ValueError(f"{name} must be a whole number >= {least}, got {getattr(cfg, name)!r}")
    for name in ("refused_weight", "conservative_weight"):
        if getattr(cfg, name) > 0 and cfg.cuda_graph:
            raise ValueError(f"{name} > 0 is not captured in the CUDA graph's update: set cuda_graph=false")
    if cfg.ibrl and cfg.cuda_graph:
        raise ValueError("ibrl's proposals are not captured in the CUDA graph's update: set cuda_graph=false")
    if cfg.world_model_config.motion_lag < 1:
        raise ValueError(f"world_model_config.motion_lag must be >= 1, got {cfg.world_model_config.motion_lag}")
    wm = cfg.world_model_config
    if wm.conflict_steps < 1:
        raise ValueError(f"world_model_config.conflict_steps must be >= 1, got {wm.conflict_steps}")
    if not 0 <= wm.approach_start <= wm.approach_stop:
        raise ValueError(
            "world_model_config.approach_start..approach_stop must be channels 0 <= start <= stop, got "
            f"{wm.approach_start}..{wm.approach_stop}"
        )
    if wm.approach_stop > wm.approach_start and not wm.motion_input:
        raise ValueError("world_model_config.approach_* (an approach-rate input) needs motion_input=true")
    if wm.ego_sectors < 0:
        raise ValueError(f"world_model_config.ego_sectors must be >= 0, got {wm.ego_sectors}")
    if cfg.world_model_config.scan_sectors < 0:
        raise ValueError(f"world_model_config.scan_sectors must be >= 0, got {cfg.world_model_config.scan_sectors}")
    if cfg.world_model_config.scan_sectors and (
        cfg.world_model_config.motion_lag != 1 or not cfg.world_model_config.motion_input
    ):
        raise ValueError(
            "world_model_config.scan_sectors (a scan-aligned motion input) needs motion_input=true and motion_lag=1"
        )
    if not 0.0 <= cfg.world_model_config.cost_label_weight <= 1.0:
        raise ValueError(
            f"world_model_config.cost_label_weight must be in [0, 1], got {cfg.world_model_config.cost_label_weight}"
        )
    if cfg.gate.horizon < 1 or cfg.gate.hold_steps < 1:
        raise ValueError("gate.horizon and gate.hold_steps must be >= 1")
    if cfg.gate.step_seconds is not None and not cfg.gate.step_seconds > 0:
        raise ValueError(f"gate.step_seconds must be > 0, got {cfg.gate.step_seconds}")
    if cfg.gate.hold_seconds is not None:
        if not cfg.gate.hold_seconds > 0:
            raise ValueError(f"gate.hold_seconds must be > 0, got {cfg.gate.hold_seconds}")
        if cfg.gate.step_seconds is None:
            raise ValueError(
                "gate.hold_seconds needs gate.step_seconds, the simulator's step: a training run sets it from its "
                "simulator (a run made before it: refit with --episodes 0 --world-model-only), or set both"
            )
    if cfg.gate.contact_floors is not None and not all(
        f is None or (isinstance(f, int | float) and math.isfinite(f) and f >= 0) for f in cfg.gate.contact_floors
    ):
        raise ValueError(
            f"gate.contact_floors must be finite numbers >= 0 (or none: the channel shows no contact), "
            f"got {cfg.gate.contact_floors}"
        )
    if cfg.gate.imagined_contact and not any(f is not None for f in cfg.gate.contact_floors or ()):
        raise ValueError(
            "gate.imagined_contact needs gate.contact_floors, where the observation shows contact: a training run sets "
            "them from its simulator; a run made before them, or a simulator whose observation shows no contact, "
            "has none (sage gate refit-bounds RUN --set gate.imagined_contact=true fills them from its simulator)"
        )
    if cfg.gate.closing_veto is not None:
        if not (math.isfinite(cfg.gate.closing_veto) and cfg.gate.closing_veto > 0):
            raise ValueError(f"gate.closing_veto must be a positive number of seconds, got {cfg.gate.closing_veto}")
        if not any(f is not None for f in cfg.gate.contact_floors or ()):
            raise ValueError(
                "gate.closing_veto reads the channels where the observation shows contact: it needs "
                "gate.contact_floors (--set gate.closing_veto=T fills them from the run's simulator)"
            )
        if cfg.gate.step_seconds is None:
            raise ValueError("gate.closing_veto needs gate.step_seconds, the simulator's step (a training run sets it)")
    if cfg.gate.contact_horizon is not None:
        if cfg.gate.contact_horizon < 1:
            raise ValueError(f"gate.contact_horizon must be >= 1 (or None), got {cfg.gate.contact_horizon}")
        if not cfg.gate.imagined_contact:
            raise ValueError(
                "gate.contact_horizon is the reach of imagined contact: it needs gate.imagined_contact (to switch "
                "imagined contact off, also set gate.contact_horizon=none and gate.mover_model=none)"
            )
        if cfg.gate.contact_horizon > cfg.gate.horizon and cfg.gate.aggregate != "max":
            raise ValueError("gate.contact_horizon beyond gate.horizon needs gate.aggregate=max")
    if cfg.gate.contact_extrapolation and not cfg.gate.imagined_contact:
        raise ValueError(
            "gate.contact_extrapolation extrapolates closing scan sectors in the imagined contact test: it needs "
            "gate.imagined_contact"
        )
    if cfg.gate.mover_model not in ("none", "cartesian"):
        raise ValueError(f"gate.mover_model must be none or cartesian, got {cfg.gate.mover_model!r}")
    if cfg.gate.mover_model != "none":
        if not cfg.gate.imagined_contact:
            raise ValueError(
                "gate.mover_model adds movers to the imagined contact test: it needs gate.imagined_contact (to "
                "switch imagined contact off, also set gate.mover_model=none)"
            )
        if not cfg.world_model_config.ego_sectors:
            raise ValueError(
                "gate.mover_model places the scan's returns by the world model's ego step: it needs "
                "world_model_config.ego_sectors (the UGV's ego-motion model)"
            )
        movers = {
            "gate.mover_max_speed": cfg.gate.mover_max_speed,
            "gate.mover_max_size": cfg.gate.mover_max_size,
            "gate.mover_min_speed": cfg.gate.mover_min_speed,
        }
        for name, value in movers.items():
            if not isinstance(value, int | float) or not math.isfinite(value) or value <= 0:
                raise ValueError(f"{name} must be a finite number > 0, got {value}")
        if not isinstance(cfg.gate.mover_history, int) or cfg.gate.mover_history < 2:
            raise ValueError(f"gate.mover_history must be an integer >= 2, got {cfg.gate.mover_history}")
        if cfg.gate.mover_min_speed >= cfg.gate.mover_max_speed:
            raise ValueError("gate.mover_min_speed must be under gate.mover_max_speed")
    if cfg.gate.contact_needs_closing and not cfg.world_model_config.motion_input:
        raise ValueError("gate.contact_needs_closing reads the motion input: it needs world_model_config.motion_input")
    if not 0.0 < cfg.gamma < 1.0:
        raise ValueError(f"gamma must be in (0, 1), got {cfg.gamma}")
    if cfg.critics < 1 or cfg.world_model_config.members < 1:
        raise ValueError("critics and world_model_config.members must be >= 1")
    subset = cfg.critic_target_subset
    if subset is not None:
        if isinstance(subset, bool) or not isinstance(subset, int) or not 1 <= subset <= cfg.critics:
            raise ValueError(f"critic_target_subset must be None or 1..critics ({cfg.critics}), got {subset!r}")
        if cfg.cuda_graph:
            raise ValueError(
                "critic_target_subset draws its critics every update, which a captured CUDA graph would fix: "
                "set cuda_graph=false"
            )
    if not 0.0 <= cfg.virtual_ratio < 1.0:
        raise ValueError(f"virtual_ratio must be in [0, 1), got {cfg.virtual_ratio}")
    if cfg.reward_bounds is not None and cfg.reward_bounds[0] > cfg.reward_bounds[1]:
        raise ValueError(f"reward_bounds must be (low, high), got {cfg.reward_bounds}")


# -- (de)serialisation and overrides -------------------------------------------------------------
def to_dict(cfg: AgentConfig) -> dict[str, Any]:
    return dataclasses.asdict(cfg)


def from_dict(data: dict[str, Any]) -> AgentConfig:
    """Inverse of :func:`to_dict`; unknown keys are an error naming them (a config from another version)."""
    data = dict(data)
    wm = data.get("world_model_config")
    if isinstance(wm, dict) and "motion_input" not in wm:
        # a checkpoint from before the motion input: its world model reads (s, a) only
        data["world_model_config"] = {**wm, "motion_input": False}
    return _build(AgentConfig, data, prefix="")


def _build(cls: type, data: dict[str, Any], prefix: str) -> Any:
    hints = typing.get_type_hints(cls)
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - known)
    if unknown:
        raise ValueError(f"unknown config field(s): {', '.join(prefix + k for k in unknown)}")
    kwargs: dict[str, Any] = {}
    for name, value in data.items():
        hint = hints[name]
        if dataclasses.is_dataclass(hint):
            kwargs[name] = _build(hint, value, prefix + name + ".")  # type: ignore[arg-type]
        elif name == "reward_bounds" and value is not None:
            kwargs[name] = (float(value[0]), float(value[1]))
        else:
            kwargs[name] = value
    return cls(**kwargs)


def set_field(cfg: Any, dotted: str, value: Any) -> None:
    """Set ``a.b`` on a (nested) config, converting strings to the field's type."""
    *parents, name = dotted.split(".")
    target = cfg
    for part in parents:
        if not hasattr(target, part) or not dataclasses.is_dataclass(getattr(target, part)):
            raise ValueError(f"unknown config section {part!r} in {dotted!r}")
        target = getattr(target, part)
    fields = {f.name for f in dataclasses.fields(target)}
    if name not in fields:
        raise ValueError(f"unknown config field {dotted!r}; known: {', '.join(sorted(fields))}")
    hint = typing.get_type_hints(type(target))[name]
    setattr(target, name, _convert(value, hint, dotted))


def parse_gate_settings(pairs: list[str], contact_floors: Sequence[float | None] = ()) -> dict[str, Any]:
    """``KEY=VALUE`` strings (``--set gate.KEY=VALUE``) as :class:`GateConfig` settings of the field's type, e.g.
    ``["hold_seconds=2"]`` -> ``{"hold_seconds": 2.0}``. Unknown names and unreadable values are a ValueError; the
    settings are validated where they meet a run's gate (:meth:`core.agents.LoadedAgent.gate_config`), since some
    need the run's own (``hold_seconds`` its ``step_seconds``). ``contact_floors``: the simulator's
    (:attr:`core.descriptor.SimDescriptor.contact_floors`), which ``imagined_contact=true`` or ``closing_veto=T``
    brings along unless the pairs set them, so that a run trained before the floors were recorded can switch it on."""
    gate, settings = GateConfig(), {}
    for pair in pairs:
        if "=" not in pair:
            raise ValueError(f"gate setting {pair!r} is not of the form key=value")
        key, value = (part.strip() for part in pair.split("=", 1))
        set_field(gate, key, value)
        settings[key] = getattr(gate, key)
    wants_floors = settings.get("imagined_contact") or settings.get("closing_veto") is not None
    if wants_floors and "contact_floors" not in settings and contact_floors:
        settings["contact_floors"] = [None if f is None else float(f) for f in contact_floors]
    return settings


def apply_overrides(cfg: AgentConfig, pairs: list[str]) -> AgentConfig:
    """Apply ``key=value`` strings (``--set`` on the command line) and validate the result."""
    for pair in pairs:
        if "=" not in pair:
            raise ValueError(f"override {pair!r} is not of the form key=value")
        key, value = pair.split("=", 1)
        set_field(cfg, key.strip(), value.strip())
    validate(cfg)
    return cfg


def _convert(value: Any, hint: Any, name: str) -> Any:
    if not isinstance(value, str):
        return value
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        if value.lower() in ("none", "null"):
            return None
        hint = next(a for a in args if a is not type(None))
        origin, args = typing.get_origin(hint), typing.get_args(hint)
    try:
        if hint is bool:
            if value.lower() in ("1", "true", "yes", "on"):
                return True
            if value.lower() in ("0", "false", "no", "off"):
                return False
            raise ValueError(value)
        if hint is int:
            return int(value)
        if hint is float:
            return float(value)
        if origin is tuple:
            low, high = (float(v) for v in value.strip("()[] ").split(","))
            return (low, high)
        if origin is list and args in ((float,), (float | None,)):
            items = [v.strip() for v in value.strip("[] ").split(",") if v.strip()]
            blank = args != (float,)  # a list that may hold None (a channel without a contact floor)
            return [None if blank and v.lower() in ("none", "null") else float(v) for v in items]
        if origin is Literal:
            if value not in args:
                raise ValueError(value)
            return value
    except ValueError:
        raise ValueError(f"{name}: cannot read {value!r} as {_described(hint)}") from None
    return value


def _described(hint: Any) -> str:
    """A type hint as a reader names it: ``int``, ``true or false``, ``one of 'none', 'q'``, ``two numbers``."""
    if hint is bool:
        return "true or false"
    if isinstance(hint, type):
        return hint.__name__
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin is Literal:
        return "one of " + ", ".join(repr(a) for a in args)
    if origin is tuple:
        return "two numbers (low,high)"
    if origin is list:
        return "a comma-separated list of numbers"
    return str(hint)
