"""Near-vacuum cavities: gas far below the ambient pressure is a pressure boundary, not a flow
(docs/design.md, #cavities). Part of the gas stage (physics/gas.py calls it at its hooks).

A gas at 1 Pa holds 1e-5 of its rest density. Projected like any gas, its faces' 1/rho (8e4 m^3/kg)
times pressure differences at the float32 gauge pressure's resolution (-101324 Pa, to 0.008 Pa)
drove its particles to 4e4 m/s; the cavity first grew, sliver cells crushed single particles and
the steps fell under 1e-9 s. The physical near vacuum has no inertia and no say in the liquid's
motion but its (tiny) pressure, and it evens that out at its sound speed (~300 m/s, faster than any
wall here). So a cavity's gas:

  - keeps its cells in the pressure system: their kappa/dt^2 term (kappa = 1/p_abs, huge) pins
    them at the gas's own pressure, a Dirichlet region as the free surface is at the ambient one;
  - is not moved by the projection: its faces take the liquid's velocity, extended in from the
    interface (release_cavity_faces), and its particles follow it as tracers;
  - fills the room the liquid leaves, with no J history (cavity_gas_J);
  - lends no compressibility to the liquid cells beside it (mark_cavities).

Which gas: cells whose gas is below CAVITY_ENTER of the ambient absolute pressure, and cells holding
gas that was in a cavity at the end of the last step (a particle field) until its pressure is back
above CAVITY_EXIT. Without that memory a cavity compressed past the entry pressure changed model in
the middle of its collapse, and the ordinary model then crushed its slivers (NaN at 0.5% ambient).
"""

from __future__ import annotations

import warp as wp

from ..core.geometry import GridGeometry
from ..core.grid import FLUID, PHASE_GAS
from ..core.cells import cell_of, cell_type_at, is_solid, unit
from ..core.boundary import finite
from ..core.transfer_kernels import CELL_OFFSET, clamp_to_domain, grid_coord, make_stencil

wp.set_module_options({"enable_backward": False})

CAVITY_ENTER = 0.02  # gas below this share of the ambient absolute pressure becomes a cavity's ...
CAVITY_EXIT = 1.0  # ... and stays one until its pressure is back above this share
# mark_cavities' cell kinds (0: none)
CAVITY_GAS = wp.constant(1)  # a gas cell of a cavity
CAVITY_EDGE = wp.constant(2)  # a liquid cell within CAVITY_REACH of one, holding the cavity's gas
CAVITY_REMNANT = wp.constant(3)  # a liquid cell holding cavity gas with no cavity near: what a collapse left
CAVITY_REACH = wp.constant(2)  # a gas particle beside the cavity reaches one cell further with its B-spline


@wp.kernel
def count_cavity_gas(x: wp.array(dtype=wp.vec3), phase: wp.array(dtype=wp.int32), active: wp.array(dtype=wp.int32),
                     flag: wp.array(dtype=wp.int32), geo: GridGeometry, count: wp.array3d(dtype=wp.int32)):
    """count[c]: the gas particles in cell c that were a cavity's at the end of the last step."""
    p = wp.tid()
    if active[p] == 0 or phase[p] != PHASE_GAS or flag[p] == 0 or not finite(x[p]):
        return
    c = cell_of(clamp_to_domain(x[p], geo.domain_hi, geo.dx, geo.dim), geo.origin, geo.dx)
    wp.atomic_add(count, c[0], c[1], c[2], 1)


@wp.func
def near_vacuum(types: wp.array3d(dtype=wp.int32), gas_volume: wp.array3d(dtype=float),
                gas_pv: wp.array3d(dtype=float), count: wp.array3d(dtype=wp.int32), c: wp.vec3i, p_atm: float,
                enter: float, leave: float):
    """A fluid cell whose gas (its volume-weighted pressure) is a cavity's: below `enter` (Pa,
    absolute), or below `leave` while it holds gas that was a cavity's."""
    if cell_type_at(types, c) != FLUID:
        return False
    vg = gas_volume[c[0], c[1], c[2]]
    if vg <= 0.0:
        return False
    p_abs = p_atm + gas_pv[c[0], c[1], c[2]] / vg
    return p_abs < enter or (p_abs < leave and count[c[0], c[1], c[2]] > 0)


