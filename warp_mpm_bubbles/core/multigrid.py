"""Multigrid V-cycle preconditioner for the pressure system (after McAdams, Sifakis & Teran 2010).

A matrix-free, symmetric positive definite approximation of A^-1 for
:class:`~warp_mpm_bubbles.pressure.PressureSystem`, rebuilt cheaply at every solve because the
cell types and face weights change every step. Choices (measured in benchmarks/performance/pressure_solver.py):

- Levels: coarsen by 2 along the simulated axes (ceil(n/2): odd sizes and non-powers of two are
  fine) until at most MAX_COARSEST_CELLS cells are left. Coarse cell C has the fine children
  2C + {0,1}^dim; it is an unknown (FLUID) iff any child is.
- Transfers: piecewise-constant prolongation onto the fluid children, restriction its transpose
  (the sum over fluid children). Constant interpolation never averages across a 1000:1 density
  jump, and with the Galerkin-type operators below the hierarchy stays robust to jumps (as in
  aggregation multigrid). McAdams et al.'s trilinear interpolation was not tried.
- Coarse operators, built from the fine level by one kernel per level: the Galerkin product
  P^T A P, whose coupling across a coarse face is the sum of the fine couplings crossing it and
  whose compressibility term (extra_diag) is the sum of the children's, with the Laplacian part
  (couplings and Dirichlet terms) scaled by COARSE_LAPLACIAN_SCALE = 1/2. Piecewise-constant
  Galerkin is known to be twice too stiff for the Laplacian (Braess 1981): the factor 1/2 makes
  it the operator re-discretised on the coarse grid with averaged face weights. Measured (2D,
  sweeps 2): tank 128^2 22 -> 6 CG iterations, 1000:1 bubbles 256^2 80 -> 27; 0.4 to 0.7 were
  no better. The extra_diag term is a mass term, which constants represent exactly: not scaled.
- Dirichlet (EMPTY) cells stay p = 0 at every level: a fine face from a fluid cell to an empty
  cell (with its ghost-fluid 1/theta) becomes a diagonal term of the coarse parent (scaled like
  the couplings), so every level sees the free surface where the fine one does. Unlike McAdams
  et al., no coarse cell is made Dirichlet, so thin sheets and droplets keep coarse unknowns.
- Smoother: red-black Gauss-Seidel, SMOOTHING_SWEEPS (red, black) sweeps going down and the same
  number of (black, red) sweeps coming up, so the V-cycle is a symmetric operator; Gauss-Seidel
  converges in the energy norm, so it is positive definite too. 2 sweeps: 3D bubbles 64^3 take
  20 CG iterations (1 sweep: 40, 3: 16) and the least time; 2D is about even between 1 and 3.
- Coarsest level: dense Cholesky in float64 by a single thread (a few dozen unknowns). A pivot
  below PIVOT_TOLERANCE of its diagonal (the constant mode of a closed tank) is dropped, which
  gives a symmetric positive semi-definite pseudo-inverse.

Active box (so that cost follows the liquid, not the domain): every level works on the bounding box of the cells that can be unknowns,
[lo, hi), passed in the Level struct; cells outside it count as outside the arrays. The finest box
is the fluid cells' bounding box, each coarser one the parents of the finer box, so the hierarchy and
every unknown are those of the whole-grid V-cycle and the result is bit-identical (red-black colours
are global, cells outside the box only ever contributed w * 0). Launches cover the box only, so the
cost follows the liquid, not the domain. Every kernel also returns at once when `L.done[0]` is set:
the CG's device-side exit flag, so iterations launched past convergence cost a launch, no work.

All arrays of all levels are allocated once per grid. Per V-cycle: 4 * SMOOTHING_SWEEPS smoothing
launches (each over one colour), one restriction (fused with the residual) and one prolongation
per level, plus one coarsest solve; no host loops over cells. On the finest level a V-cycle costs
about as much as 5 to 6 Jacobi-PCG iterations on the CPU. Written for "cpu" and "cuda" alike.
"""

