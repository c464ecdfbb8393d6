"""A Timed-Elastic-Band local planner for the UGV (Rösmann et al. 2017, the paper's TEB baseline).

It drives on what the robot senses (:meth:`sims.ugv.env.UGVEnv.sensing`): its odometry pose and velocity, the
mission goal and the lidar scan. It never reads the layout or the movers' scripts.

1. **Costmap.** Each scan marks the cell a ray ends in as occupied and clears the cells it passes through (ray
   tracing, as a ROS costmap's obstacle layer does), so a mover's old cells empty again once it has gone. The
   grid covers start and goal with a margin; cells never seen count as free.
2. **Global path.** Dijkstra (``scipy.sparse.csgraph``) from the goal over the 8-connected cells of the costmap,
   cells near obstacles costing more and cells inside the inflation blocked, then a descent from the robot and
   string pulling (the same path tools as the scripted expert, on the sensed map instead of the layout).
   Replanned every ``replan_every`` seconds, and at once when the path ahead runs into a newly seen obstacle.
3. **Timed elastic band.** Poses (x, y, θ) from the robot to the point ``lookahead`` metres along the path, and
   the time interval ΔT between each pair (as log ΔT, so always positive), optimised as one nonlinear
   least-squares problem by MINPACK's Levenberg-Marquardt (``scipy.optimize.leastsq``) with the analytic Jacobian
   (residuals and Jacobian compiled, :mod:`sims.ugv._teb_kernel`). Penalties, each a residual as in TEB's
   hyper-graph: non-holonomic kinematics (both headings of a
   segment make equal angles with it), forward driving, speed and yaw-rate limits, acceleration limits (from the
   current velocity on), clearance to the nearest sensed obstacle points (a hard-ish minimum and a soft
   inflation), and total time. Obstacle points are associated with each pose by a k-d tree, re-associated
   between a few outer iterations, as TEB does.
4. **Command.** The first segment's speed and yaw rate (clipped to the robot's limits). When even the optimised
   band leaves the robot's next poses too close to an obstacle, it stops and plans again next step.

Costs per control step, measured by ``bench/bench_baselines.py``: a few to a few tens of milliseconds, inside the
10 Hz budget (``--before REV`` compares it with an earlier commit's planner on the same steps: docs/speed.md).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import ndimage, optimize, sparse
from scipy.sparse import csgraph
from scipy.spatial import cKDTree

from sims.ugv import _teb_kernel
from sims.ugv.expert import Grid, extract_path

FAR = 1e3
"""Where an unused obstacle slot sits (m): far enough that its penalties are zero."""


@dataclass(frozen=True)
class TebConfig:
    """Every setting of the TEB planner (defaults: the robot of :class:`sims.ugv.config.RobotConfig`)."""

    poses: int = 10
    """Most poses in the band, the robot's own included."""
    spacing: float = 0.3
    """Distance between the band's poses when it is initialised along the path (m)."""
    lookahead: float = 2.5
    """The band ends this far along the global path (or at the goal when it is nearer) (m)."""
    min_obstacle_dist: float = 0.42
    """Clearance kept from the robot's centre to any obstacle point (m): the footprint's circumradius (0.32 m)
    plus a margin."""
    inflation_dist: float = 0.75
    """Below this clearance (m) a soft penalty pushes the band away from obstacles."""
    obstacles_per_pose: int = 4
    """Nearest obstacle points associated with each pose."""
    weight_obstacle: float = 60.0
    weight_inflation: float = 3.0
    weight_kinematics: float = 300.0
    weight_forward: float = 300.0
    weight_velocity: float = 30.0
    weight_acceleration: float = 3.0
    weight_time: float = 1.0
    acc_limit_v: float = 0.6
    """Linear acceleration limit (m/s²)."""
    acc_limit_w: float = 2.0
    """Angular acceleration limit (rad/s²)."""
    cruise_fraction: float = 0.8
    """The band's initial time intervals assume this fraction of the top speed."""
    outer_iterations: int = 2
    """Obstacle re-associations per control step."""
    max_evaluations: int = 25
    """Residual evaluations per least-squares solve (beyond the Jacobian's)."""
    grid_resolution: float = 0.1
    """Costmap cell size (m)."""
    map_margin: float = 4.0
    """The costmap covers start and goal with this margin (m)."""
    planner_inflation: float = 0.3
    """Cells closer than this to an obstacle are not traversable for the global path (m)."""
    preferred_clearance: float = 0.8
    """Clearance below which a cell costs extra for the global path (m)."""
    clearance_weight: float = 3.0
    replan_every: float = 1.0
    """Seconds between global replans (sooner when the path is blocked)."""
    cluster_gap: float = 0.25
    """Neighbouring scan points farther apart than this belong to different obstacles (m)."""
    mover_size: float = 1.0
    """Clusters larger than this (walls, rows of crates) are never tracked as movers (m)."""
    track_gate: float = 0.4
    """A cluster continues the previous scan's nearest track within this distance (m)."""
    velocity_smoothing: float = 0.4
    """Weight of the newest displacement in a track's velocity."""
    mover_speed: float = 0.15
    """Tracks slower than this are static (m/s)."""


