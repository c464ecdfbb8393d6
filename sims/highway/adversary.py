"""CAT-style adversarial resampling of opponent behaviour (Zhang et al., 2023), on logged highway traffic.

For a base scenario and the current ego policy:

1. **Predict the ego's path.** By default the log's reference ego (an IDM/MOBIL driver that drove
   through this very traffic when the log was recorded: an IDM prediction). With an ``ego_predictor``
   (any ``core.loop.Policy`` or ``obs -> action`` callable) the env rolls that policy through the
   log-replay version of the scenario and uses its path instead, as CAT rolls the current policy.
2. **Generate candidate opponent trajectories** from logged agents near that path, by perturbing
   their logged behaviour from an event time on: lane-change timing and duration towards the ego's
   lane (cut-ins), acceleration before the manoeuvre, and braking after it (hard brakes), or a brake
   alone for a vehicle already ahead in the ego's lane.
3. **Keep plausible, survivable ones**: the opponent stays on the road, starts its cut-in ahead of the
   ego, does not drive through other logged vehicles, and an ego that reacts within
   ``reaction_time`` by braking at ``avoid_brake`` (less than the ego's limit) can still keep
   ``min_clearance``. CAT draws from a learned motion prior; these filters play that part.
4. **Reweight towards risk**: each candidate's risk against the (non-reacting) predicted ego path
   is 1 for a collision, otherwise exp(-min TTC / 2 s) scaled by 0.8. Candidates are drawn with
   p ∝ prior · exp(beta · risk), the prior favouring milder manoeuvres (CAT's likelihood term).

The drawn trajectory replaces the opponent's logged one from the event time on. Repeated for
``opponents`` opponents, events at least ``event_spacing`` apart.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from sims.highway.config import HighwayConfig
from sims.highway.road import RoadLayout
from sims.highway.traffic import Paths

CUT_IN_DURATIONS = (1.5, 2.5, 3.5)
"""Lateral manoeuvre durations [s]."""
PRE_ACCELS = (-1.0, 0.0, 1.0)
"""Acceleration while cutting in [m/s²]."""
BRAKES = (0.0, 2.0, 4.0, 6.0)
"""Braking after the cut-in [m/s²] (0: keep speed)."""
BRAKE_ONLY = (3.0, 5.0, 6.0)
"""Braking of a leader already in the ego's lane [m/s²]."""
BRAKE_TIMES = (1.0, 2.5)
"""How long the braking lasts [s]; then the opponent holds its speed for a while and recovers."""
EVENT_STRIDE = 3
"""Candidate event times every this many log frames (0.6 s)."""
WINDOW = 8.0
"""Candidates are scored over this long after their event [s]."""
LOOK_AHEAD = 45.0
"""Opponents considered when within this distance ahead of the predicted ego at the event [m]."""


@dataclass(frozen=True)
class Event:
    vehicle: int
    frame: int
    """Log frame where the resampled manoeuvre starts."""
    kind: str
    """``cut_in`` or ``brake``."""
    duration: float
    pre_accel: float
    brake: float
    brake_time: float
    risk: float
    collides_with_prediction: bool
    candidates: int
    """How many candidates passed the plausibility and survivability filters (before the draw)."""


def _smoothstep(u: np.ndarray) -> np.ndarray:
    u = np.clip(u, 0.0, 1.0)
    return u * u * u * (10.0 + u * (-15.0 + 6.0 * u))


def _speed_profile(
    v0: np.ndarray, pre: np.ndarray, t_lat: np.ndarray, brake: np.ndarray, t_brake: np.ndarray, times: np.ndarray
) -> np.ndarray:
    """(C, K) speeds: accelerate by ``pre`` during the manoeuvre, brake, hold 1.5 s, recover at 1.5 m/s²."""
    t = times[None, :]
    v_lat_end = np.maximum(v0 + pre * t_lat, 0.0)[:, None]
    during = np.maximum(v0[:, None] + pre[:, None] * np.minimum(t, t_lat[:, None]), 0.0)
    tb = np.clip(t - t_lat[:, None], 0.0, t_brake[:, None])
    v_braked = np.maximum(v_lat_end - brake[:, None] * tb, 0.0)
    v_low = np.maximum(v_lat_end - brake[:, None] * t_brake[:, None], 0.0)
    t_rec = np.maximum(t - t_lat[:, None] - t_brake[:, None] - 1.5, 0.0)
    recovered = np.minimum(v_low + 1.5 * t_rec, v_lat_end)
    v = np.where(t <= t_lat[:, None], during, np.where(t <= (t_lat + t_brake)[:, None] + 1.5, v_braked, recovered))
    return v


