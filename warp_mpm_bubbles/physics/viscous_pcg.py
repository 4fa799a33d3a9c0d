"""The implicit viscous solve's PCG kernels (physics/viscous_solve.py, ViscousSolver.implicit): the
vector updates and the symmetric Gauss-Seidel preconditioner of each velocity component's block.

Each kernel walks a line of faces per thread (core/lines.py; on a GPU one face), stepping the
indices itself, and writes only the faces it walks, so a launch may run in slabs along x. A dot
product is summed along each line and added to the row of the line's plane of x in `dots`
(planes x 3, float64); the host adds the rows in plane order, so the sums do not depend on the
slabs and are deterministic on the CPU.
"""

from __future__ import annotations

import warp as wp

from ..core.cells import inside, unit
from ..core.lines import Lines, line_end, line_first

wp.set_module_options({"enable_backward": False})

RED, BLACK = 0, 1  # the faces' colours, the parity of i + j + k
OPERATOR, RHS, EXPLICIT = 0, 1, 2  # face_operator's modes (physics/viscous_solve.py)


@wp.func
def value_at(x: wp.array3d(dtype=float), g: wp.vec3i):
    """x[g], 0 outside the array."""
    if not inside(x, g):
        return 0.0
    return x[g[0], g[1], g[2]]


@wp.struct
class AroundFace:
    """A quantity around the faces along one axis a: on the cells (the two beside a face), and on the
    edges of the planes through a, across axis b1 and, in 3D, b2 (b2 = -1 in 2D: no second plane)."""

    cells: wp.array3d(dtype=float)
    edges_1: wp.array3d(dtype=float)
    b1: int
    edges_2: wp.array3d(dtype=float)
    b2: int


@wp.kernel
def pcg_start(walk: Lines, b: wp.array3d(dtype=float), diag: wp.array3d(dtype=float), x: wp.array3d(dtype=float),
              r: wp.array3d(dtype=float), d: wp.array3d(dtype=float), dots: wp.array2d(dtype=wp.float64)):
    """x = 0, r = b, d = M^-1 r; dots[1] += r . r, dots[2] += r . d."""
    ti, tj, tk = wp.tid()
    first = line_first(walk, ti, tj, tk)
    s0 = first[walk.axis]
    a1 = int(walk.axis == 1)
    a2 = int(walk.axis == 2)
    acc1 = wp.float64(0.0)
    acc2 = wp.float64(0.0)
    for line_s in range(s0, line_end(walk, first)):
        i = first[0]
        j = first[1] + (line_s - s0) * a1
        k = first[2] + (line_s - s0) * a2
        res = b[i, j, k]
        z = float(0.0)
        if diag[i, j, k] > 0.0:
            z = res / diag[i, j, k]
        x[i, j, k] = 0.0
        r[i, j, k] = res
        d[i, j, k] = z
        acc1 += wp.float64(res * res)
        acc2 += wp.float64(res * z)
    wp.atomic_add(dots, first[0], 1, acc1)
    wp.atomic_add(dots, first[0], 2, acc2)


@wp.kernel
def pcg_step(walk: Lines, alpha: float, d: wp.array3d(dtype=float), Ad: wp.array3d(dtype=float), diag: wp.array3d(dtype=float),
             x: wp.array3d(dtype=float), r: wp.array3d(dtype=float), z: wp.array3d(dtype=float),
             dots: wp.array2d(dtype=wp.float64)):
    """x += alpha d, r -= alpha A d, z = M^-1 r; dots[1] += r . r, dots[2] += r . z."""
    ti, tj, tk = wp.tid()
    first = line_first(walk, ti, tj, tk)
    s0 = first[walk.axis]
    a1 = int(walk.axis == 1)
    a2 = int(walk.axis == 2)
    acc1 = wp.float64(0.0)
    acc2 = wp.float64(0.0)
    for line_s in range(s0, line_end(walk, first)):
        i = first[0]
        j = first[1] + (line_s - s0) * a1
        k = first[2] + (line_s - s0) * a2
        x[i, j, k] = alpha * d[i, j, k] + x[i, j, k]
        res = r[i, j, k] - alpha * Ad[i, j, k]
        zz = float(0.0)
        if diag[i, j, k] > 0.0:
            zz = res / diag[i, j, k]
        r[i, j, k] = res
        z[i, j, k] = zz
        acc1 += wp.float64(res * res)
        acc2 += wp.float64(res * zz)
    wp.atomic_add(dots, first[0], 1, acc1)
    wp.atomic_add(dots, first[0], 2, acc2)


