"""Setting κ and the threshold bounds from real states (:func:`calibrate`), and the sample of real states a run keeps
for it (:class:`CalibrationSample`, a run folder's ``calibration.npz``): what :mod:`core.sage.fear`'s terms are
scaled by, measured after every world-model fit, by ``sage gate refit-bounds`` and when refits are merged."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from core.sage.config import GateConfig
from core.sage.fear import PolicyFn, contact_reach, contact_terms, fear_of, rollout
from core.sage.world_model import MAX_HORIZON, EnsembleWorldModel


def calibrate(
    world_model: EnsembleWorldModel,
    policy: PolicyFn,
    obs: Tensor,
    horizon: int,
    quantile: float = 0.95,
    cfg: GateConfig | None = None,
    safe: Tensor | None = None,
    motion: Tensor | None = None,
    closing_rate: Tensor | None = None,
    mover_velocity: Tensor | None = None,
) -> Tensor:
    """Set κ_k, the ``quantile`` of σ_raw at each rollout step k from real states ``obs`` under ``policy``; with
    ``cfg``, also the threshold bounds (τ_min, τ_max): the ``tau_min_quantile`` and ``tau_max_quantile`` of the
    fear of those states that were ``safe`` (no violation ahead: the states a gate should leave alone), so that
    each simulator's threshold sits where its familiar, safe fear lies (a UGV-tuned constant range put every SUMO
    and highway fear below τ_max; quantiles over all states, near-misses included, put τ above most of the
    fear that precedes a collision). ``closing_rate``: each state's closing the real scans before it showed, for a
    gate that extrapolates it (:func:`closing_rate`, ``GateConfig.contact_extrapolation``; None: none).
    ``mover_velocity``: (B, S, 2) each state's movers as the real scans before it showed, for a gate with a mover
    model (:func:`core.sage.movers.mover_velocities`, ``GateConfig.mover_model``; None: none)."""
    with torch.no_grad():
        folded = world_model.folded()
        learned = min(horizon, MAX_HORIZON)
        steps = min(contact_reach(cfg, horizon), MAX_HORIZON)  # the gate's imagined contact may reach further
        terms = contact_terms(cfg, motion)
        rate = closing_rate if cfg is not None and cfg.contact_extrapolation else None
        movers = mover_velocity if cfg is not None and cfg.mover_model != "none" else None
        ro = rollout(
            folded,
            policy,
            obs,
            policy(obs),
            steps,
            motion,
            *terms,
            learned_steps=learned,
            closing_rate=rate,
            mover_velocity=movers,
        )
        scale = torch.quantile(ro.sigma_raw[:learned], quantile, dim=1).clamp_min(1e-6)
        world_model.sigma_scale[: len(scale)] = scale
        world_model.sigma_scale[len(scale) :] = scale[-1]
        world_model.touch()
        familiar = None if safe is None else safe.bool().reshape(-1)
        if cfg is not None and len(obs) >= 20 and (familiar is None or int(familiar.sum()) >= 20):
            fear = fear_of(world_model.folded(), ro, cfg)
            values = fear.fear if familiar is None else fear.fear[familiar]
            lo = float(torch.quantile(values, cfg.tau_min_quantile))
            hi = float(torch.quantile(values, cfg.tau_max_quantile))
            world_model.tau_bounds.copy_(torch.tensor([lo, max(hi, lo + 1e-3)]))
        # the policy's own action on each state, as its gate sees most transitions
        world_model.disagreement_ref.fill_(float(world_model.disagreement(obs, policy(obs), motion).mean()))
        if cfg is not None and cfg.curiosity_signal == "novelty":  # only a gate that reads it keeps the set
            world_model.set_novelty_reference(obs, motion)
    world_model.touch()
    return scale


CALIBRATION_FILE = "calibration.npz"
"""A run folder's :class:`CalibrationSample` of its last world-model fit."""


