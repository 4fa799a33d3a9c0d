"""A two-way foam head ([effects.foam] head = true): foam that rests on the water, stacks into a head,
loads the water below with its weight, takes its films' liquid from the water and gives back what
drains, and (collapse = "drainage") bursts when its films run dry.

The foam is a light material on the surface, moved column by column (docs/foam.md, "The head"):

- **Stacking.** Each step the foam particles' volume (gas plus films' liquid) is summed into the
  cells; each grid column finds its water surface (surface_elevation) and the foam volume below
  every cell. A foam particle's place is the surface plus the foam volume below it in its column
  over the column's area: the column's foam packed on the water, in the order its particles
  already have. The head's height in a column is its foam volume over its area.
- **Resting, by weight and support.** A particle above its place falls freely under gravity; one
  that reaches it rests, moving with the water's surface along gravity and settling toward its
  place at up to `rise_speed`; across gravity it only levels the head (spreading: a light layer
  floating on water spreads down the gradient of its thickness). Every change of a resting
  particle's momentum besides its weight's impulse is the water's support: its opposite is booked
  to the column.
- **Loading the water (two-way).** Before the next pressure solve (the `force` hook) each column's
  booked impulse goes on its water LOAD_DEPTH cells under the surface, shared by the two faces
  around that depth by nearness, as the pressure solve applies its own forces (du = impulse /
  (rho_face dx^3)): a head of weight W on a column of area A adds W / A to the pressure below.
  What no face can take (a column without water) stays booked.
- **Liquid back and forth.** Per column the liquid owed to the water: new films lend theirs,
  drained liquid (foam_drainage.py) and the films of burst bubbles are owed back. Where the films
  owe a column's water a particle, water particles near the surface join them (take_water); where
  the water is owed one, the stage adds it just under the surface, at rest. Water in particles +
  films + owed stays constant to round-off.
- **Films burst when they thin** (`collapse = "drainage"`, burst_head): a foam particle whose
  liquid fraction falls below `burst_fraction` bursts (its gas vents, its films' liquid is owed to
  the water); `collapse = "lifetime"` keeps Bikerman's drawn lifetimes (foam.py).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from ..core import kernel_args
from ..core.host_state import HostState, saved
from ..core.boundary import clamp_to_domain, open_wall_exit, wall_stopped
from ..core.cells import cell_of, inside, is_solid
from ..core.geometry import GridGeometry
from ..core.grid import FLUID, LEAVING, PHASE_FOAM, PHASE_LIQUID
from ..core.kernel_args import CellPhases, FaceField, Particles
from ..core.transfer_kernels import interpolate_velocity
from .foam_drainage import BURST, LEFT, FoamBook, book_to_column, cell_at, column_launch_shape

wp.set_module_options({"enable_backward": False})

NO_SURFACE = wp.constant(-1.0e30)  # a column without water: its foam falls freely
SURFACE_FILL = wp.constant(0.5)  # a cell at least this full of liquid is under the surface
LOAD_DEPTH = wp.constant(2.5)  # cells under the surface where the foam's load goes on the water
SPREAD_LIMIT = wp.constant(0.2)  # of the explicit levelling's stability limit, dx^2 / (2 dt h)


@wp.struct
class HeadCells:
    """The head's cell arrays (per column: at the column's cell of up index 0)."""

    foam: wp.array3d(dtype=wp.float64)  # foam volume (gas + films) per cell, m^3
    stack: wp.array3d(dtype=wp.float64)  # foam volume below the cell in its column, m^3
    surface: wp.array3d(dtype=float)  # per column: the water surface's elevation, m, or NO_SURFACE
    top: wp.array3d(dtype=float)  # per column: the head's top, its surface + its foam volume / area, m
    impulse: wp.array3d(dtype=wp.vec3d)  # per column: the foam's reaction owed to the water, N s
    returned: wp.array3d(dtype=wp.float64)  # per column: liquid owed to the water, m^3


@wp.struct
class HeadParams:
    dt: float  # s
    up: wp.vec3  # unit vector against gravity
    rise_speed: float  # m/s: the fastest a submerged foam particle floats back to its place
    liquid_density: float  # kg/m^3, of the films' liquid
    burst_fraction: float  # films thinner than this liquid fraction burst; 0: they do not
    lifetimes: int  # 1: burst at the end of the drawn lifetime (Bikerman)


@wp.func
def level_index(level: int, n: int, up_sign: int):
    """The index along the up axis of the level-th cell from the bottom."""
    if up_sign > 0:
        return level
    return n - 1 - level


@wp.func
def floor_elevation(j: int, geo: GridGeometry):
    """Elevation (m, along up) of the lower face of the cell with index j along the up axis."""
    o = geo.origin[geo.up_axis]
    if geo.up_sign > 0:
        return o + float(j) * geo.dx
    return -(o + float(j + 1) * geo.dx)


@wp.func
def fill(types: wp.array3d(dtype=wp.int32), liq_volume: wp.array3d(dtype=float), c: wp.vec3i, inv_cell_vol: float):
    """The liquid share of cell c (0 for a wall), at most 1."""
    if is_solid(types[c[0], c[1], c[2]]):
        return 0.0
    return wp.min(liq_volume[c[0], c[1], c[2]] * inv_cell_vol, 1.0)


@wp.func
def surface_level(types: wp.array3d(dtype=wp.int32), liq_volume: wp.array3d(dtype=float), c0: wp.vec3i,
                  geo: GridGeometry):
    """The level (from the bottom) of the column's highest cell at least half full of liquid; -1: none."""
    n = types.shape[geo.up_axis]
    inv_cell_vol = 1.0 / (geo.dx * geo.dx * geo.dx)
    level = n - 1
    while level >= 0:
        c = cell_at(c0, geo.up_axis, level_index(level, n, geo.up_sign))
        if fill(types, liq_volume, c, inv_cell_vol) >= SURFACE_FILL:
            return level
        level = level - 1
    return -1


