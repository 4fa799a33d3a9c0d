"""The groups of kernel arguments that travel together, as Warp structs, and the functions that fill
them from the simulation's arrays.

A kernel takes its arguments in one order: the walk (a Lines box, or the first particle), then
parameters (numbers of the step), then what it reads, then what it writes. A struct stands for one
thing a physicist names: the velocity on the faces, the cells' types and phases, what the particles
splatted to the cells, the pressure system's rows, the particles. Reading a field of a struct is
the same load as reading the array, so the arithmetic, and the CPU output, do not change.
"""

from __future__ import annotations

import warp as wp


@wp.struct
class FaceField:
    """A quantity on the MAC grid's faces, one array per axis: u on the faces normal to x, v to y,
    w to z (2D runs: a stand-in array that nothing reads)."""

    u: wp.array3d(dtype=float)
    v: wp.array3d(dtype=float)
    w: wp.array3d(dtype=float)


@wp.struct
class CellPhases:
    """What each cell is: its type (EMPTY, FLUID, SOLID_*: grid.py) and, for a fluid cell, its phase
    (PHASE_LIQUID or PHASE_GAS)."""

    types: wp.array3d(dtype=wp.int32)
    phase: wp.array3d(dtype=wp.int32)


@wp.struct
class Splat:
    """What the particles splatted to each cell: the liquid's and the gas's mass and rest volume,
    and the gas's volume-weighted pressure (p V) and compressibility (kappa V). Liquid-only runs
    hold stand-ins for the gas's arrays and never read them (two_phase = 0)."""

    liq_mass: wp.array3d(dtype=float)
    liq_volume: wp.array3d(dtype=float)
    gas_mass: wp.array3d(dtype=float)
    gas_volume: wp.array3d(dtype=float)
    gas_pv: wp.array3d(dtype=float)
    gas_kv: wp.array3d(dtype=float)


@wp.struct
class StepParams:
    """The numbers of one time step that the grid kernels share."""

    dt: float  # s
    dx: float  # cell size, m
    dim: int  # 2 or 3
    inv_cell_vol: float  # 1 / dx^3
    two_phase: int  # 1 with gas in the scene (its arrays are real), else 0
    interface: int  # INTERFACE_SHARP or INTERFACE_BASELINE (grid.py)
    volume_fill: int  # the volume correction's fill: 0 each cell's own, VOLUME_FILL_SMOOTHED (volume_correction.py)
    volume_moves: int  # what it moves: 0 velocities (the solve's rhs), VOLUME_MOVES_POSITIONS (correction_rhs)


@wp.struct
class PressureRows:
    """Each fluid cell's row of the pressure system (core/pressure.py): the diagonal, the gas's
    kappa/dt^2 part of it, the right-hand side, the divergence the volume correction asks of the
    cell's liquid (two-phase runs only), and, when the correction moves positions, the right-hand
    side of its own solve (core/volume_shift.py) instead."""

    diag: wp.array3d(dtype=float)
    extra_diag: wp.array3d(dtype=float)
    rhs: wp.array3d(dtype=float)
    target_div: wp.array3d(dtype=float)
    correction_rhs: wp.array3d(dtype=float)


def face_field(arrays) -> FaceField:
    """The struct of three face arrays (a list or tuple, u, v, w)."""
    f = FaceField()
    f.u, f.v, f.w = arrays
    return f


def cell_phases(fields) -> CellPhases:
    """The cell types and phases of GridFields."""
    c = CellPhases()
    c.types, c.phase = fields.types, fields.phase_cells
    return c


def splat(fields) -> Splat:
    """The splatted cell arrays of GridFields."""
    s = Splat()
    s.liq_mass, s.liq_volume = fields.liq_mass, fields.liq_volume
    s.gas_mass, s.gas_volume, s.gas_pv, s.gas_kv = fields.gas_mass, fields.gas_volume, fields.gas_pv, fields.gas_kv
    return s


def step_params(grid, dt: float, two_phase: int, interface: int, volume_fill: int = 0,
                volume_moves: int = 0) -> StepParams:
    """The step's numbers for a MacGrid."""
    s = StepParams()
    s.dt, s.dx, s.dim = dt, grid.dx, grid.dim
    s.inv_cell_vol = 1.0 / grid.dx**3
    s.two_phase, s.interface, s.volume_fill, s.volume_moves = two_phase, interface, volume_fill, volume_moves
    return s


