"""Run a scene to a USD file: the frame loop, the progress bar and the closing summary.

Shared by the command line (`warp-mpm-bubbles run`) and the example scripts.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass

import numpy as np

from .checkpoint import checkpoint_path, load_checkpoint, resumable_checkpoint, save_checkpoint
from ..core.simulation import Simulation, SimulationError
from .devices import check_device, check_memory
from .fill import check_domain_fill
from .guards import Heartbeat, check_fluid_left, frame_step_guard
from .ownership import OutputClaim, OutputError, frames_dir, write_failed
from .streams import RunLog, now, safe_stream
from .usd_colliders import write_colliders
from .usd_materials import dress_stage, scene_prototypes
from .surface import builder_for, liquid_surface
from .usd_output import StageWriter


@dataclass
class RunResult:
    simulation: Simulation
    stage_path: str
    frames_written: int
    wall_seconds: float


class ProgressBar:
    """One line redrawn in place on a terminal; on a log (CI, a file) a line every 10% of the run.
    The ETA is measured over the frames this process ran: a resumed run starts counting at `first`."""

    def __init__(self, total: int, stream=None, width: int = 28, first: int = 0):
        self.total, self.stream, self.width, self.first = total, stream or sys.stderr, width, first
        self.start = time.perf_counter()
        self.tty = self.stream.isatty()
        self._last_decile = -1

    def update(self, done: int, sim_time: float, steps: int):
        elapsed = time.perf_counter() - self.start
        ran = done - self.first
        eta = elapsed / ran * (self.total - done) if ran > 0 else 0.0
        filled = int(self.width * done / self.total)
        line = (f"frame {done:>4}/{self.total} [{'#' * filled}{'.' * (self.width - filled)}] "
                f"t={sim_time:.3f}s steps={steps} elapsed {_clock(elapsed)} ETA {_clock(eta)}")
        if self.tty:
            self.stream.write("\r" + line + ("\n" if done == self.total else ""))
        elif done * 10 // self.total != self._last_decile or done == self.total:
            self._last_decile = done * 10 // self.total
            self.stream.write(line + "\n")
        self.stream.flush()


def _clock(seconds: float) -> str:
    m, s = divmod(int(round(seconds)), 60)
    return f"{m}m{s:02d}s" if m else f"{s}s"


def run_scene(scene, *, device=None, progress: bool = True, log=None, resume: bool = False,
              overwrite: bool = False, on_frame=None) -> RunResult:
    """Simulate scene.output.frames frames after the initial one, writing each to scene.output.path.

    The output is locked for the run (a second run on it is refused, naming the holder) and an
    existing one is replaced only with overwrite=True, which deletes only files this project
    wrote; both are checked before any simulation work (io/ownership.py), and then the device
    and the memory the scene needs (io/devices.py). After every frame a checkpoint is saved beside
    the frames; resume=True continues from it (a killed run), keeping the frames already written,
    and is refused (ResumeRefused, before any work) when any setting but the frame count changed
    or the checkpoint is damaged (io/checkpoint.py). A failed write (a full disk) raises
    OutputWriteError, keeping the finished frames; a frame that would need more than
    [solver].max_steps_per_frame steps stops before it starts (io/guards.py). `on_frame(sim)` is
    called after each frame is written, frame 0 included. Progress, a heartbeat every 30 s on a
    log, and the closing summary go to `log` (default: the sys.stderr of the moment), which may
    close at any time without stopping the run; the summary, or the error that stopped the run,
    also goes to <stem>_frames/run.log (io/streams.py).
    """
    log = safe_stream(log or sys.stderr)
    start = time.perf_counter()
    scene = scene.validate()  # the memory estimate reads the filled-in defaults
    out = scene.output
    with OutputClaim(out.path, overwrite=overwrite, resume=resume, log=log) as claim:
        resume_from = resumable_checkpoint(scene, out.path) if resume else None  # refused before any work
        dev = check_device(device)
        check_memory(scene, dev)
        sim = Simulation(scene, device=dev)
        check_fluid_left(sim)
        resume_after = None
        if resume_from is not None:
            load_checkpoint(sim, resume_from)
            resume_after = sim.frame
            if progress:
                log.write(f"resuming {scene.name} after frame {sim.frame} (t = {sim.time:.3f} s)\n")
        run_log = RunLog(frames_dir(out.path), ready=lambda: claim.prepared)  # nothing before the output is ours
        try:
            _frame_loop(sim, claim, resume_after, log if progress else None, on_frame, run_log)
        except BaseException as err:
            run_log.write(_stopped(err))
            raise
        result = RunResult(sim, str(out.path), out.frames + 1, time.perf_counter() - start)
        text = summary(result)
        run_log.write(text)
    if progress:
        log.write(text + "\n")
    return result


def _stopped(err: BaseException) -> str:
    """The run log's line for what stopped a run, as the command line words it."""
    if isinstance(err, KeyboardInterrupt):
        return f"{now()} interrupted; the finished frames are kept: --resume continues the run"
    if isinstance(err, SimulationError):
        return f"{now()} error: {err}"
    return f"{now()} internal error (a bug in warp_mpm_bubbles): {type(err).__name__}: {err}"


