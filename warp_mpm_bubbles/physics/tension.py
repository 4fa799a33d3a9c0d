"""Surface tension, all of it (docs/design.md, "Surface tension"): runs when a liquid has
surface_tension > 0.

    force      the liquid's level set (its rest-volume fraction), smoothed (for the normal); the
               curvature from height functions of the liquid's share (div(n) where no column fits),
               averaged along the surface; the Laplace jump sigma kappa on the liquid's surface faces
    after_g2p  (gas, sharp interface, gas_films = "retract") gas films thinner than a cell
               retract into the bubble beside them: the jump's part below the grid
    dt_limit   capillary waves: dt <= sqrt((rho_l + rho_g) dx^3 / (4 pi sigma)) (Brackbill et al. 1992)
"""

import math

import warp as wp

from ..core.geometry import GridGeometry
from ..core.grid import ACTIVE, INTERFACE_SHARP, PHASE_GAS, SOLID_FREE_SLIP
from ..core.stage import Stage
from ..core.cells import (
    block_offset, block_size, cell_centre, cell_of, inside, is_liquid_cell, is_phase_cell, is_solid, unit,
)
from ..core import kernel_args
from ..core.kernel_args import CellPhases, Particles
from ..core.lines import Lines, line_end, line_first, line_kernel, make_lines, on_line
from ..core.boundary import finite
from ..core.transfer_kernels import clamp_to_domain
from .curvature import CENTRING_SHIFT, CURVATURE_AVERAGING, average_curvature, column_heights, height_fraction, surface_curvature

wp.set_module_options({"enable_backward": False})


@wp.kernel
def liquid_level_set(box: Lines, inv_cell_vol: float, liq_volume: wp.array3d(dtype=float),
                     level: wp.array3d(dtype=float)):
    """psi = 2 phi_liquid - 1 in [-1, 1]: > 0 in the liquid, < 0 in gas or air, 0 on its surface.
    (box: the cells of the launch, a line a thread, core/lines.py.)"""
    ti, tj, tk = wp.tid()
    first = line_first(box, ti, tj, tk)
    for s in range(first[box.axis], line_end(box, first)):
        c = on_line(first, box.axis, s)
        level[c[0], c[1], c[2]] = wp.clamp(2.0 * liq_volume[c[0], c[1], c[2]] * inv_cell_vol - 1.0, -1.0, 1.0)


@wp.func(inline=True)
def mirrored_level(level: wp.array3d(dtype=float), types: wp.array3d(dtype=wp.int32), x: int, y: int, z: int,
                   centre: float):
    """The level set at cell (x, y, z); a solid cell (or one beyond the arrays) mirrors `centre`, the
    value at the cell that asks: a 90 degree contact."""
    v = centre
    if inside(types, wp.vec3i(x, y, z)):
        if not is_solid(types[x, y, z]):
            v = level[x, y, z]
    return v


@wp.func
def smooth_level_set_at(dim: int, types: wp.array3d(dtype=wp.int32), level: wp.array3d(dtype=float),
                        out: wp.array3d(dtype=float), i: int, j: int, k: int):
    """One pass of the binomial filter (1 2 1)/4 per axis. Particle jitter makes psi noisy at the
    scale of a cell; its second derivatives (the curvature) would turn that noise into spurious
    capillary currents. The 3^dim block in x, y, z order, in constant loops, which Warp unrolls (a loop
    over block_offset(q) cost 6x the time); the weights sum to 4^dim. Only cells on the arrays' edge
    check for neighbours outside them."""
    value = level[i, j, k]
    if is_solid(types[i, j, k]):
        out[i, j, k] = value
        return
    edge = i == 0 or j == 0 or i == types.shape[0] - 1 or j == types.shape[1] - 1  # a neighbour is outside
    if dim == 3 and (k == 0 or k == types.shape[2] - 1):
        edge = True
    total = float(0.0)
    for a in range(-1, 2):
        for b in range(-1, 2):
            for c in range(-1, 2):
                if dim == 3 or c == 0:
                    w = float((2 - wp.abs(a)) * (2 - wp.abs(b)) * (2 - wp.abs(c)))
                    v = value
                    if edge:
                        v = mirrored_level(level, types, i + a, j + b, k + c, value)
                    else:  # inner_level written out: as a call in this unrolled loop it cost 1.5x the kernel
                        v = wp.where(types[i + a, j + b, k + c] >= SOLID_FREE_SLIP, value, level[i + a, j + b, k + c])
                    total += w * v
    weight = 64.0
    if dim == 2:
        weight = 32.0  # (the slab's block: z offset 0, weight factor 2)
    out[i, j, k] = total / weight