def pressure_rows(fields) -> PressureRows:
    """The pressure system's rows of GridFields."""
    r = PressureRows()
    r.diag, r.extra_diag, r.rhs, r.target_div = fields.diag, fields.extra_diag, fields.rhs, fields.target_div
    r.correction_rhs = fields.correction_rhs
    return r


# The pressure solver's (core/pressure.py).
@wp.struct
class PressureOperator:
    """A p = diag p - (1/dx^2) sum over the faces f of a fluid cell of inv_rho_f p_n(f), p_n the
    neighbour's p if it is FLUID, else 0 (pressure.PressureSystem)."""

    types: wp.array3d(dtype=wp.int32)
    diag: wp.array3d(dtype=float)
    inv_rho: FaceField
    inv_dx2: float
    dim: int


@wp.struct
class PointPreconditioner:
    """z = M^-1 r cell by cell: mode NONE (z = r) or JACOBI (z = r / diag); MULTIGRID overwrites z
    afterwards (pressure.preconditioned)."""

    diag: wp.array3d(dtype=float)
    mode: int


@wp.struct
class PlaneSums:
    """The partial sums of a dot product, one row a plane of cells along x from plane0, which one
    thread then adds in plane order (pressure.add_to_plane)."""

    planes: wp.array2d(dtype=wp.float64)
    plane0: int


def pressure_operator(system, inv_dx2: float, dim: int) -> PressureOperator:
    """The operator of a pressure.PressureSystem."""
    A = PressureOperator()
    A.types, A.diag, A.inv_rho = system.types, system.diag, face_field(system.inv_rho)
    A.inv_dx2, A.dim = inv_dx2, dim
    return A


def point_preconditioner(diag, mode: int) -> PointPreconditioner:
    M = PointPreconditioner()
    M.diag, M.mode = diag, mode
    return M


def plane_sums(planes, plane0: int) -> PlaneSums:
    s = PlaneSums()
    s.planes, s.plane0 = planes, plane0
    return s


# The particles' (core/state.py).
@wp.struct
class Particles:
    """The arrays every particle has (state.PARTICLE_FIELDS)."""

    x: wp.array(dtype=wp.vec3)  # position, m
    v: wp.array(dtype=wp.vec3)  # velocity, m/s
    C: wp.array(dtype=wp.mat33)  # APIC affine matrix: row a is the gradient of velocity component a
    mass: wp.array(dtype=float)  # kg
    vol0: wp.array(dtype=float)  # rest volume, m^3
    J: wp.array(dtype=float)  # volume ratio: the volume is vol0 J
    phase: wp.array(dtype=wp.int32)  # PHASE_* (grid.py)
    active: wp.array(dtype=wp.int32)  # RETIRED, ACTIVE, LEAVING or AIRBORNE (grid.py)
    gas_law: wp.array(dtype=wp.int32)  # the gas's law (core/gas_law.py)
    gas_gamma: wp.array(dtype=float)  # the gas's heat-capacity ratio
    material: wp.array(dtype=wp.int32)  # index into the scene's materials
    ids: wp.array(dtype=wp.int64)  # each particle's number, in the order they were added


@wp.struct
class FacePairs:
    """p2g's (momentum, mass) pairs on the faces, one array per axis (as FaceField)."""

    u: wp.array3d(dtype=wp.vec2)
    v: wp.array3d(dtype=wp.vec2)
    w: wp.array3d(dtype=wp.vec2)


def particle_arrays(state) -> Particles:
    """The struct of a ParticleState's arrays (rebuilt at each launch: the arrays grow)."""
    p = Particles()
    p.x, p.v, p.C, p.mass, p.vol0, p.J = state.x, state.v, state.C, state.mass, state.vol0, state.J
    p.phase, p.active, p.gas_law, p.gas_gamma = state.phase, state.active, state.gas_law, state.gas_gamma
    p.material, p.ids = state.material, state.ids
    return p


def face_pairs(arrays) -> FacePairs:
    f = FacePairs()
    f.u, f.v, f.w = arrays
    return f