def _frame_loop(sim: Simulation, claim, resume_after, log, on_frame, run_log) -> None:
    """Write frames until scene.output.frames; a failed write becomes OutputWriteError, and an error
    that stops the simulation gets the frame it was computing and the frames kept."""
    scene, out = sim.scene, sim.scene.output
    checkpoint = checkpoint_path(out.path)
    looks, prototype_of = scene_prototypes(scene)  # one per material, and the sub-grid bubbles' own
    materials = [(name, color) for name, _, color in looks]
    bar = ProgressBar(out.frames, stream=log, first=resume_after or 0) if log else None
    beat, started = Heartbeat(log) if log else None, time.perf_counter()

    def decorate(stage):
        dress_stage(stage, looks)  # UsdPreviewSurface materials on the prototypes and the surface
        if scene.colliders:  # the shapes (and paths) of the colliders, for the DCC to show
            write_colliders(stage, scene.colliders, scene.dim, sim.grid.dx, out.fps, out.frames)

    def on_step(dt, remaining):
        frame_step_guard(sim, remaining=remaining)  # a limit that collapses mid-frame stops the run
        if beat:
            beat.tick(sim.frame, sim.stats.steps, dt, time.perf_counter() - started)

    def write():
        done = _write(sim, writer, checkpoint, builder)
        if on_frame:
            on_frame(sim)
        return done

    writer, saved = None, resume_after  # saved: the frame the checkpoint on disk resumes after
    try:
        writer = StageWriter(out.path, fps=out.fps, materials=materials, particle_radius=out.particle_radius,
                             format=out.format, up_axis=out.up_axis, resume_after=resume_after,
                             decorate=decorate, claim=claim, surface=out.surface, prototype_of=prototype_of)
        run_log.write(_started(sim, claim, resume_after))
        builder = builder_for(sim, out.surface_resolution, out.surface_smoothing) if out.surface else None
        with writer:
            if resume_after is None:
                saved = write()
            while sim.frame < out.frames:
                frame_step_guard(sim)
                sim.advance_frame(on_step=on_step)
                check_domain_fill(sim)  # water squeezed into too small a room stops before it is written
                saved = write()
                if bar:
                    bar.update(sim.frame, sim.time, sim.stats.steps)
    except OSError as err:
        if bar and bar.tty:
            log.write("\n")
        kept = writer.last_frame if writer else resume_after  # a resumed output keeps its frames
        raise write_failed(err, out.path, kept, saved) from err
    except SimulationError as err:
        if bar and bar.tty:
            log.write("\n")
        if not isinstance(err, OutputError):  # a write error says what it kept
            _add_frames(err, sim, writer.last_frame if writer else resume_after)
        raise


def _started(sim: Simulation, claim, resume_after) -> str:
    out = sim.scene.output
    how = "started" if resume_after is None else f"resumed after frame {resume_after}"
    return (f"{now()} run {claim.run_id} {how}: {sim.scene.name} ({sim.scene.source}), frames to {out.frames} "
            f"at {out.fps:g} fps, device {sim.device}")


