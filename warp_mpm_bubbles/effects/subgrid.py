"""Sub-grid bubbles (entrainment.py seeds them where splashes trap air).

Sub-grid bubbles are gas particles of phase PHASE_SUBGRID: the core transfers skip them, and this
stage moves them by buoyancy and drag relative to the liquid's interpolated velocity:

    (rho_g + C_m rho_l) V dv/dt = (rho_l - rho_g) V (-g) + k(|w|) (u_l - v),   w = v - u_l
    k(s) = 1/2 rho_l C_D(Re) pi r^2 s,  C_D = 24/Re (1 + 0.15 Re^0.687) for Re < 1000, else 0.44

(Schiller & Naumann 1933, a rigid sphere: small bubbles in tap water behave like one because
surfactants immobilise their surface; C_m = 1/2, the added mass of a sphere; mu is the liquid's
viscosity, 1e-3 Pa s when the scene gives none; r from the bubble's volume V = V0 J, with J from
the cell's pressure by the particle's gas law, so bubbles expand as they rise.) The drag is fully
implicit: w_new solves w (m + dt k(|w|)) = m (v - u_l) + dt F_b, a scalar root along the right-hand
side (the left side grows monotonically with |w|), found by bisection: stable at any dt, and at rest
it is exactly the terminal balance F_b = k(U) U. Two-way: the momentum dt k w that the drag took
from the bubble goes to the liquid's face velocities in the next step's grid phase, right after
u* = p/m + dt g, spread over the faces in proportion to the mass each holds (momentum-exact, lagged
by one step). The fluid's side is thus explicit, so dt k is capped at the fluid mass the bubble's
stencil holds (the drag law, its solve and the cap: effects/subgrid_drag.py).

A bubble whose cell is gas (or open air above the water) joins the resolved gas in place; the vent
or foam stage then takes it if it is in open air.

Conversions, every `convert_every` steps (CI scenes convert a few times a frame): the device
selects the candidates (sub-grid bubbles, resolved gas) and packs their rows; the host reads only
those (two reads, docs/host_syncs.md), groups them, and the device retires and pushes:
- gather: per cell, the sub-grid volume of its 3^dim neighbourhood; neighbourhoods holding at least
  the threshold volume (4/3 pi radius^3), largest first, turn their bubbles into resolved gas
  particles filling the same volume (a ball, or in 2D a disk through the one-cell slab) at
  their centroid; the liquid particles there are pushed out by the volume-preserving radial map
  r' = (r^d + R^d)^(1/d) (within 4 R), so the new gas does not sit on top of water.
- shrink: resolved gas particles are grouped into clusters of cells connected through faces,
  edges or corners (26-/8-connectivity); a cluster under shrink_ratio x the threshold volume
  becomes one sub-grid bubble at its centroid (the hysteresis keeps a bubble from flipping back).
  The small void it leaves is refilled by the solver (holes are fluid, see classify_cells).
Mass is conserved exactly: the merged masses are summed in float64, and the float32 rounding of
the new particles' masses (below 2^-24 of the converted mass) is booked in
its state (checkpointed as "gas_mass_rounding"), which Simulation.gas_budget adds to its total.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import warp as wp

from ..core.cells import cell_of
from ..core.gas_law import GAS_ADIABATIC, GAS_ISOTHERMAL
from ..core.geometry import GridGeometry
from ..core import kernel_args
from ..core.kernel_args import CellPhases, FaceField, Particles
from ..core.grid import ACTIVE, EMPTY, FLUID, PHASE_GAS, PHASE_LIQUID, PHASE_SUBGRID, connected_labels, sphere_radius
from ..core.host_state import HostState, saved
from ..core.stage import Stage
from ..physics.gas import column_of, height_along
from ..scene.effects import SubgridBubbles
from .subgrid_drag import (ADDED_MASS, PI, add_face_impulse, drag_impulse_per_speed, face_fluid_mass,
                           implicit_relative_speed)
from ..core.boundary import clamp_to_domain, open_wall_exit, wall_stopped
from ..core.transfer_kernels import (
    U_OFFSET, V_OFFSET, W_OFFSET, grid_coord, interpolate_velocity,
)

wp.set_module_options({"enable_backward": False})

WATER_VISCOSITY = 1.0e-3  # Pa s, when the liquid sets none (its inviscid grid still drags bubbles)
PUSH_REACH = 4.0  # gather: liquid within this many bubble radii makes room (displacement ~(R/r)^d)


@wp.func
def volume_ratio(law: int, gamma: float, p_gauge: float, p_atm: float):
    """J = V/V0 of gas at rest volume V0 at p_atm, now at p_atm + p_gauge (tension floored)."""
    p_abs = wp.max(p_atm + p_gauge, 0.1 * p_atm)
    if law == GAS_ISOTHERMAL:
        return p_atm / p_abs
    if law == GAS_ADIABATIC:
        return wp.pow(p_atm / p_abs, 1.0 / gamma)
    return 1.0


@wp.kernel
def deposit_drag_reaction(geo: GridGeometry, particles: Particles, impulse: wp.array(dtype=wp.vec3),
                          face_mass: FaceField, vel: FaceField):
    """The liquid gets the momentum that the drag took from each bubble in its last update."""
    p = wp.tid()
    if particles.active[p] == 0 or particles.phase[p] != PHASE_SUBGRID:
        return
    J = impulse[p]
    if wp.length_sq(J) == 0.0:
        return
    xp = clamp_to_domain(particles.x[p], geo.domain_hi, geo.dx, geo.dim)
    inv_dx = 1.0 / geo.dx
    add_face_impulse(vel.u, face_mass.u, grid_coord(xp, geo.origin, inv_dx, U_OFFSET), geo.dim, J[0])
    add_face_impulse(vel.v, face_mass.v, grid_coord(xp, geo.origin, inv_dx, V_OFFSET), geo.dim, J[1])
    if geo.dim == 3:
        add_face_impulse(vel.w, face_mass.w, grid_coord(xp, geo.origin, inv_dx, W_OFFSET), geo.dim, J[2])


@wp.func
def joins_resolved_gas(types: wp.array3d(dtype=wp.int32), phase_cells: wp.array3d(dtype=wp.int32),
                       ceiling: wp.array3d(dtype=wp.int32), c: wp.vec3i, up_axis: int, up_sign: int):
    """A bubble in cell c leaves the sub-grid for the resolved gas: c is a gas cell, or an empty cell
    above the liquid's ceiling (without gravity any empty cell is air; an empty hole inside the
    water is still water around the bubble)."""
    t = types[c[0], c[1], c[2]]
    if t == FLUID:
        return phase_cells[c[0], c[1], c[2]] == PHASE_GAS
    if t != EMPTY:
        return False
    if up_axis < 0:
        return True
    col = column_of(c, up_axis)
    return height_along(c, up_axis, up_sign, types.shape[up_axis]) > ceiling[col[0], col[1], col[2]]


@wp.struct
class Surroundings:
    """What a sub-grid bubble rises through: the liquid's density and viscosity, the ambient pressure."""

    rho_l: float  # kg/m^3
    mu: float  # Pa s
    p_atm: float  # Pa


