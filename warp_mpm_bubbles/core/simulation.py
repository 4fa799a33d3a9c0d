"""The simulation: particle and grid state on one Warp device, and the step as a list of stages.

One step (Zhang et al. 2017 incompressible MPM, APIC on a MAC grid):

    p2g       particles -> face momenta and masses, cell mass/volume, particle count per cell
              (+ gas mass, volume, pressure and compressibility per cell when the scene has gas)
    grid      u* = p/m + dt g, cell types (+ which are gas), walls, face densities, the system
    viscosity (only with viscosity > 0) explicit diffusion of u*
    tension   (only with surface_tension > 0) the Laplace jump on the liquid's surface faces
    pressure  multigrid-PCG solve of the one two-phase system, u = u* - dt/rho grad p
    extend    extrapolate u past the liquid, enforce walls (sharp interface with gas: the liquid's own
              field is extrapolated across the interface; the gas keeps the shared one)
    g2p       faces -> particle velocity and APIC matrix, J, advection clamped to the domain
              (+ with tension and gas: gas films thinner than a cell retract into their bubble)
    vent      (gas only) gas reaching open air leaves the simulation, its mass booked

The time step follows the CFL limit and lands exactly on frame times. Inside a step the host reads
only scalars (CG reductions, counters, the maximum particle speed).
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field

import numpy as np
import warp as wp

from . import grid_kernels as gk
from ..physics import tension as fk
from .grid import INTERFACE_SHARP, PHASE_FOAM, PHASE_GAS, PHASE_LIQUID, PHASE_SUBGRID, MacGrid
from .pressure import PressureSolver, PressureSystem, SolveInfo
from ..scene.model import INTERFACES
from .seeding import seed_particles
from .timing import StageTimer
from .transfer_kernels import (
    GAS_ADIABATIC, GAS_ISOTHERMAL, g2p_advect, gas_volume_rate, p2g, p2g_gas, update_gas_J,
)

EXTRAPOLATION_LAYERS = 2  # the B-spline stencil reaches 1.5 cells beyond a particle's cell
LEVEL_SET_SMOOTHING = 2  # binomial passes before the curvature (tests/test_tension.py measures it)
GAS_LAW_CODES = {"isothermal": GAS_ISOTHERMAL, "adiabatic": GAS_ADIABATIC}  # else 0: fixed density
# The per-particle arrays every scene has (effects add theirs with Simulation.add_particle_field).
PARTICLE_FIELDS = {"x": wp.vec3, "v": wp.vec3, "C": wp.mat33, "mass": float, "vol0": float, "J": float,
                   "phase": wp.int32, "active": wp.int32, "material": wp.int32, "gas_law": wp.int32,
                   "gas_gamma": float, "ids": wp.int64}
COMPACT_RETIRED = 0.25  # compact the arrays at a frame's end once this share of the particles is retired


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


class SimulationError(RuntimeError):
    """The simulation cannot go on; the message names the step, the stage and the likely cause."""


class Simulation:
    """Runs a validated :class:`~warp_mpm_bubbles.scene.Scene` on a Warp device ("cpu", "cuda:0")."""

    def __init__(self, scene, device=None):
        self.scene = scene.validate()
        self.effects = self.scene.effect_names  # the optional stages that run; no others do
        self.device = wp.get_device(device)
        self.launches: Counter[str] = Counter()  # kernel launches by name: proof of what ran
        self.grid = MacGrid.from_domain(scene.domain)
        self.timer = StageTimer(self.device)
        self.stats = SolverStats()
        self.time = 0.0
        self.frame = 0
        self.colliders = None
        if "colliders" in self.effects:
            from ..effects.colliders import ColliderStage

            self.colliders = ColliderStage(self)
        self._init_particles()
        self._init_grid()

    # ----------------------------------------------------------------------------------- state
    def _init_particles(self):
        seeds = seed_particles(self.scene)
        self.num_particles = 0  # particles in use; the arrays hold capacity >= this many
        self.particle_fields = dict(PARTICLE_FIELDS)
        for name, dtype in self.particle_fields.items():
            setattr(self, name, wp.zeros(0, dtype=dtype, device=self.device))
        self.vented_mass = wp.zeros(1, dtype=wp.float64, device=self.device)
        self.host_state: dict[str, np.ndarray] = {}  # small per-effect state that checkpoints keep
        self.host_state["next_id"] = np.zeros(1, np.int64)
        if self.colliders:  # no particle starts inside a solid
            keep = ~self.colliders.inside(self, seeds["positions"])
            seeds = {name: values[keep] for name, values in seeds.items()}
        self.add_particles(seeds["positions"], seeds["velocities"], seeds["material"], seeds["volume"],
                           seeds["pressure"])

    def add_particles(self, positions, velocities, material, volume, gauge_pressure=None) -> slice:
        """Append particles (numpy arrays; material: indices into scene.materials; volume: current,
        m^3) and return their index range. Arrays grow geometrically; each particle gets the next id,
        which it keeps for good (a renderer's motion blur follows it) while compaction moves it."""
        n = len(positions)
        materials = list(self.scene.materials.values())
        per_material = lambda f, dtype: np.array([f(m) for m in materials], dtype=dtype)[material]  # noqa: E731
        # Gas at a gauge pressure p is compressed to J0 of its rest volume.
        p_atm = self.scene.domain.ambient_pressure
        gauge = np.zeros(n) if gauge_pressure is None else np.asarray(gauge_pressure, np.float64)
        gamma = per_material(lambda m: m.gamma if m.eos == "adiabatic" else 1.0, np.float64)
        J0 = (p_atm / (p_atm + gauge)) ** (1.0 / gamma)
        rest_volume = np.asarray(volume, np.float64) / J0
        values = {
            "x": positions, "v": velocities, "C": np.zeros((n, 3, 3)),
            "mass": per_material(lambda m: m.density, np.float64) * rest_volume, "vol0": rest_volume, "J": J0,
            "phase": per_material(lambda m: PHASE_GAS if m.is_gas else PHASE_LIQUID, np.int32),
            "active": np.ones(n, np.int32), "material": np.asarray(material, np.int32),
            "gas_law": per_material(lambda m: GAS_LAW_CODES.get(m.eos, 0), np.int32),
            "gas_gamma": per_material(lambda m: m.gamma, np.float32),
            "ids": self.host_state["next_id"][0] + np.arange(n, dtype=np.int64),
        }
        self.host_state["next_id"] = self.host_state["next_id"] + n
        start = self.num_particles
        self._reserve(start + n)
        for name, dtype in self.particle_fields.items():
            if name in values and n:
                src = wp.array(np.asarray(values[name]), dtype=dtype, device=self.device)
                wp.copy(getattr(self, name), src, dest_offset=start, count=n)
        self.num_particles = start + n
        if n:
            self._max_speed = max(getattr(self, "_max_speed", 0.0),
                                  float(np.linalg.norm(np.asarray(velocities), axis=1).max()))
        return slice(start, start + n)

    def add_particle_field(self, name: str, dtype):
        """A per-particle array for an effect (zero for existing particles); grows and checkpoints with the rest."""
        self.particle_fields[name] = dtype
        setattr(self, name, wp.zeros(len(self.x), dtype=dtype, device=self.device))

    def _reserve(self, n: int):
        capacity = len(self.x)
        if n <= capacity:
            return
        capacity = n if capacity == 0 else max(n, 2 * capacity)
        for name, dtype in self.particle_fields.items():
            old = getattr(self, name)
            new = wp.zeros(capacity, dtype=dtype, device=self.device)
            if self.num_particles:
                wp.copy(new, old, count=self.num_particles)
            setattr(self, name, new)

    @property
    def has_gas(self) -> bool:
        return "gas" in self.effects

    def _init_grid(self):
        g, dev = self.grid, self.device
        faces = lambda dtype=float: [wp.zeros(g.face_shape(a), dtype=dtype, device=dev) for a in range(3)]  # noqa: E731
        cells = lambda dtype=float: wp.zeros(g.cells, dtype=dtype, device=dev)  # noqa: E731
        self.mom, self.face_mass, self.vel, self.inv_rho = faces(), faces(), faces(), faces()
        self.vel_tmp, self.valid, self.valid_tmp = faces(), faces(wp.int32), faces(wp.int32)
        self.liq_mass, self.liq_volume = cells(), cells()
        self.cell_count, self.types, self.phase_cells = cells(wp.int32), cells(wp.int32), cells(wp.int32)
        # Gas state per cell; a liquid-only scene gets one-cell placeholders that no kernel reads.
        gas_cells = cells if self.has_gas else (lambda dtype=float: wp.zeros((1, 1, 1), dtype=dtype, device=dev))
        self.gas_mass, self.gas_volume, self.gas_pv, self.gas_kv = gas_cells(), gas_cells(), gas_cells(), gas_cells()
        self.gas_count = gas_cells(wp.int32)
        self.target_div, self.gas_rate = gas_cells(), gas_cells()
        self.pressure, self.diag, self.rhs = cells(), cells(), cells()
        self.extra_diag = cells()  # kappa/dt^2 of gas cells
        # Sharp interface, liquid_velocity = "own": self.vel is the liquid's own field, and the gas
        # reads the shared projected field, gas_vel.
        own = self.has_gas and self.scene.solver.interface == "sharp" and self.scene.solver.liquid_velocity == "own"
        self.gas_vel, self.gas_valid = (faces(), faces(wp.int32)) if own else (None, None)
        self.counters = wp.zeros(2, dtype=wp.int32, device=dev)
        self.max_speed = wp.zeros(1, dtype=float, device=dev)
        self.nonfinite = wp.zeros(1, dtype=wp.int32, device=dev)  # particles p2g refused this step
        self.solver = PressureSolver(g.cells, g.dim, g.dx, dev)
        walls = self.scene.domain.wall_types
        self._wall_lo = wp.vec3i(walls[0], walls[2], walls[4])
        self._wall_hi = wp.vec3i(walls[1], walls[3], walls[5])
        self._origin = wp.vec3(*g.origin)
        self._domain_hi = wp.vec3(*g.domain_size)
        gravity = tuple(self.scene.domain.gravity) + (0.0,) * (3 - g.dim)
        self._gravity = tuple(float(a) for a in gravity)
        self._interface = INTERFACES.index(self.scene.solver.interface)
        self._init_effects()

    def _init_effects(self):
        """Settings and arrays of the optional stages; a stage the scene does not ask for gets none
        (its module is not even imported, so its kernels are never compiled)."""
        g, dev = self.grid, self.device
        self.foam = self.subgrid = self.entrainment = self.emitters = None
        if "emitters" in self.effects:
            from ..effects.emitters import EmitterStage

            self.emitters = EmitterStage(self)
        if "subgrid_bubbles" in self.effects:
            from ..effects.subgrid import SubgridBubbleStage

            self.subgrid = SubgridBubbleStage(self, self.scene.effects["subgrid_bubbles"])
        if "entrainment" in self.effects:
            from ..effects.entrainment import EntrainmentStage

            self.entrainment = EntrainmentStage(self, self.scene.effects["entrainment"])
        if "foam" in self.effects:
            from ..effects.foam import FoamStage

            self.foam = FoamStage(self, self.scene.effects["foam"])
        materials = list(self.scene.materials.values())
        liquids = [m for m in materials if m.kind == "liquid"]
        self.sigma = max((m.surface_tension for m in liquids), default=0.0)  # tension runs only if > 0
        self.rho_liquid = max((m.density for m in liquids), default=0.0)
        # Gas films thinner than a cell feel no Laplace jump (it acts on cell faces); with the sharp
        # interface they retract into their bubble, at the Taylor-Culick speed of a one-cell film.
        self.retract_films = (self.sigma > 0.0 and self.has_gas and self.scene.solver.interface == "sharp"
                              and self.scene.solver.gas_films == "retract")
        self.film_speed = math.sqrt(2.0 * self.sigma / (self.rho_liquid * g.dx)) if self.retract_films else 0.0
        if self.sigma > 0.0:
            self.curvature, self.level, self.level_tmp = (wp.zeros(g.cells, dtype=float, device=dev) for _ in range(3))
        # Kinematic viscosity per phase (the largest of its materials); viscosity runs only if > 0.
        nu = lambda ms: max((m.viscosity / m.density for m in ms), default=0.0)  # noqa: E731
        self.nu_liquid, self.nu_gas = nu(liquids), nu([m for m in materials if m.is_gas])
        self.nu_max = max(self.nu_liquid, self.nu_gas)
        # "Up" for venting: against the strongest gravity component (axis -1: no gravity, no up).
        g_abs = [abs(a) for a in self._gravity[: g.dim]]
        up_axis = int(np.argmax(g_abs)) if max(g_abs) > 0.0 else -1
        self._up = (up_axis, 1 if up_axis < 0 or self._gravity[up_axis] < 0.0 else -1)
        column = list(g.cells)
        if up_axis >= 0:
            column[up_axis] = 1
        self.ceiling = wp.zeros(tuple(column) if self.has_gas else (1, 1, 1), dtype=wp.int32, device=dev)

    def _launch(self, kernel, dim, inputs):
        self.launches[kernel.key] += 1
        wp.launch(kernel, dim=dim, inputs=inputs, device=self.device)

    # ------------------------------------------------------------------------------ the step
    def _particles_to_grid(self):
        g = self.grid
        for arr in (*self.mom, *self.face_mass, self.liq_mass, self.liq_volume, self.cell_count, self.nonfinite):
            arr.zero_()
        self._launch(
            p2g,
            self.num_particles,
            [self.x, self.v, self.C, self.mass, self.vol0, self.phase, self.active, self._origin, g.dx, g.dim,
             self._domain_hi, *self.mom, *self.face_mass, self.liq_mass, self.liq_volume, self.cell_count,
             self.nonfinite],
        )
        if self.has_gas:
            for arr in (self.gas_mass, self.gas_volume, self.gas_pv, self.gas_kv, self.gas_count):
                arr.zero_()
            self._launch(
                p2g_gas,
                self.num_particles,
                [self.x, self.mass, self.vol0, self.J, self.phase, self.active, self.gas_law, self.gas_gamma,
                 self.scene.domain.ambient_pressure, self._origin, g.dx, g.dim, self._domain_hi,
                 self.gas_mass, self.gas_volume, self.gas_pv, self.gas_kv, self.gas_count],
            )

    def step(self, dt: float):
        g = self.grid
        settings = self.scene.solver
        two_phase = int(self.has_gas)
        if self.emitters:
            with self.timer("emitters"):
                self.emitters.emit(self, self.time, dt)
        with self.timer("p2g"):
            self._particles_to_grid()
        with self.timer("grid"):
            for a in g.axes:
                self._launch(gk.momentum_to_velocity, g.face_shape(a),
                             [self.mom[a], self.face_mass[a], self._gravity[a], dt, self.vel[a]])
            if self.subgrid:
                self.subgrid.to_grid(self, dt)  # the bubbles' drag reaction on the liquid
            self._launch(gk.classify_cells, g.cells,
                         [self.cell_count, self.liq_volume, self.gas_volume, two_phase, 1.0 / g.dx**3,
                          wp.vec3i(*g.ghost), wp.vec3i(*g.interior), self._wall_lo, self._wall_hi, self.types])
            if self.colliders:  # (timed with the grid stage; push-out has its own line)
                self.colliders.mark_cells(self, self.time)
            if self.has_gas:
                self._launch(gk.classify_phases, g.cells,
                             [self.types, self.gas_count, self.liq_volume, self.gas_volume, self._interface,
                              self.phase_cells])
                up_axis, up_sign = self._up
                if up_axis >= 0:  # where the open air starts, for venting, foam and sub-grid bubbles
                    self.ceiling.fill_(-1)
                    self._launch(gk.liquid_ceiling, g.cells, [self.types, self.phase_cells, up_axis, up_sign,
                                                              self.ceiling])
            for a in g.axes:
                self._launch(gk.zero_solid_faces, g.face_shape(a), [self.types, a, self.vel[a]])
                self._launch(gk.face_inverse_density, g.face_shape(a),
                             [self.types, self.phase_cells, self.liq_mass, self.liq_volume, self.gas_mass,
                              self.gas_volume, two_phase, self._interface, a, 1.0 / g.dx**3, self.inv_rho[a]])
            if self.colliders:
                self.colliders.set_face_velocities(self, self.time)
        if self.nu_max > 0.0:
            with self.timer("viscosity"):
                for a in g.axes:
                    self._launch(fk.diffuse_velocity, g.face_shape(a),
                                 [self.types, self.phase_cells, self.inv_rho[a], self.vel[a], self.nu_liquid,
                                  self.nu_gas, a, g.dim, g.dx, dt, self.vel_tmp[a]])
                    self.vel[a], self.vel_tmp[a] = self.vel_tmp[a], self.vel[a]
        if self.sigma > 0.0:
            with self.timer("tension"):
                level, smoothed = self.level, self.level_tmp
                self._launch(fk.liquid_level_set, g.cells, [self.liq_volume, 1.0 / g.dx**3, level])
                for _ in range(LEVEL_SET_SMOOTHING):
                    self._launch(fk.smooth_level_set, g.cells, [self.types, level, g.dim, smoothed])
                    level, smoothed = smoothed, level
                self._launch(fk.surface_curvature, g.cells, [self.types, level, g.dx, g.dim, self.curvature])
                for a in g.axes:
                    self._launch(fk.apply_surface_tension, g.face_shape(a),
                                 [self.types, self.phase_cells, level, self.curvature, self.inv_rho[a],
                                  self.sigma, a, g.dx, dt, self.vel[a]])
        with self.timer("grid"):
            self.counters.zero_()
            self._launch(gk.pressure_diagonal_and_rhs, g.cells,
                         [self.types, self.phase_cells, *self.inv_rho, *self.vel, self.liq_volume, self.gas_volume,
                          self.gas_pv, self.gas_kv, two_phase, self._interface, g.dx, dt, g.dim,
                          settings.volume_correction,
                          self.diag, self.extra_diag, self.rhs, self.target_div, self.counters])
        with self.timer("pressure"):
            n_fluid, n_pinned = (int(c) for c in self.counters.numpy())
            bad = int(self.nonfinite.numpy()[0])
            if bad:
                raise SimulationError(
                    f"step {self.stats.steps + 1} (t = {self.time:.6g} s): {bad} particles entered p2g with a "
                    f"non-finite position or velocity. Likely cause: the previous step diverged (a time "
                    f"step too large for the scene: lower [solver].cfl or set [solver].max_dt) or NaN/Inf "
                    f"in the initial state.")
            info = self.solver.solve(
                PressureSystem(self.types, tuple(self.inv_rho), self.diag, self.extra_diag), self.rhs, self.pressure,
                tol=settings.cg_tolerance, max_iter=settings.cg_max_iterations,
                preconditioner=settings.preconditioner, singular=n_pinned == 0, n_fluid=n_fluid,
            )
            self.stats.record(info)
            for a in g.axes:
                self._launch(gk.subtract_pressure_gradient, g.face_shape(a),
                             [self.types, self.pressure, self.inv_rho[a], a, g.dx, dt, self.vel[a], self.valid[a]])
        with self.timer("extend"):
            if self.gas_vel:  # the gas reads the shared field; the liquid its own, extended into the gas
                for a in g.axes:
                    wp.copy(self.gas_vel[a], self.vel[a])
                    wp.copy(self.gas_valid[a], self.valid[a])
                    self._launch(gk.keep_phase_faces, g.face_shape(a),
                                 [self.types, self.phase_cells, a, PHASE_LIQUID, self.gas_valid[a], self.valid[a]])
                self._extend(self.gas_vel, self.gas_valid)
            self._extend(self.vel, self.valid)
        with self.timer("g2p"):
            # Sharp interface: the gas takes its cells' volume change (before g2p moves it: the weights
            # p2g_gas used). The baseline treats a cell with any gas as all gas, so there the
            # published rule stays: J follows the interpolated divergence.
            gas_J_from_cells = int(self.has_gas and self._interface == INTERFACE_SHARP)
            if gas_J_from_cells:
                self._launch(gas_volume_rate, g.cells, [self.types, *(self.gas_vel or self.vel), self.gas_volume,
                                                           self.target_div,
                                                           g.dx, g.dim, self.gas_rate])
                self._launch(update_gas_J, self.num_particles,
                             [self.x, self.phase, self.active, self.gas_rate, self._origin, g.dx, g.dim,
                              self._domain_hi, dt, self.J])
            self.max_speed.zero_()
            self._launch(g2p_advect, self.num_particles,
                         [*self.vel, *(self.gas_vel or self.vel), self._origin, g.dx, g.dim, dt, self._domain_hi,
                          self.x, self.v, self.C, self.J, self.active, self.phase, gas_J_from_cells,
                          self.max_speed])
        if self.retract_films:
            with self.timer("tension"):  # the Laplace jump's sub-cell part: films retract into their bubble
                self._launch(fk.retract_gas_films, self.num_particles,
                             [self.types, self.phase_cells, self.gas_volume, self.film_speed, self._origin, g.dx,
                              g.dim, dt, self._domain_hi, self.x, self.phase, self.active])
        if self.entrainment:
            with self.timer("entrainment"):
                self.entrainment.step(self, dt)
        if self.subgrid:
            with self.timer("subgrid_bubbles"):
                self.subgrid.step(self, dt)
        if self.foam:
            with self.timer("foam"):  # gas reaching open air becomes foam instead of venting
                self.foam.step(self, dt)
        elif self.has_gas:
            with self.timer("vent"):
                up_axis, up_sign = self._up
                self._launch(gk.vent_exposed_gas, self.num_particles,
                             [self.x, self.phase, self.mass, self.types, self.ceiling, up_axis, up_sign,
                              self._origin, g.dx, g.dim, self.active, self.vented_mass])
        if self.colliders:
            with self.timer("colliders"):
                self.colliders.push_out(self, self.time + dt)
        self._max_speed = float(self.max_speed.numpy()[0])  # g2p and the effects that move particles
        self.stats.steps += 1
        self.stats.dt_history.append(dt)

    def _extend(self, vel, valid):
        """Extrapolate a face field past its trusted faces (EXTRAPOLATION_LAYERS), walls, colliders."""
        g = self.grid
        for a in g.axes:
            for _ in range(EXTRAPOLATION_LAYERS):
                self._launch(gk.extrapolate_velocity, g.face_shape(a),
                             [vel[a], valid[a], g.dim, self.vel_tmp[a], self.valid_tmp[a]])
                vel[a], self.vel_tmp[a] = self.vel_tmp[a], vel[a]
                valid[a], self.valid_tmp[a] = self.valid_tmp[a], valid[a]
            self._launch(gk.enforce_walls, g.face_shape(a), [self.types, a, vel[a]])
        if self.colliders:
            self.colliders.set_face_velocities(self, self.time, vel)

    # ---------------------------------------------------------------------------- time steps
    def stable_dt(self) -> float:
        """CFL limit, with sqrt(|g| dx) added to the speed so a fluid at rest still takes safe steps;
        the capillary and viscous limits when those stages are on; max_dt."""
        s = self.scene.solver
        g_mag = math.sqrt(sum(a * a for a in self._gravity))
        # Emitted streams and moving colliders bring their speed before any particle has it (the
        # fastest they move from now to a frame ahead: steps never span more than a frame).
        t0, t1 = self.time, self.time + self.frame_dt
        speed = max([self._max_speed] + [e.speed_between(t0, t1) for e in self.scene.emitters]
                    + [c.speed_between(t0, t1) for c in self.scene.colliders])
        speed += math.sqrt(g_mag * self.grid.dx)
        dt = s.cfl * self.grid.dx / speed if speed > 0.0 else math.inf
        if self.sigma > 0.0:
            # Capillary waves (Brackbill et al. 1992): dt <= sqrt((rho_l + rho_g) dx^3 / (4 pi sigma)).
            rho = self.rho_liquid + max((m.density for m in self.scene.materials.values() if m.is_gas), default=0.0)
            dt = min(dt, math.sqrt(rho * self.grid.dx**3 / (4.0 * math.pi * self.sigma)))
        if self.nu_max > 0.0:
            # Explicit diffusion: dt <= dx^2 / (2 dim nu) (DESIGN §4: rho dx^2 / (6 mu) in 3D).
            dt = min(dt, self.grid.dx**2 / (2 * self.grid.dim * self.nu_max))
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
        self._compact()

    def _compact(self):
        """Drop retired particles (vented gas, burst foam, converted bubbles) once they are a share
        COMPACT_RETIRED of the arrays, so launches and checkpoints do not grow with every particle
        ever made. Survivors keep their order, so every kernel's sums run in the same order and the
        results are the same bit for bit."""
        n = self.num_particles
        active = self.active.numpy()[:n]
        keep = np.flatnonzero(active == 1)
        if len(keep) == n or n - len(keep) < COMPACT_RETIRED * n:
            return
        for name, dtype in self.particle_fields.items():
            data = getattr(self, name).numpy()[:n][keep]
            compacted = wp.zeros(len(getattr(self, name)), dtype=dtype, device=self.device)
            if len(keep):
                wp.copy(compacted, wp.array(data, dtype=dtype, device=self.device), count=len(keep))
            setattr(self, name, compacted)
        self.num_particles = len(keep)

    # ------------------------------------------------------------------------------ read-out
    def particles_numpy(self, include_retired: bool = False) -> dict[str, np.ndarray]:
        """Copies of the state of the active particles (vented gas is retired), or of all of them.

        Copies: on the CPU device .numpy() is a view that the next step changes.
        """
        n = self.num_particles
        view = {name: getattr(self, name).numpy()[:n] for name in ("x", "v", "material", "J", "mass", "vol0", "phase")}
        keep = slice(None) if include_retired else self.active.numpy()[:n] == 1
        return {
            "positions": view["x"][keep].copy(),
            "velocities": view["v"][keep].copy(),
            "ids": self.ids.numpy()[:n][keep].copy(),
            "material": view["material"][keep].copy(),
            "J": view["J"][keep].copy(),
            "mass": view["mass"][keep].copy(),
            "volume": (view["vol0"] * view["J"])[keep],
            "phase": view["phase"][keep].copy(),  # grid.PHASE_*: foam and sub-grid bubbles have their own radius
        }

    def gas_budget(self) -> dict[str, float]:
        """Gas mass (kg) in the liquid as resolved gas ("inside") and as sub-grid bubbles, in foam,
        vented to the atmosphere (burst foam included), the float32 rounding of bubble conversions
        (subgrid.py), and their sum (conserved exactly). "volume": the resolved gas's volume."""
        n = self.num_particles
        phase = self.phase.numpy()[:n]
        active = self.active.numpy()[:n] == 1
        mass = self.mass.numpy()[:n].astype(np.float64)
        held = {key: float(mass[(phase == code) & active].sum())
                for key, code in (("inside", PHASE_GAS), ("subgrid", PHASE_SUBGRID), ("foam", PHASE_FOAM))}
        vented = float(self.vented_mass.numpy()[0])
        rounding = float(self.host_state.get("gas_mass_rounding", np.zeros(1))[0])
        return {**held, "vented": vented, "rounding": rounding,
                "total": held["inside"] + held["subgrid"] + held["foam"] + vented + rounding,
                "volume": float((self.vol0.numpy()[:n] * self.J.numpy()[:n])[(phase == PHASE_GAS) & active].sum())}

    def pressure_numpy(self) -> np.ndarray:
        """Gauge pressure (Pa) on interior cells from the last step; non-fluid cells read 0."""
        return self.pressure.numpy()[self.grid.interior_slice()]

    def liquid_volume(self) -> float:
        """Volume the particles fill: sum over cells of min(phi, 1) dx^3, phi the rest-volume fraction.

        Clustering particles (the drift that incompressible MPM suffers) raises phi above 1 in some
        cells and lowers this number. Re-splats the current particles; the grid is rebuilt each step.
        """
        self._particles_to_grid()
        cell_vol = self.grid.dx ** 3
        phi = self.liq_volume.numpy() / cell_vol
        return float(np.minimum(phi, 1.0).sum() * cell_vol)