@wp.kernel
def splat_head(geo: GridGeometry, particles: Particles, liquid: wp.array(dtype=float), head: HeadCells):
    """Each foam particle's volume (gas and films) into its cell. Launched serially: one summing order."""
    p = wp.tid()
    if particles.active[p] == 0 or particles.phase[p] != PHASE_FOAM:
        return
    c = cell_of(particles.x[p], geo.origin, geo.dx)
    if inside(head.foam, c):
        volume = wp.float64(particles.vol0[p] * particles.J[p]) + wp.float64(liquid[p])
        wp.atomic_add(head.foam, c[0], c[1], c[2], volume)


@wp.func
def surface_elevation(types: wp.array3d(dtype=wp.int32), liq_volume: wp.array3d(dtype=float), c0: wp.vec3i,
                      geo: GridGeometry):
    """The elevation of the column's water surface, m, or NO_SURFACE: the bottom of the cell below
    the highest cell at least half full, plus the liquid of the four cells from there up (so the
    surface moves smoothly as it crosses from one cell into the next)."""
    s = surface_level(types, liq_volume, c0, geo)
    if s < 0:
        return float(NO_SURFACE)
    n = types.shape[geo.up_axis]
    inv_cell_vol = 1.0 / (geo.dx * geo.dx * geo.dx)
    base = wp.max(s - 1, 0)
    cb = cell_at(c0, geo.up_axis, level_index(base, n, geo.up_sign))
    if is_solid(types[cb[0], cb[1], cb[2]]):
        base = s  # water on a solid floor (a glass's bottom): its depth counts from the floor's top
    depth = float(0.0)
    for level in range(base, wp.min(s + 3, n)):
        depth += fill(types, liq_volume, cell_at(c0, geo.up_axis, level_index(level, n, geo.up_sign)), inv_cell_vol)
    return floor_elevation(level_index(base, n, geo.up_sign), geo) + depth * geo.dx


