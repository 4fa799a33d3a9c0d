"""Emitters: a pouring stream of liquid and an air stone releasing gas bubbles.

Both work on the host at the start of a step and append particles (Simulation.add_particles).
Their progress (stream length owed, bubbles owed, how many emitted) lives in sim.host_state, so a
resumed run emits exactly what an uninterrupted one does; every random draw is seeded by
(scene seed, emitter, count), never by a global generator.

Mass is exact by construction: a stream layer's particles share the layer's volume
(area x spacing), and a bubble's particles share its sphere's (disk's) volume.
"""

from __future__ import annotations

import math

import numpy as np

from ..core.stage import Stage
from ..scene.effects import GasInjector, LiquidInflow


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
                    self._bubble(sim, i, e, int(state[i, 1]))
                    state[i, 1] += 1

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

    def _bubble(self, sim, i, e: GasInjector, count: int):
        rng = np.random.default_rng([self.seed, i, count])
        radius = e.radius * math.exp(e.radius_spread * rng.standard_normal())
        offset = np.zeros(3)
        if e.spread > 0.0:  # uniform in the disk (ball) of radius `spread` around the centre
            u = rng.standard_normal(self.dim)
            offset[: self.dim] = u / np.linalg.norm(u) * e.spread * rng.random() ** (1.0 / self.dim)
        centre = self._point(e.center) + offset
        velocity = self._vector(e.velocity)
        bubbles = sim.stage("subgrid_bubbles")
        if bubbles and radius < bubbles.settings.radius:
            bubbles.add_bubbles(sim, centre[None], np.array([radius]), velocity[None],
                                    self.materials.index(e.material))
            return
        pts = _lattice_in_ball(radius, self.spacing, self.dim, rng)
        positions = np.tile(centre, (len(pts), 1))
        positions[:, : self.dim] += pts
        volume = (4.0 / 3.0 * math.pi * radius**3) if self.dim == 3 else math.pi * radius**2 * self.dx
        self._add(sim, positions, np.tile(velocity, (len(pts), 1)), e.material, volume / len(pts))

    def _add(self, sim, positions, velocities, material: str, volume_each: float):
        size = np.array(sim.grid.domain_size)
        eps = 1e-4 * self.dx
        positions = np.clip(positions, eps, size - eps)  # like the transfers' clamp: never outside
        n = len(positions)
        sim.add_particles(positions.astype(np.float32), velocities.astype(np.float32),
                          np.full(n, self.materials.index(material), np.int32), np.full(n, volume_each))
