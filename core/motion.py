"""The world model's motion input: the last change of state, with a range scan seen from the current heading.

One lidar frame carries no motion, so the world model also reads s_t - s_{t-1}. For a robot that turns, that
difference of two ego-centric scans is mostly the robot's own rotation: every range slides sideways by the
turn, and a mover's approach (millimetres of range per step) drowns in it. Measured on the UGV: while the
scripted expert turned on the spot, the fear of the policy's plan fell to 0.001-0.01 with a mover 0.6-0.8 m
away and closing, and the collisions on the crossing scenario came 0.1-1.3 s after such a turn.

:class:`ScanAlignment` removes the rotation: before differencing, the previous scan is resampled at the
bearings the current scan's sectors had then (linear interpolation between neighbouring sectors; a sector
that has turned in from outside the field of view takes the nearest edge sector's range), so a static
obstacle gives no motion under a pure turn and a mover gives its own. The turn over the step comes from the
current observation itself (the UGV observes its last yaw-rate command), so the same alignment serves the real
history, the replay buffer's training inputs and the imagined steps of a fear rollout (where the next state is
the model's prediction). The policy's observation is unchanged.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import torch
from torch import Tensor

if TYPE_CHECKING:
    from core.sage.config import WorldModelConfig


@dataclass(frozen=True)
class ScanAlignment:
    """Where the scan and the turn are in the observation (``WorldModelConfig.scan_*``)."""

    sectors: int
    """Channels [0, sectors) are ranges over evenly spaced sectors, in order of increasing bearing (the UGV's:
    rightmost first)."""
    turn_channel: int
    """The channel holding the turn over the step that led to this observation (a yaw rate, any units)."""
    sectors_per_unit: float
    """Sectors the heading turns by over one step per unit of ``turn_channel`` (positive: bearings increase
    with the turn channel, so a static obstacle slides to lower sectors)."""

    @classmethod
    def of(cls, sectors: int, turn_channel: int, sectors_per_unit: float, obs_dim: int) -> ScanAlignment | None:
        """The alignment a world model config describes (None for ``sectors`` 0); a ValueError names what does
        not fit an observation of ``obs_dim`` channels."""
        if sectors == 0:
            return None
        if not 2 <= sectors <= obs_dim:
            raise ValueError(f"world_model_config.scan_sectors must be 0 or in [2, {obs_dim}], got {sectors}")
        if not sectors <= turn_channel < obs_dim:
            raise ValueError(
                f"world_model_config.scan_turn_channel must be a channel after the scan, in [{sectors}, {obs_dim}), "
                f"got {turn_channel}"
            )
        if not np.isfinite(sectors_per_unit) or sectors_per_unit == 0:
            raise ValueError(f"world_model_config.scan_turn_sectors must be finite, non-zero; got {sectors_per_unit}")
        return cls(int(sectors), int(turn_channel), float(sectors_per_unit))

    def motion(self, previous: Tensor, current: Tensor) -> Tensor:
        """current - previous with ``previous``'s scan resampled at the bearings of ``current``'s sectors: the
        change of state with the robot's own turn taken out of the scan (any leading shape, (..., D))."""
        s = self.sectors
        shift = current[..., self.turn_channel : self.turn_channel + 1] * self.sectors_per_unit
        position = torch.add(_sector_index(s, previous.dtype, previous.device), shift).clamp_(0.0, s - 1.0)
        low = position.floor()
        index = low.long()
        frac = position.sub_(low)
        scan = previous[..., :s]
        below = torch.gather(scan, -1, index)
        above = torch.gather(scan, -1, (index + 1).clamp_max_(s - 1))
        out = current - previous
        out[..., :s] = current[..., :s] - below.lerp_(above, frac)
        return out


_INDEX: dict[tuple[int, torch.dtype, torch.device], Tensor] = {}


def _sector_index(sectors: int, dtype: torch.dtype, device: torch.device | None = None) -> Tensor:
    """0, 1, ..., sectors - 1 (cached: the gate aligns a scan at every imagined step)."""
    key = (sectors, dtype, torch.device("cpu") if device is None else device)
    if key not in _INDEX:
        with torch.inference_mode(False):  # a normal tensor, whichever mode asks first: autograd reads it too
            _INDEX[key] = torch.arange(sectors, dtype=dtype, device=key[2])
    return _INDEX[key]