@wp.kernel
def head_columns(geo: GridGeometry, types: wp.array3d(dtype=wp.int32), liq_volume: wp.array3d(dtype=float),
                 head: HeadCells):
    """Per column (launched with the up axis's extent 1): the water surface, and the foam volume
    below each cell."""
    i, j0, k = wp.tid()
    c0 = wp.vec3i(i, j0, k)
    n = types.shape[geo.up_axis]
    slot = cell_at(c0, geo.up_axis, 0)
    z = surface_elevation(types, liq_volume, c0, geo)
    head.surface[slot[0], slot[1], slot[2]] = z
    total = wp.float64(0.0)
    for level in range(n):
        c = cell_at(c0, geo.up_axis, level_index(level, n, geo.up_sign))
        head.stack[c[0], c[1], c[2]] = total
        total = total + head.foam[c[0], c[1], c[2]]
    head.top[slot[0], slot[1], slot[2]] = z + float(total) / (geo.dx * geo.dx)


@wp.func
def thickness(head: HeadCells, slot: wp.vec3i):
    """The head's height over its column's water, m (0 without water)."""
    z = head.surface[slot[0], slot[1], slot[2]]
    if z <= 0.5 * NO_SURFACE:
        return 0.0
    return head.top[slot[0], slot[1], slot[2]] - z


@wp.func
def spreading(geo: GridGeometry, head: HeadCells, slot: wp.vec3i, rise_speed: float, dt: float):
    """The foam's flow across gravity down the gradient of its head's height h: a light layer
    floating on the water spreads as a gravity current, levelling its thickness (its top stands
    higher where it is thicker, by (1 - rho_foam / rho_liquid) of it). A speed times the slope of h,
    at most that speed, per axis; the speed is rise_speed, or less where the levelling, a diffusion
    of h with coefficient speed x h, would be unstable in one step: SPREAD_LIMIT dx^2 / (dt h)."""
    v = wp.vec3(0.0)
    here = thickness(head, slot)
    speed = wp.min(rise_speed, SPREAD_LIMIT * geo.dx * geo.dx / (dt * wp.max(here, geo.dx)))
    for b in range(geo.dim):
        if b != geo.up_axis:
            lo = slot
            lo[b] = slot[b] - 1
            hi = slot
            hi[b] = slot[b] + 1
            h_lo = here
            h_hi = here
            if inside(head.top, lo) and head.surface[lo[0], lo[1], lo[2]] > 0.5 * NO_SURFACE:
                h_lo = thickness(head, lo)
            if inside(head.top, hi) and head.surface[hi[0], hi[1], hi[2]] > 0.5 * NO_SURFACE:
                h_hi = thickness(head, hi)
            v[b] = -speed * wp.clamp((h_hi - h_lo) / (2.0 * geo.dx), -1.0, 1.0)
    return v


@wp.kernel
def burst_head(prm: HeadParams, geo: GridGeometry, particles: Particles, book: FoamBook,
               vented_mass: wp.array(dtype=wp.float64)):
    """Age the head's foam; burst those whose lifetime is over (collapse = "lifetime") or whose films
    are thinner than burst_fraction: the gas vents, the films' liquid is owed to the column's water."""
    p = wp.tid()
    if particles.active[p] == 0 or particles.phase[p] != PHASE_FOAM:
        return
    remaining = book.life[p] - prm.dt
    book.life[p] = remaining
    held = book.liquid[p]
    gas = particles.vol0[p] * particles.J[p]
    dry = held < prm.burst_fraction * (held + gas)
    if (prm.lifetimes != 0 and remaining <= 0.0) or dry:
        particles.active[p] = 0
        wp.atomic_add(vented_mass, 0, wp.float64(particles.mass[p]))
        wp.atomic_add(book.ledger, BURST, wp.float64(held))
        x = clamp_to_domain(particles.x[p], geo.domain_hi, geo.dx, geo.dim)
        book_to_column(book, cell_of(x, geo.origin, geo.dx), geo.up_axis, wp.float64(held))


