"""The world model's trainer: when to fit it, the fit on the real buffer, what each fit measures (the τ bounds and
κ on the buffer's familiar states, and the fear budget F_0 from them) and the virtual rollouts into D_virtual.

As mbrl-lib keeps the model, the model trainer and the algorithm apart, three parts meet here: the model
(:class:`~core.sage.world_model.EnsembleWorldModel`, which knows how to fit itself on arrays), this trainer (which
knows the schedule, the buffers and the familiar states) and the algorithm (a learner of :mod:`core.sage.learner`,
which owns one :class:`WorldModelTrainer` when its method trains a model, and hands it its policy and its fear).

Virtual buffer. The paper stores the fear rollouts' imagined transitions in D_virtual. Here the same model is
rolled the same m steps under the same (current, deterministic) policy, from a batch of real states every
``virtual_every`` steps and after every fit (:meth:`WorldModelTrainer.virtual_rollout`), instead of copying the
gate's single-state rollouts: the gate must stay sub-millisecond and also runs where no learner exists (the live
dashboard), and batched rollouts give the actor the same imagined states at a fraction of the cost.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch
from torch import Tensor

from core.replay import ReplayBuffer, VirtualBuffer
from core.sage.calibration import CalibrationSample
from core.sage.config import AgentConfig, GateConfig
from core.sage.fear import (
    PolicyFn,
    closing_rate,
    contact_reach,
    contact_terms,
    rollout,
    sample_member_transitions,
    unexplained_change,
)
from core.sage.world_model import EnsembleWorldModel, FitReport

SAFE_LABEL = 0.1
"""A state counts as safe for the threshold bounds when no violation lies ahead and its cost is below this (a
dense proximity cost of 0.3 near a wall is not a state the gate should learn to leave alone)."""

FEAR_BUDGET_MIN_STATES = 20
"""The fewest familiar states a calibration sample must hold for its mean fear to set the fear budget F_0."""


def familiar_for_bounds(
    buffer: ReplayBuffer, violation_steps: int, horizon: int, conflict_weight: float = 0.0, conflict_steps: int = 1
) -> np.ndarray:
    """Per stored row (the order of :meth:`ReplayBuffer.arrays`): whether the state counts as safe for the
    threshold bounds, the states whose fear a gate should leave alone: cost below :data:`SAFE_LABEL`, and no
    violation within all that fear looks at, the m = ``horizon`` rollout steps and then the violation label's own
    ``violation_steps``. A state 1.2 s before a collision, where fear should rise, is not familiar; counted as
    such (the label's window alone ends at 1 s), it lifts τ above the fear that warns of the collision. Where the
    world model also learns conflicts (``conflict_weight``, its ``conflict_label_weight``), a conflict is no
    familiar state either, nor one the label marks as ``conflict_steps`` before a conflict."""
    ahead = buffer.violation_soon(violation_steps + horizon)
    data = buffer.arrays()
    conflict = conflict_weight * buffer.conflict_soon(conflict_steps)
    return np.maximum.reduce([data["cost"], ahead, conflict]) < SAFE_LABEL


def calibration_sample(
    buffer: ReplayBuffer,
    world_model: EnsembleWorldModel,
    gate: GateConfig,
    rng: np.random.Generator,
    motion: np.ndarray | None = None,
) -> CalibrationSample:
    """Up to ``gate.calibration_states`` distinct rows of the real buffer (all of them when it holds fewer), each
    marked familiar or not (:func:`familiar_for_bounds`), with the model's motion input (``motion``: the buffer's
    :meth:`~core.replay.ReplayBuffer.previous_deltas`, computed here when None and the model reads it): the states a
    fit sets κ and the τ bounds on (:meth:`CalibrationSample.calibrate`)."""
    data = buffer.arrays()
    wanted = gate.calibration_states
    n = len(buffer)
    # distinct states, as many as the config allows: τ_max is a tail quantile (see GateConfig)
    idx = np.arange(n) if n <= wanted else np.sort(rng.choice(n, size=wanted, replace=False))
    if motion is None and world_model.motion:
        motion = buffer.previous_deltas(world_model.motion_lag, world_model.scan)
    wm = world_model.cfg
    # familiar: no violation within the fear's reach (imagined contact's, where it looks further: contact_reach)
    familiar = familiar_for_bounds(
        buffer, wm.violation_steps, contact_reach(gate, gate.horizon), wm.conflict_label_weight, wm.conflict_steps
    )
    return CalibrationSample(
        obs=data["obs"][idx],
        action=data["action"][idx],
        next_obs=data["next_obs"][idx],
        familiar=familiar[idx],
        motion=None if motion is None else motion[idx],
        closing_rate=buffer_closing_rates(buffer, world_model, gate, idx),
        mover_velocity=buffer_mover_velocities(buffer, world_model, gate, idx),
    )


def buffer_closing_rates(
    buffer: ReplayBuffer, world_model: EnsembleWorldModel, gate: GateConfig, idx: np.ndarray
) -> np.ndarray | None:
    """(len(idx), n) the closing rate the gate would have read at each of the stored rows ``idx``
    (:meth:`core.sage.gate.SageGate.closing_rate`: from the episode's two transitions before the row), for a gate with
    ``contact_extrapolation``; zeros where the episode had not yet shown two. None for a gate without it."""
    if not gate.contact_extrapolation or not gate.contact_floors:
        return None
    channels = len(gate.contact_floors)
    data = buffer.arrays()
    rates = np.zeros((len(idx), channels), np.float32)
    before = [buffer.preceding_rows(back)[idx] for back in (2, 1)]  # the older transition first
    known = (before[0] >= 0) & (before[1] >= 0)
    if not known.any():
        return rates
    changes = []
    with torch.no_grad():
        for rows in before:
            rows = rows[known]
            obs, action = torch.from_numpy(data["obs"][rows]), torch.from_numpy(data["action"][rows])
            moved = world_model.base(obs, action)
            changes.append(unexplained_change(moved, torch.from_numpy(data["next_obs"][rows]), channels))
    rates[known] = closing_rate(*changes).numpy()
    return rates


def buffer_mover_velocities(
    buffer: ReplayBuffer, world_model: EnsembleWorldModel, gate: GateConfig, idx: np.ndarray
) -> np.ndarray | None:
    """(len(idx), S, 2) the movers the gate would have read at each of the stored rows ``idx``
    (:meth:`core.sage.gate.SageGate.mover_velocity`: from the episode's ``gate.mover_history`` transitions before the
    row), for a gate with a mover model; zeros where the episode had not yet shown them. None for a gate without one
    (or a model without the ego step)."""
    ego = world_model.ego
    if gate.mover_model == "none" or not gate.contact_floors or ego is None:
        return None
    # the gate's compiled velocities (numpy's within float64 rounding, tests/core/sage/test_compiled_movers.py): a
    # calibration sample reads some 3,000 rows, 3.4 s a fit of a UGV SAGE run through numpy's (profiled)
    from core.sage.compiled_movers import compiled_mover_velocities

    data = buffer.arrays()
    s, history = ego.sectors, gate.mover_history
    out = np.zeros((len(idx), s, 2), np.float32)
    before = np.stack([buffer.preceding_rows(back)[idx] for back in range(history, 0, -1)])  # oldest first
    for row in np.flatnonzero((before >= 0).all(0)):
        rows = before[:, row]
        scans = np.concatenate([data["obs"][rows][:, :s], data["next_obs"][rows[-1:]][:, :s]])
        out[row] = compiled_mover_velocities(
            ego, scans, data["action"][rows], gate.mover_max_speed, gate.mover_max_size, gate.mover_min_speed
        )
    return out


def familiar_mean_fear(sample: CalibrationSample, fear: Callable[[Tensor], Tensor]) -> float | None:
    """The fear budget F_0 measured from data (``AgentConfig.fear_budget_from_data``): the mean of ``fear`` (F(s, a)
    on real states, a the learner's own action) over ``sample``'s familiar states; None when it holds fewer than
    :data:`FEAR_BUDGET_MIN_STATES` of them."""
    familiar = np.asarray(sample.familiar, dtype=bool)
    if int(familiar.sum()) < FEAR_BUDGET_MIN_STATES:
        return None
    with torch.no_grad():
        values = fear(torch.from_numpy(np.asarray(sample.obs[familiar], dtype=np.float32)))
    return float(values.mean())


class WorldModelTrainer:
    """Fits one world model on a learner's real buffer when due, measures each fit's τ bounds, and rolls the model
    out into the virtual buffer.

    It draws from the learner's own generator (``rng``, shared, not copied): fits, calibration samples, rollouts
    and the learner's updates take their numbers from one stream in the order they run."""

    def __init__(self, world_model: EnsembleWorldModel, cfg: AgentConfig, rng: np.random.Generator) -> None:
        self.world_model, self.cfg, self.rng = world_model, cfg, rng
        self.steps_at_last_fit: int | None = None
        """The learner's environment steps at the last fit (None: none yet in this run; fit once enough data)."""
        self.steps_at_last_rollout = 0
        self.last_fit: FitReport | None = None
        self.last_calibration: CalibrationSample | None = None
        """The states the last fit calibrated κ and the τ bounds on (kept by a run folder for ``sage gate merge``)."""

    def ready(self) -> bool:
        """Whether the model has been fitted (here or in a loaded checkpoint)."""
        return bool(self.world_model.fitted)

    def fit_due(self, buffer: ReplayBuffer, env_steps: int) -> bool:
        """Whether a fit is due: ``wm_min_samples`` real transitions stored, and none yet in this run or
        ``wm_fit_every`` steps since the last."""
        if len(buffer) < self.cfg.wm_min_samples:
            return False
        last = self.steps_at_last_fit
        return last is None or env_steps - last >= self.cfg.wm_fit_every

    def schedule_refit(self) -> None:
        """Fit again as soon as there is enough of this run's data (a loaded model was fitted on another run's)."""
        self.steps_at_last_fit = None

    def fit(self, buffer: ReplayBuffer, policy: PolicyFn, env_steps: int) -> FitReport:
        """Fit on the whole real buffer (its violation and conflict labels, and the motion input where the model
        reads one), then recalibrate κ and the τ bounds on a sample of its states, ``policy`` choosing the
        rollouts' actions (:func:`calibration_sample`, :attr:`last_calibration`)."""
        wm = self.world_model
        data = buffer.arrays()
        labels = buffer.violation_soon(wm.cfg.violation_steps)
        motion = buffer.previous_deltas(wm.motion_lag, wm.scan) if wm.motion else None
        report = wm.fit(
            data["obs"],
            data["action"],
            data["next_obs"],
            data["cost"],
            self.rng,
            violation_soon=labels,
            motion=motion,
            conflict=buffer.conflict_soon(wm.cfg.conflict_steps),
        )
        self.steps_at_last_fit = env_steps
        self.last_fit = report
        self.last_calibration = calibration_sample(buffer, wm, self.cfg.gate, self.rng, motion)
        self.last_calibration.calibrate(wm, policy, self.cfg.gate)
        return report

    def rollout_due(self, env_steps: int) -> bool:
        """Whether a virtual rollout is due: a fitted model and ``virtual_every`` steps since the last."""
        return self.ready() and env_steps - self.steps_at_last_rollout >= self.cfg.virtual_every

    def virtual_rollout(self, buffer: ReplayBuffer, virtual: VirtualBuffer, policy: PolicyFn, env_steps: int) -> None:
        """Roll the model m steps from ``virtual_starts`` real states under ``policy`` into ``virtual`` (a randomly
        chosen member's imagined trajectory per start); nothing before a fit or with an empty buffer."""
        if not self.ready() or len(buffer) == 0:
            return
        # the model and the rollout policy (the acting copy) live on the CPU, whatever device the update samples to
        starts = buffer.sample(self.cfg.virtual_starts, self.rng).obs.cpu()
        with torch.no_grad():
            ro = rollout(
                self.world_model.folded(),
                policy,
                starts,
                policy(starts),
                self.cfg.gate.horizon,
                None,
                *contact_terms(self.cfg.gate, None),  # no motion here: contact that needs closing counts none
            )
        virtual.add_batch(*sample_member_transitions(ro, self.rng))
        self.steps_at_last_rollout = env_steps
