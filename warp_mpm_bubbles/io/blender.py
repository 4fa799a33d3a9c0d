"""Open a written animation in Blender, ready to play and render: `warp-mpm-bubbles blender OUT.usdc`.

Imports the USD with Blender's own importer (value clips, instancer, materials), then sets what the
importer leaves alone: the scene's fps from the stage's timeCodesPerSecond (Blender stays at 24
otherwise: a 60 fps file plays at 0.4x), the frame range from its start/end time codes, a camera
framing the animation, a sun light and a matte floor, and saves OUT.blend next to the file. Where the file has the
liquid's surface mesh, the liquid's particle prototype is hidden (render and viewport), so the water
renders as the mesh, given a clear, refracting material, while bubbles and foam stay particles;
unhide it to see the particles.

With `render_frame` (the command's `--render FRAME`) it also renders one frame with Cycles on the CPU,
at a few samples, to a PNG: a look at the set-up, not a final image.

The camera, frame range and fps come from pure functions (camera_pose, fps_settings, frame_in_range)
so they are tested where bpy is not installed.

Needs Blender as a Python module (bpy), which needs Python 3.11 and numpy < 2, so it lives in a
virtual environment of its own; INSTALL_HINT gives the commands, the same as the README's.
"""

from __future__ import annotations

import math
from pathlib import Path

INSTALL_HINT = ("the blender command needs Blender's Python module (bpy: Python 3.11, numpy < 2), in a virtual "
                "environment of its own: from the project's folder, run `python3.11 -m venv .venv-blender` and "
                "`.venv-blender/bin/pip install -e \".[blender]\"`, then `.venv-blender/bin/warp-mpm-bubbles blender ...`")
RENDER_SIZE = (960, 540)  # pixels: 16:9
LENS_MM, SENSOR_MM = 35.0, 36.0  # Blender's default camera, its sensor's width fitted to the image's width


class BlenderUnavailable(RuntimeError):
    pass


class BlenderInputError(ValueError):
    """An argument the file cannot honour (a frame it does not have): refused before Blender starts work."""


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


def fps_settings(fps: float) -> tuple:
    """Blender's (render.fps, render.fps_base) for a rate: fps / fps_base is exact (29.97 too)."""
    whole = max(1, round(fps))
    return whole, whole / fps


def frame_in_range(frame: int, info: dict) -> str | None:
    """Why `frame` cannot be rendered from a file with stage_timing `info`, or None if it can."""
    if not info["start"] <= frame <= info["end"]:
        return f"frame {frame} is not in the file: give one from {info['start']} to {info['end']}"
    return None


def camera_pose(lo, hi, up_axis="Y", meters_per_unit=1.0, aspect=RENDER_SIZE[0] / RENDER_SIZE[1],
                lens_mm=LENS_MM, sensor_mm=SENSOR_MM) -> dict:
    """Where a camera sees the whole box lo..hi (USD coordinates of the file, as stage_timing gives
    them): in front of it (Blender's -y) and a little above, looking at its centre, just far enough
    that every corner of the box is inside the picture with a 5% margin. Blender coordinates, m."""
    a = [v * meters_per_unit for v in _to_blender(lo, up_axis)]
    b = [v * meters_per_unit for v in _to_blender(hi, up_axis)]
    lo, hi = [min(p, q) for p, q in zip(a, b)], [max(p, q) for p, q in zip(a, b)]
    centre = [(p + q) / 2 for p, q in zip(lo, hi)]
    # Looking along +y and this much down (31 degrees: over a glass's rim, onto the water's surface);
    # the camera's axes are (1,0,0), `up` and `forward`.
    tilt = 0.6
    norm = math.hypot(1.0, tilt)
    forward, up = (0.0, 1.0 / norm, -tilt / norm), (0.0, tilt / norm, 1.0 / norm)
    tan_w = 0.95 * sensor_mm / 2 / lens_mm  # horizontal sensor fit: the width spans sensor_mm
    tan_h = tan_w / aspect
    distance = 1e-3
    for corner in ((x, y, z) for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])):
        rel = [c - m for c, m in zip(corner, centre)]
        depth = sum(r * f for r, f in zip(rel, forward))  # beyond the centre, seen from the camera
        # A corner at sideways offset s and this depth is in the picture when s <= tan * (distance + depth).
        distance = max(distance, abs(rel[0]) / tan_w - depth, abs(sum(r * u for r, u in zip(rel, up))) / tan_h - depth)
    radius = max(math.dist(lo, hi) / 2, 1e-3)
    location = tuple(c - distance * f for c, f in zip(centre, forward))
    return {"location": location, "target": tuple(centre), "clip_start": max(distance - radius, 1e-3) / 10,
            "clip_end": 4 * (distance + radius), "lens_mm": lens_mm, "sensor_mm": sensor_mm}


