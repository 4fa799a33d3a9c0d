"""wedge.usda: one stage for the whole wedge. /World carries a VariantSet "wedge" with one variant
per member, each referencing that member's output stage (relative path, so the wedge folder
moves as one), so usdview, Omniverse, Houdini or Blender switch members in one stage. Each
variant's customData records the member's values."""

from __future__ import annotations

import os
import re
from pathlib import Path

from pxr import Sdf, Usd, UsdGeom

VARIANT_SET = "wedge"


def variant_names(members) -> list[str]:
    """Member names as USD variant names ([A-Za-z0-9_|-] only), kept unique."""
    names = []
    for m in members:
        name = re.sub(r"[^A-Za-z0-9_|\-]+", "_", m.name).strip("_") or f"m{m.index}"
        if name in names:
            name = f"m{m.index}_{name}"
        names.append(name)
    return names


def write_wedge_stage(folder, members, results=None, name="wedge.usda") -> Path:
    """Write folder/name; members without an output stage on disk get no variant. The selection
    is the first finished member. Written to a temporary name and renamed."""
    folder = Path(folder)
    results = results or [{"status": "ok"}] * len(members)
    present = [(m, r, v) for m, r, v in zip(members, results, variant_names(members)) if Path(m.stage).exists()]
    path = folder / name
    tmp = path.with_name(path.stem + ".tmp" + path.suffix)  # beside it: relative references resolve
    stage = Usd.Stage.CreateNew(str(tmp))
    world = stage.DefinePrim("/World", "Xform")
    stage.SetDefaultPrim(world)
    if present:
        first = Usd.Stage.Open(str(present[0][0].stage), Usd.Stage.LoadNone)
        UsdGeom.SetStageUpAxis(stage, UsdGeom.GetStageUpAxis(first))
        UsdGeom.SetStageMetersPerUnit(stage, UsdGeom.GetStageMetersPerUnit(first))
        stage.SetTimeCodesPerSecond(first.GetTimeCodesPerSecond())
        stage.SetFramesPerSecond(first.GetFramesPerSecond())
        stage.SetStartTimeCode(min(_range(m)[0] for m, _, _ in present))
        stage.SetEndTimeCode(max(_range(m)[1] for m, _, _ in present))
    vset = world.GetVariantSets().AddVariantSet(VARIANT_SET)
    for m, r, variant in present:
        vset.AddVariant(variant)
        vset.SetVariantSelection(variant)
        with vset.GetVariantEditContext():
            world.GetReferences().AddReference(_relative(m.stage, folder))
        spec = stage.GetRootLayer().GetPrimAtPath(f"/World{{{VARIANT_SET}={variant}}}")
        spec.customData = {"member": m.name, "values": m.label, "status": r["status"]}
    chosen = next((v for m, r, v in present if r["status"] == "ok"), present[0][2] if present else "")
    if chosen:
        vset.SetVariantSelection(chosen)
    stage.GetRootLayer().documentation = (
        "Wedge of " + str(len(members)) + " members; switch with the 'wedge' variant set on /World")
    stage.GetRootLayer().Save()
    os.replace(tmp, path)
    return path


def _relative(stage_path, folder) -> str:
    return "./" + Path(os.path.relpath(stage_path, folder)).as_posix()


def _range(member) -> tuple[float, float]:
    layer = Sdf.Layer.FindOrOpen(str(member.stage))
    layer.Reload()
    return (layer.startTimeCode if layer.HasStartTimeCode() else 0.0,
            layer.endTimeCode if layer.HasEndTimeCode() else 0.0)