@wp.func
def colour_start(walk: Lines, first: wp.vec3i, colour: int):
    """The first index along the line from `first` of a face of `colour` (the parity of i + j + k)."""
    return first[walk.axis] + (first[0] + first[1] + first[2] + colour) % 2


@wp.kernel
def pcg_update(walk: Lines, alpha: float, d: wp.array3d(dtype=float), Ad: wp.array3d(dtype=float),
               diag: wp.array3d(dtype=float), x: wp.array3d(dtype=float), r: wp.array3d(dtype=float),
               z: wp.array3d(dtype=float), dots: wp.array2d(dtype=wp.float64)):
    """x += alpha d, r -= alpha A d; dots[1] += r . r; and the symmetric Gauss-Seidel sweep's first
    half-sweep: z = r / diag on the red faces (its black neighbours start at 0), 0 off the unknowns."""
    ti, tj, tk = wp.tid()
    first = line_first(walk, ti, tj, tk)
    s0 = first[walk.axis]
    a1 = int(walk.axis == 1)
    a2 = int(walk.axis == 2)
    acc = wp.float64(0.0)
    for line_s in range(s0, line_end(walk, first)):
        i = first[0]
        j = first[1] + (line_s - s0) * a1
        k = first[2] + (line_s - s0) * a2
        x[i, j, k] = alpha * d[i, j, k] + x[i, j, k]
        res = r[i, j, k] - alpha * Ad[i, j, k]
        r[i, j, k] = res
        acc += wp.float64(res * res)
        if (i + j + k) % 2 == RED:
            zz = float(0.0)
            if diag[i, j, k] > 0.0:
                zz = res / diag[i, j, k]
            z[i, j, k] = zz
    wp.atomic_add(dots, first[0], 1, acc)


@wp.func
def block_neighbours(mu: AroundFace, z: wp.array3d(dtype=float), f: wp.vec3i, a: int):
    """sum over the faces n that face f couples to in its own component's block, of -A_fn z_n dx^2/dt:
    along a through the cell between them (2 mu_c), across b through the edge between them (mu_e).
    The faces that are not unknowns hold z = 0 (a wall's mirror face among them: its weight, 0 in
    A, does not matter)."""
    ua = unit(a)
    s = 2.0 * (value_at(mu.cells, f) * value_at(z, f + ua) + value_at(mu.cells, f - ua) * value_at(z, f - ua))
    u1 = unit(mu.b1)
    s += value_at(mu.edges_1, f + u1) * value_at(z, f + u1) + value_at(mu.edges_1, f) * value_at(z, f - u1)
    if mu.b2 >= 0:
        u2 = unit(mu.b2)
        s += value_at(mu.edges_2, f + u2) * value_at(z, f + u2) + value_at(mu.edges_2, f) * value_at(z, f - u2)
    return s


@wp.kernel
def sgs_sweep(walk: Lines, colour: int, a: int, scale: float, mu: AroundFace, diag: wp.array3d(dtype=float),
              r: wp.array3d(dtype=float), z: wp.array3d(dtype=float), dots: wp.array2d(dtype=wp.float64)):
    """A Gauss-Seidel half-sweep of z = M^-1 r over the faces of axis a of one colour (scale =
    dt / dx^2; diag = 0: not an unknown, z = 0); dots[2] += r . z over them."""
    ti, tj, tk = wp.tid()
    first = line_first(walk, ti, tj, tk)
    s0 = first[walk.axis]
    a1 = int(walk.axis == 1)
    a2 = int(walk.axis == 2)
    acc = wp.float64(0.0)
    for line_s in range(colour_start(walk, first, colour), line_end(walk, first), 2):
        i = first[0]
        j = first[1] + (line_s - s0) * a1
        k = first[2] + (line_s - s0) * a2
        f = wp.vec3i(i, j, k)
        dd = diag[i, j, k]
        zz = float(0.0)
        if dd > 0.0:
            res = r[i, j, k]
            zz = (res + scale * block_neighbours(mu, z, f, a)) / dd
            acc += wp.float64(res * zz)
        z[i, j, k] = zz
    wp.atomic_add(dots, first[0], 2, acc)