def motion_between(previous: np.ndarray, current: np.ndarray, scan: ScanAlignment | None) -> np.ndarray:
    """Rows of (current - previous), scan-aligned when ``scan`` is given (numpy in, float32 numpy out)."""
    cur = np.asarray(current, dtype=np.float32)
    prev = np.asarray(previous, dtype=np.float32)
    if scan is None:
        return cur - prev
    with torch.no_grad():
        return scan.motion(torch.from_numpy(prev), torch.from_numpy(cur)).numpy()


APPROACH_RANGE_FLOOR = 0.02
"""Smallest range the approach rate divides by, in the observation's units (2% of a scan normalised to its reach):
a beam already touching something reads the largest rate, not a division by zero."""


def approach_rate(state: Tensor, motion: Tensor, start: int, stop: int) -> Tensor:
    """Per range channel in [start, stop) of ``state``: how fast it closes relative to its length,
    max(0, -Δrange) / range per step, capped at 1 (contact within a step), from the motion input's Δ.

    This is the inverse of a beam's time to contact. A small network reads ranges and their changes on their own
    scales, where a 4 m/s approach at 7 m and a 4 m/s approach at 40 m differ by nothing in the change; the ratio is
    what tells them apart, and it is a division, which a few SiLU layers learn poorly from rare violations. On
    highway the gate's rows did not improve beyond the spread of refits (docs/calibration.md), so it is an
    option, off by default. Any leading shape, (..., D) -> (..., stop - start)."""
    closing = motion[..., start:stop].neg().clamp_min(0.0)
    return closing.div(state[..., start:stop].clamp_min(APPROACH_RANGE_FLOOR)).clamp_max(1.0)


GRAZING_DEG = 80.0
"""Two neighbouring returns belong to one surface when their ranges differ by no more than a flat wall's seen at up to
this incidence across one sector (ratio 1 + tan(80°) × the sector's width): steeper jumps are an object's edge."""
SHIFT_SECTORS = 4
"""How many sectors the robot's translation over one step may move a return's bearing, besides its turn (a return
0.2 m away seen 0.06 m further on moves by up to 17°, under four 5° sectors)."""
EGO_CHUNK = 1024
"""Rows moved at once (each row tests every ray against a window of surface segments)."""


