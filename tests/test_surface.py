"""The liquid's surface mesh (io/surface.py): closed, no zero-area faces, its volume the particles'
volume, a bubble's inner wall around the gas, steady at rest, and written per frame into the USD."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from warp_mpm_bubbles import Box, Domain, Material, Output, Scene, SceneError, SolverSettings
from warp_mpm_bubbles.core.grid import PHASE_LIQUID
from warp_mpm_bubbles.io.surface import SurfaceBuilder, read_surface
from warp_mpm_bubbles.io.usd_output import StageWriter, read_frames

ROOT = Path(__file__).resolve().parent.parent
DX = 0.01


def jittered(lo_cells, hi_cells, dim=3, ppc_axis=2, seed=0):
    """Particles at ppc_axis^dim random points per cell of the block lo..hi (cells), each its share."""
    h = DX / ppc_axis
    n = [(b - a) * ppc_axis for a, b in zip(lo_cells, hi_cells)]
    idx = np.indices(n).reshape(dim, -1).T
    pos = (idx + np.random.default_rng(seed).random(idx.shape)) * h + np.asarray(lo_cells) * DX
    if dim == 2:
        pos = np.column_stack([pos, np.full(len(pos), DX / 2)])  # the slab's middle, as seeding puts them
    return pos, np.full(len(pos), h**dim * (DX if dim == 2 else 1.0))


def shells(mesh) -> int:
    """Closed sphere-like shells, from the Euler characteristic V - E + F = 2 per shell."""
    e = np.sort(np.concatenate([mesh.indices[:, [0, 1]], mesh.indices[:, [1, 2]], mesh.indices[:, [2, 0]]]), axis=1)
    return (len(mesh.points) - len(np.unique(e, axis=0)) + len(mesh.indices)) // 2


def assert_closed_and_proper(mesh, h):
    counts = mesh.edge_face_counts()
    assert counts.min() == 2 and counts.max() == 2  # every edge in exactly two faces
    assert mesh.face_areas().min() > 1e-9 * h * h  # no zero-area face (measured >= 2e-7 h^2)
    assert np.allclose(np.linalg.norm(mesh.normals, axis=1), 1.0, atol=1e-4)


def test_block_against_two_walls_is_closed_there_and_converges_with_resolution():
    # Water in the corner x = 0, y = 0 of a 16^3-cell tank, 8 x 6 x 12 cells: two walls, four free sides.
    pos, vol = jittered((0, 0, 2), (8, 6, 14))
    ratios = []
    for res in (1, 2, 3):
        mesh = SurfaceBuilder(3, DX, (16, 16, 16), res, device="cpu").build(pos, vol)
        assert_closed_and_proper(mesh, DX / res)
        assert shells(mesh) == 1
        lo, hi = mesh.extent
        assert abs(lo[0]) < 1e-6 and abs(lo[1]) < 1e-6  # closed on the walls themselves, not pulled inside
        # The free sides: measured 0.1-0.2 cell beyond the particles' block at every resolution.
        assert 0.0 < hi[0] - 0.08 < 0.25 * DX and 0.0 < 0.02 - lo[2] < 0.25 * DX
        ratios.append(mesh.volume() / vol.sum())
    # Measured 0.972 / 0.984 / 0.987: the rounded free edges cost volume, less as the grid refines.
    assert ratios == pytest.approx([0.972, 0.984, 0.987], abs=0.003)
    errors = [abs(1 - r) for r in ratios]
    assert errors[0] > errors[1] > errors[2] and errors[1] - errors[2] < errors[0] - errors[1]


def test_same_particles_same_mesh_on_the_cpu():
    pos, vol = jittered((0, 0, 0), (6, 5, 4))
    builder = SurfaceBuilder(3, DX, (8, 8, 8), 2, device="cpu")
    a, b = builder.build(pos, vol), builder.build(pos, vol)  # the builder's arrays are reused
    assert np.array_equal(a.points, b.points) and np.array_equal(a.indices, b.indices) and len(a.indices) > 100


@pytest.mark.parametrize("radius_cells, bound", [(3, 0.03), (4, 0.03)])
def test_bubble_inner_wall_encloses_the_gas(radius_cells, bound):
    pos, vol = jittered((0, 0, 0), (16, 16, 16))
    gas = np.linalg.norm(pos - 0.08, axis=1) < radius_cells * DX
    mesh = SurfaceBuilder(3, DX, (16, 16, 16), 2, device="cpu").build(pos[~gas], vol[~gas])
    assert_closed_and_proper(mesh, DX / 2)
    assert shells(mesh) == 2  # the tank's outline and the bubble's wall, as a separate shell
    inner = vol.sum() - mesh.volume()  # the tank is full: what the outer shell holds minus the water
    # Measured -0.1% (3 cells) and -1.0% (4 cells); the bound is 10%.
    assert abs(inner / vol[gas].sum() - 1) < bound


def test_2d_is_a_closed_prism_through_the_slab():
    # A 2D run is a slab one cell thick: the mesh is the 2D surface extruded from z = 0 to z = dx, and
    # a 2D bubble a hole through the slab (the mesh a torus: Euler characteristic 0).
    pos, vol = jittered((0, 0), (32, 20), dim=2)
    hole = np.linalg.norm(pos[:, :2] - (0.16, 0.08), axis=1) < 0.05  # a resolved bubble, 5 cells in radius
    builder = SurfaceBuilder(2, DX, (32, 32, 1), 2, device="cpu")
    full, bubble = builder.build(pos, vol), builder.build(pos[~hole], vol[~hole])
    for mesh in (full, bubble):
        assert_closed_and_proper(mesh, DX / 2)
        lo, hi = mesh.extent
        assert lo[2] == pytest.approx(0.0, abs=1e-6) and hi[2] == pytest.approx(DX, abs=1e-6)
    assert shells(full) == 1 and shells(bubble) == 0
    assert full.volume() / vol.sum() == pytest.approx(0.988, abs=0.003)  # measured 0.988 (two free corners)
    gas_area = (full.volume() - bubble.volume()) / DX
    assert gas_area / (vol[hole].sum() / DX) == pytest.approx(1.029, abs=0.01)  # measured +2.9%; issue: 10%


def resting_tank(tmp_path, frames=4):
    return Scene(domain=Domain(size=(0.16, 0.12, 0.08), cell_size=DX), materials={"water": Material("water")},
                 shapes=[Box("water", min=(0, 0, 0), max=(0.16, 0.06, 0.08))],
                 solver=SolverSettings(particles_per_cell=8),
                 output=Output(path=str(tmp_path / "tank.usdc"), frames=frames, surface=True), name="tank").validate()


def test_resting_tank_run_writes_a_steady_closed_surface_per_frame(tmp_path):
    from warp_mpm_bubbles.io.runner import run_scene, summary

    scene = resting_tank(tmp_path)
    result = run_scene(scene, device="cpu", progress=False)
    sim = result.simulation
    assert "surface" in sim.timer.seconds  # its own line in the summary
    assert any(line.startswith("  surface mesh:") and "ms per frame" in line for line in summary(result).splitlines())
    p = sim.particles_numpy()
    liquid = p["volume"][p["phase"] == PHASE_LIQUID].sum()
    meshes = [read_surface(scene.output.path, f) for f in range(scene.output.frames + 1)]
    h = DX / 2
    for mesh in meshes:
        assert_closed_and_proper(mesh, h)
        assert shells(mesh) == 1
        assert mesh.volume() / liquid == pytest.approx(0.994, abs=0.01)  # measured 0.993-0.995; issue: 5%
        lo, hi = mesh.extent  # on five walls: the floor and the four sides
        assert np.allclose(lo, 0.0, atol=1e-6) and hi[0] == pytest.approx(0.16) and hi[2] == pytest.approx(0.08)
        assert 0.06 < hi[1] < 0.06 + 1.0 * h  # the free surface: measured 0.0616-0.0635
    for a, b in zip(meshes, meshes[1:]):
        assert abs(b.volume() / a.volume() - 1) < 0.005  # measured <= 0.13% between frames
        top_a, top_b = (m.points[m.normals[:, 1] > 0.9, 1].mean() for m in (a, b))
        assert abs(top_b - top_a) < 0.05 * h  # the free surface's mean height: measured <= 0.02 h per frame


def test_usd_surface_attributes_are_clip_animated(tmp_path):
    from pxr import Usd, UsdGeom

    scene = resting_tank(tmp_path, frames=1)
    from warp_mpm_bubbles.io.runner import run_scene

    run_scene(scene, device="cpu", progress=False)
    stage = Usd.Stage.Open(scene.output.path)
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/World/LiquidSurface"))
    assert mesh and mesh.GetNormalsInterpolation() == UsdGeom.Tokens.vertex
    for attr in (mesh.GetPointsAttr(), mesh.GetFaceVertexCountsAttr(), mesh.GetFaceVertexIndicesAttr(),
                 mesh.GetNormalsAttr(), mesh.GetExtentAttr()):
        assert attr.GetTimeSamples() == [0.0, 1.0], attr.GetName()  # from the frame layers
        spec = stage.GetRootLayer().GetAttributeAtPath(attr.GetPath())  # declared in the top file, no values
        assert not spec.HasDefaultValue() and not stage.GetRootLayer().ListTimeSamplesForPath(attr.GetPath())
    from pxr import Sdf

    layer = Sdf.Layer.FindOrOpen(str(Path(scene.output.path).with_name("tank_frames") / "tank.000001.usdc"))
    assert layer.ListTimeSamplesForPath("/World/LiquidSurface.points") == [1.0]  # frame 1's own layer
    assert read_frames(scene.output.path)["frames"][1]["positions"].shape[1] == 3  # the particles still there


def test_writer_refuses_a_surface_it_was_not_made_for(tmp_path):
    pos, vol = jittered((0, 0, 0), (2, 2, 2))
    mesh = SurfaceBuilder(3, DX, (4, 4, 4), device="cpu").build(pos, vol)
    with StageWriter(tmp_path / "a.usdc", fps=30, materials=[("water", (0, 0, 1))], particle_radius=0.001) as w:
        with pytest.raises(ValueError, match="surface=True"):
            w.write_frame(0, pos, np.zeros_like(pos), np.arange(len(pos)), np.zeros(len(pos)), surface=mesh)


@pytest.mark.parametrize("key, value, message", [
    ("surface", "yes", "expected true or false"),
    ("surface_resolution", 0, "must be a whole number >= 1"),
    ("surface_resolution", 1.5, "must be a whole number"),
    ("surface_smoothing", 10.0, "<= 4"),
])
def test_bad_surface_settings_name_the_key(tmp_path, key, value, message):
    scene = resting_tank(tmp_path)
    setattr(scene.output, key, value)
    with pytest.raises(SceneError, match=rf"\[output\]\.{key} = .*{message}"):
        scene.validate()


@pytest.mark.parametrize("example", ["dam_break", "pour_glass"])
def test_examples_with_surface_flag_write_closed_meshes(tmp_path, example):
    out = tmp_path / f"{example}.usdc"
    cmd = [sys.executable, str(ROOT / "examples" / f"{example}.py"), "--device", "cpu", "--num-frames", "1",
           "--stage-path", str(out), "--surface", "--quiet"]
    subprocess.run(cmd, check=True, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    dx, slab = (0.0125, 1.0) if example == "dam_break" else (0.002, 0.002)
    water0 = 0.2 * 0.3 * 0.2 if example == "dam_break" else 0.08 * 0.036 * slab  # the scenes' water boxes
    for frame in (0, 1):
        mesh = read_surface(out, frame)
        assert_closed_and_proper(mesh, dx / 2)
    from pxr import Usd, UsdGeom, UsdShade  # the materials are bound in the examples too

    stage = Usd.Stage.Open(str(out))
    bound = lambda prim: UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()[0].GetPath().name  # noqa: E731
    targets = UsdGeom.PointInstancer.Get(stage, "/World/Particles").GetPrototypesRel().GetTargets()
    assert [bound(stage.GetPrimAtPath(t)) for t in targets] == [t.name for t in targets]
    assert bound(stage.GetPrimAtPath("/World/LiquidSurface")) == "water"
    colliders = stage.GetPrimAtPath("/World/Colliders")
    assert [bound(c) for c in colliders.GetChildren()] == ["Collider"] if example == "pour_glass" else not colliders
    # Frame 0, before anything moves: measured 0.998 (dam break) and 0.985 (the glass: the kernel's gap
    # along the glass's wall, which the field does not carve).
    assert read_surface(out, 0).volume() / water0 == pytest.approx(0.998 if example == "dam_break" else 0.985,
                                                                   abs=0.01)


def test_preview_draws_the_surface_2d_cut_and_3d_shaded(tmp_path):
    pytest.importorskip("matplotlib")
    from warp_mpm_bubbles.io.preview import render_preview
    from warp_mpm_bubbles.io.preview_surface import _cut
    from warp_mpm_bubbles.io.usd_materials import dress_stage

    for dim in (2, 3):
        pos, vol = jittered((0, 0), (12, 6), dim=2) if dim == 2 else jittered((0, 0, 0), (6, 4, 4))
        mesh = SurfaceBuilder(dim, DX, (16, 16, 16)[:dim] + ((1,) if dim == 2 else ()), 2, device="cpu").build(pos, vol)
        out = tmp_path / f"p{dim}.usdc"
        with StageWriter(out, fps=30, materials=[("water", (0.2, 0.45, 0.9))], particle_radius=DX / 4, surface=True,
                         decorate=lambda st: dress_stage(st, [("water", "liquid", (0.2, 0.45, 0.9))])) as w:
            w.write_frame(0, pos, np.zeros_like(pos), np.arange(len(pos)), np.zeros(len(pos)), surface=mesh)
        png = tmp_path / f"p{dim}.png"
        render_preview(out, png, [0])
        assert png.stat().st_size > 5000
        if dim == 2:  # the cut through the slab's middle is a closed curve: each end shared by two segments
            seg = _cut(mesh.points[mesh.indices], DX / 2)
            _, counts = np.unique(np.round(seg.reshape(-1, 3), 7), axis=0, return_counts=True)
            assert len(seg) > 50 and (counts == 2).all()