@wp.func
def place_in_head(geo: GridGeometry, head: HeadCells, c: wp.vec3i, e: float, zs: float):
    """The elevation of a particle's place in its column's head (at elevation e, in cell c)."""
    frac = wp.clamp((e - floor_elevation(c[geo.up_axis], geo)) / geo.dx, 0.0, 1.0)
    below = head.stack[c[0], c[1], c[2]] + wp.float64(frac) * head.foam[c[0], c[1], c[2]]
    return zs + float(below) / (geo.dx * geo.dx)


@wp.func
def out_of_solid(types: wp.array3d(dtype=wp.int32), geo: GridGeometry, x: wp.vec3, up_axis: int, up_sign: int):
    """A foam particle in a solid cell moved onto the centre line of the open cell next to it that it
    is nearest to (across gravity, or above): a collider puts particles on its true surface, which
    may lie in a cell whose centre is inside it, where the head would find no water under them and
    let them fall through the solid. The open cell's centre is outside every collider."""
    c = cell_of(x, geo.origin, geo.dx)
    if not inside(types, c) or not is_solid(types[c[0], c[1], c[2]]):
        return x
    best = float(2.0)
    y = x
    q = (x - geo.origin) / geo.dx
    for b in range(geo.dim):
        for side in range(2):
            step = 2 * side - 1
            if b == up_axis and step != up_sign:
                continue  # never down: that is through the solid
            n = c
            n[b] = c[b] + step
            gap = q[b] - float(c[b])  # how far into the cell from its low face, in cells
            if step > 0:
                gap = 1.0 - gap
            if inside(types, n) and not is_solid(types[n[0], n[1], n[2]]) and gap < best:
                best = gap
                y = x
                y[b] = geo.origin[b] + (float(n[b]) + 0.5) * geo.dx
    return y


@wp.func
def into_solid(types: wp.array3d(dtype=wp.int32), geo: GridGeometry, x: wp.vec3, moved: wp.vec3, a: int):
    """The step from x to `moved` along axis a alone ends in a solid cell (inside the domain)."""
    probe = x
    probe[a] = moved[a]
    c = cell_of(clamp_to_domain(probe, geo.domain_hi, geo.dx, geo.dim), geo.origin, geo.dx)
    return inside(types, c) and is_solid(types[c[0], c[1], c[2]])


