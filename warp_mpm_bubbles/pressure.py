"""Pressure projection: a matrix-free SPD operator and a preconditioned conjugate gradient.

The operator is ``A p = -div(1/rho grad p)`` over fluid cells (empty cells are Dirichlet p = 0 gauge,
solid faces Neumann), plus, from issue #3 on, a per-cell ``kappa/dt^2`` term for the gas. The CG is
hand-written because ``warp.optim.linear.cg`` spends most of its CPU time in its reduction kernel
(DESIGN §7); each iteration is three launches and two scalar read-backs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import warp as wp

from .grid import FLUID

wp.set_module_options({"enable_backward": False})


@wp.func
def fluid_value(types: wp.array3d(dtype=wp.int32), p: wp.array3d(dtype=float), i: int, j: int, k: int):
    if i < 0 or j < 0 or k < 0 or i >= p.shape[0] or j >= p.shape[1] or k >= p.shape[2]:
        return 0.0
    if types[i, j, k] != FLUID:
        return 0.0
    return p[i, j, k]


@wp.func
def preconditioned(r: float, diag: float, jacobi: int):
    if jacobi == 1:
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
def shift_fluid(types: wp.array3d(dtype=wp.int32), x: wp.array3d(dtype=float), shift: float):
    i, j, k = wp.tid()
    if types[i, j, k] == FLUID:
        x[i, j, k] = x[i, j, k] + shift


@wp.kernel
def start_iteration(
    b: wp.array3d(dtype=float),
    Ax: wp.array3d(dtype=float),
    diag: wp.array3d(dtype=float),
    jacobi: int,
    r: wp.array3d(dtype=float),
    d: wp.array3d(dtype=float),
    dots: wp.array(dtype=wp.float64),
):
    """r = b - A x, d = M^-1 r; dots[1] += r . r, dots[2] += r . M^-1 r."""
    i, j, k = wp.tid()
    res = b[i, j, k] - Ax[i, j, k]
    z = preconditioned(res, diag[i, j, k], jacobi)
    r[i, j, k] = res
    d[i, j, k] = z
    wp.atomic_add(dots, 1, wp.float64(res * res))
    wp.atomic_add(dots, 2, wp.float64(res * z))


@wp.kernel
def step_solution(
    alpha: float,
    d: wp.array3d(dtype=float),
    Ad: wp.array3d(dtype=float),
    diag: wp.array3d(dtype=float),
    jacobi: int,
    x: wp.array3d(dtype=float),
    r: wp.array3d(dtype=float),
    z: wp.array3d(dtype=float),
    dots: wp.array(dtype=wp.float64),
):
    """x += alpha d, r -= alpha A d, z = M^-1 r; dots[1] += r . r, dots[2] += r . z."""
    i, j, k = wp.tid()
    x[i, j, k] = x[i, j, k] + alpha * d[i, j, k]
    res = r[i, j, k] - alpha * Ad[i, j, k]
    zz = preconditioned(res, diag[i, j, k], jacobi)
    r[i, j, k] = res
    z[i, j, k] = zz
    wp.atomic_add(dots, 1, wp.float64(res * res))
    wp.atomic_add(dots, 2, wp.float64(res * zz))


@wp.kernel
def update_direction(z: wp.array3d(dtype=float), beta: float, d: wp.array3d(dtype=float)):
    i, j, k = wp.tid()
    d[i, j, k] = z[i, j, k] + beta * d[i, j, k]


@dataclass
class SolveInfo:
    iterations: int
    residual: float  # ||b - A x|| / ||b|| at exit
    converged: bool


class PressureSolver:
    """PCG on the fluid cells of one grid; scratch arrays are allocated once.

    Dot products are accumulated in float64 by the kernels that already touch the data (on the CPU
    the atomics run in thread order, so results are deterministic), which leaves three launches
    and two scalar read-backs per iteration: small grids are bound by launch overhead, not flops.
    """

    def __init__(self, shape, dim: int, dx: float, device):
        self.dim = dim
        self.inv_dx2 = 1.0 / (dx * dx)
        self.device = device
        self.shape = shape
        zeros = lambda: wp.zeros(shape, dtype=float, device=device)  # noqa: E731
        self.r, self.z, self.d, self.Ad = zeros(), zeros(), zeros(), zeros()
        self.dots = wp.zeros(3, dtype=wp.float64, device=device)

    def _launch(self, kernel, inputs):
        wp.launch(kernel, self.shape, inputs=inputs, device=self.device)

    def _dots(self, kernel, inputs):
        """Launch a kernel that accumulates into self.dots, and read the sums back."""
        self.dots.zero_()
        self._launch(kernel, [*inputs, self.dots])
        return self.dots.numpy().copy()

    def _fluid_sum(self, types, x):
        return self._dots(fluid_sum, [types, x])

    def solve(self, system, b, x, *, tol: float, max_iter: int, jacobi: bool, singular: bool, n_fluid: int):
        """Solve A x = b in place (x holds the warm start). system = (types, diag, (inv_rho_u, _v, _w))."""
        types, diag, inv_rho = system
        jacobi = int(jacobi)
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

        apply(x, self.Ad)
        _, rr, rz = self._dots(start_iteration, [b, self.Ad, diag, jacobi, self.r, self.d])
        rel = math.sqrt(rr) / b_norm
        it = 0
        while rel > tol and it < max_iter:
            dAd = apply(self.d, self.Ad)
            if dAd <= 0.0:
                break  # search direction lost positivity (round-off at convergence)
            _, rr, rz_new = self._dots(
                step_solution, [float(rz / dAd), self.d, self.Ad, diag, jacobi, x, self.r, self.z])
            it += 1
            rel = math.sqrt(rr) / b_norm
            if rel <= tol:
                break
            self._launch(update_direction, [self.z, float(rz_new / rz), self.d])
            rz = rz_new
        if singular and n_fluid > 0:
            self._launch(shift_fluid, [types, x, float(-self._fluid_sum(types, x)[0] / n_fluid)])
        return SolveInfo(it, rel, rel <= tol)
