"""Emitters: a pouring stream of liquid and an air stone releasing gas bubbles.

Both work on the host at the start of a step and append particles (Simulation.add_particles).
Their progress (stream length owed, bubbles owed, how many emitted) lives in sim.host_state, so a
resumed run emits exactly what an uninterrupted one does; every random draw is seeded by
(scene seed, emitter, count), never by a global generator.

Mass is exact by construction: a stream layer's particles share the layer's volume
(area x spacing), and a bubble's particles share its sphere's volume (in 2D its disk's through the
one-cell slab, pi r^2 dx, sub-grid bubbles too: a bubble is the same gas whichever way it is held).

Where a bubble goes (all of a step's bubbles at once, from the particles as they are now, so a
resumed run decides alike; one read, docs/host_syncs.md):
- into the open air (no liquid above its cell in its column; without gravity, none in its 3^dim
  block): the gas joins the atmosphere at once, its mass booked as vented. Before, such bubbles
  were added on top of the gas already there (a gas-only box claimed 1.7 times its volume in gas);
- into the liquid: its particles are added and the fluid around makes room, the volume-preserving
  radial push r' = (r^d + R^d)^(1/d) within PUSH_REACH R (effects/subgrid.py's gather does the
  same), liquid and resolved gas alike. Before, the new gas sat on top of the water, so water
  and gas together claimed more than the box (0.83 + 0.89 of a 2D box after two frames). What the
  push carries past an open wall leaves (booked as outflow); past a closed one it is clamped;
- into a domain the liquid cannot leave (no open wall but the top) with no room left for it (the
  liquid's rest volume, the gas's and the new bubble's above the room): the run stops,
  GasRoomError naming the injector. Injected gas is at ambient pressure: nothing here compresses
  it (a closed box of water cannot take it in), and scene/capacity.py refuses a scene whose
  shapes leave no room for even one bubble.
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from ..core.cells import cell_of
from ..core.geometry import GridGeometry
from ..core.grid import ACTIVE, AIRBORNE, PHASE_GAS, PHASE_LIQUID, PHASE_SUBGRID
from ..core.simulation import SimulationError
from ..core.stage import Stage
from ..core.transfer_kernels import clamp_to_domain, open_wall_exit
from ..scene.capacity import draining_walls, room_and_seeded_liquid
from ..scene.effects import GasInjector, LiquidInflow
from .subgrid import PUSH_REACH

wp.set_module_options({"enable_backward": False})

NO_LIQUID = -(1 << 30)  # a column's top liquid cell where it has none


class GasRoomError(SimulationError):
    """A bubble due in a domain the liquid cannot leave, which has no room left for it."""


@wp.kernel
def injection_sites(
    x: wp.array(dtype=wp.vec3), phase: wp.array(dtype=wp.int32), active: wp.array(dtype=wp.int32),
    vol0: wp.array(dtype=float), J: wp.array(dtype=float), geo: GridGeometry,
    cells: wp.array(dtype=wp.vec3i), n: int, top: wp.array(dtype=wp.int32), held: wp.array(dtype=wp.float64),
):
    """Per bubble b (its cell cells[b]): top[b], the highest liquid cell (counted upwards) in its
    column, or without gravity 1 where liquid is in its 3^dim block; held[0]: the volume the fluid
    holds (liquid at rest volume, flying liquid included; resolved and sub-grid gas at V0 J)."""
    p = wp.tid()
    a = active[p]
    ph = phase[p]
    if a != ACTIVE and a != AIRBORNE:
        return
    if ph == PHASE_LIQUID:
        wp.atomic_add(held, 0, wp.float64(vol0[p]))
    elif (ph == PHASE_GAS or ph == PHASE_SUBGRID) and a == ACTIVE:
        wp.atomic_add(held, 0, wp.float64(vol0[p] * J[p]))
    if ph != PHASE_LIQUID or a != ACTIVE:
        return
    c = cell_of(clamp_to_domain(x[p], geo.domain_hi, geo.dx, geo.dim), geo.origin, geo.dx)
    up = geo.up_axis
    for b in range(n):
        d = c - cells[b]
        if up >= 0:
            d[up] = 0
            if d[0] == 0 and d[1] == 0 and d[2] == 0:
                wp.atomic_max(top, b, geo.up_sign * c[up])
        elif wp.abs(d[0]) <= 1 and wp.abs(d[1]) <= 1 and wp.abs(d[2]) <= 1:
            wp.atomic_max(top, b, 1)


@wp.kernel
def make_room(
    centres: wp.array(dtype=wp.vec3d), radius_pow: wp.array(dtype=wp.float64), reach: wp.array(dtype=wp.float64),
    n: int, first_new: int, geo: GridGeometry,
    phase: wp.array(dtype=wp.int32), active: wp.array(dtype=wp.int32), x: wp.array(dtype=wp.vec3),
):
    """Liquid and resolved gas (not the new bubbles, from first_new on) make room for each new bubble
    in turn: r' = (r^d + R^d)^(1/d) within `reach`, in float64 (effects/subgrid.py's push_liquid).
    A particle pushed past an open wall leaves (or, liquid past an open top, flies)."""
    p = wp.tid()
    if p >= first_new or active[p] != ACTIVE or (phase[p] != PHASE_LIQUID and phase[p] != PHASE_GAS):
        return
    dim = geo.dim
    xd = wp.vec3d(wp.float64(x[p][0]), wp.float64(x[p][1]), wp.float64(x[p][2]))
    moved = int(0)
    for b in range(n):
        d = xd - centres[b]
        if dim == 2:
            d[2] = wp.float64(0.0)
        r = wp.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        if r < reach[b] and r > wp.float64(0.0):
            if dim == 2:
                scale = wp.sqrt(r * r + radius_pow[b]) / r
            else:
                scale = wp.pow(wp.pow(r, wp.float64(3.0)) + radius_pow[b], wp.float64(1.0) / wp.float64(3.0)) / r
            for a in range(dim):
                xd[a] = centres[b][a] + d[a] * scale
            moved = 1
    if moved == 0:
        return
    xn = wp.vec3(float(xd[0]), float(xd[1]), float(xd[2]))
    code = open_wall_exit(xn, geo, phase[p])
    if code == ACTIVE:
        xn = clamp_to_domain(xn, geo.domain_hi, geo.dx, dim)
    active[p] = code
    x[p] = xn


@wp.kernel
def pack_sites(top: wp.array(dtype=wp.int32), held: wp.array(dtype=wp.float64), out: wp.array(dtype=wp.float64)):
    """top and held in one array, for one read."""
    i = wp.tid()
    if i < top.shape[0]:
        out[i] = wp.float64(top[i])
    else:
        out[i] = held[0]


@wp.kernel
def book_vented(vented_mass: wp.array(dtype=wp.float64), mass: wp.float64):
    vented_mass[0] = vented_mass[0] + mass


def _perpendicular_basis(direction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    helper = np.array([1.0, 0.0, 0.0]) if abs(direction[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(direction, helper)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(direction, e1)


def _lattice_in_ball(radius: float, spacing: float, dim: int, rng) -> np.ndarray:
    """Jittered lattice points (centred on 0) within `radius`, in `dim` dimensions; at least one."""
    m = int(math.ceil(radius / spacing))
    axes = [np.arange(-m, m + 1) * spacing] * dim
    pts = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, dim)
    pts = pts + rng.uniform(-0.25, 0.25, pts.shape) * spacing
    pts = pts[np.linalg.norm(pts, axis=1) <= radius]
    return pts if len(pts) else np.zeros((1, dim))


class EmitterStage(Stage):
    """[[emitters]]: particles added at the start of each step; their speed enters the CFL limit
    before any particle has it."""

    name = "emitters"

    def __init__(self, sim, settings=None):
        super().__init__(sim, settings)
        scene = sim.scene
        self.dim = scene.dim
        self.dx = scene.domain.dx
        self.spacing = self.dx / scene.solver.particles_per_cell ** (1.0 / self.dim)
        self.seed = scene.solver.seed
        self.materials = list(scene.materials)
        self.emitters = scene.emitters
        # per emitter: [amount owed (stream length, m / bubbles), number emitted so far]
        sim.host_state["emitters"] = np.zeros((len(self.emitters), 2))
        # The room a domain the liquid cannot leave has for liquid and gas (m^3; 2D: the one-cell
        # slab), colliders where they stand at t = 0; None where the liquid drains (open walls).
        self.room = None
        if any(isinstance(e, GasInjector) for e in self.emitters) and not draining_walls(scene.domain):
            self.room = room_and_seeded_liquid(scene)[0] * (self.dx if self.dim == 2 else 1.0)

    def _point(self, v) -> np.ndarray:
        """A scene position as a 3-vector; 2D particles sit mid-slab (z = dx/2) like the seeded ones."""
        return np.array(tuple(v) + ((0.5 * self.dx,) if self.dim == 2 else ()), float)

    def _vector(self, v) -> np.ndarray:
        return np.array(tuple(v) + ((0.0,) if self.dim == 2 else ()), float)

    def incoming_speed(self, t0: float, t1: float) -> float:
        return max(e.speed_between(t0, t1) for e in self.emitters)

    def begin_step(self, sim, dt: float):
        t = sim.time
        state = sim.host_state["emitters"]
        bubbles = []  # this step's, placed together (_release)
        for i, e in enumerate(self.emitters):
            stop = math.inf if e.stop is None else e.stop
            overlap = min(t + dt, stop) - max(t, e.start)
            if overlap <= 0.0:
                continue
            if isinstance(e, LiquidInflow):
                state[i, 0] += e.speed * overlap
                while state[i, 0] >= self.spacing:
                    state[i, 0] -= self.spacing
                    # This layer entered state[i, 0] / speed ago: it has travelled that far.
                    self._stream_layer(sim, i, e, state[i, 0], int(state[i, 1]))
                    state[i, 1] += 1
            elif isinstance(e, GasInjector):
                state[i, 0] += e.rate * overlap
                while state[i, 0] >= 1.0:
                    state[i, 0] -= 1.0
                    bubbles.append(self._bubble(i, e, int(state[i, 1])))
                    state[i, 1] += 1
        if bubbles:
            self._release(sim, bubbles)

    def _stream_layer(self, sim, i, e: LiquidInflow, travelled: float, count: int):
        rng = np.random.default_rng([self.seed, i, count])
        h, direction = self.spacing, self._vector(e.direction)
        if self.dim == 2:
            side = np.array([-direction[1], direction[0], 0.0])
            n = max(1, int(round(2.0 * e.radius / h)))
            offsets = ((np.arange(n) + 0.5) / n * 2.0 - 1.0) * e.radius
            lateral = offsets[:, None] * side
            layer_volume = 2.0 * e.radius * h * self.dx  # the 2D slab is one cell thick
        else:
            e1, e2 = _perpendicular_basis(direction)
            disk = _lattice_in_ball(e.radius, h, 2, rng)
            lateral = disk[:, :1] * e1 + disk[:, 1:] * e2
            layer_volume = math.pi * e.radius**2 * h
        jitter = rng.uniform(-0.25, 0.25, len(lateral))[:, None] * h * direction
        positions = self._point(e.center) + lateral + (travelled + jitter) * direction
        self._add(sim, positions, np.tile(direction * e.speed, (len(positions), 1)), e.material,
                  layer_volume / len(positions))

    def _bubble(self, i, e: GasInjector, count: int) -> dict:
        """Bubble number `count` of emitter i: where, how big (its volume: a sphere's, in 2D the
        disk's through the slab) and how fast, its draws seeded by (scene seed, emitter, count)."""
        rng = np.random.default_rng([self.seed, i, count])
        radius = e.radius * math.exp(e.radius_spread * rng.standard_normal())
        offset = np.zeros(3)
        if e.spread > 0.0:  # uniform in the disk (ball) of radius `spread` around the centre
            u = rng.standard_normal(self.dim)
            offset[: self.dim] = u / np.linalg.norm(u) * e.spread * rng.random() ** (1.0 / self.dim)
        volume = (4.0 / 3.0 * math.pi * radius**3) if self.dim == 3 else math.pi * radius**2 * self.dx
        return {"emitter": i, "material": e.material, "radius": radius, "volume": volume, "rng": rng,
                "centre": self._point(e.center) + offset, "velocity": self._vector(e.velocity)}

    def _release(self, sim, bubbles: list[dict]):
        """Vent the bubbles due in the open air, stop the run if the rest find no room, add them
        and push the fluid out of the resolved ones (the module docstring)."""
        in_air, held = self._sites(sim, [b["centre"] for b in bubbles])
        densities = {name: m.density for name, m in sim.scene.materials.items()}
        vented = sum(densities[b["material"]] * b["volume"] for b, air in zip(bubbles, in_air) if air)
        if vented > 0.0:
            sim.launch(book_vented, 1, [sim.fields.vented_mass, wp.float64(vented)])
        bubbles = [b for b, air in zip(bubbles, in_air) if not air]
        if not bubbles:
            return
        self._check_room(sim, bubbles, held)
        subgrid = sim.stage("subgrid_bubbles")
        first_new, pushes = sim.particles.count, []
        for b in bubbles:
            mat = self.materials.index(b["material"])
            if subgrid and b["radius"] < subgrid.settings.radius:
                # A sub-grid bubble is a sphere: in 2D the one holding the disk's volume.
                r = (3.0 * b["volume"] / (4.0 * math.pi)) ** (1.0 / 3.0)
                subgrid.add_bubbles(sim, b["centre"][None], np.array([r]), b["velocity"][None], mat)
                continue
            pts = _lattice_in_ball(b["radius"], self.spacing, self.dim, b["rng"])
            positions = np.tile(b["centre"], (len(pts), 1))
            positions[:, : self.dim] += pts
            self._add(sim, positions, np.tile(b["velocity"], (len(pts), 1)), b["material"], b["volume"] / len(pts))
            pushes.append((b["centre"], b["radius"] ** self.dim, 1e30))
        if pushes:
            centres, radius_pow, reach = (np.array(col, np.float64) for col in zip(*pushes))
            dev = lambda a, t: wp.array(a, dtype=t, device=sim.device)  # noqa: E731
            p = sim.particles
            sim.launch(make_room, first_new, [dev(centres, wp.vec3d), dev(radius_pow, wp.float64),
                                              dev(reach, wp.float64), len(pushes), first_new, sim.geometry,
                                              p.phase, p.active, p.x])
            sim.book_outflow()  # what the push carried through an open wall

    def _sites(self, sim, centres) -> tuple[np.ndarray, float]:
        """(in the open air, per bubble; the volume the fluid holds now): injection_sites, one read."""
        g, p, n = sim.grid, sim.particles, len(centres)
        eps = 1e-4 * g.dx  # a centre outside the domain (a spread past a wall) counts as its edge cell's
        at = np.clip(np.asarray(centres, np.float64), eps, np.asarray(g.domain_size) - eps)
        cells = np.floor((at - np.asarray(g.origin)) / g.dx).astype(np.int32)
        top = wp.full(n, NO_LIQUID, dtype=wp.int32, device=sim.device)
        held = wp.zeros(1, dtype=wp.float64, device=sim.device)
        if p.count:
            sim.launch(injection_sites, p.count, [p.x, p.phase, p.active, p.vol0, p.J, sim.geometry,
                                                  wp.array(cells, dtype=wp.vec3i, device=sim.device), n, top, held])
        out = wp.zeros(n + 1, dtype=wp.float64, device=sim.device)
        sim.launch(pack_sites, n + 1, [top, held, out])
        result = sim.read_host(out)
        tops = result[:n]
        up, sign = sim.up
        if up >= 0:
            in_air = sign * cells[:, up] > tops
        else:
            in_air = tops == NO_LIQUID
        return in_air, float(result[n])

    def _check_room(self, sim, bubbles: list[dict], held: float):
        """GasRoomError when a domain the liquid cannot leave has no room for this step's bubbles."""
        if self.room is None:
            return
        need = held + sum(b["volume"] for b in bubbles)
        if need <= self.room:
            return
        i = bubbles[0]["emitter"]
        e = self.emitters[i]
        key = f"[emitters.{i}]"
        raise GasRoomError(
            f"t = {sim.time:.6g} s: {key} (gas_injector) releases a bubble into a domain the liquid cannot "
            f"leave, but the liquid and gas already hold {held / self.room:.3f} of its room and the bubble "
            f"needs {need / self.room - held / self.room:.3g} more: the gas would have to be squeezed into "
            f"the water. Fixes: an open wall the liquid can leave through (not the top), less liquid, "
            f"a lower {key}.rate or {key}.radius, or {key}.stop <= {sim.time:.4g}")

    def _add(self, sim, positions, velocities, material: str, volume_each: float):
        size = np.array(sim.grid.domain_size)
        eps = 1e-4 * self.dx
        positions = np.clip(positions, eps, size - eps)  # like the transfers' clamp: never outside
        n = len(positions)
        sim.add_particles(positions.astype(np.float32), velocities.astype(np.float32),
                          np.full(n, self.materials.index(material), np.int32), np.full(n, volume_each))