def _candidates_for(
    paths: Paths, plan: np.ndarray, layout: RoadLayout, cfg: HighwayConfig, f0: int, i: int
) -> list[tuple[str, float, float, float, float, float]]:
    """Manoeuvre parameters (kind, y_target, duration, pre_accel, brake, brake_time) for vehicle i at f0."""
    ex, ey = plan[f0, 0], plan[f0, 1]
    x, y = paths.x[f0, i], paths.y[f0, i]
    dx = x - ex
    if not (-2.0 <= dx <= LOOK_AHEAD):
        return []
    if not layout.right_edge_y <= y <= layout.left_edge_y:
        return []  # on the ramp: not on the main road yet
    lane = int(layout.lane_of(y))
    if abs(y - float(layout.lane_y(lane))) > 0.8 or abs(paths.heading[f0, i]) > 0.08:
        return []  # already changing lanes in the log
    out: list[tuple[str, float, float, float, float, float]] = []
    ego_lane_now = int(layout.lane_of(ey))
    if lane == ego_lane_now and dx > 6.0:
        for b, tb in itertools.product(BRAKE_ONLY, BRAKE_TIMES):
            out.append(("brake", float(layout.lane_y(lane)), 0.0, 0.0, b, tb))
    for d in CUT_IN_DURATIONS:
        f_end = min(f0 + round(d / paths.dt), paths.frames - 1)
        target = int(layout.lane_of(plan[f_end, 1]))
        if abs(target - lane) != 1:
            continue
        for pre, b, tb in itertools.product(PRE_ACCELS, BRAKES, BRAKE_TIMES):
            if b == 0.0 and tb != BRAKE_TIMES[0]:
                continue
            out.append(("cut_in", float(layout.lane_y(target)), d, pre, b, tb))
    return out


def resample(
    paths: Paths,
    plan: np.ndarray,
    layout: RoadLayout,
    cfg: HighwayConfig,
    rng: np.random.Generator,
) -> tuple[Paths, list[Event]]:
    """Adversarial variant of ``paths`` against the predicted ego ``plan`` ((F, 4): x, y, heading, speed)."""
    out = paths.copy()
    events: list[Event] = []
    for _ in range(cfg.adversary.opponents):
        event = _resample_one(out, plan, layout, cfg, rng, events)
        if event is None:
            break
        events.append(event)
    return out, events