smooth_level_set = line_kernel(smooth_level_set_at)


@wp.func
def apply_surface_tension_at(sigma: float, axis: int, dx: float, dt: float, cells: CellPhases,
                             level: wp.array3d(dtype=float), curvature: wp.array3d(dtype=float),
                             inv_rho: wp.array3d(dtype=float), vel: wp.array3d(dtype=float), i: int, j: int, k: int):
    """The pressure jump [p] = sigma kappa across the liquid's surface (Kang, Fedkiw & Liu 2000).

    On a face between a liquid cell L and a gas or empty cell N, the projection must see
    p_N - p_L = sigma kappa at the surface. Adding dt/rho_f sigma kappa / dx to u* on that face is
    the same as putting the jump into the right-hand side and into the pressure gradient, so the
    pressure operator is untouched. kappa is interpolated to where psi crosses zero.
    """
    if inv_rho[i, j, k] == 0.0:
        return
    hi = wp.vec3i(i, j, k)
    below = hi - unit(axis)
    liquid_lo = is_liquid_cell(cells.types, cells.phase, below)
    liquid_hi = is_liquid_cell(cells.types, cells.phase, hi)
    if liquid_lo == liquid_hi:
        return
    cl = below
    cn = hi
    orient = 1.0  # the jump p_hi - p_lo equals +sigma kappa when the liquid is on the low side
    if liquid_hi:
        cl = hi
        cn = below
        orient = -1.0
    psi_l = level[cl[0], cl[1], cl[2]]  # (a liquid cell: not solid)
    psi_n = mirrored_level(level, cells.types, cn[0], cn[1], cn[2], psi_l)
    theta = float(0.5)
    if psi_l - psi_n > 1.0e-6:
        theta = wp.clamp(psi_l / (psi_l - psi_n), 0.0, 1.0)
    kappa = (1.0 - theta) * curvature[cl[0], cl[1], cl[2]] + theta * curvature[cn[0], cn[1], cn[2]]
    vel[i, j, k] = vel[i, j, k] + dt * inv_rho[i, j, k] * orient * sigma * kappa / dx


apply_surface_tension = line_kernel(apply_surface_tension_at)


@wp.func
def level_at_point(level: wp.array3d(dtype=float), x: wp.vec3, origin: wp.vec3, dx: float, dim: int):
    """The level set at point x, (bi/tri)linear between the cell centres around it."""
    q = (x - origin) / dx - wp.vec3(0.5, 0.5, 0.5)
    b = wp.vec3i(int(wp.floor(q[0])), int(wp.floor(q[1])), int(wp.floor(q[2])))
    f = q - wp.vec3(float(b[0]), float(b[1]), float(b[2]))
    nk = 2
    if dim == 2:  # the slab's one layer
        nk = 1
        b[2] = 0
    total = float(0.0)
    for i in range(2):
        for j in range(2):
            for k in range(nk):
                c = wp.vec3i(wp.clamp(b[0] + i, 0, level.shape[0] - 1), wp.clamp(b[1] + j, 0, level.shape[1] - 1),
                             wp.clamp(b[2] + k, 0, level.shape[2] - 1))
                w = wp.where(i == 1, f[0], 1.0 - f[0]) * wp.where(j == 1, f[1], 1.0 - f[1])
                if dim == 3:
                    w = w * wp.where(k == 1, f[2], 1.0 - f[2])
                total += w * level[c[0], c[1], c[2]]
    return total


