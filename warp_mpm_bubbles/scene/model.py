"""Scenes as data: a TOML file and the Python API build the same dataclasses.

Everything goes through `Scene.validate`, which refuses bad input with ONE
`SceneError` naming the file, the key path (`[shapes.1].radius`), the value
given and what is allowed, before any simulation work starts.
"""
from __future__ import annotations

import copy
import math
import os
import tempfile
from dataclasses import dataclass, field, fields, MISSING
from pathlib import Path
from typing import ClassVar

import numpy as np

try:
    import tomllib
except ModuleNotFoundError:  # Python < 3.11
    import tomli as tomllib

from .checks import AXES, SceneError, _Checker, _g, _plain, derive, dim_why, underive
from .quality import GOVERNED
from .effects import EFFECT_TYPES, EMITTER_TYPES, Collider, Foam
from .limits import (
    Limit, MAX_DENSITY, MAX_FPS, MAX_FRAMES, MAX_GAMMA, MAX_GRAVITY, MAX_PRESSURE, MAX_SPEED, MAX_SURFACE_TENSION,
    MAX_VISCOSITY, MIN_AMBIENT, MIN_CELL, MIN_DENSITY, MIN_FPS, check_sampling, check_steps,
)
from .capacity import check_injection, check_pour
from .solver import SolverSettings
from .shapes import SHAPE_TYPES, Box, Cylinder, Sphere  # noqa: F401  (re-exported: scene.model.Box)
from ..core.seeding import shape_seeds_particles
from ..io.paths import output_path_problem

WALL_TYPES = ("no_slip", "free_slip", "open")
WALL_KEYS = ("x_min", "x_max", "y_min", "y_max", "z_min", "z_max")
MATERIAL_KINDS = ("liquid", "gas", "foam")  # foam: made by [effects.foam] from gas at the surface
GAS_LAWS = ("isothermal", "adiabatic", "incompressible")  # p = B rho, p ~ rho^gamma, density ratio only
# Per-kind defaults: water, and air at 20 C and 1 atm.
KIND_DEFAULTS = {"liquid": {"density": 1000.0, "color": (0.2, 0.45, 0.9)},
                 "gas": {"density": 1.2, "color": (0.92, 0.95, 1.0), "eos": "isothermal"},
                 "foam": {"density": 50.0, "color": (1.0, 1.0, 1.0)}}  # foam: ~5% liquid, the rest air
OUTPUT_FORMATS = ("instancer", "points", "both")
UP_AXES = ("Y", "Z")
MIN_RADIUS_SHARE = 1.0e-3  # [output].particle_radius at least this share of the default radius
MAX_CELLS = 2**30  # 1024^3: beyond it the grid outgrows a GPU's memory and int32 launch indices
USD_SUFFIXES = (".usd", ".usdc", ".usda")


# A scene refuses magnitudes beyond the bounds in scene/limits.py, each refusal with its reason.


