"""The simulation: particle and grid state on one Warp device, and the step as a list of stages.

One step (Zhang et al. 2017 incompressible MPM, APIC on a MAC grid):

    p2g       particles -> face momenta and masses, cell mass/volume, particle count per cell
    grid      u* = p/m + dt g, cell types, walls, face densities, pressure system
    pressure  PCG solve, u = u* - dt/rho grad p
    extend    extrapolate u past the liquid, enforce walls
    g2p       faces -> particle velocity and APIC matrix, J, advection clamped to the domain

The time step follows the CFL limit and lands exactly on frame times. Inside a step the host reads
only scalars (CG reductions, counters, the maximum particle speed).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import warp as wp

from . import grid_kernels as gk
from .grid import MacGrid
from .pressure import PressureSolver, SolveInfo
from .seeding import seed_particles
from .timing import StageTimer
from .transfer_kernels import g2p_advect, p2g

EXTRAPOLATION_LAYERS = 2  # the B-spline stencil reaches 1.5 cells beyond a particle's cell


@dataclass
class SolverStats:
    steps: int = 0
    cg_iterations: int = 0
    cg_max_iterations: int = 0
    cg_solves: int = 0
    cg_unconverged: int = 0
    cg_worst_residual: float = 0.0
    dt_history: list[float] = field(default_factory=list)

    def record(self, info: SolveInfo):
        self.cg_solves += 1
        self.cg_iterations += info.iterations
        self.cg_max_iterations = max(self.cg_max_iterations, info.iterations)
        self.cg_worst_residual = max(self.cg_worst_residual, info.residual)
        self.cg_unconverged += 0 if info.converged else 1


class Simulation:
    """Runs a validated :class:`~warp_mpm_bubbles.scene.Scene` on a Warp device ("cpu", "cuda:0")."""

    def __init__(self, scene, device=None):
        self.scene = scene.validate()
        self.device = wp.get_device(device)
        self.grid = MacGrid.from_domain(scene.domain)
        self.timer = StageTimer(self.device)
        self.stats = SolverStats()
        self.time = 0.0
        self.frame = 0
        self._init_particles()
        self._init_grid()
        self._max_speed = float(np.linalg.norm(self.particles_numpy()["velocities"], axis=1).max(initial=0.0))

    # ----------------------------------------------------------------------------------- state
    def _init_particles(self):
        seeds = seed_particles(self.scene)
        densities = np.array([m.density for m in self.scene.materials.values()], dtype=np.float32)
        n = len(seeds["positions"])
        self.num_particles = n
        self.ids = np.arange(n, dtype=np.int64)  # stable: particles are never reordered
        self.material = seeds["material"].astype(np.int32)
        arr = lambda a, dtype: wp.array(a, dtype=dtype, device=self.device)  # noqa: E731
        self.x = arr(seeds["positions"], wp.vec3)
        self.v = arr(seeds["velocities"], wp.vec3)
        self.C = wp.zeros(n, dtype=wp.mat33, device=self.device)
        self.vol0 = arr(seeds["volume"], float)
        self.mass = arr(densities[self.material] * seeds["volume"], float)
        self.J = arr(np.ones(n, dtype=np.float32), float)

    def _init_grid(self):
        g, dev = self.grid, self.device
        faces = lambda dtype=float: [wp.zeros(g.face_shape(a), dtype=dtype, device=dev) for a in range(3)]  # noqa: E731
        cells = lambda dtype=float: wp.zeros(g.cells, dtype=dtype, device=dev)  # noqa: E731
        self.mom, self.face_mass, self.vel, self.inv_rho = faces(), faces(), faces(), faces()
        self.vel_tmp, self.valid, self.valid_tmp = faces(), faces(wp.int32), faces(wp.int32)
        self.cell_mass, self.cell_volume = cells(), cells()
        self.cell_count, self.types = cells(wp.int32), cells(wp.int32)
        self.pressure, self.diag, self.rhs = cells(), cells(), cells()
        self.counters = wp.zeros(2, dtype=wp.int32, device=dev)
        self.max_speed = wp.zeros(1, dtype=float, device=dev)
        self.solver = PressureSolver(g.cells, g.dim, g.dx, dev)
        walls = self.scene.domain.wall_types
        self._wall_lo = wp.vec3i(walls[0], walls[2], walls[4])
        self._wall_hi = wp.vec3i(walls[1], walls[3], walls[5])
        self._origin = wp.vec3(*g.origin)
        self._domain_hi = wp.vec3(*g.domain_size)
        gravity = tuple(self.scene.domain.gravity) + (0.0,) * (3 - g.dim)
        self._gravity = tuple(float(a) for a in gravity)

    def _launch(self, kernel, dim, inputs):
        wp.launch(kernel, dim=dim, inputs=inputs, device=self.device)

    # ------------------------------------------------------------------------------ the step
    def _particles_to_grid(self):
        g = self.grid
        for arr in (*self.mom, *self.face_mass, self.cell_mass, self.cell_volume, self.cell_count):
            arr.zero_()
        self._launch(
            p2g,
            self.num_particles,
            [self.x, self.v, self.C, self.mass, self.vol0, self._origin, g.dx, g.dim,
             *self.mom, *self.face_mass, self.cell_mass, self.cell_volume, self.cell_count],
        )

    def step(self, dt: float):
        g = self.grid
        settings = self.scene.solver
        with self.timer("p2g"):
            self._particles_to_grid()
        with self.timer("grid"):
            for a in g.axes:
                self._launch(gk.momentum_to_velocity, g.face_shape(a),
                             [self.mom[a], self.face_mass[a], self._gravity[a], dt, self.vel[a]])
            self._launch(gk.classify_cells, g.cells,
                         [self.cell_count, wp.vec3i(*g.ghost), wp.vec3i(*g.interior),
                          self._wall_lo, self._wall_hi, self.types])
            for a in g.axes:
                self._launch(gk.zero_solid_faces, g.face_shape(a), [self.types, a, self.vel[a]])
                self._launch(gk.face_inverse_density, g.face_shape(a),
                             [self.types, self.cell_mass, self.cell_volume, a, 1.0 / g.dx**3, self.inv_rho[a]])
            self.counters.zero_()
            self._launch(gk.pressure_diagonal_and_rhs, g.cells,
                         [self.types, *self.inv_rho, *self.vel, self.cell_volume, g.dx, dt, g.dim,
                          settings.volume_correction, self.diag, self.rhs, self.counters])
        with self.timer("pressure"):
            n_fluid, n_dirichlet = (int(c) for c in self.counters.numpy())
            info = self.solver.solve(
                (self.types, self.diag, self.inv_rho), self.rhs, self.pressure,
                tol=settings.cg_tolerance, max_iter=settings.cg_max_iterations,
                jacobi=settings.preconditioner == "jacobi", singular=n_dirichlet == 0, n_fluid=n_fluid,
            )
            self.stats.record(info)
            for a in g.axes:
                self._launch(gk.subtract_pressure_gradient, g.face_shape(a),
                             [self.types, self.pressure, self.inv_rho[a], a, g.dx, dt, self.vel[a], self.valid[a]])
        with self.timer("extend"):
            for a in g.axes:
                for _ in range(EXTRAPOLATION_LAYERS):
                    self._launch(gk.extrapolate_velocity, g.face_shape(a),
                                 [self.vel[a], self.valid[a], g.dim, self.vel_tmp[a], self.valid_tmp[a]])
                    self.vel[a], self.vel_tmp[a] = self.vel_tmp[a], self.vel[a]
                    self.valid[a], self.valid_tmp[a] = self.valid_tmp[a], self.valid[a]
                self._launch(gk.enforce_walls, g.face_shape(a), [self.types, a, self.vel[a]])
        with self.timer("g2p"):
            self.max_speed.zero_()
            self._launch(g2p_advect, self.num_particles,
                         [*self.vel, self._origin, g.dx, g.dim, dt, self._domain_hi,
                          self.x, self.v, self.C, self.J, self.max_speed])
            self._max_speed = float(self.max_speed.numpy()[0])
        self.stats.steps += 1
        self.stats.dt_history.append(dt)

    # ---------------------------------------------------------------------------- time steps
    def stable_dt(self) -> float:
        """CFL limit, with sqrt(|g| dx) added to the speed so a fluid at rest still takes safe steps."""
        s = self.scene.solver
        g_mag = math.sqrt(sum(a * a for a in self._gravity))
        speed = self._max_speed + math.sqrt(g_mag * self.grid.dx)
        dt = s.cfl * self.grid.dx / speed if speed > 0.0 else math.inf
        if s.max_dt is not None:
            dt = min(dt, s.max_dt)
        return dt

    def advance_to(self, t_end: float):
        """Substep to exactly t_end, splitting what remains into equal steps under the CFL limit."""
        while self.time < t_end:
            remaining = t_end - self.time
            n = max(1, math.ceil(remaining / self.stable_dt() - 1e-9))
            dt = remaining / n
            self.step(dt)
            self.time = t_end if n == 1 else self.time + dt

    @property
    def frame_dt(self) -> float:
        return 1.0 / self.scene.output.fps

    def advance_frame(self):
        self.frame += 1
        self.advance_to(self.frame * self.frame_dt)

    # ------------------------------------------------------------------------------ read-out
    def particles_numpy(self) -> dict[str, np.ndarray]:
        """Copies of the particle state (on the CPU device .numpy() is a view that the next step changes)."""
        return {
            "positions": self.x.numpy().copy(),
            "velocities": self.v.numpy().copy(),
            "ids": self.ids.copy(),
            "material": self.material.copy(),
            "J": self.J.numpy().copy(),
        }

    def pressure_numpy(self) -> np.ndarray:
        """Gauge pressure (Pa) on interior cells from the last step; non-fluid cells read 0."""
        return self.pressure.numpy()[self.grid.interior_slice()]

    def cell_types_numpy(self) -> np.ndarray:
        return self.types.numpy()[self.grid.interior_slice()]

    def liquid_volume(self) -> float:
        """Volume the particles fill: sum over cells of min(phi, 1) dx^3, phi the rest-volume fraction.

        Clustering particles (the drift that incompressible MPM suffers) raises phi above 1 in some
        cells and lowers this number. Re-splats the current particles; the grid is rebuilt each step.
        """
        self._particles_to_grid()
        cell_vol = self.grid.dx ** 3
        phi = self.cell_volume.numpy() / cell_vol
        return float(np.minimum(phi, 1.0).sum() * cell_vol)