@wp.struct
class Films:
    """Where film gas retracts to (film_target): the cells' types and phases, the gas volume per cell,
    the smoothed liquid level set, and the film's capillary speed, m/s."""

    cells: CellPhases
    gas_volume: wp.array3d(dtype=float)
    level: wp.array3d(dtype=float)
    capillary_speed: float


@wp.func
def film_target(dt: float, geo: GridGeometry, films: Films, xp: wp.vec3):
    """Where a gas particle at xp retracts to this step (xp itself unless it is in a film): a gas
    particle in a liquid cell with gas cells in its 3^d neighbourhood (a bubble's skirt or rim thinner
    than a cell) moves towards them (their gas-volume-weighted centre) at `capillary_speed`, the
    Taylor-Culick speed of a film one cell thick, sqrt(2 sigma / (rho_l dx)) (thinner films retract
    faster), at most a quarter cell a step. Only gas on the liquid's side of the interface, where the
    smoothed liquid level set the curvature reads is positive, is a film: gas on the bubble's side in
    a cell the interface crosses is the resolved bubble (retracted, it piled into the bubble and left
    the interface's cells under-filled, with holes)."""
    types = films.cells.types
    phase_cells = films.cells.phase
    c = cell_of(xp, geo.origin, geo.dx)
    if not is_liquid_cell(types, phase_cells, c):
        return xp
    if level_at_point(films.level, xp, geo.origin, geo.dx, geo.dim) <= 0.0:
        return xp
    pull = wp.vec3(0.0)
    for q in range(block_size(geo.dim)):
        n = c + block_offset(q, geo.dim)
        if is_phase_cell(types, phase_cells, n, PHASE_GAS):
            d = cell_centre(n, geo.origin, geo.dx) - xp
            if geo.dim == 2:
                d[2] = 0.0  # the slab's centre plane, not the particle's place in its thickness
            pull += films.gas_volume[n[0], n[1], n[2]] * d
    length = wp.length(pull)
    if length == 0.0:
        return xp
    step = wp.min(films.capillary_speed * dt, 0.25 * geo.dx)
    return clamp_to_domain(xp + (step / length) * pull, geo.domain_hi, geo.dx, geo.dim)


@wp.func
def other_cell(x: wp.vec3, c: wp.vec3i, geo: GridGeometry):
    """Whether position x lies outside cell c."""
    d = cell_of(x, geo.origin, geo.dx)
    return d[0] != c[0] or d[1] != c[1] or d[2] != c[2]


@wp.kernel
def count_grid_particles(geo: GridGeometry, particles: Particles, count: wp.array3d(dtype=wp.int32)):
    """Liquid and gas particles per cell where they are now (after g2p moved them)."""
    p = wp.tid()
    if particles.active[p] != ACTIVE or particles.phase[p] > PHASE_GAS or not finite(particles.x[p]):
        return
    c = cell_of(clamp_to_domain(particles.x[p], geo.domain_hi, geo.dx, geo.dim), geo.origin, geo.dx)
    wp.atomic_add(count, c[0], c[1], c[2], 1)


@wp.kernel
def film_departures(dt: float, geo: GridGeometry, films: Films, particles: Particles,
                    leaving: wp.array3d(dtype=wp.int32), first: wp.array3d(dtype=wp.int32)):
    """Per cell, how many film particles would retract out of it, and the lowest index among them."""
    p = wp.tid()
    if particles.active[p] == 0 or particles.phase[p] != PHASE_GAS or not finite(particles.x[p]):
        return
    xp = clamp_to_domain(particles.x[p], geo.domain_hi, geo.dx, geo.dim)  # its cell is inside the arrays
    c = cell_of(xp, geo.origin, geo.dx)
    if other_cell(film_target(dt, geo, films, xp), c, geo):
        wp.atomic_add(leaving, c[0], c[1], c[2], 1)
        wp.atomic_min(first, c[0], c[1], c[2], p)