@dataclass
class Domain:
    """The box the simulation fills, from the origin to `size`.

    Attributes:
        size: extent in metres: 2 numbers make a 2D run (a slab one cell thick), 3 a 3D run;
            each a whole number (>= 4) of cells; at most 2^30 cells in all.
        cell_size: grid spacing in metres (>= 1 micrometre; [solver].refine subdivides it).
        gravity: m/s^2, one number per axis (default (0, -9.81[, 0])); magnitude at most 1,000.
        walls: "free_slip" | "no_slip" | "open" for all walls, or per wall
            {"x_min": ..., "y_max": "open", ...}; open walls let fluid and gas leave.
        ambient_pressure: Pa (default 101325): the air outside the liquid, and gas at its rest
            density; 1 Pa to 1e9 Pa.
    """

    size: tuple[float, ...]
    cell_size: float
    gravity: tuple[float, ...] | None = None
    walls: dict[str, str] | str = "free_slip"
    ambient_pressure: float = 101325.0  # Pa: the air outside the liquid, and gas at its rest density
    refine: ClassVar[int] = 1  # grid cells per cell_size along each axis: [solver].refine, set by validate

    @property
    def dim(self) -> int:
        return len(self.size)

    @property
    def dx(self) -> float:
        """The simulation's grid spacing: cell_size / [solver].refine."""
        return self.cell_size / self.refine

    @property
    def cells(self) -> tuple[int, int, int]:
        n = tuple(int(round(s / self.cell_size)) * self.refine for s in self.size)
        return n if len(n) == 3 else (*n, 1)

    @property
    def wall_types(self) -> tuple[int, ...]:
        walls = self.walls if isinstance(self.walls, dict) else dict.fromkeys(WALL_KEYS, self.walls)
        # a 2D run is one cell thick in z; its z faces behave as free slip
        return tuple(WALL_TYPES.index(walls.get(k, "free_slip") if k[0] != "z" or self.dim == 3 else "free_slip")
                     for k in WALL_KEYS)

    def _validate(self, c: _Checker):
        t = "[domain]"
        if isinstance(self.size, (str, bytes)) or not isinstance(self.size, (list, tuple, np.ndarray)) \
                or len(self.size) not in (2, 3):
            c.fail(f"{t}.size", self.size, "expected 2 numbers (2D run) or 3 numbers (3D run), each > 0")
        self.size = c.vector(f"{t}.size", self.size, len(self.size), gt=0)
        h = self.cell_size = c.number(f"{t}.cell_size", self.cell_size, gt=0, ge=MIN_CELL)
        dim = self.dim
        for a, s in enumerate(self.size):
            n = s / h
            if n > MAX_CELLS:  # (a count this large, or infinite, has no whole number to check)
                c.fail(f"{t}.size", self.size,
                       f"{AXES[a]} = {_g(s)} is {n:.3g} cells of cell_size {_g(h)}; at most {MAX_CELLS:.3g} cells "
                       f"fit in memory and in Warp's 32-bit indices: shrink [domain].size or enlarge [domain].cell_size")
            if abs(n - round(n)) > 1e-6 * n:
                fits = " or ".join(f"{m * h:.10g} ({m} cells)" for m in (math.floor(n), math.ceil(n)) if m >= 1)
                c.fail(f"{t}.size", self.size,
                       f"{AXES[a]} = {_g(s)} is {n:.6g} cells of cell_size {_g(h)}, not a whole number; "
                       f"use {AXES[a]} = {fits}, or a cell_size that divides it")
            if round(n) < 4:
                c.fail(f"{t}.size", self.size,
                       f"{AXES[a]} = {_g(s)} gives only {round(n)} cells of cell_size {_g(h)}; at least 4 "
                       f"are needed: enlarge [domain].size or reduce [domain].cell_size")
        if self.gravity is None:
            self.gravity = (0.0, -9.81, 0.0)[:dim]
        self.gravity = c.vector(f"{t}.gravity", self.gravity, dim, dim_why(dim))
        c.magnitude(f"{t}.gravity", self.gravity, MAX_GRAVITY)
        self.walls = self._resolve_walls(c, dim)
        self.ambient_pressure = c.number(f"{t}.ambient_pressure", self.ambient_pressure, gt=0, ge=MIN_AMBIENT,
                                         le=MAX_PRESSURE)

    def _check_total(self, c, refine):
        total = math.prod(round(s / self.cell_size) * refine for s in self.size)
        if total > MAX_CELLS:
            c.fail("[domain].size", self.size,
                   f"gives {total:.3g} cells of {_g(self.cell_size / refine)} m (cell_size {_g(self.cell_size)}, "
                   f"refine {refine}); at most {MAX_CELLS:.3g} fit in memory and in Warp's 32-bit indices: shrink "
                   f"[domain].size, enlarge [domain].cell_size or lower [solver].refine")

    def _resolve_walls(self, c, dim):
        keys = WALL_KEYS[: 2 * dim]
        if isinstance(self.walls, str):
            return dict.fromkeys(keys, c.choice("[domain].walls", self.walls, WALL_TYPES))
        if not isinstance(self.walls, dict):
            c.fail("[domain].walls", self.walls,
                   f"expected a wall type ({', '.join(WALL_TYPES)}) or a table like {{ x_min = \"no_slip\" }}")
        for k, v in self.walls.items():
            if dim == 2 and k in WALL_KEYS[4:]:
                c.fail(f"[domain].walls.{k}", v, "z walls exist only in 3D scenes ([domain].size has 2 "
                                                 f"entries); allowed keys: {', '.join(keys)}")
        c.unknown_keys("[domain].walls", self.walls, keys)
        return {k: c.choice(f"[domain].walls.{k}", self.walls.get(k, "free_slip"), WALL_TYPES) for k in keys}


