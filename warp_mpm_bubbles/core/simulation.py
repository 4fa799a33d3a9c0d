"""The simulation: the state on one Warp device and the step, the core stages with the scene's
optional stages (core/stage.py) hooked in.

One step (Zhang et al. 2017 incompressible MPM, APIC on a MAC grid; docs/design.md, "The step"):

    p2g       particles -> face momenta and masses, cell mass/volume, particle count per cell
    grid      u* = p/m + dt g, cell types, walls, face densities
    (forces)  the optional stages' forces on u* (viscosity, surface tension)
    pressure  the one two-phase system, multigrid-PCG, u = u* - dt/rho grad p
    extend    extrapolate u past the fluid, enforce walls
    g2p       faces -> particle velocity and APIC matrix, J, advection clamped to the domain
    (after)   the optional stages that move or convert particles

Each optional stage joins at named hook points (`Stage`). The phases, core work and hook points alike,
are declared once, in core/step.py's STEP: `step` runs that list, and `step_graph` the same list cut
into CUDA graphs.
The time step is the smallest of the CFL limit and the stages' limits, and lands exactly on frame
times. Inside a step the host reads only scalars: the grid box (core/active_box.py), the fluid box and
the CG's exit flag every few iterations (core/pressure.py), the solve's cell counts, one read-back at the
end; `count_host_reads` counts them, docs/host_syncs.md lists them.
"""

from __future__ import annotations

import math
from collections import Counter
from contextlib import ExitStack

import numpy as np
import warp as wp

from . import grid_kernels as gk
from .kernel_args import cell_phases, face_field, face_pairs, particle_arrays, pressure_rows, splat, step_params
from .active_box import ActiveRegion
from .geometry import grid_geometry
from .host_reads import HostReads
from .host_state import Ledger
from .grid import INTERFACE_SHARP, INTERFACES, PHASE_GAS, PHASE_LIQUID, RETIRED, WALL_OPEN, MacGrid
from .volume_correction import VOLUME_FILL_SMOOTHED, VOLUME_FILLS, VOLUME_MOVES, volume_relaxation_rate
from .pressure import PressureSolver, PressureSystem
from .solves import SolverStats
from .volume_shift import VolumeShift
from .seeding import seed_particles
from .context import StepContext
from .launch import Launcher
from .stage import Stage, build_stages
from .step import GRID_WRITING_HOOKS, HOOKS, PHASES, Run, step_plan
from .state import GridFields, ParticleState
from .timing import PhaseTimer
from . import readout, sealed_regions, threads
from .threads import Parallel, cpu_threads, line_slabs, split
from .gas_law import GAS_ADIABATIC, GAS_ISOTHERMAL
from .transfer_kernels import G2P, P2G, book_outflow, fastest_of_parts, split_pairs
from .voids import VoidPass

EXTRAPOLATION_LAYERS = 2  # the B-spline stencil reaches 1.5 cells beyond a particle's cell
GAS_LAW_CODES = {"isothermal": GAS_ISOTHERMAL, "adiabatic": GAS_ADIABATIC}  # else 0: fixed density
# Steps between sorts of the particles by cell (Simulation.sort_every; 10 pays at 64^3, see
# benchmarks/performance/transfers.py); 0: never. Off by default: a sort reorders the transfers' float sums,
# and that rounding-level change tipped two chaotic bubble tests across their bounds (a rising
# bubble split in two, tests/test_gas.py; two bubbles' merge, tests/test_hard_cases.py).
SORT_EVERY = 0
COMPACT_RETIRED = 0.25  # compact the arrays at a frame's end once this share of the particles is retired


class SimulationError(RuntimeError):
    """The simulation cannot go on; the message names the step, the stage and the likely cause."""