from __future__ import annotations

import math

import warp as wp

from .grid import EMPTY, FLUID
from .cells import at, unit
from .launch import Recorded, Slabs, record
from .lines import Lines, in_box, line_end, line_first, make_lines, on_line, slab_planes
from . import threads
from .threads import Parallel

wp.set_module_options({"enable_backward": False})

MAX_COARSEST_CELLS = 64
SMOOTHING_SWEEPS = 2
COARSE_LAPLACIAN_SCALE = 0.5
PIVOT_TOLERANCE = 1e-9


@wp.struct
class Level:
    """One level's operator: (A x)_c = diag_c x_c - scale * sum over faces f of w_f x_n(f), n active.

    On the finest level the arrays are the PressureSystem's (w = inv_rho, scale = 1/dx^2, Dirichlet
    terms derived from the faces to EMPTY cells); on coarse ones scale = 1 and `dirichlet` holds them.
    """

    types: wp.array3d(dtype=wp.int32)
    w_u: wp.array3d(dtype=float)
    w_v: wp.array3d(dtype=float)
    w_w: wp.array3d(dtype=float)
    diag: wp.array3d(dtype=float)
    extra: wp.array3d(dtype=float)
    dirichlet: wp.array3d(dtype=float)
    scale: float
    dim: int
    finest: int
    box: Lines  # the active box [lo, hi): cells outside it are treated as outside the arrays
    done: wp.array(dtype=wp.int32)  # done[0] != 0: skip (the CG converged on the device)


@wp.func
def level_in_box(L: Level, c: wp.vec3i):
    return in_box(L.box.lo, L.box.hi, c)


@wp.func
def type_at(L: Level, c: wp.vec3i):
    """Cell type, or -1 outside the active box (which lies inside the arrays)."""
    if not level_in_box(L, c):
        return -1
    return L.types[c[0], c[1], c[2]]


@wp.func
def weight(L: Level, axis: int, f: wp.vec3i):
    if axis == 0:
        return L.w_u[f[0], f[1], f[2]]
    if axis == 1:
        return L.w_v[f[0], f[1], f[2]]
    return L.w_w[f[0], f[1], f[2]]



@wp.func
def neighbour_sum(L: Level, x: wp.array3d(dtype=float), i: int, j: int, k: int):
    """sum of w_f x_n over the faces of cell (i, j, k) to neighbours inside the active box.

    Relies on x = 0 on every cell of the box that is not an unknown (so faces to Dirichlet cells drop
    out). Neighbours outside the box are never unknowns; their faces are skipped, not read (a face
    past the box's high end belongs to a cell no launch covers, so it may hold an older solve's value).
    """
    # Sums grouped per axis as (low + high), skipped terms 0: on the whole grid this is the rounding of
    # the sum it replaced, term for term (the base solver's results are reproduced bit for bit).
    lo_t, hi_t = float(0.0), float(0.0)
    if i > L.box.lo[0]:
        lo_t = L.w_u[i, j, k] * x[i - 1, j, k]
    if i + 1 < L.box.hi[0]:
        hi_t = L.w_u[i + 1, j, k] * x[i + 1, j, k]
    s = lo_t + hi_t
    lo_t, hi_t = float(0.0), float(0.0)
    if j > L.box.lo[1]:
        lo_t = L.w_v[i, j, k] * x[i, j - 1, k]
    if j + 1 < L.box.hi[1]:
        hi_t = L.w_v[i, j + 1, k] * x[i, j + 1, k]
    s += lo_t + hi_t
    if L.dim == 3:
        lo_t, hi_t = float(0.0), float(0.0)
        if k > L.box.lo[2]:
            lo_t = L.w_w[i, j, k] * x[i, j, k - 1]
        if k + 1 < L.box.hi[2]:
            hi_t = L.w_w[i, j, k + 1] * x[i, j, k + 1]
        s += lo_t + hi_t
    return s


