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

import math

import numpy as np
import torch
from torch import Tensor

from core.motion import EgoScanStep, _geometry


def _points(step: EgoScanStep, ranges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(S, 2) each sector's return at the mean bearing of its rays, and (S,) bool whether it is a return."""
    g = _geometry(step, torch.float64)
    cos, sin = g.cos.numpy(), g.sin.numpy()
    r = np.asarray(ranges, np.float64)[: step.sectors]
    return np.stack([r * cos, r * sin], axis=-1), r < 1.0


def _segments(step: EgoScanStep, ranges: np.ndarray) -> list[tuple[int, int]]:
    """[first, last] sector of each run of neighbouring returns of one surface (the ego step's joint rule)."""
    g = _geometry(step, torch.float64)
    r = np.asarray(ranges, np.float64)[: step.sectors]
    hit = r < 1.0
    out: list[tuple[int, int]] = []
    i = 0
    while i < step.sectors:
        if not hit[i]:
            i += 1
            continue
        j = i
        while j + 1 < step.sectors and hit[j + 1] and max(r[j], r[j + 1]) <= g.joint_ratio * min(r[j], r[j + 1]):
            j += 1
        out.append((i, j))
        i = j + 1
    return out


def arc(step: EgoScanStep, action: np.ndarray) -> tuple[float, float, float]:
    """(x, y, turn) of the robot's pose after one step of ``action``, in the frame before it (the ego step's arc: a
    chord of length v dt sinc(w dt / 2) along the heading turned by w dt / 2, then the turn)."""
    distance = float(action[step.forward_channel]) * step.forward_scale + step.forward_offset
    turn = float(action[step.turn_channel]) * step.turn_scale
    half = 0.5 * turn
    chord = distance * (math.sin(half) / half if abs(half) > 1e-6 else 1.0)
    return chord * math.cos(half), chord * math.sin(half), turn


def _into_next_frame(points: np.ndarray, pose: tuple[float, float, float]) -> np.ndarray:
    """(..., 2) points of the frame before a step, in the frame after it (``pose`` from :func:`arc`)."""
    x, y, turn = pose
    c, s = math.cos(turn), math.sin(turn)
    dx, dy = points[..., 0] - x, points[..., 1] - y
    return np.stack([c * dx + s * dy, c * dy - s * dx], axis=-1)


class _Segment:
    __slots__ = ("centroid", "cut", "extent", "first", "last", "spacing")

    def __init__(self, first: int, last: int, points: np.ndarray, width: float, sectors: int) -> None:
        self.first, self.last = first, last
        run = points[first : last + 1]
        self.centroid = run.mean(0)
        self.extent = float(np.hypot(*(run[-1] - run[0])))
        # a sector's spacing at the segment's range: the centroid's and the extent's quantisation
        self.spacing = float(np.hypot(*self.centroid)) * width
        self.cut = first == 0 or last == sectors - 1


def _scan_segments(step: EgoScanStep, ranges: np.ndarray) -> list[_Segment]:
    points, _ = _points(step, ranges)
    return [_Segment(i, j, points, step.width, step.sectors) for i, j in _segments(step, ranges)]


def _match(segment: _Segment, at: np.ndarray, before: list[_Segment], centroids: np.ndarray, reach: float) -> int:
    """Index of the segment of the scan before (``centroids``: theirs in the newest frame) nearest ``segment``'s
    centroid (``at``, in that frame) within ``reach`` plus a sector's spacing, with an extent that agrees within one
    and a half spacings and not cut by the field of view; -1: none."""
    if not before:
        return -1
    distance = np.hypot(*(centroids - at).T)
    best = int(np.argmin(distance))
    other = before[best]
    allowance = max(segment.spacing, other.spacing)
    # a segment gains or loses a sector at either end as it moves: its extent by up to a spacing, not two
    if distance[best] > reach + allowance or abs(other.extent - segment.extent) > 1.5 * allowance or other.cut:
        return -1
    return best


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
    newest = _scan_segments(step, scans[-1])
    candidates = [g for g in newest if not g.cut and g.extent <= max_size]
    if not candidates:
        return out
    # the ego step's prediction of each newest sector from the one before: what it leaves unexplained may move
    with torch.no_grad():
        moved = step.apply(torch.from_numpy(scans[-2:-1, :s]).float(), torch.from_numpy(actions[-1:]).float())
    unexplained = np.abs(scans[-1, :s] - moved[0].double().numpy())
    # every older scan's segments, their centroids moved into the newest frame by the executed actions (distances
    # between two scans' centroids are the same in any frame: the association is made here)
    older: list[tuple[list[_Segment], np.ndarray]] = []
    for j in range(history):
        segments = _scan_segments(step, scans[j])
        centroids = np.array([g.centroid for g in segments]).reshape(-1, 2)
        for action in actions[j:]:
            centroids = _into_next_frame(centroids, arc(step, action))
        older.append((segments, centroids))
    times = np.arange(-history, 1, dtype=np.float64)
    for segment in candidates:
        lo, hi = max(segment.first - 1, 0), min(segment.last + 1, s - 1)
        if float(unexplained[lo : hi + 1].max()) <= min_speed:
            continue  # the ego step explains it: static, whatever its centroid's quantisation says
        chain = [segment.centroid]
        current, here = segment, segment.centroid
        for segments, centroids in reversed(older):
            found = _match(current, here, segments, centroids, max_speed)
            if found < 0:
                break
            current, here = segments[found], centroids[found]
            chain.append(here)
        if len(chain) < history + 1:
            continue  # not seen in every scan: newly appeared, occluded, merged
        track = np.array(chain[::-1])  # oldest first, in the newest frame
        # the least-squares velocity over the whole track: a centroid's quantisation (a segment gains or loses a
        # sector) is bounded, a mover's displacement grows with the track
        velocity = ((times - times.mean())[:, None] * (track - track.mean(0))).sum(0) / np.square(
            times - times.mean()
        ).sum()
        speed = float(np.hypot(*velocity))
        if speed < max(min_speed, segment.spacing / history):
            continue
        steps = np.diff(track, axis=0)
        if float(np.hypot(*(steps - velocity).T).max()) > max(0.5 * speed, segment.spacing, min_speed):
            continue  # not steady over the track (beyond a sector's quantisation): an edge, a jump
        out[segment.first : segment.last + 1] = velocity
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