def _add_frames(err: SimulationError, sim: Simulation, last_written) -> None:
    """Append to err's message the frame being computed and the frames written and kept.
    advance_frame counts the frame before stepping it, and a frame that did not finish is not
    written: so the frame being computed is the one after the last written."""
    computing = 0 if last_written is None else last_written + 1
    out = sim.scene.output
    kept = "no frame was written" if last_written is None else \
        (f"frame 0 is written and kept in {out.path}" if last_written == 0
         else f"frames 0-{last_written} are written and kept in {out.path}")
    err.args = (f"{err.args[0] if err.args else err}; the run stopped computing frame {computing} of "
                f"{out.frames}: {kept}", *err.args[1:])


def _write(sim: Simulation, writer: StageWriter, checkpoint, builder=None) -> int:
    """The frame first (durable when write_frame returns), then the checkpoint that resumes after it."""
    surface = _surface(sim, builder)
    with sim.timer("output"):
        p = sim.particles_numpy()
        writer.write_frame(sim.frame, p["positions"], p["velocities"], p["ids"], p["material"],
                           output_radii(sim, p, writer.radius),
                           surface=surface, phase=p["phase"])
        save_checkpoint(sim, checkpoint)
    return sim.frame


def output_radii(sim: Simulation, p: dict, radius: float):
    """Each particle's radius in the frame (p: its read-out), where a stage owns some particles' size
    (real bubbles: the radius of their own volume) and `radius` for the rest; None when no stage
    does (every particle has the output radius)."""
    radii = None
    for stage in sim.stages:
        own = stage.output_radii(p)
        if own is not None:
            radii = np.full(len(p["phase"]), radius) if radii is None else radii
            radii[own[0]] = own[1]
    return radii


def _surface(sim: Simulation, builder):
    """The liquid's mesh this frame when [output].surface is on (its own line in the summary)."""
    if builder is None:
        return None
    with sim.timer("surface"):
        return liquid_surface(builder, sim.particles_numpy())


def _voids_line(sim: Simulation) -> str:
    """Particle-free regions closed off from the open air and from any gas (core/voids.py): the most at
    one step in any frame, and how many frames had some; then the bubble gaps, particle-free cells beside
    compressible gas (no extra device read)."""
    v = sim.voids
    gaps = ""
    if v.gaps_by_frame:
        frame, worst = max(v.gaps_by_frame.items(), key=lambda kv: (kv[1], -kv[0]))
        gaps = (f"; bubble gaps (particle-free cells beside the air, left for its gas to fill) in "
                f"{len(v.gaps_by_frame)} frames, at most {worst} cell{'s' * (worst != 1)} at one step (frame {frame})")
    if not v.by_frame:
        return f"  voids: none (no particle-free cell inside the liquid read as free surface){gaps}"
    frame, worst = max(v.by_frame.items(), key=lambda kv: (kv[1], -kv[0]))
    trapped = f", {v.pockets} trapped air pockets became bubbles" if v.pockets else ""
    return (f"  voids: {len(v.by_frame)} frames had cells closed off inside the liquid (at most {worst} at one "
            f"step, frame {frame}), filled as liquid{trapped}{gaps}")


def _relaxation(solver, dx: float) -> str:
    """The volume correction's relaxation time as the summary names it, with where it came from."""
    tau = solver.volume_relaxation(dx)
    if tau == 0:
        return "off"
    source = "fixed" if solver.volume_correction_speed is None else f"cell / {solver.volume_correction_speed:g} m/s"
    moves = ", moves positions" if solver.volume_correction_moves == "positions" else ""
    return f"{1e3 * tau:.3g} ms ({source}, {solver.volume_fill} fill{moves})"


