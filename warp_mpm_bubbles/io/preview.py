"""A quick look without a DCC: a strip of side views of chosen frames of a written animation.

    warp-mpm-bubbles preview dam_break.usdc --frames 0,4,8,12 --png dam_break.png

Needs matplotlib (`pip install warp-mpm-bubbles[plots]`).
"""

from __future__ import annotations

import numpy as np

from .preview_surface import draw_oblique, draw_surface, liquid_prototype, oblique_view
from .usd_output import read_frames


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
    except ImportError as err:
        raise SystemExit("preview needs matplotlib: pip install 'warp-mpm-bubbles[plots]'") from err

    data = read_frames(stage_path)
    available = sorted(data["frames"])
    if frames is None:
        frames = available[:: max(1, len(available) // 4)][:4]
    missing = [f for f in frames if f not in data["frames"]]
    if missing:
        raise SystemExit(f"frames {missing} are not in {stage_path} (it has {available[0]}..{available[-1]})")

    all_pos = np.concatenate([data["frames"][f]["positions"] for f in frames])
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
            draw_oblique(ax, stage_path, f, p["positions"][p["proto_indices"] != liquid], oblique_view(axes), corners)
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
    if sc is not None:
        fig.colorbar(sc, ax=axs[0].tolist(), label="speed (m/s)", shrink=0.8)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.savefig(png_path, dpi=dpi, bbox_inches="tight")
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
