"""Grid stages between the two transfers: momentum to velocity, cell types, boundary conditions,
the pressure system's coefficients and right-hand side, the pressure gradient, and velocity
extrapolation into the faces that the projection does not reach. The small cell helpers they
share are in cells.py, the volume correction's excess and rate in volume_correction.py.

Face ``f`` along axis ``a`` separates cell ``f - e_a`` (its low side) and cell ``f`` (its high side).
Array-edge faces have a missing neighbour; they are treated as solid.
"""

import warp as wp

from .grid import (
    EMPTY, FLUID, INTERFACE_BASELINE, PHASE_GAS, PHASE_LIQUID, SOLID_FREE_SLIP, SOLID_NO_SLIP, WALL_NO_SLIP, WALL_OPEN,
)
from .gas_law import cell_compressibility
from .cells import (HOLE_FRACTION, at, cell_divergence, cell_type_at, face_trusted, fill_fraction, is_solid,
                    neighbour_kinds, unit)
from .kernel_args import CellPhases, FaceField, PressureRows, Splat, StepParams
from .lines import line_kernel
from .volume_correction import VOLUME_MOVES_POSITIONS, correction_target, is_hole

wp.set_module_options({"enable_backward": False})

MIN_SURFACE_FRACTION = wp.constant(0.1)


@wp.func
def momentum_to_velocity_at(
    accel: float,
    dt: float,
    mom: wp.array3d(dtype=float),
    mass: wp.array3d(dtype=float),
    vel: wp.array3d(dtype=float),
    i: int,
    j: int,
    k: int,
):
    """u* = p/m + dt g on faces that received mass; zero elsewhere."""
    m = mass[i, j, k]
    if m > 0.0:
        vel[i, j, k] = mom[i, j, k] / m + dt * accel
    else:
        vel[i, j, k] = 0.0


momentum_to_velocity = line_kernel(momentum_to_velocity_at)


@wp.func
def classify_cells_at(
    step: StepParams,
    ghost: wp.vec3i,
    interior: wp.vec3i,
    wall_lo: wp.vec3i,
    wall_hi: wp.vec3i,
    count: wp.array3d(dtype=wp.int32),
    splat: Splat,
    types: wp.array3d(dtype=wp.int32),
    i: int,
    j: int,
    k: int,
):
    """Ghost cells take the type of their wall; inside, a cell is fluid if a particle is in it or
    if the splatted fill fraction exceeds HOLE_FRACTION.

    An open wall's ghost cells are always EMPTY, the air outside at p = 0 gauge (about at the face,
    by the ghost-fluid surface), so liquid at the wall drains out under its own head; read as fluid
    (the splats reach them), they would close the wall with the arrays' edge beyond them.

    Stretching flow (a wake, expanding gas) leaves particle-free cells inside the material; read
    as empty they would pin p = 0 inside the water and vent bubbles. A one-cell hole still gets
    about 0.44 from its neighbours, while the air above a flat surface gets about 0.17.
    """
    c = wp.vec3i(i, j, k)
    in_wall = int(0)
    sticky = int(0)
    outside = int(0)
    for a in range(3):
        wall = int(-1)
        if c[a] < ghost[a]:
            wall = wall_lo[a]
        if c[a] >= ghost[a] + interior[a]:
            wall = wall_hi[a]
        if wall == WALL_OPEN:
            outside = 1
        elif wall >= 0:
            in_wall = 1
            if wall == WALL_NO_SLIP:
                sticky = 1
    if in_wall == 1:
        if sticky == 1:
            types[i, j, k] = SOLID_NO_SLIP
        else:
            types[i, j, k] = SOLID_FREE_SLIP
    elif outside == 1:
        types[i, j, k] = EMPTY
    elif count[i, j, k] > 0 or fill_fraction(splat.liq_volume, splat.gas_volume, step.two_phase, c,
                                             step.inv_cell_vol) > HOLE_FRACTION:
        types[i, j, k] = FLUID
    else:
        types[i, j, k] = EMPTY


