"""The optional forces on u* before the pressure solve, each run only when a material asks for it:

- surface tension (a liquid's surface_tension > 0): the liquid's level set, its smoothing and
  curvature, and the Laplace pressure jump on the faces of the liquid's surface; after g2p, gas
  films thinner than a cell retract into the bubble beside them (sharp interface, gas_films);
- viscosity (any material's viscosity > 0): explicit diffusion of the face velocities.
"""

import warp as wp

from ..core.grid import PHASE_GAS, SOLID_NO_SLIP
from ..core.grid_kernels import (
    block_offset, block_size, cell_centre, cell_of, cell_type_at, is_liquid_cell, is_phase_cell, is_solid, unit,
)
from ..core.transfer_kernels import clamp_to_domain

wp.set_module_options({"enable_backward": False})


@wp.kernel
def liquid_level_set(liq_volume: wp.array3d(dtype=float), inv_cell_vol: float, level: wp.array3d(dtype=float)):
    """psi = 2 phi_liquid - 1 in [-1, 1]: > 0 in the liquid, < 0 in gas or air, 0 on its surface."""
    i, j, k = wp.tid()
    level[i, j, k] = wp.clamp(2.0 * liq_volume[i, j, k] * inv_cell_vol - 1.0, -1.0, 1.0)


@wp.func
def level_at(level: wp.array3d(dtype=float), types: wp.array3d(dtype=wp.int32), c: wp.vec3i, fallback: wp.vec3i):
    """The level set at c; solid cells (and the array's edge) mirror `fallback`: a 90 degree contact."""
    d = c
    if is_solid(cell_type_at(types, c)):
        d = fallback
    return level[d[0], d[1], d[2]]


@wp.kernel
def smooth_level_set(
    types: wp.array3d(dtype=wp.int32), level: wp.array3d(dtype=float), dim: int, out: wp.array3d(dtype=float)
):
    """One pass of the binomial filter (1 2 1)/4 per axis. Particle jitter makes psi noisy at the
    scale of a cell; its second derivatives (the curvature) would turn that noise into spurious
    capillary currents."""
    i, j, k = wp.tid()
    c = wp.vec3i(i, j, k)
    value = level[i, j, k]
    if is_solid(types[i, j, k]):
        out[i, j, k] = value
        return
    total = float(0.0)
    weight = float(0.0)
    for q in range(block_size(dim)):
        o = block_offset(q, dim)
        w = float((2 - wp.abs(o[0])) * (2 - wp.abs(o[1])) * (2 - wp.abs(o[2])))
        total += w * level_at(level, types, c + o, c)
        weight += w
    out[i, j, k] = total / weight


@wp.kernel
def surface_curvature(
    types: wp.array3d(dtype=wp.int32),
    level: wp.array3d(dtype=float),
    dx: float,
    dim: int,
    curvature: wp.array3d(dtype=float),
):
    """kappa = div(grad psi / |grad psi|), central differences, near the liquid's surface only.

    The normal points into the liquid, so kappa = +(d-1)/R for a bubble of radius R and -(d-1)/R
    for a drop: the pressure jump (non-liquid minus liquid) is sigma kappa in both cases. Clamped
    to 1/dx, the largest curvature the grid can carry.
    """
    i, j, k = wp.tid()
    c = wp.vec3i(i, j, k)
    curvature[i, j, k] = 0.0
    if is_solid(types[i, j, k]):
        return
    if i == 0 or j == 0 or i == types.shape[0] - 1 or j == types.shape[1] - 1:
        return
    if dim == 3 and (k == 0 or k == types.shape[2] - 1):
        return
    p0 = level_at(level, types, c, c)
    if wp.abs(p0) >= 0.99:
        return
    grad = wp.vec3(0.0)
    hess = wp.mat33(0.0)
    for a in range(dim):
        ea = unit(a)
        pp = level_at(level, types, c + ea, c)
        pm = level_at(level, types, c - ea, c)
        grad[a] = (pp - pm) / (2.0 * dx)
        hess[a, a] = (pp - 2.0 * p0 + pm) / (dx * dx)
        for b in range(a + 1, dim):
            eb = unit(b)
            cross = (level_at(level, types, c + ea + eb, c)
                     - level_at(level, types, c + ea - eb, c)
                     - level_at(level, types, c - ea + eb, c)
                     + level_at(level, types, c - ea - eb, c)) / (4.0 * dx * dx)
            hess[a, b] = cross
            hess[b, a] = cross
    g2 = wp.dot(grad, grad)
    if g2 < 1.0e-12 / (dx * dx):
        return
    # div(n) = (|g|^2 tr(H) - g^T H g) / |g|^3
    kappa = (g2 * wp.trace(hess) - wp.dot(grad, hess * grad)) / (g2 * wp.sqrt(g2))
    curvature[i, j, k] = wp.clamp(kappa, -1.0 / dx, 1.0 / dx)


