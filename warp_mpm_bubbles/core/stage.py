"""The stage protocol: how one piece of optional physics joins the step.

A stage is one class in one module that owns all of its physics (docs/design.md, "The step"):

- ``name``: the effect it implements, as `Scene.effect_names` lists it (the scene asks for it,
  the simulation builds it; a scene that does not ask never imports its module, so its kernels
  never compile).
- ``Settings``: the dataclass of its ``[effects.NAME]`` table, if it has one (keys and checks).
  Built-in settings sit in `scene/effects.py`, which imports no Warp, so validating a scene
  stays instant; a stage from outside the package keeps its settings in its own module.
- ``dt_limit(ctx)``: its time-step limit in seconds (``inf`` if none), named ``limit`` in
  `Simulation.dt_limits()` (the name scene/limits.py's step estimate and the step guard's advice
  use: "capillary", "viscous"); `Simulation.stable_dt` is the minimum of them all.
- ``incoming_speed(t0, t1)``: a speed it brings before any particle has it (emitters, moving
  colliders), added to the CFL limit.
- hooks at named points of the step (core/step.py's STEP, which tests/test_step.py holds this
  table to), in this order (each a no-op unless overridden)::

      begin_step      before p2g                       emitters add particles
      after_p2g       particle sums are on the grid    gas: mass, volume, pressure per cell
      on_momentum     u* = p/m + dt g is on the faces  sub-grid bubbles: drag reaction
      on_cells        cells are classified             colliders mark solids; gas phases
      on_faces        face densities are set           colliders' face velocities
      force           on u* before the solve           viscosity, surface tension, the foam head
      before_extend   u is projected                   gas: its own field (sharp interface)
      on_extended     a face field was extrapolated    colliders' face velocities again
      before_g2p      the grid is final                gas: volume change of its cells
      after_g2p       particles have moved             films, entrainment, bubbles, foam, venting
      end_step        last                             colliders push particles out

- ``timer``: the line its ``begin_step``, ``force``, ``after_g2p`` and ``end_step`` time goes to
  in the run summary (its other hooks are timed with the core stage they sit in).
- ``graph_safe``: its hooks at capturable points of the step launch device work only, with dt
  their only per-step value, so `Simulation.step_graph` may capture them in a CUDA graph (a stage
  that passes the time, or reads the host, says False and runs between the graphs).
- ``output_radii(particles)``, ``gas_held`` and ``summary_lines(ctx)``: what it adds to the output
  (radii of the bubbles it owns) and to the run summary, so io/ names no effect.
- what it checkpoints: per-particle arrays made with `ParticleState.add_field`, and ``state``, the
  dataclass of its small host values (derived from core/host_state.py's `HostState`), are saved
  and restored with everything else (`state_arrays`, `load_state`).

The built-in stages and the order stages take at a shared hook are not named here: the package
registers them when it loads (warp_mpm_bubbles/stages.py, `register_builtin_stages`), so the core
imports nothing above it.
"""

from __future__ import annotations

import importlib
import math
from typing import ClassVar

from .step import HOOKS

_builtin: dict[str, str] = {}  # effect name: "module:Class", imported on first use
_order: tuple[str, ...] = ()  # the built-in stages' order at every hook point
_registered: dict[str, type] = {}


