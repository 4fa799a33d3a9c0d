"""UsdPreviewSurface materials, so Blender, usdview and Omniverse render water, air and foam with no
set-up: one material per scene material bound to its PointInstancer prototype, the liquid's look bound
to the surface mesh, grey for the colliders, and for the Points prim a material that reads each
point's displayColor. displayColor stays on every prim (viewports without material support use it).
Sub-grid bubbles (a phase of a gas material, not a material of their own) get a prototype and a
material of their own, named after their gas (`air_subgrid`), so a renderer shades the small bubbles
apart from the resolved air (scene_prototypes).

Looks (UsdPreviewSurface has no transmission input: opacity plus ior is what USD renderers and
Blender's importer turn into a refracting surface):
    liquid    the material's colour, opacity 0.1, ior 1.33, roughness 0.02: clear water
    gas       white, opacity 0.25, ior 1.0, roughness 0.3: faint air
    foam      white, opaque, roughness 0.9
    subgrid   white, opacity 0.6, ior 1.0, roughness 0.1: small bubbles read as bright glossy specks
    collider  grey (usd_colliders.COLOR), opaque, roughness 0.4
"""

from __future__ import annotations

from pxr import Gf, Sdf, Tf, UsdGeom, UsdShade

LOOKS = "/World/Looks"
_WHITE = (1.0, 1.0, 1.0)


def look(kind: str, color) -> dict:
    """The UsdPreviewSurface inputs of a scene material of this kind ("liquid", "gas", "foam") or a
    "collider"."""
    if kind == "liquid":
        return {"diffuseColor": tuple(color), "opacity": 0.1, "ior": 1.33, "roughness": 0.02, "metallic": 0.0}
    if kind == "gas":
        return {"diffuseColor": _WHITE, "opacity": 0.25, "ior": 1.0, "roughness": 0.3, "metallic": 0.0}
    if kind == "subgrid":
        return {"diffuseColor": _WHITE, "opacity": 0.6, "ior": 1.0, "roughness": 0.1, "metallic": 0.0}
    if kind == "foam":
        return {"diffuseColor": (0.95, 0.95, 0.95), "opacity": 1.0, "ior": 1.5, "roughness": 0.9, "metallic": 0.0}
    if kind == "collider":
        return {"diffuseColor": tuple(color), "opacity": 1.0, "ior": 1.5, "roughness": 0.4, "metallic": 0.0}
    raise ValueError(f"no look for material kind {kind!r}")


def scene_prototypes(scene) -> tuple[list, list]:
    """The instancer's prototypes of a scene: (looks, prototype_of). looks: (name, kind, color) per
    prototype in index order, one per scene material (its particles' material index is their
    prototype), then, with [effects.subgrid_bubbles], one of kind "subgrid" per gas material for its
    sub-grid bubbles; prototype_of: (material index, phase) of each prototype after the materials,
    as StageWriter takes it. A name another prototype already has gets a trailing underscore."""
    from ..core.grid import PHASE_SUBGRID

    looks = [(m.name, m.kind, tuple(m.color)) for m in scene.materials.values()]
    prototype_of = []
    if "subgrid_bubbles" in scene.effects:
        taken = {Tf.MakeValidIdentifier(name) for name, _, _ in looks}
        for i, (name, kind, color) in enumerate(list(looks)):
            if kind != "gas":
                continue
            own = Tf.MakeValidIdentifier(name + "_subgrid")
            while own in taken:
                own += "_"
            taken.add(own)
            looks.append((own, "subgrid", color))
            prototype_of.append((i, PHASE_SUBGRID))
    return looks, prototype_of


def define_material(stage, name: str, inputs: dict, primvar_color: bool = False) -> UsdShade.Material:
    """/World/Looks/<name>: a UsdPreviewSurface with these inputs; primvar_color: diffuseColor read
    from each point's displayColor primvar instead."""
    UsdGeom.Scope.Define(stage, LOOKS)
    path = f"{LOOKS}/{Tf.MakeValidIdentifier(name)}"
    material = UsdShade.Material.Define(stage, path)
    shader = UsdShade.Shader.Define(stage, path + "/PreviewSurface")
    shader.CreateIdAttr("UsdPreviewSurface")
    for key, value in inputs.items():
        if isinstance(value, tuple):
            shader.CreateInput(key, Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*map(float, value)))
        else:
            shader.CreateInput(key, Sdf.ValueTypeNames.Float).Set(float(value))
    if primvar_color:
        reader = UsdShade.Shader.Define(stage, path + "/DisplayColor")
        reader.CreateIdAttr("UsdPrimvarReader_float3")
        reader.CreateInput("varname", Sdf.ValueTypeNames.Token).Set("displayColor")
        out = reader.CreateOutput("result", Sdf.ValueTypeNames.Float3)
        shader.GetInput("diffuseColor").ConnectToSource(out)
    material.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    return material


def bind(prim, material: UsdShade.Material) -> None:
    UsdShade.MaterialBindingAPI.Apply(prim).Bind(material)


def dress_stage(stage, materials) -> None:
    """Bind a look to each prototype, the surface mesh and the Points prim on a StageWriter's top
    stage (its `decorate` hook). materials: (name, kind, color) per scene material, in prototype order.

    With format = "both" the Points prim is made invisible: DCCs that import both would otherwise
    show every particle twice (make it visible to use the points instead)."""
    from .usd_output import INSTANCER, POINTS, SURFACE

    looks = [define_material(stage, name, look(kind, color)) for name, kind, color in materials]
    instancer = UsdGeom.PointInstancer.Get(stage, INSTANCER)
    if instancer:
        for target, material in zip(instancer.GetPrototypesRel().GetTargets(), looks):
            bind(stage.GetPrimAtPath(target), material)
    surface = stage.GetPrimAtPath(SURFACE)
    liquid = next((m for m, (_, kind, _) in zip(looks, materials) if kind == "liquid"), None)
    if surface and liquid is not None:
        bind(surface, liquid)
    points = stage.GetPrimAtPath(POINTS)
    if points:
        neutral = {"diffuseColor": _WHITE, "opacity": 1.0, "roughness": 0.3, "metallic": 0.0}
        bind(points, define_material(stage, "ParticleColor", neutral, primvar_color=True))
        if instancer:
            UsdGeom.Imageable(points).CreateVisibilityAttr(UsdGeom.Tokens.invisible)


def bind_collider(stage, prim, color) -> None:
    """The colliders' shared grey material, bound to one collider prim."""
    path = f"{LOOKS}/Collider"
    material = UsdShade.Material.Get(stage, path) or define_material(stage, "Collider", look("collider", color))
    bind(prim, material)
