"""Entrainment: sub-grid bubbles seeded where a splash traps air.

Entrainment (Ihmsen et al. 2012, trapped-air potential, on grid cells): for a liquid cell with air
in its 3^dim neighbourhood, I = sum_n W_n |u_cn| (1 - u^_cn . x^_cn) / sum_n W_n over its fluid
neighbours n (u_cn = u_c - u_n, x_cn = x_c - x_n, W = 1 - |x_cn|/2dx): the relative speed of
converging streams, doubled head-on, zero for flow that translates or separates. Clamped as
Phi = (min(I, max) - min(I, min)) / (max - min) with min_speed, max_speed; a cell seeds
rate * Phi * dt bubbles per step (the fraction by a hash of (seed, step, cell)).

No host round trip (docs/host_syncs.md): the seeds are written on the device straight into the
particle arrays, in cell order (a count per cell, an exclusive scan, then each cell writes its
own run: the order the host sort used to give, independent of launch order). The host does not
know how many there are until the step's one read-back (Simulation.step reads the fastest
particle for the next time step and this count with it); until then the particle count is
provisional, count + capacity: the unfilled slots are zero, inactive, and every kernel skips them.
The capacity (checkpointed) doubles after a step that seeds more; that step's excess is appended
at the read-back, without its first sub-grid move (logged in `overflows`).

Sizes: bubble_radius is the median; with bubble_radius_spread > 0 each seed's radius is log-normal,
r = bubble_radius exp(spread z), z standard normal cut at +-3 and r at the sub-grid radius (a larger
bubble would be resolved gas). The host draws z for every slot a step may fill from a generator
seeded by (scene seed, step): slot q's bubble, particle id next_id + q, always gets the same radius,
and the host knows every seed's float32 mass without reading the device. With spread 0 every seed
is the one bubble of bubble_radius (no draws).

The seeds' gas is air the splash took from the atmosphere: once their count is known (settle) their
mass is booked in its state's gas_mass (kg, checkpointed as "gas_mass_entrained"), which
Simulation.gas_budget subtracts from its total like the air core/voids.py books as trapped, so the
total stays conserved.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import warp as wp

from ..core.cells import block_offset, block_size, cell_type_at
from ..core import kernel_args
from ..core.geometry import GridGeometry
from ..core.kernel_args import FaceField, Particles
from ..core.grid import EMPTY, FLUID, PHASE_LIQUID, PHASE_SUBGRID
from ..core.host_state import HostState, saved
from ..core.stage import Stage
from ..core.simulation import GAS_LAW_CODES
from ..scene.effects import Entrainment

wp.set_module_options({"enable_backward": False})


@wp.func
def cell_velocity(vel: FaceField, c: wp.vec3i, dim: int):
    u = wp.vec3(0.5 * (vel.u[c[0], c[1], c[2]] + vel.u[c[0] + 1, c[1], c[2]]),
                0.5 * (vel.v[c[0], c[1], c[2]] + vel.v[c[0], c[1] + 1, c[2]]), 0.0)
    if dim == 3:
        u[2] = 0.5 * (vel.w[c[0], c[1], c[2]] + vel.w[c[0], c[1], c[2] + 1])
    return u


@wp.kernel
def trapped_air(
    dim: int,
    dt: float,
    min_speed: float,
    max_speed: float,
    rate: float,
    seed: int,
    types: wp.array3d(dtype=wp.int32),
    phase_cells: wp.array3d(dtype=wp.int32),
    vel: FaceField,
    seeds: wp.array(dtype=wp.int32),
):
    """Ihmsen et al.'s trapped-air potential per liquid cell near air: how many bubbles it seeds."""
    i, j, k = wp.tid()
    cell = (i * types.shape[1] + j) * types.shape[2] + k
    seeds[cell] = 0
    c = wp.vec3i(i, j, k)
    if types[i, j, k] != FLUID or phase_cells[i, j, k] != PHASE_LIQUID:
        return
    u_c = cell_velocity(vel, c, dim)
    near_air = int(0)
    potential = float(0.0)
    weights = float(0.0)
    for q in range(block_size(dim)):
        off = block_offset(q, dim)
        if off[0] == 0 and off[1] == 0 and off[2] == 0:
            continue
        t = cell_type_at(types, c + off)
        if t == EMPTY:
            near_air = 1  # there is air to trap
        if t != FLUID:
            continue
        d = wp.vec3(float(off[0]), float(off[1]), float(off[2]))
        dist = wp.length(d)
        weight = 1.0 - 0.5 * dist  # W = 1 - |x_cn| / 2dx
        u_rel = u_c - cell_velocity(vel, c + off, dim)
        speed = wp.length(u_rel)
        if speed > 0.0:
            # x_cn = x_c - x_n = -d: approaching streams give 1 - cos > 1, up to 2 head-on
            potential += weight * speed * (1.0 + wp.dot(u_rel, d) / (speed * dist))
        weights += weight
    if near_air == 0 or weights == 0.0:
        return
    trapped = potential / weights
    phi = (wp.min(trapped, max_speed) - wp.min(trapped, min_speed)) / (max_speed - min_speed)
    expected = rate * phi * dt
    if expected <= 0.0:
        return
    state = wp.rand_init(seed, cell)
    n = int(wp.floor(expected))
    if wp.randf(state) < expected - float(n):
        n += 1
    seeds[cell] = n


