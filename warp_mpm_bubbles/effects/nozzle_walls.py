"""A stream's nozzle against a closed wall behind it is an opening in that wall.

The grid holds a closed wall's faces at rest, so the fluid cell under a nozzle within a cell of the
wall behind it (a pipe in the ceiling) has no inflow: the pressure solve slowed the stream leaving
it (1.08 m/s laid, 0.73-0.89 m/s moving), while the emitter kept laying layers at the stream's
speed, and the liquid piled up under the nozzle, 0.80 of its rest volume after 17 ms. Here the
wall's faces behind the nozzle carry the stream's velocity into the domain, before the solve and
again on every extrapolated field, as moving colliders' faces do (effects/colliders.py).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..core.cells import cell_type_at, is_solid, unit
from ..core.geometry import GridGeometry
from ..scene.effects import LiquidInflow

wp.set_module_options({"enable_backward": False})

# A nozzle this close to a wall behind it (in cells, along the stream) opens it: within one cell
# the stream's first cell touches the wall (measured: throttled at 0.5 and 0.7 cells, not at 1.2).
NOZZLE_REACH = 1.0


@wp.kernel
def nozzle_faces(types: wp.array3d(dtype=wp.int32), geo: GridGeometry, axis: int, centre: wp.vec3,
                 direction: wp.vec3, radius: float, speeds: wp.array(dtype=float), stream: int,
                 vel: wp.array3d(dtype=float)):
    """The faces between a solid and a fluid-side cell lying behind the nozzle (at most NOZZLE_REACH
    cells upstream of it, the stream flowing away from the solid) take the stream's velocity, in
    the share of the face the stream covers (a ramp one cell wide across its edge). Its speed is
    read from speeds[stream] (0 while it does not flow), so a captured graph stays valid."""
    i, j, k = wp.tid()
    speed = speeds[stream]
    if speed == 0.0:
        return
    hi = wp.vec3i(i, j, k)
    solid_lo = is_solid(cell_type_at(types, hi - unit(axis)))
    if solid_lo == is_solid(cell_type_at(types, hi)):
        return
    into = direction[axis]
    if not solid_lo:
        into = -into
    if into <= 0.0:
        return  # the stream does not leave this wall
    f = geo.origin + geo.dx * wp.vec3(float(i) + 0.5, float(j) + 0.5, float(k) + 0.5)
    f[axis] = geo.origin[axis] + geo.dx * float(hi[axis])
    rel = f - centre
    if geo.dim == 2:
        rel[2] = 0.0
    s = wp.dot(rel, direction)
    if s > 0.0 or s < -NOZZLE_REACH * geo.dx:
        return
    cover = wp.clamp((radius - wp.length(rel - s * direction)) / geo.dx + 0.5, 0.0, 1.0)
    if cover > 0.0:
        vel[i, j, k] = cover * speed * direction[axis]


def walled_nozzles(scene, geometry) -> list[int]:
    """The streams (emitter indices) whose nozzle lies within NOZZLE_REACH cells of a closed wall of
    the domain behind it."""
    dx, size = scene.domain.dx, scene.domain.size
    found = []
    for i, e in enumerate(scene.emitters):
        if not isinstance(e, LiquidInflow):
            continue
        back = np.asarray(e.center, float) - NOZZLE_REACH * dx * np.asarray(e.direction, float)
        if any((back[a] < 0.0 and not geometry.open_lo[a]) or (back[a] > size[a] and not geometry.open_hi[a])
               for a in range(scene.dim)):
            found.append(i)
    return found


def open_nozzles(ctx, streams, speeds, vel):
    """The wall faces behind these streams' nozzles carry their velocity (speeds: this step's, per
    stream, on the device), in the face field vel."""
    dim, dx = ctx.scene.dim, ctx.grid.dx
    for n, e in enumerate(streams):
        pad = (0.0,) * (3 - dim)
        centre = wp.vec3(*(tuple(e.center) + ((0.5 * dx,) if dim == 2 else ())))
        for a in ctx.grid.axes:
            ctx.launch(nozzle_faces, ctx.grid.face_shape(a),
                       [ctx.fields.types, ctx.geometry, a, centre, wp.vec3(*(tuple(e.direction) + pad)),
                        float(e.radius), speeds, n, vel[a]])
