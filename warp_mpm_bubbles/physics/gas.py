"""Gas: the compressible phase of the one two-phase system (docs/design.md, "The gas").

The gas law and the system itself are core (core/gas_law.py; core/transfer_kernels.p2g_gas sums p
and kappa per cell, core/grid_kernels.pressure_diagonal_and_rhs puts kappa/dt^2 on the diagonal),
because every two-phase face needs both sides. This stage owns what only gas scenes do:

    after_p2g      gas mass, volume, p V and kappa V per cell
    on_cells       which fluid cells are gas; where the open air starts above each column
    before_extend  (sharp interface, liquid_velocity = "own") the gas keeps the shared projected
                   field; the liquid's own field is extrapolated across the interface
    before_g2p     (sharp interface) gas particles take their cells' volume change
    after_g2p      gas reaching open air vents, its mass booked (unless foam takes it)

A scene runs it when a shape or emitter uses a gas material, or it has sub-grid bubbles. Its time-step
limit, "gas_expansion", keeps a violent expansion or collapse resolved (dt_limit).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import warp as wp

from ..core import grid_kernels as gk
from ..core import kernel_args
from ..core.geometry import GridGeometry
from ..core.grid import EMPTY, FLUID, INTERFACE_SHARP, PHASE_GAS, PHASE_LIQUID
from ..core.cells import cell_divergence, cell_of, cell_type_at, is_phase_cell, unit
from ..core.host_state import HostState, saved
from ..core.stage import Stage
from ..core.gas_law import GAS_ADIABATIC, gas_pressure
from ..core.kernel_args import Particles
from ..core.transfer_kernels import compressible_gas_stencil, gas_volume_rate, p2g_gas, update_gas_J
from .cavity import CAVITY_ENTER, CAVITY_GAS, Cavities

wp.set_module_options({"enable_backward": False})


# ------------------------------------------------------------------------------- the open air
@wp.func
def height_along(c: wp.vec3i, up_axis: int, up_sign: int, n_up: int):
    """Cell index counted upwards (against gravity)."""
    if up_sign > 0:
        return c[up_axis]
    return n_up - 1 - c[up_axis]


@wp.func
def column_of(c: wp.vec3i, up_axis: int):
    col = c
    col[up_axis] = 0
    return col


@wp.kernel
def liquid_ceiling(
    types: wp.array3d(dtype=wp.int32),
    phase: wp.array3d(dtype=wp.int32),
    up_axis: int,
    up_sign: int,
    ceiling: wp.array3d(dtype=wp.int32),
    lo: wp.vec3i,  # first index of the launch, which may cover a box (core/active_box.py)
):
    """Per column along gravity, the height of the highest liquid cell (-1: none)."""
    i, j, k = wp.tid()
    i, j, k = i + lo[0], j + lo[1], k + lo[2]
    if types[i, j, k] != FLUID or phase[i, j, k] != PHASE_LIQUID:
        return
    c = wp.vec3i(i, j, k)
    col = column_of(c, up_axis)
    wp.atomic_max(ceiling, col[0], col[1], col[2], height_along(c, up_axis, up_sign, types.shape[up_axis]))


@wp.func
def exposed_to_open_air(
    types: wp.array3d(dtype=wp.int32),
    ceiling: wp.array3d(dtype=wp.int32),
    c: wp.vec3i,
    up_axis: int,
    up_sign: int,
    dim: int,
):
    """Open air at cell c: an empty cell at or beside it, and c above the highest liquid cell of
    its column. Without the second condition a particle-free hole that stretching opens inside
    the water would swallow the gas next to it. With no gravity there is no "above": any empty
    neighbour counts. (Venting and foam both ask this.)"""
    exposed = cell_type_at(types, c) == EMPTY
    for a in range(dim):
        for s in range(2):
            if cell_type_at(types, c + (2 * s - 1) * unit(a)) == EMPTY:
                exposed = True
    if exposed and up_axis >= 0:
        col = column_of(c, up_axis)
        exposed = height_along(c, up_axis, up_sign, types.shape[up_axis]) > ceiling[col[0], col[1], col[2]]
    return exposed


@wp.kernel
def vent_exposed_gas(geo: GridGeometry, types: wp.array3d(dtype=wp.int32), ceiling: wp.array3d(dtype=wp.int32),
                     particles: Particles, vented_mass: wp.array(dtype=wp.float64)):
    """Gas that reaches the open air joins it: the particle is retired and its mass booked as
    vented, so gas mass stays exactly accounted for.
    """
    p = wp.tid()
    if particles.active[p] == 0 or particles.phase[p] != PHASE_GAS:
        return
    c = cell_of(particles.x[p], geo.origin, geo.dx)
    if exposed_to_open_air(types, ceiling, c, geo.up_axis, geo.up_sign, geo.dim):
        particles.active[p] = 0
        wp.atomic_add(vented_mass, 0, wp.float64(particles.mass[p]))


# ------------------------------------------------------------------------- the liquid's own field
@wp.kernel
def keep_phase_faces(
    types: wp.array3d(dtype=wp.int32),
    phase: wp.array3d(dtype=wp.int32),
    axis: int,
    keep: int,
    vel: wp.array3d(dtype=float),
    valid: wp.array3d(dtype=wp.int32),
    shared_vel: wp.array3d(dtype=float),
    shared_valid: wp.array3d(dtype=wp.int32),
    lo: wp.vec3i,  # first index of the launch, which may cover a box (core/active_box.py)
):
    """Trust only the faces that touch a fluid cell of phase `keep`; the others get extrapolated.
    The projected field as it was goes to shared_vel, shared_valid (the other phase's copy).

    The liquid's own field (liquid_velocity = "own"): liquid particles read velocities extended
    from the liquid's side, so the fast gas circulating inside a bubble does not drag the water
    beside it across the interface. A face between a liquid and a gas cell keeps the normal
    velocity both phases share.
    """
    i, j, k = wp.tid()
    i, j, k = i + lo[0], j + lo[1], k + lo[2]
    trusted = valid[i, j, k]
    shared_vel[i, j, k] = vel[i, j, k]
    shared_valid[i, j, k] = trusted
    hi = wp.vec3i(i, j, k)
    lo = hi - unit(axis)
    valid[i, j, k] = 0
    if is_phase_cell(types, phase, lo, keep) or is_phase_cell(types, phase, hi, keep):
        valid[i, j, k] = trusted


# ------------------------------------------------------------------------------ pressure spread
MAX_PRESSURE_SPREAD = 10.0  # a gas particle's pressure, at most this many times its cells' (absolute)
SPREAD_GATE = MAX_PRESSURE_SPREAD - 1.0  # checked only while some gas is a cavity's or this far above ambient


@wp.kernel
def limit_gas_pressure_spread(p_atm: float, spread: float, geo: GridGeometry, gas_volume: wp.array3d(dtype=float),
                              gas_pv: wp.array3d(dtype=float), particles: Particles):
    """A gas particle's absolute pressure stays within `spread` times the highest of its cells'
    (the pressure the solve sees: volume-weighted, so a particle crushed to no volume has no say in
    it). A cell's volume change is shared by all its particles alike, so one already crushed (a
    sliver's tail beside the liquid) was crushed again every step while its cell's pressure stayed
    low, until its pressure, and with it the gas_expansion step, ran away (1e9 Pa, 1e-17 s, then
    NaN, after a 0.5%-ambient cavity closed). Measured spread in the 0.2 p_inf collapse: 1.26."""
    p = wp.tid()
    gas, s = compressible_gas_stencil(geo, particles, p)
    if not gas:
        return
    law = particles.gas_law
    gamma = particles.gas_gamma
    J = particles.J
    highest = float(0.0)
    for i in range(3):
        for j in range(3):
            for k in range(s.nk):
                vg = gas_volume[s.base[0] + i, s.base[1] + j, s.base[2] + k]
                if vg > 0.0:
                    highest = wp.max(highest, p_atm + gas_pv[s.base[0] + i, s.base[1] + j, s.base[2] + k] / vg)
    cap = spread * highest
    if highest <= 0.0 or p_atm + gas_pressure(law[p], J[p], gamma[p], p_atm) <= cap:
        return
    if law[p] == GAS_ADIABATIC:
        J[p] = wp.pow(p_atm / cap, 1.0 / gamma[p])
    else:
        J[p] = p_atm / cap


# ------------------------------------------------------------------------------ the step limit
GAS_EXPANSION_SHARE = 0.1  # the most a gas cell's volume may change in one step (relative)


GAUGE_SLOT, RATE_SLOT, CAVITY_SLOT = 2, 3, 4  # the gas's slots of the step's read-back (core/state.py)


@wp.kernel
def gas_step_measures(
    phase: wp.array(dtype=wp.int32),
    active: wp.array(dtype=wp.int32),
    J: wp.array(dtype=float),
    law: wp.array(dtype=wp.int32),
    gamma: wp.array(dtype=float),
    cavity_gas: wp.array(dtype=wp.int32),
    p_atm: float,
    cavity_enter: float,
    out: wp.array(dtype=float),
):
    """out[GAUGE_SLOT]: the largest |gauge pressure| of the gas particles; out[CAVITY_SLOT] = 1 if
    any is a cavity's or below the cavity's entry pressure (else no cell can be a cavity's next step)."""
    p = wp.tid()
    if active[p] == 0 or phase[p] != PHASE_GAS:
        return
    gauge = gas_pressure(law[p], J[p], gamma[p], p_atm)
    wp.atomic_max(out, GAUGE_SLOT, wp.abs(gauge))
    if cavity_gas[p] != 0 or p_atm + gauge < cavity_enter:
        out[CAVITY_SLOT] = 1.0


@wp.kernel
def gas_cell_expansion(
    types: wp.array3d(dtype=wp.int32),
    phase: wp.array3d(dtype=wp.int32),
    vel_u: wp.array3d(dtype=float),
    vel_v: wp.array3d(dtype=float),
    vel_w: wp.array3d(dtype=float),
    cavity: wp.array3d(dtype=wp.int32),
    target_div: wp.array3d(dtype=float),
    dx: float,
    dim: int,
    slot: int,
    out: wp.array(dtype=float),
    lo: wp.vec3i,  # first index of the launch, which may cover a box (core/active_box.py)
):
    """out[slot]: the largest |div u - d| (1/s, the gas's relative volume change rate) over gas cells,
    d the divergence the volume correction asked of the cell (target_div), which is not the gas's
    (gas_volume_rate leaves it out of J too): an incompressible gas's cells move only by d, and
    counted as expansion it would set the time step of a rising bubble at nearly every step.
    Cavities' cells are not counted (physics/cavity.py: a near vacuum's volume is the room it is left)."""
    i, j, k = wp.tid()
    i, j, k = i + lo[0], j + lo[1], k + lo[2]
    if types[i, j, k] != FLUID or phase[i, j, k] != PHASE_GAS or cavity[i, j, k] == CAVITY_GAS:
        return
    div = cell_divergence(vel_u, vel_v, vel_w, wp.vec3i(i, j, k), dim)
    wp.atomic_max(out, slot, wp.abs(div / dx - target_div[i, j, k]))


def pressure_step(cfl: float, dx: float, gauge: float, rho: float, hydrostatic: float) -> float:
    """The step at which a pressure imbalance moves the liquid cfl cells: the imbalance dp (the gas's
    |gauge pressure| beyond any hydrostatic head in the domain) accelerates the liquid across one
    cell at dp / (rho dx), reaching the speed sqrt(dp / rho) over a cell, as gravity's sqrt(g dx)
    does in the CFL limit. Shared with scene/limits.py's estimate before the run."""
    dp = gauge - hydrostatic
    return cfl * dx / math.sqrt(dp / rho) if dp > 0.0 and rho > 0.0 else math.inf


# ------------------------------------------------------------------------------------ the stage


@dataclass
class GasState(HostState):
    """The last step's measures for dt_limit, from the step's one read-back (checkpointed: a resumed
    run steps alike)."""

    gauge: float = saved("gas_gauge", math.nan)  # the largest |gauge pressure|, Pa (NaN: not measured yet)
    expansion_rate: float = saved("gas_expansion_rate", 0.0)  # the fastest relative volume change, 1/s
    cavity: float = saved("gas_cavity", 1.0)  # 1: a cavity may exist this step (physics/cavity.py)


class GasStage(Stage):
    name = "gas"
    timer = "vent"  # its after-g2p time: the rest is timed with p2g, grid, extend and g2p
    limit = "gas_expansion"
    grid_box = True  # its grid kernels cover ctx.region; outside it the gas arrays hold no gas
    # Not graph-safe: its hooks choose kernels on the host from the last read-back (a cavity may
    # exist, the gauge past SPREAD_GATE) and launch on the gas's own box, which no graph key holds.
    graph_safe = False

    def __init__(self, ctx, settings=None):
        super().__init__(ctx, settings)
        f, solver = ctx.fields, ctx.scene.solver
        f.gas_mass, f.gas_volume, f.gas_pv, f.gas_kv = (f.cells() for _ in range(4))
        f.gas_count = f.cells(wp.int32)
        f.target_div, f.gas_rate = f.cells(), f.cells()
        up_axis = ctx.up[0]
        column = list(ctx.grid.cells)
        if up_axis >= 0:
            column[up_axis] = 1
        f.ceiling = wp.zeros(tuple(column), dtype=wp.int32, device=ctx.device)
        self.sharp = ctx.interface == INTERFACE_SHARP
        self.cavities = Cavities(ctx)  # near-vacuum gas: a pressure boundary (physics/cavity.py)
        if self.sharp and solver.liquid_velocity == "own":
            f.gas_vel, f.gas_valid = f.faces(), f.faces(wp.int32)
        # Foam takes the gas that reaches open air (effects/foam.py): then nothing vents here.
        self.vents = "foam" not in ctx.effects
        self._limit = (None, math.inf)  # dt_limit is asked more than once per step
        self.state = GasState()
        ctx.report_writers.append(self._write_report)
        ctx.report_readers.append(self._read_report)
        mats = list(ctx.scene.materials.values())
        liquids = [m.density for m in mats if m.kind == "liquid"] or [m.density for m in mats if m.is_gas]
        self.rho = min(liquids)  # the lightest fluid the gas pushes: the fastest response
        g = math.sqrt(sum(a * a for a in ctx.gravity))
        height = ctx.grid.domain_size[ctx.up[0]] if ctx.up[0] >= 0 else 0.0
        self.hydrostatic = max(liquids) * g * height  # no head in the domain is deeper

    def dt_limit(self, ctx) -> float:
        """"gas_expansion": the smaller of (a) the step at which the gas's pressure imbalance moves
        the liquid cfl cells (pressure_step: it sees a violent start before anything moves) and
        (b) the step in which the fastest-changing gas cell changes volume by GAS_EXPANSION_SHARE,
        at the last step's rate. Without it a gas seeded at 10 atm started with an 8 ms step, 60
        times its expansion time (benchmarks/validation/rate_invariance.py expansion)."""
        key = (ctx.stats.steps, ctx.time, ctx.particles.count)
        if self._limit[0] == key:
            return self._limit[1]
        gauge = self.state.gauge
        if math.isnan(gauge):  # the first step (or an older checkpoint): measured once here
            first = ctx.read_host(self._measure_gauge(ctx, wp.zeros(CAVITY_SLOT + 1, dtype=float, device=ctx.device)))
            gauge = float(first[GAUGE_SLOT])
            self.state.cavity = float(first[CAVITY_SLOT])
        cfl, dx, ambient = ctx.scene.solver.cfl, ctx.grid.dx, ctx.scene.domain.ambient_pressure
        # (an infinite gauge is gas compressed to J = 0: a diverged state, left to p2g's check)
        limit = pressure_step(cfl, dx, gauge, self.rho, self.hydrostatic) if math.isfinite(gauge) else math.inf
        rate = self.state.expansion_rate  # checkpointed: a resumed run steps alike
        if 0.0 < rate < math.inf:  # an overflowed rate is a diverged step: p2g's check names it
            # Floor: a very compressible gas (near vacuum) changes volume at a rate ~ 1/dt whatever
            # dt is, which would shrink the step geometrically to 0: the floor is a tenth of the step
            # at which the ambient pressure, pushing into a vacuum, moves the liquid cfl cells.
            floor = GAS_EXPANSION_SHARE * pressure_step(cfl, dx, ambient, self.rho, 0.0)
            limit = min(limit, max(GAS_EXPANSION_SHARE / rate, floor))
        self._limit = (key, limit)
        return limit

    def _measure_gauge(self, ctx, out):
        p = ctx.particles
        ambient = ctx.scene.domain.ambient_pressure
        ctx.launch(gas_step_measures, p.count, [p.phase, p.active, p.J, p.gas_law, p.gas_gamma, p.cavity_gas, ambient,
                                                 CAVITY_ENTER * ambient, out])
        return out

    def _write_report(self, ctx):
        # The next step's limit from this step's end state, carried by the step's one read-back.
        g, f, r = ctx.grid, ctx.fields, ctx.region
        self._measure_gauge(ctx, f.max_speed)
        ctx.launch(gas_cell_expansion, r.cells, [f.types, f.phase_cells, *(f.gas_vel or f.vel), f.cavity, f.target_div,
                                                 g.dx, g.dim, RATE_SLOT, f.max_speed, r.lo])

    def _read_report(self, ctx, report):
        self.state.gauge = float(report[GAUGE_SLOT])
        self.state.expansion_rate = float(report[RATE_SLOT])
        self.state.cavity = float(report[CAVITY_SLOT])

    def hooks(self) -> set[str]:
        hooks = super().hooks()
        if not self.vents:
            hooks.discard("after_g2p")
        return hooks

    def after_p2g(self, ctx, dt: float):
        f, p = ctx.fields, ctx.particles
        for arr in (f.gas_mass, f.gas_volume, f.gas_pv, f.gas_kv, f.gas_count):
            arr.zero_()
        ctx.launch_splat(p2g_gas, [ctx.scene.domain.ambient_pressure, ctx.geometry, kernel_args.particle_arrays(p),
                                   kernel_args.splat(f), f.gas_count])
        self.cavities.after_p2g(ctx)

    def on_cells(self, ctx, dt: float):
        f, r = ctx.fields, ctx.region
        ctx.launch(gk.classify_phases, r.cells,
                   [f.types, f.gas_count, f.liq_volume, f.gas_volume, ctx.interface, f.phase_cells, r.lo])
        self.cavities.on_cells(ctx)
        up_axis, up_sign = ctx.up
        if up_axis >= 0:  # where the open air starts, for venting, foam and sub-grid bubbles
            f.ceiling.fill_(-1)  # (no liquid cell lies outside the box)
            ctx.launch(liquid_ceiling, r.cells, [f.types, f.phase_cells, up_axis, up_sign, f.ceiling, r.lo])

    def before_extend(self, ctx, dt: float):
        f, r = ctx.fields, ctx.region
        self.cavities.before_extend(ctx)
        if f.gas_vel is None:
            return
        # The gas reads (a copy of) the shared projected field; the liquid keeps only its own faces,
        # and the core extends that across the interface. (Outside the box both hold the empty state.)
        for a in ctx.grid.axes:
            ctx.launch_box(keep_phase_faces, r.lo, r.faces(a),
                           [f.types, f.phase_cells, a, PHASE_LIQUID, f.vel[a], f.valid[a], f.gas_vel[a], f.gas_valid[a]])
        # Only gas particles (g2p) and cells holding gas (their volume change, the step limit) read
        # the gas's field, all within a cell of a gas particle: it is extended on the gas's box
        # (active_box.ActiveRegion.gas_box), whose margin covers what they read; outside it the field
        # keeps the projected values, which nothing reads.
        ctx.extend(f.gas_vel, f.gas_valid, r.gas_box(ctx.particles))

    def before_g2p(self, ctx, dt: float):
        if not self.sharp:
            return
        g, f, p = ctx.grid, ctx.fields, ctx.particles
        # The gas takes its cells' volume change, before g2p moves it (the weights p2g_gas used).
        # The baseline treats a cell with any gas as all gas, so there the published rule stays:
        # J follows the interpolated divergence (in g2p).
        box = ctx.region.gas_box(p)  # update_gas_J reads the rate within a cell of its gas particles
        ctx.launch(gas_volume_rate, box.cells, [box.lo, g.dx, g.dim, f.types,
                                                kernel_args.face_field(f.gas_vel or f.vel), f.gas_volume, f.target_div,
                                                f.gas_rate])
        ctx.launch_particles(update_gas_J, [dt, ctx.geometry, f.gas_rate, kernel_args.particle_arrays(p)])
        self.cavities.update_J(ctx, dt)
        ambient = ctx.scene.domain.ambient_pressure
        if self.cavities.active or self.state.gauge > SPREAD_GATE * ambient:
            ctx.launch(limit_gas_pressure_spread, p.count,
                       [ambient, MAX_PRESSURE_SPREAD, ctx.geometry, f.gas_volume, f.gas_pv, kernel_args.particle_arrays(p)])

    def after_g2p(self, ctx, dt: float):
        f, p = ctx.fields, ctx.particles
        ctx.launch(vent_exposed_gas, p.count,
                   [ctx.geometry, f.types, f.ceiling, kernel_args.particle_arrays(p), f.vented_mass])