@wp.struct
class Bubble:
    """What every entrained bubble starts with (Simulation.add_particles' values for one at ambient):
    mass and vol0, or with `sized` 1 each slot's own, mass_of[slot] and vol0_of[slot]."""

    mass: float
    vol0: float
    sized: int
    mass_of: wp.array(dtype=float)
    vol0_of: wp.array(dtype=float)
    material: int
    gas_law: int
    gas_gamma: float


@wp.kernel
def place_seeds(
    seed: int,
    lo: int,
    hi: int,
    base: int,
    next_id: wp.int64,
    geo: GridGeometry,
    bubble: Bubble,
    seeds: wp.array(dtype=wp.int32),
    first: wp.array(dtype=wp.int32),
    vel: FaceField,
    types: wp.array3d(dtype=wp.int32),
    particles: Particles,
):
    """Each seeding cell writes its bubbles at base + its run (first: the exclusive scan of seeds),
    those of its slots in [lo, hi); the draws repeat trapped_air's and go on from there."""
    i, j, k = wp.tid()
    cell = (i * types.shape[1] + j) * types.shape[2] + k
    n = seeds[cell]
    if n == 0:
        return
    state = wp.rand_init(seed, cell)
    wp.randf(state)  # trapped_air's draw of the fraction
    u_c = cell_velocity(vel, wp.vec3i(i, j, k), geo.dim)
    for q in range(n):
        jitter = wp.vec3(wp.randf(state), wp.randf(state), 0.5)
        if geo.dim == 3:
            jitter[2] = wp.randf(state)
        slot = first[cell] + q
        if slot >= lo and slot < hi:
            p = base + slot
            particles.x[p] = geo.origin + (wp.vec3(float(i), float(j), float(k)) + jitter) * geo.dx
            particles.v[p] = u_c
            particles.mass[p] = bubble.mass
            particles.vol0[p] = bubble.vol0
            if bubble.sized == 1:
                particles.mass[p] = bubble.mass_of[slot]
                particles.vol0[p] = bubble.vol0_of[slot]
            particles.J[p] = 1.0
            particles.phase[p] = PHASE_SUBGRID
            particles.active[p] = 1
            particles.material[p] = bubble.material
            particles.gas_law[p] = bubble.gas_law
            particles.gas_gamma[p] = bubble.gas_gamma
            particles.ids[p] = next_id + wp.int64(slot)


@wp.kernel
def seed_total(seeds: wp.array(dtype=wp.int32), first: wp.array(dtype=wp.int32), total: wp.array(dtype=wp.int32),
               report: wp.array(dtype=float)):
    """This step's bubbles, for the host's one read-back (report[1], exact below 2^24)."""
    last = seeds.shape[0] - 1
    n = first[last] + seeds[last]
    total[0] = n
    report[1] = float(n)


@dataclass
class EntrainmentState(HostState):
    capacity: int = saved("entrainment_capacity", 256)  # seed slots per step (doubled past an overflow)
    gas_mass: float = saved("gas_mass_entrained", 0.0)  # kg taken from the air (module docstring)


