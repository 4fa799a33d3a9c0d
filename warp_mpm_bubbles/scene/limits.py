"""What a scene may ask of the solver and of the machine, checked before any work starts.

- Magnitude bounds (LIMITS): each with the reason beside it, so the refusal can say why.
- The steps a frame needs, estimated from the scene alone (the CFL, capillary, viscous, gas
  expansion and max_dt limits at the start): a scene whose first frame would take more than
  [solver].max_steps_per_frame steps is refused instead of running silently for hours.
- Memory: particles and grid arrays in bytes, estimated before seeding, compared with what the
  host (and a GPU) has, refused with the figure and the fix.
- Colliders that cover every seeded particle.

Nothing here imports Warp: `warp-mpm-bubbles check` stays instant.
"""
from __future__ import annotations

import math
import os

import numpy as np

from .checks import SceneError, _g


class Limit(float):
    """A bound that carries its reason (a float everywhere a number is expected)."""

    def __new__(cls, value, why: str):
        obj = super().__new__(cls, value)
        obj.why = why
        return obj


# The bounds, each with its reason. Every example and test scene sits well inside them.
MAX_SPEED = Limit(1.0e3, "m/s: an incompressible liquid cannot move near water's speed of sound (1,480 m/s)")
MAX_GRAVITY = Limit(1.0e3, "m/s^2: about 100 g, a high-g centrifuge; beyond it no water-and-air flow holds together")
MIN_FPS = Limit(1.0e-2, "frames per second: one frame per 100 s of simulated time at the slowest")
MAX_FPS = Limit(1.0e5, "frames per second: 10 microsecond frames, shorter than any step the solver takes")
MAX_FRAMES = Limit(1_000_000, "frames: 9 hours of animation at 30 fps; split longer runs into shots")
MIN_DENSITY = Limit(1.0e-3, "kg/m^3: air at 50 km altitude; rarer gas makes the pressure system singular")
MAX_DENSITY = Limit(1.0e5, "kg/m^3: four times osmium (22,590), the densest element")
MAX_VISCOSITY = Limit(1.0e3, "Pa s: a hundred times honey; past it the implicit viscous solve needs "
                             "thousands of iterations a step (the explicit step, rho dx^2 / (4 dim mu), millions)")
MAX_SURFACE_TENSION = Limit(3.0, "N/m: molten metals reach about 2 (water 0.072)")
MIN_AMBIENT = Limit(1.0, "Pa: near vacuum; the gas law divides by it")
MAX_PRESSURE = Limit(1.0e9, "Pa: 10,000 atmospheres, where water itself compresses by a third")
# A gas at gauge pressure p drives the liquid beside it at about sqrt(p / density). The liquid is
# solved as incompressible, which holds below Mach 0.3; past it the liquid's rebound crushes the gas
# to ever higher pressures, and the gas_expansion step with them: measured on a 2D 40 x 40 cell tank
# (5 mm cells, a 3 cm bubble), 1e9 and 5e8 Pa stopped in frame 2 (steps of 2e-7 s, over 100,000 a
# frame) while 2e8 Pa ran its frames in 1,600 steps each.
MAX_LIQUID_MACH = 0.3
WATER_SOUND_SPEED = 1480.0  # m/s
MIN_CELL = Limit(1.0e-6, "m: one micrometre; below it the continuum model and float32 positions fail")
MAX_GAMMA = Limit(3.0, "the adiabatic index of real gases lies between 1 and 5/3")
MAX_CG_ITERATIONS = Limit(1_000_000, "iterations: beyond this a solve that has not converged never will")
MIN_VOLUME_RELAXATION = Limit(1.0e-3, "s: a faster correction turns the seeding noise into speeds of about "
                                     "0.1 cell_size / time (1 m/s at 1 cm cells), which the particles keep; "
                                     "0 turns it off")
MAX_VOLUME_RELAXATION = Limit(1.0e3, "s: a correction slower than this undoes nothing a run can see; "
                                     "0 turns it off")