@wp.kernel
def settle_foam(prm: HeadParams, geo: GridGeometry, types: wp.array3d(dtype=wp.int32), vel: FaceField,
                particles: Particles, book: FoamBook, head: HeadCells):
    """Move the head's foam: free fall above its place, resting on the water at it; the support's
    impulse is booked, reversed, to the column's water. Foam never enters a solid cell: over a solid
    with no water between (a glass's rim, the floor outside it) it rests on the solid. Foam that
    goes out through an open wall takes its films' liquid with it (booked as LEFT)."""
    liquid = book.liquid
    p = wp.tid()
    if particles.active[p] == 0 or particles.phase[p] != PHASE_FOAM:
        return
    x0 = clamp_to_domain(particles.x[p], geo.domain_hi, geo.dx, geo.dim)
    xp = out_of_solid(types, geo, x0, geo.up_axis, geo.up_sign)
    c = cell_of(xp, geo.origin, geo.dx)
    slot = cell_at(c, geo.up_axis, 0)
    zs = head.surface[slot[0], slot[1], slot[2]]
    v_old = particles.v[p]
    vp = v_old + prm.dt * geo.gravity  # free flight
    e = wp.dot(xp, prm.up)
    resting = False
    if zs > 0.5 * NO_SURFACE:
        zt = place_in_head(geo, head, c, e, zs)
        if e + prm.dt * wp.dot(vp, prm.up) <= zt:  # it reaches its place: the water below carries it
            at_surface = clamp_to_domain(xp + (wp.min(e, zs) - e) * prm.up, geo.domain_hi, geo.dx, geo.dim)
            vl = interpolate_velocity(vel, at_surface, geo.origin, geo.dx, geo.dim)
            # It moves with the surface, settling toward its place at up to rise_speed (linearly within a cell).
            vp = (wp.dot(vl, prm.up) + prm.rise_speed * wp.clamp((zt - e) / geo.dx, -1.0, 1.0)) * prm.up
            vp = vp + spreading(geo, head, slot, prm.rise_speed, prm.dt)
            resting = True
    moved = xp + prm.dt * vp
    for a in range(geo.dim):  # a solid takes the part of the step that would carry it in
        if into_solid(types, geo, xp, moved, a):
            moved[a] = xp[a]
            vp[a] = 0.0
    if resting:
        m = wp.float64(particles.mass[p]) + wp.float64(prm.liquid_density * liquid[p])
        support = wp.vec3d(vp - v_old - prm.dt * geo.gravity)
        wp.atomic_sub(head.impulse, slot[0], slot[1], slot[2], m * support)  # the water's reaction
    code = open_wall_exit(moved, geo, particles.phase[p])
    if code == LEAVING:  # book_outflow retires it and books its gas
        wp.atomic_add(book.ledger, LEFT, wp.float64(liquid[p]))
    particles.active[p] = code
    xn = clamp_to_domain(moved, geo.domain_hi, geo.dx, geo.dim)
    particles.x[p] = xn
    particles.v[p] = wall_stopped(moved, xn, vp, geo.dim)


@wp.func
def push_face(vel: wp.array3d(dtype=float), inv_rho: wp.array3d(dtype=float), cells: CellPhases,
              f: wp.vec3i, axis: int, impulse: float, inv_cell_vol: float):
    """Give the face f (normal to `axis`) between two liquid cells `impulse` (N s) as the pressure
    solve gives its own (du = impulse / (rho_face dx^3)); returns what it took. A face beside a gas
    cell (a bubble under the head) takes none: its density is the gas's, and the same impulse
    would move it about a thousand times faster than the water it stands for."""
    lo = f
    lo[axis] = f[axis] - 1
    if not inside(cells.types, lo) or not inside(cells.types, f) or not inside(inv_rho, f):
        return 0.0
    if cells.types[lo[0], lo[1], lo[2]] != FLUID or cells.types[f[0], f[1], f[2]] != FLUID:
        return 0.0
    if cells.phase[lo[0], lo[1], lo[2]] != PHASE_LIQUID or cells.phase[f[0], f[1], f[2]] != PHASE_LIQUID:
        return 0.0
    k = inv_rho[f[0], f[1], f[2]]
    if k <= 0.0:
        return 0.0
    vel[f[0], f[1], f[2]] = vel[f[0], f[1], f[2]] + impulse * k * inv_cell_vol
    return impulse


@wp.func
def push_axis(vel: FaceField, inv_rho: FaceField, cells: CellPhases, f: wp.vec3i, axis: int,
              impulse: float, inv_cell_vol: float):
    if axis == 0:
        return push_face(vel.u, inv_rho.u, cells, f, 0, impulse, inv_cell_vol)
    if axis == 1:
        return push_face(vel.v, inv_rho.v, cells, f, 1, impulse, inv_cell_vol)
    return push_face(vel.w, inv_rho.w, cells, f, 2, impulse, inv_cell_vol)


@wp.func
def bottom_face(level: int, n: int, up_sign: int):
    """The index along the up axis of the face under the level-th cell from the bottom."""
    if up_sign > 0:
        return level
    return n - level


