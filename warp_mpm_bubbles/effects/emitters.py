"""Emitters: a pouring stream of liquid and an air stone releasing gas bubbles.

Both work on the host at the start of a step and append particles (Simulation.add_particles).
Their progress (stream length owed, bubbles owed, how many emitted) lives in the stage's state, so a
resumed run emits exactly what an uninterrupted one does; every random draw is seeded by
(scene seed, emitter, count), never by a global generator.

Mass is exact by construction: a stream layer's particles share the layer's volume
(area x spacing), and a bubble's particles share its sphere's volume (in 2D its disk's through the
one-cell slab, pi r^2 dx, sub-grid bubbles too: a bubble is the same gas whichever way it is held).

A stream delivers what the liquid lets in: a particle whose cell the liquid already fills past
CROWDED_FILL (a nozzle under water, aimed at a wall, or in a full box) is not laid, and
the state's inflow books what each stream owed and what it delivered (the run's summary
says when it is less). Laid anyway, such layers crowded the liquid into 0.84-0.89 of its rest volume.

Where a bubble goes (all of a step's bubbles at once, from the particles as they are now, so a
resumed run decides alike; one read, docs/host_syncs.md):
- into the open air (no liquid above its cell in its column; without gravity, none in its 3^dim
  block): the gas joins the atmosphere at once, its mass booked as vented. Before, such bubbles
  were added on top of the gas already there (a gas-only box claimed 1.7 times its volume in gas);
- into the liquid: its particles are added and the fluid around makes room, the volume-preserving
  radial push r' = (r^d + R^d)^(1/d) (effects/subgrid.py's gather uses it within 4 R), liquid and
  resolved gas alike, by as much as the bubble overlaps, everywhere, with the bubble's images
  across the walls (effects/room.py: sources across closed walls, sinks across open ones), its
  ball inside the domain (moved in from the walls by its radius). Before, the new gas sat on top
  of the water, so water and gas together claimed more than the box (0.83 + 0.89 of a 2D box after two frames).
  What the push carries past an open wall leaves (booked as outflow); past a closed one it is clamped;
- into a domain the liquid cannot leave (no open wall but the top) with no room left for it (the
  liquid's rest volume, the gas's and the new bubble's above the room): the run stops,
  GasRoomError naming the injector. Injected gas is at ambient pressure: nothing here compresses
  it (a closed box of water cannot take it in), and scene/capacity.py refuses a scene whose
  shapes leave no room for even one bubble.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import warp as wp

from ..core.cells import cell_of
from ..core.geometry import GridGeometry
from ..core.grid import ACTIVE, AIRBORNE, PHASE_GAS, PHASE_LIQUID, PHASE_SUBGRID
from ..core.simulation import SimulationError
from ..core.host_state import HostState, saved
from ..core.stage import Stage
from ..core.transfer_kernels import CELL_OFFSET, grid_coord, make_stencil
from ..core.boundary import clamp_to_domain
from ..scene.capacity import MAX_INJECTED_GAUGE, draining_walls, room_and_seeded_liquid
from ..scene.limits import max_gauge_pressure
from ..scene.effects import GasInjector, LiquidInflow
from .nozzle_walls import open_nozzles, walled_nozzles
from .room import NO_LIQUID, in_open_air, make_room_for

wp.set_module_options({"enable_backward": False})

# A stream particle is not laid into a cell whose liquid already fills more than this of it (rest
# volume, splatted as p2g does): a full cell. Measured: a free stream's cells read up to 0.75 (a 2 m/s
# pour), a submerged or blocked nozzle's 1.1-4.8. At 1.2 the fuzz's blocked nozzles kept the liquid in
# 0.94-0.95 of its rest volume (0.84-0.89 laying every layer), and a closed-box pour whose splashes
# reach the nozzle delivered 70% of its stream by frame 16, the liquid in 0.92-1.0 of its rest volume
# (0.88). But 1.2 still laid layers into cells already full: a stream into a full box open at the top
# and side overfilled it to 1.023 of the box (1.011 at 1.0), one into a full tank open at the side
# with a bubble to 1.021 with the gas (1.015), and one aimed at a closed corner a cell away crowded
# the liquid into 0.853 of its rest volume (0.911) (tests/run_fuzz_scenes.py's HARD_SCENES).
CROWDED_FILL = 1.0


class GasRoomError(SimulationError):
    """A bubble due in a domain the liquid cannot leave, which has no room left for it."""


@wp.kernel
def vent_released(first_new: int, owner: wp.array(dtype=wp.int32), cells: wp.array(dtype=wp.vec3i),
                  top: wp.array(dtype=wp.int32), geo: GridGeometry, mass: wp.array(dtype=float),
                  active: wp.array(dtype=wp.int32), vented_mass: wp.array(dtype=wp.float64)):
    """The new particles (from first_new on) of bubbles released in the open air join it at once:
    retired, their mass booked as vented."""
    i = wp.tid()
    b = owner[i]
    if in_open_air(cells[b], top[b], geo):
        p = first_new + i
        active[p] = 0
        wp.atomic_add(vented_mass, 0, wp.float64(mass[p]))


@wp.kernel
def injection_sites(
    x: wp.array(dtype=wp.vec3), phase: wp.array(dtype=wp.int32), active: wp.array(dtype=wp.int32),
    vol0: wp.array(dtype=float), J: wp.array(dtype=float), geo: GridGeometry,
    cells: wp.array(dtype=wp.vec3i), n: int, top: wp.array(dtype=wp.int32), held: wp.array(dtype=wp.float64),
    least_J: wp.array(dtype=float),
):
    """Per bubble b (its cell cells[b]): top[b], the highest liquid cell (counted upwards) in its
    column, or without gravity 1 where liquid is in its 3^dim block. held[0]: the liquid's rest
    volume (flying liquid included), held[1]: the gas's volume V0 J (resolved and sub-grid), held[2]:
    its rest volume V0; least_J[0]: the gas's smallest J (its highest pressure)."""
    p = wp.tid()
    a = active[p]
    ph = phase[p]
    if a != ACTIVE and a != AIRBORNE:
        return
    if ph == PHASE_LIQUID:
        wp.atomic_add(held, 0, wp.float64(vol0[p]))
    elif (ph == PHASE_GAS or ph == PHASE_SUBGRID) and a == ACTIVE:
        wp.atomic_add(held, 1, wp.float64(vol0[p] * J[p]))
        wp.atomic_add(held, 2, wp.float64(vol0[p]))
        wp.atomic_min(least_J, 0, J[p])
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
def fill_box(x: wp.array(dtype=wp.vec3), phase: wp.array(dtype=wp.int32), active: wp.array(dtype=wp.int32),
             vol0: wp.array(dtype=float), geo: GridGeometry, lo: wp.vec3i, size: wp.vec3i,
             box: wp.array(dtype=float)):
    """The liquid's rest volume in the cells lo .. lo + size - 1 (box, x-major), splatted as p2g
    splats fields.liq_volume (quadratic B-spline, cell centres) from the particles as they are now."""
    p = wp.tid()
    if active[p] != ACTIVE or phase[p] != PHASE_LIQUID:
        return
    xp = clamp_to_domain(x[p], geo.domain_hi, geo.dx, geo.dim)
    s = make_stencil(grid_coord(xp, geo.origin, 1.0 / geo.dx, CELL_OFFSET), geo.dim)
    for i in range(3):
        for j in range(3):
            for k in range(s.nk):
                n = s.base + wp.vec3i(i, j, k) - lo
                if n[0] >= 0 and n[1] >= 0 and n[2] >= 0 and n[0] < size[0] and n[1] < size[1] and n[2] < size[2]:
                    wp.atomic_add(box, (n[0] * size[1] + n[1]) * size[2] + n[2], s.wx[i] * s.wy[j] * s.wz[k] * vol0[p])