@dataclass(frozen=True)
class EgoScanStep:
    """The next range scan of a static world after the robot's own motion: the geometric part of the world model's
    step (``WorldModelConfig.ego_*``).

    A small network predicts a lidar scan's change near obstacles poorly: measured on the UGV's calibration drives,
    its one-step range error on the sectors the next scan reads within 0.6 m was 0.157 m on average (worse than
    predicting no change, 0.146 m), so the imagined robot drove through walls the real one turned away from. Most of
    that change is geometry. :meth:`apply` places each sector's return (a range short of the scan's reach) at the
    mean bearing of the sector's rays, joins neighbouring returns of one surface into segments (:data:`GRAZING_DEG`),
    moves them by the arc the action commands over one step (a chord of length v dt sinc(w dt / 2) along the heading
    turned by w dt / 2, then a turn by -w dt into the new heading), and casts the sectors' rays at them from both
    poses. A sector the surface covers from both takes its reading plus the change between the two casts (the
    placement of a return within its sector errs alike in both and cancels); one it newly covers, the cast. The end
    of a surface, or a return on none (an object's edge, a post), lands in the sector its bearing falls in, the nearest
    counting. A sector nothing reaches keeps its range. Moving along a wall then reads the same wall, turning slides
    the scan by the turn, and passing an obstacle its edge slides into the sector behind. On the same drives this step
    alone errs 0.022 m on average on those sectors (median 0.0015 m, 99th percentile 0.10 m; a scratch measurement in
    the issue's notes). The world model predicts the residual over it, so movers, what comes into view and the
    channels after the scan stay learned.
    """

    sectors: int
    """Channels [0, sectors) are ranges in units of the scan's reach (1: nothing within reach)."""
    start: float
    """Bearing where sector 0 begins (rad, relative to the heading; bearings increase to the left)."""
    width: float
    """Each sector's width (rad)."""
    rays: int
    """Rays per sector, at start + (i + q / rays) × width for q < rays; a sector reads the nearest of them."""
    forward_channel: int
    forward_scale: float
    forward_offset: float
    """The distance driven over one step, in range units: ``action[forward_channel] * scale + offset``."""
    turn_channel: int
    turn_scale: float
    """The heading's turn over one step (rad, positive to the left): ``action[turn_channel] * scale``."""

    @classmethod
    def of(cls, cfg: WorldModelConfig, obs_dim: int, act_dim: int) -> EgoScanStep | None:
        """The step a world model config describes (None when ``ego_sectors`` is 0); a ValueError names what does
        not fit an observation of ``obs_dim`` channels and an action of ``act_dim``."""
        sectors = int(cfg.ego_sectors)
        if sectors == 0:
            return None
        if not 2 <= sectors <= obs_dim:
            raise ValueError(f"world_model_config.ego_sectors must be 0 or in [2, {obs_dim}], got {sectors}")
        step = cls(
            sectors,
            float(cfg.ego_scan_start),
            float(cfg.ego_sector_width),
            int(cfg.ego_rays_per_sector),
            int(cfg.ego_forward_channel),
            float(cfg.ego_forward_scale),
            float(cfg.ego_forward_offset),
            int(cfg.ego_turn_channel),
            float(cfg.ego_turn_scale),
        )
        numbers = (step.start, step.width, step.forward_scale, step.forward_offset, step.turn_scale)
        if not all(np.isfinite(numbers)) or not 0 < step.width * sectors <= 2 * np.pi or step.rays < 1:
            raise ValueError(
                "world_model_config.ego_* must be finite, ego_sector_width > 0 (all sectors within a full turn) and "
                f"ego_rays_per_sector >= 1; got start {step.start}, width {step.width}, rays {step.rays}, forward "
                f"{step.forward_scale} x + {step.forward_offset}, turn {step.turn_scale} x"
            )
        for name, channel in (("ego_forward_channel", step.forward_channel), ("ego_turn_channel", step.turn_channel)):
            if not 0 <= channel < act_dim:
                raise ValueError(
                    f"world_model_config.{name} must be an action channel in [0, {act_dim}), got {channel}"
                )
        return step

    def geometry(self) -> Tensor:
        """The step's numbers as one tensor (the world model keeps it as a buffer, so that a checkpoint of a model
        that predicts the residual over another step, or over none, is not read as this one's)."""
        numbers = [self.sectors, self.start, self.width, self.rays, self.forward_channel, self.forward_scale]
        numbers += [self.forward_offset, self.turn_channel, self.turn_scale]
        return torch.tensor(numbers, dtype=torch.float64)

    @property
    def window(self) -> int:
        """Segments tested on each side of a ray's own sector: the largest turn of a step plus the translation's."""
        return int(np.ceil(abs(self.turn_scale) / self.width)) + SHIFT_SECTORS

    def apply(self, state: Tensor, action: Tensor) -> Tensor:
        """The state with its scan moved by the action's motion (any leading shape, (..., D) and (..., A)); the
        channels after the scan are unchanged. Differentiable almost everywhere in the action."""
        if state.numel() == 0:
            return state.clone()
        if state.device.type != "cpu":  # the compiled kernel reads numpy: on a GPU the tensor version, batched
            grad = torch.is_grad_enabled() and (state.requires_grad or action.requires_grad)
            with contextlib.nullcontext() if grad else torch.no_grad():
                return self._apply_tensors(state, action)
        if not (torch.is_grad_enabled() and (state.requires_grad or action.requires_grad)):
            out = torch.empty(state.shape, dtype=state.dtype)
            self.apply_into(state, action, out)
            return out
        return self._apply_chosen(state, action)

    def _apply_chosen(self, state: Tensor, action: Tensor) -> Tensor:
        """:meth:`apply` with gradients on the CPU: the compiled kernel finds which segment and ray gave each reading
        (``core._ego_kernel.scan_with_choices``), and torch recomputes only those, differentiably, from the same
        formulas as :meth:`_scan`. The value and the gradient are the tensor version's (the minimum over candidates
        passes its gradient to the one it chose) at a few operations per sector instead of one per candidate: the
        actor's fear term over the ego step, the bulk of a SAGE-SAC update on the UGV (bench/bench_sac.py --ego)."""
        from core import _ego_kernel as kernel

        s, d = self.sectors, state.shape[-1]
        lead = state.shape[:-1]
        ranges = state[..., :s].reshape(-1, s)
        actions = action.expand(*lead, action.shape[-1]).reshape(-1, action.shape[-1])
        rows = len(ranges)
        choices = np.empty((kernel.CHOICE_FIELDS, rows, s), dtype=np.int64)
        reading = np.empty((rows, d), dtype=np.float64)
        with torch.no_grad():
            kernel.scan_with_choices(
                state.detach().reshape(-1, d).numpy(), actions.detach().numpy(), reading, choices,
                *_kernel_geometry(self),
            )  # fmt: skip
        chosen = torch.from_numpy(choices)
        kind = chosen[0]
        g = _geometry(self, ranges.dtype)
        forward = actions[:, self.forward_channel : self.forward_channel + 1]
        distance = forward * self.forward_scale + self.forward_offset
        turn = actions[:, self.turn_channel : self.turn_channel + 1] * self.turn_scale
        half = 0.5 * turn
        small = half.abs() <= 1e-6
        safe = torch.where(small, torch.ones_like(half), half)
        chord = distance * torch.where(small, torch.ones_like(half), torch.sin(safe) / safe)
        x0, y0 = ranges * g.cos, ranges * g.sin
        x, y = x0 - chord * torch.cos(half), y0 - chord * torch.sin(half)
        c, n = torch.cos(turn), torch.sin(turn)
        x, y = c * x + n * y, c * y - n * x
        ray_cos, ray_sin = g.ray_cos.reshape(-1), g.ray_sin.reshape(-1)  # sector * rays + ray
        after = _chosen_cast(x, y, chosen[1], chosen[2], ray_cos, ray_sin)
        before = _chosen_cast(x0, y0, chosen[3], chosen[4], ray_cos, ray_sin)
        source = chosen[5]
        found = source >= 0
        at = source.clamp_min(0)
        lx, ly = x.gather(1, at), y.gather(1, at)
        landed = torch.hypot(torch.where(found, lx, torch.ones_like(lx)), torch.where(found, ly, torch.zeros_like(ly)))
        seen = ranges + (after - before)
        clamped = torch.from_numpy(reading[:, :s]).to(ranges.dtype)
        scan = torch.where(
            kind == kernel.KIND_SEEN, seen,
            torch.where(kind == kernel.KIND_AFTER, after,
                        torch.where(kind == kernel.KIND_LANDED, landed,
                                    torch.where(kind == kernel.KIND_RANGE, ranges, clamped))),
        )  # fmt: skip
        return torch.cat([scan.reshape(*lead, s), state[..., s:]], dim=-1)

    def _apply_tensors(self, state: Tensor, action: Tensor) -> Tensor:
        s = self.sectors
        lead = state.shape[:-1]
        ranges = state[..., :s].reshape(-1, s)
        actions = action.expand(*lead, action.shape[-1]).reshape(-1, action.shape[-1])
        parts = [
            self._scan(ranges[i : i + EGO_CHUNK], actions[i : i + EGO_CHUNK]) for i in range(0, len(ranges), EGO_CHUNK)
        ]
        scan = parts[0] if len(parts) == 1 else torch.cat(parts)
        return torch.cat([scan.reshape(*lead, s), state[..., s:]], dim=-1)

    def apply_into(self, state: Tensor, action: Tensor, out: Tensor) -> None:
        """:meth:`apply` without a gradient, written into ``out`` (the shape of ``state``, a separate tensor whose
        rows can be viewed as (-1, D)): compiled (``core._ego_kernel``), a tenth of the cost on a gate's few rows."""
        self.bound(state.detach(), action.detach().expand(*state.shape[:-1], action.shape[-1]), out)()

    def contact(self, state: Tensor, action: Tensor, delta: Tensor, floors: Tensor, closing: Tensor | None) -> Tensor:
        """(N, B) bool, without a gradient: whether each member's imagined state ``apply(state, action) + delta[n]`` is
        at or under ``floors`` (F,) in some channel i < F where ``closing`` ((B, F) or (F,) bool; None: every channel)
        allows it, as ``core.sage.fear.with_contact`` reads it, compiled in one call (``core._ego_kernel.contact``)
        and on the CPU. ``state`` (B, D) shared by the members or (N, B, D) one per member, ``action`` likewise;
        ``delta`` (N, B, F) in the state's dtype."""
        from core import _ego_kernel

        d, a = state.shape[-1], action.shape[-1]
        members, rows, width = delta.shape
        if state.shape[:-1] not in ((rows,), (members, rows)):
            raise ValueError(
                f"ego contact: states {tuple(state.shape)} fit neither ({rows}, D) nor ({members}, {rows}, D)"
            )
        states = state.detach().reshape(-1, d)
        actions = action.detach().expand(*state.shape[:-1], a).reshape(-1, a)
        allowed = torch.ones(1, width, dtype=torch.bool) if closing is None else closing.reshape(-1, width)
        touching = torch.empty(members, rows, dtype=torch.bool)
        _ego_kernel.contact(
            states.numpy(), actions.numpy(), delta.detach().numpy(), floors.numpy(), allowed.numpy(),
            touching.numpy(), *_kernel_geometry(self),
        )  # fmt: skip
        return touching

    def bound(self, state: Tensor, action: Tensor, out: Tensor, *, views: bool = False) -> Callable[[], None]:
        """A call that does :meth:`apply_into` for what ``state`` and ``action`` hold when it is made: numpy views of
        the three tensors taken once (``state`` and ``action`` of the same leading shape, viewed or copied as rows;
        a copy is read as it was now), so that a loop over preallocated buffers (the gate kernel's rollout) pays
        only the compiled call. ``views``: a ValueError where the rows could only be copied (a loop whose buffers
        change between calls would read stale rows)."""
        from core import _ego_kernel  # numba's import and compilation are paid by the first call

        d, a = state.shape[-1], action.shape[-1]
        rows = state.reshape(-1, d), action.reshape(-1, a)
        if views and any(r.data_ptr() != t.data_ptr() for r, t in zip(rows, (state, action), strict=True)):
            raise ValueError("the ego step's bound rows must be views of the buffers it reads")
        arrays = (rows[0].numpy(), rows[1].numpy(), out.view(-1, d).numpy())
        geometry = _kernel_geometry(self)
        scan = _ego_kernel.scan
        return lambda: scan(*arrays, *geometry)

    def _scan(self, ranges: Tensor, action: Tensor) -> Tensor:
        """(B, S) ranges and (B, A) actions -> (B, S) ranges seen after the step."""
        s = self.sectors
        geometry = _geometry(self, ranges.dtype, ranges.device)
        distance = action[:, self.forward_channel : self.forward_channel + 1] * self.forward_scale + self.forward_offset
        turn = action[:, self.turn_channel : self.turn_channel + 1] * self.turn_scale
        half = 0.5 * turn
        small = half.abs() <= 1e-6
        safe = torch.where(small, torch.ones_like(half), half)
        chord = distance * torch.where(small, torch.ones_like(half), torch.sin(safe) / safe)  # sin(h) / h
        x0, y0 = ranges * geometry.cos, ranges * geometry.sin
        x, y = x0 - chord * torch.cos(half), y0 - chord * torch.sin(half)
        c, n = torch.cos(turn), torch.sin(turn)
        x, y = c * x + n * y, c * y - n * x
        hit = ranges < 1.0
        # neighbouring returns of one surface (a ratio of ranges a flat wall's incidence allows) form a segment
        near, far = torch.minimum(ranges[:, :-1], ranges[:, 1:]), torch.maximum(ranges[:, :-1], ranges[:, 1:])
        joined = hit[:, :-1] & hit[:, 1:] & (far <= geometry.joint_ratio * near)
        # A sector's reading is the nearest over its rays, its return placed at their mean bearing: cast from where
        # the robot was, the segments give back the readings only roughly. So a sector the surface covers before and
        # after takes the change between the two casts, in which that error cancels; one it newly covers, the cast.
        before = _cast(x0, y0, joined, geometry, geometry.own)
        after = _cast(x, y, joined, geometry, geometry.candidates)
        inf = torch.full((), float("inf"), dtype=ranges.dtype, device=ranges.device)
        both = torch.isfinite(before) & torch.isfinite(after)
        seen = torch.where(both, ranges + (after - torch.where(both, before, inf.new_zeros(()))), after)
        # a return at the end of a surface, or on none (an object's edge, a post), lands in the sector its bearing
        # falls in: passing an obstacle, its edge slides into the sector behind, where the background was read
        inside = torch.zeros_like(hit)
        inside[:, 1:-1] = joined[:, :-1] & joined[:, 1:]
        sector = torch.floor((torch.atan2(y, x) - self.start) / self.width)
        lands = hit & ~inside & (sector >= 0) & (sector < s)
        sector = torch.where(lands, sector, torch.full_like(sector, s)).long()  # the rest go to an extra bin
        landed = torch.full((len(ranges), s + 1), float("inf"), dtype=ranges.dtype, device=ranges.device)
        landed = landed.scatter_reduce(1, sector, torch.where(lands, torch.hypot(x, y), inf), "amin")[:, :s]
        nearest = torch.minimum(seen, landed)
        return torch.where(torch.isinf(nearest), ranges, nearest.clamp(0.0, 1.0))