class Stage:
    """Base class: every hook is a no-op and there is no time-step limit."""

    name: ClassVar[str] = ""
    Settings: ClassVar[type | None] = None
    timer: ClassVar[str | None] = None  # None: the stage's name
    limit: ClassVar[str | None] = None  # its dt_limit's name in Simulation.dt_limits(); None: the stage's name
    # True: its kernels at the grid hooks cover only `ctx.region` (the grid stages' box, with the
    # offset `ctx.region.lo`) and leave every cell outside it in the empty state (core/active_box.py).
    # A scene whose grid-hook stages all say so keeps the box; any other stage there: the whole grid.
    grid_box: ClassVar[bool] = False
    graph_safe: ClassVar[bool] = False  # may be captured in step_graph's CUDA graphs (module docstring)
    # The gas it holds, for the run summary's gas line: (key of Simulation.gas_budget(), words), e.g.
    # ("foam", "in foam"); None: none of its own.
    gas_held: ClassVar[tuple[str, str] | None] = None

    def __init__(self, ctx, settings=None):
        self.settings = settings
        self.state = None  # its HostState, if it keeps host values from step to step

    def state_arrays(self) -> dict:
        """Its host values by checkpoint name (io/checkpoint.py saves them)."""
        return self.state.arrays() if self.state is not None else {}

    def load_state(self, arrays: dict) -> None:
        """Take back those of its values `arrays` holds (a resumed run)."""
        if self.state is not None:
            self.state.load(arrays)

    @property
    def timer_name(self) -> str:
        return self.timer or self.name

    def hooks(self) -> set[str]:
        """The hook points this stage runs at: those its class overrides (a stage may drop one
        it does not need in this scene, so the step neither calls nor times it)."""
        return {h for h in HOOKS if getattr(type(self), h) is not getattr(Stage, h)}

    def dt_limit(self, ctx) -> float:
        return math.inf

    def incoming_speed(self, t0: float, t1: float) -> float:
        return 0.0

    def output_radii(self, particles: dict):
        """The particles of a frame's read-out (`Simulation.particles_numpy()`) it writes with a radius
        of their own, as (mask, radii in metres); None: it owns none (they take [output].particle_radius)."""
        return None

    def summary_lines(self, ctx) -> list[str]:
        """Lines of its own for the run summary (io/runner.py), after the mass budgets."""
        return []

    def begin_step(self, ctx, dt: float): ...
    def after_p2g(self, ctx, dt: float): ...
    def on_momentum(self, ctx, dt: float): ...
    def on_cells(self, ctx, dt: float): ...
    def on_faces(self, ctx, dt: float): ...
    def force(self, ctx, dt: float): ...
    def before_extend(self, ctx, dt: float): ...
    def on_extended(self, ctx, vel): ...
    def before_g2p(self, ctx, dt: float): ...
    def after_g2p(self, ctx, dt: float): ...
    def end_step(self, ctx, dt: float): ...


def register_stage(cls: type) -> type:
    """Add a stage from outside the package (usable as a class decorator). It runs only in scenes
    that have its ``[effects.NAME]`` table, whose keys its ``Settings`` dataclass checks (give it a
    ``key`` class attribute equal to the name and a ``_validate(checker, table, scene)`` method).
    Scenes learn of it from the registry (scene/effects.py asks `registered_settings`)."""
    if not (isinstance(cls, type) and issubclass(cls, Stage)) or not cls.name:
        raise TypeError("register_stage takes a Stage subclass with a name")
    if cls.name in _builtin:
        raise ValueError(f"'{cls.name}' is a built-in stage; choose another name")
    settings = cls.Settings
    if settings is None or getattr(settings, "key", None) != cls.name:
        raise TypeError(f"{cls.__name__}.Settings must be a dataclass with key = {cls.name!r}")
    _registered[cls.name] = cls
    return cls


def register_builtin_stages(table: dict[str, str], order: tuple[str, ...]) -> None:
    """The package's own stages ("module:Class" by effect name, imported only when a scene asks
    for one) and their order at a shared hook; stages registered from outside come after them."""
    global _order
    _builtin.update(table)
    _order = tuple(order)


def registered_settings() -> dict[str, type]:
    """The settings dataclass of each stage registered from outside the package, by effect name."""
    return {name: cls.Settings for name, cls in _registered.items()}


def stage_class(name: str) -> type:
    if name in _registered:
        return _registered[name]
    module, _, attr = _builtin[name].partition(":")
    return getattr(importlib.import_module(module), attr)


def build_stages(ctx, names) -> list[Stage]:
    """The stages of these effect names, built once, in step order."""
    rank = {name: i for i, name in enumerate(_order)}
    ordered = sorted(names, key=lambda n: (rank.get(n, len(rank)), list(names).index(n)))
    effects = ctx.scene.effects
    return [stage_class(name)(ctx, effects.get(name)) for name in ordered]