@wp.kernel
def compress_gas(phase: wp.array(dtype=wp.int32), active: wp.array(dtype=wp.int32), factor: float,
                 J: wp.array(dtype=float)):
    """Every gas particle (resolved and sub-grid) gives up the same share of its volume."""
    p = wp.tid()
    if active[p] == ACTIVE and (phase[p] == PHASE_GAS or phase[p] == PHASE_SUBGRID):
        J[p] = J[p] * factor


@wp.kernel
def pack_sites(top: wp.array(dtype=wp.int32), held: wp.array(dtype=wp.float64), least_J: wp.array(dtype=float),
               out: wp.array(dtype=wp.float64)):
    """top, held and least_J in one array, for one read."""
    i = wp.tid()
    n = top.shape[0]
    if i < n:
        out[i] = wp.float64(top[i])
    elif i < n + 3:
        out[i] = held[i - n]
    else:
        out[i] = wp.float64(least_J[0])


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


@dataclass
class EmitterState(HostState):
    # per emitter: [amount owed (stream length, m / bubbles), number emitted so far]
    progress: np.ndarray = saved("emitters", factory=lambda: np.zeros((0, 2)))
    # per emitter: [volume its stream owed (layers x layer volume), volume delivered] (m^3; 2D: the
    # one-cell slab). A blocked nozzle delivers less (_deliver): the summary says so.
    inflow: np.ndarray = saved("inflow_volume", factory=lambda: np.zeros((0, 2)))