DEFAULT_VOLUME_RELAXATION = 0.01  # s, when no speed is set; why: docs/design.md, #volume-correction
MIN_VOLUME_CORRECTION_SPEED = Limit(1.0e-2, "m/s: a relaxation of a second at 1 cm cells undoes nothing a run can "
                                            "see; [solver].volume_relaxation_time = 0 turns the correction off")
MAX_VOLUME_CORRECTION_SPEED = Limit(10.0, "m/s: the 1 ms floor at 1 cm cells; faster turns the seeding noise into "
                                          "speeds of about 0.03-0.1 times it")
MAX_STEPS_PER_FRAME = 100_000  # default [solver].max_steps_per_frame
MAX_STEPS_LIMIT = Limit(1.0e8, "steps per frame: a setting above this disables the guard")

LIMITS = {  # key -> bound, for docs/api.md and the README
    "shape, emitter and collider speed": MAX_SPEED, "[domain].gravity (magnitude)": MAX_GRAVITY,
    "[output].fps (min)": MIN_FPS, "[output].fps (max)": MAX_FPS, "[output].frames / --num-frames": MAX_FRAMES,
    "[materials.*].density (min)": MIN_DENSITY, "[materials.*].density (max)": MAX_DENSITY,
    "[materials.*].viscosity": MAX_VISCOSITY, "[materials.*].surface_tension": MAX_SURFACE_TENSION,
    "[domain].ambient_pressure (min)": MIN_AMBIENT, "[domain].ambient_pressure, [shapes].pressure": MAX_PRESSURE,
    "[domain].cell_size (min)": MIN_CELL, "[materials.*].gamma": MAX_GAMMA,
    "[solver].cg_max_iterations": MAX_CG_ITERATIONS, "[solver].volume_relaxation_time (min)": MIN_VOLUME_RELAXATION,
    "[solver].volume_relaxation_time (max)": MAX_VOLUME_RELAXATION,
    "[solver].volume_correction_speed (min)": MIN_VOLUME_CORRECTION_SPEED,
    "[solver].volume_correction_speed (max)": MAX_VOLUME_CORRECTION_SPEED,
}


def max_gauge_pressure(materials) -> Limit:
    """The largest initial gauge pressure of a gas shape: MAX_PRESSURE, or less where it would drive
    the lightest liquid past MAX_LIQUID_MACH (with no liquid: MAX_PRESSURE, the steps check decides)."""
    liquids = [m.density for m in materials.values() if m.kind == "liquid"]
    if not liquids:
        return MAX_PRESSURE
    rho, speed = min(liquids), MAX_LIQUID_MACH * WATER_SOUND_SPEED
    if rho * speed**2 >= MAX_PRESSURE:
        return MAX_PRESSURE
    return Limit(rho * speed**2, f"Pa: the gas would drive the liquid (density {rho:g} kg/m^3) at sqrt(pressure / "
                                 f"density), over {speed:.0f} m/s, Mach {MAX_LIQUID_MACH:g} of water's speed of sound: "
                                 f"there the incompressible liquid's rebound crushes the gas to ever higher "
                                 f"pressures and the run's steps shrink until it stops; start the gas lower")


# ------------------------------------------------------------------------- steps per frame
def step_limits(scene) -> dict[str, float]:
    """The time-step limits (s) at the start of the run, as core.Simulation.stable_dt computes them
    from the live state: "cfl", "capillary", "viscous", "gas_expansion", "max_dt" (those that apply)."""
    s, d = scene.solver, scene.domain
    dx, dim = d.dx, scene.dim
    frame = 1.0 / scene.output.fps
    speed = max([math.hypot(*sh.velocity) for sh in scene.shapes]
                + [item.speed_between(0.0, frame) for item in (*scene.emitters, *scene.colliders)])
    speed += math.sqrt(math.hypot(*d.gravity) * dx)
    limits = {"cfl": s.cfl * dx / speed if speed > 0.0 else math.inf}
    mats = list(scene.materials.values())
    liquids = [m for m in mats if m.kind == "liquid"]
    sigma = max((m.surface_tension for m in liquids), default=0.0)
    if sigma > 0.0:
        rho = max((m.density for m in liquids), default=0.0) + max((m.density for m in mats if m.is_gas), default=0.0)
        limits["capillary"] = math.sqrt(rho * dx**3 / (4.0 * math.pi * sigma))
    nu = max((m.viscosity / m.density for m in mats if m.kind != "foam"), default=0.0)
    visc = scene.effects.get("viscosity")
    if nu > 0.0 and getattr(visc, "solver", "auto") == "explicit":  # auto and implicit need no extra steps
        limits["viscous"] = dx**2 / (4 * dim * nu)  # the stress form's grad div doubles the Laplacian's rate
    gas = gas_expansion_step(scene)
    if gas < math.inf:
        limits["gas_expansion"] = gas
    if s.max_dt is not None:
        limits["max_dt"] = s.max_dt
    return limits


