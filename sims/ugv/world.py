"""The pymunk world of one episode: static walls and obstacles, movers on scripted paths, the robot.

The robot is a dynamic body with a *sensor* box shape: it is driven by setting its velocity (no
forces), so its motion is exactly the unicycle model, and any contact is reported by a ``begin``
callback as a collision (which ends the episode). Movers are kinematic bodies. Per control step
the velocity is set once, along the chord of the arc that constant (v, w) would trace, so the pose
after the physics sub-steps is the exact arc end; collisions are checked at every sub-step.

Mover poses are a pure function of time (see :meth:`sims.ugv.scenario.MoverPlan.poses`) and are
tabulated at the control instants once per episode; the lidar and the expert read the same table.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pymunk
from pymunk._chipmunk import lib as chipmunk

from sims.ugv.config import UGVConfig
from sims.ugv.lidar import NumpyLidar, PymunkLidar, box_edges_batch, oriented_box_edges, segment_table, two_sided
from sims.ugv.scenario import Layout

ROBOT_COLLISION_TYPE = 1
ROBOT_CATEGORY = 0b10
LIDAR_FILTER = pymunk.ShapeFilter(mask=pymunk.ShapeFilter.ALL_MASKS() ^ ROBOT_CATEGORY)
"""What the lidar sees: everything but the robot itself."""


class World:
    """One episode's physics; rebuilt at every reset (obstacle poses are randomised)."""

    def __init__(self, config: UGVConfig, layout: Layout, table_steps: int) -> None:
        self.config = config
        self.layout = layout
        self.dt = config.dt
        self.substep_dt = self.dt / config.physics_substeps
        self.k = 0
        """Control steps taken since the episode start (time = k * dt)."""
        self.collided = False

        space = pymunk.Space()
        space.gravity = (0.0, 0.0)
        static = space.static_body
        shapes: list[pymunk.Shape] = []
        for a, b in layout.walls:
            shapes.append(pymunk.Segment(static, a, b, 0.0))
        for box in layout.boxes:
            corners = oriented_box_edges(box.x, box.y, box.yaw, box.length, box.width)[:, 0:2]
            shapes.append(pymunk.Poly(static, [tuple(p) for p in corners]))
        for circle in layout.circles:
            shapes.append(pymunk.Circle(static, circle.radius, (circle.x, circle.y)))
        space.add(*shapes)

        robot = config.robot
        self.robot_body = pymunk.Body(1.0, 1.0)
        self.robot_shape = pymunk.Poly.create_box(self.robot_body, (robot.length, robot.width))
        self.robot_shape.sensor = True
        self.robot_shape.collision_type = ROBOT_COLLISION_TYPE
        self.robot_shape.filter = pymunk.ShapeFilter(categories=ROBOT_CATEGORY)
        space.add(self.robot_body, self.robot_shape)

        self.mover_bodies: list[pymunk.Body] = []
        for mover in layout.movers:
            body = pymunk.Body(body_type=pymunk.Body.KINEMATIC)
            shape: pymunk.Shape
            if mover.kind == "box":
                shape = pymunk.Poly.create_box(body, (mover.length, mover.width))
            else:
                shape = pymunk.Circle(body, mover.radius)
            space.add(body, shape)
            self.mover_bodies.append(body)

        self._mover_motion = [(0.0, 0.0, 0.0)] * len(self.mover_bodies)
        space.on_collision(ROBOT_COLLISION_TYPE, None, begin=self._on_contact)
        self.space = space
        self._handle = space._space  # Chipmunk's cpSpace, for the direct sub-steps in step()
        self._extend_tables(table_steps)
        self.set_robot_pose(*layout.start)
        self._place_movers(0, exact=True)

    # -- movers --------------------------------------------------------------------------------
    def _extend_tables(self, steps: int) -> None:
        """Tabulate mover poses (and their lidar geometry) at control instants 0..steps."""
        times = np.arange(steps + 1) * self.dt
        layout = self.layout
        self.mover_poses = (
            np.stack([m.poses(times) for m in layout.movers]) if layout.movers else np.zeros((0, steps + 1, 3))
        )
        box_tables = []
        for mover, poses in zip(layout.movers, self.mover_poses, strict=True):
            if mover.kind == "box":
                edges = box_edges_batch(poses, mover.length, mover.width)  # (T, 4, 4)
                box_tables.append(segment_table(edges.reshape(-1, 4)).reshape(len(poses), 4, 7))
        self.mover_segment_tables = (
            np.concatenate(box_tables, axis=1) if box_tables else np.zeros((steps + 1, 0, 7), np.float32)
        )
        circle_movers = [(m, p) for m, p in zip(layout.movers, self.mover_poses, strict=True) if m.kind == "circle"]
        self.mover_circles = (
            np.stack([np.column_stack([p[:, 0], p[:, 1], np.full(len(p), m.radius)]) for m, p in circle_movers], axis=1)
            if circle_movers
            else np.zeros((steps + 1, 0, 3))
        )
        self.table_steps = steps
        self._pose_lists = [poses.tolist() for poses in self.mover_poses]  # fast per-step indexing

    def ensure_table(self, k: int) -> None:
        """Make the mover tables reach control step ``k`` (doubling, so amortised cheap)."""
        if k > self.table_steps:
            self._extend_tables(max(k, 2 * self.table_steps))

    def _place_movers(self, k: int, exact: bool = False) -> None:
        """Send the movers from their step-k pose towards their step-(k + 1) pose during this step.

        Velocities are piecewise constant, so pymunk's integration keeps them on the table between
        changes; a body is re-placed (position, velocity, heading) only when its motion changes.
        ``exact`` puts them at pose k at rest (at reset, before any step).
        """
        if k + 1 > self.table_steps:
            self.ensure_table(k + 1)
        hz = self.config.control_hz
        for i, body in enumerate(self.mover_bodies):
            poses = self._pose_lists[i]
            x0, y0, yaw0 = poses[k]
            x1, y1, yaw1 = poses[k + 1]
            if exact:
                body.position = (x0, y0)
                body.angle = yaw0
                body.velocity = (0.0, 0.0)
                self.space.reindex_shapes_for_body(body)
                self._mover_motion[i] = (0.0, 0.0, yaw0)
                continue
            vx, vy = (x1 - x0) * hz, (y1 - y0) * hz
            last_vx, last_vy, last_yaw = self._mover_motion[i]
            if abs(vx - last_vx) + abs(vy - last_vy) > 1e-9:
                body.position = (x0, y0)
                body.velocity = (vx, vy)
            if yaw1 != last_yaw:
                # the heading of pose k + 1 from the start of the step: after it, pymunk's pose is
                # exactly the tabulated pose k + 1 (what the numpy lidar and the scene use)
                body.angle = yaw1
            self._mover_motion[i] = (vx, vy, yaw1)

    @property
    def static_segments(self) -> np.ndarray:
        """One-sided segments of the static world (box edges facing out, walls both ways), (K, 4)."""
        walls = two_sided(np.array([(*a, *b) for a, b in self.layout.walls])) if self.layout.walls else np.zeros((0, 4))
        boxes = [oriented_box_edges(b.x, b.y, b.yaw, b.length, b.width) for b in self.layout.boxes]
        return np.vstack([walls, *boxes]) if boxes else walls

    @property
    def static_circles(self) -> np.ndarray:
        return np.array([(c.x, c.y, c.radius) for c in self.layout.circles], dtype=float).reshape(-1, 3)

    # -- robot ---------------------------------------------------------------------------------
    def _on_contact(self, arbiter: pymunk.Arbiter, space: pymunk.Space, data: Any) -> None:
        self.collided = True

    def set_robot_pose(self, x: float, y: float, yaw: float) -> None:
        body = self.robot_body
        body.position = (x, y)
        body.angle = yaw
        body.velocity = (0.0, 0.0)
        body.angular_velocity = 0.0
        self.space.reindex_shapes_for_body(body)

    def robot_overlaps(self) -> bool:
        """True when the robot's footprint touches anything now (used to reject start poses)."""
        return bool(self.space.shape_query(self.robot_shape))

    def clearance_at(self, x: float, y: float, distance: float) -> bool:
        """True when nothing static or moving lies within ``distance`` of the point."""
        return not self.space.point_query((x, y), distance, LIDAR_FILTER)

    def step(self, v: float, w: float) -> tuple[float, float, float]:
        """Advance one control period with linear speed v and yaw rate w; return the new pose."""
        self._place_movers(self.k)
        body = self.robot_body
        yaw = body.angle
        half_turn = 0.5 * w * self.dt
        # chord of the arc: length v dt sinc(w dt / 2), direction yaw + w dt / 2
        chord_speed = v * (math.sin(half_turn) / half_turn if abs(half_turn) > 1e-9 else 1.0)
        heading = yaw + half_turn
        body.velocity = (chord_speed * math.cos(heading), chord_speed * math.sin(heading))
        body.angular_velocity = w
        h = self.substep_dt
        # The first sub-step goes through pymunk's wrapper (it runs deferred adds, removals and post-step
        # callbacks); the rest call Chipmunk directly, which skips ~1 µs of Python bookkeeping each.
        # Nothing is added or removed during a control step, so both paths simulate the same.
        self.space.step(h)
        handle, chipmunk_step = self._handle, chipmunk.cpSpaceStep
        for _ in range(self.config.physics_substeps - 1):
            chipmunk_step(handle, h)
        self.k += 1
        x, y = body.position
        return x, y, body.angle

    @property
    def pose(self) -> tuple[float, float, float]:
        body = self.robot_body
        x, y = body.position
        return x, y, body.angle

    @property
    def time(self) -> float:
        return self.k * self.dt


