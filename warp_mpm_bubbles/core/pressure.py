"""Pressure projection: a matrix-free SPD operator and a preconditioned conjugate gradient.

The operator is ``A p = -div(1/rho grad p)`` over fluid cells (empty cells are Dirichlet p = 0 gauge,
solid faces Neumann), plus, from issue #3 on, a per-cell ``kappa/dt^2`` term for the gas. The CG is
hand-written because ``warp.optim.linear.cg`` spends most of its CPU time in its reduction kernel
(docs/design.md, #cg-on-warp); each iteration is four launches (plus one V-cycle and one dot product with
the multigrid preconditioner of multigrid.py) and no read-back: alpha, beta and the convergence test
are computed on the device, and the host checks a device flag every CHECK_EVERY iterations. All
launches cover the fluid cells' bounding box (docs/performance.md).

Preconditioners: "none", "jacobi" (diagonal), "multigrid" (one symmetric V-cycle). Jacobi-PCG
iterations grow linearly with the resolution and with the density ratio; multigrid-PCG's barely
grow (benchmarks/pressure_solver.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import warp as wp

from .active_box import reset_bounds
from .grid import EMPTY, FLUID, PRECONDITIONERS
from .lines import Lines, line_end, line_first, make_lines, on_line
from .multigrid import MultigridPreconditioner

wp.set_module_options({"enable_backward": False})

NONE, JACOBI, MULTIGRID = range(3)  # indices of PRECONDITIONERS
# Iterations between the host's convergence checks after the first (benchmarks/domain_scaling.py
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
# Slots of `scalars`: sums over the right-hand side and the solution, kept apart from the rows.
B_SUM, B2, X_SUM = range(3)
# info[]: done flag, iterations completed, and its relative residual squared (float bits below).
DONE, ITERS = range(2)


@wp.kernel
def apply_operator(
    box: Lines,
    done: wp.array(dtype=wp.int32),
    types: wp.array3d(dtype=wp.int32),
    diag: wp.array3d(dtype=float),
    inv_rho_u: wp.array3d(dtype=float),
    inv_rho_v: wp.array3d(dtype=float),
    inv_rho_w: wp.array3d(dtype=float),
    inv_dx2: float,
    dim: int,
    p: wp.array3d(dtype=float),
    out: wp.array3d(dtype=float),
    dots: wp.array2d(dtype=wp.float64),
    row: int,
):
    """out = A p on fluid cells of the box (0 elsewhere in it); dots[row, DAD] += p . A p."""
    if done[0] != 0:
        return
    ti, tj, tk = wp.tid()
    first = line_first(box, ti, tj, tk)
    for s in range(first[box.axis], line_end(box, first)):
        c = on_line(first, box.axis, s)
        i, j, k = c[0], c[1], c[2]
        if types[i, j, k] != FLUID:
            out[i, j, k] = 0.0
            continue
        # Neighbours that are not fluid contribute nothing: empty ones are p = 0, solid faces have 1/rho = 0.
        n = inv_rho_u[i, j, k] * fluid_value(types, p, i - 1, j, k)
        n += inv_rho_u[i + 1, j, k] * fluid_value(types, p, i + 1, j, k)
        n += inv_rho_v[i, j, k] * fluid_value(types, p, i, j - 1, k)
        n += inv_rho_v[i, j + 1, k] * fluid_value(types, p, i, j + 1, k)
        if dim == 3:
            n += inv_rho_w[i, j, k] * fluid_value(types, p, i, j, k - 1)
            n += inv_rho_w[i, j, k + 1] * fluid_value(types, p, i, j, k + 1)
        Ap = diag[i, j, k] * p[i, j, k] - n * inv_dx2
        out[i, j, k] = Ap
        wp.atomic_add(dots, row, DAD, wp.float64(p[i, j, k] * Ap))


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
def fluid_sums(box: Lines, done: wp.array(dtype=wp.int32), types: wp.array3d(dtype=wp.int32),
               x: wp.array3d(dtype=float), sums: wp.array(dtype=wp.float64), slot: int, square_slot: int):
    """sums[slot] += sum of x over the fluid cells; sums[square_slot] += x . x (if square_slot >= 0)."""
    if done[0] != 0:
        return
    ti, tj, tk = wp.tid()
    first = line_first(box, ti, tj, tk)
    for s in range(first[box.axis], line_end(box, first)):
        c = on_line(first, box.axis, s)
        if types[c[0], c[1], c[2]] == FLUID:
            v = x[c[0], c[1], c[2]]
            wp.atomic_add(sums, slot, wp.float64(v))
            if square_slot >= 0:
                wp.atomic_add(sums, square_slot, wp.float64(v * v))


@wp.kernel
def fluid_dot(box: Lines, done: wp.array(dtype=wp.int32), types: wp.array3d(dtype=wp.int32),
              x: wp.array3d(dtype=float), y: wp.array3d(dtype=float), dots: wp.array2d(dtype=wp.float64), row: int):
    """dots[row, RZ_MG] += x . y, dots[row, Z_SUM] += sum of y over fluid cells."""
    if done[0] != 0:
        return
    ti, tj, tk = wp.tid()
    first = line_first(box, ti, tj, tk)
    for s in range(first[box.axis], line_end(box, first)):
        c = on_line(first, box.axis, s)
        i, j, k = c[0], c[1], c[2]
        if types[i, j, k] == FLUID:
            wp.atomic_add(dots, row, RZ_MG, wp.float64(x[i, j, k] * y[i, j, k]))
            wp.atomic_add(dots, row, Z_SUM, wp.float64(y[i, j, k]))


@wp.kernel
def shift_fluid(box: Lines, done: wp.array(dtype=wp.int32), types: wp.array3d(dtype=wp.int32),
                x: wp.array3d(dtype=float), sums: wp.array(dtype=wp.float64), slot: int, n: int):
    """x -= sums[slot] / n on the fluid cells: removes the mean when sums[slot] is x's sum over n cells."""
    if done[0] != 0:
        return
    shift = float(-sums[slot] / wp.float64(n))
    ti, tj, tk = wp.tid()
    first = line_first(box, ti, tj, tk)
    for s in range(first[box.axis], line_end(box, first)):
        c = on_line(first, box.axis, s)
        i, j, k = c[0], c[1], c[2]
        if types[i, j, k] == FLUID:
            x[i, j, k] = x[i, j, k] + shift