classify_cells = line_kernel(classify_cells_at)


@wp.kernel
def classify_phases(
    types: wp.array3d(dtype=wp.int32),
    gas_count: wp.array3d(dtype=wp.int32),
    liq_volume: wp.array3d(dtype=float),
    gas_volume: wp.array3d(dtype=float),
    interface: int,
    phase: wp.array3d(dtype=wp.int32),
    lo: wp.vec3i,  # first index of the launch, which may cover a box (core/active_box.py)
):
    """Which fluid cells are gas. Baseline (the published rule): any gas particle in the cell.
    Sharp: the gas's splatted volume exceeds the liquid's, i.e. the cell centre is on the gas side
    of the interface that the particles describe.
    """
    i, j, k = wp.tid()
    i, j, k = i + lo[0], j + lo[1], k + lo[2]
    ph = PHASE_LIQUID
    if types[i, j, k] == FLUID:
        if interface == INTERFACE_BASELINE:
            if gas_count[i, j, k] > 0:
                ph = PHASE_GAS
        elif gas_volume[i, j, k] > liq_volume[i, j, k]:
            ph = PHASE_GAS
    phase[i, j, k] = ph


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


@wp.func
def face_inverse_density_at(
    step: StepParams,
    axis: int,
    cells: CellPhases,
    splat: Splat,
    inv_rho: wp.array3d(dtype=float),
    i: int,
    j: int,
    k: int,
):
    """Face weight of the pressure operator: 1/rho, divided by theta on liquid-air faces; 0 if inactive.

    Active faces have no solid side and at least one fluid side. rho is the mass over the volume
    splatted to the fluid cells beside the face, so a single liquid gets exactly its density. On a
    face to an empty cell, p = 0 is imposed at the surface (theta of the way across), not at the
    empty cell's centre: hydrostatic pressure then matches rho g depth, not rho g (depth + dx/2).
    With gas, the baseline mixes both phases' mass and volume (a smeared density); the sharp
    interface keeps each phase's own density and, on a face between a liquid and a gas cell,
    takes rho = theta rho_liquid + (1 - theta) rho_gas with theta the liquid share of the segment
    between the centres (ghost-fluid method, Liu, Fedkiw & Kang 2000).
    """
    types = cells.types
    two_phase = step.two_phase
    inv_cell_vol = step.inv_cell_vol
    liq_mass = splat.liq_mass
    liq_volume = splat.liq_volume
    gas_mass = splat.gas_mass
    gas_volume = splat.gas_volume
    hi = wp.vec3i(i, j, k)
    lo = hi - unit(axis)
    t_lo = cell_type_at(types, lo)
    t_hi = cell_type_at(types, hi)
    if is_solid(t_lo) or is_solid(t_hi) or (t_lo != FLUID and t_hi != FLUID):
        inv_rho[i, j, k] = 0.0
        return
    f_lo = float(t_lo == FLUID)
    f_hi = float(t_hi == FLUID)
    ml = f_lo * at(liq_mass, lo) + f_hi * at(liq_mass, hi)
    vl = f_lo * at(liq_volume, lo) + f_hi * at(liq_volume, hi)
    rho = float(0.0)
    if two_phase == 0:  # liquid-only scenes never read the gas arrays
        rho = ml / vl
    else:
        mg = f_lo * at(gas_mass, lo) + f_hi * at(gas_mass, hi)
        vg = f_lo * at(gas_volume, lo) + f_hi * at(gas_volume, hi)
        rho = (ml + mg) / (vl + vg)  # the baseline's mixture; also the fallback below
        if step.interface != INTERFACE_BASELINE:
            p_lo = -1
            p_hi = -1
            if t_lo == FLUID:
                p_lo = cells.phase[lo[0], lo[1], lo[2]]
            if t_hi == FLUID:
                p_hi = cells.phase[hi[0], hi[1], hi[2]]
            if p_lo == PHASE_GAS and p_hi == PHASE_LIQUID:
                rho = interface_density(splat, hi, lo, inv_cell_vol)
            elif p_lo == PHASE_LIQUID and p_hi == PHASE_GAS:
                rho = interface_density(splat, lo, hi, inv_cell_vol)
            elif (p_lo == PHASE_GAS or p_hi == PHASE_GAS) and vg > 0.0:
                rho = mg / vg
            elif vl > 0.0:
                rho = ml / vl
    value = 1.0 / rho
    # Free surface: the total (liquid + gas) volume fraction crosses 1/2 between the centres.
    if t_lo == EMPTY:
        value = value / surface_fraction(
            fill_fraction(liq_volume, gas_volume, two_phase, hi, inv_cell_vol),
            fill_fraction(liq_volume, gas_volume, two_phase, lo, inv_cell_vol))
    if t_hi == EMPTY:
        value = value / surface_fraction(
            fill_fraction(liq_volume, gas_volume, two_phase, lo, inv_cell_vol),
            fill_fraction(liq_volume, gas_volume, two_phase, hi, inv_cell_vol))
    inv_rho[i, j, k] = value


