"""warp_mpm_bubbles: air bubbles in water with the Material Point Method in NVIDIA Warp, written as USD.

    from warp_mpm_bubbles import load_scene, run_scene
    run_scene(load_scene("examples/dam_break.toml"), device="cpu")
"""

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

__all__ = [
    "Box", "Cylinder", "Domain", "Material", "Output", "Scene", "SceneError", "SolverSettings", "Sphere",
    "load_scene", "Simulation", "run_scene",
]
__version__ = "0.1.0"


def __getattr__(name):
    # Warp loads only when the simulator is used, so validating a scene stays instant.
    if name == "Simulation":
        from .core.simulation import Simulation

        return Simulation
    if name == "run_scene":
        from .io.runner import run_scene

        return run_scene
    raise AttributeError(name)