def gas_expansion_step(scene) -> float:
    """physics/gas.py's pressure_step at the start: a gas shape seeded at a gauge pressure beyond any
    hydrostatic head in the domain moves the liquid at sqrt(dp / rho) (kept in step with it here,
    without importing Warp)."""
    d, mats = scene.domain, scene.materials
    gauge = max((abs(sh.pressure) for sh in scene.shapes if sh.pressure), default=0.0)
    liquids = [m.density for m in mats.values() if m.kind == "liquid"] or [m.density for m in mats.values()]
    g = math.hypot(*d.gravity)
    up = int(np.argmax(np.abs(d.gravity))) if g > 0.0 else -1
    dp = gauge - (max(liquids) * g * d.size[up] if up >= 0 else 0.0)
    return scene.solver.cfl * d.dx / math.sqrt(dp / min(liquids)) if dp > 0.0 else math.inf


# What to change when a limit makes frames too long, by the limit's name.
STEP_FIXES = {
    "cfl": ("[solver].cfl", "lower the shapes', emitters' or colliders' speeds or [domain].gravity, or use a "
                            "coarser [domain].cell_size"),
    "capillary": ("[materials].surface_tension", "lower surface_tension or use a coarser [domain].cell_size "
                                                 "(the capillary step grows as cell_size^1.5)"),
    "viscous": ("[materials].viscosity", "set [effects.viscosity].solver = \"auto\" (implicit, no viscous "
                                         "limit), lower viscosity or use a coarser [domain].cell_size "
                                         "(the viscous step grows as cell_size^2)"),
    "gas_expansion": ("[shapes].pressure", "start the gas nearer the surrounding liquid's pressure (its gauge "
                                           "[shapes].pressure), or use a coarser [domain].cell_size (the gas "
                                           "expansion step grows as cell_size)"),
    "max_dt": ("[solver].max_dt", "raise [solver].max_dt or remove it"),
}


def steps_message(steps: float, limit_name: str, dt: float, frame_dt: float, most: int) -> str:
    """One sentence: how many steps, which limit and what to change (shared with io/guards.py)."""
    fix = STEP_FIXES.get(limit_name, ("", "use a coarser [domain].cell_size"))[1]
    return (f"a frame of {_g(frame_dt)} s would need {steps:.3g} steps of {dt:.3g} s (the {limit_name} limit), "
            f"more than [solver].max_steps_per_frame = {most:,}: {fix}; or raise [output].fps for shorter "
            f"frames, or raise [solver].max_steps_per_frame if you mean it")


def check_steps(c, scene):
    """Refuse a scene whose first frame needs more than [solver].max_steps_per_frame steps."""
    limits = step_limits(scene)
    name = min(limits, key=limits.get)
    dt, frame_dt, most = limits[name], 1.0 / scene.output.fps, scene.solver.max_steps_per_frame
    steps = frame_dt / dt if dt > 0 else math.inf
    if steps > most:
        key = STEP_FIXES.get(name, ("[domain].cell_size",))[0]
        raise SceneError(f"{scene.source}: {key}: {steps_message(steps, name, dt, frame_dt, most)}", key, steps,
                         f"at most {most} steps per frame")


