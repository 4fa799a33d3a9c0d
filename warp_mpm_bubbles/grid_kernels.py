"""Grid stages between the two transfers: momentum to velocity, cell types, boundary conditions,
the pressure system's coefficients and right-hand side, the pressure gradient, and velocity
extrapolation into the faces that the projection does not reach.

Face ``f`` along axis ``a`` separates cell ``f - e_a`` (its low side) and cell ``f`` (its high side).
Array-edge faces have a missing neighbour; they are treated as solid.
"""

import warp as wp

from .grid import EMPTY, FLUID, SOLID_FREE_SLIP, SOLID_NO_SLIP, WALL_NO_SLIP, WALL_OPEN

wp.set_module_options({"enable_backward": False})

MIN_SURFACE_FRACTION = wp.constant(0.1)
VOLUME_NOISE_BAND = wp.constant(0.1)


@wp.func
def unit(axis: int):
    return wp.vec3i(int(axis == 0), int(axis == 1), int(axis == 2))


@wp.func
def cell_type_at(types: wp.array3d(dtype=wp.int32), c: wp.vec3i):
    """Type of cell c; outside the array counts as a free-slip solid."""
    if c[0] < 0 or c[1] < 0 or c[2] < 0:
        return SOLID_FREE_SLIP
    if c[0] >= types.shape[0] or c[1] >= types.shape[1] or c[2] >= types.shape[2]:
        return SOLID_FREE_SLIP
    return types[c[0], c[1], c[2]]


@wp.func
def is_solid(t: int):
    return t >= SOLID_FREE_SLIP


@wp.kernel
def momentum_to_velocity(
    mom: wp.array3d(dtype=float), mass: wp.array3d(dtype=float), accel: float, dt: float, vel: wp.array3d(dtype=float)
):
    """u* = p/m + dt g on faces that received mass; zero elsewhere."""
    i, j, k = wp.tid()
    m = mass[i, j, k]
    if m > 0.0:
        vel[i, j, k] = mom[i, j, k] / m + dt * accel
    else:
        vel[i, j, k] = 0.0


@wp.kernel
def classify_cells(
    count: wp.array3d(dtype=wp.int32),
    ghost: wp.vec3i,
    interior: wp.vec3i,
    wall_lo: wp.vec3i,
    wall_hi: wp.vec3i,
    types: wp.array3d(dtype=wp.int32),
):
    """Ghost cells take the type of their wall (open walls are empty); inside, any particle -> fluid."""
    i, j, k = wp.tid()
    c = wp.vec3i(i, j, k)
    in_wall = int(0)
    sticky = int(0)
    for a in range(3):
        wall = int(-1)
        if c[a] < ghost[a]:
            wall = wall_lo[a]
        if c[a] >= ghost[a] + interior[a]:
            wall = wall_hi[a]
        if wall >= 0 and wall != WALL_OPEN:
            in_wall = 1
            if wall == WALL_NO_SLIP:
                sticky = 1
    if in_wall == 1:
        if sticky == 1:
            types[i, j, k] = SOLID_NO_SLIP
        else:
            types[i, j, k] = SOLID_FREE_SLIP
    elif count[i, j, k] > 0:
        types[i, j, k] = FLUID
    else:
        types[i, j, k] = EMPTY


@wp.func
def volume_fraction(cell_volume: wp.array3d(dtype=float), c: wp.vec3i, inv_cell_vol: float):
    if c[0] < 0 or c[1] < 0 or c[2] < 0:
        return 0.0
    if c[0] >= cell_volume.shape[0] or c[1] >= cell_volume.shape[1] or c[2] >= cell_volume.shape[2]:
        return 0.0
    return cell_volume[c[0], c[1], c[2]] * inv_cell_vol


@wp.func
def surface_fraction(phi_fluid: float, phi_empty: float):
    """Fraction theta of the centre-to-centre distance from a fluid cell to an empty one that is liquid.

    The surface is where the rest-volume fraction phi crosses 1/2, interpolated linearly between the
    two centres (Enright et al. 2003 ghost-fluid free surface). Clamped so the coefficient 1/theta
    stays bounded for droplets and thin sheets, whose centres already lie outside the liquid.
    """
    theta = 1.0
    if phi_fluid > phi_empty:
        theta = (phi_fluid - 0.5) / (phi_fluid - phi_empty)
    return wp.clamp(theta, MIN_SURFACE_FRACTION, 1.0)


