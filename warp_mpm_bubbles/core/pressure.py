"""Pressure projection: a matrix-free SPD operator and a preconditioned conjugate gradient.

The operator is ``A p = -div(1/rho grad p)`` over fluid cells (empty cells are Dirichlet p = 0 gauge,
solid faces Neumann), plus, from issue #3 on, a per-cell ``kappa/dt^2`` term for the gas. The CG is
hand-written because ``warp.optim.linear.cg`` spends most of its CPU time in its reduction kernel
(docs/design.md, #cg-on-warp); each iteration is three launches and two scalar read-backs (plus one V-cycle and one
dot product with the multigrid preconditioner of multigrid.py).

Preconditioners: "none", "jacobi" (diagonal), "multigrid" (one symmetric V-cycle). Jacobi-PCG
iterations grow linearly with the resolution and with the density ratio; multigrid-PCG's barely
grow (benchmarks/pressure_solver.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import warp as wp

from .grid import EMPTY, FLUID, PRECONDITIONERS
from .multigrid import MultigridPreconditioner

wp.set_module_options({"enable_backward": False})

NONE, JACOBI, MULTIGRID = range(3)  # indices of PRECONDITIONERS


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


@wp.kernel
def apply_operator(
    types: wp.array3d(dtype=wp.int32),
    diag: wp.array3d(dtype=float),
    inv_rho_u: wp.array3d(dtype=float),
    inv_rho_v: wp.array3d(dtype=float),
    inv_rho_w: wp.array3d(dtype=float),
    inv_dx2: float,
    dim: int,
    p: wp.array3d(dtype=float),
    out: wp.array3d(dtype=float),
    dots: wp.array(dtype=wp.float64),
):
    """out = A p on fluid cells (0 elsewhere); dots[0] += p . A p."""
    i, j, k = wp.tid()
    if types[i, j, k] != FLUID:
        out[i, j, k] = 0.0
        return
    # Neighbours that are not fluid contribute nothing: empty ones are p = 0, solid faces have 1/rho = 0.
    s = inv_rho_u[i, j, k] * fluid_value(types, p, i - 1, j, k)
    s += inv_rho_u[i + 1, j, k] * fluid_value(types, p, i + 1, j, k)
    s += inv_rho_v[i, j, k] * fluid_value(types, p, i, j - 1, k)
    s += inv_rho_v[i, j + 1, k] * fluid_value(types, p, i, j + 1, k)
    if dim == 3:
        s += inv_rho_w[i, j, k] * fluid_value(types, p, i, j, k - 1)
        s += inv_rho_w[i, j, k + 1] * fluid_value(types, p, i, j, k + 1)
    Ap = diag[i, j, k] * p[i, j, k] - s * inv_dx2
    out[i, j, k] = Ap
    wp.atomic_add(dots, 0, wp.float64(p[i, j, k] * Ap))


@wp.kernel
def mask_to_fluid(types: wp.array3d(dtype=wp.int32), x: wp.array3d(dtype=float)):
    i, j, k = wp.tid()
    if types[i, j, k] != FLUID:
        x[i, j, k] = 0.0


@wp.kernel
def fluid_sum(types: wp.array3d(dtype=wp.int32), x: wp.array3d(dtype=float), dots: wp.array(dtype=wp.float64)):
    """dots[0] += sum of x over fluid cells; dots[1] += x . x."""
    i, j, k = wp.tid()
    if types[i, j, k] == FLUID:
        wp.atomic_add(dots, 0, wp.float64(x[i, j, k]))
        wp.atomic_add(dots, 1, wp.float64(x[i, j, k] * x[i, j, k]))


@wp.kernel
def fluid_dot(types: wp.array3d(dtype=wp.int32), x: wp.array3d(dtype=float), y: wp.array3d(dtype=float),
              dots: wp.array(dtype=wp.float64)):
    """dots[0] += x . y, dots[1] += sum of y over fluid cells."""
    i, j, k = wp.tid()
    if types[i, j, k] == FLUID:
        wp.atomic_add(dots, 0, wp.float64(x[i, j, k] * y[i, j, k]))
        wp.atomic_add(dots, 1, wp.float64(y[i, j, k]))


@wp.kernel
def shift_fluid(types: wp.array3d(dtype=wp.int32), x: wp.array3d(dtype=float), shift: float):
    i, j, k = wp.tid()
    if types[i, j, k] == FLUID:
        x[i, j, k] = x[i, j, k] + shift


@wp.kernel
def start_iteration(
    b: wp.array3d(dtype=float),
    Ax: wp.array3d(dtype=float),
    diag: wp.array3d(dtype=float),
    mode: int,
    r: wp.array3d(dtype=float),
    d: wp.array3d(dtype=float),
    dots: wp.array(dtype=wp.float64),
):
    """r = b - A x, d = M^-1 r; dots[0] += sum r, dots[1] += r . r, dots[2] += r . M^-1 r."""
    i, j, k = wp.tid()
    res = b[i, j, k] - Ax[i, j, k]
    z = preconditioned(res, diag[i, j, k], mode)
    r[i, j, k] = res
    d[i, j, k] = z
    wp.atomic_add(dots, 0, wp.float64(res))
    wp.atomic_add(dots, 1, wp.float64(res * res))
    wp.atomic_add(dots, 2, wp.float64(res * z))


@wp.kernel
def step_solution(
    alpha: float,
    d: wp.array3d(dtype=float),
    Ad: wp.array3d(dtype=float),
    diag: wp.array3d(dtype=float),
    mode: int,
    x: wp.array3d(dtype=float),
    r: wp.array3d(dtype=float),
    z: wp.array3d(dtype=float),
    dots: wp.array(dtype=wp.float64),
):
    """x += alpha d, r -= alpha A d, z = M^-1 r; dots[0] += sum r, dots[1] += r . r, dots[2] += r . z."""
    i, j, k = wp.tid()
    x[i, j, k] = x[i, j, k] + alpha * d[i, j, k]
    res = r[i, j, k] - alpha * Ad[i, j, k]
    zz = preconditioned(res, diag[i, j, k], mode)
    r[i, j, k] = res
    z[i, j, k] = zz
    wp.atomic_add(dots, 0, wp.float64(res))
    wp.atomic_add(dots, 1, wp.float64(res * res))
    wp.atomic_add(dots, 2, wp.float64(res * zz))


@wp.kernel
def update_direction(z: wp.array3d(dtype=float), beta: float, d: wp.array3d(dtype=float)):
    i, j, k = wp.tid()
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

    Dot products are accumulated in float64 by the kernels that already touch the data (on the CPU
    the atomics run in thread order, so results are deterministic), which leaves three launches
    and two scalar read-backs per iteration: small grids are bound by launch overhead, not flops.
    """

    def __init__(self, shape, dim: int, dx: float, device):
        self.dim, self.dx = dim, dx
        self.inv_dx2 = 1.0 / (dx * dx)
        self.device = device
        self.shape = shape
        zeros = lambda: wp.zeros(shape, dtype=float, device=device)  # noqa: E731
        self.r, self.z, self.d, self.Ad = zeros(), zeros(), zeros(), zeros()
        self.dots = wp.zeros(3, dtype=wp.float64, device=device)
        self.multigrid = None  # built on first use

    def _launch(self, kernel, inputs):
        wp.launch(kernel, self.shape, inputs=inputs, device=self.device)

    def _dots(self, kernel, inputs):
        """Launch a kernel that accumulates into self.dots, and read the sums back."""
        self.dots.zero_()
        self._launch(kernel, [*inputs, self.dots])
        return self.dots.numpy().copy()

    def _fluid_sum(self, types, x):
        return self._dots(fluid_sum, [types, x])

    def _v_cycle(self, types, r, z, r_sum: float, n_project: int):
        """z = M^-1 r by the multigrid V-cycle; returns r . z.

        n_project > 0 (a singular system with that many fluid cells): r and z are first projected
        onto the range (mean zero). Round-off leaves r a small constant part, which the V-cycle
        would amplify (the constant is its near-null direction) and CG then loses orthogonality.
        """
        if n_project:
            self._launch(shift_fluid, [types, r, float(-r_sum / n_project)])
        self.multigrid.apply(r, z)
        rz, z_sum, _ = self._dots(fluid_dot, [types, r, z])
        if n_project:
            self._launch(shift_fluid, [types, z, float(-z_sum / n_project)])
        return rz

    def solve(self, system: PressureSystem, b, x, *, tol: float, max_iter: int, singular: bool, n_fluid: int,
              preconditioner: str = "multigrid"):
        """Solve A x = b in place; x holds the warm start. preconditioner: "none" | "jacobi" | "multigrid"."""
        mode = PRECONDITIONERS.index(preconditioner)
        types, diag, inv_rho = system.types, system.diag, system.inv_rho
        apply = lambda p, out: self._dots(  # noqa: E731
            apply_operator, [types, diag, *inv_rho, self.inv_dx2, self.dim, p, out])[0]
        if singular and n_fluid > 0:
            # Closed tank: only b's component orthogonal to constants is reachable.
            self._launch(shift_fluid, [types, b, float(-self._fluid_sum(types, b)[0] / n_fluid)])
        self._launch(mask_to_fluid, [types, x])
        b_norm = math.sqrt(self._fluid_sum(types, b)[1])
        if b_norm == 0.0:
            x.zero_()
            return SolveInfo(0, 0.0, True)
        if mode == MULTIGRID:
            if self.multigrid is None:
                self.multigrid = MultigridPreconditioner(self.shape, self.dim, self.dx, self.device)
            self.multigrid.build(system)

        apply(x, self.Ad)
        project = n_fluid if singular else 0
        r_sum, rr, rz = self._dots(start_iteration, [b, self.Ad, diag, mode, self.r, self.d])
        if mode == MULTIGRID:
            rz = self._v_cycle(types, self.r, self.d, r_sum, project)
        rel = math.sqrt(rr) / b_norm
        it = 0
        while rel > tol and it < max_iter:
            dAd = apply(self.d, self.Ad)
            if dAd <= 0.0:
                break  # search direction lost positivity (round-off at convergence)
            r_sum, rr, rz_new = self._dots(
                step_solution, [float(rz / dAd), self.d, self.Ad, diag, mode, x, self.r, self.z])
            it += 1
            rel = math.sqrt(rr) / b_norm
            if rel <= tol:
                break
            if mode == MULTIGRID:
                rz_new = self._v_cycle(types, self.r, self.z, r_sum, project)
            self._launch(update_direction, [self.z, float(rz_new / rz), self.d])
            rz = rz_new
        if singular and n_fluid > 0:
            self._launch(shift_fluid, [types, x, float(-self._fluid_sum(types, x)[0] / n_fluid)])
        return SolveInfo(it, rel, rel <= tol)
