"""Pressure projection: a matrix-free SPD operator and a preconditioned conjugate gradient.

The operator is ``A p = -div(1/rho grad p)`` over fluid cells (empty cells are Dirichlet p = 0 gauge,
solid faces Neumann), plus, from issue #3 on, a per-cell ``kappa/dt^2`` term for the gas. The CG is
hand-written on ``wp.utils.array_inner`` because ``warp.optim.linear.cg`` spends most of its CPU
time in its reduction kernel (DESIGN §7). Each iteration costs one operator application, three
small update kernels and three scalar reductions read back to the host.
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
):
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
    out[i, j, k] = diag[i, j, k] * p[i, j, k] - s * inv_dx2


@wp.kernel
def mask_to_fluid(types: wp.array3d(dtype=wp.int32), x: wp.array3d(dtype=float)):
    i, j, k = wp.tid()
    if types[i, j, k] != FLUID:
        x[i, j, k] = 0.0


@wp.kernel
def shift_fluid(types: wp.array3d(dtype=wp.int32), x: wp.array3d(dtype=float), shift: float):
    i, j, k = wp.tid()
    if types[i, j, k] == FLUID:
        x[i, j, k] = x[i, j, k] + shift


@wp.kernel
def residual(b: wp.array3d(dtype=float), Ax: wp.array3d(dtype=float), r: wp.array3d(dtype=float)):
    i, j, k = wp.tid()
    r[i, j, k] = b[i, j, k] - Ax[i, j, k]


@wp.kernel
def precondition(
    r: wp.array3d(dtype=float), diag: wp.array3d(dtype=float), jacobi: int, z: wp.array3d(dtype=float)
):
    i, j, k = wp.tid()
    if jacobi == 1:
        z[i, j, k] = r[i, j, k] / diag[i, j, k]
    else:
        z[i, j, k] = r[i, j, k]


@wp.kernel
def step_solution(
    alpha: float,
    d: wp.array3d(dtype=float),
    Ad: wp.array3d(dtype=float),
    x: wp.array3d(dtype=float),
    r: wp.array3d(dtype=float),
):
    i, j, k = wp.tid()
    x[i, j, k] = x[i, j, k] + alpha * d[i, j, k]
    r[i, j, k] = r[i, j, k] - alpha * Ad[i, j, k]


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
    """PCG on the fluid cells of one grid; scratch arrays are allocated once."""

    def __init__(self, shape, dim: int, dx: float, device):
        self.dim = dim
        self.inv_dx2 = 1.0 / (dx * dx)
        self.device = device
        self.shape = shape
        zeros = lambda: wp.zeros(shape, dtype=float, device=device)  # noqa: E731
        self.r, self.z, self.d, self.Ad = zeros(), zeros(), zeros(), zeros()

    def _apply(self, system, x, out):
        types, diag, inv_rho = system
        wp.launch(
            apply_operator,
            self.shape,
            inputs=[types, diag, inv_rho[0], inv_rho[1], inv_rho[2], self.inv_dx2, self.dim, x, out],
            device=self.device,
        )

    def solve(self, system, b, x, *, tol: float, max_iter: int, jacobi: bool, singular: bool, n_fluid: int):
        """Solve A x = b in place (x holds the warm start). system = (types, diag, (inv_rho_u, _v, _w))."""
        types, diag, _ = system
        launch = lambda kernel, inputs: wp.launch(kernel, self.shape, inputs=inputs, device=self.device)  # noqa: E731
        if singular and n_fluid > 0:
            # Closed tank: only b's component orthogonal to constants is reachable.
            launch(shift_fluid, [types, b, -wp.utils.array_sum(b) / n_fluid])
        launch(mask_to_fluid, [types, x])
        b_norm = math.sqrt(wp.utils.array_inner(b, b))
        if b_norm == 0.0:
            x.zero_()
            return SolveInfo(0, 0.0, True)

        self._apply(system, x, self.Ad)
        launch(residual, [b, self.Ad, self.r])
        launch(precondition, [self.r, diag, int(jacobi), self.z])
        self.d.assign(self.z)
        rz = wp.utils.array_inner(self.r, self.z)
        rel = math.sqrt(wp.utils.array_inner(self.r, self.r)) / b_norm
        it = 0
        while rel > tol and it < max_iter:
            self._apply(system, self.d, self.Ad)
            dAd = wp.utils.array_inner(self.d, self.Ad)
            if dAd <= 0.0:
                break  # search direction lost positivity (round-off at convergence)
            launch(step_solution, [rz / dAd, self.d, self.Ad, x, self.r])
            it += 1
            rel = math.sqrt(wp.utils.array_inner(self.r, self.r)) / b_norm
            if rel <= tol:
                break
            launch(precondition, [self.r, diag, int(jacobi), self.z])
            rz_new = wp.utils.array_inner(self.r, self.z)
            launch(update_direction, [self.z, rz_new / rz, self.d])
            rz = rz_new
        if singular and n_fluid > 0:
            launch(shift_fluid, [types, x, -wp.utils.array_sum(x) / n_fluid])
        return SolveInfo(it, rel, rel <= tol)
