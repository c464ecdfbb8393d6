"""A Cartesian mover model for the gate's imagined contact (``GateConfig.mover_model = "cartesian"``).

The per-sector closing rate (``gate.contact_extrapolation``) reads a mover only while it closes along one sector's
ray. A vehicle crossing in front of the robot moves *across* sectors: no sector shows a steady closing, and the gate
stayed quiet until too late (docs/notes/generalisation.md). Here the movers are tracked as points in the plane:

1. **Points.** Each sector's return (range < 1) is a point at the sector's bearing (the mean of its rays', as
   :class:`core.motion.EgoScanStep` places it), in the robot's frame, in range units.
2. **Objects, not points.** Neighbouring returns of one surface are joined into segments by the ego step's own rule
   (a ratio of ranges a flat wall at up to :data:`core.motion.GRAZING_DEG` allows). A sector's return on a body that
   slides sideways stays in that sector at nearly the same range (the aperture problem), so a point's nearest
   neighbour in the previous scan reads no lateral motion; the segment's centroid moves with the body. Each segment
   of the newest scan is associated with the nearest segment centroid of the scan before, moved into the newest frame
   by the robot's executed action (the ego step's arc), within ``mover_max_speed`` (a mover's largest displacement in
   a step) plus one sector's spacing at its range (the centroid's quantisation: a segment gains or loses a sector).
3. **What may move.** A segment longer than ``mover_max_size`` (walls, long clutter) is structure; one touching the
   first or last sector is cut by the field of view, its centroid not the body's; one whose extent changed by more
   than one and a half sectors' spacing between two scans (a moving segment gains or loses at most a sector an end)
   is partly occluded or merged with another: none of these gets a velocity. Nor does a segment the ego step
   explains: none of its sectors or their two neighbours changed by more than ``mover_min_speed`` beyond the ego
   step's prediction from the scan before (``core.sage.fear.unexplained_change``).
4. **Over a track** (``mover_history`` = L steps; two at least, as ``closing_rate`` asks): the segment must be
   associated back through every one of the last L + 1 scans. Its velocity is the least-squares slope of its
   centroids over the track, in the newest frame. A centroid jumps by up to about a sector's spacing as its segment
   gains or loses a sector (a static post passed at 1.5 m: 0.2-0.3 m/s read over two steps); that error is bounded
   while a mover's displacement grows with the track, so a speed under ``mover_min_speed`` or under a spacing over L
   reads static, and a track any of whose steps departs from the slope by more than half its speed (or a spacing) is
   not steady: an edge, an occlusion's jump. A return that newly appears (an occlusion ending, an edge entering the
   field of view) has no track: no velocity.

Every sector of a moving segment carries its velocity: (B, S, 2) per state, range units per step in the newest
robot frame, zero where static (what the live gate, the calibration sample and ``sage gate refit-bounds`` store, like
``closing_rate``). :func:`mover_contact` then moves each moving point at constant velocity, p + k v at imagined step
k, into each member's imagined pose at step k (the member's own actions integrated over the same arc), and counts
contact where the point falls at or under the floor of the sector its bearing falls in: the floors are the robot's
footprint along each sector's rays (what a reading at or under them means: something touching the body), so the
test is the one a real scan from that pose would fail. Points outside the field of view count no contact, as a
scan would show none.
"""

from __future__ import annotations

import copy
import math

import numpy as np
import torch
from torch import Tensor

from core.motion import EgoScanStep, _geometry

_LAYOUT: dict[EgoScanStep, tuple[np.ndarray, np.ndarray, float]] = {}
_SEGMENTS: dict[tuple[EgoScanStep, bytes], _Segments] = {}
"""The last scans' segments in their own frames, by step and scan (its float64 bytes): the gate's track reads each
scan in L + 1 consecutive steps, and a scan's segments depend on nothing else."""
_SEGMENTS_KEPT = 32


def _layout(step: EgoScanStep) -> tuple[np.ndarray, np.ndarray, float]:
    """(S,) cos and sin of each sector's return bearing (the mean of its rays', as the ego step places it) and the
    ego step's joint ratio (cached per step)."""
    if step not in _LAYOUT:
        g = _geometry(step, torch.float64)
        _LAYOUT[step] = (g.cos.numpy().copy(), g.sin.numpy().copy(), float(g.joint_ratio))
    return _LAYOUT[step]