def summary(result: RunResult) -> str:
    """Seconds per timed phase of the step, CG effort, particles and steps: what the run cost and where."""
    sim = result.simulation
    st, timer = sim.stats, sim.timer
    w = max([10, *(len(name) + 2 for name in timer.seconds)])  # the name column fits the longest name
    lines = [
        f"{sim.scene.name}: {result.frames_written} frames to {result.stage_path}, "
        f"{sim.time:.3f} s simulated in {st.steps} steps, {sim.num_particles:,} particles, "
        f"{sim.grid.dim}D {'x'.join(map(str, sim.grid.interior[:sim.grid.dim]))} cells, device {sim.device}",
        f"  {'phase':<{w}}{'seconds':>10}{'share':>8}{'ms/step':>10}",
    ]
    total = timer.total
    for name, seconds in timer.seconds.items():
        per_step = 1e3 * seconds / max(st.steps, 1)
        lines.append(f"  {name:<{w}}{seconds:>10.2f}{100 * seconds / total:>7.0f}%{per_step:>10.2f}")
    lines.append(f"  {'total':<{w}}{total:>10.2f}   (wall {result.wall_seconds:.2f} s incl. setup and compile)")
    mean = st.cg_iterations / max(st.cg_solves, 1)
    lines.append(f"  pressure CG: {st.cg_iterations:,} iterations over {st.cg_solves} solves "
                 f"(mean {mean:.1f}, max {st.cg_max_iterations}), worst residual {st.cg_worst_residual:.1e}"
                 + (f", {st.cg_unconverged} solves hit the iteration cap" if st.cg_unconverged else ""))
    if sim.volume_shift:  # timed with the pressure stage
        vs = sim.volume_shift
        lines.append(f"  volume shift CG (the correction's own solve): {vs.iterations:,} iterations over "
                     f"{vs.solves} solves (mean {vs.iterations / max(vs.solves, 1):.1f})")
    if sim.has_gas:
        b = sim.gas_budget()
        # shares of all the gas the run has had: the conserved total (seeded and injected) and the
        # air it took from the atmosphere (trapped pockets, entrained bubbles), which the total leaves out
        had = b["total"] + b["trapped"] + b["entrained"]
        share = lambda key: 100 * b[key] / had if had > 0 else 0.0  # noqa: E731
        held = "".join(f", {share(s.gas_held[0]):.1f}% {s.gas_held[1]}" for s in sim.stages if s.gas_held)
        gone = f", {share('left'):.1f}% out through open walls" if sim.open_walls else ""
        lines.append(f"  gas: {share('vented'):.1f}% of its mass vented to the atmosphere{gone}{held}, "
                     f"{b['volume'] * 1e6:.3g} cm^3 resolved left in the liquid")
    if sim.open_walls:
        liquid = sim.mass_budget()["liquid"]
        out = 100 * liquid["left"] / liquid["added"] if liquid["added"] > 0 else 0.0
        lines.append(f"  open walls: {out:.1f}% of the liquid's mass left through them ({liquid['left']:.4g} of "
                     f"{liquid['added']:.4g} kg seeded and emitted)")
    for stage in sim.stages:
        lines += stage.summary_lines(sim.ctx)
    lines.append(_voids_line(sim))
    if "surface" in timer.seconds:  # built once per frame, not per step
        lines.append(f"  surface mesh: {1e3 * timer.seconds['surface'] / result.frames_written:.0f} ms per frame")
    solver = sim.scene.solver
    lines.append(f"  quality {solver.quality}: cfl {solver.cfl:g}, cg_tolerance {solver.cg_tolerance:g}, "
                 f"{solver.particles_per_cell} particles per cell, refine {solver.refine} "
                 f"(cell {sim.grid.dx:.4g} m), volume relaxation {_relaxation(solver, sim.grid.dx)}; steps set by "
                 + ", ".join(f"{name} {100 * n / max(sum(st.limited_by.values()), 1):.0f}%"  # this process's
                             for name, n in sorted(st.limited_by.items(), key=lambda kv: -kv[1])))  # steps: not resumed ones
    lines.append(f"  effects: {', '.join(sim.effects) or 'none (liquid only)'}")
    lines.append(f"  phases timed: {', '.join(timer.phases_run)}")
    return "\n".join(lines)