# ------------------------------------------------------------------------------------ memory
PARTICLE_DEVICE_BYTES = 104  # x, v vec3; C mat33; mass, vol0, J, phase, active, material, gas_law, gas_gamma; ids int64
PARTICLE_HOST_BYTES = 160  # seeding (float64 samples, float32 results) and Simulation.add_particles' numpy copies
EFFECT_PARTICLE_BYTES = 32  # foam, sub-grid bubbles and emitters add their own per-particle fields
FACE_ARRAYS, GAS_FACE_ARRAYS = 21, 6  # 7 face fields x 3 axes; the gas's own field with a sharp interface
CELL_ARRAYS, GAS_CELL_ARRAYS = 9 + 4, 8  # state, system and the PCG vectors; gas mass, volume, law terms
MULTIGRID_ARRAYS = {2: 10 / 3, 3: 10 / 7}  # coarse levels: 10 arrays on 1/4 (1/8), 1/16 (1/64)... of the cells
EFFECT_CELL_ARRAYS = 4  # tension's level set and curvature, colliders' owner index, effects' counters
HEADROOM = 1.25  # Warp's allocator, Python, USD and the checkpoint copies


def estimate_particles(scene) -> int:
    """The particles seeding makes, from the shapes' volumes (an upper bound: overlaps counted twice),
    capped at every cell filled; computed without seeding."""
    d = scene.domain
    dim, dx, ppc = scene.dim, d.dx, scene.solver.particles_per_cell
    total = 0.0
    for s in scene.shapes:
        lo, hi = s.bounds()
        box = float(np.prod(np.asarray(hi) - np.asarray(lo)))
        if s.type_name == "sphere":
            box *= math.pi / 4 if dim == 2 else math.pi / 6
        elif s.type_name == "cylinder" and (dim == 3 or s.axis == "z"):  # a 2D cylinder along x or y: a box
            box *= math.pi / 4
        total += box / dx**dim * ppc
    cells = math.prod(d.cells[:dim])
    return round(min(total, cells * ppc))


def slab_bytes(scene) -> float:
    """Host bytes to sample one x-slab of cells (seeding and validation do it slab by slab):
    the random keys, the argsort and the float64 positions of every sub-cell of the y-z section."""
    d = scene.domain
    k = 1
    while k**scene.dim < scene.solver.particles_per_cell:
        k += 1
    return math.prod(d.cells[1:scene.dim]) * k**scene.dim * 8 * (3 + scene.dim)


def check_sampling(scene):
    """Refuse before sampling a slab of cells that does not fit in the host's memory (a domain
    thin in x with a huge y-z section would otherwise die in numpy inside validation)."""
    need, have = HEADROOM * slab_bytes(scene), host_available()
    if have is not None and need > have:
        raise MemoryLimitError(scene, estimate_memory(scene), "host memory to sample one slab of cells", need, have)


def estimate_memory(scene) -> dict[str, float]:
    """Bytes the run needs: "particles", "grid" (both on the device) and "host" (the host's share
    besides the device arrays: seeding and copies), with "count" and "cells"."""
    d = scene.domain
    dim = scene.dim
    count = estimate_particles(scene)
    cells = math.prod(n + 2 for n in d.cells[:dim])  # with the ghost layers
    gas = any(m.is_gas for m in scene.materials.values()) or "subgrid_bubbles" in scene.effects
    extra = bool(scene.effects or scene.emitters)
    faces = FACE_ARRAYS + (GAS_FACE_ARRAYS if gas else 0)
    arrays = faces + CELL_ARRAYS + (GAS_CELL_ARRAYS if gas else 0) + EFFECT_CELL_ARRAYS + MULTIGRID_ARRAYS[dim]
    return {
        "count": count, "cells": cells,
        "particles": HEADROOM * count * (PARTICLE_DEVICE_BYTES + (EFFECT_PARTICLE_BYTES if extra else 0)),
        "grid": HEADROOM * cells * 4 * arrays,
        "host": HEADROOM * (count * PARTICLE_HOST_BYTES + slab_bytes(scene)),
    }