@wp.kernel
def apply_surface_tension(
    types: wp.array3d(dtype=wp.int32),
    phase: wp.array3d(dtype=wp.int32),
    level: wp.array3d(dtype=float),
    curvature: wp.array3d(dtype=float),
    inv_rho: wp.array3d(dtype=float),
    sigma: float,
    axis: int,
    dx: float,
    dt: float,
    vel: wp.array3d(dtype=float),
):
    """The pressure jump [p] = sigma kappa across the liquid's surface (Kang, Fedkiw & Liu 2000).

    On a face between a liquid cell L and a gas or empty cell N, the projection must see
    p_N - p_L = sigma kappa at the surface. Adding dt/rho_f sigma kappa / dx to u* on that face is
    the same as putting the jump into the right-hand side and into the pressure gradient, so the
    pressure operator is untouched. kappa is interpolated to where psi crosses zero.
    """
    i, j, k = wp.tid()
    if inv_rho[i, j, k] == 0.0:
        return
    hi = wp.vec3i(i, j, k)
    lo = hi - unit(axis)
    liquid_lo = is_liquid_cell(types, phase, lo)
    liquid_hi = is_liquid_cell(types, phase, hi)
    if liquid_lo == liquid_hi:
        return
    cl = lo
    cn = hi
    orient = 1.0  # the jump p_hi - p_lo equals +sigma kappa when the liquid is on the low side
    if liquid_hi:
        cl = hi
        cn = lo
        orient = -1.0
    psi_l = level_at(level, types, cl, cl)
    psi_n = level_at(level, types, cn, cl)
    theta = float(0.5)
    if psi_l - psi_n > 1.0e-6:
        theta = wp.clamp(psi_l / (psi_l - psi_n), 0.0, 1.0)
    kappa = (1.0 - theta) * curvature[cl[0], cl[1], cl[2]] + theta * curvature[cn[0], cn[1], cn[2]]
    vel[i, j, k] = vel[i, j, k] + dt * inv_rho[i, j, k] * orient * sigma * kappa / dx


@wp.kernel
def diffuse_velocity(
    types: wp.array3d(dtype=wp.int32),
    phase: wp.array3d(dtype=wp.int32),
    inv_rho: wp.array3d(dtype=float),
    vel: wp.array3d(dtype=float),
    nu_liquid: float,
    nu_gas: float,
    axis: int,
    dim: int,
    dx: float,
    dt: float,
    out: wp.array3d(dtype=float),
):
    """Explicit viscosity: u += dt nu lap(u) on the faces the pressure acts on, nu of the phase beside
    the face (the liquid's if either side is liquid).

    A neighbour face outside the material contributes nothing (zero gradient: a stress-free
    surface or a free-slip wall); a tangential neighbour inside a no-slip wall is taken as -u, so
    the velocity is zero on the wall.
    """
    i, j, k = wp.tid()
    u = vel[i, j, k]
    out[i, j, k] = u
    if inv_rho[i, j, k] == 0.0:
        return
    hi = wp.vec3i(i, j, k)
    lo = hi - unit(axis)
    nu = nu_gas
    if is_liquid_cell(types, phase, lo) or is_liquid_cell(types, phase, hi):
        nu = nu_liquid
    lap = float(0.0)
    for a in range(dim):
        for s in range(2):
            n = hi + (2 * s - 1) * unit(a)
            if n[0] < 0 or n[1] < 0 or n[2] < 0 or n[0] >= vel.shape[0] or n[1] >= vel.shape[1] or n[2] >= vel.shape[2]:
                continue
            t_a = cell_type_at(types, n - unit(axis))
            t_b = cell_type_at(types, n)
            if inv_rho[n[0], n[1], n[2]] > 0.0:
                lap += vel[n[0], n[1], n[2]] - u
            elif a == axis and (is_solid(t_a) or is_solid(t_b)):
                lap += vel[n[0], n[1], n[2]] - u  # the wall's normal face: the wall's velocity, 0
            elif a != axis and (t_a == SOLID_NO_SLIP or t_b == SOLID_NO_SLIP):
                lap += -2.0 * u  # mirrored across a no-slip wall half a cell away
    out[i, j, k] = u + dt * nu * lap / (dx * dx)


@wp.kernel
def retract_gas_films(
    types: wp.array3d(dtype=wp.int32),
    phase_cells: wp.array3d(dtype=wp.int32),
    gas_volume: wp.array3d(dtype=float),
    capillary_speed: float,
    origin: wp.vec3,
    dx: float,
    dim: int,
    dt: float,
    domain_hi: wp.vec3,
    x: wp.array(dtype=wp.vec3),
    phase: wp.array(dtype=wp.int32),
    active: wp.array(dtype=wp.int32),
):
    """Surface tension below the grid: a gas particle in a liquid cell with gas cells in its 3^d
    neighbourhood (a bubble's skirt or rim thinner than a cell) moves towards them (their
    gas-volume-weighted centre) at `capillary_speed`, the Taylor-Culick speed of a film one cell
    thick, sqrt(2 sigma / (rho_l dx)) (thinner films retract faster), at most a quarter cell a step.

    The Laplace jump acts only on faces between liquid and gas cells, so a film under a cell's size
    feels no tension and rides the liquid away. Only the position moves: mass, velocity and J are kept.
    """
    p = wp.tid()
    if active[p] == 0 or phase[p] != PHASE_GAS:
        return
    xp = x[p]
    c = cell_of(xp, origin, dx)
    if not is_liquid_cell(types, phase_cells, c):
        return
    pull = wp.vec3(0.0)
    for q in range(block_size(dim)):
        n = c + block_offset(q, dim)
        if is_phase_cell(types, phase_cells, n, PHASE_GAS):
            d = cell_centre(n, origin, dx) - xp
            if dim == 2:
                d[2] = 0.0  # the slab's centre plane, not the particle's place in its thickness
            pull += gas_volume[n[0], n[1], n[2]] * d
    length = wp.length(pull)
    if length == 0.0:
        return
    step = wp.min(capillary_speed * dt, 0.25 * dx)
    x[p] = clamp_to_domain(xp + (step / length) * pull, domain_hi, dx, dim)