@wp.kernel
def advance_subgrid(
    dt: float,
    geo: GridGeometry,
    around: Surroundings,
    vel: FaceField,
    face_mass: FaceField,
    cells: CellPhases,
    ceiling: wp.array3d(dtype=wp.int32),
    pressure: wp.array3d(dtype=float),
    particles: Particles,
    impulse: wp.array(dtype=wp.vec3),
    max_speed: wp.array(dtype=float),
):
    """Buoyancy and implicit drag for every sub-grid bubble in the liquid; the others join the
    resolved gas (a gas cell, or open air: the vent or foam stage that follows takes those). The
    drag's dt k is capped at the fluid mass the bubble's stencil holds (face_fluid_mass; the module
    docstring says why: the fluid takes the reaction explicitly)."""
    p = wp.tid()
    if particles.active[p] == 0 or particles.phase[p] != PHASE_SUBGRID:
        return
    xp = clamp_to_domain(particles.x[p], geo.domain_hi, geo.dx, geo.dim)
    c = cell_of(xp, geo.origin, geo.dx)
    t = cells.types[c[0], c[1], c[2]]
    if joins_resolved_gas(cells.types, cells.phase, ceiling, c, geo.up_axis, geo.up_sign):
        particles.phase[p] = PHASE_GAS
        impulse[p] = wp.vec3(0.0)
        return
    p_gauge = float(0.0)
    if t == FLUID:
        p_gauge = pressure[c[0], c[1], c[2]]
    Jp = volume_ratio(particles.gas_law[p], particles.gas_gamma[p], p_gauge, around.p_atm)
    particles.J[p] = Jp
    vol = particles.vol0[p] * Jp
    r = wp.pow(0.75 * vol / PI, 1.0 / 3.0)
    rho_g = particles.mass[p] / vol
    m_eff = (rho_g + ADDED_MASS * around.rho_l) * vol
    u_l = interpolate_velocity(vel, xp, geo.origin, geo.dx, geo.dim)
    fluid_mass = face_fluid_mass(face_mass, xp, geo.origin, geo.dx, geo.dim)
    b = m_eff * (particles.v[p] - u_l) - dt * (around.rho_l - rho_g) * vol * geo.gravity
    b_len = wp.length(b)
    w = wp.vec3(0.0)
    drag = float(0.0)  # dt k, capped
    if b_len > 0.0:
        s = implicit_relative_speed(b_len, m_eff, dt, r, around.rho_l, around.mu, fluid_mass)
        w = b * (s / b_len)
        drag = drag_impulse_per_speed(s, dt, r, around.rho_l, around.mu, fluid_mass)
    vp = u_l + w
    impulse[p] = drag * w  # what the drag took from the bubble goes to the fluid next step
    moved = xp + dt * vp
    # LEAVING through an open wall: book_outflow retires it
    particles.active[p] = open_wall_exit(moved, geo, particles.phase[p])
    xn = clamp_to_domain(moved, geo.domain_hi, geo.dx, geo.dim)
    vp = wall_stopped(moved, xn, vp, geo.dim)
    particles.x[p] = xn
    particles.v[p] = vp
    wp.atomic_max(max_speed, 0, wp.length(vp))