@wp.kernel
def retract_gas_films(start: int, dt: float, geo: GridGeometry, films: Films, count: wp.array3d(dtype=wp.int32),
                      leaving: wp.array3d(dtype=wp.int32), first: wp.array3d(dtype=wp.int32), particles: Particles):
    """Surface tension below the grid: film gas retracts into its bubble (film_target).

    The Laplace jump acts only on faces between liquid and gas cells, so a film under a cell's size
    feels no tension and rides the liquid away. Only the position moves: mass, velocity and J are
    kept. The retraction keeps the partition of space between the phases: it never empties a cell.
    If every particle of a cell would leave it, the lowest-indexed one stays, moved only as far as
    its own cell allows, so the space the film held is given up only as liquid comes in (a gas
    particle leaving a cell alone left a particle-free hole that read as free surface). Particles
    start + tid (Simulation.launch_particles: each writes only its own position).
    """
    p = wp.tid() + start
    if particles.active[p] == 0 or particles.phase[p] != PHASE_GAS or not finite(particles.x[p]):
        return
    xp = clamp_to_domain(particles.x[p], geo.domain_hi, geo.dx, geo.dim)
    c = cell_of(xp, geo.origin, geo.dx)
    target = film_target(dt, geo, films, xp)
    if other_cell(target, c, geo) and leaving[c[0], c[1], c[2]] >= count[c[0], c[1], c[2]]:
        if first[c[0], c[1], c[2]] == p:  # the cell's last particle: stays, at the side facing its bubble
            lo = cell_centre(c, geo.origin, geo.dx) - wp.vec3(0.49 * geo.dx)
            hi = cell_centre(c, geo.origin, geo.dx) + wp.vec3(0.49 * geo.dx)
            target = wp.vec3(wp.clamp(target[0], lo[0], hi[0]), wp.clamp(target[1], lo[1], hi[1]),
                             wp.clamp(target[2], lo[2], hi[2]))
    particles.x[p] = target


LEVEL_SET_SMOOTHING = 2  # binomial passes of psi before its normal and div(n) (tests/test_tension.py measures it)