@dataclass
class Material:
    """A fluid: its kind, density, colour and, for a liquid, surface tension and viscosity.

    Attributes:
        name: the material's key in Scene.materials (shapes and emitters refer to it).
        kind: "liquid" (default) | "gas" | "foam" (made by the foam effect, not placed by shapes).
        density: kg/m^3 (gas: at the ambient pressure), 1e-3 to 1e5; None: water 1000,
            air 1.2, foam 50.
        color: (red, green, blue), each 0..1, for the USD prototype; None: per-kind default.
        eos: gas only: "isothermal" (default, p proportional to density) | "adiabatic"
            (p ~ density^gamma) | "incompressible" (a density ratio only).
        gamma: adiabatic index (dimensionless, > 1, <= 3; air 1.4), used by eos = "adiabatic".
        surface_tension: N/m, liquid only (water-air 0.072; at most 3); 0 skips the stage.
        viscosity: dynamic viscosity, Pa s (water 1.0e-3, air 1.8e-5; at most 1,000);
            0 everywhere skips the stage.
    """

    name: str
    kind: str = "liquid"
    density: float | None = None  # kg/m^3 (gas: at the ambient pressure); None -> per-kind default
    color: tuple[float, float, float] | None = None
    eos: str | None = None  # gas only: isothermal (default) | adiabatic | incompressible
    gamma: float = 1.4  # adiabatic index, used by eos = "adiabatic"
    surface_tension: float = 0.0  # liquid only, N/m (water-air 0.072); 0 = the stage does not run
    viscosity: float = 0.0  # dynamic, Pa s (water 1.0e-3, air 1.8e-5); 0 everywhere = the stage does not run

    @property
    def is_gas(self) -> bool:
        return self.kind == "gas"

    def _validate(self, c: _Checker, key):
        t = f"[materials.{key}]"
        if self.name != key:
            c.fail(f"{t}.name", self.name, f"must equal its key '{key}' in Scene.materials")
        self.kind = c.choice(f"{t}.kind", self.kind, MATERIAL_KINDS)
        defaults = KIND_DEFAULTS[self.kind]
        self.density = c.number(f"{t}.density", defaults["density"] if self.density is None else self.density,
                                gt=0, ge=MIN_DENSITY, le=MAX_DENSITY)
        self.color = c.vector(f"{t}.color", defaults["color"] if self.color is None else self.color, 3,
                              " (red, green, blue)", ge=0, le=1)
        if self.kind == "gas":
            self.eos = c.choice(f"{t}.eos", defaults["eos"] if self.eos is None else self.eos, GAS_LAWS)
            self.gamma = c.number(f"{t}.gamma", self.gamma, gt=1, le=MAX_GAMMA)
        elif self.eos is not None:
            c.fail(f"{t}.eos", self.eos, f"only gas materials have an equation of state; remove it or set "
                                         f"{t}.kind = \"gas\"")
        self.surface_tension = c.number(f"{t}.surface_tension", self.surface_tension, ge=0, le=MAX_SURFACE_TENSION)
        self.viscosity = c.number(f"{t}.viscosity", self.viscosity, ge=0, le=MAX_VISCOSITY)
        if self.kind == "gas" and self.surface_tension > 0:
            c.fail(f"{t}.surface_tension", self.surface_tension,
                   "surface tension belongs to the liquid (it acts on its surface with gas and air); "
                   "set it on the liquid material")
        if self.kind == "foam":  # foam rides the surface one-way: it has no stress of its own
            for name in ("surface_tension", "viscosity"):
                if getattr(self, name) > 0:
                    c.fail(f"{t}.{name}", getattr(self, name), f"foam takes no {name} (it moves with the liquid's "
                                                               f"surface); remove the key or set it on the liquid")


