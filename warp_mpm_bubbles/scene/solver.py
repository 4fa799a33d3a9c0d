"""[solver]: how the equations are solved (resolution, time steps, the pressure solve, the volume
correction), validated like the rest of the scene (scene/model.py) and filled from the quality preset."""

from __future__ import annotations

from dataclasses import dataclass

from .checks import _Checker, _g
from .quality import DEFAULT_QUALITY, GOVERNED, PRESETS, preset_value
from ..core.grid import INTERFACES, PRECONDITIONERS
from ..core.volume_correction import VOLUME_FILLS, VOLUME_MOVES
from .limits import (
    DEFAULT_VOLUME_RELAXATION, MAX_CG_ITERATIONS, MAX_STEPS_LIMIT, MAX_STEPS_PER_FRAME, MAX_VOLUME_CORRECTION_SPEED,
    MAX_VOLUME_RELAXATION, MIN_VOLUME_CORRECTION_SPEED, MIN_VOLUME_RELAXATION,
)

LIQUID_VELOCITIES = ("own", "shared")  # g2p: the liquid from its own side of the interface, or the shared field
GAS_FILMS = ("retract", "passive")  # gas thinner than a cell beside a bubble: drawn back by tension, or carried


_VOLUME_CORRECTION_REMOVED = (
    "volume_correction was a share of the excess undone per step, so its strength grew as the step "
    "shrank; it is replaced by [solver].volume_relaxation_time, a time in seconds (default "
    f"{DEFAULT_VOLUME_RELAXATION} s; the old share s at steps of dt is about dt / s, e.g. 0.3 at 10 ms "
    "steps is 0.033 s), or [solver].volume_correction_speed (the time is then the cell over it). Remove "
    "volume_correction and set one of them, or volume_relaxation_time = 0 to turn the correction off")


