"""The curiosity-modulated threshold (eq:curiosity, eq:threshold).

Curiosity and threshold. C_t = ||ŝ_{t+1} - s_{t+1}||₂ on states normalised by the model's state std. With
r = C_t / Ĉ_{t-1}, Ĉ an exponential moving average of recent curiosity (started at the held-out curiosity of the
last fit), ρ(C_t) = r^p / (1 + r^p) ∈ [0, 1) (p = ``curiosity_sharpness``, 2 by default; p = 1 is C / (C + Ĉ)):
ρ = 1/2 when curiosity is at its recent average, → 1 when far above it (novel ground, threshold towards
τ_min), → 0 when far below (familiar, threshold towards τ_max). τ_t = τ_max - ρ(C_t)(τ_max - τ_min).
On UGV data the curiosity of a mover's approach is 2-4 times its average while static driving sits well
below it, which p = 2 turns into ρ ≈ 0.8-0.95 against ≈ 0.05.
"""

from __future__ import annotations

import math

from core.sage.config import GateConfig


class CuriosityThreshold:
    """τ_t = τ_max - ρ(C_t)(τ_max - τ_min), ρ(C) = C / (C + EMA of recent C) (see the module docstring), or its
    geometric form (``GateConfig.tau_interpolation``)."""

    def __init__(self, cfg: GateConfig, reference: float = 1.0, bounds: tuple[float, float] | None = None) -> None:
        self.cfg = cfg
        self.ema = max(float(reference), 1e-8)
        self.smoothed: float | None = None
        """C_t smoothed over a few steps (``curiosity_smoothing``): one noisy transition must not swing τ."""
        self.tau_min, self.tau_max = cfg.tau_min, cfg.tau_max
        self.set_bounds(bounds)
        self.threshold = self.neutral()

    def set_bounds(self, bounds: tuple[float, float] | None) -> None:
        """(τ_min, τ_max) measured from data (:func:`calibrate`); None or non-finite keeps the config's. Either
        is multiplied by ``tau_scale``."""
        if bounds is not None and all(math.isfinite(b) for b in bounds) and bounds[1] > bounds[0]:
            low, high = float(bounds[0]), float(bounds[1])
        else:
            low, high = self.cfg.tau_min, self.cfg.tau_max
        self.tau_min, self.tau_max = self.cfg.tau_scale * low, self.cfg.tau_scale * high

    def neutral(self) -> float:
        return self.at(0.5)

    def at(self, rho: float) -> float:
        """τ for ρ in [0, 1]: ``tau_interpolation`` between τ_max (ρ = 0) and τ_min (ρ = 1)."""
        if self.cfg.tau_interpolation == "geometric" and self.tau_min > 0.0:
            return self.tau_min**rho * self.tau_max ** (1.0 - rho)
        return self.tau_max - rho * (self.tau_max - self.tau_min)

    def rho(self, curiosity: float) -> float:
        if not math.isfinite(curiosity) or curiosity < 0:
            return 0.5
        ratio = (curiosity / self.ema) ** self.cfg.curiosity_sharpness
        return ratio / (1.0 + ratio) if math.isfinite(ratio) else 1.0

    def reset_smoothing(self) -> None:
        """A new episode: its first transition is not smoothed with the last one's."""
        self.smoothed = None

    def update(self, curiosity: float) -> float:
        """Take C_t, return the threshold τ_t it sets, then fold C_t into the moving average."""
        if not self.cfg.use_curiosity:
            self.threshold = self.neutral()
            return self.threshold
        if math.isfinite(curiosity) and curiosity >= 0:
            alpha = self.cfg.curiosity_smoothing
            self.smoothed = curiosity if self.smoothed is None else (1 - alpha) * self.smoothed + alpha * curiosity
        rho = self.rho(self.smoothed if self.smoothed is not None else curiosity)
        self.threshold = self.at(rho)
        if math.isfinite(curiosity) and self.cfg.curiosity_reference == "recent":  # "fitted": a fixed reference
            self.ema = max((1.0 - self.cfg.curiosity_ema) * self.ema + self.cfg.curiosity_ema * curiosity, 1e-8)
        return self.threshold
