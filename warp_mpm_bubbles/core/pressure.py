"""Pressure projection: a matrix-free SPD operator and a preconditioned conjugate gradient.

The operator is ``A p = -div(1/rho grad p)`` over fluid cells (empty cells are Dirichlet p = 0 gauge,
solid faces Neumann), plus a per-cell ``kappa/dt^2`` term for the gas. The CG is
hand-written because ``warp.optim.linear.cg`` spends most of its CPU time in its reduction kernel
(docs/design.md, #cg-on-warp); alpha, beta and the convergence test are computed on the device, with
no read-back per iteration (PressureSolver). All launches cover the fluid cells' bounding box
(docs/performance.md).

Preconditioners: "none", "jacobi" (diagonal), "multigrid" (one symmetric V-cycle). Jacobi-PCG
iterations grow linearly with the resolution and with the density ratio; multigrid-PCG's barely
grow (benchmarks/performance/pressure_solver.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import warp as wp

from .active_box import reset_bounds
from .grid import EMPTY, FLUID, PRECONDITIONERS
from .kernel_args import (PlaneSums, PointPreconditioner, PressureOperator, plane_sums, point_preconditioner,
                          pressure_operator)
from .launch import Recorded, Slabs, launch_key, record
from .lines import Lines, line_end, line_first, make_lines, on_line
from .multigrid import MultigridPreconditioner
from .solves import SolveInfo
from .threads import Parallel, line_slab_count

wp.set_module_options({"enable_backward": False})

NONE, JACOBI, MULTIGRID = range(3)  # indices of PRECONDITIONERS
# Iterations between the host's convergence checks after the first (benchmarks/performance/domain_scaling.py
# --check-every: 1, 2, 4 and 8 within noise on the CPU; 2 wastes at most one no-op iteration).
CHECK_EVERY = 2


@wp.func
def fluid_value(types: wp.array3d(dtype=wp.int32), p: wp.array3d(dtype=float), i: int, j: int, k: int):
    if i < 0 or j < 0 or k < 0 or i >= p.shape[0] or j >= p.shape[1] or k >= p.shape[2]:
        return 0.0
    if types[i, j, k] != FLUID:
        return 0.0
    return p[i, j, k]


@wp.func
def preconditioned(r: float, diag: float, mode: int):
    """z = M^-1 r for the pointwise preconditioners; multigrid overwrites z afterwards."""
    if mode == JACOBI:
        return r / diag
    return r


# Slots of a row of the solver's per-iteration scalars (float64, one row per iteration, on the device).
R_SUM, RR, RZ, DAD, RZ_MG, Z_SUM = range(6)
ROW = 8
# Slots of `scalars` (one row): sums over the right-hand side and the solution, kept apart from the rows.
B_SUM, B2, X_SUM = range(3)
# info[]: done flag, iterations completed, and its relative residual squared (float bits below).
DONE, ITERS = range(2)


# Sums (the dot products) in a fixed order whatever the threads: each thread adds its line's sum
# (accumulated in order along the line) into the partial sum of the line's plane, planes[x - plane0,
# slot]; a slab of planes is one thread's, so each plane sums its lines in order; then one thread adds
# the planes in order (sum_planes) and zeroes them for the next sum. On a GPU (a cell a thread) the
# planes' atomics run in any order.
@wp.func
def add_to_plane(out: PlaneSums, first: wp.vec3i, slot: int, value: wp.float64):
    if value != wp.float64(0.0):
        wp.atomic_add(out.planes, first[0] - out.plane0, slot, value)


@wp.func
def keep_residual(M: PointPreconditioner, c: wp.vec3i, res: float, r: wp.array3d(dtype=float),
                  z: wp.array3d(dtype=float), sums: wp.vec3d):
    """r = res and z = M^-1 res at cell c; returns sums + (res, res^2, res z), in float64."""
    zz = preconditioned(res, M.diag[c[0], c[1], c[2]], M.mode)
    r[c[0], c[1], c[2]] = res
    z[c[0], c[1], c[2]] = zz
    return sums + wp.vec3d(wp.float64(res), wp.float64(res * res), wp.float64(res * zz))


@wp.func
def add_residual_sums(out: PlaneSums, first: wp.vec3i, sums: wp.vec3d):
    """A line's (sum r, r . r, r . z) into its plane's R_SUM, RR and RZ."""
    add_to_plane(out, first, R_SUM, sums[0])
    add_to_plane(out, first, RR, sums[1])
    add_to_plane(out, first, RZ, sums[2])


@wp.kernel
def sum_planes(done: wp.array(dtype=wp.int32), planes: wp.array2d(dtype=wp.float64), n: int, first_slot: int,
               count: int, out: wp.array2d(dtype=wp.float64), row: int, out_slot: int):
    """One thread: out[row, out_slot + t] = the sum of planes[0:n, first_slot + t] in plane order, for t
    in [0, count); those planes zeroed."""
    if done[0] != 0:
        return
    for t in range(count):
        total = wp.float64(0.0)
        for q in range(n):
            total += planes[q, first_slot + t]
            planes[q, first_slot + t] = wp.float64(0.0)
        out[row, out_slot + t] = total


@wp.kernel
def apply_operator(walk: Lines, inside: int, done: wp.array(dtype=wp.int32), A: PressureOperator,
                   p: wp.array3d(dtype=float), out: wp.array3d(dtype=float), sums: PlaneSums):
    """out = A p on the fluid cells of `walk` (0 elsewhere in it); planes[.., DAD] += p . A p.

    inside = 1: p is 0 on every cell of the fluid box that is not FLUID (the solver keeps x, d and z
    so) and every fluid cell's face neighbours lie in the arrays (no fluid cell on their outer layer,
    as the ghost layer ensures): the neighbours are read without a test, an empty or solid one adding
    w * 0 (solid faces have w = 0 as well), which is the tested sum bit for bit. 0: each neighbour is
    tested (fluid_value)."""
    if done[0] != 0:
        return
    types = A.types
    inv_rho_u = A.inv_rho.u
    inv_rho_v = A.inv_rho.v
    inv_rho_w = A.inv_rho.w
    dim = A.dim
    ti, tj, tk = wp.tid()
    first = line_first(walk, ti, tj, tk)
    dot = wp.float64(0.0)
    for s in range(first[walk.axis], line_end(walk, first)):
        c = on_line(first, walk.axis, s)
        i, j, k = c[0], c[1], c[2]
        if types[i, j, k] != FLUID:
            out[i, j, k] = 0.0
            continue
        # Two copies of the sum, the test hoisted out of them: one sum with the test per neighbour
        # read made the kernel 18% slower on the CPU (4.7 against 5.6 ms a step, the peer block).
        n = float(0.0)
        if inside == 1:
            n = inv_rho_u[i, j, k] * p[i - 1, j, k]
            n += inv_rho_u[i + 1, j, k] * p[i + 1, j, k]
            n += inv_rho_v[i, j, k] * p[i, j - 1, k]
            n += inv_rho_v[i, j + 1, k] * p[i, j + 1, k]
            if dim == 3:
                n += inv_rho_w[i, j, k] * p[i, j, k - 1]
                n += inv_rho_w[i, j, k + 1] * p[i, j, k + 1]
        else:
            n = inv_rho_u[i, j, k] * fluid_value(types, p, i - 1, j, k)
            n += inv_rho_u[i + 1, j, k] * fluid_value(types, p, i + 1, j, k)
            n += inv_rho_v[i, j, k] * fluid_value(types, p, i, j - 1, k)
            n += inv_rho_v[i, j + 1, k] * fluid_value(types, p, i, j + 1, k)
            if dim == 3:
                n += inv_rho_w[i, j, k] * fluid_value(types, p, i, j, k - 1)
                n += inv_rho_w[i, j, k + 1] * fluid_value(types, p, i, j, k + 1)
        Ap = A.diag[i, j, k] * p[i, j, k] - n * A.inv_dx2
        out[i, j, k] = Ap
        dot += wp.float64(p[i, j, k] * Ap)
    add_to_plane(sums, first, DAD, dot)


@wp.kernel
def mask_and_bound(region: Lines, types: wp.array3d(dtype=wp.int32), x: wp.array3d(dtype=float),
                   box: wp.array(dtype=wp.int32)):
    """x = 0 off the fluid cells (of the whole region: the warm start may hold an older step's cells);
    box[0:3], box[3:6] = min and max fluid cell (box starts at (big, -1))."""
    ti, tj, tk = wp.tid()
    first = line_first(region, ti, tj, tk)
    for s in range(first[region.axis], line_end(region, first)):
        c = on_line(first, region.axis, s)
        i, j, k = c[0], c[1], c[2]
        if types[i, j, k] != FLUID:
            x[i, j, k] = 0.0
            continue
        wp.atomic_min(box, 0, i)
        wp.atomic_min(box, 1, j)
        wp.atomic_min(box, 2, k)
        wp.atomic_max(box, 3, i)
        wp.atomic_max(box, 4, j)
        wp.atomic_max(box, 5, k)


@wp.kernel
def fluid_sums(walk: Lines, squares: int, done: wp.array(dtype=wp.int32), types: wp.array3d(dtype=wp.int32),
               x: wp.array3d(dtype=float), sums: PlaneSums):
    """planes[.., 0] += the sum of x over the fluid cells, or of x^2 if `squares`."""
    if done[0] != 0:
        return
    ti, tj, tk = wp.tid()
    first = line_first(walk, ti, tj, tk)
    total = wp.float64(0.0)
    for s in range(first[walk.axis], line_end(walk, first)):
        c = on_line(first, walk.axis, s)
        if types[c[0], c[1], c[2]] == FLUID:
            v = x[c[0], c[1], c[2]]
            if squares != 0:
                v = v * v
            total += wp.float64(v)
    add_to_plane(sums, first, 0, total)


@wp.kernel
def fluid_dot(walk: Lines, done: wp.array(dtype=wp.int32), types: wp.array3d(dtype=wp.int32),
              x: wp.array3d(dtype=float), y: wp.array3d(dtype=float), sums: PlaneSums):
    """planes[.., RZ_MG] += x . y, planes[.., Z_SUM] += the sum of y over the fluid cells."""
    if done[0] != 0:
        return
    ti, tj, tk = wp.tid()
    first = line_first(walk, ti, tj, tk)
    dot = wp.float64(0.0)
    total = wp.float64(0.0)
    for s in range(first[walk.axis], line_end(walk, first)):
        c = on_line(first, walk.axis, s)
        i, j, k = c[0], c[1], c[2]
        if types[i, j, k] == FLUID:
            dot += wp.float64(x[i, j, k] * y[i, j, k])
            total += wp.float64(y[i, j, k])
    add_to_plane(sums, first, RZ_MG, dot)
    add_to_plane(sums, first, Z_SUM, total)


@wp.kernel
def shift_fluid(walk: Lines, done: wp.array(dtype=wp.int32), types: wp.array3d(dtype=wp.int32),
                x: wp.array3d(dtype=float), sums: wp.array2d(dtype=wp.float64), row: int, slot: int, n: int):
    """x -= sums[row, slot] / n on the fluid cells: removes the mean when that is x's sum over n cells."""
    if done[0] != 0:
        return
    shift = float(-sums[row, slot] / wp.float64(n))
    ti, tj, tk = wp.tid()
    first = line_first(walk, ti, tj, tk)
    for s in range(first[walk.axis], line_end(walk, first)):
        c = on_line(first, walk.axis, s)
        i, j, k = c[0], c[1], c[2]
        if types[i, j, k] == FLUID:
            x[i, j, k] = x[i, j, k] + shift


@wp.kernel
def start_iteration(walk: Lines, M: PointPreconditioner, done: wp.array(dtype=wp.int32), b: wp.array3d(dtype=float),
                    Ax: wp.array3d(dtype=float), r: wp.array3d(dtype=float), d: wp.array3d(dtype=float),
                    out: PlaneSums):
    """r = b - A x, d = M^-1 r; planes: sum r, r . r, r . M^-1 r."""
    if done[0] != 0:
        return
    ti, tj, tk = wp.tid()
    first = line_first(walk, ti, tj, tk)
    sums = wp.vec3d()
    for s in range(first[walk.axis], line_end(walk, first)):
        c = on_line(first, walk.axis, s)
        sums = keep_residual(M, c, b[c[0], c[1], c[2]] - Ax[c[0], c[1], c[2]], r, d, sums)
    add_residual_sums(out, first, sums)


@wp.kernel
def step_solution(
    walk: Lines,
    row: int,
    rz_slot: int,
    M: PointPreconditioner,
    done: wp.array(dtype=wp.int32),
    dots: wp.array2d(dtype=wp.float64),
    d: wp.array3d(dtype=float),
    Ad: wp.array3d(dtype=float),
    x: wp.array3d(dtype=float),
    r: wp.array3d(dtype=float),
    z: wp.array3d(dtype=float),
    out: PlaneSums,
):
    """alpha = rz / d.Ad from the device; x += alpha d, r -= alpha A d, z = M^-1 r; planes: sum r, r . r,
    r . z. Nothing if d.Ad <= 0 (the search direction lost positivity: round-off at convergence)."""
    if done[0] != 0:
        return
    dAd = dots[row, DAD]
    if dAd <= wp.float64(0.0):
        return
    alpha = float(dots[row - 1, rz_slot] / dAd)
    ti, tj, tk = wp.tid()
    first = line_first(walk, ti, tj, tk)
    sums = wp.vec3d()
    for s in range(first[walk.axis], line_end(walk, first)):
        c = on_line(first, walk.axis, s)
        i, j, k = c[0], c[1], c[2]
        x[i, j, k] = x[i, j, k] + alpha * d[i, j, k]
        sums = keep_residual(M, c, r[i, j, k] - alpha * Ad[i, j, k], r, z, sums)
    add_residual_sums(out, first, sums)


@wp.kernel
def check_convergence(dots: wp.array2d(dtype=wp.float64), row: int, sums: wp.array2d(dtype=wp.float64),
                      tol2: wp.float64, done: wp.array(dtype=wp.int32), info: wp.array(dtype=wp.float64)):
    """One thread: after iteration `row` (0: the start), record it and raise `done` once
    ||r||^2 <= tol2 ||b||^2, if b = 0, or if the iteration broke down (then it does not count)."""
    if done[0] != 0:
        return
    b2 = sums[0, B2]
    if b2 == wp.float64(0.0):
        done[0] = 1
        info[DONE] = wp.float64(1.0)
        info[ITERS] = wp.float64(0.0)
        info[2] = wp.float64(0.0)
        return
    if row > 0:
        if dots[row, DAD] <= wp.float64(0.0):
            done[0] = 1
            info[DONE] = wp.float64(1.0)
            return
    rel2 = dots[row, RR] / b2
    info[ITERS] = wp.float64(row)
    info[2] = rel2
    if rel2 <= tol2:
        done[0] = 1
        info[DONE] = wp.float64(1.0)


@wp.kernel
def zero_if_trivial(walk: Lines, sums: wp.array2d(dtype=wp.float64), x: wp.array3d(dtype=float)):
    """b = 0 on every fluid cell: the solution is x = 0."""
    if sums[0, B2] == wp.float64(0.0):
        ti, tj, tk = wp.tid()
        first = line_first(walk, ti, tj, tk)
        for s in range(first[walk.axis], line_end(walk, first)):
            c = on_line(first, walk.axis, s)
            x[c[0], c[1], c[2]] = 0.0


@wp.kernel
def update_direction(walk: Lines, row: int, rz_slot: int, done: wp.array(dtype=wp.int32), dots: wp.array2d(dtype=wp.float64),
                     z: wp.array3d(dtype=float), d: wp.array3d(dtype=float)):
    """d = z + beta d with beta = rz(row) / rz(row - 1), from the device."""
    if done[0] != 0:
        return
    beta = float(dots[row, rz_slot] / dots[row - 1, rz_slot])
    ti, tj, tk = wp.tid()
    first = line_first(walk, ti, tj, tk)
    for s in range(first[walk.axis], line_end(walk, first)):
        c = on_line(first, walk.axis, s)
        i, j, k = c[0], c[1], c[2]
        d[i, j, k] = z[i, j, k] + beta * d[i, j, k]


@dataclass
class PressureSystem:
    """The SPD system on FLUID cells, all arrays on the solver's device.

    (A p)_c = extra_diag_c p_c + (1/dx^2) sum over the 6 faces f of c of inv_rho_f (p_c - p_n(f)),
    where p_n = p of the neighbour if it is FLUID, else 0: an EMPTY neighbour is Dirichlet p = 0
    (its face weight already carries the ghost-fluid 1/theta), a SOLID one has inv_rho_f = 0.
    diag = extra_diag + sum(inv_rho_f) / dx^2 on fluid cells (1 elsewhere, unused).
    extra_diag is kappa/dt^2 of compressible gas cells, 0 for liquid. The system is singular
    (constants in its null space) iff no fluid cell touches an empty cell and extra_diag == 0.
    Faces on the arrays' outer boundary have inv_rho = 0 (the ghost layer keeps fluid off them);
    the multigrid preconditioner relies on it. b must be 0 on cells that are not FLUID.
    """

    types: wp.array3d  # int32 cell types (grid.py)
    inv_rho: tuple  # face arrays for the u, v, w faces
    diag: wp.array3d
    extra_diag: wp.array3d

    @classmethod
    def from_numpy(cls, types, inv_rho, extra_diag, dx: float, dim: int, device):
        """Build the system from numpy cell types, face weights and extra_diag (tests, benchmarks);
        diag is computed here, in float64, then stored as float32 like every other array.

        Returns (system, n_fluid, singular), as the simulation counts them for its grid work.
        """
        fluid = types == FLUID
        faces = [np.asarray(w, dtype=np.float32) for w in inv_rho]
        total = sum(np.take(w, range(0, w.shape[a] - 1), axis=a) + np.take(w, range(1, w.shape[a]), axis=a)
                    for a, w in enumerate(faces[:dim]))
        diag = np.where(fluid, extra_diag + total / dx**2, 1.0).astype(np.float32)
        pinned = bool(np.any(extra_diag[fluid] > 0))
        for a in range(dim):  # a fluid cell beside an empty one pins the constant
            f, e = np.moveaxis(fluid, a, 0), np.moveaxis(types == EMPTY, a, 0)
            pinned |= bool(np.any(f[:-1] & e[1:]) or np.any(f[1:] & e[:-1]))
        arr = lambda a, dtype=float: wp.array(np.ascontiguousarray(a), dtype=dtype, device=device)  # noqa: E731
        system = cls(arr(types.astype(np.int32), wp.int32), tuple(arr(w) for w in faces), arr(diag),
                     arr(np.where(fluid, extra_diag, 0.0).astype(np.float32)))
        return system, int(fluid.sum()), not pinned


class PressureSolver:
    """PCG on the fluid cells of one grid; scratch arrays (and multigrid levels) are allocated once.

    Work follows the liquid: one pass over the whole grid masks the warm start and finds
    the fluid cells' bounding box on the device; the host reads the box (the solve's one read before
    it iterates, to size the launches) and every other launch covers the box grown by one cell (so
    each fluid cell's face neighbours are in it), at every multigrid level. `active_box=False`
    launches over the whole grid instead (same arithmetic, for tests and benchmarks).

    No host read per iteration: alpha and beta come from float64 dot products that the kernels sum
    into one device row per iteration, per plane of the box and then over the planes in order
    (sum_planes), so on the CPU the sums do not depend on the threads. A one-thread kernel raises a
    device flag at convergence, after which every kernel returns at once; the host reads the flag
    first after as many iterations as the last solve took (usually that one read is all), then every
    `check_every` iterations (up to check_every - 1 no-op iterations). A chunk is a fixed launch
    sequence, which a CUDA graph can capture. On the CPU the cell kernels run in slabs of planes on
    the threads of `parallel`; a solve's launches are recorded once and replayed, the row set on each.
    """

    def __init__(self, shape, dim: int, dx: float, device, *, active_box: bool = True,
                 check_every: int = CHECK_EVERY, parallel=None):
        self.dim, self.dx = dim, dx
        self.inv_dx2 = 1.0 / (dx * dx)
        self.device = device
        self.shape = shape
        self.active_box, self.check_every = active_box, check_every
        zeros = lambda: wp.zeros(shape, dtype=float, device=device)  # noqa: E731
        self.r, self.z, self.d, self.Ad = zeros(), zeros(), zeros(), zeros()
        self.rows = wp.zeros((0, ROW), dtype=wp.float64, device=device)  # grown to max_iter + 1 rows
        self.scalars = wp.zeros((1, ROW), dtype=wp.float64, device=device)
        self.planes = wp.zeros((shape[0], ROW), dtype=wp.float64, device=device)  # per-plane partial sums
        self.done = wp.zeros(1, dtype=wp.int32, device=device)
        self.info = wp.zeros(3, dtype=wp.float64, device=device)
        self.bounds = wp.zeros(6, dtype=wp.int32, device=device)
        self.multigrid = None  # built on first use
        self.parallel = parallel or Parallel(1)  # the CPU's threads for the large launches (core/threads.py)
        self.host_reads = 0  # reads from the device by the last solve (the box, then one per check)
        self.predicted = check_every  # iterations before the first check: the last solve's count
        self.box = ((0, 0, 0), tuple(shape))
        self.planes_n = shape[0]  # planes of the box (along x): what sum_planes adds
        self.recorded = Recorded()  # the solve's recorded launches, kept from solve to solve
        self.slabs = None  # the box's slabs that the recorded cell launches walk (solve)
        self.sums = plane_sums(self.planes, 0)  # moved in place with the box, like the slabs

    def _tag(self, kernel, kind, inputs):
        """A batch's tag in `self.recorded`: its kernel and arguments, the plane sums (which move with
        the box) by name rather than by their first plane."""
        return kernel.key, kind, launch_key(["sums" if v is self.sums else v for v in inputs])

    def _record(self, kernel, inputs):
        """One recorded launch of a one-thread kernel that does not depend on the box (its inputs as
        given): a batch of one part, recorded once while the solve's arrays stay the same."""
        return self.recorded.get(self._tag(kernel, "one", inputs), lambda: [record(kernel, 1, inputs, self.device)])

    def _record_cells(self, kernel, inputs):
        """Recorded launches of a cell kernel over the box, its first argument the walk: slabs of planes,
        one a thread, when the box is large enough to split (core/threads.py); a batch, recorded once
        while the solve's arrays stay the same, and moved with the box (`self.slabs`, `self.sums`)."""
        return self.recorded.get(self._tag(kernel, "cells", inputs), lambda: self.slabs.record(
            kernel, lambda walk: [walk, *inputs], self.device))

    def _run(self, batch, row=None):
        """Replay a batch's launches at once (setting `row` first, for the kernels that take one)."""
        if row is not None:
            for launch in batch:
                launch.set_param_by_name("row", row)
        if len(batch) == 1:
            batch[0].launch()
        else:
            self.parallel.run([launch.launch for launch in batch])

    def _reduce(self, first_slot: int, count: int, out, out_slot: int):
        """A batch: out[row, out_slot + t] = the planes' sum of slot first_slot + t (sum_planes), over
        the box's planes (their number set again when the box moves)."""
        inputs = lambda n: [self.done, self.planes, n, first_slot, count, out, 0, out_slot]  # noqa: E731
        return self.recorded.get(
            self._tag(sum_planes, "planes", inputs(None)),
            lambda: [record(sum_planes, 1, inputs(self.planes_n), self.device)],
            move=lambda batch: batch[0].set_param_by_name("n", self.planes_n))

    def _find_box(self, types, x, region):
        """Mask x to the fluid cells and set self.box to the fluid bounding box grown by one cell."""
        lo, hi = region or ((0, 0, 0), self.shape)
        wp.launch(reset_bounds, 6, inputs=[self.bounds, 6], device=self.device)
        walk, dims = make_lines(lo, hi, self.dim, self.device)
        wp.launch(mask_and_bound, dims, inputs=[walk, types, x, self.bounds], device=self.device)
        if not self.active_box:
            self.box = ((0, 0, 0), tuple(self.shape))
        else:
            b = self.bounds.numpy()
            self.host_reads += 1
            if b[3] < 0:  # no fluid cell
                self.box = ((0, 0, 0), (0, 0, 0))
            else:
                self.box = (tuple(max(int(b[a]) - 1, 0) for a in range(3)),
                            tuple(min(int(b[3 + a]) + 2, self.shape[a]) for a in range(3)))
        # apply_operator reads neighbours untested when no fluid cell lies on the arrays' outer layer:
        # the box then holds a layer of non-fluid cells around them (it is never clipped).
        lo, hi = self.box
        self.inside = int(all(lo[a] > 0 and hi[a] < self.shape[a] for a in range(self.dim)))
        self.lines, self.dims = make_lines(*self.box, self.dim, self.device)
        self.planes_n = hi[0] - lo[0]

    def _check(self):
        """Read the device's flag, iteration count and residual: the only read while iterating."""
        self.host_reads += 1
        info = self.info.numpy()
        return info[DONE] != 0.0, int(info[ITERS]), float(info[2])

    def _sum_fluid(self, types, v, out_slot: int, squares: bool):
        """scalars[out_slot] = the sum of v (or of v^2) over the fluid cells."""
        self._run(self._record_cells(fluid_sums, [int(squares), self.done, types, v, self.sums]))
        self._run(self._reduce(0, 1, self.scalars, out_slot))

    def _center(self, types, v, sums, row: int, slot: int, n: int):
        """v -= its mean over the n fluid cells, when sums[row, slot] is its sum."""
        self._run(self._record_cells(shift_fluid, [self.done, types, v, sums, 0, slot, n]), row)

    def solve(self, system: PressureSystem, b, x, *, tol: float, max_iter: int, singular: bool, n_fluid: int,
              preconditioner: str = "multigrid", region=None, same_system: bool = False):
        """Solve A x = b in place; x holds the warm start. preconditioner: "none" | "jacobi" | "multigrid".
        region: None, or a box (lo, hi) that holds every fluid cell and outside which x is already 0
        (the simulation's grid box): the one pass that masks x and finds the fluid box covers only it.
        same_system: A is the last solve's, unchanged (a second right-hand side): its multigrid
        hierarchy is kept rather than built again."""
        mode = PRECONDITIONERS.index(preconditioner)
        self.host_reads = 0
        self._find_box(system.types, x, region)
        if min(h - l for l, h in zip(*self.box)) == 0:  # noqa: E741
            return SolveInfo(0, 0.0, True)
        if self.rows.shape[0] < max_iter + 1:
            self.rows = wp.zeros((max_iter + 1, ROW), dtype=wp.float64, device=self.device)
        # The launches recorded by the last solve replay if its arrays, threads and number of slabs are
        # these (and whether the box touches the arrays' outer layer: `inside`), moved to this box.
        slabs = line_slab_count(self.lines, self.dims, self.parallel.threads)
        if not self.recorded.keep(slabs, self.inside, self.parallel.threads, system.types, system.inv_rho,
                                  system.diag, system.extra_diag, b, x, self.rows, box=self.box):
            self.slabs = Slabs(slabs)
        self.slabs.move(self.lines, self.dims)
        self.sums.plane0 = self.box[0][0]
        self.recorded.move()
        for a in (self.rows, self.scalars, self.done, self.info):
            a.zero_()
        project = n_fluid if singular else 0
        if project:  # closed tank: only b's component orthogonal to constants is reachable
            self._sum_fluid(system.types, b, B_SUM, squares=False)
            self._center(system.types, b, self.scalars, 0, B_SUM, project)
        self._sum_fluid(system.types, b, B2, squares=True)
        self._run(self._record_cells(zero_if_trivial, [self.scalars, x]))
        if mode == MULTIGRID and not (same_system and self.multigrid is not None):
            if self.multigrid is None:
                self.multigrid = MultigridPreconditioner(self.shape, self.dim, self.dx, self.device,
                                                         parallel=self.parallel)
            self.multigrid.build(system, self.box, self.done)
        it, rel2 = self._iterate(system, b, x, mode, project, tol, max_iter)
        if project:
            self.done.zero_()
            self._sum_fluid(system.types, x, X_SUM, squares=False)
            self._center(system.types, x, self.scalars, 0, X_SUM, project)
        rel = math.sqrt(rel2)
        return SolveInfo(it, rel, rel <= tol)

    def _iterate(self, system, b, x, mode: int, project: int, tol: float, max_iter: int):
        """The PCG iterations from the warm start x; returns (iterations, relative residual squared)."""
        types, done, rows = system.types, self.done, self.rows
        sums = self.sums
        M = point_preconditioner(system.diag, mode)
        rz_slot = RZ_MG if mode == MULTIGRID else RZ
        A = pressure_operator(system, self.inv_dx2, self.dim)
        # One iteration's launches, recorded once for this solve (the row is set on each replay).
        apply_d = self._record_cells(apply_operator, [self.inside, done, A, self.d, self.Ad, sums])
        reduce_dAd = self._reduce(DAD, 1, rows, DAD)
        step = self._record_cells(step_solution, [0, rz_slot, M, done, rows, self.d, self.Ad, x, self.r, self.z, sums])
        reduce_step = self._reduce(R_SUM, 3, rows, R_SUM)
        check = self._record(check_convergence, [rows, 0, self.scalars, wp.float64(tol * tol), done, self.info])
        dot_z = self._record_cells(fluid_dot, [done, types, self.r, self.z, sums])
        reduce_dot = self._reduce(RZ_MG, 2, rows, RZ_MG)
        update = self._record_cells(update_direction, [0, rz_slot, done, rows, self.z, self.d])

        def precondition(z, row, dot):
            """z = M^-1 r by the V-cycle; rows[row] gets r . z and the sum of z. A singular system's r
            and z are first projected onto the range (mean zero): round-off leaves r a small constant
            part, which the V-cycle would amplify (the constant is its near-null direction) and CG then
            loses orthogonality."""
            if project:
                self._center(types, self.r, rows, row, R_SUM, project)
            self.multigrid.apply(self.r, z)
            self._run(dot)
            self._run(reduce_dot, row)
            if project:
                self._center(types, z, rows, row, Z_SUM, project)

        # Row 0: r = b - A x, d = M^-1 r. A x's p . A p lands in row 0's DAD slot, which nothing reads.
        self._run(self._record_cells(apply_operator, [self.inside, done, A, x, self.Ad, sums]))
        self._run(reduce_dAd, 0)
        self._run(self._record_cells(start_iteration, [M, done, b, self.Ad, self.r, self.d, sums]))
        self._run(reduce_step, 0)
        self._run(check, 0)
        if mode == MULTIGRID:
            precondition(self.d, 0, self._record_cells(fluid_dot, [done, types, self.r, self.d, sums]))
        # Chunks of iterations between reads: the first as long as the last solve took (warm-started
        # steps take about as many), then check_every. Iterations past convergence are no-ops.
        row, stop, chunk = 0, False, self.predicted
        while not stop and row < max_iter:
            for _ in range(min(chunk, max_iter - row)):
                row += 1
                self._run(apply_d)
                self._run(reduce_dAd, row)
                self._run(step, row)
                self._run(reduce_step, row)
                self._run(check, row)
                if mode == MULTIGRID:
                    precondition(self.z, row, dot_z)
                self._run(update, row)
            stop, it, rel2 = self._check()
            chunk = self.check_every
        if row == 0:  # max_iter == 0
            stop, it, rel2 = self._check()
        self.predicted = max(it, 1)
        return it, rel2
