"""A quick look without a DCC: a strip of side views of chosen frames of a written animation.

    warp-mpm-bubbles preview dam_break.usdc --frames 0,4,8,12 --png dam_break.png

Needs matplotlib (`pip install warp-mpm-bubbles[plots]`).
"""

from __future__ import annotations

import numpy as np

from .usd_output import read_frames


def render_preview(stage_path, png_path, frames=None, axes=(0, 1), title=None, dpi=110, color_by="auto"):
    """Scatter the particles of each frame projected on `axes` (x, y by default).

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
    for ax, f in zip(axs[0], frames):
        p = data["frames"][f]
        pos = p["positions"]
        if by_material:
            for m in range(n_materials):
                pts = pos[p["proto_indices"] == m]
                ax.scatter(pts[:, axes[0]], pts[:, axes[1]], s=1.0, color=palette[m % len(palette)], linewidths=0)
        else:
            speed = np.linalg.norm(p["velocities"], axis=1)
            order = np.argsort(pos[:, 2])
            sc = ax.scatter(pos[order, axes[0]], pos[order, axes[1]], c=speed[order], s=1.0, cmap="viridis",
                            vmin=0.0, vmax=vmax, linewidths=0)
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
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