@wp.func
def interface_density(splat: Splat, c_liq: wp.vec3i, c_gas: wp.vec3i, inv_cell_vol: float):
    """theta rho_l + (1 - theta) rho_g on a face between a liquid cell and a gas cell.

    The level set psi = phi_liquid - phi_gas is positive on the liquid side; theta is where it
    crosses zero along the segment between the two centres.
    """
    psi_l = (at(splat.liq_volume, c_liq) - at(splat.gas_volume, c_liq)) * inv_cell_vol
    psi_g = (at(splat.liq_volume, c_gas) - at(splat.gas_volume, c_gas)) * inv_cell_vol
    theta = float(0.5)
    if psi_l - psi_g > 1.0e-6:
        theta = wp.clamp(psi_l / (psi_l - psi_g), 0.0, 1.0)
    rho_l = at(splat.liq_mass, c_liq) / at(splat.liq_volume, c_liq)
    rho_g = at(splat.gas_mass, c_gas) / at(splat.gas_volume, c_gas)
    return theta * rho_l + (1.0 - theta) * rho_g


face_inverse_density = line_kernel(face_inverse_density_at)


@wp.func
def zero_solid_faces_at(axis: int, types: wp.array3d(dtype=wp.int32), vel: wp.array3d(dtype=float), i: int, j: int,
                        k: int):
    """Walls are at rest: the normal velocity on any face touching a solid cell is zero."""
    hi = wp.vec3i(i, j, k)
    lo = hi - unit(axis)
    if is_solid(cell_type_at(types, lo)) or is_solid(cell_type_at(types, hi)):
        vel[i, j, k] = 0.0


zero_solid_faces = line_kernel(zero_solid_faces_at)


@wp.func
def ask_volume_correction(step: StepParams, volume_rate: float, cells: CellPhases, splat: Splat, rows: PressureRows,
                          enclosed_cells: wp.array3d(dtype=wp.int32), c: wp.vec3i, enclosed: int):
    """The volume correction's part of cell c's row (docs/design.md, #volume-correction): what it adds
    to the step's right-hand side. Where the correction moves positions and c is enclosed, it is
    solved for on its own (rows.correction_rhs, core/volume_shift.py) and adds nothing: the flow's
    pressure and velocity never carry it. Only enclosed cells shift: at a surface the solve's
    pressure is what gas gives way to (#volume-shift)."""
    dt = step.dt
    shifted = int(0)
    if step.volume_moves == VOLUME_MOVES_POSITIONS and enclosed != 0:
        shifted = 1
    inv_dx2 = 1.0 / (step.dx * step.dx)
    target = correction_target(step.volume_fill, shifted, volume_rate, cells, splat, step.two_phase, c, step.dim,
                               enclosed, inv_dx2, step.dx, enclosed_cells)
    if shifted != 0:
        rows.correction_rhs[c[0], c[1], c[2]] = target / dt
        return 0.0
    if step.two_phase != 0:  # the divergence asked of the liquid, which is not the gas's to take
        rows.target_div[c[0], c[1], c[2]] = target
    return target / dt


