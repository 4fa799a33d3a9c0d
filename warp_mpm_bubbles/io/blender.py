"""Open a written animation in Blender, ready to play and render: `warp-mpm-bubbles blender OUT.usdc`.

Imports the USD with Blender's own importer (value clips, instancer, materials), then sets what the
importer leaves alone: the scene's fps from the stage's timeCodesPerSecond (Blender stays at 24
otherwise: a 60 fps file plays at 0.4x), the frame range from its start/end time codes, a camera
framing the animation and a sun light, and saves OUT.blend next to the file. Where the file has the
liquid's surface mesh, the liquid's particle prototype is hidden (render and viewport), so the water
renders as the mesh while bubbles and foam stay particles; unhide it to see the particles.

Needs Blender as a Python module: `pip install -e ".[blender]"` (bpy; Python 3.11, and it pins
numpy < 2, so give it its own virtual environment).
"""

from __future__ import annotations

import math
from pathlib import Path

INSTALL_HINT = 'the blender command needs Blender\'s Python module: pip install -e ".[blender]" (bpy, Python 3.11)'


class BlenderUnavailable(RuntimeError):
    pass


def stage_timing(usd_path) -> dict:
    """fps, first and last frame, up axis and the animation's bounding box (USD units) of a file."""
    from pxr import Gf, Usd, UsdGeom

    stage = Usd.Stage.Open(str(usd_path))
    if not stage:
        raise OSError(f"cannot open {usd_path}")
    start, end = stage.GetStartTimeCode(), stage.GetEndTimeCode()
    cache = UsdGeom.BBoxCache(start, [UsdGeom.Tokens.default_, UsdGeom.Tokens.render])
    box = None
    for t in sorted({start, (start + end) / 2, end}):
        cache.SetTime(t)
        r = cache.ComputeWorldBound(stage.GetPseudoRoot()).ComputeAlignedRange()
        if not r.IsEmpty():
            box = r if box is None else Gf.Range3d.GetUnion(box, r)
    lo, hi = (tuple(box.GetMin()), tuple(box.GetMax())) if box is not None else ((0, 0, 0), (1, 1, 1))
    return {"fps": stage.GetTimeCodesPerSecond(), "start": int(start), "end": int(end),
            "up_axis": UsdGeom.GetStageUpAxis(stage), "lo": lo, "hi": hi,
            "meters_per_unit": UsdGeom.GetStageMetersPerUnit(stage)}


def _to_blender(p, up_axis):
    """USD Y-up coordinates as Blender's importer places them (Z-up: a +90 degree turn about x)."""
    x, y, z = p
    return (x, -z, y) if up_axis == "Y" else (x, y, z)


def open_in_blender(usd_path, blend_path=None) -> dict:
    """Import `usd_path` into an empty Blender scene, set it up and save it; returns what was set."""
    try:
        import bpy
        from mathutils import Vector
    except ImportError as err:
        raise BlenderUnavailable(INSTALL_HINT) from err
    usd_path = Path(usd_path).resolve()
    if not usd_path.exists():
        raise FileNotFoundError(f"{usd_path} does not exist")
    blend_path = Path(blend_path) if blend_path else usd_path.with_suffix(".blend")
    info = stage_timing(usd_path)

    bpy.ops.wm.read_factory_settings(use_empty=True)
    # merge_parent_xform off: /World stays an object in every file (it was merged away when it had one child).
    result = bpy.ops.wm.usd_import(filepath=str(usd_path), set_frame_range=True, import_materials=True,
                                   import_all_materials=True, import_usd_preview=True, merge_parent_xform=False,
                                   import_visible_only=True)
    if "FINISHED" not in result:
        raise RuntimeError(f"Blender could not import {usd_path}")
    hidden = _ensure_materials(usd_path)
    scene = bpy.context.scene
    fps = info["fps"]
    scene.render.fps = max(1, round(fps))
    scene.render.fps_base = scene.render.fps / fps  # exact for fractional rates (29.97)
    scene.frame_start, scene.frame_end = info["start"], info["end"]
    scene.frame_set(info["start"])

    scale = info["meters_per_unit"]
    lo = Vector(_to_blender(info["lo"], info["up_axis"])) * scale
    hi = Vector(_to_blender(info["hi"], info["up_axis"])) * scale
    lo, hi = Vector(map(min, lo, hi)), Vector(map(max, lo, hi))
    centre, size = (lo + hi) / 2, max((hi - lo).length, 1e-3)
    _add_camera(scene, centre, size)
    _add_sun(scene)
    if scene.world is None:
        scene.world = bpy.data.worlds.new("World")
    bpy.ops.wm.save_as_mainfile(filepath=str(blend_path))
    materials = {o.name: [s.material.name for s in o.material_slots if s.material] for o in scene.objects
                 if o.type == "MESH"}
    return {"blend": str(blend_path), "fps": scene.render.fps / scene.render.fps_base, "hidden": hidden,
            "frames": (scene.frame_start, scene.frame_end), "objects": sorted(o.name for o in scene.objects),
            "materials": materials}


def _ensure_materials(usd_path) -> list:
    """Give every imported mesh the material its prim is bound to in the file: Blender 5.0's importer
    drops the bindings of UsdGeom.Sphere prims (the particle prototypes) while it keeps the meshes'.
    Where the file has a surface, the prototypes sharing its material (the liquid's particles) are
    hidden, so the water renders as the mesh; returns their names."""
    import bpy
    from pxr import Usd, UsdGeom, UsdShade

    from .usd_output import INSTANCER, SURFACE

    stage = Usd.Stage.Open(str(usd_path))
    bound = lambda prim: UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()[0]  # noqa: E731
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.Gprim):
            continue
        material = bound(prim)
        obj = bpy.data.objects.get(prim.GetName())
        mat = bpy.data.materials.get(material.GetPrim().GetName()) if material else None
        if obj is not None and obj.type == "MESH" and mat is not None and not any(s.material for s in obj.material_slots):
            obj.data.materials.append(mat)
    surface, inst = stage.GetPrimAtPath(SURFACE), UsdGeom.PointInstancer.Get(stage, INSTANCER)
    if not surface or not inst or not bound(surface):
        return []
    hidden = []
    for target in inst.GetPrototypesRel().GetTargets():
        obj = bpy.data.objects.get(target.name)
        if obj is not None and bound(stage.GetPrimAtPath(target)).GetPath() == bound(surface).GetPath():
            obj.hide_render = obj.hide_viewport = True  # its instances go with it
            hidden.append(obj.name)
    return hidden


def _add_camera(scene, centre, size):
    import bpy

    data = bpy.data.cameras.new("Camera")
    data.lens = 35.0
    cam = bpy.data.objects.new("Camera", data)
    scene.collection.objects.link(cam)
    # In front of the tank (Blender's -y) and a little above, looking at its centre.
    cam.location = centre + type(centre)((0.0, -1.6 * size, 0.45 * size))
    cam.rotation_euler = (centre - cam.location).to_track_quat("-Z", "Y").to_euler()
    data.clip_end = 20.0 * size
    scene.camera = cam


def _add_sun(scene):
    import bpy

    data = bpy.data.lights.new("Sun", type="SUN")
    data.energy = 3.0
    sun = bpy.data.objects.new("Sun", data)
    sun.rotation_euler = (math.radians(50.0), 0.0, math.radians(30.0))
    scene.collection.objects.link(sun)
