"""Colliders: analytic solid shapes (sphere, box, cylinder, an open glass), static or moving.

The grid sees a collider as solid cells: a cell whose centre is inside the shape becomes
SOLID_NO_SLIP or SOLID_FREE_SLIP, exactly like a domain wall, so the pressure solve needs nothing
new. A moving collider also gives the faces it touches its velocity (the pressure solve then
pushes the liquid aside). Particles that end a step inside a shape are moved to its surface and
lose the velocity that points into it: no particle stays inside a collider.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..core.geometry import GridGeometry
from ..core.grid import ACTIVE, SOLID_FREE_SLIP, SOLID_NO_SLIP
from ..core.stage import Stage
from ..core.cells import cell_centre, unit
from ..core.transfer_kernels import clamp_to_domain

wp.set_module_options({"enable_backward": False})

SPHERE, BOX, CYLINDER, GLASS = 0, 1, 2, 3
KINDS = {"sphere": SPHERE, "box": BOX, "cylinder": CYLINDER, "glass": GLASS}
FAR = 1.0e6  # metres: "unbounded" for the axes a 2D scene does not have
GRID_MARGIN = wp.constant(0.01)  # cells: how much the grid's view of a collider is grown


@wp.struct
class Shape:
    kind: int
    center: wp.vec3  # at time 0 (glass: the centre of its bottom)
    half: wp.vec3  # box half extents
    radius: float
    half_length: float  # cylinder
    height: float  # glass
    thickness: float  # glass wall and bottom
    axis: int  # cylinder and glass (the glass opens towards +axis)
    velocity: wp.vec3  # at the start time
    acceleration: wp.vec3
    start: float
    stop: float
    no_slip: int


@wp.func
def shape_center(s: Shape, t: float):
    tau = wp.clamp(t, s.start, s.stop) - s.start
    return s.center + s.velocity * tau + 0.5 * tau * tau * s.acceleration


@wp.func
def shape_velocity(s: Shape, t: float):
    if t >= s.start and t < s.stop:
        return s.velocity + (t - s.start) * s.acceleration
    return wp.vec3(0.0)


@wp.func
def capped_cylinder(d: wp.vec3, axis: int, radius: float, half_length: float):
    """Signed distance to a cylinder centred at d = 0 along `axis`."""
    along = d[axis]
    radial = d
    radial[axis] = 0.0
    a = wp.length(radial) - radius
    b = wp.abs(along) - half_length
    return wp.min(wp.max(a, b), 0.0) + wp.length(wp.vec2(wp.max(a, 0.0), wp.max(b, 0.0)))


@wp.func
def signed_distance(s: Shape, x: wp.vec3, t: float, dim: int):
    """Negative inside the shape at time t. 2D scenes ignore z (shapes are prisms along z)."""
    d = x - shape_center(s, t)
    if dim == 2:
        d[2] = 0.0
    if s.kind == SPHERE:
        return wp.length(d) - s.radius
    if s.kind == BOX:
        q = wp.vec3(wp.abs(d[0]) - s.half[0], wp.abs(d[1]) - s.half[1], wp.abs(d[2]) - s.half[2])
        outside = wp.vec3(wp.max(q[0], 0.0), wp.max(q[1], 0.0), wp.max(q[2], 0.0))
        return wp.length(outside) + wp.min(wp.max(q[0], wp.max(q[1], q[2])), 0.0)
    if s.kind == CYLINDER:
        return capped_cylinder(d, s.axis, s.radius, s.half_length)
    # Glass: a solid cylinder minus a cavity that starts above the bottom and runs past the rim.
    up = unit(s.axis)
    h = s.height
    outer = capped_cylinder(d - 0.5 * h * wp.vec3(float(up[0]), float(up[1]), float(up[2])), s.axis, s.radius,
                            0.5 * h)
    lo = s.thickness
    hi = h + s.radius
    cavity = capped_cylinder(d - 0.5 * (lo + hi) * wp.vec3(float(up[0]), float(up[1]), float(up[2])), s.axis,
                             s.radius - s.thickness, 0.5 * (hi - lo))
    return wp.max(outer, -cavity)


@wp.func
def nearest_collider(shapes: wp.array(dtype=Shape), x: wp.vec3, t: float, dim: int, margin: float):
    """(index, distance) of the shape x is deepest inside (grown by margin), or (-1, +) if none."""
    best = int(-1)
    dist = float(FAR)
    for c in range(shapes.shape[0]):
        d = signed_distance(shapes[c], x, t, dim)
        if d < margin and d < dist:
            best = c
            dist = d
    return wp.vec2(float(best), dist)


@wp.kernel
def mark_collider_cells(
    shapes: wp.array(dtype=Shape),
    t: float,
    geo: GridGeometry,
    types: wp.array3d(dtype=wp.int32),
    collider_of_cell: wp.array3d(dtype=wp.int32),
):
    """A cell whose centre is inside a collider is solid (no-slip or free-slip as the collider says).

    The shapes are grown by GRID_MARGIN cells here, so a wall one cell thick covers at least one
    cell centre however it lies on the grid (a wall exactly between two centres would otherwise
    cover none).
    """
    origin = geo.origin
    dx = geo.dx
    dim = geo.dim
    i, j, k = wp.tid()
    x = cell_centre(wp.vec3i(i, j, k), origin, dx)
    hit = nearest_collider(shapes, x, t, dim, GRID_MARGIN * dx)
    c = int(hit[0])
    collider_of_cell[i, j, k] = c
    if c >= 0:
        if shapes[c].no_slip != 0:
            types[i, j, k] = SOLID_NO_SLIP
        else:
            types[i, j, k] = SOLID_FREE_SLIP


@wp.kernel
def moving_collider_faces(
    shapes: wp.array(dtype=Shape),
    collider_of_cell: wp.array3d(dtype=wp.int32),
    t: float,
    axis: int,
    vel: wp.array3d(dtype=float),
):
    """Faces touching a collider cell move with it: its normal velocity is the boundary condition."""
    i, j, k = wp.tid()
    hi = wp.vec3i(i, j, k)
    lo = hi - unit(axis)
    c = int(-1)
    if hi[axis] < collider_of_cell.shape[axis]:
        c = collider_of_cell[hi[0], hi[1], hi[2]]
    if c < 0 and lo[axis] >= 0:
        c = collider_of_cell[lo[0], lo[1], lo[2]]
    if c >= 0:
        vel[i, j, k] = shape_velocity(shapes[c], t)[axis]


@wp.kernel
def push_out_of_colliders(
    shapes: wp.array(dtype=Shape),
    t: float,
    geo: GridGeometry,
    active: wp.array(dtype=wp.int32),
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
):
    """A particle inside a collider moves to its surface (along the distance gradient) and keeps
    only the velocity, relative to the collider, that does not point into it."""
    dx = geo.dx
    dim = geo.dim
    domain_hi = geo.domain_hi
    p = wp.tid()
    if active[p] != ACTIVE:
        return
    xp = x[p]
    for _ in range(2):  # a second pass for a particle pushed from one collider into another
        hit = nearest_collider(shapes, xp, t, dim, 0.0)
        c = int(hit[0])
        if c >= 0:
            s = shapes[c]
            h = 1.0e-3 * dx
            n = wp.vec3(0.0)
            for a in range(dim):
                e = wp.vec3(0.0)
                e[a] = h
                n[a] = signed_distance(s, xp + e, t, dim) - signed_distance(s, xp - e, t, dim)
            if wp.length(n) > 0.0:
                n = wp.normalize(n)
                xp = clamp_to_domain(xp + (1.0e-3 * dx - hit[1]) * n, domain_hi, dx, dim)
                vs = shape_velocity(s, t)
                rel = v[p] - vs
                vn = wp.dot(rel, n)
                if vn < 0.0:
                    v[p] = vs + rel - vn * n
    x[p] = xp


@wp.kernel
def inside_any_collider(shapes: wp.array(dtype=Shape), x: wp.array(dtype=wp.vec3), t: float, dim: int,
                        inside: wp.array(dtype=wp.int32)):
    p = wp.tid()
    inside[p] = wp.where(nearest_collider(shapes, x[p], t, dim, 0.0)[0] >= 0.0, 1, 0)


def _shape(collider, dim: int) -> Shape:
    pad = lambda v, fill: tuple(v) + (fill,) * (3 - dim)  # noqa: E731
    s = Shape()
    s.kind = KINDS[collider.type]
    s.center = wp.vec3(*pad(collider.center, 0.0))
    half = [0.5 * a for a in collider.size] if collider.size is not None else [0.0] * dim
    s.half = wp.vec3(*pad(half, FAR))
    s.radius = float(collider.radius or 0.0)
    s.half_length = 0.5 * float(collider.length) if collider.length is not None else FAR
    s.height = float(collider.height or 0.0)
    s.thickness = float(collider.wall_thickness or 0.0)
    s.axis = "xyz".index(collider.axis)
    s.velocity = wp.vec3(*pad(collider.velocity, 0.0))
    s.acceleration = wp.vec3(*pad(collider.acceleration, 0.0))
    s.start = float(collider.start)
    s.stop = float(collider.stop) if collider.stop is not None else 1.0e30
    s.no_slip = int(collider.boundary == "no_slip")
    return s


class ColliderStage(Stage):
    """[[colliders]] on the device: solid cells after the cells are classified, moving colliders'
    velocities on their faces (and again on every extended field), particles pushed out last."""

    name = "colliders"

    def __init__(self, ctx, settings=None):
        super().__init__(ctx, settings)
        self.dim = ctx.grid.dim
        self.colliders = ctx.scene.colliders
        self.shapes = wp.array([_shape(c, self.dim) for c in self.colliders], dtype=Shape, device=ctx.device)
        self.moving = any(c.moves for c in self.colliders)
        self.collider_of_cell = wp.zeros(ctx.grid.cells, dtype=wp.int32, device=ctx.device)

    def hooks(self) -> set[str]:
        hooks = super().hooks()
        if not self.moving:  # a static collider's faces are walls: the grid's zero already holds
            hooks -= {"on_faces", "on_extended"}
        return hooks

    def incoming_speed(self, t0: float, t1: float) -> float:
        return max(c.speed_between(t0, t1) for c in self.colliders)

    def inside(self, ctx, positions: np.ndarray, t: float = 0.0) -> np.ndarray:
        """Which of these points are inside a collider at time t (seeding drops them)."""
        x = wp.array(np.asarray(positions, np.float32), dtype=wp.vec3, device=ctx.device)
        out = wp.zeros(len(positions), dtype=wp.int32, device=ctx.device)
        ctx.launch(inside_any_collider, len(positions), [self.shapes, x, t, self.dim, out])
        return out.numpy().astype(bool)

    def on_cells(self, ctx, dt: float):
        g = ctx.grid
        ctx.launch(mark_collider_cells, g.cells,
                   [self.shapes, ctx.time, ctx.geometry, ctx.fields.types, self.collider_of_cell])

    def on_faces(self, ctx, dt: float):
        self.on_extended(ctx, ctx.fields.vel)

    def on_extended(self, ctx, vel):
        """Moving colliders' velocity on the faces they touch, of this face field."""
        for a in ctx.grid.axes:
            ctx.launch(moving_collider_faces, ctx.grid.face_shape(a),
                       [self.shapes, self.collider_of_cell, ctx.time, a, vel[a]])

    def end_step(self, ctx, dt: float):
        p = ctx.particles
        ctx.launch(push_out_of_colliders, p.count,
                   [self.shapes, ctx.time + dt, ctx.geometry, p.active, p.x, p.v])