@wp.kernel
def start_iteration(
    box: Lines,
    done: wp.array(dtype=wp.int32),
    b: wp.array3d(dtype=float),
    Ax: wp.array3d(dtype=float),
    diag: wp.array3d(dtype=float),
    mode: int,
    r: wp.array3d(dtype=float),
    d: wp.array3d(dtype=float),
    dots: wp.array2d(dtype=wp.float64),
):
    """r = b - A x, d = M^-1 r; row 0 of dots: sum r, r . r, r . M^-1 r."""
    if done[0] != 0:
        return
    ti, tj, tk = wp.tid()
    first = line_first(box, ti, tj, tk)
    for s in range(first[box.axis], line_end(box, first)):
        c = on_line(first, box.axis, s)
        i, j, k = c[0], c[1], c[2]
        res = b[i, j, k] - Ax[i, j, k]
        z = preconditioned(res, diag[i, j, k], mode)
        r[i, j, k] = res
        d[i, j, k] = z
        wp.atomic_add(dots, 0, R_SUM, wp.float64(res))
        wp.atomic_add(dots, 0, RR, wp.float64(res * res))
        wp.atomic_add(dots, 0, RZ, wp.float64(res * z))


@wp.kernel
def step_solution(
    box: Lines,
    done: wp.array(dtype=wp.int32),
    dots: wp.array2d(dtype=wp.float64),
    row: int,
    rz_slot: int,
    d: wp.array3d(dtype=float),
    Ad: wp.array3d(dtype=float),
    diag: wp.array3d(dtype=float),
    mode: int,
    x: wp.array3d(dtype=float),
    r: wp.array3d(dtype=float),
    z: wp.array3d(dtype=float),
):
    """alpha = rz / d.Ad from the device; x += alpha d, r -= alpha A d, z = M^-1 r; row: sum r, r . r, r . z.
    Nothing if d.Ad <= 0 (the search direction lost positivity: round-off at convergence)."""
    if done[0] != 0:
        return
    dAd = dots[row, DAD]
    if dAd <= wp.float64(0.0):
        return
    alpha = float(dots[row - 1, rz_slot] / dAd)
    ti, tj, tk = wp.tid()
    first = line_first(box, ti, tj, tk)
    for s in range(first[box.axis], line_end(box, first)):
        c = on_line(first, box.axis, s)
        i, j, k = c[0], c[1], c[2]
        x[i, j, k] = x[i, j, k] + alpha * d[i, j, k]
        res = r[i, j, k] - alpha * Ad[i, j, k]
        zz = preconditioned(res, diag[i, j, k], mode)
        r[i, j, k] = res
        z[i, j, k] = zz
        wp.atomic_add(dots, row, R_SUM, wp.float64(res))
        wp.atomic_add(dots, row, RR, wp.float64(res * res))
        wp.atomic_add(dots, row, RZ, wp.float64(res * zz))