class WorldLidar:
    """The robot's lidar in one world: ``cast`` returns inverse ranges of every ray at the current step.

    A :class:`NumpyLidar` may be passed in to be reused across episodes (it keeps its buffers).
    """

    def __init__(self, world: World, caster: NumpyLidar | None = None) -> None:
        self.world = world
        config = world.config.lidar
        self.caster: NumpyLidar | PymunkLidar
        if config.backend == "pymunk":
            self.caster = PymunkLidar(config, world.space, LIDAR_FILTER)
            self._numpy = False
        else:
            caster = caster or NumpyLidar(config)
            caster.set_static(
                world.static_segments,
                world.static_circles,
                dynamic_segments=world.mover_segment_tables.shape[1],
                dynamic_circles=world.mover_circles.shape[1],
            )
            self.caster = caster
            self._numpy = True
            self._dynamic_segments = world.mover_segment_tables.shape[1] > 0
            self._dynamic_circles = world.mover_circles.shape[1] > 0

    def cast(self, x: float, y: float, yaw: float) -> np.ndarray:
        caster = self.caster
        if self._numpy:
            assert isinstance(caster, NumpyLidar)
            k = self.world.k
            self.world.ensure_table(k)
            if self._dynamic_segments:
                caster.set_dynamic_table(self.world.mover_segment_tables[k])
            if self._dynamic_circles:
                caster.set_dynamic_circles(self.world.mover_circles[k])
        return caster.cast(x, y, yaw)
