"""The stage protocol: how one piece of optional physics joins the step.

A stage is one class in one module that owns all of its physics (docs/design.md, "The step"):

- ``name``: the effect it implements, as `Scene.effect_names` lists it (the scene asks for it,
  the simulation builds it; a scene that does not ask never imports its module, so its kernels
  never compile).
- ``Settings``: the dataclass of its ``[effects.NAME]`` table, if it has one (keys and checks).
  Built-in settings sit in `scene/effects.py`, which imports no Warp, so validating a scene
  stays instant; a stage from outside the package keeps its settings in its own module.
- ``dt_limit(sim)``: its time-step limit in seconds (``inf`` if none), named ``limit`` in
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
      force           on u* before the solve           viscosity, surface tension
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
- what it checkpoints: per-particle arrays made with `ParticleState.add_field` and entries of
  `Simulation.host_state` are saved and restored with everything else.

Stages run in STEP_ORDER at every hook point. The order matters only where two stages share a hook:
colliders mark solid cells before the gas labels phases (the phases read the cell types); forces
add viscosity then tension; after g2p, films retract before anything else reads the gas, entrained
bubbles are seeded before the sub-grid stage moves them, and foam takes surfacing gas before venting
would remove it.
"""

from __future__ import annotations

import importlib
import math
from typing import ClassVar

from .step import HOOKS

# The built-in stages, by the effect name a scene asks for: "module:Class", imported on first use.
BUILTIN_STAGES = {
    "gas": "warp_mpm_bubbles.physics.gas:GasStage",
    "colliders": "warp_mpm_bubbles.effects.colliders:ColliderStage",
    "viscosity": "warp_mpm_bubbles.physics.viscosity:ViscosityStage",
    "surface_tension": "warp_mpm_bubbles.physics.tension:TensionStage",
    "emitters": "warp_mpm_bubbles.effects.emitters:EmitterStage",
    "foam": "warp_mpm_bubbles.effects.foam:FoamStage",
    "subgrid_bubbles": "warp_mpm_bubbles.effects.subgrid:SubgridBubbleStage",
    "entrainment": "warp_mpm_bubbles.effects.entrainment:EntrainmentStage",
}
# Order at every hook point (see the module docstring); stages registered from outside come after.
STEP_ORDER = ("emitters", "colliders", "viscosity", "surface_tension", "entrainment", "subgrid_bubbles", "foam",
              "gas")

_registered: dict[str, type] = {}


class Stage:
    """Base class: every hook is a no-op and there is no time-step limit."""

    name: ClassVar[str] = ""
    Settings: ClassVar[type | None] = None
    timer: ClassVar[str | None] = None  # None: the stage's name
    limit: ClassVar[str | None] = None  # its dt_limit's name in Simulation.dt_limits(); None: the stage's name
    # True: its kernels at the grid hooks cover only `sim.region` (the grid stages' box, with the
    # offset `sim.region.lo`) and leave every cell outside it in the empty state (core/active_box.py).
    # A scene whose grid-hook stages all say so keeps the box; any other stage there: the whole grid.
    grid_box: ClassVar[bool] = False
    graph_safe: ClassVar[bool] = False  # may be captured in step_graph's CUDA graphs (module docstring)

    def __init__(self, sim, settings=None):
        self.settings = settings

    @property
    def timer_name(self) -> str:
        return self.timer or self.name

    def hooks(self) -> set[str]:
        """The hook points this stage runs at: those its class overrides (a stage may drop one
        it does not need in this scene, so the step neither calls nor times it)."""
        return {h for h in HOOKS if getattr(type(self), h) is not getattr(Stage, h)}

    def dt_limit(self, sim) -> float:
        return math.inf

    def incoming_speed(self, t0: float, t1: float) -> float:
        return 0.0

    def begin_step(self, sim, dt: float): ...
    def after_p2g(self, sim, dt: float): ...
    def on_momentum(self, sim, dt: float): ...
    def on_cells(self, sim, dt: float): ...
    def on_faces(self, sim, dt: float): ...
    def force(self, sim, dt: float): ...
    def before_extend(self, sim, dt: float): ...
    def on_extended(self, sim, vel): ...
    def before_g2p(self, sim, dt: float): ...
    def after_g2p(self, sim, dt: float): ...
    def end_step(self, sim, dt: float): ...


def register_stage(cls: type) -> type:
    """Add a stage from outside the package (usable as a class decorator). It runs only in scenes
    that have its ``[effects.NAME]`` table, whose keys its ``Settings`` dataclass checks (give it a
    ``key`` class attribute equal to the name and a ``_validate(checker, table, scene)`` method)."""
    from ..scene.effects import EFFECT_TYPES

    if not (isinstance(cls, type) and issubclass(cls, Stage)) or not cls.name:
        raise TypeError("register_stage takes a Stage subclass with a name")
    if cls.name in BUILTIN_STAGES:
        raise ValueError(f"'{cls.name}' is a built-in stage; choose another name")
    settings = cls.Settings
    if settings is None or getattr(settings, "key", None) != cls.name:
        raise TypeError(f"{cls.__name__}.Settings must be a dataclass with key = {cls.name!r}")
    _registered[cls.name] = cls
    EFFECT_TYPES[cls.name] = settings
    return cls


def stage_class(name: str) -> type:
    if name in _registered:
        return _registered[name]
    module, _, attr = BUILTIN_STAGES[name].partition(":")
    return getattr(importlib.import_module(module), attr)


def build_stages(sim, names) -> list[Stage]:
    """The stages of these effect names, built once, in step order."""
    rank = {name: i for i, name in enumerate(STEP_ORDER)}
    ordered = sorted(names, key=lambda n: (rank.get(n, len(rank)), list(names).index(n)))
    effects = sim.scene.effects
    return [stage_class(name)(sim, effects.get(name)) for name in ordered]
