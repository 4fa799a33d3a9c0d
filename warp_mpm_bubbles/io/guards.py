"""No silent hangs: a frame that would need too many steps stops before it starts, and a run
whose output is not a terminal prints a heartbeat at least every 30 s.

The runner's frame loop uses them (see docs/api.md):

    guard = frame_step_guard(sim)                       # before each frame: FrameTooLongError
    beat = Heartbeat(sys.stderr)                         # after each step:
    beat.tick(sim.frame, sim.stats.steps, dt, elapsed)   # a line when 30 s have passed (not on a tty)
"""
from __future__ import annotations

import math
import sys
import time

from ..core.simulation import SimulationError
from ..scene.limits import MAX_STEPS_PER_FRAME, steps_message


class FrameTooLongError(SimulationError):
    """A frame would need more than the allowed steps; the message names the limiting term and the fix."""

    def __init__(self, message: str, limit: str, steps: float):
        super().__init__(message)
        self.limit, self.steps = limit, steps


class NoFluidError(SimulationError):
    """Nothing is left to simulate (colliders cover every seeded particle, and nothing is emitted)."""

    exit_code = 2  # a refusal before any work, like a bad scene


def dt_limits(sim) -> dict[str, float]:
    """The simulation's time-step limits in seconds by name ("cfl", "capillary", "viscous",
    "gas_expansion", "max_dt"): Simulation.dt_limits() where it has one, else {"cfl": stable_dt()}."""
    limits = getattr(sim, "dt_limits", None)
    limits = dict(limits()) if callable(limits) else {"cfl": sim.stable_dt()}
    return {k: float(v) for k, v in limits.items() if v is not None and not math.isnan(v)} or {"cfl": math.inf}


def frame_step_guard(sim, max_steps_per_frame: int | None = None, remaining: float | None = None) -> float:
    """Raise FrameTooLongError when the next frame would take more than max_steps_per_frame steps
    (default: the scene's [solver].max_steps_per_frame, else 100,000) at the current step limit;
    returns the steps it needs. Call it before each frame; inside the frame's step loop, pass
    `remaining` (s left to the frame's end) to catch a step limit that collapses mid-frame."""
    if max_steps_per_frame is None:
        max_steps_per_frame = getattr(sim.scene.solver, "max_steps_per_frame", MAX_STEPS_PER_FRAME)
    limits = dt_limits(sim)
    name = min(limits, key=limits.get)
    dt = limits[name]
    frame_dt = 1.0 / sim.scene.output.fps if remaining is None else remaining
    steps = frame_dt / dt if dt > 0.0 else math.inf
    if not steps <= max_steps_per_frame:
        # Simulation.advance_frame counts a frame before stepping it: inside the frame's step loop
        # sim.frame is the frame being computed, before it the last one finished.
        computing = sim.frame if remaining is not None else sim.frame + 1
        raise FrameTooLongError(f"frame {computing}: " + steps_message(steps, name, dt, frame_dt,
                                                                       max_steps_per_frame), name, steps)
    return steps


def check_fluid_left(sim):
    """Raise NoFluidError when a simulation starts with no particles and no emitter to bring any:
    call it once after Simulation(...) is built."""
    if sim.num_particles == 0 and not sim.scene.emitters:
        why = "the shapes seed no particles"
        if sim.scene.colliders:
            why = (f"the colliders cover all {getattr(sim, 'seeded', 0):,} seeded particles; move or shrink the "
                   f"[[colliders]], or move the [[shapes]] outside them")
        raise NoFluidError(f"{sim.scene.source}: no fluid to simulate: {why}")


class Heartbeat:
    """A line (frame, steps, dt, seconds) at least every `interval_s` seconds while a frame runs,
    when `stream` is not a terminal (a log, a pipe, CI); a terminal has the progress bar."""

    def __init__(self, stream=None, interval_s: float = 30.0, clock=time.monotonic):
        self.stream = stream or sys.stderr
        self.interval_s, self.clock = interval_s, clock
        try:
            self.enabled = not self.stream.isatty()
        except (AttributeError, ValueError):  # a closed or file-like stream without isatty
            self.enabled = True
        self.last = clock()
        self.lines = 0

    def tick(self, frame: int, steps: int, dt: float, seconds: float) -> bool:
        """Call after each step: `frame` being computed, total `steps`, the last `dt` (s) and
        `seconds` of wall time since the run started. Returns whether a line was written."""
        now = self.clock()
        if not self.enabled or now - self.last < self.interval_s:
            return False
        self.last = now
        self.lines += 1
        self.stream.write(f"heartbeat: computing frame {frame}, {steps:,} steps, dt {dt:.3g} s, "
                          f"{seconds:.0f} s elapsed\n")
        self.stream.flush()
        return True
