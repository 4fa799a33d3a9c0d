"""Entrainment (issue #4, item 3): sub-grid bubbles seeded where a splash traps air.

Entrainment (Ihmsen et al. 2012, trapped-air potential, on grid cells): for a liquid cell with air
in its 3^dim neighbourhood, I = sum_n W_n |u_cn| (1 - u^_cn . x^_cn) / sum_n W_n over its fluid
neighbours n (u_cn = u_c - u_n, x_cn = x_c - x_n, W = 1 - |x_cn|/2dx): the relative speed of
converging streams, doubled head-on, zero for flow that translates or separates. Clamped as
Phi = (min(I, max) - min(I, min)) / (max - min) with min_speed, max_speed; a cell seeds
rate * Phi * dt bubbles per step (the fraction by a hash of (seed, step, cell)).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..core import grid_kernels as gk
from ..core.geometry import GridGeometry
from ..core.grid import EMPTY, FLUID, PHASE_LIQUID
from ..core.stage import Stage
from ..scene.effects import Entrainment

wp.set_module_options({"enable_backward": False})


@wp.func
def cell_velocity(
    vel_u: wp.array3d(dtype=float), vel_v: wp.array3d(dtype=float), vel_w: wp.array3d(dtype=float),
    c: wp.vec3i, dim: int,
):
    u = wp.vec3(0.5 * (vel_u[c[0], c[1], c[2]] + vel_u[c[0] + 1, c[1], c[2]]),
                0.5 * (vel_v[c[0], c[1], c[2]] + vel_v[c[0], c[1] + 1, c[2]]), 0.0)
    if dim == 3:
        u[2] = 0.5 * (vel_w[c[0], c[1], c[2]] + vel_w[c[0], c[1], c[2] + 1])
    return u


@wp.kernel
def trapped_air(
    types: wp.array3d(dtype=wp.int32),
    phase_cells: wp.array3d(dtype=wp.int32),
    vel_u: wp.array3d(dtype=float),
    vel_v: wp.array3d(dtype=float),
    vel_w: wp.array3d(dtype=float),
    geo: GridGeometry,
    dt: float,
    min_speed: float,
    max_speed: float,
    rate: float,
    seed: int,
    capacity: int,
    count: wp.array(dtype=wp.int32),
    spawn_key: wp.array(dtype=wp.int64),
    spawn_x: wp.array(dtype=wp.vec3),
    spawn_v: wp.array(dtype=wp.vec3),
):
    """Ihmsen et al.'s trapped-air potential per liquid cell near air; appends the bubbles it seeds."""
    origin = geo.origin
    dx = geo.dx
    dim = geo.dim
    i, j, k = wp.tid()
    c = wp.vec3i(i, j, k)
    if types[i, j, k] != FLUID or phase_cells[i, j, k] != PHASE_LIQUID:
        return
    u_c = cell_velocity(vel_u, vel_v, vel_w, c, dim)
    near_air = int(0)
    potential = float(0.0)
    weights = float(0.0)
    for q in range(gk.block_size(dim)):
        off = gk.block_offset(q, dim)
        if off[0] == 0 and off[1] == 0 and off[2] == 0:
            continue
        t = gk.cell_type_at(types, c + off)
        if t == EMPTY:
            near_air = 1  # there is air to trap
        if t != FLUID:
            continue
        d = wp.vec3(float(off[0]), float(off[1]), float(off[2]))
        dist = wp.length(d)
        weight = 1.0 - 0.5 * dist  # W = 1 - |x_cn| / 2dx
        u_rel = u_c - cell_velocity(vel_u, vel_v, vel_w, c + off, dim)
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
    cell = (i * types.shape[1] + j) * types.shape[2] + k
    state = wp.rand_init(seed, cell)
    n = int(wp.floor(expected))
    if wp.randf(state) < expected - float(n):
        n += 1
    if n == 0:
        return
    start = wp.atomic_add(count, 0, n)
    for q in range(n):
        slot = start + q
        if slot < capacity:
            jitter = wp.vec3(wp.randf(state), wp.randf(state), 0.5)
            if dim == 3:
                jitter[2] = wp.randf(state)
            spawn_key[slot] = wp.int64(cell) * wp.int64(1024) + wp.int64(q)  # host sorts: launch order free
            spawn_x[slot] = origin + (wp.vec3(float(i), float(j), float(k)) + jitter) * dx
            spawn_v[slot] = u_c


class EntrainmentStage(Stage):
    """[effects.entrainment]: seeds sub-grid bubbles after g2p, before the sub-grid stage moves them
    (through that stage's add_bubbles)."""

    name = "entrainment"
    Settings = Entrainment

    def __init__(self, sim, settings):
        super().__init__(sim, settings)
        self._capacity = 0
        self.seeded = 0  # bubbles seeded since start (not checkpointed)

    def _allocate(self, sim, capacity):
        dev = sim.device
        self._capacity = capacity
        self._count = wp.zeros(1, dtype=wp.int32, device=dev)
        self._key = wp.zeros(capacity, dtype=wp.int64, device=dev)
        self._x = wp.zeros(capacity, dtype=wp.vec3, device=dev)
        self._v = wp.zeros(capacity, dtype=wp.vec3, device=dev)

    def after_g2p(self, sim, dt: float):
        s, g, f = self.settings, sim.grid, sim.fields
        if s.rate == 0.0:
            return
        if self._capacity == 0:
            self._allocate(sim, 256)
        # One seed per step (scene seed, step index); the kernel hashes the cell index in.
        seed = (int(sim.scene.solver.seed) * 1_000_003 + (sim.stats.steps + 1) * 2_654_435_761) & 0x7FFFFFFF
        for _ in range(2):  # a second launch only if the buffer was too small
            self._count.zero_()
            sim.launch(trapped_air, g.cells,
                       [f.types, f.phase_cells, *f.vel, sim.geometry, dt, s.min_speed,
                        s.max_speed, s.rate, seed, self._capacity, self._count, self._key, self._x, self._v])
            count = int(self._count.numpy()[0])
            if count <= self._capacity:
                break
            self._allocate(sim, 2 * count)
        if count == 0:
            return
        order = np.argsort(self._key.numpy()[:count], kind="stable")
        positions = self._x.numpy()[:count][order]
        velocities = self._v.numpy()[:count][order]
        bubbles = sim.stage("subgrid_bubbles")
        bubbles.add_bubbles(sim, positions, np.full(count, s.bubble_radius), velocities, bubbles.gas_material)
        self.seeded += count
