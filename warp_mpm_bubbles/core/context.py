"""The step context: what a stage sees of the simulation, and all it sees (docs/new_effect.md).

Every hook of a stage (core/stage.py) receives one `StepContext`, never the `Simulation`: the state
it works on (grid, fields, particles, the active region, the geometry), the launch helpers
(`launcher`, core/launch.py, whose methods it also offers by name: `ctx.launch_lines(...)`), the
clock (time, frame, this step's dt, steps done), the scene's constants, and the few services of the
core a stage needs (read the host, add particles, reach another stage by name, extrapolate a field,
retire what left through an open wall, the other time-step limits, the step's one read-back).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable


@dataclass(eq=False)
class StepContext:
    scene: Any  # the validated Scene (settings only: a stage's own are `self.settings`)
    device: Any  # the Warp device
    grid: Any  # MacGrid: dims, dx, axes, face shapes
    fields: Any  # GridFields: the grid arrays (core/state.py)
    particles: Any  # ParticleState: the particle arrays and count (core/state.py)
    geometry: Any  # GridGeometry: the struct a particle kernel takes (core/geometry.py)
    launcher: Any  # Launcher (core/launch.py)
    stats: Any  # SolverStats: `steps` done (seeds, messages); read it, never write it
    gravity: tuple  # 3 floats, m/s^2
    up: tuple  # (axis, sign) against the strongest gravity component; axis -1 without gravity
    two_phase: int  # 1 with the gas stage: the solve sees gas cells
    interface: int  # index into core.grid.INTERFACES ([solver].interface)
    has_gas: bool
    effects: list  # the effect names that run in this scene
    ledger: Any  # Ledger (core/host_state.py): next particle id, liquid and gas added; a stage's own: its `state`
    # the step's one read-back (core/step.py, read_back): f(ctx) writes into it before, f(ctx, report) reads after
    report_writers: list = field(default_factory=list)
    report_readers: list = field(default_factory=list)
    # services of the core
    read_host: Callable = None  # read_host(array) -> numpy: the one counted way to read device data
    add_particles: Callable = None  # add_particles(positions, velocities, material, volume, gauge=None) -> slice
    stage: Callable = None  # stage(name) -> the running stage of that effect, or None
    extend: Callable = None  # extend(vel, valid, box=None): extrapolate a face field, walls, on_extended
    book_outflow: Callable = None  # after a kernel that moves particles: retire those gone through an open wall
    dt_limits: Callable = None  # dt_limits() -> {name: seconds}: every limit on the next step
    region: Any = None  # ActiveRegion: the grid stages' box (core/active_box.py)
    time: float = 0.0  # s, at the start of the step being taken
    frame: int = 0  # the frame being computed
    dt: float = 0.0  # this step's, once it started

    # The launcher's helpers by the names the core uses (their docstrings: core/launch.py).
    @property
    def launch(self):
        return self.launcher.launch

    @property
    def launch_lines(self):
        return self.launcher.launch_lines

    @property
    def launch_particles(self):
        return self.launcher.launch_particles

    @property
    def launch_box(self):
        return self.launcher.launch_box

    @property
    def launch_splat(self):
        return self.launcher.launch_splat

    @property
    def launch_parts(self):
        return self.launcher.launch_parts