@wp.kernel
def face_inverse_density(
    types: wp.array3d(dtype=wp.int32),
    cell_mass: wp.array3d(dtype=float),
    cell_volume: wp.array3d(dtype=float),
    axis: int,
    inv_cell_vol: float,
    inv_rho: wp.array3d(dtype=float),
):
    """Face weight of the pressure operator: 1/rho, divided by theta on liquid-air faces; 0 if inactive.

    Active faces have no solid side and at least one fluid side. rho is the mass over the volume
    splatted to the fluid cells beside the face, so a single liquid gets exactly its density. On a
    face to an empty cell, p = 0 is imposed at the surface (theta of the way across), not at the
    empty cell's centre: hydrostatic pressure then matches rho g depth, not rho g (depth + dx/2).
    """
    i, j, k = wp.tid()
    hi = wp.vec3i(i, j, k)
    lo = hi - unit(axis)
    t_lo = cell_type_at(types, lo)
    t_hi = cell_type_at(types, hi)
    value = float(0.0)
    if not is_solid(t_lo) and not is_solid(t_hi) and (t_lo == FLUID or t_hi == FLUID):
        m = float(0.0)
        vol = float(0.0)
        if t_lo == FLUID:
            m += cell_mass[lo[0], lo[1], lo[2]]
            vol += cell_volume[lo[0], lo[1], lo[2]]
        if t_hi == FLUID:
            m += cell_mass[hi[0], hi[1], hi[2]]
            vol += cell_volume[hi[0], hi[1], hi[2]]
        if m > 0.0:
            value = vol / m
        phi_lo = volume_fraction(cell_volume, lo, inv_cell_vol)
        phi_hi = volume_fraction(cell_volume, hi, inv_cell_vol)
        if t_lo == EMPTY:
            value = value / surface_fraction(phi_hi, phi_lo)
        if t_hi == EMPTY:
            value = value / surface_fraction(phi_lo, phi_hi)
    inv_rho[i, j, k] = value


@wp.kernel
def zero_solid_faces(types: wp.array3d(dtype=wp.int32), axis: int, vel: wp.array3d(dtype=float)):
    """Walls are at rest: the normal velocity on any face touching a solid cell is zero."""
    i, j, k = wp.tid()
    hi = wp.vec3i(i, j, k)
    lo = hi - unit(axis)
    if is_solid(cell_type_at(types, lo)) or is_solid(cell_type_at(types, hi)):
        vel[i, j, k] = 0.0


@wp.kernel
def pressure_diagonal_and_rhs(
    types: wp.array3d(dtype=wp.int32),
    inv_rho_u: wp.array3d(dtype=float),
    inv_rho_v: wp.array3d(dtype=float),
    inv_rho_w: wp.array3d(dtype=float),
    vel_u: wp.array3d(dtype=float),
    vel_v: wp.array3d(dtype=float),
    vel_w: wp.array3d(dtype=float),
    cell_volume: wp.array3d(dtype=float),
    dx: float,
    dt: float,
    dim: int,
    volume_correction: float,
    diag: wp.array3d(dtype=float),
    rhs: wp.array3d(dtype=float),
    counters: wp.array(dtype=wp.int32),
):
    """Diagonal of -div(1/rho grad) and b = -(div u* - d_target)/dt in fluid cells.

    d_target = volume_correction * max(phi - 1, 0) / dt asks over-full cells (rest-volume fraction
    phi > 1) to expand, which stops the slow volume loss of particle clustering.
    counters[0] counts fluid cells, counters[1] fluid cells with a Dirichlet (empty) neighbour:
    with none, the system is singular and the caller projects out the constant.
    """
    i, j, k = wp.tid()
    if types[i, j, k] != FLUID:
        diag[i, j, k] = 1.0
        rhs[i, j, k] = 0.0
        return
    inv_dx2 = 1.0 / (dx * dx)
    d = inv_rho_u[i, j, k] + inv_rho_u[i + 1, j, k] + inv_rho_v[i, j, k] + inv_rho_v[i, j + 1, k]
    div = vel_u[i + 1, j, k] - vel_u[i, j, k] + vel_v[i, j + 1, k] - vel_v[i, j, k]
    dirichlet = int(0)
    for s in range(2):
        if cell_type_at(types, wp.vec3i(i - 1 + 2 * s, j, k)) == EMPTY:
            dirichlet = 1
        if cell_type_at(types, wp.vec3i(i, j - 1 + 2 * s, k)) == EMPTY:
            dirichlet = 1
    if dim == 3:
        d += inv_rho_w[i, j, k] + inv_rho_w[i, j, k + 1]
        div += vel_w[i, j, k + 1] - vel_w[i, j, k]
        for s in range(2):
            if cell_type_at(types, wp.vec3i(i, j, k - 1 + 2 * s)) == EMPTY:
                dirichlet = 1
    div = div / dx
    phi = cell_volume[i, j, k] * inv_dx2 / dx
    target = volume_correction * wp.max(phi - 1.0 - VOLUME_NOISE_BAND, 0.0) / dt
    diag[i, j, k] = d * inv_dx2
    rhs[i, j, k] = (target - div) / dt
    wp.atomic_add(counters, 0, 1)
    wp.atomic_add(counters, 1, dirichlet)