@wp.kernel
def load_water(geo: GridGeometry, cells: CellPhases, liq_volume: wp.array3d(dtype=float),
               vel: FaceField, inv_rho: FaceField, head: HeadCells):
    """Each column's booked impulse onto its water's faces (launched with the up axis's extent 1):
    LOAD_DEPTH cells under the surface, shared by the two faces around that depth in proportion to
    their nearness (so the load moves smoothly with the surface: a load that jumped a cell with it
    would push the water sideways), across gravity on the side faces of the cell there."""
    i, j0, k = wp.tid()
    c0 = wp.vec3i(i, j0, k)
    slot = cell_at(c0, geo.up_axis, 0)
    owed = head.impulse[slot[0], slot[1], slot[2]]
    zs = surface_elevation(cells.types, liq_volume, c0, geo)
    if zs <= 0.5 * NO_SURFACE or (owed[0] == wp.float64(0.0) and owed[1] == wp.float64(0.0)
                                  and owed[2] == wp.float64(0.0)):
        return
    n = cells.types.shape[geo.up_axis]
    a = geo.up_axis
    icv = 1.0 / (geo.dx * geo.dx * geo.dx)
    q = (zs - LOAD_DEPTH * geo.dx - floor_elevation(level_index(0, n, geo.up_sign), geo)) / geo.dx
    level = int(wp.floor(q))
    w = q - float(level)
    if level < 1:  # shallow water: the face under the first cell above the floor's
        level = 1
        w = 0.0
    whole = float(owed[a])
    f = cell_at(c0, a, bottom_face(level, n, geo.up_sign))
    took = push_axis(vel, inv_rho, cells, f, a, (1.0 - w) * whole, icv)
    f = cell_at(c0, a, bottom_face(level + 1, n, geo.up_sign))
    took += push_axis(vel, inv_rho, cells, f, a, whole - took, icv)
    left = owed
    left[a] = owed[a] - wp.float64(took)
    # Across gravity: half on each side face of the cell at that depth (all on one where the other
    # is a wall).
    h = cell_at(c0, a, level_index(level, n, geo.up_sign))
    for b in range(geo.dim):
        if b != a:
            whole = float(owed[b])
            hi = h
            hi[b] = h[b] + 1
            took_lo = push_axis(vel, inv_rho, cells, h, b, 0.5 * whole, icv)
            took_hi = push_axis(vel, inv_rho, cells, hi, b, whole - took_lo, icv)
            if took_hi == 0.0 and took_lo != 0.0:
                took_lo += push_axis(vel, inv_rho, cells, h, b, whole - took_lo, icv)
            left[b] = owed[b] - wp.float64(took_lo) - wp.float64(took_hi)
    head.impulse[slot[0], slot[1], slot[2]] = left


@wp.kernel
def take_water(geo: GridGeometry, particles: Particles, head: HeadCells, taken: wp.array(dtype=wp.float64)):
    """Water particles within LOAD_DEPTH cells of the surface of a column that owes its films at least
    their volume join the films (retired; their mass booked in `taken`, kg): the liquid a new foam's
    films hold comes out of the water under it. Launched serially on the CPU: the same particles
    every run; on a GPU, which of a column's particles go may differ, never how much."""
    p = wp.tid()
    if particles.active[p] == 0 or particles.phase[p] != PHASE_LIQUID:
        return
    xp = clamp_to_domain(particles.x[p], geo.domain_hi, geo.dx, geo.dim)
    c = cell_of(xp, geo.origin, geo.dx)
    slot = cell_at(c, geo.up_axis, 0)
    if not inside(head.surface, slot):
        return
    zs = head.surface[slot[0], slot[1], slot[2]]
    if zs <= 0.5 * NO_SURFACE or float(geo.up_sign) * xp[geo.up_axis] < zs - LOAD_DEPTH * geo.dx:
        return
    v = wp.float64(particles.vol0[p])
    before = wp.atomic_add(head.returned, slot[0], slot[1], slot[2], v)
    if before > -v:  # the column owes less than this particle: it stays water
        wp.atomic_sub(head.returned, slot[0], slot[1], slot[2], v)
        return
    particles.active[p] = 0
    wp.atomic_add(taken, 0, wp.float64(particles.mass[p]))