@wp.func
def pressure_diagonal_and_rhs_at(
    step: StepParams,
    volume_rate: float,
    slot: int,
    cells: CellPhases,
    inv_rho: FaceField,
    vel: FaceField,
    splat: Splat,
    rows: PressureRows,
    counters: wp.array(dtype=wp.int32),
    enclosed_cells: wp.array3d(dtype=wp.int32),
    i: int,
    j: int,
    k: int,
):
    """Diagonal and right-hand side of the one two-phase system (docs/design.md, #pressure-equation), per fluid cell c:

        (kappa_c/dt^2)(p_c - p^_c) - div(1/rho grad p)_c = -(div u* - d_target)/dt

    kappa = 0 in liquid cells; in gas cells kappa and the particles' pressure p^ are the
    volume-weighted averages splatted by p2g_gas. d_target = volume_rate * volume_excess asks liquid
    cells whose rest-volume fraction phi is beyond the seeding noise to expand (over-full) or
    contract (under-full and enclosed), which stops the slow volume loss of particle clustering;
    volume_rate = volume_relaxation_rate(tau, dt) is a rate, 1/s, so the state does not depend on dt.
    counters[slot] counts fluid cells, counters[slot + 1] those that pin the pressure level (an empty
    neighbour or kappa > 0): with none, the system is singular and the solver projects out the constant.
    """
    types = cells.types
    phase = cells.phase
    liq_volume = splat.liq_volume
    gas_volume = splat.gas_volume
    gas_kv = splat.gas_kv
    two_phase = step.two_phase
    interface = step.interface
    dx = step.dx
    dt = step.dt
    dim = step.dim
    if two_phase != 0:
        rows.target_div[i, j, k] = 0.0
    shift = step.volume_moves == VOLUME_MOVES_POSITIONS
    if shift:
        rows.correction_rhs[i, j, k] = 0.0
    if types[i, j, k] != FLUID:
        rows.diag[i, j, k] = 1.0
        rows.extra_diag[i, j, k] = 0.0
        rows.rhs[i, j, k] = 0.0
        return
    inv_dx2 = 1.0 / (dx * dx)
    d = inv_rho.u[i, j, k] + inv_rho.u[i + 1, j, k] + inv_rho.v[i, j, k] + inv_rho.v[i, j + 1, k]
    div = cell_divergence(vel.u, vel.v, vel.w, wp.vec3i(i, j, k), dim)
    sides = neighbour_kinds(types, phase, gas_kv, wp.vec3i(i, j, k), dim, two_phase)
    pinned = sides[0]
    enclosed = sides[1]
    if is_hole(liq_volume, gas_volume, two_phase, wp.vec3i(i, j, k), inv_dx2 / dx, pinned):
        enclosed = 1
    if dim == 3:
        d += inv_rho.w[i, j, k] + inv_rho.w[i, j, k + 1]
    b = -div / (dx * dt)
    extra = float(0.0)
    vg = float(0.0)
    if two_phase != 0:
        vg = gas_volume[i, j, k]
    if vg > 0.0 and (interface != INTERFACE_BASELINE or phase[i, j, k] == PHASE_GAS):
        extra = cell_compressibility(gas_kv[i, j, k], vg, interface, dx * dx * dx) / (dt * dt)
        b += extra * splat.gas_pv[i, j, k] / vg
        if extra > 0.0:
            pinned = 1
    if two_phase == 0 or phase[i, j, k] == PHASE_LIQUID or (interface != INTERFACE_BASELINE and extra == 0.0):
        b += ask_volume_correction(step, volume_rate, cells, splat, rows, enclosed_cells, wp.vec3i(i, j, k), enclosed)
    rows.diag[i, j, k] = d * inv_dx2 + extra
    rows.extra_diag[i, j, k] = extra
    rows.rhs[i, j, k] = b
    wp.atomic_add(counters, slot, 1)
    wp.atomic_add(counters, slot + 1, pinned)