@dataclass
class Band:
    """A timed elastic band: poses (n, 3) and the time intervals (n - 1,) between them."""

    poses: np.ndarray
    dts: np.ndarray


class Costmap:
    """Occupancy from lidar scans (marking and ray-trace clearing) on a fixed grid, in the map frame."""

    def __init__(self, x0: float, y0: float, nx: int, ny: int, res: float) -> None:
        self.x0, self.y0, self.res = x0, y0, res
        self.occupied = np.zeros((ny, nx), bool)
        self.version = 0
        """Scans folded in so far."""

    def cells(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Cell indices (iy, ix) of points (P, 2) and whether each lies on the grid."""
        return self._cells(xy[:, 0], xy[:, 1])

    def _cells(self, px: np.ndarray, py: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        ny, nx = self.occupied.shape
        ix = np.floor((px - self.x0) / self.res).astype(int)
        iy = np.floor((py - self.y0) / self.res).astype(int)
        inside = (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
        return iy, ix, inside

    def add_scan(
        self, x: float, y: float, yaw: float, angles: np.ndarray, ranges: np.ndarray, max_range: float
    ) -> None:
        res = self.res
        directions = np.column_stack([np.cos(yaw + angles), np.sin(yaw + angles)])
        # clear along each ray up to one cell short of its end
        steps = np.arange(0.0, max_range, 0.5 * res)
        along = steps[None, :] < (ranges[:, None] - res)
        # only the points each ray passes (the same products and sums as the whole rays x steps grid would take)
        ray, step = np.nonzero(along)
        iy, ix, inside = self._cells(x + directions[ray, 0] * steps[step], y + directions[ray, 1] * steps[step])
        self.occupied[iy[inside], ix[inside]] = False
        hit = ranges < max_range - 1e-6
        ends = np.array([x, y]) + directions[hit] * ranges[hit, None]
        iy, ix, inside = self.cells(ends)
        self.occupied[iy[inside], ix[inside]] = True
        self.version += 1

    def points(self) -> np.ndarray:
        """Centres of the occupied cells (P, 2)."""
        iy, ix = np.nonzero(self.occupied)
        return np.column_stack([self.x0 + (ix + 0.5) * self.res, self.y0 + (iy + 0.5) * self.res])

    def grid(self, goal: tuple[float, float, float], robot_half_width: float, cfg: TebConfig) -> Grid:
        """The navigation function to the goal over this costmap (:class:`sims.ugv.expert.Grid`)."""
        res = self.res
        ny, nx = self.occupied.shape
        clearance = ndimage.distance_transform_edt(~self.occupied) * res - 0.5 * res
        clearance = np.maximum(clearance, 0.0) if self.occupied.any() else np.full((ny, nx), 1e3)
        shortfall = np.clip((cfg.preferred_clearance - clearance) / cfg.preferred_clearance, 0.0, 1.0)
        cell_cost = 1.0 + cfg.clearance_weight * shortfall
        xs = self.x0 + (np.arange(nx) + 0.5) * res
        ys = self.y0 + (np.arange(ny) + 0.5) * res
        gx, gy = np.meshgrid(xs, ys)
        goal_dist = np.hypot(gx - goal[0], gy - goal[1])
        targets = (goal_dist <= max(goal[2], res)) & (clearance >= robot_half_width)
        if not targets.any():
            targets = goal_dist <= goal_dist.min() + 1e-9
        blocked = (clearance < cfg.planner_inflation) & ~targets
        cost_to_go = _dijkstra(cell_cost, blocked, targets, goal_dist, res)
        return Grid(self.x0, self.y0, res, clearance, cost_to_go)


def _dijkstra(
    cell_cost: np.ndarray, blocked: np.ndarray, targets: np.ndarray, goal_dist: np.ndarray, res: float
) -> np.ndarray:
    """Cost to the nearest target over the 8-connected free cells (inf where unreachable or blocked)."""
    ny, nx = cell_cost.shape
    n = ny * nx
    index = np.arange(n).reshape(ny, nx)
    free = ~blocked
    rows, cols, weights = [], [], []
    for dy, dx in ((0, 1), (1, 0), (1, 1), (1, -1)):
        ys0, ys1 = (0, ny - dy)
        xs0, xs1 = (max(0, -dx), nx - max(0, dx))
        a = index[ys0:ys1, xs0:xs1]
        b = index[ys0 + dy : ys1 + dy, xs0 + dx : xs1 + dx]
        ok = free[ys0:ys1, xs0:xs1] & free[ys0 + dy : ys1 + dy, xs0 + dx : xs1 + dx]
        step = res * (math.sqrt(2.0) if dx and dy else 1.0)
        w = step * 0.5 * (cell_cost[ys0:ys1, xs0:xs1] + cell_cost[ys0 + dy : ys1 + dy, xs0 + dx : xs1 + dx])
        rows.append(a[ok])
        cols.append(b[ok])
        weights.append(w[ok])
    # a virtual source (node n) reaches every target cell at its distance to the goal centre
    target_idx = index[targets]
    rows.append(np.full(len(target_idx), n))
    cols.append(target_idx)
    weights.append(goal_dist[targets] + 1e-6)
    graph = sparse.csr_matrix(
        (np.concatenate(weights), (np.concatenate(rows), np.concatenate(cols))), shape=(n + 1, n + 1)
    )
    dist = csgraph.dijkstra(graph, directed=False, indices=n)
    return dist[:n].reshape(ny, nx)


@functools.lru_cache(maxsize=8)
def _diamond(reach: int) -> tuple[np.ndarray, np.ndarray]:
    """Cell offsets (dy, dx) within ``reach`` 4-connected steps: what ``reach`` binary dilations by a cross add."""
    dy, dx = np.mgrid[-reach : reach + 1, -reach : reach + 1]
    keep = np.abs(dy) + np.abs(dx) <= reach
    return dy[keep], dx[keep]


class MoverTracker:
    """Moving obstacles from consecutive scans: the scan's hit points are split into clusters (neighbouring rays
    whose ends lie close together), small clusters are matched to the previous scan's by nearest centroid, and
    their velocity is the smoothed displacement of the centroid. What TEB's dynamic-obstacle mode takes as input
    (ROS gets it from costmap_converter); a static obstacle whose visible face changes may look slowly moving,
    which only ever adds predicted obstacles, never removes sensed ones."""

    def __init__(self, cfg: TebConfig, dt: float) -> None:
        self.cfg, self.dt = cfg, dt
        self._tracks: list[dict[str, Any]] = []

    def reset(self) -> None:
        self._tracks = []

    def update(self, x: float, y: float, yaw: float, angles: np.ndarray, ranges: np.ndarray, max_range: float) -> None:
        cfg = self.cfg
        order = np.argsort(angles)
        hit = ranges[order] < max_range - 1e-6
        theta = yaw + angles[order][hit]
        points = np.column_stack([x + ranges[order][hit] * np.cos(theta), y + ranges[order][hit] * np.sin(theta)])
        clusters: list[np.ndarray] = []
        if len(points):
            breaks = np.flatnonzero(np.hypot(*np.diff(points, axis=0).T) > cfg.cluster_gap) + 1
            clusters = [c for c in np.split(points, breaks) if np.ptp(c, axis=0).max(initial=0.0) <= cfg.mover_size]
        centres = [cluster.mean(axis=0) for cluster in clusters]
        nearest: list[tuple[dict[str, Any], float]] = []
        if centres and self._tracks:
            # every cluster's distance to every previous track at once; the first nearest track on a tie, as min() did
            before = np.array([track["centre"] for track in self._tracks])
            now = np.array(centres)
            gaps = np.hypot(before[None, :, 0] - now[:, None, 0], before[None, :, 1] - now[:, None, 1])
            picks = gaps.argmin(axis=1)
            nearest = [(self._tracks[k], float(gaps[i, k])) for i, k in enumerate(picks)]
        tracks = []
        for i, (cluster, centre) in enumerate(zip(clusters, centres, strict=True)):
            velocity, age = np.zeros(2), 1
            if nearest and nearest[i][1] <= cfg.track_gate:
                previous = nearest[i][0]
                measured = (centre - previous["centre"]) / self.dt
                velocity = (1 - cfg.velocity_smoothing) * previous["velocity"] + cfg.velocity_smoothing * measured
                age = previous["age"] + 1
            tracks.append({"centre": centre, "points": cluster, "velocity": velocity, "age": age})
        self._tracks = tracks

    def movers(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """(points, velocity) of the clusters that move (tracked long enough, fast enough)."""
        cfg = self.cfg
        out = []
        for track in self._tracks:
            if track["age"] >= 3 and float(np.hypot(*track["velocity"])) >= cfg.mover_speed:
                points = track["points"]
                step = max(1, len(points) // 4)
                out.append((points[::step], track["velocity"]))
        return out


@dataclass(frozen=True)
class _BandLayout:
    """Where each entry of the band's Jacobian goes, for n poses and m obstacles per pose, built once per (n, m).

    :meth:`TebOptimizer._jacobian` computes the entries term by term (the terms' order below) and adds them into the
    matrix of the free variables in one ``np.add.at``, in that order: an entry that two terms reach sums them in
    the order the term-by-term writes did, and the fixed variables' entries (the first pose, the last position) go
    to a spare column that is cut off."""

    flat: np.ndarray
    """Flat index into the (rows, free + 1) matrix of every entry, in the terms' order."""
    shape: tuple[int, int]
    """(rows, free variables + 1): the last column collects the fixed variables' entries."""


_Terms = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]
"""What residuals and Jacobian share (:meth:`TebOptimizer._terms`): segment terms, slot terms, cos, sin and dts."""


