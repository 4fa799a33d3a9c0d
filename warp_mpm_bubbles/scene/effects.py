"""The optional effects a scene may ask for, as data: [effects.*] tables, [[emitters]] and
[[colliders]]. Each is checked like the rest of the scene (one SceneError naming key and fix).

    [effects.foam]               gas reaching open air becomes foam that rides the surface and drains
    [effects.subgrid_bubbles]    bubbles under ~2 cells as Lagrangian particles with drag
    [effects.entrainment]        sub-grid bubbles seeded where a splash traps air
    [effects.viscosity]          solver = "auto" | "explicit" | "implicit" (viscosity is on the materials)
    [[emitters]]  type = "liquid_inflow" | "gas_injector"
    [[colliders]] type = "sphere" | "box" | "cylinder" | "glass"

A scene that names none of them runs none of their stages (Scene.effects lists what runs).
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from .checks import AXES, _Checker, _did_you_mean, _g, derive, dim_why
from ..core.stage import registered_settings
from .limits import Limit

BOUNDARIES = ("no_slip", "free_slip")
MAX_BUBBLE_RATE = 1.0e5  # bubbles per second from one gas injector
COLLIDER_TYPES = ("sphere", "box", "cylinder", "glass")


def _material(c: _Checker, key, name, scene, kinds):
    mats = scene.materials
    if not isinstance(name, str) or name not in mats:
        c.fail(key, name, f"no such material; defined materials: {', '.join(mats)}{_did_you_mean(name, mats)}")
    if mats[name].kind not in kinds:
        c.fail(key, name, f"material '{name}' is {mats[name].kind}; expected a {' or '.join(kinds)} material")
    return name


def _window(c: _Checker, key, start, stop):
    """A time window [start, stop); stop None means until the end of the run."""
    start = c.number(f"{key}.start", start, ge=0)
    if stop is not None:
        stop = c.number(f"{key}.stop", stop, gt=start)
    return start, stop


def _active_between(emitter, t0: float, t1: float) -> bool:
    return emitter.start <= t1 and (emitter.stop is None or emitter.stop > t0)


def _inside_domain(c: _Checker, key, point, scene, what):
    size = np.array(scene.domain.size)
    p = np.array(point)
    if (p < 0).any() or (p > size).any():
        c.fail(key, list(point), f"{what} {_g(p)} is outside the domain {_g(0 * size)} .. {_g(size)}; move it "
                                 f"inside or enlarge [domain].size")


# ------------------------------------------------------------------------------------- effects
@dataclass
class Foam:
    """Gas that reaches open air becomes foam particles riding the surface instead of leaving; the
    liquid in their films drains by the foam-drainage equation (docs/foam.md)."""

    material: str = "foam"  # a kind = "foam" material (its prototype); created with defaults if absent
    # Mean seconds before a foam particle bursts (exponential lifetimes): Bikerman's decay time of
    # the head, whose volume falls as exp(-t / lifetime).
    lifetime: float = 2.0
    # "random": each lifetime from a hash of (seed, id); "stratified": from a low-discrepancy
    # sequence over the ids (the same exponential law, without sampling noise)
    lifetimes: str = "random"
    rise_speed: float = 0.25  # m/s: foam pushed under the surface floats back up at most this fast
    drainage: bool = True  # drain the films' liquid by the foam-drainage equation
    bubble_radius: float = 5.0e-4  # m, of the foam's bubbles (sets the Plateau borders' size)
    liquid_fraction: float = 0.2  # of new foam (liquid volume / foam volume)
    viscosity: float = 1.0e-3  # Pa s, of the liquid in the films
    surface_tension: float = 0.072  # N/m, of the films
    permeability_constant: float = 50.0  # Verbist's Plateau-border drag coefficient C (rigid walls ~50)
    # A two-way head: the foam rests and stacks on the water, loads it with its weight, and its
    # drained liquid returns to the water as particles (docs/foam.md, "The head")
    head: bool = False
    collapse: str = "lifetime"  # "lifetime": Bikerman's drawn lifetimes; "drainage": films burst when dry
    burst_fraction: float = 1.0e-3  # collapse = "drainage": films drier than this liquid fraction burst
    key: ClassVar[str] = "foam"

    def _validate(self, c: _Checker, t, scene):
        self.lifetime = c.number(f"{t}.lifetime", self.lifetime, gt=0)
        self.rise_speed = c.number(f"{t}.rise_speed", self.rise_speed, ge=0)
        _material(c, f"{t}.material", self.material, scene, ("foam",))
        self.lifetimes = c.choice(f"{t}.lifetimes", self.lifetimes, ("random", "stratified"))
        self.drainage = c.flag(f"{t}.drainage", self.drainage)
        self.bubble_radius = c.number(f"{t}.bubble_radius", self.bubble_radius, ge=Limit(
            1e-6, "m: smaller bubbles are not a draining foam; give the radius in metres (0.5 mm: 5e-4)"),
            le=Limit(0.05, "m: bubbles larger than this are no foam; give the radius in metres (0.5 mm: 5e-4)"))
        self.liquid_fraction = c.number(f"{t}.liquid_fraction", self.liquid_fraction, gt=0, le=Limit(
            0.36, "is random close packing: wetter, the bubbles separate and it is a bubbly liquid, not a foam; "
                  "a fresh beer head is about 0.2"))
        self.viscosity = c.number(f"{t}.viscosity", self.viscosity, gt=0, le=1000)
        self.surface_tension = c.number(f"{t}.surface_tension", self.surface_tension, gt=0, le=3)
        self.permeability_constant = c.number(f"{t}.permeability_constant", self.permeability_constant, gt=0,
                                              le=1e6)
        self.head = c.flag(f"{t}.head", self.head)
        self.collapse = c.choice(f"{t}.collapse", self.collapse, ("lifetime", "drainage"))
        self.burst_fraction = c.number(f"{t}.burst_fraction", self.burst_fraction, gt=0, lt=Limit(
            self.liquid_fraction, "is the new foam's liquid_fraction: it would burst as it forms; set a value "
                                  "below it (films burst near 0.001)"))
        if self.head and not any(scene.domain.gravity):
            c.fail(f"{t}.head", self.head, "a head rests on the water by its weight: give [domain].gravity, or "
                   "set head = false")
        if self.head and not any(m.kind == "liquid" for m in scene.materials.values()):
            c.fail(f"{t}.head", self.head, "a head rests on liquid: define a [materials.NAME] with kind = "
                   "\"liquid\", or set head = false")
        if self.collapse == "drainage" and not (self.head and self.drainage):
            c.fail(f"{t}.collapse", self.collapse, "films burst when drainage thins them, on a two-way head: set "
                   "head = true and drainage = true, or collapse = \"lifetime\"")


@dataclass
class SubgridBubbles:
    """Bubbles smaller than `radius` as Lagrangian particles with buoyancy and drag."""

    radius: float | None = None  # resolved <-> sub-grid threshold, m; None: one cell (diameter 2 cells)
    convert_every: int = 10  # steps between the (host-side) checks that convert bubbles both ways
    shrink_ratio: float = 0.5  # resolved gas clusters under this share of the threshold volume turn sub-grid
    key: ClassVar[str] = "subgrid_bubbles"

    def _validate(self, c: _Checker, t, scene):
        if self.radius is None:
            derive(self, "radius", scene.domain.dx)
        self.radius = c.number(f"{t}.radius", self.radius, gt=0)
        self.convert_every = c.number(f"{t}.convert_every", self.convert_every, ge=1, whole=True)
        # Below 1 so a bubble just converted one way is not converted straight back (hysteresis).
        self.shrink_ratio = c.number(f"{t}.shrink_ratio", self.shrink_ratio, gt=0, lt=1)
        if not any(m.is_gas for m in scene.materials.values()):
            c.fail(t, {}, "sub-grid bubbles are gas: define a [materials.NAME] with kind = \"gas\"")


@dataclass
class Entrainment:
    """Sub-grid bubbles seeded where a splash traps air (Ihmsen et al. 2012's trapped-air measure)."""

    bubble_radius: float | None = None  # m, the median; None: half the sub-grid threshold
    # Standard deviation of ln(radius), as the gas injector's radius_spread; 0: all the same size.
    # Draws lie within 3 standard deviations and at most the sub-grid radius (a larger one is resolved).
    bubble_radius_spread: float = 0.0
    # The potential is the mean approach speed of a cell and its neighbours, so on a grid it is a
    # velocity difference across about one cell: a ball plunging at 1.5 m/s into 5 mm cells gives
    # 0.25..0.5 m/s over its splash and 1.2 m/s at most (examples/plunge.toml).
    rate: float = 20.0  # bubbles per cell per second at full trapped-air potential
    min_speed: float = 0.25  # m/s: relative speeds below this trap no air
    max_speed: float | None = None  # m/s: the potential saturates here; None: 4 min_speed (Ihmsen's 5..20)
    key: ClassVar[str] = "entrainment"

    def _validate(self, c: _Checker, t, scene):
        sub = scene.effects.get("subgrid_bubbles")
        if sub is None:
            c.fail(t, {}, "entrainment seeds sub-grid bubbles: add an [effects.subgrid_bubbles] table")
        if self.bubble_radius is None:
            derive(self, "bubble_radius", 0.5 * sub.radius)
        self.bubble_radius = c.number(f"{t}.bubble_radius", self.bubble_radius, gt=0, le=sub.radius)
        self.bubble_radius_spread = c.number(f"{t}.bubble_radius_spread", self.bubble_radius_spread, ge=0, le=1)
        self.rate = c.number(f"{t}.rate", self.rate, ge=0)
        self.min_speed = c.number(f"{t}.min_speed", self.min_speed, ge=0)
        if self.max_speed is None:
            self.max_speed = 4.0 * self.min_speed if self.min_speed > 0 else 1.0
        self.max_speed = c.number(f"{t}.max_speed", self.max_speed, gt=self.min_speed)


VISCOUS_SOLVERS = ("auto", "explicit", "implicit")


@dataclass
class Viscosity:
    """How the viscous stress is integrated in time (the viscosity itself is on the materials).

    explicit: forward Euler under the "viscous" step limit; implicit: backward Euler by PCG, no
    limit; auto: explicit while its limit is not below the step the other limits allow.
    """

    solver: str = "auto"
    tolerance: float = 1.0e-5  # PCG: relative residual
    max_iterations: int = 500
    key: ClassVar[str] = "viscosity"

    def _validate(self, c: _Checker, t, scene):
        if self.solver not in VISCOUS_SOLVERS:
            c.fail(f"{t}.solver", self.solver,
                   "expected one of 'auto' (explicit while it needs no extra steps, else implicit), 'explicit' "
                   f"or 'implicit'{_did_you_mean(self.solver, VISCOUS_SOLVERS)}; set solver = \"auto\" if unsure")
        self.tolerance = c.number(f"{t}.tolerance", self.tolerance, gt=0, lt=1)
        self.max_iterations = c.number(f"{t}.max_iterations", self.max_iterations, ge=1, whole=True)
        if not any(m.viscosity > 0 for m in scene.materials.values()):
            c.fail(t, {}, "no material has viscosity > 0, so nothing would use it: set "
                          "[materials.NAME].viscosity (Pa s) or remove [effects.viscosity]")


class _EffectTypes(Mapping):
    """The settings of each [effects.KEY] table: the built-in ones, then those of the stages from
    outside the package, asked of the stage registry (core/stage.py, register_stage) when read, so
    a stage registered after this module loaded is known to every scene checked after it."""

    def __init__(self, builtin: dict):
        self._builtin = builtin

    def _all(self) -> dict:
        return {**self._builtin, **registered_settings()}

    def __getitem__(self, key):
        return self._all()[key]

    def __iter__(self):
        return iter(self._all())

    def __len__(self):
        return len(self._all())


EFFECT_TYPES = _EffectTypes({cls.key: cls for cls in (Foam, SubgridBubbles, Entrainment, Viscosity)})


# ------------------------------------------------------------------------------------ emitters
@dataclass
class LiquidInflow:
    """A pouring stream: liquid enters through a disk (a segment in 2D) at a set speed."""

    material: str
    center: tuple
    direction: tuple
    radius: float
    speed: float
    start: float = 0.0
    stop: float | None = None  # s; None: for the whole run
    type_name: ClassVar[str] = "liquid_inflow"

    def _validate(self, c: _Checker, key, scene):
        dim = scene.dim
        _material(c, f"{key}.material", self.material, scene, ("liquid",))
        self.center = c.vector(f"{key}.center", self.center, dim, dim_why(dim))
        _inside_domain(c, f"{key}.center", self.center, scene, "the nozzle centre")
        self.direction = c.vector(f"{key}.direction", self.direction, dim, dim_why(dim))
        norm = math.hypot(*self.direction)  # no overflow or underflow for huge or tiny components
        if norm == 0.0 or not math.isfinite(norm):
            c.fail(f"{key}.direction", list(self.direction), "must not be zero: the direction the stream flows")
        self.direction = tuple(d / norm for d in self.direction)
        self.radius = c.number(f"{key}.radius", self.radius, gt=0, le=0.5 * min(scene.domain.size))
        self._check_nozzle_inside(c, key, scene)
        self.speed = c.number(f"{key}.speed", self.speed, gt=0)
        self.start, self.stop = _window(c, key, self.start, self.stop)

    def _check_nozzle_inside(self, c: _Checker, key, scene):
        """The nozzle (a disc across `direction`; in 2D a segment) lies inside the domain: liquid laid
        past a wall would be pressed onto it, crowding the wall's cells (water squeezed), and the
        stream would bring less than speed x area."""
        size = np.asarray(scene.domain.size, float)
        half = self.radius * np.sqrt(np.clip(1.0 - np.square(self.direction), 0.0, 1.0))  # its half-extent per axis
        lo, hi = np.asarray(self.center) - half, np.asarray(self.center) + half
        slack = 1e-9 * size
        if (lo < -slack).any() or (hi > size + slack).any():
            c.fail(f"{key}.radius", self.radius,
                   f"the nozzle spans {_g(lo)} .. {_g(hi)}, past the domain {_g(0 * size)} .. {_g(size)}: move "
                   f"{key}.center at least that far inside the walls, or use a smaller radius")

    def speed_between(self, t0: float, t1: float) -> float:
        return self.speed if _active_between(self, t0, t1) else 0.0

    @property
    def volume_rate(self) -> float:
        """m^3/s (3D) or m^2/s (2D: per unit slab thickness)."""
        return self.speed * (math.pi * self.radius**2 if len(self.center) == 3 else 2.0 * self.radius)


@dataclass
class GasInjector:
    """An air stone: gas bubbles released at a set rate with a log-normal size distribution."""

    material: str
    center: tuple
    rate: float  # bubbles per second
    radius: float  # median bubble radius, m
    radius_spread: float = 0.0  # standard deviation of ln(radius); 0: all the same size
    spread: float = 0.0  # bubbles start uniformly within this distance of the centre, m
    velocity: tuple | None = None
    start: float = 0.0
    stop: float | None = None
    type_name: ClassVar[str] = "gas_injector"

    def _validate(self, c: _Checker, key, scene):
        dim = scene.dim
        _material(c, f"{key}.material", self.material, scene, ("gas",))
        self.center = c.vector(f"{key}.center", self.center, dim, dim_why(dim))
        _inside_domain(c, f"{key}.center", self.center, scene, "the injector centre")
        # Bubbles are emitted one by one on the host: beyond MAX_BUBBLE_RATE use entrainment instead.
        self.rate = c.number(f"{key}.rate", self.rate, gt=0, le=MAX_BUBBLE_RATE)
        half = 0.5 * min(scene.domain.size)  # larger bubbles or spreads do not fit in the domain
        self.radius = c.number(f"{key}.radius", self.radius, gt=0, le=half)
        self.radius_spread = c.number(f"{key}.radius_spread", self.radius_spread, ge=0, le=1)
        self.spread = c.number(f"{key}.spread", self.spread, ge=0, le=half)
        self.velocity = (0.0,) * dim if self.velocity is None else self.velocity
        self.velocity = c.vector(f"{key}.velocity", self.velocity, dim, dim_why(dim))
        self.start, self.stop = _window(c, key, self.start, self.stop)
        if self.radius < scene.domain.dx and "subgrid_bubbles" not in scene.effects:
            c.fail(f"{key}.radius", self.radius,
                   f"bubbles under one grid cell ({_g(scene.domain.dx)} m) are not resolved by the grid: add "
                   f"[effects.subgrid_bubbles], or use a radius >= that")


    def speed_between(self, t0: float, t1: float) -> float:
        return math.hypot(*self.velocity) if _active_between(self, t0, t1) else 0.0


EMITTER_TYPES = {cls.type_name: cls for cls in (LiquidInflow, GasInjector)}


# ----------------------------------------------------------------------------------- colliders
@dataclass
class Collider:
    """A solid analytic shape, static or moving during [start, stop) with `velocity` and
    `acceleration` (a dropped ball: acceleration = gravity), at rest where it got to after `stop`.

    sphere: center, radius. box: center, size (full extents). cylinder: center, radius, axis,
    length. glass: an open cup standing on `center` (the bottom's centre), opening along +axis:
    radius (outer), height, wall_thickness.
    """

    type: str
    center: tuple
    radius: float | None = None
    size: tuple | None = None
    axis: str = "y"
    length: float | None = None
    height: float | None = None
    wall_thickness: float | None = None
    velocity: tuple | None = None
    acceleration: tuple | None = None
    start: float = 0.0
    stop: float | None = None
    boundary: str = "no_slip"

    NEEDS: ClassVar[dict] = {"sphere": ("radius",), "box": ("size",), "cylinder": ("radius", "length"),
                             "glass": ("radius", "height", "wall_thickness")}

    def _validate(self, c: _Checker, key, scene):
        dim, dx = scene.dim, scene.domain.dx
        self.type = c.choice(f"{key}.type", self.type, COLLIDER_TYPES)
        needs = self.NEEDS[self.type]
        for name in ("radius", "size", "length", "height", "wall_thickness"):
            given = getattr(self, name) is not None
            if name in needs and not given:
                c.missing(f"{key}.{name}", f"a {self.type} collider needs {', '.join(needs)}")
            if name not in needs and given:
                c.fail(f"{key}.{name}", getattr(self, name), f"a {self.type} collider has no {name} "
                                                             f"(it takes {', '.join(needs)}); remove it")
        self.center = c.vector(f"{key}.center", self.center, dim, dim_why(dim))
        if self.size is not None:
            self.size = c.vector(f"{key}.size", self.size, dim, dim_why(dim), gt=0)
        for name in ("radius", "length", "height", "wall_thickness"):
            if getattr(self, name) is not None:
                setattr(self, name, c.number(f"{key}.{name}", getattr(self, name), gt=0))
        self.axis = c.choice(f"{key}.axis", self.axis, AXES[:dim])
        if self.type == "glass":
            # The grid sees a solid wall only where a cell centre is inside it.
            if self.wall_thickness < dx:
                c.fail(f"{key}.wall_thickness", self.wall_thickness,
                       f"must be >= one grid cell ({_g(dx)} m) for the grid to see the wall; thicken it "
                       f"or refine the grid")
            if self.wall_thickness >= self.radius:
                c.fail(f"{key}.wall_thickness", self.wall_thickness, f"must be < radius = {_g(self.radius)}")
        self.velocity = (0.0,) * dim if self.velocity is None else self.velocity
        self.velocity = c.vector(f"{key}.velocity", self.velocity, dim, dim_why(dim))
        self.acceleration = (0.0,) * dim if self.acceleration is None else self.acceleration
        self.acceleration = c.vector(f"{key}.acceleration", self.acceleration, dim, dim_why(dim))
        self.start, self.stop = _window(c, key, self.start, self.stop)
        if self.stop is None and any(a != 0.0 for a in self.acceleration):
            c.fail(f"{key}.stop", None, "an accelerating collider needs a stop time (s), or it speeds up forever")
        self.boundary = c.choice(f"{key}.boundary", self.boundary, BOUNDARIES)

    @property
    def moves(self) -> bool:
        return any(v != 0.0 for v in self.velocity + self.acceleration)

    def center_at(self, t: float) -> np.ndarray:
        """Where the centre is at time t (the same path colliders.shape_center follows)."""
        tau = min(max(t, self.start), math.inf if self.stop is None else self.stop) - self.start
        return np.array(self.center) + np.array(self.velocity) * tau + 0.5 * tau * tau * np.array(self.acceleration)

    def half_extents(self, dim: int) -> tuple[np.ndarray, np.ndarray]:
        """How far the shape reaches below and above its centre on each axis (a glass stands on
        its centre, opening along +axis)."""
        r = self.radius or 0.0
        lo, hi = np.full(dim, r), np.full(dim, r)
        a = "xyz".index(self.axis)
        if self.type == "box":
            lo = hi = 0.5 * np.asarray(self.size, float)
        elif self.type == "cylinder" and a < dim:
            lo[a] = hi[a] = 0.5 * self.length
        elif self.type == "glass" and a < dim:
            lo[a], hi[a] = 0.0, self.height
        return lo, hi

    def swept_bounds(self, t_end: float) -> tuple[np.ndarray, np.ndarray]:
        """The box the collider covers at some time in [0, t_end]: its centre moves on a parabola per
        axis, whose extremes lie at the ends of the window, where it starts or stops, or at its turn."""
        times = [0.0, t_end, self.start] + ([] if self.stop is None else [self.stop])
        times += [self.start - v / a for v, a in zip(self.velocity, self.acceleration) if a != 0.0]
        centres = np.array([self.center_at(min(max(t, 0.0), t_end)) for t in times])
        lo, hi = self.half_extents(len(self.center))
        return centres.min(axis=0) - lo, centres.max(axis=0) + hi

    def speed_between(self, t0: float, t1: float) -> float:
        """The fastest it moves during [t0, t1] (the velocity is linear in time while it moves)."""
        t0, t1 = max(t0, self.start), min(t1, math.inf if self.stop is None else self.stop)
        if t0 > t1:
            return 0.0
        v0, a = np.array(self.velocity), np.array(self.acceleration)
        return float(max(np.linalg.norm(v0 + a * (t - self.start)) for t in (t0, t1)))