def _chosen_cast(x: Tensor, y: Tensor, segment: Tensor, ray: Tensor, ray_cos: Tensor, ray_sin: Tensor) -> Tensor:
    """(B, S) where each sector's chosen ray (``ray``: index into the flat ``ray_cos`` / ``ray_sin``) meets its chosen
    segment (index of its first return; -1: none, then a finite stand-in whose gradient is zero), :func:`_cast`'s
    arithmetic on one candidate per sector."""
    found = segment >= 0
    first = segment.clamp_min(0)
    ax, ay = x.gather(1, first), y.gather(1, first)
    ex, ey = x.gather(1, first + 1) - ax, y.gather(1, first + 1) - ay
    which = ray.clamp_min(0)
    ux, uy = ray_cos.take(which), ray_sin.take(which)
    den = ux * ey - uy * ex
    den = torch.where(found, den, torch.ones_like(den))  # a found hit has |den| > 1e-9
    along = (ax * ey - ay * ex) / den
    return torch.where(found, along, torch.zeros_like(along))


def _cast(x: Tensor, y: Tensor, joined: Tensor, geometry: _EgoGeometry, idx: Tensor) -> Tensor:
    """(B, S) the nearest hit over each sector's rays on the segments between joined neighbouring returns at
    (x, y) (inf: none), testing sector i's rays against the segments idx[i] (index of their first return). A ray u
    meets segment A -> A + E at t u = A + e E, e in [0, 1]: t = (A x E) / (u x E), e = (A x u) / (u x E)."""
    ax, ay = x[:, idx].unsqueeze(-1), y[:, idx].unsqueeze(-1)  # (B, S, W, 1)
    ex, ey = x[:, idx + 1].unsqueeze(-1) - ax, y[:, idx + 1].unsqueeze(-1) - ay
    ux, uy = geometry.ray_cos, geometry.ray_sin  # (S, 1, rays)
    den = ux * ey - uy * ex
    flat = den.abs() <= 1e-9
    den = torch.where(flat, torch.ones_like(den), den)
    along = (ax * ey - ay * ex) / den
    across = (ax * uy - ay * ux) / den
    meets = joined[:, idx].unsqueeze(-1) & ~flat & (across >= 0.0) & (across <= 1.0) & (along > 0.0)
    return torch.where(meets, along, torch.full((), float("inf"), dtype=x.dtype, device=x.device)).amin(dim=(2, 3))