class _Segments:
    """The runs of neighbouring returns of one surface in a scan (the ego step's joint rule), as arrays: first and
    last sector, centroid (in the scan's frame, until moved), extent (first to last return), a sector's spacing at
    the centroid's range, and whether the field of view cuts it (it touches the first or last sector)."""

    def __init__(self, step: EgoScanStep, ranges: np.ndarray) -> None:
        cos, sin, ratio = _layout(step)
        s = step.sectors
        r = np.asarray(ranges, np.float64)[:s]
        hit = r < 1.0
        near, far = np.minimum(r[:-1], r[1:]), np.maximum(r[:-1], r[1:])
        joined = hit[:-1] & hit[1:] & (far <= ratio * near)
        starts = hit.copy()
        starts[1:] &= ~joined
        ends = hit.copy()
        ends[:-1] &= ~joined
        self.first, self.last = np.flatnonzero(starts), np.flatnonzero(ends)
        points = np.stack([np.where(hit, r * cos, 0.0), np.where(hit, r * sin, 0.0)], axis=-1)
        total = np.concatenate([np.zeros((1, 2)), np.cumsum(points, axis=0)])
        count = (self.last - self.first + 1)[:, None]
        self.centroid = (total[self.last + 1] - total[self.first]) / np.maximum(count, 1)
        self.extent = np.hypot(*(points[self.last] - points[self.first]).T)
        self.spacing = np.hypot(*self.centroid.T) * step.width
        self.cut = (self.first == 0) | (self.last == s - 1)

    def __len__(self) -> int:
        return len(self.first)

    def moved(self, pose: tuple[float, float, float]) -> _Segments:
        """A copy whose centroids are moved into the frame after a step (``pose`` from :func:`arc`); the rest shared."""
        x, y, turn = pose
        c, s = math.cos(turn), math.sin(turn)
        dx, dy = self.centroid[:, 0] - x, self.centroid[:, 1] - y
        out = copy.copy(self)
        out.centroid = np.stack([c * dx + s * dy, c * dy - s * dx], axis=-1)
        return out


def _segments(step: EgoScanStep, ranges: np.ndarray) -> _Segments:
    """``_Segments(step, ranges)`` for a float64 scan, kept for the next steps' tracks (never modified: ``moved``
    copies)."""
    key = (step, ranges[: step.sectors].tobytes())
    found = _SEGMENTS.get(key)
    if found is None:
        found = _SEGMENTS[key] = _Segments(step, ranges)
        while len(_SEGMENTS) > _SEGMENTS_KEPT:
            _SEGMENTS.pop(next(iter(_SEGMENTS)), None)  # the oldest first (insertion order)
    return found


def arc(step: EgoScanStep, action: np.ndarray) -> tuple[float, float, float]:
    """(x, y, turn) of the robot's pose after one step of ``action``, in the frame before it (the ego step's arc: a
    chord of length v dt sinc(w dt / 2) along the heading turned by w dt / 2, then the turn)."""
    distance = float(action[step.forward_channel]) * step.forward_scale + step.forward_offset
    turn = float(action[step.turn_channel]) * step.turn_scale
    half = 0.5 * turn
    chord = distance * (math.sin(half) / half if abs(half) > 1e-6 else 1.0)
    return chord * math.cos(half), chord * math.sin(half), turn


def _compose(first: tuple[float, float, float], second: tuple[float, float, float]) -> tuple[float, float, float]:
    """The pose after ``first`` then ``second`` (each in the frame before it), in the frame before ``first``."""
    x, y, turn = first
    c, s = math.cos(turn), math.sin(turn)
    return x + c * second[0] - s * second[1], y + s * second[0] + c * second[1], turn + second[2]


def _match(at: np.ndarray, extent: float, spacing: float, before: _Segments, reach: float) -> int:
    """Index of the segment of the scan before (its centroids in the same frame as ``at``) nearest the centroid ``at``
    within ``reach`` plus a sector's spacing, with an extent that agrees within one and a half spacings and not cut by
    the field of view; -1: none."""
    if not len(before):
        return -1
    distance = np.hypot(*(before.centroid - at).T)
    best = int(np.argmin(distance))
    allowance = max(spacing, float(before.spacing[best]))
    # a segment gains or loses a sector at either end as it moves: its extent by up to a spacing, not two
    if distance[best] > reach + allowance or abs(float(before.extent[best]) - extent) > 1.5 * allowance:
        return -1
    return -1 if bool(before.cut[best]) else best