def _resample_one(
    paths: Paths, plan: np.ndarray, layout: RoadLayout, cfg: HighwayConfig, rng: np.random.Generator, done: list[Event]
) -> Event | None:
    acfg = cfg.adversary
    dt, frames = paths.dt, paths.frames
    first = round(acfg.first_event / dt)
    last = frames - round(4.0 / dt)  # leave time for the manoeuvre to matter
    used = {e.vehicle for e in done}
    spacing = round(acfg.event_spacing / dt)
    rows: list[tuple[int, int, tuple[str, float, float, float, float, float]]] = []
    for f0 in range(first, max(first, last), EVENT_STRIDE):
        if any(abs(f0 - e.frame) < spacing for e in done):
            continue
        for i in range(paths.count):
            if i in used:
                continue
            rows.extend((i, f0, c) for c in _candidates_for(paths, plan, layout, cfg, f0, i))
    if not rows:
        return None
    veh = np.array([r[0] for r in rows])
    f0s = np.array([r[1] for r in rows])
    params = np.array([r[2][1:] for r in rows], dtype=np.float64)  # y_target, duration, pre, brake, brake_time
    kind = np.array([r[2][0] == "cut_in" for r in rows])

    # score every candidate over a window after its event
    window = round(WINDOW / dt)
    local = np.arange(window)
    idx = f0s[:, None] + local[None, :]  # (C, W) log frames
    valid = idx < frames
    idx = np.minimum(idx, frames - 1)
    x, y, v = _trajectories(paths, veh, f0s, params, kind, local * dt)
    length = paths.length[veh][:, None]
    width = paths.width[veh][:, None]
    el, ew = cfg.ego.length, cfg.ego.width
    ex, ey, ev = plan[idx, 0], plan[idx, 1], plan[idx, 3]
    lat_overlap = (np.abs(y - ey) < (width + ew) / 2) & valid
    gap = x - ex - (length + el) / 2  # positive: the opponent is ahead of the predicted ego
    collide = lat_overlap & (np.abs(x - ex) < (length + el) / 2)
    closing = ev - v
    with np.errstate(divide="ignore", invalid="ignore"):
        ttc = np.where(lat_overlap & (gap > 0) & (closing > 0.1), gap / closing, np.inf)
    collides = collide.any(axis=1)
    risk = np.where(collides, 1.0, 0.8 * np.exp(-ttc.min(axis=1) / 2.0))

    # survivable: at the first lateral overlap the opponent is ahead, and braking from there keeps a gap
    has_onset = lat_overlap.any(axis=1)
    onset = np.argmax(lat_overlap, axis=1)
    rows_idx = np.arange(len(rows))
    g_on = np.where(has_onset, gap[rows_idx, onset], -np.inf)
    ok = has_onset & (g_on >= acfg.min_clearance)
    react = onset + round(acfg.reaction_time / dt)
    v_react = ev[rows_idx, np.minimum(react, window - 1)]
    since = (local[None, :] - react[:, None]) * dt
    v_brake = np.maximum(v_react[:, None] - acfg.avoid_brake * np.maximum(since, 0.0), v)
    v_ego = np.where(since > 0, np.minimum(ev, v_brake), ev)
    from_onset = local[None, :] >= onset[:, None]
    gap_avoid = g_on[:, None] - np.cumsum(np.where(from_onset, v_ego - v, 0.0) * dt, axis=1)
    ok &= np.where(from_onset & valid, gap_avoid, np.inf).min(axis=1) >= acfg.min_clearance
    # on the road, and not through other logged vehicles
    ok &= (params[:, 0] <= layout.left_edge_y) & (params[:, 0] >= layout.right_edge_y)
    if not ok.any():
        return None
    _, dur, pre, brake, t_brake = params.T
    prior = -brake / 3.0 - np.abs(pre) - 1.0 / np.maximum(dur, 1.0) - 0.3 * (~kind)
    logits = np.where(ok, prior + acfg.risk_weight * risk, -np.inf)
    p = np.exp(logits - logits.max())
    # draw, and reject candidates that drive through other logged vehicles (checking all is costly)
    while True:
        total = p.sum()
        if total <= 0:
            return None
        c = int(rng.choice(len(rows), p=p / total))
        if not _hits_others(paths, veh[c : c + 1], x[c : c + 1], y[c : c + 1], idx[c : c + 1])[0]:
            break
        p[c] = 0.0
        ok[c] = False
    i, f0 = int(veh[c]), int(f0s[c])
    # the chosen manoeuvre over the rest of the log
    fx, fy, fv = (
        a[0]
        for a in _trajectories(
            paths, veh[c : c + 1], f0s[c : c + 1], params[c : c + 1], kind[c : c + 1], np.arange(frames - f0) * dt
        )
    )
    heading = np.arctan2(np.gradient(fy), np.maximum(np.gradient(fx), 1e-3)) if fx.size > 1 else np.zeros(1)
    paths.x[f0:, i] = fx
    paths.y[f0:, i] = fy
    paths.speed[f0:, i] = fv
    paths.heading[f0:, i] = np.where(fv > 0.5, heading, paths.heading[f0, i])
    paths.adversarial[i] = True
    return Event(
        vehicle=i,
        frame=f0,
        kind="cut_in" if kind[c] else "brake",
        duration=float(dur[c]),
        pre_accel=float(pre[c]),
        brake=float(brake[c]),
        brake_time=float(t_brake[c]),
        risk=float(risk[c]),
        collides_with_prediction=bool(collides[c]),
        candidates=int(ok.sum()),
    )


def _trajectories(
    paths: Paths, veh: np.ndarray, f0s: np.ndarray, params: np.ndarray, kind: np.ndarray, times: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(C, K) x, y, speed of candidates at ``times`` after their event (the first entry is the event frame)."""
    y_tgt, dur, pre, brake, t_brake = params.T
    x0 = paths.x[f0s, veh]
    y0 = paths.y[f0s, veh]
    v = _speed_profile(paths.speed[f0s, veh], pre, dur, brake, t_brake, times)
    dt = float(times[1] - times[0]) if times.size > 1 else 0.0
    x = x0[:, None] + np.concatenate(
        [np.zeros((len(veh), 1)), np.cumsum(0.5 * (v[:, 1:] + v[:, :-1]) * dt, axis=1)], axis=1
    )
    lat = _smoothstep(times[None, :] / np.maximum(dur, 1e-6)[:, None])
    y = y0[:, None] + (y_tgt - y0)[:, None] * np.where(kind[:, None], lat, 0.0)
    return x, y, v


def _hits_others(paths: Paths, veh: np.ndarray, x: np.ndarray, y: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """(C,) whether a candidate overlaps another logged vehicle in its window (with a small margin)."""
    if veh.size == 0:
        return np.zeros(0, dtype=bool)
    sub = idx[:, ::2]  # every 0.4 s is enough at these speeds
    ox, oy = paths.x[sub], paths.y[sub]  # (C, K, N)
    dx = np.abs(x[:, ::2, None] - ox)
    dy = np.abs(y[:, ::2, None] - oy)
    long_lim = (paths.length[veh][:, None, None] + paths.length[None, None, :]) / 2 + 1.0
    lat_lim = (paths.width[veh][:, None, None] + paths.width[None, None, :]) / 2 + 0.2
    clash = (dx < long_lim) & (dy < lat_lim)
    clash[np.arange(len(veh)), :, veh] = False  # a vehicle does not clash with its own logged self
    return clash.any(axis=(1, 2))
