"""The grid's geometry as one Warp struct, passed to the particle kernels instead of loose scalars
(so two same-typed arguments cannot be swapped silently)."""

import warp as wp


@wp.struct
class GridGeometry:
    origin: wp.vec3  # world position of ghost cell (0, 0, 0)'s lower corner, m
    dx: float  # cell size, m
    dim: int  # 2 or 3 (a 2D run is a slab one cell thick)
    domain_hi: wp.vec3  # the domain's upper corner, m (its lower corner is 0)
    gravity: wp.vec3  # m/s^2 (z = 0 in 2D)
    up_axis: int  # the axis against the strongest gravity component; -1 without gravity
    up_sign: int  # +1 if "up" is +up_axis, -1 if it is -up_axis
    open_lo: wp.vec3i  # 1 where the wall on an axis' low side is open (an outflow), else 0
    open_hi: wp.vec3i  # the same for the high side


def grid_geometry(grid, gravity, up, open_lo=(0, 0, 0), open_hi=(0, 0, 0)) -> GridGeometry:
    """The struct of a MacGrid with gravity (3 floats), up ((axis, sign)) and which walls are open
    (1 per axis on the low and the high side)."""
    geo = GridGeometry()
    geo.origin = wp.vec3(*grid.origin)
    geo.dx = float(grid.dx)
    geo.dim = int(grid.dim)
    geo.domain_hi = wp.vec3(*grid.domain_size)
    geo.gravity = wp.vec3(*gravity)
    geo.up_axis, geo.up_sign = int(up[0]), int(up[1])
    geo.open_lo, geo.open_hi = wp.vec3i(*open_lo), wp.vec3i(*open_hi)
    return geo