def mover_velocities(
    step: EgoScanStep,
    scans: np.ndarray,
    actions: np.ndarray,
    max_speed: float,
    max_size: float,
    min_speed: float,
) -> np.ndarray:
    """(S, 2) each sector's velocity (range units per step, in the newest scan's frame; zero where static or unknown)
    from L + 1 consecutive scans ``scans`` (L + 1, >= S) oldest first and the L executed actions between them
    ``actions`` (L, A), L >= 2. See the module docstring for the rules."""
    s = step.sectors
    out = np.zeros((s, 2), np.float64)
    scans = np.asarray(scans, np.float64)
    history = len(scans) - 1
    if history < 2 or len(actions) != history:
        raise ValueError(f"mover velocities need L + 1 >= 3 scans and L actions, got {len(scans)} and {len(actions)}")
    newest = _segments(step, scans[-1])
    candidates = np.flatnonzero(~newest.cut & (newest.extent <= max_size))
    if not len(candidates):
        return out
    # the ego step's prediction of each newest sector from the one before: what it leaves unexplained may move
    with torch.no_grad():
        moved = step.apply(torch.from_numpy(scans[-2:-1, :s]).float(), torch.from_numpy(actions[-1:]).float())
    unexplained = np.abs(scans[-1, :s] - moved[0].double().numpy()) > min_speed
    changed = unexplained | np.concatenate([[False], unexplained[:-1]]) | np.concatenate([unexplained[1:], [False]])
    counts = np.concatenate([[0], np.cumsum(changed)])
    candidates = candidates[counts[newest.last[candidates] + 1] - counts[newest.first[candidates]] > 0]
    if not len(candidates):
        return out  # the ego step explains every one: static, whatever their centroids' quantisation says
    # every older scan's segments, their centroids moved into the newest frame by the executed actions (distances
    # between two scans' centroids are the same in any frame: the association is made there)
    older: list[_Segments] = []
    pose = (0.0, 0.0, 0.0)
    for j in range(history - 1, -1, -1):
        pose = _compose(arc(step, actions[j]), pose)  # scan j's frame -> the newest
        older.append(_segments(step, scans[j]).moved(pose))  # newest first
    times = np.arange(-history, 1, dtype=np.float64)
    centred = times - times.mean()
    for index in candidates:
        here = newest.centroid[index]
        extent, spacing = float(newest.extent[index]), float(newest.spacing[index])
        chain = [here]
        for segments in older:
            found = _match(here, extent, spacing, segments, max_speed)
            if found < 0:
                break
            here = segments.centroid[found]
            extent, spacing = float(segments.extent[found]), float(segments.spacing[found])
            chain.append(here)
        if len(chain) < history + 1:
            continue  # not seen in every scan: newly appeared, occluded, merged
        track = np.array(chain[::-1])  # oldest first, in the newest frame
        # the least-squares velocity over the whole track: a centroid's quantisation (a segment gains or loses a
        # sector) is bounded, a mover's displacement grows with the track
        velocity = (centred[:, None] * (track - track.mean(0))).sum(0) / np.square(centred).sum()
        speed = float(np.hypot(*velocity))
        spacing = float(newest.spacing[index])
        if speed < max(min_speed, spacing / history):
            continue
        steps = np.diff(track, axis=0)
        if float(np.hypot(*(steps - velocity).T).max()) > max(0.5 * speed, spacing, min_speed):
            continue  # not steady over the track (beyond a sector's quantisation): an edge, a jump
        out[newest.first[index] : newest.last[index] + 1] = velocity
    return out


def mover_contact(step: EgoScanStep, obs: Tensor, velocity: Tensor, actions: Tensor, floors: Tensor) -> Tensor:
    """(m, N, B) bool: whether some moving point of each state, moved at constant velocity to p + k v, falls at or
    under the floor of its sector as seen from each member's imagined pose after k steps (k = 1..m). ``obs`` (B, D)
    the real states (their scans place the points), ``velocity`` (B, S, 2) from :func:`mover_velocities`, ``actions``
    (m, N, B, A) each member's imagined actions (the first the real first action), ``floors`` (F,) the contact floors
    of sectors [0, F). No gradient."""
    with torch.no_grad():
        s = step.sectors
        g = _geometry(step, obs.dtype, obs.device)
        ranges = obs[:, :s]
        moving = (velocity.abs().sum(-1) > 0) & (ranges < 1.0)  # (B, S)
        m, n, b = actions.shape[0], actions.shape[1], actions.shape[2]
        if not bool(moving.any()):
            return torch.zeros(m, n, b, dtype=torch.bool, device=obs.device)
        px, py = ranges * g.cos, ranges * g.sin  # (B, S)
        vx, vy = velocity[..., 0].to(obs.dtype), velocity[..., 1].to(obs.dtype)
        # every member's imagined pose after each step, in the real state's frame: the arcs summed (all steps at once)
        distance = actions[..., step.forward_channel].to(obs.dtype) * step.forward_scale + step.forward_offset
        turn = actions[..., step.turn_channel].to(obs.dtype) * step.turn_scale  # (m, N, B)
        half = 0.5 * turn
        small = half.abs() <= 1e-6
        sinc = torch.sin(half) / torch.where(small, torch.ones_like(half), half)
        chord = distance * torch.where(small, torch.ones_like(half), sinc)
        heading = torch.cumsum(turn, 0)
        along = heading - half  # the heading before each step, turned by half its turn
        x = torch.cumsum(chord * torch.cos(along), 0).unsqueeze(-1)  # (m, N, B, 1)
        y = torch.cumsum(chord * torch.sin(along), 0).unsqueeze(-1)
        ahead = torch.arange(1, m + 1, dtype=obs.dtype, device=obs.device).view(m, 1, 1, 1)
        dx, dy = px + ahead * vx - x, py + ahead * vy - y  # (m, N, B, S): the points moved k steps, from pose k
        c, sn = torch.cos(heading).unsqueeze(-1), torch.sin(heading).unsqueeze(-1)
        lx, ly = c * dx + sn * dy, c * dy - sn * dx
        floor = floors.to(obs.device, obs.dtype)
        width = floor.shape[0]
        sector = torch.floor((torch.atan2(ly, lx) - step.start) / step.width)
        inside = (sector >= 0) & (sector < width)
        limit = floor[sector.clamp(0, width - 1).long()]
        touching = inside & (torch.hypot(lx, ly) <= limit) & moving
        return touching.any(-1)