class TensionStage(Stage):
    name = "surface_tension"
    timer = "tension"
    limit = "capillary"
    grid_box = True  # the force covers ctx.region: outside it psi = -1, kappa = 0 and no face is active
    graph_safe = True

    def __init__(self, ctx, settings=None):
        super().__init__(ctx, settings)
        g, materials = ctx.grid, ctx.scene.materials.values()
        liquids = [m for m in materials if m.kind == "liquid"]
        self.sigma = max(m.surface_tension for m in liquids)  # N/m; the stage runs only if > 0
        self.rho_liquid = max(m.density for m in liquids)
        self.rho_gas = max((m.density for m in materials if m.is_gas), default=0.0)
        self.level, self.level_tmp = ctx.fields.cells(), ctx.fields.cells()  # psi and its smoothing's spare
        self.fraction = ctx.fields.cells()  # height_fraction's psi, which the columns sum
        self.heights = ctx.fields.cells(wp.vec3)  # column_heights: per cell, one column per axis
        self.from_heights = ctx.fields.cells()  # 1 where kappa came from heights, 0 where from div(n)
        self.kappa, self.kappa_tmp = ctx.fields.cells(), ctx.fields.cells()  # kappa and its averaging's spare
        self.curvature = self.kappa  # force() names the buffer its averaging ends in
        self.smoothed = self.level  # force() names the buffer its smoothing ends in
        # Gas films thinner than a cell feel no Laplace jump (it acts on cell faces); with the sharp
        # interface they retract into their bubble, at the Taylor-Culick speed of a one-cell film.
        self.retract_films = (ctx.has_gas and ctx.interface == INTERFACE_SHARP
                              and ctx.scene.solver.gas_films == "retract")
        self.film_speed = math.sqrt(2.0 * self.sigma / (self.rho_liquid * g.dx)) if self.retract_films else 0.0
        if self.retract_films:  # particles per cell now, film particles leaving each cell, the first of them
            self.count, self.leaving, self.first = (ctx.fields.cells(wp.int32) for _ in range(3))
        # A cell's last film particle stays (no hole) only with incompressible gas: with air, whose
        # gas expands into a gap by itself, keeping films back broke a rising bubble up (the largest
        # kept 31% of the gas after five diameters instead of 67%; tests/test_gas.py).
        self.hold_films = self.retract_films and not any(
            m.is_gas and m.eos != "incompressible" for m in ctx.scene.materials.values())

    def hooks(self) -> set[str]:
        hooks = super().hooks()
        if not self.retract_films:
            hooks.discard("after_g2p")
        return hooks

    def dt_limit(self, ctx) -> float:
        # Capillary waves (Brackbill et al. 1992): dt <= sqrt((rho_l + rho_g) dx^3 / (4 pi sigma)).
        return math.sqrt((self.rho_liquid + self.rho_gas) * ctx.grid.dx**3 / (4.0 * math.pi * self.sigma))

    def force(self, ctx, dt: float):
        g, f, r = ctx.grid, ctx.fields, ctx.region
        level, smoothed = self.level, self.level_tmp
        cells = r.cell_lines
        ctx.launch_lines(liquid_level_set, cells, [1.0 / g.dx**3, f.liq_volume, level])
        for _ in range(LEVEL_SET_SMOOTHING):
            ctx.launch_lines(smooth_level_set, cells, [g.dim, f.types, level, smoothed])
            level, smoothed = smoothed, level
        gas_volume = f.gas_volume if ctx.has_gas else f.liq_volume  # (not read without gas)
        ctx.launch_lines(height_fraction, cells, [1.0 / g.dx**3, g.dim, int(ctx.has_gas), f.liq_volume, gas_volume,
                                                  f.types, self.fraction])
        lo, hi = r.box
        # The box grown: the curvature reads the columns beside its best-centred one, which is up to
        # CENTRING_SHIFT cells off along the axis.
        start = [max(a - CENTRING_SHIFT, 0) for a in lo]
        end = [min(b + CENTRING_SHIFT, n) for b, n in zip(hi, g.cells)]
        ctx.launch_lines(column_heights, make_lines(start, end, g.dim, ctx.device),
                         [g.dim, r.lo, wp.vec3i(*hi), self.fraction, f.types, self.heights])
        kappa, spare = self.kappa, self.kappa_tmp
        ctx.launch_lines(surface_curvature, cells, [g.dx, g.dim, f.types, level, self.heights, kappa,
                                                    self.from_heights])
        for _ in range(CURVATURE_AVERAGING):
            ctx.launch_lines(average_curvature, cells, [g.dim, kappa, self.from_heights, spare])
            kappa, spare = spare, kappa
        self.curvature = kappa
        self.smoothed = level  # the films' side of the interface (after_g2p)
        for a in g.axes:
            ctx.launch_lines(apply_surface_tension, r.face_lines[a],
                             [self.sigma, a, g.dx, dt, kernel_args.cell_phases(f), level, kappa, f.inv_rho[a], f.vel[a]])

    def after_g2p(self, ctx, dt: float):
        f, p = ctx.fields, ctx.particles
        self.first.fill_(2**31 - 1)  # no particle is a cell's first: without holding, none is held back
        films = Films()
        films.cells, films.gas_volume = kernel_args.cell_phases(f), f.gas_volume
        films.level, films.capillary_speed = self.smoothed, self.film_speed
        particles = kernel_args.particle_arrays(p)
        if self.hold_films:  # the particles per cell, and how many would leave each: the last one stays
            self.count.zero_()
            self.leaving.zero_()
            ctx.launch(count_grid_particles, p.count, [ctx.geometry, particles, self.count])
            ctx.launch(film_departures, p.count, [dt, ctx.geometry, films, particles, self.leaving, self.first])
        ctx.launch_particles(retract_gas_films, [dt, ctx.geometry, films, self.count, self.leaving, self.first,
                                                 particles])