# ------------------------------------------------------------- conversions: the device's part
CANDIDATE_COLUMNS = 13  # index, phase, x (3), v (3), mass, vol0, J, material, in a fluid cell


@wp.func
def host_cell(x: wp.vec3, origin: wp.vec3d, dx: wp.float64, cells: wp.vec3i, dim: int):
    """The cell the host's _cells gives x (float64, clamped to the grid; k = 0 in 2D)."""
    c = wp.vec3i(0, 0, 0)
    for a in range(dim):
        q = wp.floor((wp.float64(x[a]) - origin[a]) / dx)
        c[a] = wp.clamp(int(q), 0, cells[a] - 1)
    return c


@wp.kernel
def flag_candidates(phase: wp.array(dtype=wp.int32), active: wp.array(dtype=wp.int32),
                    flag: wp.array(dtype=wp.int32)):
    """1 for the particles a conversion may take: active sub-grid bubbles and resolved gas."""
    p = wp.tid()
    flag[p] = 0
    if active[p] == 1 and (phase[p] == PHASE_SUBGRID or phase[p] == PHASE_GAS):
        flag[p] = 1


@wp.kernel
def candidate_count(flag: wp.array(dtype=wp.int32), slot: wp.array(dtype=wp.int32), last: int,
                    counts: wp.array(dtype=wp.int32)):
    counts[0] = slot[last] + flag[last]


@wp.kernel
def pack_candidates(
    origin: wp.vec3d, dx: wp.float64, cells: wp.vec3i, dim: int, flag: wp.array(dtype=wp.int32),
    slot: wp.array(dtype=wp.int32), types: wp.array3d(dtype=wp.int32), particles: Particles,
    rows: wp.array2d(dtype=wp.float64),
):
    """The candidates' rows, in particle order (the scan's): all the host reads of them."""
    p = wp.tid()
    if flag[p] == 0:
        return
    r = slot[p]
    c = host_cell(particles.x[p], origin, dx, cells, dim)
    rows[r, 0] = wp.float64(p)
    rows[r, 1] = wp.float64(particles.phase[p])
    for a in range(3):
        rows[r, 2 + a] = wp.float64(particles.x[p][a])
        rows[r, 5 + a] = wp.float64(particles.v[p][a])
    rows[r, 8] = wp.float64(particles.mass[p])
    rows[r, 9] = wp.float64(particles.vol0[p])
    rows[r, 10] = wp.float64(particles.J[p])
    rows[r, 11] = wp.float64(particles.material[p])
    rows[r, 12] = wp.float64(wp.where(types[c[0], c[1], c[2]] == FLUID, 1, 0))


@wp.kernel
def retire(indices: wp.array(dtype=wp.int32), active: wp.array(dtype=wp.int32)):
    active[indices[wp.tid()]] = 0


