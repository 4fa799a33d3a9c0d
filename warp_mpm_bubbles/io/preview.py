"""A quick look without a DCC: a strip of side views of chosen frames of a written animation.

    warp-mpm-bubbles preview dam_break.usdc --frames 0,4,8,12 --png dam_break.png

Needs matplotlib (`pip install warp-mpm-bubbles[plots]`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .preview_surface import draw_oblique, draw_surface, liquid_prototype, oblique_view
from .usd_output import read_frames

USD_SUFFIXES = (".usd", ".usdc", ".usda")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".pdf", ".svg")


class PreviewError(ValueError):
    """A preview argument was refused: the message names it and the fix."""


def parse_frames(text: str | None) -> list[int] | None:
    """--frames "0,4,8" -> [0, 4, 8]; None or "" -> None (four frames, spread). PreviewError otherwise."""
    if text is None or not text.strip():
        return None
    frames = []
    for part in text.split(","):
        part = part.strip()
        if not (part.isascii() and part.isdigit()) or len(part) > 9:
            raise PreviewError(f"--frames {text!r}: {part!r} is not a frame number; give whole numbers >= 0 "
                               f"separated by commas, e.g. --frames 0,12,24")
        frames.append(int(part))
    return frames


def load_animation(stage_path) -> dict:
    """read_frames, with every way a path can be wrong turned into a PreviewError."""
    path = Path(stage_path)
    if path.suffix.lower() == ".toml":
        raise PreviewError(f"{stage_path}: this is a scene file; preview reads the USD animation that "
                           f"`warp-mpm-bubbles run {stage_path}` writes (its [output].path)")
    if not path.exists():
        raise PreviewError(f"{stage_path}: no such file; give the .usdc (.usd, .usda) that `run` wrote")
    if not path.is_file():
        raise PreviewError(f"{stage_path}: not a file; give the .usdc (.usd, .usda) that `run` wrote")
    if path.suffix.lower() not in USD_SUFFIXES:
        raise PreviewError(f"{stage_path}: expected a .usd, .usdc or .usda file written by `run`")
    try:
        data = read_frames(path)
    except Exception as err:  # noqa: BLE001 (pxr raises its own Tf.ErrorException on a bad file)
        first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        raise PreviewError(f"{stage_path}: cannot read it as a USD animation ({first[:200]})") from None
    if not data["frames"]:
        raise PreviewError(f"{stage_path}: holds no particle frames (/World/Particles has no time samples); "
                           f"is it a file written by `warp-mpm-bubbles run`?")
    return data


def check_image_path(png_path):
    """The image must have a known suffix and a directory that exists."""
    path = Path(png_path)
    if path.suffix.lower() not in IMAGE_SUFFIXES:
        raise PreviewError(f"--png {png_path}: expected a file name ending in {', '.join(IMAGE_SUFFIXES)}")
    if not path.absolute().parent.is_dir():
        raise PreviewError(f"--png {png_path}: directory {path.absolute().parent} does not exist; create it "
                           f"or choose another path")


def render_preview(stage_path, png_path, frames=None, axes=(0, 1), title=None, dpi=110, color_by="auto"):
    """Scatter the particles of each frame projected on `axes` (x, y by default); where the file has
    the liquid's surface mesh, the surface (2D: the cut through the slab, 3D: shaded) instead of the
    liquid's particles, with the other particles (bubbles, foam) on top.

    color_by: "speed", "material" (each material its own colour, later materials drawn on top, so
    bubbles show inside the water), or "auto" (material when there are several, else speed).
    """
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise PreviewError("preview needs matplotlib: from the checkout, pip install -e '.[plots]' "
                           "(or pip install matplotlib)") from None

    check_image_path(png_path)
    data = load_animation(stage_path)
    available = sorted(data["frames"])
    if frames is None:
        frames = available[:: max(1, len(available) // 4)][:4]
    missing = [f for f in frames if f not in data["frames"]]
    if missing:
        raise PreviewError(f"--frames: {', '.join(map(str, missing))} not in {stage_path}, which has frames "
                           f"{available[0]}..{available[-1]}")

    all_pos = np.concatenate([np.asarray(data["frames"][f]["positions"]).reshape(-1, 3) for f in frames])
    if not len(all_pos):
        raise PreviewError(f"--frames: frames {', '.join(map(str, frames))} of {stage_path} hold no particles")
    lo, hi = all_pos[:, axes].min(axis=0), all_pos[:, axes].max(axis=0)
    vmax = max(float(np.linalg.norm(data["frames"][f]["velocities"], axis=1).max()) for f in frames) or 1.0
    aspect = (hi[1] - lo[1]) / max(hi[0] - lo[0], 1e-9)
    fig, axs = plt.subplots(1, len(frames), figsize=(3.2 * len(frames), 3.2 * aspect + 0.8), squeeze=False)
    n_materials = max(int(data["frames"][f]["proto_indices"].max(initial=0)) + 1 for f in frames)
    by_material = color_by == "material" or (color_by == "auto" and n_materials > 1)
    palette = ("#3373e6", "#f2a81d", "#e64b3c", "#3cbf6e")
    sc = None
    liquid = liquid_prototype(stage_path)  # not None: the file has a surface mesh, drawn instead of the water
    flat = bool(np.ptp(all_pos[:, 2]) == 0)  # a 2D run's slab
    for ax, f in zip(axs[0], frames):
        p = data["frames"][f]
        if liquid is not None and not flat:  # 3D: the shaded mesh seen from above at an angle
            box = np.stack([all_pos.min(axis=0), all_pos.max(axis=0)])
            corners = np.array([[box[(i >> a) & 1, a] for a in range(3)] for i in range(8)])
            view = oblique_view(axes)
            draw_oblique(ax, stage_path, f, p["positions"][p["proto_indices"] != liquid], view, corners)
            _frame_on(ax, _draw_colliders_oblique(ax, stage_path, f, view))
            ax.set_title(f"frame {f}  t = {f / data['fps']:.3f} s", fontsize=9)
            continue
        if liquid is not None and draw_surface(ax, stage_path, f, axes, flat=flat):
            p = {k: v[p["proto_indices"] != liquid] if k != "extent" else v for k, v in p.items()}
        pos = p["positions"]
        if not len(pos):  # all of it drawn as the surface
            pass
        elif by_material:
            for m in range(n_materials):  # later materials (gas, foam) drawn larger, on top
                pts = pos[p["proto_indices"] == m]
                ax.scatter(pts[:, axes[0]], pts[:, axes[1]], s=1.0 if m == 0 else 3.0, color=palette[m % len(palette)],
                           linewidths=0)
        else:
            speed = np.linalg.norm(p["velocities"], axis=1)
            order = np.argsort(pos[:, 2])
            sc = ax.scatter(pos[order, axes[0]], pos[order, axes[1]], c=speed[order], s=1.0, cmap="viridis",
                            vmin=0.0, vmax=vmax, linewidths=0)
        c_lo, c_hi = _draw_colliders(ax, stage_path, f, axes)
        ax.set_xlim(min(lo[0], c_lo[0]), max(hi[0], c_hi[0]))
        ax.set_ylim(min(lo[1], c_lo[1]), max(hi[1], c_hi[1]))
        ax.set_aspect("equal")
        ax.set_title(f"frame {f}  t = {f / data['fps']:.3f} s", fontsize=9)
        ax.tick_params(labelsize=7)
    _fit_around_panels(fig, axs[0], sc, title)
    try:
        fig.savefig(png_path, dpi=dpi, bbox_inches="tight")
    except OSError as err:
        raise PreviewError(f"--png {png_path}: cannot write it ({err.strerror or err})") from None
    finally:
        plt.close(fig)
    return png_path


def _draw_colliders(ax, stage_path, frame, axes):
    """Draw the colliders written under /World/Colliders (grey), projected on `axes`; returns
    the (lo, hi) corners of what was drawn in those axes (inf, -inf if nothing)."""
    from pxr import Usd, UsdGeom

    drawn_lo, drawn_hi = np.full(2, np.inf), np.full(2, -np.inf)
    stage = Usd.Stage.Open(str(stage_path))
    root = stage.GetPrimAtPath("/World/Colliders")
    for prim in root.GetChildren() if root else []:
        box = UsdGeom.Imageable(prim).ComputeWorldBound(frame, UsdGeom.Tokens.default_).ComputeAlignedRange()
        lo, hi = box.GetMin(), box.GetMax()
        a, b = axes
        drawn_lo = np.minimum(drawn_lo, (lo[a], lo[b]))
        drawn_hi = np.maximum(drawn_hi, (hi[a], hi[b]))
        if prim.IsA(UsdGeom.Mesh):  # the glass: its points, projected
            m = UsdGeom.Mesh(prim)
            pts = np.asarray(m.GetPointsAttr().Get()) + np.asarray(
                UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(frame).ExtractTranslation())
            if len(m.GetFaceVertexCountsAttr().Get()) == len(pts) // 2 + 2:  # a 2D U extruded: fill its cap
                ax.fill(*_outline(pts[:, [a, b]]), color="0.6", alpha=0.6, linewidth=0)
            else:  # a revolved 3D glass: its surface points
                ax.scatter(pts[:, a], pts[:, b], s=1.0, color="0.6", linewidths=0)
        elif prim.IsA(UsdGeom.Cube):
            ax.add_patch(_patches().Rectangle((lo[a], lo[b]), hi[a] - lo[a], hi[b] - lo[b], color="0.6", alpha=0.6))
        else:  # spheres and cylinders: a disk in a side view of a 2D run, an outline otherwise
            centre = ((lo[a] + hi[a]) / 2, (lo[b] + hi[b]) / 2)
            ax.add_patch(_patches().Ellipse(centre, hi[a] - lo[a], hi[b] - lo[b], color="0.6", alpha=0.6))
    return drawn_lo, drawn_hi


def _patches():
    import matplotlib.patches

    return matplotlib.patches


def _outline(points):
    """The first half of an extruded outline's points is its front cap, in order."""
    half = points[: len(points) // 2]
    return half[:, 0], half[:, 1]


def _fit_around_panels(fig, axs, sc, title):
    """Put the colour bar and the title against the panels as drawn. An equal-aspect panel is
    shrunk to fit its slot, so a colour bar or title placed by the figure's size would stand
    away from the panels, leaving a blank band that bbox_inches="tight" cannot crop."""
    fig.canvas.draw()  # applies the equal aspect: the panels' real boxes
    boxes = [ax.get_position() for ax in axs]
    y0, y1, x1 = min(b.y0 for b in boxes), max(b.y1 for b in boxes), max(b.x1 for b in boxes)
    if sc is not None:
        cax = fig.add_axes((x1 + 0.015, y0, 0.012, y1 - y0))
        fig.colorbar(sc, cax=cax, label="speed (m/s)")
    if title:
        to_fig = fig.transFigure.inverted()
        top = max(to_fig.transform(ax.get_tightbbox().corners()).max(axis=0)[1] for ax in axs)
        fig.suptitle(title, fontsize=10, y=top + 0.01, va="bottom")


def _draw_colliders_oblique(ax, stage_path, frame, view) -> list:
    """Draw the colliders under /World/Colliders as seen from the oblique `view` of a 3D run: each
    one's silhouette (the convex hull of its projected surface points), grey, over the water as
    in the side view. Returns the patches, one per collider."""
    from pxr import Usd

    stage = Usd.Stage.Open(str(stage_path))
    root = stage.GetPrimAtPath("/World/Colliders")
    drawn = []
    for prim in root.GetChildren() if root else []:
        pts = _collider_points(prim, frame)
        if pts is None:
            continue
        q = pts @ view[:2].T
        drawn.append(ax.add_patch(_patches().Polygon(_hull(q), closed=True, facecolor="0.6", alpha=0.6,
                                                     edgecolor="0.35", linewidth=0.6, zorder=3)))
    return drawn


def _collider_points(prim, frame):
    """Points on a collider prim's surface in world space (enough to outline it), None if unknown."""
    from pxr import UsdGeom

    if prim.IsA(UsdGeom.Mesh):  # the glass
        local = np.asarray(UsdGeom.Mesh(prim).GetPointsAttr().Get(frame), dtype=float)
    elif prim.IsA(UsdGeom.Cube):
        half = UsdGeom.Cube(prim).GetSizeAttr().Get(frame) / 2
        local = np.array([[half * (1 if (i >> a) & 1 else -1) for a in range(3)] for i in range(8)], dtype=float)
    elif prim.IsA(UsdGeom.Sphere):
        r = UsdGeom.Sphere(prim).GetRadiusAttr().Get(frame)
        k = np.arange(400) + 0.5  # a Fibonacci sphere: its hull is the disk seen from any side
        z, phi = 1 - 2 * k / len(k), np.pi * (1 + 5**0.5) * k
        local = r * np.column_stack([np.sqrt(1 - z * z) * np.cos(phi), np.sqrt(1 - z * z) * np.sin(phi), z])
    elif prim.IsA(UsdGeom.Cylinder):
        cyl = UsdGeom.Cylinder(prim)
        r, h, axis = cyl.GetRadiusAttr().Get(frame), cyl.GetHeightAttr().Get(frame), cyl.GetAxisAttr().Get()
        t = np.linspace(0, 2 * np.pi, 64, endpoint=False)
        ring = np.column_stack([r * np.cos(t), r * np.sin(t)])
        a = "XYZ".index(axis)
        local = np.zeros((128, 3))
        local[:, [i for i in range(3) if i != a]] = np.vstack([ring, ring])
        local[:, a] = np.repeat([-h / 2, h / 2], 64)
    else:
        return None
    m = np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(frame))  # row vectors: p' = p M
    return local @ m[:3, :3] + m[3, :3]


def _hull(q):
    """Convex hull of 2D points, counter-clockwise (Andrew's monotone chain)."""
    q = np.unique(np.round(q, 12), axis=0)
    if len(q) < 3:
        return q

    def half(points):
        out = []
        for p in points:
            while len(out) >= 2 and _turn(out[-2], out[-1], p) <= 0:
                out.pop()
            out.append(p)
        return out[:-1]

    return np.array(half(q) + half(q[::-1]))


def _turn(o, a, b):
    """> 0 where o -> a -> b turns counter-clockwise."""
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])


def _frame_on(ax, patches):
    """Widen the panel's limits to take in the drawn colliders."""
    for patch in patches:
        xy = patch.get_xy()
        x0, x1 = ax.get_xlim()
        y0, y1 = ax.get_ylim()
        ax.set_xlim(min(x0, xy[:, 0].min()), max(x1, xy[:, 0].max()))
        ax.set_ylim(min(y0, xy[:, 1].min()), max(y1, xy[:, 1].max()))