@wp.kernel
def mark_cavities(
    types: wp.array3d(dtype=wp.int32),
    phase: wp.array3d(dtype=wp.int32),
    gas_volume: wp.array3d(dtype=float),
    gas_pv: wp.array3d(dtype=float),
    count: wp.array3d(dtype=wp.int32),
    p_atm: float,
    enter: float,
    leave: float,
    dim: int,
    gas_kv: wp.array3d(dtype=float),
    cavity: wp.array3d(dtype=wp.int32),
):
    """cavity[c]: CAVITY_GAS, CAVITY_EDGE, CAVITY_REMNANT or 0. An edge cell's kappa is zeroed: the
    liquid moving into it pushes the cavity's gas back rather than crushing it (the mixture's
    compressibility, alpha_g / p_abs, made a 1 Pa sliver take the whole cell's volume change)."""
    i, j, k = wp.tid()
    c = wp.vec3i(i, j, k)
    cavity[i, j, k] = 0
    if not near_vacuum(types, gas_volume, gas_pv, count, c, p_atm, enter, leave):
        return
    if phase[i, j, k] == PHASE_GAS:
        cavity[i, j, k] = CAVITY_GAS
        return
    cavity[i, j, k] = CAVITY_REMNANT
    nz = 0
    if dim == 3:
        nz = CAVITY_REACH
    for a in range(-CAVITY_REACH, CAVITY_REACH + 1):
        for b in range(-CAVITY_REACH, CAVITY_REACH + 1):
            for e in range(-nz, nz + 1):
                n = c + wp.vec3i(a, b, e)
                if near_vacuum(types, gas_volume, gas_pv, count, n, p_atm, enter, leave):
                    if phase[n[0], n[1], n[2]] == PHASE_GAS:
                        cavity[i, j, k] = CAVITY_EDGE
    if cavity[i, j, k] == CAVITY_EDGE:
        gas_kv[i, j, k] = 0.0


@wp.func
def is_cavity_gas(cavity: wp.array3d(dtype=wp.int32), types: wp.array3d(dtype=wp.int32), c: wp.vec3i):
    if cell_type_at(types, c) == FLUID:  # nested: Warp evaluates both sides of `and`
        if cavity[c[0], c[1], c[2]] == CAVITY_GAS:
            return True
    return False


@wp.kernel
def release_cavity_faces(types: wp.array3d(dtype=wp.int32), cavity: wp.array3d(dtype=wp.int32), axis: int,
                         vel: wp.array3d(dtype=float), valid: wp.array3d(dtype=wp.int32)):
    """Faces inside a cavity (a cavity cell on one side, nothing but cavity or empty cells on
    either, no solid) are not trusted and start at rest, so the extension carries the liquid's
    velocity in from the interface instead of the projection's."""
    i, j, k = wp.tid()
    hi = wp.vec3i(i, j, k)
    lo = hi - unit(axis)
    cav_lo = is_cavity_gas(cavity, types, lo)
    cav_hi = is_cavity_gas(cavity, types, hi)
    if not (cav_lo or cav_hi):
        return
    t_lo = cell_type_at(types, lo)
    t_hi = cell_type_at(types, hi)
    if is_solid(t_lo) or is_solid(t_hi) or (t_lo == FLUID and not cav_lo) or (t_hi == FLUID and not cav_hi):
        return
    vel[i, j, k] = 0.0
    valid[i, j, k] = 0


@wp.kernel
def cavity_room(
    cavity: wp.array3d(dtype=wp.int32),
    liq_volume: wp.array3d(dtype=float),
    gas_volume: wp.array3d(dtype=float),
    gas_mass: wp.array3d(dtype=float),
    rate: wp.array3d(dtype=float),
    cell_volume: float,
    dt: float,
    room: wp.array3d(dtype=float),
):
    """room[c]: the volume a cavity's cell gives its gas at the step's end, per kg of that gas
    (m^3/kg); -1 outside cavities. A near vacuum holds no space against the liquid and leaves
    none: in a cavity's gas or edge cell it fills the cell less its liquid, changed by the cell's
    volume change over the step (rate: gas_volume_rate's; 0 in an edge cell, which is
    incompressible); in a remnant cell it takes the cell's volume change, shared evenly. (An edge
    cell that only gave room back, never took it, left the gas 0.3 cells short of the liquid's
    cavity: the collapse time 1.5% early at 16 cells per radius, against 0.6%.)"""
    i, j, k = wp.tid()
    room[i, j, k] = -1.0
    kind = cavity[i, j, k]
    vg = gas_volume[i, j, k]
    mg = gas_mass[i, j, k]
    if kind == 0 or vg <= 0.0 or mg <= 0.0:
        return
    space = vg * wp.exp(wp.clamp(dt * rate[i, j, k], -1.0, 1.0))  # a remnant: its cell's volume change
    if kind != CAVITY_REMNANT:
        space = wp.max(cell_volume - liq_volume[i, j, k] + dt * rate[i, j, k] * vg, 0.0)
    room[i, j, k] = space / mg


