"""Scenes as data: the schema, its validation (one SceneError naming key and fix) and the presets."""

from .checks import SceneError
from .model import Box, Cylinder, Domain, Material, Output, Scene, SolverSettings, Sphere, load_scene

__all__ = ["Box", "Cylinder", "Domain", "Material", "Output", "Scene", "SceneError", "SolverSettings", "Sphere",
           "load_scene"]
