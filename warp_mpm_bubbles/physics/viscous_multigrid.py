"""A multigrid V-cycle preconditioner for the implicit viscous solve (physics/viscous_solve.py), one
per velocity component, on that component's face grid.

The preconditioner keeps the block structure of the symmetric Gauss-Seidel one it can replace
(physics/viscous_pcg.py): M is block diagonal, one block per component, each block the matrix's
own coupling of that component's faces (the cross terms du_b/dx_a between components are left
out). A component's block is a 5-point (3D: 7-point) stencil on its face grid:

    (A z)_f = diag_f z_f - dt/dx^2 sum_n w_fn z_n

with w = 2 mu_c to the faces along the component's own axis (through the cell between them) and
w = mu_e to the faces across (through the edge between them); diag_f = rho_f + dt K_ff. That is
the shape of the pressure system's operator, so the pressure's V-cycle (core/multigrid.py: red-black
Gauss-Seidel smoothing, piecewise-constant transfers, Galerkin coarse operators with the Laplacian
part halved, a dense Cholesky on the coarsest level) runs on it unchanged: this module only builds
the finest level from the viscous system. The finest Level uses the multigrid's "coarse" form
(finest = 0), its terms given by arrays:

    types      FLUID on the unknown faces (inv_rho > 0), EMPTY elsewhere (z = 0 there)
    w_a        2 mu_c of the cell below each face along a; w_b: the plane (a, b)'s edge viscosities
    extra      rho_f: the mass term, exact on every level (constants represent it), never halved
    dirichlet  the rest of diag_f: its couplings to faces that are not unknowns (walls, EMPTY
               cells' faces) and the no-slip walls' mirror terms; halved on coarse levels like
               the couplings

Each V-cycle is a symmetric positive definite operator (core/multigrid.py), so M is too and the
PCG stays valid. The hierarchy is rebuilt every solve (viscosities, densities and dt change every
step): a kernel per component for the finest level, then one per coarse level.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..core.grid import EMPTY, FLUID
from ..core.cells import unit
from ..core.lines import Lines, line_end, line_first, make_lines
from ..core.multigrid import Level, MultigridPreconditioner, build_coarse, coarse_box, factor_coarsest
from .viscous_pcg import AroundFace, value_at

wp.set_module_options({"enable_backward": False})

# V-cycle smoothing sweeps (red, black) on the way down and (black, red) up: one (with it a V-cycle
# costs about six of the PCG's Gauss-Seidel half-sweeps at 80 x 160 cells; more were not measured).
VISCOUS_SWEEPS = 1


@wp.func
def unknown(inv_rho: wp.array3d(dtype=float), g: wp.vec3i):
    """1 on an unknown face (inv_rho > 0), 0 elsewhere and outside the array."""
    return float(value_at(inv_rho, g) > 0.0)


@wp.kernel
def face_level(a: int, scale: float, inv_rho: wp.array3d(dtype=float), diag: wp.array3d(dtype=float),
               mu: AroundFace, types: wp.array3d(dtype=wp.int32), w_normal: wp.array3d(dtype=float),
               extra: wp.array3d(dtype=float), dirichlet: wp.array3d(dtype=float)):
    """The finest Level of component a's block at face f (scale = dt / dx^2): its type, the coupling
    2 mu_c to the face below it along a, its mass term and the part of its diagonal that no unknown
    neighbour accounts for (never below 0, so rounding cannot make the coarse levels indefinite)."""
    i, j, k = wp.tid()
    f = wp.vec3i(i, j, k)
    ua = unit(a)
    w_normal[i, j, k] = 2.0 * value_at(mu.cells, f - ua)
    ir = inv_rho[i, j, k]
    if ir == 0.0:
        types[i, j, k] = EMPTY
        extra[i, j, k] = 0.0
        dirichlet[i, j, k] = 0.0
        return
    types[i, j, k] = FLUID
    coupled = 2.0 * (value_at(mu.cells, f) * unknown(inv_rho, f + ua) + value_at(mu.cells, f - ua) * unknown(inv_rho, f - ua))
    u1 = unit(mu.b1)
    coupled += value_at(mu.edges_1, f + u1) * unknown(inv_rho, f + u1) + value_at(mu.edges_1, f) * unknown(inv_rho, f - u1)
    if mu.b2 >= 0:
        u2 = unit(mu.b2)
        coupled += (value_at(mu.edges_2, f + u2) * unknown(inv_rho, f + u2)
                    + value_at(mu.edges_2, f) * unknown(inv_rho, f - u2))
    rho = 1.0 / ir
    extra[i, j, k] = rho
    dirichlet[i, j, k] = wp.max(diag[i, j, k] - rho - scale * coupled, 0.0)


@wp.kernel
def pcg_residual(walk: Lines, alpha: float, d: wp.array3d(dtype=float), Ad: wp.array3d(dtype=float),
                 x: wp.array3d(dtype=float), r: wp.array3d(dtype=float), dots: wp.array2d(dtype=wp.float64)):
    """x += alpha d, r -= alpha A d; dots[1] += r . r (the V-cycle then sets z = M^-1 r)."""
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
    wp.atomic_add(dots, first[0], 1, acc)


@wp.kernel
def dot_rz(walk: Lines, r: wp.array3d(dtype=float), z: wp.array3d(dtype=float), dots: wp.array2d(dtype=wp.float64)):
    """dots[2] += r . z."""
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
        acc += wp.float64(r[i, j, k] * z[i, j, k])
    wp.atomic_add(dots, first[0], 2, acc)


def unknowns_box(inv_rho, dim: int):
    """The unknown faces' bounding box grown by one face (their neighbours), within the array; None
    when there is none."""
    ir = inv_rho.numpy()
    shape = ir.shape
    lo, hi = [0, 0, 0], list(shape)
    for a in range(dim):
        rest = tuple(b for b in range(3) if b != a)
        present = np.nonzero(ir.max(axis=rest) > 0.0)[0]
        if len(present) == 0:
            return None
        lo[a], hi[a] = max(int(present[0]) - 1, 0), min(int(present[-1]) + 2, shape[a])
    return tuple(lo), tuple(hi)


class FaceMultigrid(MultigridPreconditioner):
    """z = M^-1 r by one V-cycle of core/multigrid.py on the face grid of axis `axis`; build() once per
    solve, then apply(r, z) as often as needed."""

    def __init__(self, shape, axis: int, dim: int, device, *, sweeps: int = VISCOUS_SWEEPS, parallel=None):
        super().__init__(shape, dim, 1.0, device, sweeps=sweeps, parallel=parallel)
        self.axis = axis
        zeros = lambda sh, dtype=float: wp.zeros(sh, dtype=dtype, device=device)  # noqa: E731
        self.types = zeros(shape, wp.int32)
        self.w_normal = zeros(tuple(n + int(b == axis) for b, n in enumerate(shape)))
        self.extra, self.dirichlet = zeros(shape), zeros(shape)

    def build_faces(self, scale: float, inv_rho, diag, mu: AroundFace, box):
        """The finest level from the viscous system (scale = dt / dx^2; mu: the viscosities around
        this axis's faces), then the coarse levels and the coarsest factor over `box` (lo, hi)."""
        a = self.axis
        wp.launch(face_level, inv_rho.shape, inputs=[a, float(scale), inv_rho, diag, mu, self.types, self.w_normal,
                                                     self.extra, self.dirichlet], device=self.device)
        F = Level()
        F.types, F.diag, F.extra, F.dirichlet = self.types, diag, self.extra, self.dirichlet
        w = [self.w_normal] * 3
        w[mu.b1] = mu.edges_1
        if mu.b2 >= 0:
            w[mu.b2] = mu.edges_2
        F.w_u, F.w_v, F.w_w = w
        F.scale, F.dim, F.finest = float(scale), self.dim, 0
        self._hierarchy(F, box)

    def _hierarchy(self, F: Level, box):
        """As MultigridPreconditioner.build after its finest level: the boxes of every level, the
        coarse operators level by level (slabs at once), the coarsest factor."""
        self.boxes = [tuple(map(tuple, box))]
        for _ in self.shapes[1:]:
            self.boxes.append(coarse_box(self.boxes[-1], self.dim))
        self.levels[0] = F
        self.dims = []
        for L, (lo, hi) in zip(self.levels, self.boxes):
            L.box, dims = make_lines(lo, hi, self.dim, self.device)
            self.dims.append(dims)
            L.done = self.not_done
        for lvl in range(1, len(self.levels)):
            batch = self._parts(build_coarse, lvl, lambda walk: [self.levels[lvl - 1], self.levels[lvl], walk,
                                                                 self.laplacian_scale], work_level=lvl - 1)
            self.parallel.run([part.launch for part in batch])
        self._launch(factor_coarsest, 1, [self.levels[-1], self.factor, self.inv_pivot])
        self._cycles = {}