@functools.lru_cache(maxsize=64)
def _band_layout(n: int, m: int) -> _BandLayout:
    segments = n - 1
    j = np.arange(segments)
    X, Y, T, U = 3 * j, 3 * j + 1, 3 * j + 2, 3 * n + j  # full columns of pose j (pose j + 1 is + 3) and log dt_j
    p_cols = np.stack([X, X + 3, Y, Y + 3, T], axis=1)  # what progress_j depends on
    pose_x = np.repeat(3 * (j + 1)[:, None], m, axis=1)  # obstacles act on poses 1..n-1
    blocks = np.arange(7 * segments)  # kinematics, forward, speed, yaw rate, acc v, acc w, time: one row each
    kin, fwd, speed, yaw, acc_v, acc_w, time = (blocks[b * segments : (b + 1) * segments] for b in range(7))
    clearance = 7 * segments + np.arange(segments * m).reshape(segments, m)
    inflation = clearance + segments * m
    rows_cols: list[tuple[np.ndarray, np.ndarray]] = [
        (kin, X), (kin, X + 3), (kin, Y), (kin, Y + 3), (kin, T), (kin, T + 3),
        (np.repeat(fwd, 5), p_cols),
        (np.repeat(speed, 5), p_cols), (speed, U),
        (yaw, T + 3), (yaw, T), (yaw, U),
        (np.repeat(acc_v, 5), p_cols), (np.repeat(acc_v[1:], 5), p_cols[:-1]), (acc_v, U), (acc_v[1:], U[:-1]),
        (acc_w, T + 3), (acc_w, T), (acc_w[1:], T[:-1] + 3), (acc_w[1:], T[:-1]), (acc_w, U), (acc_w[1:], U[:-1]),
        (time, U),
        (clearance, pose_x), (clearance, pose_x + 1), (inflation, pose_x), (inflation, pose_x + 1),
    ]  # fmt: skip
    rows = np.concatenate([r.ravel() for r, _ in rows_cols])
    cols = np.concatenate([c.ravel() for _, c in rows_cols])
    inner = np.arange(1, n - 1)
    free = np.concatenate([np.stack([3 * inner, 3 * inner + 1], axis=1).ravel(), 3 * np.arange(1, n) + 2, U])
    spare = len(free)
    column_of = np.full(3 * n + segments, spare)
    column_of[free] = np.arange(len(free))
    shape = (7 * segments + 2 * segments * m, len(free) + 1)
    flat = rows * shape[1] + column_of[cols]
    flat.flags.writeable = False  # shared between calls
    return _BandLayout(flat, shape)