def host_available() -> int | None:
    """Bytes of host memory available now (MemAvailable), or None where it cannot be read."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def _gb(n: float) -> str:
    return f"{n / 1e9:.3g} GB"


def check_memory(scene, host_bytes=None, device_bytes=None, device_name: str = "cpu"):
    """Refuse (MemoryLimitError) a scene that will not fit: the host must hold the seeding copies
    (and, on the CPU device, the particle and grid arrays too); a GPU its particles and grid.
    host_bytes None: read /proc/meminfo; device_bytes None: no GPU to check. Returns the estimate."""
    est = estimate_memory(scene)
    host_bytes = host_available() if host_bytes is None else host_bytes
    on_cpu = device_bytes is None or str(device_name).startswith("cpu")
    arrays = est["particles"] + est["grid"]
    need_host = est["host"] + (arrays if on_cpu else 0.0)
    where = [("host memory", need_host, host_bytes)] + ([] if on_cpu else [(f"{device_name} memory", arrays,
                                                                              device_bytes)])
    for what, need, have in where:
        if have is not None and need > have:
            raise MemoryLimitError(scene, est, what, need, have)
    return est


class MemoryLimitError(SceneError):
    """The scene needs more memory than the machine has; the message gives the figures and the fix."""

    def __init__(self, scene, est, what, need, have):
        d, s = scene.domain, scene.solver
        ratio = need / max(have, 1)
        coarser = d.cell_size * ratio ** (1 / scene.dim) * 1.1
        msg = (f"{scene.source}: needs about {_gb(need)} of {what} but {_gb(have)} is available: "
               f"{est['count']:,} particles ({_gb(est['particles'])}) at {s.particles_per_cell} per cell and "
               f"{est['cells']:,} grid cells ({_gb(est['grid'])}); use a coarser [domain].cell_size "
               f"(about {coarser:.3g} m instead of {_g(d.cell_size)}), fewer [solver].particles_per_cell, "
               f"a smaller [domain].size or a lower --quality")
        super().__init__(msg, "[domain].cell_size", d.cell_size, f"at most {_gb(have)} of {what}")
        self.need, self.have = need, have


# --------------------------------------------------------------------------------- colliders
def inside_collider(collider, points: np.ndarray, dim: int) -> np.ndarray:
    """Which points are inside the collider at t = 0 (the numpy twin of effects.colliders'
    signed_distance < 0, used to find scenes whose colliders swallow all the fluid)."""
    d = np.asarray(points, np.float64)[:, :dim] - np.asarray(collider.center_at(0.0))[:dim]
    if collider.type == "sphere":
        return np.linalg.norm(d, axis=1) < collider.radius
    if collider.type == "box":
        return np.all(np.abs(d) < 0.5 * np.asarray(collider.size), axis=1)
    a = "xyz".index(collider.axis)
    radial = np.linalg.norm(np.delete(d, a, axis=1), axis=1) if dim == 3 else np.abs(d[:, 1 - a])
    if collider.type == "cylinder":
        return (radial < collider.radius) & (np.abs(d[:, a]) < 0.5 * collider.length)
    h, t = collider.height, collider.wall_thickness  # glass: the cup minus its cavity
    cup = (radial < collider.radius) & (d[:, a] > 0.0) & (d[:, a] < h)
    return cup & ~((radial < collider.radius - t) & (d[:, a] > t))


def check_colliders_leave_fluid(scene, positions: np.ndarray):
    """Refuse a scene whose colliders cover every seeded particle (nothing would be simulated)."""
    if not scene.colliders or len(positions) == 0 or scene.emitters:
        return
    covered = np.zeros(len(positions), bool)
    for col in scene.colliders:
        covered |= inside_collider(col, positions, scene.dim)
    if covered.all():
        raise SceneError(f"{scene.source}: [colliders]: the colliders cover all {len(positions):,} seeded "
                         f"particles, so no fluid is left to simulate; move or shrink the colliders, or move "
                         f"the [[shapes]] outside them", "[colliders]", None, "some fluid outside the colliders")