@wp.kernel
def check_convergence(dots: wp.array2d(dtype=wp.float64), row: int, sums: wp.array(dtype=wp.float64),
                      tol2: wp.float64, done: wp.array(dtype=wp.int32), info: wp.array(dtype=wp.float64)):
    """One thread: after iteration `row` (0: the start), record it and raise `done` once
    ||r||^2 <= tol2 ||b||^2, if b = 0, or if the iteration broke down (then it does not count)."""
    if done[0] != 0:
        return
    b2 = sums[B2]
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
def zero_if_trivial(box: Lines, sums: wp.array(dtype=wp.float64), x: wp.array3d(dtype=float)):
    """b = 0 on every fluid cell: the solution is x = 0."""
    if sums[B2] == wp.float64(0.0):
        ti, tj, tk = wp.tid()
        first = line_first(box, ti, tj, tk)
        for s in range(first[box.axis], line_end(box, first)):
            c = on_line(first, box.axis, s)
            x[c[0], c[1], c[2]] = 0.0


@wp.kernel
def update_direction(box: Lines, done: wp.array(dtype=wp.int32), dots: wp.array2d(dtype=wp.float64), row: int,
                     rz_slot: int, z: wp.array3d(dtype=float), d: wp.array3d(dtype=float)):
    """d = z + beta d with beta = rz(row) / rz(row - 1), from the device."""
    if done[0] != 0:
        return
    beta = float(dots[row, rz_slot] / dots[row - 1, rz_slot])
    ti, tj, tk = wp.tid()
    first = line_first(box, ti, tj, tk)
    for s in range(first[box.axis], line_end(box, first)):
        c = on_line(first, box.axis, s)
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

        Returns (system, n_fluid, singular), as the simulation's grid stage counts them.
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


@dataclass
class SolveInfo:
    iterations: int
    residual: float  # ||b - A x|| / ||b|| at exit
    converged: bool