@wp.func
def pushed_from(xd: wp.vec3d, centre: wp.vec3d, reach: wp.float64, radius_pow: wp.float64, dim: int):
    """(where xd goes, 1) when a bubble of radius r at `centre` pushes it aside, else (xd, 0): a point
    within `reach` moves out along its ray so the area (2D, radius_pow = r^2) or volume (3D, r^3)
    inside its new distance is the old one's plus the bubble's, so the pushed fluid keeps its volume."""
    d = xd - centre
    if dim == 2:
        d[2] = wp.float64(0.0)
    r = wp.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    out = xd
    hit = int(0)
    if r < reach and r > wp.float64(0.0):
        scale = wp.float64(0.0)
        if dim == 2:
            scale = wp.sqrt(r * r + radius_pow) / r
        else:
            scale = wp.pow(wp.pow(r, wp.float64(3.0)) + radius_pow, wp.float64(1.0) / wp.float64(3.0)) / r
        for a in range(dim):
            out[a] = centre[a] + d[a] * scale
        hit = 1
    return out, hit


@wp.kernel
def push_liquid(
    centres: wp.array(dtype=wp.vec3d), radius_pow: wp.array(dtype=wp.float64),
    reach: wp.array(dtype=wp.float64), n: int, dim: int, lo: wp.float64, hi: wp.vec3d,
    phase: wp.array(dtype=wp.int32), active: wp.array(dtype=wp.int32), x: wp.array(dtype=wp.vec3),
):
    """The liquid makes room for each new bubble in turn (from where the previous push left it):
    r' = (r^d + R^d)^(1/d) within `reach`, in float64, as the host did."""
    p = wp.tid()
    if active[p] != ACTIVE or phase[p] != PHASE_LIQUID:
        return
    xd = wp.vec3d(wp.float64(x[p][0]), wp.float64(x[p][1]), wp.float64(x[p][2]))
    moved = int(0)
    for b in range(n):
        pushed = pushed_from(xd, centres[b], reach[b], radius_pow[b], dim)
        if pushed[1] != 0:
            xd = pushed[0]
            for a in range(3):
                xd[a] = wp.clamp(xd[a], lo, hi[a])
            moved = 1
    if moved == 1:
        x[p] = wp.vec3(float(xd[0]), float(xd[1]), float(xd[2]))


# ------------------------------------------------------------------------------------- host side
def add_bubbles(ctx, positions, radii, velocities, material_index: int, gauge_pressure=None) -> slice:
    """Append sub-grid bubbles (numpy: positions (n, 3) or (n, dim), radii (n,) current, m;
    velocities like positions) of the gas material `material_index`; returns their index range.
    gauge_pressure (n,) compresses them as in Simulation.add_particles (default: at ambient)."""
    radii = np.asarray(radii, np.float64)
    n = len(radii)
    pos, vel = _as_vec3(ctx, positions, n), _as_vec3(ctx, velocities, n, fill=0.0)
    material = np.full(n, int(material_index), np.int32)
    sl = ctx.add_particles(pos, vel, material, 4.0 / 3.0 * math.pi * radii**3, gauge_pressure)
    if n:
        ctx.particles.phase[sl].fill_(PHASE_SUBGRID)
        ctx.particles.subgrid_impulse[sl].zero_()
    return sl


def _as_vec3(ctx, a, n, fill=None):
    a = np.asarray(a, np.float32).reshape(n, -1)
    if a.shape[1] == 3:
        return a
    out = np.full((n, 3), 0.5 * ctx.grid.dx if fill is None else fill, np.float32)  # 2D: mid-slab
    out[:, : a.shape[1]] = a
    return out


def _neighbourhood_sum(field: np.ndarray, dim: int) -> np.ndarray:
    """Sum over each cell's 3^dim block (zero outside the array)."""
    padded = np.pad(field, [(1, 1)] * dim + [(0, 0)] * (field.ndim - dim))
    out = np.zeros_like(field)
    for off in np.ndindex(*(3,) * dim):
        out += padded[tuple(slice(o, o + n) for o, n in zip(off, field.shape[:dim]))]
    return out