@wp.func
def neighbour_sum_inside(L: Level, x: wp.array3d(dtype=float), i: int, j: int, k: int):
    """neighbour_sum for a cell whose face neighbours all lie inside the active box: no term skipped,
    the same sums in the same order, without the tests."""
    s = L.w_u[i, j, k] * x[i - 1, j, k] + L.w_u[i + 1, j, k] * x[i + 1, j, k]
    s += L.w_v[i, j, k] * x[i, j - 1, k] + L.w_v[i, j + 1, k] * x[i, j + 1, k]
    if L.dim == 3:
        s += L.w_w[i, j, k] * x[i, j, k - 1] + L.w_w[i, j, k + 1] * x[i, j, k + 1]
    return s


@wp.func
def line_inside(L: Level, first: wp.vec3i, axis: int):
    """Every cell of the line through `first` has its neighbours across the line (off `axis`) in the box."""
    for a in range(L.dim):
        if a != axis:
            if first[a] <= L.box.lo[a] or first[a] + 1 >= L.box.hi[a]:
                return False
    return True


@wp.func
def cell_inside(L: Level, inside_line: bool, axis: int, s: int):
    """Cell s of a line with line_inside has both neighbours along the line in the box."""
    return inside_line and s > L.box.lo[axis] and s + 1 < L.box.hi[axis]


@wp.func
def residual(L: Level, b: wp.array3d(dtype=float), x: wp.array3d(dtype=float), c: wp.vec3i):
    return at(b, c) - at(L.diag, c) * at(x, c) + L.scale * neighbour_sum(L, x, c[0], c[1], c[2])


@wp.func
def dirichlet_term(L: Level, c: wp.vec3i):
    """Diagonal part of cell c from its Dirichlet neighbours."""
    if L.finest == 0:
        return at(L.dirichlet, c)
    s = float(0.0)
    for a in range(L.dim):
        e = unit(a)
        if type_at(L, c - e) == EMPTY:
            s += weight(L, a, c)
        if type_at(L, c + e) == EMPTY:
            s += weight(L, a, c + e)
    return L.scale * s


