"""Small cell and face helpers every grid kernel shares: unit axes, the 2^dim block of a cell,
bounds, cell types, fill fractions, the divergence of a cell, positions of cells. Functions only
(no kernels), so this file compiles into the modules whose kernels call it, never on its own.

Face ``f`` along axis ``a`` separates cell ``f - e_a`` (its low side) and cell ``f`` (its high side).
"""

from typing import Any

import warp as wp

from .grid import EMPTY, FLUID, PHASE_LIQUID, SOLID_FREE_SLIP

HOLE_FRACTION = wp.constant(0.25)  # a particle-free cell filled past this by its neighbours' splats is no free surface


@wp.func
def unit(axis: int):
    return wp.vec3i(int(axis == 0), int(axis == 1), int(axis == 2))


@wp.func
def block_size(dim: int):
    """Cells in the 3^dim block around a cell (a 2D slab's block is 3 x 3)."""
    if dim == 3:
        return 27
    return 9


@wp.func
def block_offset(q: int, dim: int):
    """Offset q (0 <= q < block_size) of that block, in the order of loops over x, then y (, then z)."""
    if dim == 3:
        return wp.vec3i(q // 9 - 1, (q // 3) % 3 - 1, q % 3 - 1)
    return wp.vec3i(q // 3 - 1, q % 3 - 1, 0)


@wp.func
def inside(a: wp.array3d(dtype=Any), c: wp.vec3i):
    """Index c lies inside array a (any dtype: one definition per dtype used)."""
    if c[0] < 0 or c[1] < 0 or c[2] < 0:
        return False
    return c[0] < a.shape[0] and c[1] < a.shape[1] and c[2] < a.shape[2]


@wp.func
def cell_type_at(types: wp.array3d(dtype=wp.int32), c: wp.vec3i):
    """Type of cell c; outside the array counts as a free-slip solid."""
    if not inside(types, c):
        return SOLID_FREE_SLIP
    return types[c[0], c[1], c[2]]


@wp.func
def is_solid(t: int):
    return t >= SOLID_FREE_SLIP


@wp.func
def volume_fraction(cell_volume: wp.array3d(dtype=float), c: wp.vec3i, inv_cell_vol: float):
    if not inside(cell_volume, c):
        return 0.0
    return cell_volume[c[0], c[1], c[2]] * inv_cell_vol


@wp.func
def fill_fraction(
    liq_volume: wp.array3d(dtype=float), gas_volume: wp.array3d(dtype=float), two_phase: int, c: wp.vec3i,
    inv_cell_vol: float,
):
    phi = volume_fraction(liq_volume, c, inv_cell_vol)
    if two_phase != 0:
        phi += volume_fraction(gas_volume, c, inv_cell_vol)
    return phi


@wp.func
def at(a: wp.array3d(dtype=float), c: wp.vec3i):
    return a[c[0], c[1], c[2]]


@wp.func
def face_trusted(valid: wp.array3d(dtype=wp.int32), c: wp.vec3i):
    """valid[c] == 1, false for a face outside the array."""
    if not inside(valid, c):
        return False
    return valid[c[0], c[1], c[2]] == 1


@wp.func
def is_phase_cell(types: wp.array3d(dtype=wp.int32), phase: wp.array3d(dtype=wp.int32), c: wp.vec3i, which: int):
    """A fluid cell of phase `which` (cells outside the array are not)."""
    if cell_type_at(types, c) == FLUID:  # nested: Warp evaluates both sides of `and`
        if phase[c[0], c[1], c[2]] == which:
            return True
    return False


@wp.func
def cell_divergence(vel_u: wp.array3d(dtype=float), vel_v: wp.array3d(dtype=float), vel_w: wp.array3d(dtype=float),
                    c: wp.vec3i, dim: int):
    """A cell's net outflow through its faces, velocity units (div u dx): x and y, then z in 3D."""
    i, j, k = c[0], c[1], c[2]
    div = vel_u[i + 1, j, k] - vel_u[i, j, k] + vel_v[i, j + 1, k] - vel_v[i, j, k]
    if dim == 3:
        div += vel_w[i, j, k + 1] - vel_w[i, j, k]
    return div


@wp.func
def is_liquid_cell(types: wp.array3d(dtype=wp.int32), phase: wp.array3d(dtype=wp.int32), c: wp.vec3i):
    """A fluid cell on the liquid side of the interface (cells outside the array are not)."""
    return is_phase_cell(types, phase, c, PHASE_LIQUID)


@wp.func
def cell_of(x: wp.vec3, origin: wp.vec3, dx: float):
    """The index of the cell holding world position x (ghost layer included)."""
    q = (x - origin) / dx
    return wp.vec3i(int(wp.floor(q[0])), int(wp.floor(q[1])), int(wp.floor(q[2])))


@wp.func
def cell_centre(c: wp.vec3i, origin: wp.vec3, dx: float):
    """The world position of cell c's centre (the inverse of cell_of)."""
    return origin + dx * wp.vec3(float(c[0]) + 0.5, float(c[1]) + 0.5, float(c[2]) + 0.5)


@wp.func
def neighbour_kinds(types: wp.array3d(dtype=wp.int32), phase: wp.array3d(dtype=wp.int32),
                    gas_kv: wp.array3d(dtype=float), c: wp.vec3i, dim: int, two_phase: int):
    """(pinned, enclosed) of fluid cell c: pinned = 1 if a face neighbour is empty (Dirichlet p = 0);
    enclosed = 1 if every face neighbour is liquid or incompressible gas (gas_kv = 0): no surface,
    wall or compressible gas nearby to lower its rest-volume fraction legitimately (compressible gas
    expands into a gap by itself; an incompressible one cannot, like the liquid)."""
    pinned = int(0)
    enclosed = int(1)
    for a in range(dim):
        for s in range(2):
            n = c + (2 * s - 1) * unit(a)
            t = cell_type_at(types, n)
            if t == EMPTY:
                pinned = 1
            if t != FLUID:
                enclosed = 0
            elif two_phase != 0 and phase[n[0], n[1], n[2]] != PHASE_LIQUID:
                if gas_kv[n[0], n[1], n[2]] > 0.0:
                    enclosed = 0
    return wp.vec2i(pinned, enclosed)