@dataclass(frozen=True)
class _EgoGeometry:
    cos: Tensor
    sin: Tensor
    """(S,) the bearing of each sector's return (the mean of its rays')."""
    ray_cos: Tensor
    ray_sin: Tensor
    """(S, 1, rays) each sector's ray directions."""
    candidates: Tensor
    """(S, 2 window) the segments (index of their first return) each sector's rays are tested against after a step."""
    own: Tensor
    """(S, 2) the two segments a sector's rays cross where the robot is (its returns lie on its rays' bearings)."""
    joint_ratio: float


_GEOMETRY: dict[tuple[EgoScanStep, torch.dtype, torch.device], _EgoGeometry] = {}


def _geometry(step: EgoScanStep, dtype: torch.dtype, device: torch.device | None = None) -> _EgoGeometry:
    """The step's fixed bearings and candidate segments (cached per step, dtype and device)."""
    key = (step, dtype, torch.device("cpu") if device is None else device)
    if key not in _GEOMETRY:
        with torch.inference_mode(False):
            s, k, w = step.sectors, step.rays, step.window
            sector = torch.arange(s, dtype=torch.float64)
            point = step.start + (sector + (k - 1) / (2 * k)) * step.width
            ray = step.start + (sector[:, None] + torch.arange(k, dtype=torch.float64) / k) * step.width
            offsets = torch.arange(-w, w)
            candidates = (torch.arange(s)[:, None] + offsets).clamp(0, s - 2)
            own = (torch.arange(s)[:, None] + torch.arange(-1, 1)).clamp(0, s - 2)
            to = key[2]
            _GEOMETRY[key] = _EgoGeometry(
                point.cos().to(to, dtype),
                point.sin().to(to, dtype),
                ray.cos().to(to, dtype)[:, None, :],
                ray.sin().to(to, dtype)[:, None, :],
                candidates.to(to),
                own.to(to),
                1.0 + float(np.tan(np.radians(GRAZING_DEG))) * step.width,
            )
    return _GEOMETRY[key]


