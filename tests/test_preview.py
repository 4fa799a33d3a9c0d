"""`preview`'s figure: panels that fill it (no blank band above them) and colliders drawn in 3D too."""

import numpy as np
import pytest

from warp_mpm_bubbles import Collider
from warp_mpm_bubbles.io.surface import SurfaceBuilder
from warp_mpm_bubbles.io.usd_colliders import write_colliders
from warp_mpm_bubbles.io.usd_materials import dress_stage
from warp_mpm_bubbles.io.usd_output import StageWriter

DX = 0.01
WATER = (0.2, 0.45, 0.9)


def tiny_run(path, dim, colliders=(), surface=True):
    """A one-frame animation of a block of water (with its surface mesh) and `colliders`, as `run` writes."""
    cells = (12, 6) if dim == 2 else (6, 4, 4)
    idx = np.stack(np.meshgrid(*[np.arange(2 * n) for n in cells], indexing="ij"), -1).reshape(-1, len(cells))
    pos = (idx + np.random.default_rng(0).random(idx.shape)) * DX / 2
    if dim == 2:
        pos = np.column_stack([pos, np.full(len(pos), DX / 2)])
    vol = np.full(len(pos), (DX / 2) ** dim * (DX if dim == 2 else 1.0))
    res = (16, 16, 16)[:dim] + ((1,) if dim == 2 else ())
    mesh = SurfaceBuilder(dim, DX, res, 2, device="cpu").build(pos, vol) if surface else None

    def decorate(stage):
        dress_stage(stage, [("water", "liquid", WATER)])
        write_colliders(stage, list(colliders), dim, DX, 30, 1)

    with StageWriter(path, fps=30, materials=[("water", WATER)], particle_radius=DX / 4, surface=surface,
                     decorate=decorate) as w:
        w.write_frame(0, pos, np.zeros_like(pos), np.arange(len(pos)), np.zeros(len(pos)), surface=mesh)
    return path


def blank_rows(png, side="top"):
    """How many rows at the top (or bottom) of the image's left half (the first panels: not the colour
    bar, which may stand taller) are all background (the first pixel's colour); and the image's height."""
    import matplotlib.image

    img = matplotlib.image.imread(str(png))[..., :3]
    img = img[:, : img.shape[1] // 2]
    rows = img if side == "top" else img[::-1]
    plain = np.all(np.abs(rows - img[0, 0]) < 1e-3, axis=(1, 2))
    return int(np.argmin(plain)) if not plain.all() else len(img), len(img)


def widest_blank_band(png):
    """The most rows in a row, anywhere in the image's left half, that are all background."""
    import matplotlib.image

    img = matplotlib.image.imread(str(png))[..., :3]
    img = img[:, : img.shape[1] // 2]
    plain = np.all(np.abs(img - img[0, 0]) < 1e-3, axis=(1, 2))
    best = run = 0
    for blank in plain:
        run = run + 1 if blank else 0
        best = max(best, run)
    return best


PAD_ROWS = 11 + 4  # bbox_inches="tight" keeps 0.1 inch of background (11 rows at the preview's 110 dpi)


@pytest.mark.parametrize("dim,surface,title", [(2, False, None), (2, True, "a title"), (3, False, "a title"),
                                               (3, True, "a title")],
                         ids=["2d_colour_bar", "2d_surface_title", "3d_colour_bar_title", "3d_surface_title"])
def test_the_figure_fits_its_panels_with_no_blank_band(tmp_path, dim, surface, title):
    # Measured before the fix (widest blank band, rows of the image's height): 35/199, 36/230, 83/287,
    # 22/279; after: 13/181, 13/201, 13/241, 11/263, the save's pad and no more.
    pytest.importorskip("matplotlib")
    from warp_mpm_bubbles.io.preview import render_preview

    png = render_preview(tiny_run(tmp_path / "a.usdc", dim, surface=surface), tmp_path / "a.png", [0] * 4, title=title)
    top, height = blank_rows(png)
    assert top <= PAD_ROWS and widest_blank_band(png) <= PAD_ROWS, (top, widest_blank_band(png), height)


def box_sphere_cylinder_glass(dim):
    still = dict(velocity=(0.0,) * dim, acceleration=(0.0,) * dim)
    z = (0.02,) if dim == 3 else ()
    return [Collider("box", (0.015, 0.02) + z, size=(0.01, 0.01) + ((0.01,) if dim == 3 else ()), **still),
            Collider("sphere", (0.045, 0.02) + z, radius=0.008, **still),
            Collider("cylinder", (0.03, 0.02) + z, radius=0.004, length=0.02, axis="x", **still),
            Collider("glass", (0.03, 0.0) + z, radius=0.01, height=0.03, wall_thickness=0.002, **still)]


def test_3d_preview_draws_each_collider(tmp_path):
    pytest.importorskip("matplotlib")
    from warp_mpm_bubbles.io.preview import render_preview

    import matplotlib.image

    images = {}
    for name, colliders in (("none", []), ("sphere", box_sphere_cylinder_glass(3)[1:2])):
        # The sphere lies inside the water's box, so the frame (and the image's size) is the same.
        stage = tiny_run(tmp_path / f"{name}.usdc", 3, colliders)
        images[name] = matplotlib.image.imread(str(render_preview(stage, tmp_path / f"{name}.png", [0])))[..., :3]
    assert images["none"].shape == images["sphere"].shape
    changed = np.any(np.abs(images["none"] - images["sphere"]) > 0.02, axis=2)
    # Its disk (radius 0.008 m) on a panel about 0.08 m across: some 3% of the panel, drawn half see-through.
    assert changed.mean() > 0.01, changed.mean()
    rows, cols = np.nonzero(changed)  # one blob, as wide as it is tall: a disk, not stray pixels
    assert abs((np.ptp(rows) + 1) / (np.ptp(cols) + 1) - 1) < 0.15


def test_the_oblique_view_outlines_every_kind_of_collider(tmp_path):
    pytest.importorskip("matplotlib")
    import matplotlib.pyplot as plt

    from warp_mpm_bubbles.io.preview import _draw_colliders_oblique
    from warp_mpm_bubbles.io.preview_surface import oblique_view

    stage = tiny_run(tmp_path / "c.usdc", 3, box_sphere_cylinder_glass(3))
    fig, ax = plt.subplots()
    view = oblique_view((0, 1))
    patches = _draw_colliders_oblique(ax, stage, 0, view)
    plt.close(fig)
    assert len(patches) == 4
    box, sphere = (p.get_xy() for p in patches[:2])
    corners = np.array([[0.015 + 0.005 * sx, 0.02 + 0.005 * sy, 0.02 + 0.005 * sz]
                        for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) @ view[:2].T
    assert np.allclose([box.min(axis=0), box.max(axis=0)], [corners.min(axis=0), corners.max(axis=0)], atol=1e-6)
    centre = np.array([0.045, 0.02, 0.02]) @ view[:2].T
    assert np.allclose(np.linalg.norm(sphere - centre, axis=1), 0.008, rtol=0.01)  # the sphere seen: a circle