@wp.func
def coarse_coupling(F: Level, axis: int, f0: wp.vec3i):
    """Sum of the fine couplings over the 2^(dim-1) fine faces of the coarse face starting at face f0."""
    s = float(0.0)
    e = unit(axis)
    for t in range(4):
        o = (t % 2) * unit((axis + 1) % 3) + (t // 2) * unit((axis + 2) % 3)
        f = f0 + o
        if F.dim == 3 or o[2] == 0:
            if type_at(F, f - e) == FLUID:
                if type_at(F, f) == FLUID:
                    s += weight(F, axis, f)
    return F.scale * s


@wp.kernel
def build_coarse(F: Level, C: Level, walk: Lines, laplacian_scale: float):
    """The rows of the operator on `walk` (C's box, or a slab of it) from their fine children."""
    if C.done[0] != 0:
        return
    ti, tj, tk = wp.tid()
    first = line_first(walk, ti, tj, tk)
    for s in range(first[walk.axis], line_end(walk, first)):
        coarse_row(F, C, on_line(first, walk.axis, s), laplacian_scale)


@wp.func
def coarse_row(F: Level, C: Level, cc: wp.vec3i, laplacian_scale: float):
    """Coarse cell cc's row of the operator from its fine children."""
    i, j, k = cc[0], cc[1], cc[2]
    nz = 1
    if F.dim == 3:
        nz = 2
    extra = float(0.0)
    dirichlet = float(0.0)
    active = int(0)
    for ox in range(2):
        for oy in range(2):
            for oz in range(nz):
                c = 2 * cc + wp.vec3i(ox, oy, oz)
                if type_at(F, c) == FLUID:
                    active = 1
                    extra += at(F.extra, c)
                    dirichlet += dirichlet_term(F, c)
    dirichlet *= laplacian_scale
    diag = extra + dirichlet
    for a in range(F.dim):
        e = unit(a)
        lo = float(0.0)
        if active == 1:
            lo = laplacian_scale * coarse_coupling(F, a, 2 * cc)
            diag += lo + laplacian_scale * coarse_coupling(F, a, 2 * cc + 2 * e)
        if a == 0:
            C.w_u[i, j, k] = lo
        elif a == 1:
            C.w_v[i, j, k] = lo
        else:
            C.w_w[i, j, k] = lo
    if active == 0:
        C.types[i, j, k] = EMPTY
        diag = 1.0
    else:
        C.types[i, j, k] = FLUID
    C.diag[i, j, k] = diag
    C.extra[i, j, k] = extra
    C.dirichlet[i, j, k] = dirichlet


@wp.kernel
def smooth(L: Level, walk: Lines, b: wp.array3d(dtype=float), x: wp.array3d(dtype=float), color: int):
    """One colour of a red-black Gauss-Seidel sweep on A x = b over `walk` (the box, or a slab of it):
    the cells of that colour (parity of i + j + k, as on the whole grid) of each thread's line
    (core/lines.py). The colour's cells depend only on the other colour's, so slabs run at once."""
    if L.done[0] != 0:
        return
    ti, tj, tk = wp.tid()
    first = line_first(walk, ti, tj, tk)
    axis = walk.axis
    parity = (first[0] + first[1] + first[2] + color) % 2
    inside = line_inside(L, first, axis)
    for s in range(first[axis] + parity, line_end(walk, first), 2):
        c = on_line(first, axis, s)
        i, j, k = c[0], c[1], c[2]
        if L.types[i, j, k] == FLUID:
            d = L.diag[i, j, k]
            if d > 0.0:
                n = float(0.0)
                if cell_inside(L, inside, axis, s):
                    n = neighbour_sum_inside(L, x, i, j, k)
                else:
                    n = neighbour_sum(L, x, i, j, k)
                x[i, j, k] = (b[i, j, k] + L.scale * n) / d


@wp.kernel
def restrict_residual(
    F: Level, C: Level, walk: Lines, b: wp.array3d(dtype=float), x: wp.array3d(dtype=float),
    b_coarse: wp.array3d(dtype=float), x_coarse: wp.array3d(dtype=float),
):
    """b_coarse = P^T (b - A x), summed over the fluid children; x_coarse = 0 (over `walk`: C's box,
    or a slab of it)."""
    if C.done[0] != 0:
        return
    nz = 1
    if F.dim == 3:
        nz = 2
    ti, tj, tk = wp.tid()
    first = line_first(walk, ti, tj, tk)
    for line_s in range(first[walk.axis], line_end(walk, first)):
        cc = on_line(first, walk.axis, line_s)
        s = float(0.0)
        for ox in range(2):
            for oy in range(2):
                for oz in range(nz):
                    c = 2 * cc + wp.vec3i(ox, oy, oz)
                    if type_at(F, c) == FLUID:
                        s += residual(F, b, x, c)
        b_coarse[cc[0], cc[1], cc[2]] = s
        x_coarse[cc[0], cc[1], cc[2]] = 0.0


@wp.kernel
def prolongate(F: Level, walk: Lines, x_coarse: wp.array3d(dtype=float), x: wp.array3d(dtype=float)):
    """x += P x_coarse over `walk` (F's box, or a slab of it)."""
    if F.done[0] != 0:
        return
    ti, tj, tk = wp.tid()
    first = line_first(walk, ti, tj, tk)
    for s in range(first[walk.axis], line_end(walk, first)):
        c = on_line(first, walk.axis, s)
        i, j, k = c[0], c[1], c[2]
        if F.types[i, j, k] == FLUID:
            x[i, j, k] = x[i, j, k] + x_coarse[i // 2, j // 2, k // 2]


@wp.func
def dense_index(L: Level, c: wp.vec3i):
    return (c[0] * L.types.shape[1] + c[1]) * L.types.shape[2] + c[2]


@wp.kernel
def factor_coarsest(L: Level, A: wp.array2d(dtype=wp.float64), inv_pivot: wp.array(dtype=wp.float64)):
    """Assemble the coarsest operator densely (in float64) and factor it, A = L L^T in place (one thread).
    Cells outside the box get an identity row, like the other non-unknowns."""
    if L.done[0] != 0:
        return
    n = A.shape[0]
    for r in range(n):
        for c in range(n):
            A[r, c] = wp.float64(0.0)
    for i in range(L.types.shape[0]):
        for j in range(L.types.shape[1]):
            for k in range(L.types.shape[2]):
                cc = wp.vec3i(i, j, k)
                r = dense_index(L, cc)
                if type_at(L, cc) != FLUID:
                    A[r, r] = wp.float64(1.0)
                else:
                    d = wp.float64(at(L.extra, cc)) + wp.float64(dirichlet_term(L, cc))
                    for a in range(L.dim):
                        e = unit(a)
                        if type_at(L, cc - e) == FLUID:
                            w = wp.float64(L.scale * weight(L, a, cc))
                            A[r, dense_index(L, cc - e)] = -w
                            d += w
                        if type_at(L, cc + e) == FLUID:
                            w = wp.float64(L.scale * weight(L, a, cc + e))
                            A[r, dense_index(L, cc + e)] = -w
                            d += w
                    A[r, r] = d
    for j in range(n):
        s = A[j, j]
        for m in range(j):
            s -= A[j, m] * A[j, m]
        if s > wp.float64(PIVOT_TOLERANCE) * A[j, j]:
            ljj = wp.sqrt(s)
            A[j, j] = ljj
            inv_pivot[j] = wp.float64(1.0) / ljj
            for r in range(j + 1, n):
                t = A[r, j]
                for m in range(j):
                    t -= A[r, m] * A[j, m]
                A[r, j] = t / ljj
        else:  # (near-)null direction: drop it (pseudo-inverse)
            A[j, j] = wp.float64(0.0)
            inv_pivot[j] = wp.float64(0.0)
            for r in range(j + 1, n):
                A[r, j] = wp.float64(0.0)


@wp.kernel
def solve_coarsest(
    L: Level, A: wp.array2d(dtype=wp.float64), inv_pivot: wp.array(dtype=wp.float64),
    b: wp.array3d(dtype=float), y: wp.array(dtype=wp.float64), x: wp.array3d(dtype=float),
):
    """x = L^-T L^-1 b with the factor of factor_coarsest (one thread); b reads 0 outside the box."""
    if L.done[0] != 0:
        return
    n = A.shape[0]
    nyz = L.types.shape[1] * L.types.shape[2]
    nz = L.types.shape[2]
    for r in range(n):
        c = wp.vec3i(r // nyz, (r // nz) % L.types.shape[1], r % nz)
        t = wp.float64(0.0)
        if level_in_box(L, c):
            t = wp.float64(b[c[0], c[1], c[2]])
        for m in range(r):
            t -= A[r, m] * y[m]
        y[r] = t * inv_pivot[r]
    for q in range(n):
        r = n - 1 - q
        t = y[r]
        for m in range(r + 1, n):
            t -= A[m, r] * y[m]
        y[r] = t * inv_pivot[r]
        x[r // nyz, (r // nz) % L.types.shape[1], r % nz] = float(y[r])


def level_shapes(shape, dim: int) -> list[tuple[int, int, int]]:
    """Finest to coarsest: halve (rounding up) the simulated axes until at most MAX_COARSEST_CELLS."""
    shapes = [tuple(shape)]
    while math.prod(shapes[-1]) > MAX_COARSEST_CELLS and max(shapes[-1][:dim]) > 1:
        s = shapes[-1]
        shapes.append(tuple((n + 1) // 2 if a < dim else n for a, n in enumerate(s)))
    return shapes


def coarse_box(box, dim: int):
    """The parents of the cells of box [lo, hi) on the next coarser level."""
    lo, hi = box
    return (tuple(n // 2 if a < dim else n for a, n in enumerate(lo)),
            tuple((n - 1) // 2 + 1 if a < dim else n for a, n in enumerate(hi)))


class MultigridPreconditioner:
    """z = M^-1 r by one V-cycle; call build(system, box) once per solve before apply()."""

    def __init__(self, shape, dim: int, dx: float, device, *, sweeps: int = SMOOTHING_SWEEPS,
                 laplacian_scale: float = COARSE_LAPLACIAN_SCALE, parallel: Parallel | None = None):
        self.dim, self.device = dim, device
        self.parallel = parallel or Parallel(1)
        self.inv_dx2 = 1.0 / (dx * dx)
        self.sweeps, self.laplacian_scale = sweeps, laplacian_scale
        self.shapes = level_shapes(shape, dim)
        self.not_done = wp.zeros(1, dtype=wp.int32, device=device)  # the flag when no CG passes one
        self.levels = [Level()]  # the finest Level wraps the system's arrays, set by build()
        self.b, self.x = [None], [None]
        for s in self.shapes[1:]:
            zeros = lambda sh=s, dtype=float: wp.zeros(sh, dtype=dtype, device=device)  # noqa: E731
            L = Level()
            L.types = zeros(dtype=wp.int32)
            L.w_u, L.w_v, L.w_w = (zeros(tuple(n + (a == b) for b, n in enumerate(s))) for a in range(3))
            L.diag, L.extra, L.dirichlet = zeros(), zeros(), zeros()
            L.scale, L.dim, L.finest = 1.0, dim, 0
            self.levels.append(L)
            self.b.append(zeros())
            self.x.append(zeros())
        self.boxes = [((0, 0, 0), s) for s in self.shapes]
        n = math.prod(self.shapes[-1])
        self.factor = wp.zeros((n, n), dtype=wp.float64, device=device)
        self.inv_pivot = wp.zeros(n, dtype=wp.float64, device=device)
        self.y = wp.zeros(n, dtype=wp.float64, device=device)
        self.recorded = Recorded()  # the coarse operators' and the V-cycles' recorded launches (build)
        self.slabs = {}  # (level, number of slabs): the Slabs that recorded launches walk on that level

    def _launch(self, kernel, shape, inputs):
        wp.launch(kernel, shape, inputs=inputs, device=self.device)

    def build(self, system, box=None, done=None):
        """Wrap the fine system, build every coarse level from the one above, factor the coarsest.

        box: (lo, hi) on the finest level, containing every fluid cell and its face neighbours
        (default: the whole grid); done: the CG's exit flag (an int32 device array of one)."""
        self.boxes = [tuple(map(tuple, box)) if box is not None else ((0, 0, 0), self.shapes[0])]
        for _ in self.shapes[1:]:
            self.boxes.append(coarse_box(self.boxes[-1], self.dim))
        # The Levels are kept from solve to solve and written in place: the recorded launches hold them
        # by reference (core/launch.Slabs), so a level's new box reaches every launch that takes it.
        F = self.levels[0]
        F.types = system.types
        F.w_u, F.w_v, F.w_w = system.inv_rho
        F.diag, F.extra, F.dirichlet = system.diag, system.extra_diag, system.diag  # dirichlet unused here
        F.scale, F.dim, F.finest = self.inv_dx2, self.dim, 1
        self.dims = []  # each level's launch: a thread per line of its box (core/lines.py)
        for L, (lo, hi) in zip(self.levels, self.boxes):
            L.box, dims = make_lines(lo, hi, self.dim, self.device)
            self.dims.append(dims)
            L.done = self.not_done if done is None else done
        # Launches are recorded once and replayed while the levels' arrays, the flag, the threads and
        # the number of slabs of each launch stay the same from solve to solve (recording packs every
        # argument in Python); a moved box moves them (Slabs.move).
        split = [(self._count(lvl, lvl), self._count(lvl, lvl - 1)) for lvl in range(len(self.levels))]
        if not self.recorded.keep(F.types, system.inv_rho, F.diag, F.extra, F.done, self.parallel.threads, split,
                                  box=self.boxes):
            self.slabs = {}
        for (lvl, count), slabs in self.slabs.items():
            slabs.move(self.levels[lvl].box, self.dims[lvl])
        for lvl in range(1, len(self.levels)):  # a row reads only its children: slabs run at once
            batch = self.recorded.get(("coarse", lvl), lambda: self._parts(
                build_coarse, lvl, lambda walk: [self.levels[lvl - 1], self.levels[lvl], walk, self.laplacian_scale],
                work_level=lvl - 1))
            self.parallel.run([part.launch for part in batch])
        self._launch(factor_coarsest, 1, [self.levels[-1], self.factor, self.inv_pivot])

    def apply(self, r, z):
        """z = M^-1 r (one V-cycle from z = 0 on the box); r and z are fine-level cell arrays, z is 0
        outside the box. The cycle's launches are recorded once while the levels' arrays stay the same
        (Warp packs a launch's arguments in Python: 15-30 us a launch, about 10 ms a step at the peer
        block), moved with the box (build) and replayed."""
        cycle = self.recorded.get(("cycle", r.ptr, z.ptr), lambda: self._record_cycle(r, z))
        z.zero_()
        for batch in cycle:
            if len(batch) == 1:
                batch[0].launch()
            else:
                self.parallel.run([part.launch for part in batch])

    def _record_cycle(self, r, z):
        """The V-cycle as batches of recorded launches: a batch's launches (slabs of one kernel's box,
        on a level large enough to split; core/threads.py) run at once, batches one after another."""
        b, x, last, L = [r, *self.b[1:]], [z, *self.x[1:]], len(self.levels) - 1, self.levels
        batches = []

        def smoothing(lvl, colors):
            for _ in range(self.sweeps):
                for color in colors:
                    batches.append(self._parts(smooth, lvl, lambda walk: [L[lvl], walk, b[lvl], x[lvl], color]))

        for lvl in range(last):
            smoothing(lvl, (0, 1))
            batches.append(self._parts(restrict_residual, lvl + 1,  # its work: the finer level's cells
                                      lambda walk: [L[lvl], L[lvl + 1], walk, b[lvl], x[lvl], b[lvl + 1], x[lvl + 1]],
                                      work_level=lvl))
        batches.append([self._record(solve_coarsest, 1, [L[last], self.factor, self.inv_pivot, b[last], self.y, x[last]])])
        for lvl in range(last - 1, -1, -1):
            batches.append(self._parts(prolongate, lvl, lambda walk: [L[lvl], walk, x[lvl + 1], x[lvl]]))
            smoothing(lvl, (1, 0))
        return batches

    def _record(self, kernel, dims, inputs):
        return record(kernel, dims, inputs, self.device)

    def _count(self, lvl, work_level):
        """The slabs of a launch over level lvl's box whose work is level work_level's cells (the level
        itself, or for the restriction and the coarse operators the finer one): one per thread when
        they number threads.SPLIT_CELLS or more (each slab costs a thread hand-off), else one."""
        if work_level < 0:
            return 1
        work = math.prod(self.dims[work_level]) * self.levels[work_level].box.length
        parts = self.parallel.threads if work >= threads.SPLIT_CELLS else 1
        return len(slab_planes(self.dims[lvl][0], parts))

    def _parts(self, kernel, lvl, inputs, work_level=None):
        """Recorded launches of `kernel` over level lvl's box, split into slabs by the cells it works on
        (level work_level's box, by default lvl's: _count); they walk lvl's Slabs, which move with the
        box."""
        count = self._count(lvl, lvl if work_level is None else work_level)
        slabs = self.slabs.get((lvl, count))
        if slabs is None:
            slabs = self.slabs[lvl, count] = Slabs(count)
            slabs.move(self.levels[lvl].box, self.dims[lvl])
        return slabs.record(kernel, inputs, self.device)