@dataclass
class SolverSettings:
    """How the equations are solved: resolution, time steps and the pressure solve.

    Attributes:
        quality: "preview" | "production" (default) | "reference": fills particles_per_cell, cfl,
            cg_tolerance and refine where they are None.
        particles_per_cell: 1..64 (production: 4 in 2D, 8 in 3D).
        cfl: time-step factor (dimensionless, 0 < cfl <= 2): dt = cfl dx / speed (production 0.5).
        max_dt: an upper bound on the step, s (None: none).
        cg_tolerance: relative residual of the pressure solve, 0..1 (production 1e-5).
        refine: grid cells per [domain].cell_size and axis, 1..8 (reference: 2).
        cg_max_iterations: cap on pressure-solve iterations per step (1..1e6, default 2000).
        preconditioner: "multigrid" (default) | "jacobi" | "none".
        interface: gas-liquid faces: "sharp" (default, ghost fluid) | "baseline".
        liquid_velocity: sharp interface only: "own" (default) | "shared".
        gas_films: "retract" (default) | "passive": sub-cell gas films beside a bubble.
        volume_relaxation_time: s (0.001..1000, default 0.01): a cell's over-fill (or, enclosed in
            liquid, under-fill) beyond the seeding noise is undone at excess / this per second, but
            never more than all of it in one step; 0 turns the correction off.
        volume_fill: "cell" (default) | "smoothed": the fill the correction reads. "cell": each
            cell's own: its whole excess in an enclosed cell that moves positions, elsewhere its
            excess past a noise band of 0.1. "smoothed": in an enclosed cell a weighted mean over the
            cell's neighbours, its whole excess: moving velocities, a rising bubble's speed then
            jitters a twentieth as much, but a drop a few cells across reads its Laplace pressure
            less well (docs/design.md, #volume-correction).
        volume_correction_moves: "positions" (default) | "velocities": what the correction moves.
            "positions": in cells enclosed in liquid it is solved for on its own (a second, loosely
            converged solve a step) and only displaces the particles, so the flow's pressure and
            velocity are the flow's alone and a rising bubble does not shiver; cells at a surface
            ask the pressure solve. "velocities": every cell's divergence is asked of the pressure
            solve, so the particles carry it and the pressure holds its part (the default before
            2026-12-07: a rising bubble's speed jitters by 1-2%) (docs/design.md, #volume-shift).
        volume_correction_speed: m/s (0.01..10; None, the default: the fixed time above): makes the
            relaxation time the simulated cell over it, so the volume drift converges with the grid,
            at the price of correction speeds that do not (docs/design.md, #volume-correction).
        volume_correction: removed (it was a share per step, so its strength depended on dt); a
            scene that sets it is refused with the conversion to volume_relaxation_time.
        seed: seeds the jittered particle placement (a whole number >= 0).
        max_steps_per_frame: a frame that would need more steps is refused before it starts,
            naming the limiting term (default 100,000).
    """

    quality: str = DEFAULT_QUALITY  # preview | production | reference: fills the unset settings below
    particles_per_cell: int | None = None  # None: from the quality preset (production: 4 in 2D, 8 in 3D)
    cfl: float | None = None  # None: from the preset (production: 0.5)
    max_dt: float | None = None
    cg_tolerance: float | None = None  # None: from the preset (production: 1e-5)
    refine: int | None = None  # grid cells per [domain].cell_size and axis; None: from the preset (reference: 2)
    cg_max_iterations: int = 2000
    preconditioner: str = "multigrid"  # V-cycle PCG; "jacobi" needs 10-75x the iterations (benchmarks/)
    interface: str = "sharp"  # gas-liquid faces: "sharp" (ghost fluid) or "baseline" (published method)
    liquid_velocity: str = "own"  # sharp interface: the liquid reads its own field extended into the gas, or "shared"
    gas_films: str = "retract"  # sharp interface with tension: sub-cell gas beside a bubble retracts into it
    volume_relaxation_time: float | None = None  # s: excess undone at excess / this per second; None: 0.01 or the speed's
    volume_correction_speed: float | None = None  # m/s: tau = cell / this; None: the fixed time
    volume_fill: str = "cell"  # the fill the correction reads: each cell's own, or "smoothed" over its neighbours
    volume_correction_moves: str = "positions"  # a solve of its own displaces the particles; or "velocities"
    seed: int = 0
    max_steps_per_frame: int = MAX_STEPS_PER_FRAME  # the guard against a frame that never ends
    volume_correction: float | None = None  # removed: refused with the conversion (see _validate)

    def _validate(self, c: _Checker, dim):
        t = "[solver]"
        self.quality = c.choice(f"{t}.quality", self.quality, tuple(PRESETS))
        for name in GOVERNED:
            if getattr(self, name) is None:
                setattr(self, name, preset_value(self.quality, name, dim))
        self.particles_per_cell = c.number(f"{t}.particles_per_cell", self.particles_per_cell,
                                           ge=1, le=64, whole=True)
        self.cfl = c.number(f"{t}.cfl", self.cfl, gt=0, le=2)
        self.refine = c.number(f"{t}.refine", self.refine, ge=1, le=8, whole=True)
        if self.max_dt is not None:
            self.max_dt = c.number(f"{t}.max_dt", self.max_dt, gt=0)
        self.cg_tolerance = c.number(f"{t}.cg_tolerance", self.cg_tolerance, gt=0, lt=1)
        self.cg_max_iterations = c.number(f"{t}.cg_max_iterations", self.cg_max_iterations, ge=1,
                                          le=MAX_CG_ITERATIONS, whole=True)
        self.preconditioner = c.choice(f"{t}.preconditioner", self.preconditioner, PRECONDITIONERS)
        self.interface = c.choice(f"{t}.interface", self.interface, INTERFACES)
        self.liquid_velocity = c.choice(f"{t}.liquid_velocity", self.liquid_velocity, LIQUID_VELOCITIES)
        self.gas_films = c.choice(f"{t}.gas_films", self.gas_films, GAS_FILMS)
        if self.volume_correction is not None:
            c.fail(f"{t}.volume_correction", self.volume_correction, _VOLUME_CORRECTION_REMOVED)
        self._validate_volume_relaxation(c, t)
        self.volume_fill = c.choice(f"{t}.volume_fill", self.volume_fill, VOLUME_FILLS)
        self.volume_correction_moves = c.choice(f"{t}.volume_correction_moves", self.volume_correction_moves,
                                                VOLUME_MOVES)
        self.seed = c.number(f"{t}.seed", self.seed, ge=0, le=2**63 - 1, whole=True)
        self.max_steps_per_frame = c.number(f"{t}.max_steps_per_frame", self.max_steps_per_frame, ge=1,
                                            le=MAX_STEPS_LIMIT, whole=True)

    def _validate_volume_relaxation(self, c: _Checker, t: str):
        """A fixed relaxation time (default 0.01 s), or a speed that ties it to the grid; not both."""
        tau, speed = self.volume_relaxation_time, self.volume_correction_speed
        if speed is not None:
            if tau is not None:
                c.fail(f"{t}.volume_correction_speed", speed,
                       f"set either it or [solver].volume_relaxation_time (= {_g(tau)}), not both: the time is "
                       f"fixed, the speed makes it the cell over the speed; remove one")
            self.volume_correction_speed = c.number(f"{t}.volume_correction_speed", speed,
                                                    ge=MIN_VOLUME_CORRECTION_SPEED, le=MAX_VOLUME_CORRECTION_SPEED)
            return
        tau = c.number(f"{t}.volume_relaxation_time", DEFAULT_VOLUME_RELAXATION if tau is None else tau,
                       ge=0, le=MAX_VOLUME_RELAXATION)
        self.volume_relaxation_time = tau if tau == 0 else c.number(  # 0: off
            f"{t}.volume_relaxation_time", tau, ge=MIN_VOLUME_RELAXATION, le=MAX_VOLUME_RELAXATION)

    def volume_relaxation(self, dx: float) -> float:
        """The volume correction's relaxation time, s, on a grid of cell dx (0: off): the fixed time,
        or dx / volume_correction_speed, whose drift converges with the grid."""
        if self.volume_correction_speed is not None:
            return dx / self.volume_correction_speed
        return self.volume_relaxation_time