class PressureSolver:
    """PCG on the fluid cells of one grid; scratch arrays (and multigrid levels) are allocated once.

    Work follows the liquid (issue #13): one pass over the whole grid masks the warm start and finds
    the fluid cells' bounding box on the device; the host reads the box (the solve's one read before
    it iterates, to size the launches) and every other launch covers the box grown by one cell (so
    each fluid cell's face neighbours are in it), at every multigrid level. `active_box=False`
    launches over the whole grid instead (same arithmetic, for tests and benchmarks).

    No host read per iteration: alpha and beta are computed by the kernels from float64 dot products
    that they accumulate into one device row per iteration (on the CPU the atomics run in thread
    order, so results are deterministic). A one-thread kernel raises a device flag at convergence,
    after which every kernel returns at once; the host reads the flag (with the iteration count and
    residual) first after as many iterations as the last solve took (consecutive warm-started steps
    take about as many: usually that one read is all), then every `check_every` iterations; up to
    check_every - 1 iterations past convergence are launched as no-ops. That is a fixed launch sequence per chunk, which a CUDA graph can capture
    (wp.capture_while on the flag would make the loop itself device-side).
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
        self.scalars = wp.zeros(ROW, dtype=wp.float64, device=device)
        self.done = wp.zeros(1, dtype=wp.int32, device=device)
        self.info = wp.zeros(3, dtype=wp.float64, device=device)
        self.bounds = wp.zeros(6, dtype=wp.int32, device=device)
        self.multigrid = None  # built on first use
        self.parallel = parallel  # the CPU's threads for the V-cycle's large launches (core/threads.py)
        self.host_reads = 0  # reads from the device by the last solve (the box, then one per check)
        self.predicted = check_every  # iterations before the first check: the last solve's count
        self.box = ((0, 0, 0), tuple(shape))

    def _launch(self, kernel, inputs, dim=None):
        wp.launch(kernel, dim or self.dims, inputs=inputs, device=self.device)

    def _find_box(self, types, x, region):
        """Mask x to the fluid cells and set self.box to the fluid bounding box grown by one cell."""
        lo, hi = region or ((0, 0, 0), self.shape)
        wp.launch(reset_bounds, 6, inputs=[self.bounds], device=self.device)
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
        self.lines, self.dims = make_lines(*self.box, self.dim, self.device)

    def _v_cycle(self, types, r, z, row: int, n_project: int):
        """z = M^-1 r by the multigrid V-cycle; dots[row] gets r . z and the sum of z.

        n_project > 0 (a singular system with that many fluid cells): r and z are first projected
        onto the range (mean zero). Round-off leaves r a small constant part, which the V-cycle
        would amplify (the constant is its near-null direction) and CG then loses orthogonality.
        """
        box, done, rows = self.lines, self.done, self.rows
        if n_project:
            self._launch(shift_fluid, [box, done, types, r, rows[row], R_SUM, n_project])
        self.multigrid.apply(r, z)
        self._launch(fluid_dot, [box, done, types, r, z, rows, row])
        if n_project:
            self._launch(shift_fluid, [box, done, types, z, rows[row], Z_SUM, n_project])

    def _check(self):
        """Read the device's flag, iteration count and residual: the only read while iterating."""
        self.host_reads += 1
        info = self.info.numpy()
        return info[DONE] != 0.0, int(info[ITERS]), float(info[2])

    def solve(self, system: PressureSystem, b, x, *, tol: float, max_iter: int, singular: bool, n_fluid: int,
              preconditioner: str = "multigrid", region=None):
        """Solve A x = b in place; x holds the warm start. preconditioner: "none" | "jacobi" | "multigrid".
        region: None, or a box (lo, hi) that holds every fluid cell and outside which x is already 0
        (the simulation's grid box): the one pass that masks x and finds the fluid box covers only it."""
        mode = PRECONDITIONERS.index(preconditioner)
        types, diag, inv_rho = system.types, system.diag, system.inv_rho
        self.host_reads = 0
        self._find_box(types, x, region)
        if min(h - l for l, h in zip(*self.box)) == 0:  # noqa: E741
            return SolveInfo(0, 0.0, True)
        if self.rows.shape[0] < max_iter + 1:
            self.rows = wp.zeros((max_iter + 1, ROW), dtype=wp.float64, device=self.device)
        box, done, rows, sums = self.lines, self.done, self.rows, self.scalars
        for a in (rows, sums, done, self.info):
            a.zero_()
        project = n_fluid if singular else 0
        if project:  # closed tank: only b's component orthogonal to constants is reachable
            self._launch(fluid_sums, [box, done, types, b, sums, B_SUM, -1])
            self._launch(shift_fluid, [box, done, types, b, sums, B_SUM, project])
        self._launch(fluid_sums, [box, done, types, b, sums, 3, B2])
        self._launch(zero_if_trivial, [box, sums, x])
        if mode == MULTIGRID:
            if self.multigrid is None:
                self.multigrid = MultigridPreconditioner(self.shape, self.dim, self.dx, self.device,
                                                         parallel=self.parallel)
            self.multigrid.build(system, self.box, done)
        apply = lambda p, out, row: self._launch(  # noqa: E731
            apply_operator, [box, done, types, diag, *inv_rho, self.inv_dx2, self.dim, p, out, rows, row])
        rz_slot = RZ_MG if mode == MULTIGRID else RZ
        tol2 = wp.float64(tol * tol)

        apply(x, self.Ad, 0)  # its p . A p lands in row 0's DAD slot, which nothing reads
        self._launch(start_iteration, [box, done, b, self.Ad, diag, mode, self.r, self.d, rows])
        self._launch(check_convergence, [rows, 0, sums, tol2, done, self.info], dim=1)
        if mode == MULTIGRID:
            self._v_cycle(types, self.r, self.d, 0, project)
        # Chunks of iterations between reads: the first as long as the last solve took (warm-started
        # steps take about as many), then check_every. Iterations past convergence are no-ops.
        row, stop, chunk = 0, False, self.predicted
        while not stop and row < max_iter:
            for _ in range(min(chunk, max_iter - row)):
                row += 1
                apply(self.d, self.Ad, row)
                self._launch(step_solution, [box, done, rows, row, rz_slot, self.d, self.Ad, diag, mode, x, self.r,
                                             self.z])
                self._launch(check_convergence, [rows, row, sums, tol2, done, self.info], dim=1)
                if mode == MULTIGRID:
                    self._v_cycle(types, self.r, self.z, row, project)
                self._launch(update_direction, [box, done, rows, row, rz_slot, self.z, self.d])
            stop, it, rel2 = self._check()
            chunk = self.check_every
        if row == 0:  # max_iter == 0
            stop, it, rel2 = self._check()
        self.predicted = max(it, 1)
        if project:
            done.zero_()
            self._launch(fluid_sums, [box, done, types, x, sums, X_SUM, -1])
            self._launch(shift_fluid, [box, done, types, x, sums, X_SUM, project])
        rel = math.sqrt(rel2)
        return SolveInfo(it, rel, rel <= tol)