@wp.kernel
def cavity_gas_J(
    x: wp.array(dtype=wp.vec3),
    phase: wp.array(dtype=wp.int32),
    active: wp.array(dtype=wp.int32),
    pmass: wp.array(dtype=float),
    pvol0: wp.array(dtype=float),
    room: wp.array3d(dtype=float),
    geo: GridGeometry,
    J: wp.array(dtype=float),
    flag: wp.array(dtype=wp.int32),
):
    """After update_gas_J: a gas particle touching a cavity's cells takes, on their share of its
    B-spline weights, the density their room leaves its gas (J = rest density / that density), not
    its own history: particles at the cavity's edge, whose stencil overlaps the liquid, were
    otherwise crushed step after step (J to 1e-3 at 32 cells per radius). Mass is untouched; the
    cavity's gas volume is its cells' room. flag: whether it touched a cavity (the memory)."""
    p = wp.tid()
    if active[p] == 0 or phase[p] != PHASE_GAS or not finite(x[p]):
        return
    xp = clamp_to_domain(x[p], geo.domain_hi, geo.dx, geo.dim)
    s = make_stencil(grid_coord(xp, geo.origin, 1.0 / geo.dx, CELL_OFFSET), geo.dim)
    w_cavity = float(0.0)
    specific = float(0.0)
    for i in range(3):
        for j in range(3):
            for k in range(s.nk):
                r = room[s.base[0] + i, s.base[1] + j, s.base[2] + k]
                if r >= 0.0:
                    w = s.wx[i] * s.wy[j] * s.wz[k]
                    w_cavity += w
                    specific += w * r
    flag[p] = 0
    if w_cavity > 0.0:
        J[p] = (1.0 - w_cavity) * J[p] + specific * pmass[p] / pvol0[p]
        flag[p] = 1


class Cavities:
    """The gas stage's cavity part: its arrays, and one call per hook of the gas stage."""

    def __init__(self, ctx):
        f = ctx.fields
        f.cavity, f.cavity_count, f.cavity_room = f.cells(wp.int32), f.cells(wp.int32), f.cells()
        ctx.particles.add_field("cavity_gas", wp.int32)  # checkpointed, sorted, compacted with the rest
        self.active = True  # whether a cavity may exist this step (then the kernels below run)
        self._marked = False  # whether f.cavity may hold a mark from an earlier step

    def after_p2g(self, ctx):
        """First of the step: no gas was a cavity's, nor under CAVITY_ENTER, at the last step's end
        (the gas stage's read-back, its state) means no cell can be one now: all is skipped."""
        f, p = ctx.fields, ctx.particles
        self.active = ctx.stage("gas").state.cavity > 0.0
        if not self.active:
            if self._marked:
                f.cavity.zero_()
                self._marked = False
            return
        self._marked = True
        f.cavity_count.zero_()
        ctx.launch(count_cavity_gas, p.count, [p.x, p.phase, p.active, p.cavity_gas, ctx.geometry, f.cavity_count])

    def on_cells(self, ctx):
        """After classify_phases: which cells are a cavity's."""
        if not self.active:
            return
        g, f = ctx.grid, ctx.fields
        ambient = ctx.scene.domain.ambient_pressure
        ctx.launch(mark_cavities, g.cells, [f.types, f.phase_cells, f.gas_volume, f.gas_pv, f.cavity_count, ambient,
                                            CAVITY_ENTER * ambient, CAVITY_EXIT * ambient, g.dim, f.gas_kv, f.cavity])

    def before_extend(self, ctx):
        """Before the gas's and the liquid's fields are extended (and copied: both get it)."""
        if not self.active:
            return
        f = ctx.fields
        for a in ctx.grid.axes:
            ctx.launch(release_cavity_faces, ctx.grid.face_shape(a), [f.types, f.cavity, a, f.vel[a], f.valid[a]])

    def update_J(self, ctx, dt: float):
        """After update_gas_J (f.gas_rate holds the cells' volume change)."""
        if not self.active:
            return
        g, f, p = ctx.grid, ctx.fields, ctx.particles
        ctx.launch(cavity_room, g.cells, [f.cavity, f.liq_volume, f.gas_volume, f.gas_mass, f.gas_rate, g.dx**3, dt,
                                          f.cavity_room])
        ctx.launch(cavity_gas_J, p.count, [p.x, p.phase, p.active, p.mass, p.vol0, f.cavity_room, ctx.geometry, p.J,
                                           p.cavity_gas])