@dataclass
class Output:
    """Where and how the animation is written.

    Attributes:
        path: the USD file (.usd, .usdc or .usda); its frames go to <stem>_frames/ beside it.
        fps: frames per second of simulated time (0.01 to 1e5; default 30); also the stage's
            timeCodesPerSecond.
        frames: frames simulated after the initial one (1..1,000,000): frames + 1 samples,
            time codes 0..frames.
        format: "instancer" (UsdGeomPointInstancer, default) | "points" (UsdGeomPoints) | "both".
        particle_radius: m, for the spheres drawn; None: half the particle spacing; at least a
            thousandth of that, at most half the domain's smallest extent.
        up_axis: "Y" (default) | "Z", the stage's upAxis.
        surface: also write the liquid's surface mesh per frame (/World/LiquidSurface; io/surface.py).
        surface_resolution: surface grid cells per simulation cell and axis (1..8; default 2).
        surface_smoothing: the surface kernel's radius, in simulation cells (0.5..4; default 1.25).
    """

    path: str = "out.usdc"
    fps: float = 30.0
    frames: int = 60
    format: str = "instancer"
    particle_radius: float | None = None
    up_axis: str = "Y"
    surface: bool = False  # the liquid's surface mesh per frame (io/surface.py)
    surface_resolution: int = 2  # surface grid cells per simulation cell and axis; <= 8 (512 nodes a cell)
    surface_smoothing: float = 1.25  # kernel radius, cells: 1.0 leaves voids, > 4 rounds all but the tank away

    def _validate(self, c: _Checker, scene: Scene):
        t = "[output]"
        if isinstance(self.path, os.PathLike):
            self.path = os.fspath(self.path)
        if not isinstance(self.path, str) or Path(self.path).suffix.lower() not in USD_SUFFIXES:
            c.fail(f"{t}.path", self.path, "expected a file name ending in .usd, .usdc or .usda")
        self._check_writable(c, f"{t}.path")
        self.fps = c.number(f"{t}.fps", self.fps, gt=0, ge=MIN_FPS, le=MAX_FPS)
        self.frames = c.number(f"{t}.frames", self.frames, ge=1, le=MAX_FRAMES, whole=True)
        self.format = c.choice(f"{t}.format", self.format, OUTPUT_FORMATS)
        if self.particle_radius is None:
            derive(self, "particle_radius", self.default_radius(scene))
        small, large = MIN_RADIUS_SHARE * self.default_radius(scene), Limit(
            0.5 * min(scene.domain.size), "m: half the domain's smallest extent; one particle's sphere would "
                                          "be wider than the domain and hide the rest")
        self.particle_radius = c.number(f"{t}.particle_radius", self.particle_radius, gt=0, le=large, ge=Limit(
            small, f"m: {MIN_RADIUS_SHARE:g} times the default (half the particle spacing, "
                   f"{_g(self.default_radius(scene))} m); smaller spheres show as nothing, and usually mean a "
                   f"unit mistake (mm for m)"))
        self.up_axis = c.choice(f"{t}.up_axis", self.up_axis, UP_AXES)
        self.surface = c.flag(f"{t}.surface", self.surface)
        self.surface_resolution = c.number(f"{t}.surface_resolution", self.surface_resolution, ge=1, le=8, whole=True)
        self.surface_smoothing = c.number(f"{t}.surface_smoothing", self.surface_smoothing, ge=0.5, le=4)

    @staticmethod
    def default_radius(scene) -> float:
        """Half the particle spacing: neighbouring spheres just touch."""
        return 0.5 * scene.domain.dx / scene.solver.particles_per_cell ** (1 / scene.dim)

    def _check_writable(self, c, key):
        # Refuse now rather than after a long run; missing directories are fine (the writer creates them).
        too_long = output_path_problem(self.path)  # before any stat: an over-long name makes stat raise
        if too_long:
            c.fail(key, self.path, too_long)
        target = Path(self.path).absolute()
        if target.is_dir():
            c.fail(key, self.path, "is a directory; give a file name ending in .usdc")
        if target.exists() and not os.access(target, os.W_OK):
            c.fail(key, self.path, "the file exists and is not writable")
        ancestor = target.parent
        while not ancestor.exists():
            ancestor = ancestor.parent
        if not ancestor.is_dir():
            c.fail(key, self.path, f"cannot create it: {ancestor} is not a directory")
        if not os.access(ancestor, os.W_OK | os.X_OK):
            c.fail(key, self.path, f"cannot write it: directory {ancestor} is not writable")
        # os.access trusts permission bits, which root passes everywhere: /proc, read-only mounts.
        # So try: create (and remove) a scratch file of our own in the directory the writer will use.
        try:
            fd, scratch = tempfile.mkstemp(prefix=".wmb-probe-", dir=ancestor)
            os.close(fd)
            os.unlink(scratch)
        except OSError as e:
            c.fail(key, self.path, f"cannot write it: creating a file in {ancestor} failed ({e.strerror}); "
                                   f"choose another directory (--stage-path or [output].path)")