class Simulation:
    """Runs a validated :class:`~warp_mpm_bubbles.scene.Scene` on a Warp device ("cpu", "cuda:0").

    Public state: ``particles`` (`ParticleState`), ``fields`` (`GridFields`), ``grid`` (`MacGrid`),
    ``time`` and ``frame``, ``ledger`` (the next id, the liquid and gas added), ``ctx`` (the
    `StepContext` the stages see), ``gravity`` (3 floats, m/s^2), ``up`` ((axis, sign) against the strongest gravity component; axis -1
    without gravity), and ``geometry``, the `GridGeometry` struct the particle kernels take.
    """

    def __init__(self, scene, device=None):
        self.scene = scene.validate()
        self.effects = self.scene.effect_names  # the optional stages that run; no others do
        self.device = wp.get_device(device)
        self.grid = g = MacGrid.from_domain(scene.domain)
        self.timer = PhaseTimer(self.device)
        self.max_particle_speed = 0.0  # m/s, from the last step (it sets the next time step)
        self.sort_every = SORT_EVERY
        self._sorted_at = 0  # the step of the last sort by cell
        self.ledger = Ledger()  # the next particle's id, the liquid and gas added (core/host_state.py)
        self._init_geometry()
        self.particles = ParticleState(self.device)
        self.parallel = Parallel(cpu_threads() if self.device.is_cpu else 1)  # for the transfers and the V-cycle
        self.fields = GridFields(g, self.device, parts=self.parallel.threads)
        # g2p parts' fastest speeds, a cache line apart: each part writes its slot for every particle
        self.speed_parts = wp.zeros(self.parallel.threads * threads.CACHE_LINE_FLOATS, dtype=float, device=self.device)
        # Every launch goes through the launcher (core/launch.py); the core uses its helpers by name.
        self.launcher = launcher = Launcher(self.device, self.parallel, g, self.particles)
        self.launches = launcher.launches  # kernel launches by name: proof of what ran
        self.launch, self.launch_lines, self.launch_particles = launcher.launch, launcher.launch_lines, launcher.launch_particles
        self.launch_box, self.launch_splat, self.launch_parts = launcher.launch_box, launcher.launch_splat, launcher.launch_parts
        self.solver = PressureSolver(g.cells, g.dim, g.dx, self.device, parallel=self.parallel)
        # Fluid regions no free surface reaches, one apart from another: only solids inside the domain (the
        # colliders) can seal one off; without them the fluid is one region or reaches the air.
        self.sealed = sealed_regions.SealedRegions(g.cells, self.device) if scene.colliders else None
        # [solver].volume_correction_moves = "positions": the correction's own solve and shift (core/volume_shift.py)
        self.volume_shift = VolumeShift(self) if self.volume_moves else None
        if self.volume_fill == VOLUME_FILL_SMOOTHED:
            self.fields.enclosed_cells = self.fields.cells(wp.int32)
        self._graphs: dict = {}  # step_graph's captured stretches (CUDA only)
        self.ctx = self._context()  # what the stages see (core/context.py)
        self.voids = VoidPass(self)  # particle-free cells inside the liquid are not free surface (core/voids.py)
        self.stages: list[Stage] = build_stages(self.ctx, self.effects)
        self._hooks = {hook: [s for s in self.stages if hook in s.hooks()] for hook in HOOKS}
        self._plans = {graph: step_plan(self._hooks, graph) for graph in (False, True)}  # core/step.py
        # the grid stages' launch box (core/active_box.py): the particles' cells and a margin;
        # unless every stage at a grid-writing hook is box-aware, the whole grid (its kernels may write anywhere)
        self.region = ActiveRegion(g, self.device, parallel=self.parallel,
                                   enabled=all(s.grid_box for h in GRID_WRITING_HOOKS for s in self._hooks[h]))
        self._seed()

    def _context(self) -> StepContext:
        return StepContext(
            scene=self.scene, device=self.device, grid=self.grid, fields=self.fields, particles=self.particles,
            geometry=self.geometry, launcher=self.launcher, stats=SolverStats(), gravity=self.gravity, up=self.up,
            two_phase=self.two_phase, interface=self.interface, has_gas=self.has_gas,
            effects=self.effects, ledger=self.ledger, read_host=self.read_host,
            add_particles=self.add_particles, stage=self.stage, extend=self.extend, book_outflow=self.book_outflow,
            dt_limits=self.dt_limits)

    def _set_region(self, region: ActiveRegion):
        self.ctx.region = self.launcher.region = region

    # The clock, the counts and the box live in the context, which the stages read them from.
    stats = property(lambda self: self.ctx.stats, lambda self, st: setattr(self.ctx, "stats", st))
    region = property(lambda self: self.ctx.region, _set_region)
    time = property(lambda self: self.ctx.time, lambda self, t: setattr(self.ctx, "time", t))
    frame = property(lambda self: self.ctx.frame, lambda self, n: setattr(self.ctx, "frame", n))
    report_writers = property(lambda self: self.ctx.report_writers)  # stages' f(ctx) writing into the read-back
    report_readers = property(lambda self: self.ctx.report_readers)  # stages' f(ctx, report) after it

    def _init_geometry(self):
        g, scene = self.grid, self.scene
        walls = scene.domain.wall_types
        self.wall_lo = wp.vec3i(walls[0], walls[2], walls[4])
        self.wall_hi = wp.vec3i(walls[1], walls[3], walls[5])
        open_lo = tuple(int(w == WALL_OPEN) for w in walls[0::2])
        open_hi = tuple(int(w == WALL_OPEN) for w in walls[1::2])
        self.open_walls = any(open_lo + open_hi)  # particles may leave: book_outflow runs after each mover
        gravity = tuple(scene.domain.gravity) + (0.0,) * (3 - g.dim)
        self.gravity = tuple(float(a) for a in gravity)
        g_abs = [abs(a) for a in self.gravity[: g.dim]]
        up_axis = int(np.argmax(g_abs)) if max(g_abs) > 0.0 else -1
        self.up = (up_axis, 1 if up_axis < 0 or self.gravity[up_axis] < 0.0 else -1)
        self.geometry = grid_geometry(g, self.gravity, self.up, open_lo, open_hi)  # what the particle kernels take
        self.interface = INTERFACES.index(scene.solver.interface)
        self.volume_fill = VOLUME_FILLS.index(scene.solver.volume_fill)
        self.volume_moves = VOLUME_MOVES.index(scene.solver.volume_correction_moves)
        self.two_phase = int(self.has_gas)

    def _seed(self):
        seeds = seed_particles(self.scene)
        self.seeded = len(seeds["positions"])  # what the shapes seed, before colliders remove any
        colliders = self.stage("colliders")
        if colliders:  # no particle starts inside a solid
            keep = ~colliders.inside(self.ctx, seeds["positions"])
            seeds = {name: values[keep] for name, values in seeds.items()}
        self.add_particles(seeds["positions"], seeds["velocities"], seeds["material"], seeds["volume"],
                           seeds["pressure"])

    # ----------------------------------------------------------------------------- interface
    @property
    def has_gas(self) -> bool:
        return "gas" in self.effects

    @property
    def num_particles(self) -> int:
        return self.particles.count

    def stage(self, name: str) -> Stage | None:
        """The running stage of this effect name, or None: how one stage reaches another."""
        return next((s for s in self.stages if s.name == name), None)

    def read_host(self, array) -> np.ndarray:
        """The one way the step reads device data on the host (a round trip on a GPU; counted by
        `count_host_reads`; docs/host_syncs.md lists each and why)."""
        return array.numpy()

    def count_host_reads(self) -> HostReads:
        """``with sim.count_host_reads() as reads: sim.step(dt)``: the host reads inside, by module."""
        return HostReads()

    def state_arrays(self) -> dict[str, np.ndarray]:
        """The host values a resumed run needs, by checkpoint name: the core's ledger, the void pass's
        and each stage's `state` (core/host_state.py; io/checkpoint.py saves them)."""
        out = {**self.ledger.arrays(), **self.voids.state.arrays()}
        for s in self.stages:
            out.update(s.state_arrays())
        return out

    def load_state(self, arrays: dict) -> None:
        """Take back what state_arrays gave (a name missing from an older checkpoint keeps its fresh value)."""
        self.ledger.load(arrays)
        self.voids.state.load(arrays)
        for s in self.stages:
            s.load_state(arrays)

    def add_particles(self, positions, velocities, material, volume, gauge_pressure=None) -> slice:
        """Append particles (numpy arrays; material: indices into scene.materials; volume: current,
        m^3) and return their index range. Each particle gets the next id, which it keeps for good
        (a renderer's motion blur follows it) while compaction moves it."""
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
            "ids": self.ledger.next_id + np.arange(n, dtype=np.int64),
        }
        self.ledger.next_id += n
        liquid = values["phase"] == PHASE_LIQUID  # booked as stored (float32), so the ledger closes exactly
        stored = np.asarray(values["mass"], np.float32).astype(np.float64)
        self.ledger.liquid_added += float(stored[liquid].sum())
        # Gas appended (kg; conversions re-append what they retire, so an upper bound of what is held):
        # the emitters' room bound reads nothing (effects/emitters.py, _may_fill).
        self.ledger.gas_added += float(stored[~liquid].sum())
        added = self.particles.append(values, n)
        if n:
            self.max_particle_speed = max(self.max_particle_speed,
                                          float(np.linalg.norm(np.asarray(velocities), axis=1).max()))
        return added

    # ------------------------------------------------------------------------------ the step
    def step(self, dt: float):
        """One time step: the phases of core/step.py's STEP, in order (docs/design.md, "The step")."""
        self.ctx.dt = dt
        self._run_plan(self._plans[False], dt)

    def step_plan(self, graph: bool = False) -> list[Run]:
        """The runs of phases step (graph=False) or step_graph (graph=True) makes of this scene's step."""
        return self._plans[graph]

    def _run_plan(self, runs: list[Run], dt: float, again: bool = False):
        """Run each phase in turn, those sharing a timer line under one timer (it synchronizes on a
        GPU); a hook without one times each stage on its own line. A captured run is one CUDA graph."""
        with ExitStack() as timed:
            line = None  # the timer line open now
            for i, run in enumerate(runs):
                first = PHASES[run.phases[0]]
                name = f"graph: {run.phases[0]} .. {run.phases[-1]}" if run.captured else first.timer
                if name != line:
                    timed.close()
                    if name is not None:
                        timed.enter_context(self.timer(name))
                    line = name
                if run.captured:
                    self._replay(run, dt)
                elif first.repeat_from:
                    if self.voids.seeded:  # trapped air seeded in this step's cells: this solve must see its gas
                        timed.close()
                        line = None
                        start = next(j for j, r in enumerate(runs) if first.repeat_from in r.phases)
                        self._run_plan(runs[start:i], dt, again=True)
                else:
                    self._run_phase(first, dt, again, timed=name is None)

    def _run_phase(self, phase, dt: float, again: bool, timed: bool = False):
        if not phase.hook:
            getattr(self, f"_phase_{phase.name}")(dt, again)
            return
        for s in self._hooks[phase.name]:
            if timed:
                with self.timer(s.timer_name):
                    getattr(s, phase.name)(self.ctx, dt)
            else:
                getattr(s, phase.name)(self.ctx, dt)

    def _phase_sort(self, dt: float, again: bool):
        if not again:
            self._sort_if_due()

    def _phase_region(self, dt: float, again: bool):
        """The box the grid phases cover, read on the host; again: the same step's, after the void pass
        seeded trapped air (core/voids.py). The second pass writes what it writes from scratch, on a box
        holding the first's (the same particles and more, united with the previous step's)."""
        self.region.update(self.particles, again)

    def _phase_p2g(self, dt: float, again: bool):
        self.particles_to_grid(self.region)

    def _phase_read_back(self, dt: float, again: bool):
        # The step's one read-back: the fastest particle (g2p and the stages that move particles)
        # sets the next dt on the host; the stages' counts come with it (docs/host_syncs.md).
        for write in self.report_writers:
            write(self.ctx)
        report = self.read_host(self.fields.max_speed)
        self.max_particle_speed = float(report[0])
        for read in self.report_readers:
            read(self.ctx, report)
        self.stats.steps += 1
        self.stats.dt_history.append(dt)

    def step_graph(self, dt: float):
        """step(dt) with each capturable stretch of the step (step_plan(graph=True)) captured as a
        CUDA graph (wp.ScopedCapture) and replayed while nothing it bakes in changes; the phases that
        read the host run between them as in step(). On the CPU it is step(dt). UNTESTED on a GPU
        (docs/host_syncs.md): the same results as step() are the acceptance test to run first."""
        if not self.device.is_cuda:
            return self.step(dt)
        self.ctx.dt = dt
        self._run_plan(self._plans[True], dt)

    def _replay(self, run: Run, dt: float):
        """Capture `run` once per (dt, particle arrays, box, face arrays) and launch the graph; the
        face lists the stretch swaps (viscosity, extend) are set as the capture left them."""
        f, p = self.fields, self.particles
        lists = [a for a in (f.vel, f.vel_tmp, f.valid, f.valid_tmp, f.gas_vel, f.gas_valid) if a is not None]
        key = (run.phases, dt, p.count, p.x.ptr, self.region.box, tuple(a.ptr for arrays in lists for a in arrays))
        if key not in self._graphs:
            if len(self._graphs) >= 16:  # dt changes: keep only recent graphs
                self._graphs.clear()
            before = Counter(self.launches)
            with wp.ScopedCapture(device=self.device) as capture:
                for name in run.phases:
                    self._run_phase(PHASES[name], dt, again=False)  # untimed: the timer synchronizes
            self._graphs[key] = (capture.graph, self.launches - before, [list(a) for a in lists])
            self.launches.clear()
            self.launches.update(before)
        graph, launches, after = self._graphs[key]
        wp.capture_launch(graph)
        self.launches.update(launches)
        for arrays, state in zip(lists, after):
            arrays[:] = state

    def _sort_if_due(self):
        since = self.stats.steps - self._sorted_at
        if self.sort_every and (self.particles.in_id_order or since >= self.sort_every):
            self.sort_particles()

    def sort_particles(self):
        """Order the particles by cell (ParticleState.sort_by_cell): the transfers then read and add
        to the grid in memory order. Read-outs (particles_numpy) stay in id order, and advance_to
        returns the arrays in id order (a particle keeps its index from one frame to the next)."""
        self.particles.sort_by_cell(self.geometry, self.grid.cells, self.launch)
        self._sorted_at = self.stats.steps

    def particles_to_grid(self, region: ActiveRegion | None = None):
        """Splat the particles: face momenta and masses, liquid mass and volume per cell, counts.
        region: a box holding every particle's stencil (this step's ActiveRegion), or the whole grid.
        On the CPU the splat runs as one part per thread, each owning a slab of the box's nodes along
        x (core/threads.py): the same sums, bit for bit, as one launch."""
        f, p, r = self.fields, self.particles, region or self.region.whole
        for arr in (*f.face_pairs, f.cell_pairs, f.cell_count, f.nonfinite):
            arr.zero_()
        args = [self.geometry, particle_arrays(p), face_pairs(f.face_pairs), f.cell_pairs, f.cell_count, f.nonfinite]
        self.launch_splat(P2G[self.grid.dim], args, r)
        for a in range(3):
            self.launch_lines(split_pairs, r.face_lines[a], [f.face_pairs[a], f.mom[a], f.face_mass[a]])
        self.launch_lines(split_pairs, r.cell_lines, [f.cell_pairs, f.liq_mass, f.liq_volume])

    def _phase_momentum(self, dt: float, again: bool):
        g, f, r = self.grid, self.fields, self.region
        for a in g.axes:
            self.launch_lines(gk.momentum_to_velocity, r.face_lines[a],
                              [self.gravity[a], dt, f.mom[a], f.face_mass[a], f.vel[a]])

    def _phase_classify(self, dt: float, again: bool):
        g, f, r = self.grid, self.fields, self.region
        step = self._step_params(dt)
        self.launch_lines(gk.classify_cells, r.cell_lines, [step, wp.vec3i(*g.ghost), wp.vec3i(*g.interior), self.wall_lo,
                                                            self.wall_hi, f.cell_count, splat(f), f.types])

    def _phase_voids(self, dt: float, again: bool):
        self.voids.apply(dt)  # EMPTY cells closed off from the open air become liquid (or trapped air)

    def _phase_face_density(self, dt: float, again: bool):
        g, f, r = self.grid, self.fields, self.region
        step = self._step_params(dt)
        for a in g.axes:
            self.launch_lines(gk.zero_solid_faces, r.face_lines[a], [a, f.types, f.vel[a]])
            self.launch_lines(gk.face_inverse_density, r.face_lines[a],
                              [step, a, cell_phases(f), splat(f), f.inv_rho[a]])

    def _phase_assemble(self, dt: float, again: bool):
        g, f, r = self.grid, self.fields, self.region
        f.counters.zero_()
        step = self._step_params(dt)
        rate = volume_relaxation_rate(self.scene.solver.volume_relaxation(g.dx), dt)
        if self.volume_fill == VOLUME_FILL_SMOOTHED:  # its neighbours' enclosed flags, before any cell reads them
            self.launch_lines(gk.mark_enclosed, r.cell_lines, [cell_phases(f), f.gas_kv, g.dim, self.two_phase,
                                                               f.enclosed_cells])
        fields = [cell_phases(f), face_field(f.inv_rho), face_field(f.vel), splat(f), pressure_rows(f), f.counters,
                  f.enclosed_cells]
        # Slabs at once, each counting into its own counters (integers: the total is exact in any order).
        slabs = line_slabs(*r.cell_lines, self.parallel.threads)
        self.launch_parts(gk.pressure_diagonal_and_rhs, [(d, [slab, step, rate, q * threads.CACHE_LINE_FLOATS, *fields])
                                                         for q, (slab, d) in enumerate(slabs)])

    def _phase_solve(self, dt: float, again: bool):
        g, f, settings, r = self.grid, self.fields, self.scene.solver, self.region
        if self.sealed:
            self.sealed.count(self, f)  # the fluid's connected regions, into counters[3:6]
        wp.copy(f.counters, f.nonfinite, dest_offset=2, count=1)  # one read-back, not two
        counts = self.read_host(f.counters).reshape(-1, threads.CACHE_LINE_FLOATS)
        n_fluid, n_pinned, bad = int(counts[:, 0].sum()), int(counts[:, 1].sum()), int(counts[0, 2])
        if bad:
            raise SimulationError(
                f"step {self.stats.steps + 1} (t = {self.time:.6g} s): {bad} particles entered p2g with a "
                f"non-finite position or velocity. Likely cause: the previous step diverged (a time "
                f"step too large for the scene: lower [solver].cfl or set [solver].max_dt) or NaN/Inf "
                f"in the initial state.")
        # A sealed region beside others is made solvable on its own; else a closed tank full of liquid
        # (one sealed region) is singular as a whole, and the solver projects out the constant.
        apart = bool(self.sealed) and self._settle_sealed(counts[0], n_fluid, dt)
        singular = n_pinned == 0 and not apart
        info = self.solver.solve(
            PressureSystem(f.types, tuple(f.inv_rho), f.diag, f.extra_diag), f.rhs, f.pressure,
            tol=settings.cg_tolerance, max_iter=settings.cg_max_iterations,
            preconditioner=settings.preconditioner, singular=singular, n_fluid=n_fluid,
            region=r.box if r.enabled else None,
        )
        if apart:
            self.sealed.center(self, f)
        self.stats.record(info)
        step = self._step_params(dt)
        for a in g.axes:
            self.launch_lines(gk.subtract_pressure_gradient, r.face_lines[a],
                              [step, a, f.types, f.pressure, f.inv_rho[a], f.vel[a], f.valid[a]])
        if self.volume_shift:
            self.volume_shift.solve(self, step, singular, n_fluid, apart)

    def _step_params(self, dt: float):
        return step_params(self.grid, dt, self.two_phase, self.interface, self.volume_fill, self.volume_moves)

    def _settle_sealed(self, counts, n_fluid: int, dt: float) -> bool:
        """Stop a run whose solids squeeze liquid they shut in; make each sealed region solvable on
        its own when there are several (core/sealed_regions.py). Whether it did."""
        squeezed = self.sealed.squeeze_error(counts, n_fluid)
        if squeezed:
            raise SimulationError(f"step {self.stats.steps + 1} (t = {self.time:.6g} s): {squeezed}")
        return self.sealed.settle(self, self.fields, counts, dt)

    def extend(self, vel, valid, box=None):
        """Extrapolate a face field past its trusted faces (EXTRAPOLATION_LAYERS), enforce walls,
        then the stages' boundary velocities (moving colliders). Swaps arrays in the lists given.
        `box`: the cells to cover (an active_box.LaunchBox inside the region), else the region."""
        g, f, r = self.grid, self.fields, box or self.region
        for a in g.axes:
            for _ in range(EXTRAPOLATION_LAYERS):
                self.launch_lines(gk.extrapolate_velocity, r.face_lines[a],
                                  [g.dim, vel[a], valid[a], f.vel_tmp[a], f.valid_tmp[a]])
                vel[a], f.vel_tmp[a] = f.vel_tmp[a], vel[a]
                valid[a], f.valid_tmp[a] = f.valid_tmp[a], valid[a]
            self.launch_lines(gk.enforce_walls, r.face_lines[a], [a, f.types, vel[a]])
        for s in self._hooks["on_extended"]:
            s.on_extended(self.ctx, vel)

    def _phase_extend(self, dt: float, again: bool):
        self.extend(self.fields.vel, self.fields.valid)

    def _phase_g2p(self, dt: float, again: bool):
        f, p = self.fields, self.particles
        # The sharp interface's gas took its cells' volume change in before_g2p; the baseline (and
        # the liquid) follow the interpolated divergence.
        gas_J_from_cells = int(self.has_gas and self.interface == INTERFACE_SHARP)
        f.max_speed.zero_()
        vs = self.volume_shift  # its displacement moves positions in the same gather (core/volume_shift.py)
        shift = (1, face_field(vs.shift)) if vs else (0, face_field(f.vel))
        args = [self.geometry, face_field(f.vel), face_field(f.gas_vel or f.vel), *shift, particle_arrays(p)]
        if self.parallel.threads == 1:
            self.launch(G2P[self.grid.dim], p.count, [0, dt, gas_J_from_cells, 0, *args, f.max_speed])
        else:
            # One part per thread: particles are independent; their largest speed, combined exactly.
            self.speed_parts.zero_()
            cuts = split(0, p.count, self.parallel.threads)
            line = threads.CACHE_LINE_FLOATS
            self.launch_parts(G2P[self.grid.dim], [(b - a, [a, dt, gas_J_from_cells, q * line, *args, self.speed_parts])
                                                    for q, (a, b) in enumerate(zip(cuts, cuts[1:]))])
            self.launch(fastest_of_parts, 1, [self.speed_parts, self.parallel.threads, line, f.max_speed])
        self.book_outflow()

    def book_outflow(self):
        """Retire the particles a mover marked as gone through an open wall, booking their mass by
        phase (`outflow_mass`): every kernel that moves particles calls this after it, so no later
        kernel sees a particle outside the domain. Nothing to do in a closed domain."""
        if self.open_walls and self.particles.count:
            p = self.particles
            self.launch(book_outflow, p.count, [p.active, p.phase, p.mass, self.fields.outflow_mass])

    # ---------------------------------------------------------------------------- time steps
    def dt_limits(self) -> dict[str, float]:
        """Each limit on the next step, in seconds, by name: "cfl" (with sqrt(|g| dx) added to the
        fastest particle, so a fluid at rest still takes safe steps, and the speed emitters and
        moving colliders bring), each stage's own limit by its `limit` name ("capillary", "viscous",
        "gas_expansion"), and "max_dt" if set."""
        s = self.scene.solver
        g_mag = math.sqrt(sum(a * a for a in self.gravity))
        t0, t1 = self.time, self.time + self.frame_dt  # steps never span more than a frame
        speed = max([self.max_particle_speed] + [st.incoming_speed(t0, t1) for st in self.stages])
        speed += math.sqrt(g_mag * self.grid.dx)
        limits = {"cfl": s.cfl * self.grid.dx / speed if speed > 0.0 else math.inf}
        for st in self.stages:
            limit = st.dt_limit(self.ctx)
            if limit < math.inf:
                limits[st.limit or st.name] = limit
        if s.max_dt is not None:
            limits["max_dt"] = s.max_dt
        return limits

    def stable_dt(self) -> float:
        return min(self.dt_limits().values())

    def advance_to(self, t_end: float, on_step=None):
        """Substep to exactly t_end, splitting what remains into equal steps under the limits;
        `on_step(dt, remaining)` runs after each step (the runner's heartbeat and step guard)."""
        setter = None  # the limit that split this interval into steps
        while self.time < t_end:
            remaining = t_end - self.time
            limits = self.dt_limits()
            name = min(limits, key=limits.get)
            n = max(1, math.ceil(remaining / limits[name] - 1e-9))
            dt = remaining / n
            if n == 1 and remaining < limits[name]:
                name = setter or "frame"  # the split's last step, or a frame shorter than every limit
            setter = name
            self.stats.limited_by[name] = self.stats.limited_by.get(name, 0) + 1
            self.step(dt)
            self.time = t_end if n == 1 else self.time + dt
            if on_step:
                on_step(dt, t_end - self.time)
        if not self.particles.in_id_order:
            self.particles.sort_by_id(self.ledger.next_id, self.launch)

    @property
    def frame_dt(self) -> float:
        return 1.0 / self.scene.output.fps

    def advance_frame(self, on_step=None):
        self.frame += 1
        self.advance_to(self.frame * self.frame_dt, on_step)
        self._compact()

    def _compact(self):
        """Drop retired particles (vented gas, burst foam, converted bubbles) once they are a share
        COMPACT_RETIRED of the arrays, so launches and checkpoints do not grow with every particle
        ever made."""
        n = self.particles.count
        keep = np.flatnonzero(self.particles.numpy("active") != RETIRED)
        if len(keep) == n or n - len(keep) < COMPACT_RETIRED * n:
            return
        self.particles.compact(keep)

    # ------------------------------------------------------------------------------ read-out
    def particles_numpy(self, include_retired: bool = False) -> dict[str, np.ndarray]:
        """Copies of the active particles' state (readout.particles_numpy)."""
        return readout.particles_numpy(self, include_retired)

    def gas_budget(self) -> dict[str, float]:
        """Where the gas went, kg (readout.gas_budget)."""
        return readout.gas_budget(self)

    def mass_budget(self) -> dict[str, dict[str, float]]:
        """Where the liquid and the gas went, kg (readout.mass_budget)."""
        return readout.mass_budget(self)

    def pressure_numpy(self) -> np.ndarray:
        """Gauge pressure (Pa) on interior cells from the last step (readout.pressure_numpy)."""
        return readout.pressure_numpy(self)

    def liquid_volume(self) -> float:
        """Volume the particles fill, m^3 (readout.liquid_volume)."""
        return readout.liquid_volume(self)

    def liquid_density(self) -> float:
        """The liquid's mean rest-volume fraction inside it, 1 at rest (readout.liquid_density)."""
        return readout.liquid_density(self)