pressure_diagonal_and_rhs = line_kernel(pressure_diagonal_and_rhs_at)


@wp.func
def mark_enclosed_at(cells: CellPhases, gas_kv: wp.array3d(dtype=float), dim: int, two_phase: int,
                     enclosed_cells: wp.array3d(dtype=wp.int32), i: int, j: int, k: int):
    """1 where a fluid cell has liquid (or incompressible gas) on every side (neighbour_kinds), else 0:
    the smoothed fill reads its neighbours' from this one pass, not six cells' types each (in 3D it
    read 26 neighbours' 6 faces for every enclosed cell)."""
    e = int(0)
    if cells.types[i, j, k] == FLUID:
        e = neighbour_kinds(cells.types, cells.phase, gas_kv, wp.vec3i(i, j, k), dim, two_phase)[1]
    enclosed_cells[i, j, k] = e


mark_enclosed = line_kernel(mark_enclosed_at)


@wp.func
def subtract_pressure_gradient_at(
    step: StepParams,
    axis: int,
    types: wp.array3d(dtype=wp.int32),
    pressure: wp.array3d(dtype=float),
    inv_rho: wp.array3d(dtype=float),
    vel: wp.array3d(dtype=float),
    valid: wp.array3d(dtype=wp.int32),
    i: int,
    j: int,
    k: int,
):
    """u = u* - dt/rho dp/dx on faces next to fluid (p = 0 gauge in empty cells).

    Marks which faces now hold trusted velocities: projected faces and solid faces bordering fluid.
    """
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
        vel[i, j, k] = vel[i, j, k] - step.dt * inv_rho[i, j, k] * (p_hi - p_lo) / step.dx
        ok = 1
    elif (is_solid(t_lo) and t_hi == FLUID) or (is_solid(t_hi) and t_lo == FLUID):
        ok = 1
    valid[i, j, k] = ok


subtract_pressure_gradient = line_kernel(subtract_pressure_gradient_at)


@wp.func
def extrapolate_velocity_at(
    dim: int,
    vel_in: wp.array3d(dtype=float),
    valid_in: wp.array3d(dtype=wp.int32),
    vel_out: wp.array3d(dtype=float),
    valid_out: wp.array3d(dtype=wp.int32),
    i: int,
    j: int,
    k: int,
):
    """One layer of extrapolation: an untrusted face takes the mean of its trusted neighbours.

    Ping-pong buffers keep the result independent of thread order.
    """
    vel_out[i, j, k] = vel_in[i, j, k]
    valid_out[i, j, k] = valid_in[i, j, k]
    if valid_in[i, j, k] == 1:
        return
    total = float(0.0)
    n = int(0)
    for a in range(dim):
        for s in range(2):
            c = wp.vec3i(i, j, k) + (2 * s - 1) * unit(a)
            if face_trusted(valid_in, c):
                total += at(vel_in, c)
                n += 1
    if n > 0:
        vel_out[i, j, k] = total / float(n)
        valid_out[i, j, k] = 1


extrapolate_velocity = line_kernel(extrapolate_velocity_at)


@wp.func
def enforce_walls_at(axis: int, types: wp.array3d(dtype=wp.int32), vel: wp.array3d(dtype=float), i: int, j: int,
                     k: int):
    """Zero normal velocity at solid faces; inside no-slip walls also zero the tangential velocity.

    Inside free-slip walls the extrapolated tangential velocity stays, so particles slide along.
    """
    hi = wp.vec3i(i, j, k)
    lo = hi - unit(axis)
    t_lo = cell_type_at(types, lo)
    t_hi = cell_type_at(types, hi)
    if is_solid(t_lo) != is_solid(t_hi):
        vel[i, j, k] = 0.0
    elif is_solid(t_lo) and (t_lo == SOLID_NO_SLIP or t_hi == SOLID_NO_SLIP):
        vel[i, j, k] = 0.0


enforce_walls = line_kernel(enforce_walls_at)