@dataclass
class Scene:
    """A whole scene: what `load_scene` reads from TOML and `run_scene` simulates.

    Attributes:
        domain: Domain; materials: {name: Material}; shapes: [Box | Sphere | Cylinder], later
            shapes overwriting earlier ones; solver: SolverSettings; output: Output.
        effects: {"foam": Foam, "subgrid_bubbles": SubgridBubbles, "entrainment": Entrainment}.
        emitters: [LiquidInflow | GasInjector]; colliders: [Collider].
        name: shown in the summary (TOML: the file's stem); source: the file, for messages.

    `validate()` checks everything and fills the defaults (raises SceneError naming the key).
    """

    domain: Domain
    materials: dict[str, Material]
    shapes: list[Box | Sphere | Cylinder]
    solver: SolverSettings = field(default_factory=SolverSettings)
    output: Output = field(default_factory=Output)
    effects: dict = field(default_factory=dict)  # [effects.NAME] settings: Foam, SubgridBubbles, Entrainment
    emitters: list = field(default_factory=list)  # LiquidInflow, GasInjector
    colliders: list = field(default_factory=list)  # Collider
    name: str = "scene"
    source: str = "<python>"

    @property
    def dim(self) -> int:
        return self.domain.dim

    @property
    def effect_names(self) -> list[str]:
        """The effects this scene runs; a stage of any other effect never runs."""
        used = {s.material for s in self.shapes} | {e.material for e in self.emitters}
        mats = [self.materials[m] for m in used]
        names = ["gas"] if any(m.is_gas for m in mats) or "subgrid_bubbles" in self.effects else []
        names += ["colliders"] if self.colliders else []
        names += ["viscosity"] if any(m.viscosity > 0 for m in self.materials.values()) else []
        names += ["surface_tension"] if any(m.surface_tension > 0 for m in self.materials.values()) else []
        names += ["emitters"] if self.emitters else []
        return names + [k for k in EFFECT_TYPES if k in self.effects and k not in names]  # viscosity: both

    def validate(self) -> Scene:
        """Check everything and fill resolved defaults; raises SceneError. Idempotent."""
        c = _Checker(self.source)
        if not isinstance(self.name, str) or not self.name:
            c.fail("name", self.name, "expected a non-empty string")
        c.instance("[domain]", self.domain, Domain, "a Domain")
        self.domain._validate(c)
        c.instance("[solver]", self.solver, SolverSettings, "a SolverSettings")
        self.solver._validate(c, self.dim)
        self.domain._check_total(c, self.solver.refine)
        self.domain.refine = self.solver.refine
        c.instance("[materials]", self.materials, dict, "a table of materials keyed by name")
        if not self.materials:
            c.fail("[materials]", self.materials, "no materials defined; add one, e.g. [materials.water]")
        for key, m in self.materials.items():
            c.instance(f"[materials.{key}]", m, Material, "a Material")
            m._validate(c, key)
        _check_material_names(c, self.materials)
        self._validate_effects(c)
        c.instance("[shapes]", self.shapes, list, "a list of shapes ([[shapes]] tables)")
        if not self.shapes:
            c.fail("[shapes]", self.shapes, "no shapes defined; add at least one [[shapes]] table")
        for i, s in enumerate(self.shapes):
            c.instance(f"[shapes.{i}]", s, tuple(SHAPE_TYPES.values()), "a Box, Sphere or Cylinder")
            s._validate(c, f"[shapes.{i}]", self)
        c.instance("[output]", self.output, Output, "an Output")
        self.output._validate(c, self)
        for i, item in enumerate(self.emitters):
            self._check_speed(c, f"[emitters.{i}]", item)
        for i, item in enumerate(self.colliders):
            self._check_speed(c, f"[colliders.{i}]", item)
            self._check_reaches_domain(c, f"[colliders.{i}]", item)
        check_steps(c, self)  # a first frame needing millions of steps would run silently for hours
        check_pour(self)  # a closed domain poured over full packs the water several times over
        check_injection(self)  # nor can a closed domain full of water take in more gas than it can compress
        # Last: the only check that generates samples (after making sure one slab of them fits).
        check_sampling(self)
        ppc, seed = self.solver.particles_per_cell, self.solver.seed
        for i, s in enumerate(self.shapes):
            if not shape_seeds_particles(s, self.domain, ppc, seed):
                c.fail(f"[shapes.{i}]", s, f"seeds no particles: it is smaller than the particle spacing "
                                           f"({_g(self.domain.dx / ppc ** (1 / self.dim))}); enlarge it "
                                           f"or refine [domain].cell_size", shown=s.describe())
        return self

    def _validate_effects(self, c: _Checker):
        c.instance("[effects]", self.effects, dict, "a table of effects keyed by name")
        c.unknown_keys("[effects]", self.effects, tuple(EFFECT_TYPES))
        foam = self.effects.get("foam")
        if isinstance(foam, Foam) and foam.material == "foam" and "foam" not in self.materials:
            self.materials["foam"] = Material("foam", kind="foam")  # the default foam: white, 50 kg/m^3
            self.materials["foam"]._validate(c, "foam")
        for key, cls in EFFECT_TYPES.items():  # in this order: entrainment reads subgrid_bubbles
            if key in self.effects:
                c.instance(f"[effects.{key}]", self.effects[key], cls, f"a {cls.__name__}")
                self.effects[key]._validate(c, f"[effects.{key}]", self)
        for name, items, types in (("emitters", self.emitters, tuple(EMITTER_TYPES.values())),
                                   ("colliders", self.colliders, (Collider,))):
            c.instance(f"[{name}]", items, list, f"a list of [[{name}]] tables")
            for i, item in enumerate(items):
                c.instance(f"[{name}.{i}]", item, types, " or ".join(t.__name__ for t in types))
                item._validate(c, f"[{name}.{i}]", self)

    def _check_speed(self, c: _Checker, key, item):
        """Emitters and colliders obey the shapes' speed bound over the whole run (a collider
        accelerating until its stop time included)."""
        with np.errstate(over="ignore", invalid="ignore"):  # a huge acceleration: inf, refused below
            speed = item.speed_between(0.0, self.output.frames / self.output.fps)
        if not speed <= MAX_SPEED:
            c.fail(key, speed, f"moves at up to {speed:.3g} m/s during the run, more than {_g(MAX_SPEED)} "
                               f"{MAX_SPEED.why}; lower its speed, velocity or acceleration", shown=f"{speed:.3g} m/s")

    def _check_reaches_domain(self, c: _Checker, key, collider):
        """Refuse a collider that lies wholly outside the domain for the whole run: it does nothing,
        and is most likely a misplaced centre (a unit mistake, or a 3D position in a 2D scene)."""
        with np.errstate(over="ignore", invalid="ignore"):
            lo, hi = collider.swept_bounds(self.output.frames / self.output.fps)
        size = np.asarray(self.domain.size, float)
        if (hi <= 0.0).any() or (lo >= size).any():
            moving = " while it moves" if collider.moves else ""
            c.fail(f"{key}.center", list(collider.center),
                   f"the {collider.type} collider covers {_g(lo)} .. {_g(hi)}{moving}, wholly outside the domain "
                   f"{_g(0 * size)} .. {_g(size)}, so it would touch nothing; move its center inside the domain, "
                   f"or remove it")

    @classmethod
    def from_dict(cls, d: dict, source: str = "<dict>") -> Scene:
        c = _Checker(source)
        c.table("the scene", d)
        c.unknown_keys("", d, ("name", "domain", "solver", "materials", "shapes", "output", "effects", "emitters",
                               "colliders"))
        if "domain" not in d:
            c.missing("[domain]", "add a [domain] table with size and cell_size")
        domain = _build(c, Domain, "[domain]", d["domain"])
        materials = {}
        for key, m in c.table("[materials]", d.get("materials", {})).items():
            materials[key] = _build(c, Material, f"[materials.{key}]", m, name=key)
        shapes = d.get("shapes", [])
        if not isinstance(shapes, list):
            c.fail("[shapes]", shapes, "expected a list of shapes: write each as a [[shapes]] table")
        built = []
        for i, s in enumerate(shapes):
            key = f"[shapes.{i}]"
            s = dict(c.table(key, s))
            if "type" not in s:
                c.missing(f"{key}.type", f"expected one of {', '.join(SHAPE_TYPES)}")
            kind = c.choice(f"{key}.type", s.pop("type"), tuple(SHAPE_TYPES))
            built.append(_build(c, SHAPE_TYPES[kind], key, s))
        raw_effects = c.table("[effects]", d.get("effects", {}))
        c.unknown_keys("[effects]", raw_effects, tuple(EFFECT_TYPES))
        effects = {k: _build(c, EFFECT_TYPES[k], f"[effects.{k}]", v) for k, v in raw_effects.items()}
        emitters = []
        for i, e in enumerate(_table_list(c, "emitters", d)):
            key = f"[emitters.{i}]"
            e = dict(e)
            if "type" not in e:
                c.missing(f"{key}.type", f"expected one of {', '.join(EMITTER_TYPES)}")
            emitters.append(_build(c, EMITTER_TYPES[c.choice(f"{key}.type", e.pop("type"), tuple(EMITTER_TYPES))],
                                   key, e))
        colliders = [_build(c, Collider, f"[colliders.{i}]", e) for i, e in enumerate(_table_list(c, "colliders", d))]
        scene = cls(
            domain=domain,
            materials=materials,
            shapes=built,
            solver=_build(c, SolverSettings, "[solver]", d.get("solver", {})),
            output=_build(c, Output, "[output]", d.get("output", {})),
            effects=effects,
            emitters=emitters,
            colliders=colliders,
            name=d.get("name", "scene"),
            source=source,
        )
        return scene.validate()

    @classmethod
    def from_toml(cls, path) -> Scene:
        path = Path(path)
        source = str(path)
        try:
            # Editors on Windows save UTF-8 with a byte-order mark, which tomllib refuses as an
            # invalid statement at line 1: the mark says nothing about the scene, so drop it.
            d = tomllib.loads(path.read_bytes().decode("utf-8").removeprefix("\ufeff"))
        except FileNotFoundError:
            raise SceneError(f"{source}: scene file not found", "", source, "an existing .toml file") from None
        except OSError as e:
            raise SceneError(f"{source}: cannot read scene file: {e.strerror}", "", source) from None
        except UnicodeDecodeError:
            raise SceneError(f"{source}: not UTF-8 text; save the scene file as UTF-8", "", source) from None
        except tomllib.TOMLDecodeError as e:  # its message ends with "(at line L, column C)"
            last = len(path.read_text(errors="replace").splitlines()) or 1
            msg = str(e).replace("(at end of document)", f"(at end of document, line {last})")
            raise SceneError(f"{source}: invalid TOML: {msg}", "", source, "valid TOML syntax") from None
        d.setdefault("name", path.stem)
        return cls.from_dict(d, source=source)

    def to_dict(self) -> dict:
        """Plain TOML-shaped data (lists, no None) that from_dict accepts back."""
        return {
            "name": self.name,
            "domain": _plain(self.domain),
            "solver": _plain(self.solver),
            "materials": {k: _plain(m, skip=("name",)) for k, m in self.materials.items()},
            "shapes": [{"type": s.type_name, **_plain(s)} for s in self.shapes],
            "output": _plain(self.output),
            "effects": {k: _plain(e) for k, e in self.effects.items()},
            "emitters": [{"type": e.type_name, **_plain(e)} for e in self.emitters],
            "colliders": [_plain(e) for e in self.colliders],
        }

    def with_quality(self, quality: str) -> Scene:
        """A validated copy at another quality preset; the preset replaces the scene's own values."""
        new = copy.deepcopy(self)
        for obj in (new.output, *new.effects.values()):  # defaults derived from the grid: derive again
            underive(obj)
        new.solver.quality = quality
        for name in GOVERNED:
            setattr(new.solver, name, None)
        return new.validate()

    def replace_output(self, path=None, frames=None) -> Scene:
        """A validated copy with another output path and/or frame count."""
        new = copy.deepcopy(self)
        if path is not None:
            new.output.path = os.fspath(path)
        if frames is not None:
            new.output.frames = frames
        return new.validate()