@dataclass
class CalibrationSample:
    """Real states a world model's κ and τ bounds were set on (:func:`calibrate`), with what re-setting them on
    another model needs: whether each was familiar (``safe``), its motion input, and the transition that
    followed (for curiosity). A run folder keeps its last fit's sample as ``calibration.npz``, so that the
    world models of several refits can be merged into one ensemble and calibrated on their own data
    (:func:`core.merge.merge_runs`)."""

    obs: np.ndarray
    action: np.ndarray
    next_obs: np.ndarray
    familiar: np.ndarray
    motion: np.ndarray | None = None
    closing_rate: np.ndarray | None = None
    """(B, n) each state's closing per step that the real scans before it showed (``gate.contact_extrapolation``'s
    :func:`closing_rate`); None where the gate it was drawn for does not extrapolate (read as none)."""
    mover_velocity: np.ndarray | None = None
    """(B, S, 2) each state's movers as the real scans before it showed (``gate.mover_model``'s
    :func:`core.sage.movers.mover_velocities`); None where the gate it was drawn for has no mover model (none)."""

    def __post_init__(self) -> None:
        n = len(self.obs)
        parts = {"action": self.action, "next_obs": self.next_obs, "familiar": self.familiar}
        if self.motion is not None:
            parts["motion"] = self.motion
        if self.closing_rate is not None:
            parts["closing_rate"] = self.closing_rate
        if self.mover_velocity is not None:
            parts["mover_velocity"] = self.mover_velocity
        for name, values in parts.items():
            if len(values) != n:
                raise ValueError(f"calibration sample: {name} has {len(values)} rows, obs has {n}")

    def __len__(self) -> int:
        return len(self.obs)

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        arrays = {"obs": self.obs, "action": self.action, "next_obs": self.next_obs, "familiar": self.familiar}
        if self.motion is not None:
            arrays["motion"] = self.motion
        if self.closing_rate is not None:
            arrays["closing_rate"] = self.closing_rate
        if self.mover_velocity is not None:
            arrays["mover_velocity"] = self.mover_velocity
        tmp = path.with_name(path.name + ".tmp.npz")
        # allow_pickle given (its default): else mypy matches **arrays against it too
        np.savez_compressed(tmp, allow_pickle=True, **arrays)
        tmp.replace(path)
        return path

    @classmethod
    def load(cls, path: str | Path) -> CalibrationSample:
        try:
            with np.load(path, allow_pickle=False) as data:
                arrays = {key: np.asarray(data[key]) for key in data.files}
        except (OSError, ValueError) as exc:
            raise ValueError(f"{path} is not a readable calibration sample ({exc})") from None
        missing = {"obs", "action", "next_obs", "familiar"} - set(arrays)
        if missing:
            raise ValueError(f"{path} is not a calibration sample: it lacks {', '.join(sorted(missing))}")
        return cls(
            obs=arrays["obs"].astype(np.float32),
            action=arrays["action"].astype(np.float32),
            next_obs=arrays["next_obs"].astype(np.float32),
            familiar=arrays["familiar"].astype(bool),
            motion=arrays["motion"].astype(np.float32) if "motion" in arrays else None,
            closing_rate=arrays["closing_rate"].astype(np.float32) if "closing_rate" in arrays else None,
            mover_velocity=arrays["mover_velocity"].astype(np.float32) if "mover_velocity" in arrays else None,
        )

    def calibrate(self, world_model: EnsembleWorldModel, policy: PolicyFn, cfg: GateConfig) -> None:
        """Set ``world_model``'s κ and τ bounds on these states under ``policy`` (:func:`calibrate`) for the gate
        ``cfg``: its fear (β, horizon, aggregation) and its quantiles."""
        calibrate(
            world_model,
            policy,
            torch.from_numpy(self.obs),
            cfg.horizon,
            cfg=cfg,
            safe=torch.from_numpy(self.familiar),
            motion=None if self.motion is None else torch.from_numpy(self.motion),
            closing_rate=None if self.closing_rate is None else torch.from_numpy(self.closing_rate),
            mover_velocity=None if self.mover_velocity is None else torch.from_numpy(self.mover_velocity),
        )

    @classmethod
    def concat(cls, samples: list[CalibrationSample]) -> CalibrationSample:
        if not samples:
            raise ValueError("no calibration samples to join")
        with_motion = {s.motion is not None for s in samples}
        if len(with_motion) > 1:
            raise ValueError("calibration samples disagree on the motion input: some have it, some do not")
        return cls(
            obs=np.concatenate([s.obs for s in samples]),
            action=np.concatenate([s.action for s in samples]),
            next_obs=np.concatenate([s.next_obs for s in samples]),
            familiar=np.concatenate([s.familiar for s in samples]),
            motion=np.concatenate([s.motion for s in samples]) if with_motion == {True} else None,
            closing_rate=_joined_rates(samples),
            mover_velocity=_joined_movers(samples),
        )

    def subset(self, index: np.ndarray) -> CalibrationSample:
        return CalibrationSample(
            obs=self.obs[index],
            action=self.action[index],
            next_obs=self.next_obs[index],
            familiar=self.familiar[index],
            motion=None if self.motion is None else self.motion[index],
            closing_rate=None if self.closing_rate is None else self.closing_rate[index],
            mover_velocity=None if self.mover_velocity is None else self.mover_velocity[index],
        )


def _joined_rates(samples: list[CalibrationSample]) -> np.ndarray | None:
    """The samples' closing rates joined; a sample without them (drawn for a gate that does not extrapolate) reads
    as none closing, zeros. None when no sample has them."""
    widths = {s.closing_rate.shape[1] for s in samples if s.closing_rate is not None}
    if not widths:
        return None
    if len(widths) > 1:
        raise ValueError("calibration samples disagree on the closing rates' channels")
    width = widths.pop()
    return np.concatenate(
        [s.closing_rate if s.closing_rate is not None else np.zeros((len(s), width), np.float32) for s in samples]
    )


def _joined_movers(samples: list[CalibrationSample]) -> np.ndarray | None:
    """The samples' mover velocities joined; a sample without them (drawn for a gate without a mover model) reads as
    none moving, zeros. None when no sample has them."""
    shapes = {s.mover_velocity.shape[1:] for s in samples if s.mover_velocity is not None}
    if not shapes:
        return None
    if len(shapes) > 1:
        raise ValueError("calibration samples disagree on the mover velocities' sectors")
    shape = shapes.pop()
    return np.concatenate(
        [s.mover_velocity if s.mover_velocity is not None else np.zeros((len(s), *shape), np.float32) for s in samples]
    )