def _ball_lattice(n: int, spacing: float, dim: int) -> np.ndarray:
    """The n points of a cubic lattice (spacing, centred on the origin) nearest the origin: a ball
    (disk in 2D) of n particle volumes. Stable sort: the same points every time."""
    reach = int(math.ceil(n ** (1.0 / dim))) + 1  # a cube of side 2 reach holds a ball of n points
    axes = [np.arange(-reach, reach + 1)] * dim
    pts = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, dim).astype(np.float64)
    order = np.argsort((pts**2).sum(axis=1), kind="stable")
    return pts[order[:n]] * spacing


@dataclass
class ConversionRounding(HostState):
    gas_mass: float = saved("gas_mass_rounding", 0.0)  # kg, see the module docstring


class SubgridBubbleStage(Stage):
    """[effects.subgrid_bubbles]: the drag reaction on u* (on_momentum), bubbles moved and converted
    after g2p. Other stages add bubbles through `add_bubbles` (entrainment, emitters)."""

    name = "subgrid_bubbles"
    Settings = SubgridBubbles
    graph_safe = True
    gas_held = ("subgrid", "in sub-grid bubbles")

    def output_radii(self, particles: dict):
        """Sub-grid bubbles are real: written with the radius of their own volume."""
        bubbles = particles["phase"] == PHASE_SUBGRID
        return bubbles, sphere_radius(particles["volume"][bubbles])

    def __init__(self, ctx, settings):
        super().__init__(ctx, settings)
        materials = list(ctx.scene.materials.values())
        liquids = [m for m in materials if m.kind == "liquid"]
        liquid = max(liquids, key=lambda m: m.density) if liquids else None
        self.rho_l = liquid.density if liquid else 1000.0
        self.mu = liquid.viscosity if liquid is not None and liquid.viscosity > 0.0 else WATER_VISCOSITY
        self.gas_material = next(i for i, m in enumerate(materials) if m.is_gas)  # for entrained bubbles
        self.threshold_volume = 4.0 / 3.0 * math.pi * settings.radius**3
        ctx.particles.add_field("subgrid_impulse", wp.vec3)
        self.state = ConversionRounding()
        self.conversions = {"gathered": 0, "shrunk": 0}  # events since start (not checkpointed)
        self._flag = self._slot = None  # conversions' scratch: candidate flags and their scan
        self._counts = wp.zeros(2, dtype=wp.int32, device=ctx.device)  # candidates, entrainment's pending seeds

    def add_bubbles(self, ctx, positions, radii, velocities, material_index: int, gauge_pressure=None) -> slice:
        return add_bubbles(ctx, positions, radii, velocities, material_index, gauge_pressure)

    def on_momentum(self, ctx, dt: float):
        f, p = ctx.fields, ctx.particles
        ctx.launch(deposit_drag_reaction, p.count, [ctx.geometry, kernel_args.particle_arrays(p), p.subgrid_impulse,
                                                    kernel_args.face_field(f.face_mass), kernel_args.face_field(f.vel)])

    def after_g2p(self, ctx, dt: float):
        f, p = ctx.fields, ctx.particles
        around = Surroundings()
        around.rho_l, around.mu, around.p_atm = self.rho_l, self.mu, ctx.scene.domain.ambient_pressure
        ctx.launch(advance_subgrid, p.count,
                   [dt, ctx.geometry, around, kernel_args.face_field(f.vel), kernel_args.face_field(f.face_mass),
                    kernel_args.cell_phases(f), f.ceiling, f.pressure, kernel_args.particle_arrays(p), p.subgrid_impulse,
                    f.max_speed])
        ctx.book_outflow()  # bubbles carried through an open wall
        if (ctx.stats.steps + 1) % self.settings.convert_every == 0:
            self.convert(ctx)

    # ------------------------------------------------------------------ conversions (host)
    def convert(self, ctx):
        """Both conversions from one snapshot: gathered sub-grid bubbles become resolved gas,
        small resolved clusters become sub-grid bubbles (see the module docstring). The device
        selects the candidates (sub-grid bubbles and resolved gas, in particle order); the host
        reads their count (with entrainment's pending one: a single read) and then their rows,
        never the full particle arrays, and writes back only what changes."""
        p = ctx.particles
        counts = self._candidates(ctx)
        entrainment = ctx.stage("entrainment")
        if entrainment is not None and entrainment.pending_total is not None:
            wp.copy(counts, entrainment.pending_total, dest_offset=1, count=1)
        n_candidates, entrained = (int(c) for c in ctx.read_host(counts))
        if entrainment is not None and entrainment.pending_total is not None:
            entrainment.settle(ctx, entrained)  # the count is exact before anything is appended
        if n_candidates == 0:
            return
        g = ctx.grid
        rows = wp.zeros((n_candidates, CANDIDATE_COLUMNS), dtype=wp.float64, device=ctx.device)
        ctx.launch(pack_candidates, self._n,
                   [wp.vec3d(*g.origin), wp.float64(g.dx), wp.vec3i(*g.cells), g.dim, self._flag, self._slot,
                    ctx.fields.types, kernel_args.particle_arrays(p), rows])
        rows = ctx.read_host(rows)
        index, phase = rows[:, 0].astype(np.int64), rows[:, 1].astype(np.int32)
        snap = {"x": rows[:, 2:5], "v": rows[:, 5:8], "mass": rows[:, 8], "vol0": rows[:, 9], "J": rows[:, 10],
                "material": rows[:, 11].astype(np.int32), "in_fluid": rows[:, 12] == 1.0}
        groups_up = self._gathered(ctx, snap, np.flatnonzero(phase == PHASE_SUBGRID))
        groups_down = self._small_clusters(ctx, snap, np.flatnonzero(phase == PHASE_GAS))
        if not groups_up and not groups_down:
            return
        retired = index[np.concatenate(groups_up + groups_down)].astype(np.int32)
        ctx.launch(retire, len(retired), [wp.array(retired, dtype=wp.int32, device=ctx.device), p.active])
        # The liquid makes room on the device, each new bubble from where the previous one left it.
        pushes = [self._to_resolved(ctx, snap, members) for members in groups_up]
        if pushes:
            centres, radius_pow, reach = (np.array(col, np.float64) for col in zip(*pushes))
            size = np.asarray(g.domain_size, np.float64)
            dev = lambda a, t: wp.array(a, dtype=t, device=ctx.device)  # noqa: E731
            ctx.launch(push_liquid, self._n,
                       [dev(centres, wp.vec3d), dev(radius_pow, wp.float64), dev(reach, wp.float64), len(pushes), g.dim,
                        wp.float64(1e-4 * g.dx), wp.vec3d(*(size - 1e-4 * g.dx)), p.phase, p.active, p.x])
        for members in groups_down:
            self._to_subgrid(ctx, snap, members)
        self.conversions["gathered"] += len(groups_up)
        self.conversions["shrunk"] += len(groups_down)

    def _candidates(self, ctx):
        """Flag and scan the candidates on the device; returns the (device) counts array."""
        n = self._n = ctx.particles.count
        if self._flag is None or self._flag.shape[0] < n:  # scratch grows like the particle arrays
            self._flag = wp.zeros(max(n, 2 * (0 if self._flag is None else self._flag.shape[0])), dtype=wp.int32,
                                  device=ctx.device)
            self._slot = wp.zeros_like(self._flag)
        self._counts.zero_()
        if n:
            p = ctx.particles
            ctx.launch(flag_candidates, n, [p.phase, p.active, self._flag])
            wp.utils.array_scan(self._flag[:n], self._slot[:n], inclusive=False)
            ctx.launch(candidate_count, 1, [self._flag, self._slot, n - 1, self._counts])
        return self._counts

    def _cells(self, ctx, x):
        g = ctx.grid
        c = np.floor((x - np.asarray(g.origin)) / g.dx).astype(np.int64)
        return np.clip(c, 0, np.array(g.cells) - 1)[:, : g.dim]

    def _gathered(self, ctx, snap, sub) -> list[np.ndarray]:
        """Groups of sub-grid bubbles (one material each) whose 3^dim cell block holds >= the threshold."""
        if len(sub) == 0:
            return []
        g = ctx.grid
        groups = []
        volume = snap["vol0"][sub].astype(np.float64) * snap["J"][sub]
        cells = self._cells(ctx, snap["x"][sub])
        for mat in np.unique(snap["material"][sub]):
            mine = snap["material"][sub] == mat
            field = np.zeros(g.cells[: g.dim])
            np.add.at(field, tuple(cells[mine].T), volume[mine])
            block = _neighbourhood_sum(field, g.dim)
            centres = np.argwhere(block >= self.threshold_volume)
            if len(centres) == 0:
                continue
            # Largest first; ties by cell index (argwhere order): deterministic.
            centres = centres[np.argsort(-block[tuple(centres.T)], kind="stable")]
            free = mine.copy()
            for c in centres:
                members = free & np.all(np.abs(cells - c) <= 1, axis=1)
                if volume[members].sum() >= self.threshold_volume:
                    groups.append(sub[members])
                    free &= ~members
        return groups

    def _small_clusters(self, ctx, snap, gas) -> list[np.ndarray]:
        """Connected groups of resolved-gas cells holding less than shrink_ratio x the threshold.

        A group with a particle outside this step's fluid cells is in the air (a bubble that just
        surfaced, which the vent or foam stage takes later in this step): it is left alone.
        """
        if len(gas) == 0:
            return []
        cells = self._cells(ctx, snap["x"][gas])
        occupied, row = np.unique(cells, axis=0, return_inverse=True)
        row = row.reshape(-1)
        label = connected_labels(occupied, ctx.grid.dim)[row]
        volume = snap["vol0"][gas].astype(np.float64) * snap["J"][gas]
        per_label = np.bincount(label, weights=volume)
        outside = (~snap["in_fluid"][gas]).astype(np.float64)  # not in a fluid cell (the device looked)
        in_air = np.bincount(label, weights=outside, minlength=len(per_label)) > 0
        small = np.flatnonzero((per_label > 0) & ~in_air
                               & (per_label < self.settings.shrink_ratio * self.threshold_volume))
        return [gas[label == lab] for lab in small]

    def _book_rounding(self, ctx, exact: float, stored: np.ndarray):
        self.state.gas_mass += float(exact - stored.astype(np.float64).sum())

    def _to_resolved(self, ctx, snap, members):
        """Fill the merged volume with gas particles at the seeding spacing; returns the liquid's
        push (centre, R^dim, reach) for push_liquid."""
        g = ctx.grid
        mass = snap["mass"][members].astype(np.float64)
        rest = snap["vol0"][members].astype(np.float64)
        volume = rest * snap["J"][members]
        total_mass, total_rest, total_volume = mass.sum(), rest.sum(), volume.sum()
        centre = (snap["x"][members] * volume[:, None]).sum(axis=0) / total_volume
        velocity = (snap["v"][members] * mass[:, None]).sum(axis=0) / total_mass
        ppc = ctx.scene.solver.particles_per_cell
        count = max(1, int(round(total_volume / (g.dx**3 / ppc))))
        pts = np.tile(centre, (count, 1))
        pts[:, : g.dim] += _ball_lattice(count, g.dx / ppc ** (1.0 / g.dim), g.dim)
        pts = np.clip(pts, 1e-4 * g.dx, np.asarray(g.domain_size) - 1e-4 * g.dx)
        material = np.full(count, snap["material"][members[0]], np.int32)
        sl = ctx.add_particles(pts.astype(np.float32), np.tile(velocity, (count, 1)).astype(np.float32), material,
                               np.full(count, total_volume / count))
        each = np.full(count, total_mass / count, np.float32)
        ctx.particles.mass[sl].assign(each)
        ctx.particles.vol0[sl].assign(np.full(count, total_rest / count, np.float32))
        ctx.particles.J[sl].assign(np.full(count, total_volume / total_rest, np.float32))
        self._book_rounding(ctx, total_mass, each)
        # Volume-preserving push of the liquid out of the new bubble (ball radius R in 3D, disk in 2D).
        radius = (sphere_radius(total_volume) if g.dim == 3 else math.sqrt(total_volume / (math.pi * g.dx)))
        return centre, radius**g.dim, PUSH_REACH * radius

    def _to_subgrid(self, ctx, snap, members):
        mass = snap["mass"][members].astype(np.float64)
        rest = snap["vol0"][members].astype(np.float64)
        volume = rest * snap["J"][members]
        total_mass, total_rest, total_volume = mass.sum(), rest.sum(), volume.sum()
        centre = (snap["x"][members] * volume[:, None]).sum(axis=0) / total_volume
        velocity = (snap["v"][members] * mass[:, None]).sum(axis=0) / total_mass
        sl = add_bubbles(ctx, centre[None], sphere_radius([total_volume]), velocity[None],
                         int(snap["material"][members[0]]))
        stored = np.array([total_mass], np.float32)
        ctx.particles.mass[sl].assign(stored)
        ctx.particles.vol0[sl].assign(np.array([total_rest], np.float32))
        ctx.particles.J[sl].assign(np.array([total_volume / total_rest], np.float32))
        self._book_rounding(ctx, total_mass, stored)