def _check_material_names(c: _Checker, materials):
    """Refuse names that differ only by case ("Water" and "water"): USD prim names and the users
    who pick materials by name mix them up, and one would silently stand for the other."""
    seen = {}
    for key in materials:
        other = seen.setdefault(str(key).casefold(), key)
        if other != key:
            c.fail(f"[materials.{key}]", key, f"differs from [materials.{other}] only by case; material names "
                                               f"must differ by more than case: rename one, or merge them")


def _table_list(c: _Checker, name, d) -> list:
    items = d.get(name, [])
    if not isinstance(items, list):
        c.fail(f"[{name}]", items, f"expected a list: write each as a [[{name}]] table")
    return [c.table(f"[{name}.{i}]", e) for i, e in enumerate(items)]


def _build(c: _Checker, cls, key, d, **given):
    """Construct a dataclass from a TOML table, refusing unknown and missing keys."""
    c.table(key, d)
    names = [f.name for f in fields(cls) if f.name not in given]
    c.unknown_keys(key, d, names)
    required = [f.name for f in fields(cls) if f.default is MISSING and f.default_factory is MISSING]
    for name in required:
        if name not in d and name not in given:
            c.missing(f"{key}.{name}", f"required keys: {', '.join(n for n in required if n not in given)}")
    return cls(**d, **given)


def load_scene(path) -> Scene:
    """Load and validate a TOML scene file."""
    return Scene.from_toml(path)