@dataclass
class HeadState(HostState):
    """The water particles made so far from the head's liquid (their offsets in a cell follow it)."""

    water_made: int = saved("foam_head_water_made", 0)


class Head:
    """The two-way head's arrays and host work, for FoamStage (head = true)."""

    def __init__(self, ctx, settings, liquid_density: float):
        shape, dev = ctx.fields.types.shape, ctx.device
        self.columns = column_launch_shape(shape, ctx.geometry.up_axis)
        cells = HeadCells()
        cells.foam = wp.zeros(shape, dtype=wp.float64, device=dev)
        cells.stack = wp.zeros(shape, dtype=wp.float64, device=dev)
        cells.surface = wp.zeros(self.columns, dtype=float, device=dev)
        cells.top = wp.zeros(self.columns, dtype=float, device=dev)
        cells.impulse = wp.zeros(self.columns, dtype=wp.vec3d, device=dev)
        cells.returned = wp.zeros(self.columns, dtype=wp.float64, device=dev)
        self.cells = cells
        self.taken = wp.zeros(1, dtype=wp.float64, device=dev)  # kg of water joined to films this step
        prm = HeadParams()
        axis, sign = ctx.geometry.up_axis, ctx.geometry.up_sign
        prm.up = wp.vec3(*(float(sign) if a == axis else 0.0 for a in range(3)))
        prm.rise_speed, prm.liquid_density = settings.rise_speed, liquid_density
        prm.burst_fraction = settings.burst_fraction if settings.collapse == "drainage" else 0.0
        prm.lifetimes = int(settings.collapse == "lifetime")
        self.params = prm
        self.water = next(i for i, m in enumerate(ctx.scene.materials.values()) if m.kind == "liquid")
        solver = ctx.scene.solver
        # The scene's own liquid particle (seeding's h^3 / ppc), as the float32 it is stored in.
        self.particle_volume = float(np.float32(ctx.grid.dx ** 3 / solver.particles_per_cell))
        self.state = HeadState()

    def advance(self, ctx, dt: float, book, vented_mass):
        """Burst, stack and move the head's foam (after g2p, before new foam is made)."""
        f, p, geo = ctx.fields, ctx.particles, ctx.geometry
        self.params.dt = dt
        parts = kernel_args.particle_arrays(p)
        ctx.launch(burst_head, p.count, [self.params, geo, parts, book, vented_mass])
        self.cells.foam.zero_()
        ctx.launch(splat_head, p.count, [geo, parts, book.liquid, self.cells])
        ctx.launch(head_columns, self.columns, [geo, f.types, f.liq_volume, self.cells])
        ctx.launch(settle_foam, p.count, [self.params, geo, f.types, kernel_args.face_field(f.vel), parts,
                                          book, self.cells])
        ctx.book_outflow()  # foam blown through an open wall

    def load(self, ctx):
        """The foam's booked reaction onto the water's faces (the force hook, before the solve)."""
        f = ctx.fields
        ctx.launch(load_water, self.columns, [ctx.geometry, kernel_args.cell_phases(f), f.liq_volume,
                                              kernel_args.face_field(f.vel),
                                              kernel_args.face_field(f.inv_rho), self.cells])

    def return_water(self, ctx):
        """Settle the columns' water with their films: where the films owe a column's water its
        particles, those near the surface join them (take_water); where the water is owed a whole
        particle, one is added just under the surface (at rest). The rest stays owed. Two host reads a
        step: the mass taken (the core's liquid ledger books it as removed) and the owed liquid."""
        self.taken.zero_()
        ctx.launch(take_water, ctx.particles.count, [ctx.geometry, kernel_args.particle_arrays(ctx.particles),
                                                     self.cells, self.taken])
        taken = float(ctx.read_host(self.taken)[0])
        if taken:
            ctx.ledger.liquid_added -= taken
        owed = np.array(ctx.read_host(self.cells.returned), np.float64)
        per = self.particle_volume
        columns = np.argwhere(owed >= per)
        if not len(columns):
            return
        surface = ctx.read_host(self.cells.surface)
        geo, dx = ctx.geometry, ctx.grid.dx
        axis, sign = geo.up_axis, geo.up_sign
        origin = np.array([geo.origin[0], geo.origin[1], geo.origin[2]], np.float64)
        floor = 0.0 if sign > 0 else -ctx.grid.domain_size[axis]  # the domain's lower face, as an elevation
        positions = []
        for col in map(tuple, columns):
            # No water below, or less than a quarter cell of it inside the domain (over an open
            # floor the surface reads the splat in the air below, and can lie under the floor): the
            # liquid stays owed.
            if surface[col] <= 0.5 * NO_SURFACE or surface[col] - 0.25 * dx <= floor:
                continue
            count = int(owed[col] // per)
            for _ in range(count):
                n = self.state.water_made
                self.state.water_made += 1
                # A low-discrepancy spread inside the column (golden ratio, plastic number).
                shifts = [((n + 0.5) * 0.6180339887498949) % 1.0, ((n + 0.5) * 0.7548776662466927) % 1.0]
                x = origin + (np.array(col, np.float64) + 0.5) * dx
                for b in (b for b in range(ctx.grid.dim) if b != axis):
                    x[b] += (shifts.pop(0) - 0.5) * 0.8 * dx
                x[axis] = sign * (surface[col] - 0.25 * dx)
                if ctx.grid.dim == 2:
                    x[2] = 0.5 * dx  # the 2D run is a slab one cell thick
                positions.append(x)
            owed[col] -= count * per
        if not positions:
            return
        self.cells.returned.assign(wp.array(owed, dtype=wp.float64, device=self.cells.returned.device))
        # Entrainment's seeds of this step sit in provisional slots past the count (entrainment.py):
        # the count must be exact before anything is appended, or the new water lands past the
        # seeds, is cut off when they settle, and the next step's seeds overwrite it (a water
        # particle booked as added turned into a sub-grid bubble). A third host read, on the
        # steps that make water in a scene with entrainment only.
        entrainment = ctx.stage("entrainment")
        if entrainment is not None and entrainment.pending_total is not None:
            entrainment.settle(ctx, int(ctx.read_host(entrainment.pending_total)[0]))
        k = len(positions)
        ctx.add_particles(np.array(positions, np.float32), np.zeros((k, 3), np.float32),
                          np.full(k, self.water, np.int32), np.full(k, per, np.float32))

    def state_arrays(self) -> dict:
        return {**self.state.arrays(), "foam_head_impulse": self.cells.impulse.numpy().copy(),
                "foam_head_returned": self.cells.returned.numpy().copy()}

    def load_state(self, arrays: dict) -> None:
        self.state.load(arrays)
        for name, array in (("foam_head_impulse", self.cells.impulse), ("foam_head_returned", self.cells.returned)):
            if name in arrays:
                array.assign(wp.array(arrays[name], dtype=array.dtype, device=array.device))

    def height(self) -> float:
        """The head's mean height over the columns with water, m (its foam volume over their area)."""
        surface, top = self.cells.surface.numpy(), self.cells.top.numpy()
        wet = surface > 0.5 * NO_SURFACE
        return float((top[wet] - surface[wet]).mean()) if wet.any() else 0.0

    def owed(self) -> float:
        """m^3 of liquid owed to the water now (negative: the films hold more than has come back)."""
        return float(self.cells.returned.numpy().astype(np.float64).sum())
