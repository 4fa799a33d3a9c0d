"""Colliders in the USD output: each scene collider as a prim under /World/Colliders, moving ones
with a time-sampled translation per frame, so a DCC shows the ball that made the splash.

Spheres, boxes and cylinders are the UsdGeom primitives; the open glass is a mesh (its U-shaped
profile revolved about its axis). A 2D run is a slab one cell thick in z, so its colliders are
prisms of that thickness: a sphere or a cylinder along z becomes a disk, a glass a U extruded.
"""

from __future__ import annotations

import math

from pxr import Gf, UsdGeom, Vt

from .usd_materials import bind_collider

ROOT = "/World/Colliders"
COLOR = (0.55, 0.55, 0.58)
SEGMENTS = 48  # around a revolved glass


def _glass_profile(radius: float, height: float, wall: float) -> list:
    """The wall's cross-section in (radial, up), counter-clockwise, as a closed polygon."""
    return [(0.0, 0.0), (radius, 0.0), (radius, height), (radius - wall, height), (radius - wall, wall), (0.0, wall)]


def _revolve(profile: list, axis: int):
    """Points and quads of `profile` (radial, up) revolved about `axis` through the origin."""
    others = [a for a in range(3) if a != axis]
    points, faces = [], []
    n = len(profile)
    for s in range(SEGMENTS):
        ang = 2.0 * math.pi * s / SEGMENTS
        for r, up in profile:
            p = [0.0, 0.0, 0.0]
            p[axis], p[others[0]], p[others[1]] = up, r * math.cos(ang), r * math.sin(ang)
            points.append(p)
    for s in range(SEGMENTS):
        t = (s + 1) % SEGMENTS
        for i in range(n):
            j = (i + 1) % n
            faces.append([s * n + i, s * n + j, t * n + j, t * n + i])
    return points, faces


def _extrude_u(radius: float, height: float, wall: float, axis: int, thickness: float):
    """The 2D glass: a U (two walls and a bottom) extruded through the slab along z."""
    inner = radius - wall
    outline = [(-radius, 0.0), (radius, 0.0), (radius, height), (inner, height), (inner, wall),
               (-inner, wall), (-inner, height), (-radius, height)]
    side = 1 - axis  # the horizontal axis of a 2D glass standing along x or y
    points = []
    for z in (0.0, thickness):
        for across, up in outline:
            p = [0.0, 0.0, z]
            p[axis], p[side] = up, across
            points.append(p)
    n = len(outline)
    faces = [list(range(n))[::-1], list(range(n, 2 * n))]  # the two caps
    faces += [[i, (i + 1) % n, n + (i + 1) % n, n + i] for i in range(n)]
    return points, faces


def write_colliders(stage, colliders, dim: int, slab: float, fps: float, frames: int) -> None:
    """Define the colliders on `stage` (the top layer's), sampled at frames 0..frames for moving ones."""
    if not colliders:
        return
    UsdGeom.Scope.Define(stage, ROOT)
    for i, c in enumerate(colliders):
        path = f"{ROOT}/{c.type}_{i}"
        flat = dim == 2  # 2D: prisms through the slab, centred on it
        if c.type == "sphere" and not flat:
            prim = UsdGeom.Sphere.Define(stage, path)
            prim.CreateRadiusAttr(c.radius)
        elif c.type in ("sphere", "cylinder"):
            prim = UsdGeom.Cylinder.Define(stage, path)
            along = "Z" if flat and c.type == "sphere" else c.axis.upper()  # a 2D ball is a disk in the slab
            prim.CreateAxisAttr(along)
            prim.CreateRadiusAttr(c.radius)
            prim.CreateHeightAttr(slab if along == "Z" and flat else c.length)
        elif c.type == "box":
            prim = UsdGeom.Cube.Define(stage, path)
            prim.CreateSizeAttr(1.0)
        else:  # glass
            prim = UsdGeom.Mesh.Define(stage, path)
            axis = "xyz".index(c.axis)
            if flat:
                points, faces = _extrude_u(c.radius, c.height, c.wall_thickness, axis, slab)
            else:
                points, faces = _revolve(_glass_profile(c.radius, c.height, c.wall_thickness), axis)
            pts = Vt.Vec3fArray([Gf.Vec3f(*p) for p in points])
            prim.CreatePointsAttr(pts)
            prim.CreateExtentAttr(UsdGeom.PointBased.ComputeExtent(pts))
            prim.CreateFaceVertexCountsAttr([len(f) for f in faces])
            prim.CreateFaceVertexIndicesAttr([i for f in faces for i in f])
        prim.CreateDisplayColorAttr([Gf.Vec3f(*COLOR)])
        bind_collider(stage, prim.GetPrim(), COLOR)
        # Glass and (2D) prisms are built from their base; the primitives are centred.
        lift = slab / 2 if flat and c.type in ("sphere", "cylinder", "box") else 0.0
        translate = prim.AddTranslateOp()  # first in xformOpOrder: applied after the scale
        if c.type == "box":
            prim.AddScaleOp().Set(Gf.Vec3f(*(tuple(c.size) + ((slab,) if flat else ()))))
        centre = lambda t: Gf.Vec3d(*(tuple(c.center_at(t)) + ((lift,) if flat else ())))  # noqa: E731
        if c.moves:
            for f in range(frames + 1):
                translate.Set(centre(f / fps), f)
        else:
            translate.Set(centre(0.0))