class TebOptimizer:
    """The band's least-squares problem for one obstacle association (see the module docstring).

    Variables: the x, y of the free poses 1..n-2, the headings of poses 1..n-1 (the last pose's position is the
    band's target, its heading free) and u_j = log ΔT_j (so that every interval stays positive without bounds).
    Residuals and their analytic Jacobian are written out term by term; MINPACK's Levenberg-Marquardt (``lmder``,
    through ``scipy.optimize.leastsq``) solves the small dense problem. Within a solve the terms both share are
    computed once per point (the solver asks for the residuals and then the Jacobian at each accepted point)."""

    def __init__(self, cfg: TebConfig, v_max: float, w_max: float) -> None:
        self.cfg, self.v_max, self.w_max = cfg, v_max, w_max
        weights = np.empty(_teb_kernel.WEIGHTS)
        weights[: _teb_kernel.V_MAX] = [
            math.sqrt(w)
            for w in (
                cfg.weight_kinematics, cfg.weight_forward, cfg.weight_velocity, cfg.weight_acceleration,
                cfg.weight_time, cfg.weight_obstacle, cfg.weight_inflation,
            )
        ]  # fmt: skip
        weights[_teb_kernel.V_MAX :] = [
            v_max,
            w_max,
            cfg.acc_limit_v,
            cfg.acc_limit_w,
            cfg.min_obstacle_dist,
            cfg.inflation_dist,
        ]
        self._weights = weights

    @staticmethod
    def pack(band: Band) -> np.ndarray:
        inner = band.poses[1:-1]
        return np.concatenate([inner[:, :2].ravel(), band.poses[1:, 2], np.log(band.dts)])

    @staticmethod
    def unpack(z: np.ndarray, start: np.ndarray, end_xy: np.ndarray, n: int) -> Band:
        k = n - 2
        poses = np.empty((n, 3))
        poses[0] = start
        poses[1:-1, :2] = z[: 2 * k].reshape(k, 2)
        poses[-1, :2] = end_xy
        poses[1:, 2] = z[2 * k : 2 * k + n - 1]
        return Band(poses, np.exp(z[2 * k + n - 1 :]))

    def _terms(
        self, z: np.ndarray, start: np.ndarray, end_xy: np.ndarray, n: int, v0: float, w0: float, obstacles: np.ndarray
    ) -> _Terms:
        """What residuals and Jacobian share at ``z``; the transcendental functions here, in numpy, the rest
        compiled (:mod:`sims.ugv._teb_kernel`)."""
        k = n - 2
        th = np.empty(n)
        th[0], th[1:] = start[2], z[2 * k : 2 * k + n - 1]
        c, s = np.cos(th), np.sin(th)
        dts = np.exp(z[2 * k + n - 1 :])
        segment_terms, slot_terms = _teb_kernel.band_terms(
            z, start, end_xy, float(v0), float(w0), np.ascontiguousarray(obstacles, dtype=np.float64), c, s, dts, th
        )
        return segment_terms, slot_terms, c, s, dts

    def load_kernels(self) -> None:
        """Compile the band's kernels, or load them from numba's on-disk cache (some 0.3 s; 10-15 s the first time in
        a checkout), by evaluating a small band once."""
        n = 3
        z = np.zeros(2 * (n - 2) + 2 * (n - 1))
        args = (np.zeros(3), np.ones(2), n, 0.0, 0.0, np.ones((n - 1, 1, 2)))
        self.residuals(z, *args)
        self.jacobian(z, *args)

    def residuals(
        self, z: np.ndarray, start: np.ndarray, end_xy: np.ndarray, n: int, v0: float, w0: float, obstacles: np.ndarray
    ) -> np.ndarray:
        return self._residuals(self._terms(z, start, end_xy, n, v0, w0, obstacles))

    def jacobian(
        self, z: np.ndarray, start: np.ndarray, end_xy: np.ndarray, n: int, v0: float, w0: float, obstacles: np.ndarray
    ) -> np.ndarray:
        """d residuals / d z, written out (checked against finite differences in the tests)."""
        return self._jacobian(self._terms(z, start, end_xy, n, v0, w0, obstacles), n, obstacles.shape[1])

    def _residuals(self, terms: _Terms) -> np.ndarray:
        return _teb_kernel.band_residuals(*terms, self._weights)

    def _jacobian(self, terms: _Terms, n: int, m: int) -> np.ndarray:
        layout = _band_layout(n, m)
        return _teb_kernel.band_jacobian(*terms, self._weights, layout.flat, layout.shape)[:, :-1]

    def solve(self, band: Band, v0: float, w0: float, obstacles: np.ndarray) -> tuple[Band, float]:
        """Optimise the band for fixed obstacle associations (n - 1, m, 2); returns it and its cost."""
        n, m = len(band.poses), obstacles.shape[1]
        start, end_xy = band.poses[0].copy(), band.poses[-1, :2].copy()
        last: dict[str, Any] = {"z": b""}

        def terms(z: np.ndarray) -> _Terms:
            key = z.tobytes()  # the very bits: a point the solver asks for again
            if key != last["z"]:
                last.clear()
                last["z"], last["terms"] = key, self._terms(z, start, end_xy, n, v0, w0, obstacles)
            return last["terms"]

        def residuals(z: np.ndarray) -> np.ndarray:
            t = terms(z)
            if "residuals" not in last:
                last["residuals"] = self._residuals(t)
            return last["residuals"]

        def jacobian(z: np.ndarray) -> np.ndarray:
            t = terms(z)
            if "jacobian" not in last:
                last["jacobian"] = self._jacobian(t, n, m)
            return last["jacobian"]

        # what least_squares(method="lm") asked of MINPACK before (its tolerances, its factor, its scaling by the
        # Jacobian's columns), without its wrappers' per-call copies and checks. full_output (for the final fvec) also
        # makes leastsq form the covariance, unused here, which overflows on an ill-conditioned band: not a warning
        with np.errstate(over="ignore", invalid="ignore"):
            x, _cov, info, _message, _status = optimize.leastsq(
                residuals,
                self.pack(band),
                Dfun=jacobian,
                full_output=True,
                ftol=1e-8,
                xtol=1e-8,
                gtol=1e-8,
                maxfev=self.cfg.max_evaluations,
                factor=100.0,
            )
        fvec = info["fvec"]
        return self.unpack(x, start, end_xy, n), float(0.5 * np.dot(fvec, fvec))