class EntrainmentStage(Stage):
    """[effects.entrainment]: seeds sub-grid bubbles after g2p, before the sub-grid stage moves them."""

    name = "entrainment"
    Settings = Entrainment
    graph_safe = True

    def __init__(self, ctx, settings):
        super().__init__(ctx, settings)
        n_cells = math.prod(ctx.grid.cells)
        self._seeds = wp.zeros(n_cells, dtype=wp.int32, device=ctx.device)
        self._first = wp.zeros(n_cells, dtype=wp.int32, device=ctx.device)
        self._total = wp.zeros(1, dtype=wp.int32, device=ctx.device)
        self.state = EntrainmentState()
        self._pending = None  # (base, capacity, seed) while this step's seeds are provisional
        self.seeded = 0  # bubbles seeded since start (not checkpointed)
        self.overflows = 0  # steps that seeded more than the capacity (not checkpointed)
        ctx.report_readers.append(self._read_report)
        self._bubble = None

    def _bubble_values(self, ctx) -> Bubble:
        """Simulation.add_particles' values for one bubble of bubble_radius at ambient pressure (J0 = 1)."""
        if self._bubble is None:
            index = ctx.stage("subgrid_bubbles").gas_material
            m = list(ctx.scene.materials.values())[index]
            volume = 4.0 / 3.0 * math.pi * np.float64(self.settings.bubble_radius) ** 3
            b = self._bubble = Bubble()
            b.mass, b.vol0 = float(np.float32(m.density * volume)), float(np.float32(volume))
            b.material, b.gas_law, b.gas_gamma = index, GAS_LAW_CODES.get(m.eos, 0), float(np.float32(m.gamma))
            b.sized, self._density = 0, m.density
            b.mass_of = b.vol0_of = wp.zeros(1, dtype=float, device=ctx.device)
        return self._bubble

    def _draw_sizes(self, ctx, step: int, n: int) -> np.ndarray:
        """The float32 masses of slots 0..n-1 of this step's seeds (module docstring: Sizes), and their
        masses and rest volumes on the device for place_seeds; None with no spread."""
        s = self.settings
        if s.bubble_radius_spread == 0.0:
            return None
        b = self._bubble_values(ctx)
        z = np.clip(np.random.default_rng([int(ctx.scene.solver.seed), step]).standard_normal(n), -3.0, 3.0)
        radius = np.minimum(s.bubble_radius * np.exp(s.bubble_radius_spread * z), ctx.scene.effects["subgrid_bubbles"].radius)
        volume = 4.0 / 3.0 * math.pi * radius**3
        mass, vol0 = (self._density * volume).astype(np.float32), volume.astype(np.float32)
        if b.mass_of.shape[0] < n:  # grows like the capacity
            b.mass_of = wp.zeros(n, dtype=float, device=ctx.device)
            b.vol0_of = wp.zeros(n, dtype=float, device=ctx.device)
        b.mass_of[:n].assign(mass)
        b.vol0_of[:n].assign(vol0)
        b.sized = 1
        return mass

    def after_g2p(self, ctx, dt: float):
        s, g, f, p = self.settings, ctx.grid, ctx.fields, ctx.particles
        if s.rate == 0.0:
            return
        # One seed per step (scene seed, step index); the kernel hashes the cell index in.
        seed = (int(ctx.scene.solver.seed) * 1_000_003 + (ctx.stats.steps + 1) * 2_654_435_761) & 0x7FFFFFFF
        ctx.launch(trapped_air, g.cells, [g.dim, dt, s.min_speed, s.max_speed, s.rate, seed, f.types, f.phase_cells,
                                          kernel_args.face_field(f.vel), self._seeds])
        wp.utils.array_scan(self._seeds, self._first, inclusive=False)
        ctx.launch(seed_total, 1, [self._seeds, self._first, self._total, f.max_speed])
        base, capacity = p.count, self.state.capacity
        p.reserve(base + capacity)
        masses = self._draw_sizes(ctx, ctx.stats.steps + 1, capacity)
        self._place(ctx, seed, 0, capacity, base)
        p.count = base + capacity  # provisional: the next stages' launches cover the seeds
        self._pending = (base, capacity, seed, ctx.stats.steps + 1, masses)

    def _place(self, ctx, seed, lo, hi, base):
        f, p = ctx.fields, ctx.particles
        ctx.launch(place_seeds, ctx.grid.cells,
                   [seed, lo, hi, base, wp.int64(ctx.ledger.next_id), ctx.geometry, self._bubble_values(ctx),
                    self._seeds, self._first, kernel_args.face_field(f.vel), f.types, kernel_args.particle_arrays(p)])

    @property
    def pending_total(self):
        """The device count of this step's seeds while the host has not read it, else None."""
        return self._total if self._pending else None

    def _read_report(self, ctx, report):
        if self._pending:
            total = int(report[1])
            if total >= 1 << 24:  # past float32's exact integers (never in practice): the int itself
                total = int(ctx.read_host(self._total)[0])
            self.settle(ctx, total)

    def settle(self, ctx, total: int):
        """The read-back gave this step's seed count: the particle count becomes exact."""
        base, capacity, seed, step, masses = self._pending
        self._pending = None
        p = ctx.particles
        p.count = base + min(total, capacity)
        if total > capacity:  # rare: the excess joins now; the next steps have room
            p.reserve(base + total)
            masses = self._draw_sizes(ctx, step, total)  # the same stream: slots below capacity unchanged
            self._place(ctx, seed, capacity, total, base)
            p.count = base + total
            self.state.capacity = 2 * total
            self.overflows += 1
        ctx.ledger.next_id += total
        # The booking is the float32 masses place_seeds wrote, summed exactly: it matches the particles.
        if masses is None:
            self.state.gas_mass += float(total * self._bubble_values(ctx).mass)
        else:
            self.state.gas_mass += float(masses[:total].astype(np.float64).sum())
        self.seeded += total