def open_in_blender(usd_path, blend_path=None, render=None, png=None, samples=16) -> dict:
    """Import `usd_path` into an empty Blender scene, set it up and save it; with `render` (a frame
    number) also render that frame to `png`. Returns what was set."""
    try:
        import bpy
    except ImportError as err:
        raise BlenderUnavailable(INSTALL_HINT) from err
    usd_path = Path(usd_path).resolve()
    if not usd_path.exists():
        raise FileNotFoundError(f"{usd_path} does not exist")
    blend_path = Path(blend_path) if blend_path else usd_path.with_suffix(".blend")
    info = stage_timing(usd_path)
    if render is not None and frame_in_range(render, info):
        raise BlenderInputError(f"--render {render}: {frame_in_range(render, info)}")

    bpy.ops.wm.read_factory_settings(use_empty=True)
    # merge_parent_xform off: /World stays an object in every file (it was merged away when it had one child).
    result = bpy.ops.wm.usd_import(filepath=str(usd_path), set_frame_range=True, import_materials=True,
                                   import_all_materials=True, import_usd_preview=True, merge_parent_xform=False,
                                   import_visible_only=True)
    if "FINISHED" not in result:
        raise RuntimeError(f"Blender could not import {usd_path}")
    hidden = _ensure_materials(usd_path)
    _clear_glasses()
    _clear_water(hidden)
    scene = bpy.context.scene
    scene.render.fps, scene.render.fps_base = fps_settings(info["fps"])
    scene.frame_start, scene.frame_end = info["start"], info["end"]
    scene.frame_set(info["start"])
    scene.render.resolution_x, scene.render.resolution_y = RENDER_SIZE
    _add_camera(scene, camera_pose(info["lo"], info["hi"], info["up_axis"], info["meters_per_unit"]))
    _add_sun(scene)
    _light_sky(scene)
    _add_floor(scene, info)
    bpy.ops.wm.save_as_mainfile(filepath=str(blend_path))
    materials = {o.name: [s.material.name for s in o.material_slots if s.material] for o in scene.objects
                 if o.type == "MESH"}
    done = {"blend": str(blend_path), "fps": scene.render.fps / scene.render.fps_base, "hidden": hidden,
            "frames": (scene.frame_start, scene.frame_end), "objects": sorted(o.name for o in scene.objects),
            "materials": materials}
    if render is not None:
        done["png"] = render_frame(scene, render, png or usd_path.with_name(f"{usd_path.stem}_{render}.png"), samples)
    return done


def render_frame(scene, frame: int, png, samples: int = 16) -> str:
    """Render `frame` with Cycles on the CPU at `samples` samples to `png`; returns its path."""
    import bpy

    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples
    scene.render.image_settings.file_format = "PNG"
    scene.render.filepath = str(Path(png).resolve())
    scene.frame_set(frame)
    bpy.ops.render.render(write_still=True)
    return scene.render.filepath


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


def _clear_glasses():
    """Glass colliders (prims glass_N under /World/Colliders) get a clear material of their own: the
    file's grey collider material suits a ball or a stone, but an opaque glass hides what is in it."""
    import bpy

    glasses = [o for o in bpy.data.objects if o.type == "MESH" and o.name.startswith("glass_")
               and o.parent is not None and o.parent.name == "Colliders"]
    if not glasses:
        return
    mat = bpy.data.materials.new("Glass")
    _make_transmissive(mat, ior=1.5)
    for obj in glasses:
        obj.data.materials.clear()
        obj.data.materials.append(mat)