class TebPlanner:
    """The TEB planner as a :class:`core.loop.Policy` for one UGV env (``make_planner("teb", env)``)."""

    def __init__(self, env: Any, config: TebConfig | None = None) -> None:
        self.env = env
        self.cfg = config or TebConfig()
        sim = env.unwrapped
        robot = sim.config.robot
        self.v_max, self.w_max = robot.v_max, robot.w_max
        self.half_width = robot.width / 2
        self.dt = sim.config.dt
        self.optimizer = TebOptimizer(self.cfg, self.v_max, self.w_max)
        self.optimizer.load_kernels()  # here, not in the first control step
        self.tracker = MoverTracker(self.cfg, self.dt)
        self._episode = None
        self.costmap: Costmap | None = None
        self.grid: Grid | None = None
        self.path: np.ndarray | None = None
        self.band: Band | None = None
        self._last_plan = -math.inf
        self._t = 0.0
        self.stats: dict[str, float] = {}

    # -- episode ---------------------------------------------------------------------------------
    def _new_episode(self, sensing: Any) -> None:
        cfg = self.cfg
        x, y, _ = sensing.pose
        gx, gy, _ = sensing.goal
        x0, y0 = min(x, gx) - cfg.map_margin, min(y, gy) - cfg.map_margin
        x1, y1 = max(x, gx) + cfg.map_margin, max(y, gy) + cfg.map_margin
        res = cfg.grid_resolution
        self.costmap = Costmap(x0, y0, math.ceil((x1 - x0) / res), math.ceil((y1 - y0) / res), res)
        self.grid = self.path = self.band = None
        self.tracker.reset()
        self._last_plan = -math.inf
        self._t = 0.0

    # -- acting ----------------------------------------------------------------------------------
    def act(self, obs: np.ndarray, deterministic: bool = True) -> np.ndarray:
        sim = self.env.unwrapped
        sensing = sim.sensing()
        if self._episode != sim.episode or self.costmap is None:
            self._episode = sim.episode
            self._new_episode(sensing)
        assert self.costmap is not None
        x, y, yaw = sensing.pose
        self.costmap.add_scan(x, y, yaw, sensing.ray_angles, sensing.ranges, sensing.max_range)
        self.tracker.update(x, y, yaw, sensing.ray_angles, sensing.ranges, sensing.max_range)
        self._t += self.dt
        if self.path is None or self._t - self._last_plan >= self.cfg.replan_every or self._path_blocked(x, y):
            self._plan(sensing)
        v, w = self._command(sensing)
        return np.array([2.0 * v / self.v_max - 1.0, w / self.w_max], np.float32)

    def _plan(self, sensing: Any) -> None:
        assert self.costmap is not None
        self.grid = self.costmap.grid(sensing.goal, self.half_width, self.cfg)
        x, y, _ = sensing.pose
        gx, gy, _ = sensing.goal
        path = extract_path(self.grid, (x, y), (gx, gy), self.cfg.planner_inflation)
        self.path = None if path is None else path.xy
        self._last_plan = self._t

    def _path_blocked(self, x: float, y: float) -> bool:
        """Whether the path's next few metres now pass inside the inflation of a sensed obstacle."""
        if self.path is None or self.costmap is None:
            return True
        ahead = self._path_ahead(x, y, 3.0)
        iy, ix, inside = self.costmap.cells(ahead)
        if not inside.any():
            return False
        # the path's cells past the first three against the occupied cells dilated by the inflation (a cross
        # dilated `reach` times: the cells within `reach` steps), looked up around those cells only
        iy, ix = iy[inside][3:], ix[inside][3:]
        occupied = self.costmap.occupied
        dy, dx = _diamond(max(1, int(self.cfg.planner_inflation / self.costmap.res)))
        yy, xx = iy[:, None] + dy, ix[:, None] + dx
        on_grid = (yy >= 0) & (yy < occupied.shape[0]) & (xx >= 0) & (xx < occupied.shape[1])
        return bool(occupied[yy[on_grid], xx[on_grid]].any())

    def _path_ahead(self, x: float, y: float, length: float) -> np.ndarray:
        assert self.path is not None
        i = int(np.argmin(np.hypot(self.path[:, 0] - x, self.path[:, 1] - y)))
        seg = np.hypot(*np.diff(self.path[i:], axis=0).T)
        s = np.concatenate([[0.0], np.cumsum(seg)])
        return self.path[i:][s <= length]

    def _initial_band(self, sensing: Any) -> Band:
        cfg = self.cfg
        x, y, yaw = sensing.pose
        gx, gy, _ = sensing.goal
        if self.path is None or len(self.path) < 2:
            route = np.array([[x, y], [gx, gy]])
        else:
            route = np.vstack([[x, y], self._path_ahead(x, y, cfg.lookahead + 1.0)])
        seg = np.hypot(*np.diff(route, axis=0).T)
        s = np.concatenate([[0.0], np.cumsum(seg)])
        length = min(cfg.lookahead, float(s[-1]))
        n = int(np.clip(math.ceil(length / cfg.spacing) + 1, 3, cfg.poses))
        at = np.linspace(0.0, max(length, 1e-3), n)
        xy = np.column_stack([np.interp(at, s, route[:, 0]), np.interp(at, s, route[:, 1])])
        heading = np.arctan2(np.diff(xy[:, 1]), np.diff(xy[:, 0]))
        th = np.concatenate([[yaw], heading])
        # unwrap the headings from the robot's, so the band turns the short way
        th = yaw + np.concatenate([[0.0], np.cumsum((np.diff(th) + math.pi) % (2 * math.pi) - math.pi)])
        step = np.hypot(*np.diff(xy, axis=0).T)
        turns = np.abs(np.diff(th))
        dts = np.maximum(step / (cfg.cruise_fraction * self.v_max), turns / (0.8 * self.w_max))
        return Band(np.column_stack([xy, th]), np.maximum(dts, 0.05))

    def _associate(
        self, band: Band, tree: cKDTree | None, points: np.ndarray, movers: list[tuple[np.ndarray, np.ndarray]]
    ) -> np.ndarray:
        """The nearest obstacle points of each pose 1..n-1: sensed ones, and movers' points predicted (constant
        velocity) to the time the band reaches that pose."""
        m = self.cfg.obstacles_per_pose
        n = len(band.poses)
        xy = band.poses[1:, :2]
        candidates = np.full((n - 1, m, 2), FAR)
        if tree is not None:
            dist, idx = tree.query(xy, k=m, distance_upper_bound=2.0 * self.cfg.inflation_dist)
            dist, idx = np.asarray(dist).reshape(n - 1, m), np.asarray(idx).reshape(n - 1, m)
            found = np.isfinite(dist)
            candidates[found] = points[idx[found]]
        if not movers:
            return candidates
        times = np.cumsum(band.dts)  # arrival time at poses 1..n-1
        predicted = [cluster[None, :, :] + times[:, None, None] * velocity for cluster, velocity in movers]
        pool = np.concatenate([candidates, *predicted], axis=1)  # (n - 1, m + P, 2)
        nearest = np.argsort(np.linalg.norm(pool - xy[:, None, :], axis=2), axis=1)[:, :m]
        return np.take_along_axis(pool, nearest[..., None], axis=1)

    def _command(self, sensing: Any) -> tuple[float, float]:
        assert self.costmap is not None
        cfg = self.cfg
        x, y, yaw = sensing.pose
        v0, w0 = sensing.velocity
        points = self.costmap.points()
        near = points[np.hypot(points[:, 0] - x, points[:, 1] - y) < cfg.lookahead + 2.0 * cfg.inflation_dist]
        tree = cKDTree(near) if len(near) else None
        movers = self.tracker.movers()
        band = self._initial_band(sensing)
        for _ in range(cfg.outer_iterations):
            band, _cost = self.optimizer.solve(band, v0, w0, self._associate(band, tree, near, movers))
        self.band = band
        obstacles = self._associate(band, tree, near, movers)[:2]
        clear = float(np.linalg.norm(obstacles - band.poses[1:3, None, :2], axis=2).min())
        if clear < 0.75 * cfg.min_obstacle_dist:
            self.stats["stops"] = self.stats.get("stops", 0.0) + 1.0
            return 0.0, 0.0
        d = band.poses[1, :2] - band.poses[0, :2]
        progress = math.cos(yaw) * d[0] + math.sin(yaw) * d[1]
        turn = (band.poses[1, 2] - band.poses[0, 2] + math.pi) % (2 * math.pi) - math.pi
        dt0 = float(band.dts[0])
        v = min(max(progress / dt0, 0.0), self.v_max)
        w = min(max(turn / dt0, -self.w_max), self.w_max)
        return v, w
