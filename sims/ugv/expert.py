"""The scripted UGV expert: a grid planner around static obstacles, pure pursuit, and yielding to movers.

Privileged: it reads the static layout and the movers' scripted future poses from the world.

1. Planning (once per episode, and again when the robot has left the path): a clearance grid of
   the static obstacles, a navigation function (cost-to-goal over 8-connected cells, cells near
   obstacles cost more so paths keep to the middle of passages) computed by vectorised relaxation,
   a descent from the robot's cell, and shortcutting that never lowers the path's clearance.
2. Tracking: pure pursuit on the path, speed limited so the yaw rate stays within bounds; a large
   heading error is first turned away on the spot.
3. Yielding: for each speed cap, fastest first, the robot's progress along the path at that speed
   is predicted for ``go_horizon`` seconds; the cap is taken if the robot keeps clear of every mover
   (bounding circles plus a margin) the whole time. If no cap is, it moves at most one step, to where
   standing still stays clear for ``stop_horizon`` seconds (it stops abruptly, as the paper's expert
   does). Failing even that (a takeover that finds the robot in a mover's way), it leaves the path by the
   manoeuvre (an arc, or a turn on the spot and a straight run) that keeps clear of the movers longest (contact
   measured to each mover's own box or circle), then replans. While it evades it says it is ``engaged``: the env's
   ``expert_engaged``, which keeps a takeover going until the evasion is over.
4. Detours: after yielding for ``detour_after`` seconds, it plans again on the grid with the movers' sweep over
   the next few seconds laid on it as obstacles, and follows that path if a faster speed keeps clear along it
   (the check of 3.): a mover going its way slowly is passed rather than trailed for the rest of the episode.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol, cast

import numpy as np

from sims.ugv.config import RobotConfig, UGVConfig
from sims.ugv.scenario import Layout, MoverPlan

if TYPE_CHECKING:
    from sims.ugv.world import World

SQRT2 = math.sqrt(2.0)
NEIGHBOURS = ((1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (1, -1), (-1, 1), (-1, -1))
PATH_SPACING = 0.05
"""Spacing of the resampled path that pure pursuit follows (m)."""
SWEEP_SPACING = 0.25
"""Time between the circles that lay a mover's sweep on a detour's grid (s): at the movers' speeds (up to about
1 m/s) the gaps between them stay under a mover's bounding radius."""


def wrap(angle: float) -> float:
    return (angle + math.pi) % (2 * math.pi) - math.pi


def point_segment_distances(points: np.ndarray, segments: np.ndarray) -> np.ndarray:
    """(P, K) distances from points (P, 2) to segments (K, 4) rows ax, ay, bx, by."""
    a = segments[:, 0:2]
    e = segments[:, 2:4] - a
    length2 = np.maximum((e * e).sum(axis=1), 1e-12)
    ap = points[:, None, :] - a[None, :, :]
    t = np.clip((ap * e[None]).sum(axis=2) / length2, 0.0, 1.0)
    closest = a[None] + t[..., None] * e[None]
    diff = points[:, None, :] - closest
    return np.sqrt((diff * diff).sum(axis=2))


def static_clearance(points: np.ndarray, layout: Layout) -> np.ndarray:
    """Distance (m) from each point to the nearest wall, box or round obstacle; 0 inside one."""
    segments = [np.array([(*a, *b) for a, b in layout.walls]).reshape(-1, 4)]
    inside = np.zeros(len(points), dtype=bool)
    for box in layout.boxes:
        c, s = math.cos(box.yaw), math.sin(box.yaw)
        hl, hw = box.length / 2, box.width / 2
        corners = np.array(
            [
                (box.x + c * px - s * py, box.y + s * px + c * py)
                for px, py in ((hl, hw), (hl, -hw), (-hl, -hw), (-hl, hw))
            ]
        )
        segments.append(np.hstack([corners, np.roll(corners, -1, axis=0)]))
        rel = points - (box.x, box.y)
        along = rel[:, 0] * c + rel[:, 1] * s
        across = -rel[:, 0] * s + rel[:, 1] * c
        inside |= (np.abs(along) <= hl) & (np.abs(across) <= hw)
    all_segments = np.vstack(segments)
    clearance = np.full(len(points), np.inf)
    for chunk in range(0, len(points), 2048):  # bounded memory
        part = points[chunk : chunk + 2048]
        if len(all_segments):
            clearance[chunk : chunk + 2048] = point_segment_distances(part, all_segments).min(axis=1)
    for circle in layout.circles:
        clearance = np.minimum(clearance, np.hypot(points[:, 0] - circle.x, points[:, 1] - circle.y) - circle.radius)
    clearance[inside] = 0.0
    return np.maximum(clearance, 0.0)


