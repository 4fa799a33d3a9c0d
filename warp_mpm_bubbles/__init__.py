"""warp_mpm_bubbles: air bubbles in water with the Material Point Method in NVIDIA Warp, written as USD.

Build or load a scene, validate it, run it:

    from warp_mpm_bubbles import load_scene, run_scene
    scene = load_scene("examples/dam_break.toml")     # or Scene(domain=Domain(...), ...)
    result = run_scene(scene, device="cpu")           # writes scene.output.path, frame by frame
    result.simulation.particles_numpy()["positions"]  # the last frame's state

Scenes (units: metres, seconds, kilograms, pascals):
    Scene, Domain, Material, SolverSettings, Output       the schema; Scene.validate() checks it
    Box, Sphere, Cylinder                                  shapes that seed particles
    Foam, SubgridBubbles, Entrainment                      effects ([effects.*])
    LiquidInflow, GasInjector                              emitters ([[emitters]])
    Collider                                               colliders ([[colliders]])
    load_scene(path)                                       a TOML file -> a validated Scene
    SceneError                                             every refusal: names the key and the fix

Running (these import Warp on first use):
    run_scene(scene, device=None, progress=True, resume=False, overwrite=False, on_frame=None)
                                            the frame loop, USD and checkpoints; on_frame(sim) after each frame
    Simulation(scene, device=None)          the state and the step, for your own loop
    SimulationError                         the simulation cannot go on

Extending (docs/new_effect.md):
    Stage, register_stage                   a stage of your own, run only by scenes that ask for it

docs/api.md walks through the API with examples.
"""

from .core.stage import register_builtin_stages as _register_builtin_stages
from .stages import BUILTIN_STAGES as _BUILTIN_STAGES, STEP_ORDER as _STEP_ORDER
from .scene import (
    Box,
    Cylinder,
    Domain,
    Material,
    Output,
    Scene,
    SceneError,
    SolverSettings,
    Sphere,
    load_scene,
)

# Effect, emitter and collider settings, by name -> the module that defines them (imported on first
# use). They live in scene/effects.py; when they move, only this table changes.
_LAZY = {name: "warp_mpm_bubbles.scene.effects" for name in (
    "Foam", "SubgridBubbles", "Entrainment", "LiquidInflow", "GasInjector", "Collider")}
# Warp loads only when the simulator is used, so validating a scene stays instant.
_LAZY.update(Simulation="warp_mpm_bubbles.core.simulation", SimulationError="warp_mpm_bubbles.core.simulation",
             run_scene="warp_mpm_bubbles.io.runner", RunResult="warp_mpm_bubbles.io.runner",
             Stage="warp_mpm_bubbles.core.stage", register_stage="warp_mpm_bubbles.core.stage")

__all__ = [
    "Box", "Cylinder", "Domain", "Material", "Output", "Scene", "SceneError", "SolverSettings", "Sphere",
    "load_scene", *_LAZY,
]
__version__ = "0.1.0"
_register_builtin_stages(_BUILTIN_STAGES, _STEP_ORDER)  # the core names no effect: it is told them here


def __getattr__(name):
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value  # once imported, a plain attribute
        return value
    raise AttributeError(f"module 'warp_mpm_bubbles' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(__all__))
