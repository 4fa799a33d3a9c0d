"""UsdPreviewSurface materials (io/usd_materials.py) bound to each prototype, the surface mesh, the
Points prim and the colliders, with displayColor kept."""

from pathlib import Path

import numpy as np
import pytest
from pxr import Gf, Usd, UsdGeom, UsdShade

from warp_mpm_bubbles.io.usd_colliders import write_colliders
from warp_mpm_bubbles.io.usd_materials import dress_stage
from warp_mpm_bubbles.io.usd_output import StageWriter
from warp_mpm_bubbles.scene.model import load_scene

ROOT = Path(__file__).resolve().parent.parent
LOOKS = [("water", "liquid", (0.2, 0.45, 0.9)), ("air", "gas", (0.92, 0.95, 1.0)), ("foam", "foam", (1.0, 1.0, 1.0))]


def inputs_of(prim) -> dict:
    material, _ = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()
    assert material, f"{prim.GetPath()} has no bound material"
    shader = UsdShade.Shader(material.GetSurfaceOutput().GetConnectedSources()[0][0].source.GetPrim())
    assert shader.GetIdAttr().Get() == "UsdPreviewSurface"
    values = {i.GetBaseName(): i.Get() for i in shader.GetInputs()}
    values["_material"] = material.GetPath().name
    values["_color_reader"] = shader.GetInput("diffuseColor").HasConnectedSource()
    return values


def check_particle_looks(stage, looks):
    """Every prototype carries the look of its material kind; returns the inputs per prototype name."""
    instancer = UsdGeom.PointInstancer.Get(stage, "/World/Particles")
    found = {}
    for target, (name, kind, color) in zip(instancer.GetPrototypesRel().GetTargets(), looks):
        prim = stage.GetPrimAtPath(target)
        got = inputs_of(prim)
        found[name] = got
        assert got["_material"] == name
        assert UsdGeom.Gprim(prim).GetDisplayColorAttr().Get()[0] == Gf.Vec3f(*color)  # displayColor kept
        if kind == "liquid":  # clear water
            assert got["opacity"] == pytest.approx(0.1) and got["ior"] == pytest.approx(1.33)
            assert got["roughness"] < 0.1 and got["diffuseColor"] == Gf.Vec3f(*color)
        elif kind == "gas":  # white and faint
            assert got["diffuseColor"] == Gf.Vec3f(1, 1, 1) and got["opacity"] == pytest.approx(0.25)
        else:  # foam: white and rough
            assert min(got["diffuseColor"]) > 0.9 and got["roughness"] == pytest.approx(0.9) and got["opacity"] == 1
    assert len(found) == len(looks)
    return found


def test_every_prototype_the_surface_points_and_colliders_have_a_material(tmp_path):
    scene = load_scene(ROOT / "examples" / "pour_glass.toml").validate()

    def decorate(stage):
        dress_stage(stage, LOOKS)
        write_colliders(stage, scene.colliders, 2, 0.002, 60, 2)

    out = tmp_path / "m.usdc"
    with StageWriter(out, fps=60, materials=[(n, c) for n, _, c in LOOKS], particle_radius=0.001, format="both",
                     decorate=decorate, surface=True) as w:
        w.write_frame(0, np.zeros((3, 3)), np.zeros((3, 3)), np.arange(3), np.arange(3))
    stage = Usd.Stage.Open(str(out))
    check_particle_looks(stage, LOOKS)
    surface = inputs_of(stage.GetPrimAtPath("/World/LiquidSurface"))
    assert surface["_material"] == "water" and surface["ior"] == pytest.approx(1.33)
    points = stage.GetPrimAtPath("/World/ParticlePoints")
    assert inputs_of(points)["_color_reader"]  # each point's displayColor feeds the diffuse colour
    assert UsdGeom.Imageable(points).ComputeVisibility() == UsdGeom.Tokens.invisible  # "both": shown once
    glass = stage.GetPrimAtPath("/World/Colliders").GetChildren()
    assert len(glass) == 1
    grey = inputs_of(glass[0])
    assert grey["_material"] == "Collider" and grey["diffuseColor"] == Gf.Vec3f(0.55, 0.55, 0.58)
    assert UsdGeom.Gprim(glass[0]).GetDisplayColorAttr().Get()[0] == Gf.Vec3f(0.55, 0.55, 0.58)


def test_world_is_the_default_prim_with_looks_beside_the_particles(tmp_path):
    # Blender merges a root Xform with a single child into it (dam_break lost its World object):
    # /World always holds the Looks scope besides the particles.
    out = tmp_path / "w.usdc"
    with StageWriter(out, fps=30, materials=[("water", (0, 0, 1))], particle_radius=0.001,
                     decorate=lambda st: dress_stage(st, LOOKS[:1])) as w:
        w.write_frame(0, np.zeros((1, 3)), np.zeros((1, 3)), np.arange(1), np.zeros(1))
    stage = Usd.Stage.Open(str(out))
    assert stage.GetDefaultPrim().GetPath() == "/World" and stage.GetDefaultPrim().IsA(UsdGeom.Xform)
    assert [c.GetName() for c in stage.GetDefaultPrim().GetChildren()] == ["Particles", "Looks"]