@dataclass
class Grid:
    """The static world on a regular grid: clearance per cell and the navigation function to the goal."""

    x0: float
    y0: float
    res: float
    clearance: np.ndarray
    """(ny, nx) distance to the nearest static obstacle (m)."""
    cost_to_go: np.ndarray
    """(ny, nx) path cost to the goal; inf where unreachable or blocked."""

    def cell(self, x: float, y: float) -> tuple[int, int]:
        ny, nx = self.clearance.shape
        ix = min(max(int((x - self.x0) / self.res), 0), nx - 1)
        iy = min(max(int((y - self.y0) / self.res), 0), ny - 1)
        return iy, ix

    def centre(self, iy: int, ix: int) -> tuple[float, float]:
        return self.x0 + (ix + 0.5) * self.res, self.y0 + (iy + 0.5) * self.res

    def clearance_at(self, points: np.ndarray) -> np.ndarray:
        """Bilinear clearance at (P, 2) points."""
        ny, nx = self.clearance.shape
        fx = np.clip((points[:, 0] - self.x0) / self.res - 0.5, 0, nx - 1.000001)
        fy = np.clip((points[:, 1] - self.y0) / self.res - 0.5, 0, ny - 1.000001)
        ix, iy = fx.astype(int), fy.astype(int)
        tx, ty = fx - ix, fy - iy
        ix1, iy1 = np.minimum(ix + 1, nx - 1), np.minimum(iy + 1, ny - 1)
        c = self.clearance
        top = c[iy, ix] * (1 - tx) + c[iy, ix1] * tx
        bottom = c[iy1, ix] * (1 - tx) + c[iy1, ix1] * tx
        return top * (1 - ty) + bottom * ty


def build_grid(layout: Layout, config: UGVConfig) -> Grid:
    ex = config.expert
    res = ex.grid_resolution
    xmin, ymin, xmax, ymax = layout.bounds
    nx, ny = max(1, math.ceil((xmax - xmin) / res)), max(1, math.ceil((ymax - ymin) / res))
    points = _cell_centres(xmin, ymin, res, nx, ny)
    clearance = static_clearance(points, layout).reshape(ny, nx)
    return Grid(xmin, ymin, res, clearance, _navigation(clearance, points, layout, config))


def detour_grid(grid: Grid, layout: Layout, config: UGVConfig, circles: np.ndarray) -> Grid:
    """``grid`` with more round obstacles, (K, 3) rows x, y, radius (the movers' sweep): its clearance and its
    navigation function recomputed around them."""
    ny, nx = grid.clearance.shape
    points = _cell_centres(grid.x0, grid.y0, grid.res, nx, ny)
    clearance = grid.clearance.ravel().copy()
    for cx, cy, radius in circles:
        np.minimum(clearance, np.hypot(points[:, 0] - cx, points[:, 1] - cy) - radius, out=clearance)
    clearance = np.maximum(clearance, 0.0).reshape(ny, nx)
    return Grid(grid.x0, grid.y0, grid.res, clearance, _navigation(clearance, points, layout, config))


def _cell_centres(x0: float, y0: float, res: float, nx: int, ny: int) -> np.ndarray:
    gx, gy = np.meshgrid(x0 + (np.arange(nx) + 0.5) * res, y0 + (np.arange(ny) + 0.5) * res)
    return np.column_stack([gx.ravel(), gy.ravel()])


def _navigation(clearance: np.ndarray, points: np.ndarray, layout: Layout, config: UGVConfig) -> np.ndarray:
    """The navigation function (path cost to the goal per cell) over a clearance grid."""
    ex = config.expert
    ny, nx = clearance.shape
    # traversal cost per cell: 1 in the open, more near obstacles, inf inside the inflation
    shortfall = np.clip((ex.preferred_clearance - clearance) / ex.preferred_clearance, 0.0, 1.0)
    cell_cost = 1.0 + ex.clearance_weight * shortfall
    gxg, gyg, goal_radius = layout.goal
    goal_dist = np.hypot(points[:, 0] - gxg, points[:, 1] - gyg).reshape(ny, nx)
    # cells inside the goal region are targets even within the inflation, as long as the robot fits
    targets = (goal_dist <= max(goal_radius, ex.grid_resolution)) & (clearance >= config.robot.width / 2)
    blocked = (clearance < ex.inflation) & ~targets
    cell_cost[blocked] = np.inf
    cost_to_go = np.full((ny, nx), np.inf)
    cost_to_go[targets] = goal_dist[targets]
    if not targets.any():
        iy, ix = np.unravel_index(np.argmin(goal_dist), goal_dist.shape)
        cost_to_go[iy, ix] = 0.0
    _relax(cost_to_go, cell_cost, ex.grid_resolution)
    return cost_to_go