@wp.kernel
def subtract_pressure_gradient(
    types: wp.array3d(dtype=wp.int32),
    pressure: wp.array3d(dtype=float),
    inv_rho: wp.array3d(dtype=float),
    axis: int,
    dx: float,
    dt: float,
    vel: wp.array3d(dtype=float),
    valid: wp.array3d(dtype=wp.int32),
):
    """u = u* - dt/rho dp/dx on faces next to fluid (p = 0 gauge in empty cells).

    Marks which faces now hold trusted velocities: projected faces and solid faces bordering fluid.
    """
    i, j, k = wp.tid()
    hi = wp.vec3i(i, j, k)
    lo = hi - unit(axis)
    t_lo = cell_type_at(types, lo)
    t_hi = cell_type_at(types, hi)
    ok = int(0)
    if inv_rho[i, j, k] > 0.0:
        p_lo = float(0.0)
        p_hi = float(0.0)
        if t_lo == FLUID:
            p_lo = pressure[lo[0], lo[1], lo[2]]
        if t_hi == FLUID:
            p_hi = pressure[hi[0], hi[1], hi[2]]
        vel[i, j, k] = vel[i, j, k] - dt * inv_rho[i, j, k] * (p_hi - p_lo) / dx
        ok = 1
    elif (is_solid(t_lo) and t_hi == FLUID) or (is_solid(t_hi) and t_lo == FLUID):
        ok = 1
    valid[i, j, k] = ok


@wp.kernel
def extrapolate_velocity(
    vel_in: wp.array3d(dtype=float),
    valid_in: wp.array3d(dtype=wp.int32),
    dim: int,
    vel_out: wp.array3d(dtype=float),
    valid_out: wp.array3d(dtype=wp.int32),
):
    """One layer of extrapolation: an untrusted face takes the mean of its trusted neighbours.

    Ping-pong buffers keep the result independent of thread order.
    """
    i, j, k = wp.tid()
    vel_out[i, j, k] = vel_in[i, j, k]
    valid_out[i, j, k] = valid_in[i, j, k]
    if valid_in[i, j, k] == 1:
        return
    total = float(0.0)
    n = int(0)
    for a in range(dim):
        for s in range(2):
            c = wp.vec3i(i, j, k) + (2 * s - 1) * unit(a)
            if c[0] >= 0 and c[1] >= 0 and c[2] >= 0:
                if c[0] < vel_in.shape[0] and c[1] < vel_in.shape[1] and c[2] < vel_in.shape[2]:
                    if valid_in[c[0], c[1], c[2]] == 1:
                        total += vel_in[c[0], c[1], c[2]]
                        n += 1
    if n > 0:
        vel_out[i, j, k] = total / float(n)
        valid_out[i, j, k] = 1


@wp.kernel
def enforce_walls(types: wp.array3d(dtype=wp.int32), axis: int, vel: wp.array3d(dtype=float)):
    """Zero normal velocity at solid faces; inside no-slip walls also zero the tangential velocity.

    Inside free-slip walls the extrapolated tangential velocity stays, so particles slide along.
    """
    i, j, k = wp.tid()
    hi = wp.vec3i(i, j, k)
    lo = hi - unit(axis)
    t_lo = cell_type_at(types, lo)
    t_hi = cell_type_at(types, hi)
    if is_solid(t_lo) != is_solid(t_hi):
        vel[i, j, k] = 0.0
    elif is_solid(t_lo) and (t_lo == SOLID_NO_SLIP or t_hi == SOLID_NO_SLIP):
        vel[i, j, k] = 0.0