class EmitterStage(Stage):
    """[[emitters]]: particles added at the start of each step; their speed enters the CFL limit
    before any particle has it."""

    name = "emitters"
    graph_safe = True  # begin_step runs outside the graphs; the nozzles' faces read their speeds from a device array

    def __init__(self, ctx, settings=None):
        super().__init__(ctx, settings)
        scene = ctx.scene
        self.dim = scene.dim
        self.dx = scene.domain.dx
        self.size = np.asarray(ctx.grid.domain_size[: self.dim], float)
        self.spacing = self.dx / scene.solver.particles_per_cell ** (1.0 / self.dim)
        self.seed = scene.solver.seed
        self.materials = list(scene.materials)
        self.emitters = scene.emitters
        self.state = EmitterState(np.zeros((len(self.emitters), 2)), np.zeros((len(self.emitters), 2)))
        # The room a domain the liquid cannot leave has for liquid and gas (m^3; 2D: the one-cell
        # slab), colliders where they stand at t = 0; None where the liquid drains (open walls).
        self.room = None
        if any(isinstance(e, GasInjector) for e in self.emitters) and not draining_walls(scene.domain):
            self.room = room_and_seeded_liquid(scene)[0] * (self.dx if self.dim == 2 else 1.0)
        # Streams whose nozzle is against a closed wall behind it open that wall (effects/nozzle_walls.py).
        self.walled = walled_nozzles(scene, ctx.geometry)
        self.walled_speed = wp.zeros(len(self.walled), dtype=float, device=ctx.device)  # this step's, per stream

    def hooks(self) -> set[str]:
        hooks = super().hooks()
        if not self.walled:  # no wall to open: the grid hooks would do nothing
            hooks -= {"on_faces", "on_extended"}
        return hooks

    def on_faces(self, ctx, dt: float):
        self.on_extended(ctx, ctx.fields.vel)

    def on_extended(self, ctx, vel):
        open_nozzles(ctx, [self.emitters[i] for i in self.walled], self.walled_speed, vel)

    def _point(self, v) -> np.ndarray:
        """A scene position as a 3-vector; 2D particles sit mid-slab (z = dx/2) like the seeded ones."""
        return np.array(tuple(v) + ((0.5 * self.dx,) if self.dim == 2 else ()), float)

    def _vector(self, v) -> np.ndarray:
        return np.array(tuple(v) + ((0.0,) if self.dim == 2 else ()), float)

    def incoming_speed(self, t0: float, t1: float) -> float:
        return max(e.speed_between(t0, t1) for e in self.emitters)

    def summary_lines(self, ctx) -> list[str]:
        """A line for each stream that delivered less than it owed (_deliver refused crowded cells)."""
        return [f"  [emitters.{i}] delivered {100 * delivered / owed:.0f}% of its stream: its nozzle's cells "
                f"were full of liquid (submerged, or the stream blocked)"
                for i, (owed, delivered) in enumerate(self.state.inflow) if delivered < owed * (1.0 - 1e-9)]

    def begin_step(self, ctx, dt: float):
        t = ctx.time
        state = self.state.progress
        bubbles, layers = [], []  # this step's, placed together (_release, _deliver)
        flowing = set()
        for i, e in enumerate(self.emitters):
            stop = math.inf if e.stop is None else e.stop
            overlap = min(t + dt, stop) - max(t, e.start)
            if overlap <= 0.0:
                continue
            flowing.add(i)
            if isinstance(e, LiquidInflow):
                state[i, 0] += e.speed * overlap
                while state[i, 0] >= self.spacing:
                    state[i, 0] -= self.spacing
                    # This layer entered state[i, 0] / speed ago: it has travelled that far.
                    layers.append(self._stream_layer(i, e, state[i, 0], int(state[i, 1])))
                    state[i, 1] += 1
            elif isinstance(e, GasInjector):
                state[i, 0] += e.rate * overlap
                while state[i, 0] >= 1.0:
                    state[i, 0] -= 1.0
                    bubbles.append(self._bubble(i, e, int(state[i, 1])))
                    state[i, 1] += 1
        if self.walled:  # the streams opening a wall flow in this step, or not (a copy, no read)
            speeds = [self.emitters[i].speed * (i in flowing) for i in self.walled]
            self.walled_speed.assign(np.array(speeds, np.float32))
        if layers:
            self._deliver(ctx, layers)
        if bubbles:
            self._release(ctx, bubbles)

    def _deliver(self, ctx, layers: list[tuple]):
        """Add this step's stream layers, each particle only where its cell is not crowded already:
        a nozzle under water or aimed at a wall delivers what the liquid lets in. Laid into cells
        already full, the new particles crowded the liquid (a run's liquid in 0.84-0.89 of its rest
        volume), an excess the pressure solve removes only through its volume correction. The cells'
        fill is splatted from the particles as they are now (not the last step's fields.liq_volume,
        which a resumed run has not yet made), one read of the layers' cells per step that lays any
        (docs/host_syncs.md)."""
        positions = np.concatenate([self._inside(ctx, layer[1]) for layer in layers])
        cells = np.floor((positions - np.asarray(ctx.grid.origin)) / self.dx).astype(np.int64)
        if self.dim == 2:
            cells[:, 2] = 0  # the splat's one layer of cells
        lo = cells.min(0)
        size = cells.max(0) - lo + 1
        box = wp.zeros(int(np.prod(size)), dtype=float, device=ctx.device)
        p = ctx.particles
        if p.count:
            ctx.launch(fill_box, p.count, [p.x, p.phase, p.active, p.vol0, ctx.geometry, wp.vec3i(*lo.tolist()),
                                           wp.vec3i(*size.tolist()), box])
        held = ctx.read_host(box).reshape(tuple(size))
        room = held[tuple((cells - lo).T)] <= CROWDED_FILL * self.dx**3
        start, delivered = 0, self.state.inflow
        for i, points, velocity, material, layer_volume in layers:
            keep = room[start:start + len(points)]
            start += len(points)
            delivered[i, 0] += layer_volume
            delivered[i, 1] += layer_volume * keep.sum() / len(points)
            if keep.any():
                self._add(ctx, points[keep], np.tile(velocity, (int(keep.sum()), 1)), material,
                          layer_volume / len(points))

    def _stream_layer(self, i, e: LiquidInflow, travelled: float, count: int) -> tuple:
        """Layer number `count` of emitter i, `travelled` past the nozzle: (emitter, positions,
        velocity, material, layer volume)."""
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
        return i, positions, direction * e.speed, e.material, layer_volume

    def _bubble(self, i, e: GasInjector, count: int) -> dict:
        """Bubble number `count` of emitter i: where, how big (its volume: a sphere's, in 2D the
        disk's through the slab) and how fast, its draws seeded by (scene seed, emitter, count)."""
        rng = np.random.default_rng([self.seed, i, count])
        radius = e.radius * math.exp(e.radius_spread * rng.standard_normal())
        offset = np.zeros(3)
        if e.spread > 0.0:  # uniform in the disk (ball) of radius `spread` around the centre
            u = rng.standard_normal(self.dim)
            offset[: self.dim] = u / np.linalg.norm(u) * e.spread * rng.random() ** (1.0 / self.dim)
        return self._fitted({"emitter": i, "material": e.material, "radius": radius, "rng": rng,
                             "centre": self._point(e.center) + offset, "velocity": self._vector(e.velocity)})

    def _ball_volume(self, radius: float) -> float:
        """A bubble's volume: a sphere's, in 2D the disk's through the one-cell slab."""
        return (4.0 / 3.0 * math.pi * radius**3) if self.dim == 3 else math.pi * radius**2 * self.dx

    def _fitted(self, b: dict) -> dict:
        """b with its ball inside the domain, and its volume: the radius at most half the domain's
        smallest extent (what [emitters].radius may be; a log-normal draw can exceed it), the centre
        moved in from each wall by the radius. A ball reaching past a wall was laid with its
        particles clamped onto the wall, the whole ball's gas in the part inside: gas at up to
        twice its density that its J does not know (scene 1045 of the run fuzz: a bubble 0.29 of the
        box, a third of it past the floor and a wall; liquid and gas then filled 1.13 of the box,
        1.11 with the ball inside, 1.00 with the open floor's sink too: effects/room.py)."""
        size = self.size
        b["radius"] = min(b["radius"], 0.5 * size.min())
        b["volume"] = self._ball_volume(b["radius"])
        b["centre"][: self.dim] = np.clip(b["centre"][: self.dim], b["radius"], size - b["radius"])
        return b

    def _release(self, ctx, bubbles: list[dict]):
        """Add this step's bubbles, vent those due in the open air, push the fluid out of the others
        (the module docstring). In a domain the liquid cannot leave that may be full (_may_fill) the
        host reads the sites first: it needs the room left to compress the gas or stop the run."""
        g, dev = ctx.grid, lambda a, t: wp.array(a, dtype=t, device=ctx.device)  # noqa: E731
        eps = 1e-4 * g.dx  # a centre outside the domain (a spread past a wall) counts as its edge cell's
        at = np.clip(np.array([b["centre"] for b in bubbles]), eps, np.asarray(g.domain_size) - eps)
        cells = np.floor((at - np.asarray(g.origin)) / g.dx).astype(np.int32)
        top, held, least_J = self._sites(ctx, dev(cells, wp.vec3i))
        factor, vent_on_device = 1.0, True
        for k, b in enumerate(bubbles):
            b["site"] = k
        if self.room is not None and self._may_fill(ctx, bubbles):
            in_air, measured = self._read_sites(ctx, top, held, least_J, cells)
            densities = {name: m.density for name, m in ctx.scene.materials.items()}
            vented = sum(densities[b["material"]] * b["volume"] for b, air in zip(bubbles, in_air) if air)
            if vented > 0.0:
                ctx.launch(book_vented, 1, [ctx.fields.vented_mass, wp.float64(vented)])
            bubbles = [b for b, air in zip(bubbles, in_air) if not air]
            if not bubbles:
                return
            factor, vent_on_device = self._room_factor(ctx, bubbles, measured), False
        subgrid = ctx.stage("subgrid_bubbles")
        first_new, owner, pushes = ctx.particles.count, [], []
        for b in bubbles:
            mat = self.materials.index(b["material"])
            if subgrid and b["radius"] < subgrid.settings.radius:
                # A sub-grid bubble is a sphere: in 2D the one holding the disk's volume.
                r = (3.0 * b["volume"] / (4.0 * math.pi)) ** (1.0 / 3.0)
                subgrid.add_bubbles(ctx, b["centre"][None], np.array([r]), b["velocity"][None], mat)
                owner.append(b["site"])
                continue
            # Compressed (factor < 1), the bubble fills a smaller ball: that is the room it takes.
            radius = b["radius"] * factor ** (1.0 / self.dim)
            pts = _lattice_in_ball(radius, self.spacing, self.dim, b["rng"])
            positions = np.tile(b["centre"], (len(pts), 1))
            positions[:, : self.dim] += pts
            self._add(ctx, positions, np.tile(b["velocity"], (len(pts), 1)), b["material"], b["volume"] / len(pts))
            owner += [b["site"]] * len(pts)
            pushes.append((b["centre"], radius**self.dim, b["site"]))
        p, cells_dev = ctx.particles, dev(cells, wp.vec3i)
        if vent_on_device:
            ctx.launch(vent_released, len(owner), [first_new, dev(np.array(owner, np.int32), wp.int32), cells_dev, top,
                                                   ctx.geometry, p.mass, p.active, ctx.fields.vented_mass])
        if pushes and factor == 1.0:  # compressed, there is no room to push into: the gas gave it
            make_room_for(ctx, pushes, first_new, cells_dev, top)
        if factor < 1.0:
            ctx.launch(compress_gas, p.count, [p.phase, p.active, factor, p.J])

    def _sites(self, ctx, cells):
        """The device's measures of the bubbles' sites and the fluid (injection_sites): no read."""
        p, n = ctx.particles, cells.shape[0]
        top = wp.full(n, NO_LIQUID, dtype=wp.int32, device=ctx.device)
        held = wp.zeros(3, dtype=wp.float64, device=ctx.device)
        least_J = wp.full(1, 1.0, dtype=float, device=ctx.device)
        if p.count:
            ctx.launch(injection_sites, p.count, [p.x, p.phase, p.active, p.vol0, p.J, ctx.geometry, cells, n, top,
                                                  held, least_J])
        return top, held, least_J

    def _read_sites(self, ctx, top, held, least_J, cells) -> tuple[np.ndarray, dict]:
        """(in the open air, per bubble; what the fluid holds now: "liquid" rest volume, "gas" volume V0 J
        and "gas_rest" V0, the gas's "least_J"), in one read."""
        n = len(cells)
        out = wp.zeros(n + 4, dtype=wp.float64, device=ctx.device)
        ctx.launch(pack_sites, n + 4, [top, held, least_J, out])
        result = ctx.read_host(out)
        tops = result[:n]
        up, sign = ctx.up
        in_air = sign * cells[:, up] > tops if up >= 0 else tops == NO_LIQUID
        names = ("liquid", "gas", "gas_rest", "least_J")
        return in_air, {k: float(v) for k, v in zip(names, result[n:])}

    def _may_fill(self, ctx, bubbles: list[dict]) -> bool:
        """Whether the liquid, the gas and this step's bubbles may exceed the room, by bounds the host
        knows without a read: the liquid ever added at its rest volume (closed: none left), the gas
        ever added (Simulation.add_particles' ledger, which conversions only raise, and entrained air)
        at the most the last step's largest gauge pressure of the resolved gas lets it expand. Sub-grid
        bubbles take their cell's pressure, which that measure does not see: one in suction could
        expand more; bounding them by their 0.1-atmosphere floor (10 times) read the room on most
        steps of a splash with 5% gas, so this gate trusts the resolved gas's measure. Only where the
        bound may exceed the room is the room read (docs/host_syncs.md)."""
        mats = list(ctx.scene.materials.values())
        ledger, p_atm = ctx.ledger, ctx.scene.domain.ambient_pressure
        gas_stage, entrainment = ctx.stage("gas"), ctx.stage("entrainment")
        liquid = ledger.liquid_added / min((m.density for m in mats if m.kind == "liquid"), default=1.0)
        gas_mass = ledger.gas_added + (entrainment.state.gas_mass if entrainment else 0.0)
        gauge = gas_stage.state.gauge if gas_stage else math.nan
        if math.isnan(gauge):  # the first step: the gas is as the shapes seeded it
            gauge = max((abs(s.pressure or 0.0) for s in ctx.scene.shapes), default=0.0)
        if (gas_stage.state.cavity if gas_stage else 1.0) != 0.0:
            return True  # a near vacuum's gas may expand without bound
        J = p_atm / max(p_atm - gauge, 0.1 * p_atm)
        gas = gas_mass / min(m.density for m in mats if m.is_gas) * J
        return liquid + gas + sum(b["volume"] for b in bubbles) > self.room

    def _room_factor(self, ctx, bubbles: list[dict], held: dict) -> float:
        """1, or in a domain the liquid cannot leave that has no room for this step's bubbles at
        ambient pressure, the factor every gas particle's J takes (new bubbles included) so that the
        gas fills exactly the room the liquid leaves it: a closed box of water takes gas in only by
        compressing the gas it holds (Boyle, p V = const, for isothermal gas; the solve alone did
        not: gas J 0.96 where Boyle says 0.86, 1.11 of its room). GasRoomError where it is
        impossible: no room at all, an incompressible gas, or a pressure past scene/capacity.py's
        MAX_INJECTED_GAUGE (or the gas shapes' bound, scene/limits.py's max_gauge_pressure, where lower)."""
        new = sum(b["volume"] for b in bubbles)
        if self.room is None or held["liquid"] + held["gas"] + new <= self.room:
            return 1.0
        space, gas = self.room - held["liquid"], held["gas"] + new
        mats = [m for m in ctx.scene.materials.values() if m.is_gas]
        key = f"[emitters.{bubbles[0]['emitter']}]"
        if space <= 0.0 or any(m.eos == "incompressible" for m in mats):
            why = ("the liquid fills all of it" if space <= 0.0
                   else "the gas is incompressible (eos), so none of it can make room")
        else:
            factor = space / gas
            gamma = max(m.gamma if m.eos == "adiabatic" else 1.0 for m in mats)
            p_atm = ctx.scene.domain.ambient_pressure
            gauge = p_atm * (min(held["least_J"], 1.0) * factor) ** -gamma - p_atm  # the most compressed gas's
            bound = min(float(max_gauge_pressure(ctx.scene.materials)), MAX_INJECTED_GAUGE * p_atm)
            if gauge <= bound:
                return factor
            why = (f"the gas, {gas / space:.3g} times its room, would be at {gauge:.4g} Pa gauge, above the "
                   f"{bound:.4g} Pa that compressed gas is held to here ({MAX_INJECTED_GAUGE:g} x "
                   f"[domain].ambient_pressure, beyond which the solve does not keep it at Boyle's pressure)")
        stop = f", or {key}.stop <= {ctx.time:.4g} s" if ctx.time > self.emitters[bubbles[0]["emitter"]].start else ""
        raise GasRoomError(
            f"t = {ctx.time:.6g} s: {key} (gas_injector) releases gas into a domain the liquid cannot leave "
            f"and has no room for it: {why}. Fixes: an open wall the liquid can leave through (not the top), "
            f"less liquid, a lower {key}.rate or {key}.radius{stop}")

    def _inside(self, ctx, positions):
        eps = 1e-4 * self.dx
        return np.clip(positions, eps, np.array(ctx.grid.domain_size) - eps)  # like the transfers' clamp

    def _add(self, ctx, positions, velocities, material: str, volume_each: float):
        positions = self._inside(ctx, positions)  # never outside
        n = len(positions)
        ctx.add_particles(positions.astype(np.float32), velocities.astype(np.float32),
                          np.full(n, self.materials.index(material), np.int32), np.full(n, volume_each))
