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
    """How many feasible candidates it was drawn from."""


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
    for f0 in range(first, max(first, last), 2):
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
    kind = np.array([r[2][0] == "cut_in" for r in rows])
    y_tgt = np.array([r[2][1] for r in rows])
    dur = np.array([r[2][2] for r in rows])
    pre = np.array([r[2][3] for r in rows])
    brake = np.array([r[2][4] for r in rows])
    t_brake = np.array([r[2][5] for r in rows])

    k = np.arange(frames)
    rel = (k[None, :] - f0s[:, None]) * dt  # (C, F) time since the event (negative before)
    after = rel >= 0
    times = np.maximum(rel, 0.0)
    x0 = paths.x[f0s, veh]
    y0 = paths.y[f0s, veh]
    v0 = paths.speed[f0s, veh]
    # the speed profile on the time since the event, per candidate
    v = _speed_profile(v0, pre, dur, brake, t_brake, np.arange(frames) * dt)
    shift = np.clip(k[None, :] - f0s[:, None], 0, frames - 1)
    v = np.take_along_axis(v, shift, axis=1)
    x = x0[:, None] + np.concatenate(
        [np.zeros((len(rows), 1)), np.cumsum(0.5 * (v[:, 1:] + v[:, :-1]) * dt, axis=1)], axis=1
    )
    x = x - np.take_along_axis(x, f0s[:, None], axis=1) + x0[:, None]
    lat = _smoothstep(times / np.maximum(dur, 1e-6)[:, None])
    y = y0[:, None] + (y_tgt - y0)[:, None] * np.where(kind[:, None], lat, 0.0)
    # before the event the opponent is exactly its logged self
    x = np.where(after, x, paths.x[:, veh].T)
    y = np.where(after, y, paths.y[:, veh].T)
    v = np.where(after, v, paths.speed[:, veh].T)

    length = paths.length[veh][:, None]
    width = paths.width[veh][:, None]
    el, ew = cfg.ego.length, cfg.ego.width
    ex, ey, ev = plan[None, :, 0], plan[None, :, 1], plan[None, :, 3]
    lat_overlap = np.abs(y - ey) < (width + ew) / 2
    gap = x - ex - (length + el) / 2  # positive: the opponent is ahead of the predicted ego
    collide = lat_overlap & (np.abs(x - ex) < (length + el) / 2) & after
    closing = ev - v
    with np.errstate(divide="ignore", invalid="ignore"):
        ttc = np.where(lat_overlap & after & (gap > 0) & (closing > 0.1), gap / closing, np.inf)
    collides = collide.any(axis=1)
    risk = np.where(collides, 1.0, 0.8 * np.exp(-ttc.min(axis=1) / 2.0))

    # survivable: at the first lateral overlap the opponent is ahead, and braking from there keeps a gap
    onset = np.where((lat_overlap & after).any(axis=1), np.argmax(lat_overlap & after, axis=1), -1)
    ok = onset >= 0
    rows_idx = np.arange(len(rows))
    g_on = np.where(ok, gap[rows_idx, np.maximum(onset, 0)], -np.inf)
    ok &= g_on >= acfg.min_clearance
    react = onset + round(acfg.reaction_time / dt)
    v_react = plan[np.clip(react, 0, frames - 1), 3]
    since = (k[None, :] - react[:, None]) * dt
    v_brake = np.maximum(v_react[:, None] - acfg.avoid_brake * np.maximum(since, 0.0), v)
    v_ego = np.where(since > 0, np.minimum(ev, v_brake), ev)
    closing_avoid = np.where(k[None, :] >= onset[:, None], v_ego - v, 0.0)
    gap_avoid = g_on[:, None] - np.cumsum(closing_avoid * dt, axis=1)
    horizon = (k[None, :] >= onset[:, None]) & (k[None, :] <= onset[:, None] + round(6.0 / dt))
    ok &= np.where(horizon, gap_avoid, np.inf).min(axis=1) >= acfg.min_clearance
    # on the road, and not through other logged vehicles
    ok &= (y_tgt <= layout.left_edge_y) & (y_tgt >= layout.right_edge_y)
    kept = np.flatnonzero(ok)
    ok[kept[_hits_others(paths, veh[kept], x[kept], y[kept], after[kept])]] = False
    if not ok.any():
        return None
    prior = -brake / 3.0 - np.abs(pre) - 1.0 / np.maximum(dur, 1.0) - 0.3 * (~kind)
    logits = prior + acfg.risk_weight * risk
    logits = np.where(ok, logits, -np.inf)
    p = np.exp(logits - logits.max())
    p /= p.sum()
    c = int(rng.choice(len(rows), p=p))
    i, f0 = int(veh[c]), int(f0s[c])
    heading = np.arctan2(np.gradient(y[c]), np.maximum(np.gradient(x[c]), 1e-3))
    paths.x[f0:, i] = x[c, f0:]
    paths.y[f0:, i] = y[c, f0:]
    paths.speed[f0:, i] = v[c, f0:]
    paths.heading[f0:, i] = np.where(v[c, f0:] > 0.5, heading[f0:], paths.heading[f0, i])
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


def _hits_others(paths: Paths, veh: np.ndarray, x: np.ndarray, y: np.ndarray, after: np.ndarray) -> np.ndarray:
    """(C,) whether a candidate overlaps another logged vehicle after its event (with a small margin)."""
    hits = np.zeros(len(veh), dtype=bool)
    frames = np.flatnonzero(after.any(axis=0))
    if frames.size == 0:
        return hits
    sub = frames[::2]  # every 0.4 s is enough at these speeds
    ox, oy = paths.x[sub], paths.y[sub]  # (K, N)
    cx, cy = x[:, sub], y[:, sub]  # (C, K)
    dx = np.abs(cx[:, :, None] - ox[None])
    dy = np.abs(cy[:, :, None] - oy[None])
    long_lim = (paths.length[veh][:, None, None] + paths.length[None, None, :]) / 2 + 1.0
    lat_lim = (paths.width[veh][:, None, None] + paths.width[None, None, :]) / 2 + 0.2
    clash = (dx < long_lim) & (dy < lat_lim) & after[:, sub][:, :, None]
    clash[np.arange(len(veh)), :, veh] = False  # a vehicle does not clash with its own logged self
    return clash.any(axis=(1, 2))