def _relax(cost_to_go: np.ndarray, cell_cost: np.ndarray, res: float) -> None:
    """Bellman-Ford on the 8-connected grid, all cells at once, until nothing improves (in place)."""
    ny, nx = cost_to_go.shape
    padded_cost = np.pad(cell_cost, 1, constant_values=np.inf)
    edges = []
    for dx, dy in NEIGHBOURS:
        step = res * (SQRT2 if dx and dy else 1.0)
        neighbour_cost = padded_cost[1 + dy : ny + 1 + dy, 1 + dx : nx + 1 + dx]
        edges.append(step * 0.5 * (cell_cost + neighbour_cost))
    padded = np.pad(cost_to_go, 1, constant_values=np.inf)
    inner = padded[1:-1, 1:-1]
    for _ in range(4 * (nx + ny)):
        before = inner.copy()
        for (dx, dy), edge in zip(NEIGHBOURS, edges, strict=True):
            np.minimum(inner, padded[1 + dy : ny + 1 + dy, 1 + dx : nx + 1 + dx] + edge, out=inner)
        if np.array_equal(before, inner):
            break
    cost_to_go[:] = inner


@dataclass
class Path:
    xy: np.ndarray
    """(n, 2) points every ~PATH_SPACING m, from the robot towards the goal."""
    s: np.ndarray
    """(n,) arc length at each point."""


def extract_path(grid: Grid, start: tuple[float, float], goal: tuple[float, float], min_keep: float) -> Path | None:
    """Descend the navigation function from ``start``, shortcut it, resample it. None if unreachable."""
    cost = grid.cost_to_go
    ny, nx = cost.shape
    iy, ix = grid.cell(*start)
    if not math.isfinite(cost[iy, ix]):
        # start inside an obstacle's inflation: head for the best reachable cell nearby
        reach = max(1, round(0.8 / grid.res))
        y0, y1, x0, x1 = max(iy - reach, 0), min(iy + reach + 1, ny), max(ix - reach, 0), min(ix + reach + 1, nx)
        window = cost[y0:y1, x0:x1]
        if not np.isfinite(window).any():
            return None
        yy, xx = np.mgrid[y0:y1, x0:x1]
        score = window + 3.0 * grid.res * np.hypot(yy - iy, xx - ix)
        iy, ix = (int(v) for v in np.unravel_index(np.argmin(score), score.shape))
        iy, ix = iy + y0, ix + x0
    cells = [(iy, ix)]
    for _ in range(nx * ny):
        if cost[iy, ix] <= grid.res:  # inside the goal's target cells
            break
        best, best_val = None, cost[iy, ix]
        for dx, dy in NEIGHBOURS:
            jy, jx = iy + dy, ix + dx
            if 0 <= jy < ny and 0 <= jx < nx and cost[jy, jx] < best_val:
                best, best_val = (jy, jx), cost[jy, jx]
        if best is None:
            break
        iy, ix = best
        cells.append(best)
    points = np.array([start, *(grid.centre(*c) for c in cells[1:]), goal], dtype=float)
    return _resample(_shortcut(grid, points, min_keep))


def _shortcut(grid: Grid, points: np.ndarray, min_keep: float) -> np.ndarray:
    """Greedy string pulling: jump to the farthest point whose straight line keeps the clearance
    of the original path (or ``min_keep``, whichever is lower)."""
    clearance = grid.clearance_at(points)
    kept = [0]
    i, n = 0, len(points)
    while i < n - 1:
        j_best = i + 1
        for j in range(min(n - 1, i + 80), i + 1, -1):
            need = min(min_keep, float(clearance[i + 1 : j].min()) if j > i + 1 else min_keep) - 0.02
            length = float(np.hypot(*(points[j] - points[i])))
            samples = max(2, int(length / (grid.res * 0.5)) + 1)
            line = points[i] + np.linspace(0.0, 1.0, samples)[:, None] * (points[j] - points[i])
            if grid.clearance_at(line[1:-1]).min(initial=np.inf) >= need:
                j_best = j
                break
        kept.append(j_best)
        i = j_best
    return points[kept]