@wp.kernel
def pcg_direction(walk: Lines, z: wp.array3d(dtype=float), beta: float, d: wp.array3d(dtype=float)):
    ti, tj, tk = wp.tid()
    first = line_first(walk, ti, tj, tk)
    s0 = first[walk.axis]
    a1 = int(walk.axis == 1)
    a2 = int(walk.axis == 2)
    for line_s in range(s0, line_end(walk, first)):
        i = first[0]
        j = first[1] + (line_s - s0) * a1
        k = first[2] + (line_s - s0) * a2
        d[i, j, k] = z[i, j, k] + beta * d[i, j, k]


@wp.kernel
def add_into(walk: Lines, delta: wp.array3d(dtype=float), vel: wp.array3d(dtype=float)):
    ti, tj, tk = wp.tid()
    first = line_first(walk, ti, tj, tk)
    s0 = first[walk.axis]
    a1 = int(walk.axis == 1)
    a2 = int(walk.axis == 2)
    for line_s in range(s0, line_end(walk, first)):
        i = first[0]
        j = first[1] + (line_s - s0) * a1
        k = first[2] + (line_s - s0) * a2
        vel[i, j, k] = vel[i, j, k] + delta[i, j, k]


@wp.kernel
def guess_start(walk: Lines, c1: float, c2: float, inv_rho: wp.array3d(dtype=float), b: wp.array3d(dtype=float),
                x: wp.array3d(dtype=float), previous: wp.array3d(dtype=float), dots: wp.array2d(dtype=wp.float64)):
    """x = c1 x - c2 previous on the unknown faces, 0 elsewhere (the last two solves' changes
    extrapolated to this step), and previous = the last change; dots[2] += b . x."""
    ti, tj, tk = wp.tid()
    first = line_first(walk, ti, tj, tk)
    s0 = first[walk.axis]
    a1 = int(walk.axis == 1)
    a2 = int(walk.axis == 2)
    acc = wp.float64(0.0)
    for line_s in range(s0, line_end(walk, first)):
        i = first[0]
        j = first[1] + (line_s - s0) * a1
        k = first[2] + (line_s - s0) * a2
        last = x[i, j, k]
        v = float(0.0)
        if inv_rho[i, j, k] > 0.0:
            v = c1 * last - c2 * previous[i, j, k]
        previous[i, j, k] = last
        x[i, j, k] = v
        acc += wp.float64(b[i, j, k] * v)
    wp.atomic_add(dots, first[0], 2, acc)


@wp.kernel
def pcg_restart(walk: Lines, gamma: float, b: wp.array3d(dtype=float), Ax: wp.array3d(dtype=float),
                diag: wp.array3d(dtype=float), x: wp.array3d(dtype=float), r: wp.array3d(dtype=float),
                d: wp.array3d(dtype=float), dots: wp.array2d(dtype=wp.float64)):
    """From the guess gamma x: x = gamma x, r = b - gamma A x, d = r / diag (Jacobi; 0 off the
    unknowns); dots[0] += b . b, dots[1] += r . r, dots[2] += r . d."""
    ti, tj, tk = wp.tid()
    first = line_first(walk, ti, tj, tk)
    s0 = first[walk.axis]
    a1 = int(walk.axis == 1)
    a2 = int(walk.axis == 2)
    acc0 = wp.float64(0.0)
    acc1 = wp.float64(0.0)
    acc2 = wp.float64(0.0)
    for line_s in range(s0, line_end(walk, first)):
        i = first[0]
        j = first[1] + (line_s - s0) * a1
        k = first[2] + (line_s - s0) * a2
        bb = b[i, j, k]
        x[i, j, k] = gamma * x[i, j, k]
        res = bb - gamma * Ax[i, j, k]
        z = float(0.0)
        if diag[i, j, k] > 0.0:
            z = res / diag[i, j, k]
        r[i, j, k] = res
        d[i, j, k] = z
        acc0 += wp.float64(bb * bb)
        acc1 += wp.float64(res * res)
        acc2 += wp.float64(res * z)
    wp.atomic_add(dots, first[0], 0, acc0)
    wp.atomic_add(dots, first[0], 1, acc1)
    wp.atomic_add(dots, first[0], 2, acc2)