def _clear_water(hidden: list):
    """Where the file has a surface mesh (its particles then hidden), the liquid's material becomes clear
    and refracting. UsdPreviewSurface has no transmission: Blender reads the look's low opacity as alpha,
    and a surface drawn at 10% alpha renders as a dim, dark body instead of water."""
    import bpy

    for name in hidden:
        obj = bpy.data.objects.get(name)
        for slot in (obj.material_slots if obj is not None else ()):
            if slot.material is not None:
                _make_transmissive(slot.material, ior=1.33)


def _make_transmissive(mat, ior: float):
    """A Principled BSDF that lets light through (glass, clear water): no alpha, full transmission."""
    if mat.node_tree is None:  # Blender 4 makes a material without nodes; 5 with them
        mat.use_nodes = True
    bsdf = next(n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
    for link in [link for link in mat.node_tree.links if link.to_node == bsdf and link.to_socket.name == "Alpha"]:
        mat.node_tree.links.remove(link)
    for name, value in (("Base Color", (1.0, 1.0, 1.0, 1.0)), ("Roughness", 0.02), ("IOR", ior),
                        ("Alpha", 1.0), ("Transmission Weight", 1.0)):
        if name in bsdf.inputs:  # the inputs' names as of Blender 4 and 5
            bsdf.inputs[name].default_value = value


def _light_sky(scene, grey=0.7):
    """A light grey sky: what clear water and glass refract; against Blender's dark default they render black."""
    import bpy

    if scene.world is None:
        scene.world = bpy.data.worlds.new("World")
    scene.world.color = (grey, grey, grey)
    tree = scene.world.node_tree if getattr(scene.world, "use_nodes", False) else None
    for node in (tree.nodes if tree else ()):
        if node.type == "BACKGROUND":
            node.inputs["Color"].default_value = (grey, grey, grey, 1.0)


def _add_floor(scene, info: dict, grey=0.5):
    """A matte floor under the domain, twenty times its size: the shadows ground the scene, and clear
    water and glass have something to refract besides a uniform sky."""
    import bpy

    a = [v * info["meters_per_unit"] for v in _to_blender(info["lo"], info["up_axis"])]
    b = [v * info["meters_per_unit"] for v in _to_blender(info["hi"], info["up_axis"])]
    half = 10 * max(abs(p - q) for p, q in zip(a, b))
    cx, cy, z = (a[0] + b[0]) / 2, (a[1] + b[1]) / 2, min(a[2], b[2]) - 1e-4  # just under the floor wall
    mesh = bpy.data.meshes.new("Floor")
    mesh.from_pydata([(cx - half, cy - half, z), (cx + half, cy - half, z), (cx + half, cy + half, z),
                      (cx - half, cy + half, z)], [], [(0, 1, 2, 3)])
    mat = bpy.data.materials.new("Floor")
    if mat.node_tree is None:
        mat.use_nodes = True
    bsdf = next(n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
    bsdf.inputs["Base Color"].default_value = (grey, grey, grey, 1.0)
    bsdf.inputs["Roughness"].default_value = 0.8
    mesh.materials.append(mat)
    scene.collection.objects.link(bpy.data.objects.new("Floor", mesh))


def _add_camera(scene, pose: dict):
    import bpy
    from mathutils import Vector

    data = bpy.data.cameras.new("Camera")
    data.lens, data.sensor_width, data.sensor_fit = pose["lens_mm"], pose["sensor_mm"], "HORIZONTAL"
    data.clip_start, data.clip_end = pose["clip_start"], pose["clip_end"]
    cam = bpy.data.objects.new("Camera", data)
    scene.collection.objects.link(cam)
    cam.location = Vector(pose["location"])
    cam.rotation_euler = (Vector(pose["target"]) - cam.location).to_track_quat("-Z", "Y").to_euler()
    scene.camera = cam


def _add_sun(scene):
    import bpy

    data = bpy.data.lights.new("Sun", type="SUN")
    data.energy = 3.0
    sun = bpy.data.objects.new("Sun", data)
    sun.rotation_euler = (math.radians(50.0), 0.0, math.radians(30.0))
    scene.collection.objects.link(sun)