def _resample(points: np.ndarray) -> Path:
    seg = np.diff(points, axis=0)
    length = np.hypot(seg[:, 0], seg[:, 1])
    keep = np.concatenate([[True], length > 1e-9])
    points = points[keep]
    s_vertices = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(points, axis=0).T))])
    total = s_vertices[-1]
    s = np.linspace(0.0, total, max(2, math.ceil(total / PATH_SPACING) + 1))
    xy = np.column_stack([np.interp(s, s_vertices, points[:, 0]), np.interp(s, s_vertices, points[:, 1])])
    return Path(xy, s)


class ExpertView(Protocol):
    """What the expert reads of the env (its privileged view), so that it depends on no env class."""

    world: World | None
    layout: Layout | None
    config: UGVConfig
    episode: int


class UGVExpert:
    """The expert of one env; call :meth:`act` at any step (takeovers may start mid-episode)."""

    def __init__(self, env: ExpertView, yield_to_movers: bool | None = None, evade: bool = True) -> None:
        self.env = env
        self.yield_to_movers = env.config.expert.yield_to_movers if yield_to_movers is None else yield_to_movers
        """False gives the naive goal seeker: the same planner and tracker, blind to movers (None: the env's
        ``expert.yield_to_movers``)."""
        self.evade = evade
        """Leave the path when no speed along it keeps clear of a mover (False: delay contact along the path,
        the behaviour before evasion existed; kept for the comparison in the tests)."""
        self.reset()

    def reset(self) -> None:
        self._grid: Grid | None = None
        self._path: Path | None = None
        self._index = 0
        self._episode: int | None = None
        self._best_cost_to_go = math.inf
        self._stalled = 0
        self._escape: tuple[int, float, float] | None = None  # steps left, v, w
        self._yielded = 0  # steps spent yielding in a row (since the last search for a detour)
        self.engaged = False
        """True when the last :meth:`act` was evading a mover (no speed along the path kept clear): a manoeuvre
        that handing control back would cut short (see :func:`core.protocol.expert_engaged`)."""

    # -- planning --------------------------------------------------------------------------------
    def _ensure_plan(self, x: float, y: float) -> Path | None:
        env = self.env
        world = env.world
        if world is None or env.layout is None:
            raise RuntimeError("reset the env before asking the expert")
        if self._episode != env.episode:  # a new episode (the env resets its own expert; others notice here)
            self.reset()
            self._episode = env.episode
            self._grid = build_grid(env.layout, env.config)
        if self._path is None:
            self._replan(x, y)
        return self._path

    def _replan(self, x: float, y: float) -> None:
        assert self._grid is not None and self.env.layout is not None
        gx, gy, _ = self.env.layout.goal
        self._path = extract_path(self._grid, (x, y), (gx, gy), min_keep=0.45)
        self._index = 0

    # -- acting ----------------------------------------------------------------------------------
    def act(self) -> np.ndarray:
        self.engaged = False
        env = self.env
        cfg = env.config
        robot, ex = cfg.robot, cfg.expert
        x, y, yaw = env.world.pose if env.world is not None else (0.0, 0.0, 0.0)
        path = self._ensure_plan(x, y)
        gx, gy, _ = env.layout.goal  # type: ignore[union-attr]
        if self._escape is not None:
            return self._escaping(x, y, yaw)

        if path is not None:
            index, offset = self._nearest(path, x, y)
            if offset > ex.replan_distance:
                self._replan(x, y)
                path = self._path
                index = 0
        if path is None:  # no route around the static obstacles: head straight for the goal
            target = (gx, gy)
            index = 0
        else:
            self._index = index
            s_target = path.s[index] + ex.lookahead
            j = min(int(np.searchsorted(path.s, s_target)), len(path.s) - 1)
            target = (float(path.xy[j, 0]), float(path.xy[j, 1]))

        dx, dy = target[0] - x, target[1] - y
        distance = math.hypot(dx, dy)
        alpha = wrap(math.atan2(dy, dx) - yaw) if distance > 1e-6 else 0.0
        if abs(alpha) > math.radians(ex.turn_in_place_deg):
            v_track, w = 0.0, math.copysign(min(robot.w_max, 2.0 * abs(alpha)), alpha)
        else:
            curvature = 2.0 * math.sin(alpha) / max(distance, 1e-6)
            v_track = robot.v_max if abs(curvature) < 1e-9 else min(robot.v_max, robot.w_max / abs(curvature))
            w = v_track * curvature
        if self._grid is not None:
            v_track, w = self._keep_clear(x, y, yaw, v_track, w)

        v = v_track
        yielding = False
        if self.yield_to_movers and env.layout is not None and env.layout.movers and path is not None:
            cap, safe = self._speed_cap(path, index, v_track)
            if not safe and self.evade:
                # handed over (or caught) where no speed along the path keeps clear: leave the path
                return self._normalised(*self._evade(x, y, yaw))
            if cap < v:
                w = w * (cap / v) if v > 0 else w
                v = cap
                yielding = True
                self._yielded += 1
                if self._yielded >= cfg.expert.detour_after * cfg.control_hz - 1e-6:  # inf: never
                    self._yielded = 0
                    self._detour(x, y, cap, v_track)  # followed from the next step if it is faster
            else:
                self._yielded = 0
        if self._stuck(x, y, yielding):
            return self._escaping(x, y, yaw)
        return self._normalised(v, w)

    def _normalised(self, v: float, w: float) -> np.ndarray:
        robot = self.env.config.robot
        return np.array([2.0 * v / robot.v_max - 1.0, max(-1.0, min(1.0, w / robot.w_max))], dtype=np.float32)

    def _stuck(self, x: float, y: float, yielding: bool) -> bool:
        """True after ``stall_time`` without getting closer to the goal (waiting for a mover aside):
        no reverse gear, so a robot wedged against an obstacle needs to drive out and replan."""
        grid = self._grid
        if grid is None or yielding:
            self._stalled = 0
            return False
        here = float(grid.cost_to_go[grid.cell(x, y)])
        if here < self._best_cost_to_go - 0.05:
            self._best_cost_to_go, self._stalled = here, 0
            return False
        self._stalled += 1
        if self._stalled < round(self.env.config.expert.stall_time * self.env.config.control_hz):
            return False
        self._stalled = 0
        self._best_cost_to_go = math.inf
        self._escape = (round(self.env.config.control_hz), 0.0, 0.0)  # drive out for 1 s
        return True

    def _escaping(self, x: float, y: float, yaw: float) -> np.ndarray:
        """Drive along the clearest arc for a second, then plan again from wherever that leads."""
        assert self._escape is not None and self._grid is not None
        steps, v, w = self._escape
        if v == 0.0 and w == 0.0:  # choose the arc once, at the start
            robot = self.env.config.robot
            arcs = [(0.5 * robot.v_max, turn * robot.w_max) for turn in (-1.0, -0.5, 0.0, 0.5, 1.0)]
            v, w = max(arcs, key=lambda arc: self._arc_clearance(self._grid, x, y, yaw, arc[0], arc[1], 1.0))  # type: ignore[arg-type]
        self._escape = (steps - 1, v, w) if steps > 1 else None
        if self._escape is None:
            self._path = None  # replan from the new pose at the next call
        return self._normalised(v, w)

    def _keep_clear(self, x: float, y: float, yaw: float, v: float, w: float) -> tuple[float, float]:
        """Slow down, turn harder or turn the other way when holding (v, w) for ``clear_horizon`` would
        bring the footprint closer to a static obstacle than allowed (or than it is now, if it is
        already closer). It matters after a takeover next to an obstacle."""
        grid, cfg = self._grid, self.env.config
        assert grid is not None
        robot = cfg.robot
        turn = math.copysign(robot.w_max, w) if w else robot.w_max
        candidates = [(v, w)]
        if v > 0:
            candidates += [(0.5 * v, max(-robot.w_max, min(robot.w_max, 2.0 * w))), (0.25 * v, turn)]
        candidates += [(0.0, turn), (0.0, -turn)]
        radius = footprint_radius(robot)
        allowed = min(radius + 0.02, self._footprint_clearance(grid, x, y, np.array([yaw])) - 0.005)
        best, best_clearance = candidates[0], -math.inf
        for v_try, w_try in candidates:
            clearance = self._arc_clearance(grid, x, y, yaw, v_try, w_try, cfg.expert.clear_horizon)
            if clearance >= allowed:
                return v_try, w_try
            if clearance > best_clearance:
                best, best_clearance = (v_try, w_try), clearance
        return best

    def _footprint_clearance(
        self, grid: Grid, px: np.ndarray | float, py: np.ndarray | float, heading: np.ndarray
    ) -> float:
        """Least clearance of three circles covering the robot's footprint at the given poses
        (centres at -L/3, 0, L/3 along the heading, radius hypot(L/6, W/2))."""
        points = np.asarray(px, dtype=float).reshape(-1), np.asarray(py, dtype=float).reshape(-1)
        cx, cy = footprint_centres(*points, heading, self.env.config.robot)
        return float(grid.clearance_at(np.column_stack([cx.ravel(), cy.ravel()])).min())

    def _arc_clearance(self, grid: Grid, x: float, y: float, yaw: float, v: float, w: float, horizon: float) -> float:
        """Least footprint clearance while holding (v, w) for ``horizon`` seconds."""
        t = np.linspace(horizon / 6, horizon, 6)
        heading = yaw + w * t
        if abs(w) > 1e-9:
            px = x + v / w * (np.sin(heading) - math.sin(yaw))
            py = y - v / w * (np.cos(heading) - math.cos(yaw))
        else:
            px, py = x + v * t * math.cos(yaw), y + v * t * math.sin(yaw)
        return self._footprint_clearance(grid, px, py, heading)

    def _nearest(self, path: Path, x: float, y: float) -> tuple[int, float]:
        """Index of the path point nearest the robot, searched forward from the last one."""
        lo = max(self._index - 10, 0)
        hi = min(self._index + 60, len(path.s))
        window = path.xy[lo:hi]
        d = np.hypot(window[:, 0] - x, window[:, 1] - y)
        i = int(np.argmin(d))
        return lo + i, float(d[i])

    def _speed_cap(self, path: Path, index: int, v_track: float) -> tuple[float, bool]:
        """The fastest speed cap whose committed motion keeps clear of every mover (see module doc), and
        whether any cap along the path keeps clear at all (False: the caller evades off the path)."""
        env = self.env
        world = env.world
        assert world is not None and env.layout is not None
        cfg = env.config
        ex = cfg.expert
        dt = cfg.dt
        n_go = max(1, round(ex.go_horizon / dt))
        n_stop = max(n_go, round(ex.stop_horizon / dt))
        k = world.k
        world.ensure_table(k + n_stop)
        future = world.mover_poses[:, k + 1 : k + n_stop + 1, 0:2]  # (M, T, 2), T = n_stop
        radii = np.array([m.bounding_radius for m in env.layout.movers])
        reach = (radii + cfg.robot.circumradius + ex.mover_margin)[:, None]  # (M, 1)

        caps = np.array([c for c in ex.speed_caps if c < v_track] + [v_track])
        caps = np.unique(np.minimum(caps, v_track))[::-1]  # fastest first
        go = future[:, :n_go]
        # progress along the path at a constant speed cap (the path ends at the goal)
        progress = path.s[index] + caps[:, None] * dt * np.arange(1, n_go + 1)[None, :]  # (C, T)
        px = np.interp(progress, path.s, path.xy[:, 0])
        py = np.interp(progress, path.s, path.xy[:, 1])
        gap = np.hypot(px[:, None, :] - go[None, :, :, 0], py[:, None, :] - go[None, :, :, 1]) - reach[None]
        clear = (gap >= 0).all(axis=(1, 2))
        if clear.any():
            return float(caps[int(np.argmax(clear))]), True
        # no committed motion is safe: move one step at most, to where standing still is safe
        one_step = path.s[index] + caps * dt  # (C,)
        sx = np.interp(one_step, path.s, path.xy[:, 0])
        sy = np.interp(one_step, path.s, path.xy[:, 1])
        gap_stop = (
            np.hypot(sx[:, None, None] - future[None, :, :, 0], sy[:, None, None] - future[None, :, :, 1]) - reach[None]
        )
        stop_safe = (gap_stop >= 0).all(axis=(1, 2))
        if stop_safe.any():
            return float(caps[int(np.argmax(stop_safe))]), True
        # nothing along the path is safe: delay contact as long as possible (if evading cannot do better)
        contact = (gap < 0).any(axis=1)  # (C, T)
        first_contact = np.where(contact.any(axis=1), contact.argmax(axis=1), n_go)
        return float(caps[int(np.argmax(first_contact))]), False

    def _detour(self, x: float, y: float, cap: float, v_track: float) -> None:
        """Plan around the movers' sweep over the next ``detour_horizon`` (their bounding circles, grown so that the
        grid's inflation keeps the robot's centre as far from them as the speed caps do) and take that path if a
        faster cap keeps clear along it than ``cap`` along the current one."""
        env, grid = self.env, self._grid
        world, layout = env.world, env.layout
        assert world is not None and layout is not None and grid is not None
        cfg = env.config
        ex = cfg.expert
        n = max(1, round(ex.detour_horizon / cfg.dt))
        k = world.k
        world.ensure_table(k + n)
        sweep = world.mover_poses[:, k : k + n + 1 : max(1, round(SWEEP_SPACING / cfg.dt)), 0:2]  # (M, S, 2)
        grow = cfg.robot.circumradius + ex.mover_margin - ex.inflation
        radii = np.array([m.bounding_radius + grow for m in layout.movers])
        circles = np.column_stack([sweep.reshape(-1, 2), np.repeat(radii, sweep.shape[1])])
        gx, gy, _ = layout.goal
        path = extract_path(detour_grid(grid, layout, cfg, circles), (x, y), (gx, gy), min_keep=0.45)
        if path is None:
            return
        faster, safe = self._speed_cap(path, 0, v_track)
        if safe and faster > cap:
            self._path, self._index = path, 0

    def _evade(self, x: float, y: float, yaw: float) -> tuple[float, float]:
        """The first command of the manoeuvre that keeps clear of the movers longest, without touching a static
        obstacle. Used where no speed along the planned path keeps clear, e.g. after a takeover in a mover's way:
        there is no reverse gear, so the way out is sideways or forwards, off the path; the path is replanned once
        clear. Re-chosen at every step (receding horizon), so a manoeuvre need only be good from here.

        The manoeuvres (:meth:`_manoeuvres`): arcs held for ``evade_time``, and turns on the spot for a while
        followed by a straight run, which is how a robot facing the wrong way leaves a mover's sweep; each then
        stands still. Ranked by the first real contact (the footprint's three circles against the mover's own
        shape, its box or circle: waiting on the spot is not safe just because the margin is kept for longer,
        and a long box's bounding circle would call every way out a contact), then the first breach of the
        margin, then the narrowest gap."""
        env, grid = self.env, self._grid
        world = env.world
        assert world is not None and env.layout is not None and grid is not None
        cfg = env.config
        robot, ex, dt = cfg.robot, cfg.expert, cfg.dt
        n = max(1, round(ex.stop_horizon / dt))
        k = world.k
        world.ensure_table(k + n)
        poses = world.mover_poses[:, k + 1 : k + n + 1, :]  # (M, T, 3)
        future = poses[..., 0:2]
        radii = np.array([m.bounding_radius for m in env.layout.movers])[:, None, None]  # (M, 1, 1)
        v, w = self._manoeuvres(n)  # (P, T)
        px, py, heading = unicycle_poses(x, y, yaw, v, w, dt)  # (P, T) poses after each step
        touching = footprint_radius(robot)
        moving = v > 0
        cx, cy = footprint_centres(px, py, heading, robot)  # (P, T, 3)
        walls = grid.clearance_at(np.column_stack([cx.ravel(), cy.ravel()])).reshape(cx.shape).min(axis=2)
        blocked = (moving & (walls < touching)).any(axis=1)  # drives into a static obstacle
        # the margin: the bounding circles (what the path's speed caps keep clear of); real contact: the footprint
        margin_gap = np.hypot(px[:, None] - future[None, :, :, 0], py[:, None] - future[None, :, :, 1])
        margin_gap = (margin_gap - radii[None, :, :, 0] - robot.circumradius - ex.mover_margin).min(axis=1)  # (P, T)
        touch_gap = mover_distances(cx, cy, poses, env.layout.movers)  # (P, M, T, 3)
        # numpy's stub types any(axis=...) as a scalar or an array; of a (P, M, T, 3) array it is an array
        touch = cast(np.ndarray, (touch_gap < touching).any(axis=(1, 3)))  # (P, T)
        breach = margin_gap < 0
        first_touch = np.where(touch.any(axis=1), touch.argmax(axis=1), n)
        first_breach = np.where(breach.any(axis=1), breach.argmax(axis=1), n)
        keys = {
            p: (int(first_touch[p]), int(first_breach[p]), float(margin_gap[p].min()))
            for p in range(v.shape[0])
            if not blocked[p]
        }
        self._path = None  # replan from wherever the evasion leads
        self.engaged = True
        if not keys:
            return 0.0, 0.0
        best = max(keys, key=keys.__getitem__)  # the first of equals, in the order of the manoeuvres
        return float(v[best, 0]), float(w[best, 0])

    def _manoeuvres(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """(v, w) per step, (P, n) each: the arcs (three speeds, five turn rates) held for ``evade_time`` (at top
        speed also twice as long), and turns on the spot either way for each of ``evade_turns`` followed by a
        straight run at top speed for ``evade_time``; every manoeuvre then stands still."""
        cfg = self.env.config
        robot, ex, dt = cfg.robot, cfg.expert, cfg.dt
        n_move = max(1, round(ex.evade_time / dt))
        plans: list[tuple[np.ndarray, np.ndarray]] = []

        def plan(segments: list[tuple[int, float, float]]) -> None:
            v, w, t = np.zeros(n), np.zeros(n), 0
            for steps, speed, rate in segments:
                v[t : t + steps], w[t : t + steps] = speed, rate
                t += steps
            plans.append((v, w))

        for speed in (robot.v_max, 0.5 * robot.v_max, 0.0):
            for turn in (-1.0, -0.5, 0.0, 0.5, 1.0):
                plan([(n_move, speed, turn * robot.w_max)])
                if speed == robot.v_max:
                    plan([(2 * n_move, speed, turn * robot.w_max)])
        for seconds in ex.evade_turns:
            for turn in (-1.0, 1.0):
                plan([(max(1, round(seconds / dt)), 0.0, turn * robot.w_max), (n_move, robot.v_max, 0.0)])
        return np.stack([v for v, _ in plans]), np.stack([w for _, w in plans])


class BlindExpertPolicy:
    """The scripted expert blind to movers as a planner (:mod:`core.planners`, ``blind-movers``): the same planner
    and tracker, running into movers. ``sage train --demo-expert blind-movers`` makes the demonstrations that teach a
    world model what a closing mover means, while takeovers stay with the expert that yields (``--env
    expert.yield_to_movers=false`` would make both blind)."""

    def __init__(self, env: ExpertView) -> None:
        self.expert = UGVExpert(getattr(env, "unwrapped", env), yield_to_movers=False)

    def act(self, obs: np.ndarray, deterministic: bool = False) -> np.ndarray:
        return self.expert.act()


def footprint_radius(robot: RobotConfig) -> float:
    """The radius of the three circles (centres at -L/3, 0, L/3 along the heading) that cover the footprint."""
    return math.hypot(robot.length / 6, robot.width / 2)


def footprint_centres(
    px: np.ndarray, py: np.ndarray, heading: np.ndarray, robot: RobotConfig
) -> tuple[np.ndarray, np.ndarray]:
    """x and y of the three footprint circles' centres at poses of any shape S, as S + (3,)."""
    offsets = np.array([-1.0, 0.0, 1.0]) * (robot.length / 3)
    return px[..., None] + offsets * np.cos(heading)[..., None], py[..., None] + offsets * np.sin(heading)[..., None]


def mover_distances(cx: np.ndarray, cy: np.ndarray, poses: np.ndarray, movers: Sequence[MoverPlan]) -> np.ndarray:
    """Distances (m, 0 inside) from points (P, T, C) to each mover's shape, a box or a circle, at its pose of
    the same step ((M, T, 3): x, y, yaw), as (P, M, T, C)."""
    out = np.empty((cx.shape[0], len(movers), *cx.shape[1:]))
    for i, mover in enumerate(movers):
        mx, my, myaw = (poses[i, :, j][None, :, None] for j in range(3))  # (1, T, 1)
        dx, dy = cx - mx, cy - my
        if mover.kind == "box":
            cos, sin = np.cos(myaw), np.sin(myaw)
            along = np.maximum(np.abs(cos * dx + sin * dy) - mover.length / 2, 0.0)
            across = np.maximum(np.abs(cos * dy - sin * dx) - mover.width / 2, 0.0)
            out[:, i] = np.hypot(along, across)
        else:
            out[:, i] = np.maximum(np.hypot(dx, dy) - mover.radius, 0.0)
    return out


def unicycle_poses(
    x: float, y: float, yaw: float, v: np.ndarray, w: np.ndarray, dt: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Poses after each step of (v, w) sequences (P, T), each step an exact arc as the world drives it (the
    chord at the mean heading)."""
    start = yaw + np.cumsum(w * dt, axis=1) - w * dt  # heading at each step's start
    half = 0.5 * w * dt
    chord = v * dt * np.sinc(half / np.pi)  # np.sinc(x) = sin(pi x) / (pi x): the arc's chord
    px = x + np.cumsum(chord * np.cos(start + half), axis=1)
    py = y + np.cumsum(chord * np.sin(start + half), axis=1)
    return px, py, start + 2 * half
