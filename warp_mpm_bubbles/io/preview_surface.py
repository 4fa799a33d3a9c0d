"""The liquid's surface mesh in `preview` (matplotlib): a 2D run's cut through its slab, a 3D run's
mesh shaded (Lambert, one light, painter's order) and projected along the axis the view looks down."""

from __future__ import annotations

import numpy as np

from .surface import read_surface

_LIGHT = np.array([0.35, 0.6, 0.72])


def liquid_prototype(stage_path) -> int | None:
    """Index of the prototype whose material the surface mesh shares (the liquid's), if any."""
    from pxr import Usd, UsdGeom, UsdShade

    from .usd_output import INSTANCER, SURFACE

    stage = Usd.Stage.Open(str(stage_path))
    surface, inst = stage.GetPrimAtPath(SURFACE), UsdGeom.PointInstancer.Get(stage, INSTANCER)
    if not surface or not inst:
        return None
    bound = lambda prim: UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()[0].GetPath()  # noqa: E731
    mine = bound(surface)
    for i, target in enumerate(inst.GetPrototypesRel().GetTargets()):
        if bound(stage.GetPrimAtPath(target)) == mine:
            return i
    return 0


def draw_surface(ax, stage_path, frame, axes, flat: bool, color=(0.2, 0.45, 0.9)) -> bool:
    """Draw the mesh of `frame` on `ax`; False if the file has no surface. flat: a 2D run's slab."""
    mesh = read_surface(stage_path, frame)
    if mesh is None:
        return False
    if not len(mesh.indices):
        return True
    from matplotlib.collections import LineCollection, PolyCollection

    depth_axis = 3 - sum(axes)
    tri = mesh.points[mesh.indices]  # (F, 3, 3)
    lo, hi = mesh.points[:, depth_axis].min(), mesh.points[:, depth_axis].max()
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
    if flat and depth_axis == 2:  # a 2D run: fill the front cap (faces looking along -z), outline the cut through the slab
        cap = n[:, 2] < -0.3  # the cap at z = 0 (tilted near the free surface)
        fill = tuple(1.0 - 0.45 * (1.0 - np.asarray(color)))  # opaque, so the triangles' seams do not show
        ax.add_collection(PolyCollection(tri[cap][:, :, list(axes)], facecolors=[fill], edgecolors=[fill],
                                         linewidths=0.3))
        ax.add_collection(LineCollection(_cut(tri, (lo + hi) / 2)[:, :, list(axes)], colors=[color], linewidths=1.0))
        return True
    facing = n[:, depth_axis] > 0  # towards the viewer, who looks down -depth_axis
    light = _LIGHT / np.linalg.norm(_LIGHT)
    shade = 0.3 + 0.7 * np.clip(n[facing] @ light, 0.0, 1.0)
    order = np.argsort(tri[facing][:, :, depth_axis].mean(axis=1))  # far first
    faces = tri[facing][order][:, :, list(axes)]
    colors = np.clip(np.outer(shade[order], color) + 0.15 * shade[order, None] ** 8, 0, 1)
    ax.add_collection(PolyCollection(faces, facecolors=colors, edgecolors=colors, linewidths=0.2))
    return True


def _cut(tri, z):
    """Segments where the triangles cross the plane at height z along axis 2."""
    d = tri[:, :, 2] - z
    segments = []
    for f in np.nonzero((d.min(axis=1) < 0) & (d.max(axis=1) > 0))[0]:
        pts = []
        for a, b in ((0, 1), (1, 2), (2, 0)):
            if (d[f, a] < 0) != (d[f, b] < 0):
                t = d[f, a] / (d[f, a] - d[f, b])
                pts.append(tri[f, a] + t * (tri[f, b] - tri[f, a]))
        if len(pts) == 2:
            segments.append(pts)
    return np.asarray(segments).reshape(-1, 2, 3)


def oblique_view(axes, azimuth=-30.0, elevation=22.0) -> np.ndarray:
    """Rows: screen right, screen up and towards the viewer, for a camera turned `azimuth` degrees
    about the up axis axes[1] from the side view along the third axis, and raised `elevation` degrees."""
    right, up = np.eye(3)[axes[0]], np.eye(3)[axes[1]]
    back = np.cross(right, up)
    a, e = np.radians(azimuth), np.radians(elevation)
    r = np.cos(a) * right + np.sin(a) * back
    b = np.cross(r, up)
    towards = np.cos(e) * b + np.sin(e) * up
    return np.stack([r, np.cross(towards, r), towards])


def draw_oblique(ax, stage_path, frame, others, view, corners, color=(0.2, 0.45, 0.9)) -> None:
    """A 3D run's surface mesh shaded from the oblique `view`, the other particles (bubbles, foam) on
    top, framed on the projected `corners` (8, 3) of the box the frames fill."""
    from matplotlib.collections import PolyCollection

    mesh = read_surface(stage_path, frame)
    if mesh is not None and len(mesh.indices):
        tri = mesh.points[mesh.indices] @ view.T  # (F, 3, 3): screen x, screen y, depth (towards)
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
        facing = n[:, 2] > 0
        light = np.array([-0.4, 0.7, 0.6]) / np.linalg.norm([-0.4, 0.7, 0.6])  # from upper left, in view space
        shade = 0.25 + 0.75 * np.clip(n[facing] @ light, 0.0, 1.0)
        order = np.argsort(tri[facing][:, :, 2].mean(axis=1))  # far first
        colors = np.clip(np.outer(shade[order], color) + 0.2 * shade[order, None] ** 12, 0, 1)
        ax.add_collection(PolyCollection(tri[facing][order][:, :, :2], facecolors=colors, edgecolors=colors,
                                         linewidths=0.2))
    if len(others):
        q = others @ view.T
        ax.scatter(q[:, 0], q[:, 1], s=2.0, color="#f2a81d", linewidths=0)
    c = corners @ view.T
    for i in range(8):  # the tank's edges, thin grey
        for j in range(i + 1, 8):
            if bin(i ^ j).count("1") == 1:
                ax.plot(c[[i, j], 0], c[[i, j], 1], color="0.7", linewidth=0.5, zorder=0)
    ax.set_xlim(c[:, 0].min(), c[:, 0].max())
    ax.set_ylim(c[:, 1].min(), c[:, 1].max())
    ax.set_aspect("equal")
    ax.set_axis_off()