_KERNEL_GEOMETRY: dict[EgoScanStep, tuple[np.ndarray, ...]] = {}
OWN_MARGIN = 1e-3
"""How far outside a segment's ends (in sectors' widths) a ray is still cast at it where the robot was."""


def _own_crossings(step: EgoScanStep, own: Tensor) -> Tensor:
    """(S, 2 rays) int64: 1 where ray q of sector i can meet its own segment t (``own[i, t]``) where the robot was,
    column t * rays + q. Before the step the returns lie at their sectors' fixed bearings, so whether a ray lies within
    a segment's ends is known from the layout alone (a ray outside them misses it: ``core._ego_kernel.RAY_MARGIN``);
    the kernel then skips the casts that cannot hit, about half. Every ray where sectors are a quarter turn wide."""
    k = step.rays
    ray = torch.arange(k, dtype=torch.float64) / k - (k - 1) / (2 * k)  # from the sector's return, in widths
    offset = torch.arange(step.sectors, dtype=torch.float64)[:, None] - own.to(torch.float64)  # (S, 2)
    position = offset[:, :, None] + ray  # (S, 2, rays): the ray's bearing from the segment's first return, in widths
    crosses = (position >= -OWN_MARGIN) & (position <= 1.0 + OWN_MARGIN)
    if step.width >= np.pi / 2:
        crosses = torch.ones_like(crosses)
    return crosses.reshape(step.sectors, 2 * k).to(torch.int64)


def _kernel_geometry(step: EgoScanStep) -> tuple[np.ndarray, ...]:
    """:func:`_geometry` in float64 packed as ``core._ego_kernel.scan`` reads it (cached per step)."""
    if step not in _KERNEL_GEOMETRY:
        g = _geometry(step, torch.float64)
        directions = torch.cat([g.cos[:, None], g.sin[:, None], g.ray_cos[:, 0], g.ray_sin[:, 0]], dim=1)
        segments = torch.cat([g.candidates, g.own, _own_crossings(step, g.own)], dim=1)
        numbers = [step.start, step.width, step.forward_scale, step.forward_offset, step.turn_scale, g.joint_ratio]
        _KERNEL_GEOMETRY[step] = (
            np.ascontiguousarray(directions.numpy()),
            np.ascontiguousarray(segments.numpy()),
            np.array(numbers, dtype=np.float64),
            np.array([step.forward_channel, step.turn_channel], dtype=np.int64),
        )
    return _KERNEL_GEOMETRY[step]
