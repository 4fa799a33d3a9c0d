"""`warp-mpm-bubbles blender`: each example, imported by Blender's own USD importer (bpy), comes in
with its fps, frame range, particles, surface mesh, materials, a camera and a light. Skipped where
bpy is not installed (README: Install, Blender: Python 3.11, numpy < 2, its own venv .venv-blender).
The set-up bpy does not compute (camera placement, fps, frame range) is tested without it."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from scenes import SMALL_2D

from warp_mpm_bubbles.cli import main

try:
    import tomllib
except ImportError:  # Python 3.10
    import tomli as tomllib

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = sorted(p.stem for p in (ROOT / "examples").glob("*.py") if p.with_suffix(".toml").exists())  # a scene each


def test_without_bpy_the_command_says_how_to_install_it(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "bpy", None)  # import bpy fails, as where it is not installed
    assert main(["blender", str(tmp_path / "x.usdc")]) == 2
    err = capsys.readouterr().err
    # The README's steps, word for word: its own venv, then the extra installed into it.
    readme = (ROOT / "README.md").read_text()
    for step in ("python3.11 -m venv .venv-blender", '.venv-blender/bin/pip install -e ".[blender]"'):
        assert step in err and step in readme
    assert "Traceback" not in err


def test_render_flags_are_refused_before_anything_starts(capsys):
    for argv, says in ((["--render", "x"], "--render"), (["--samples", "0"], "1 to 4096")):
        with pytest.raises(SystemExit) as stop:
            main(["blender", "out.usdc", *argv])
        assert stop.value.code == 2 and says in capsys.readouterr().err


def test_frame_range_and_fps_come_from_the_file(tmp_path):
    from warp_mpm_bubbles.io.blender import fps_settings, frame_in_range, stage_timing

    out = tmp_path / "small.usdc"
    scene = tmp_path / "small.toml"
    scene.write_text(SMALL_2D.format(out=out.as_posix(), frames=2))
    assert main(["run", str(scene), "--quiet"]) == 0
    info = stage_timing(out)
    assert (info["start"], info["end"]) == (0, 2) and info["fps"] == pytest.approx(60.0)
    assert info["up_axis"] == "Y" and all(lo < hi for lo, hi in zip(info["lo"], info["hi"]))
    assert frame_in_range(2, info) is None and "from 0 to 2" in frame_in_range(3, info)
    assert fps_settings(30.0) == (30, 1.0)
    whole, base = fps_settings(29.97)
    assert whole == 30 and whole / base == pytest.approx(29.97, rel=1e-12)


@pytest.mark.parametrize("aspect", [16 / 9, 1.0, 0.6])
@pytest.mark.parametrize("box", [((0, 0, 0), (0.8, 0.4, 0.2)), ((0, 0, 0), (0.16, 0.24, 0.002)),
                                 ((0.1, -0.2, 0.3), (0.12, -0.1, 0.9))])
def test_the_camera_sees_the_whole_box_and_fills_the_frame(box, aspect):
    """Every corner of the box (USD, Y-up) projects inside the image, and the box is not a speck in it."""
    from warp_mpm_bubbles.io.blender import camera_pose

    lo, hi = box
    pose = camera_pose(lo, hi, "Y", 1.0, aspect=aspect)
    eye, target = np.array(pose["location"]), np.array(pose["target"])
    forward = (target - eye) / np.linalg.norm(target - eye)
    right = np.cross(forward, (0, 0, 1))
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    half_w = pose["sensor_mm"] / 2 / pose["lens_mm"]  # tan of the half-angles (horizontal sensor fit)
    half_h = half_w / aspect
    corners = np.array([(x, -z, y) for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    rel = corners - eye
    depth = rel @ forward
    assert (depth > pose["clip_start"]).all() and (depth < pose["clip_end"]).all()
    sx, sy = np.abs(rel @ right) / depth / half_w, np.abs(rel @ up) / depth / half_h
    assert sx.max() <= 0.95 + 1e-9 and sy.max() <= 0.95 + 1e-9, "a corner of the box is outside the picture (a 5% margin kept)"
    assert max(sx.max(), sy.max()) > 0.9, "the box fills less than 90% of the picture's width or height"
    assert eye[1] < corners[:, 1].min() and eye[2] > target[2]  # in front (Blender's -y) and above
    centre = (corners.min(axis=0) + corners.max(axis=0)) / 2
    np.testing.assert_allclose(target, centre)


@pytest.mark.slow
@pytest.mark.parametrize("example", EXAMPLES)
def test_example_opens_ready_in_blender(tmp_path, example):
    bpy = pytest.importorskip("bpy")
    from warp_mpm_bubbles.io.blender import open_in_blender
    from warp_mpm_bubbles.io.surface import read_surface
    from warp_mpm_bubbles.io.usd_output import read_frames

    out = tmp_path / f"{example}.usdc"
    cmd = [sys.executable, str(ROOT / "examples" / f"{example}.py"), "--device", "cpu", "--num-frames", "1",
           "--stage-path", str(out), "--surface", "--quiet"]
    subprocess.run(cmd, check=True, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    fps = tomllib.loads((ROOT / "examples" / f"{example}.toml").read_text())["output"]["fps"]

    done = open_in_blender(out)
    assert Path(done["blend"]) == out.with_suffix(".blend") and out.with_suffix(".blend").exists()
    assert done["fps"] == pytest.approx(fps) and done["frames"] == (0, 1)
    # The same object names in every file: /World stays (it was merged away in dam_break).
    assert {"World", "Particles", "Prototypes", "Looks", "LiquidSurface", "Camera", "Sun"} <= set(done["objects"])
    assert done["materials"]["LiquidSurface"] == ["water"]
    assert done["materials"]["water"] == ["water"]  # the prototypes' materials came through
    assert done["hidden"] == ["water"] and bpy.data.objects["water"].hide_render  # the surface renders the water
    assert all(not bpy.data.objects[n].hide_render for n in ("air", "foam") if n in bpy.data.objects)
    scene = bpy.context.scene
    assert scene.camera is not None and scene.world is not None
    scene.frame_set(1)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    mesh = bpy.data.objects["LiquidSurface"].evaluated_get(depsgraph).data
    assert len(mesh.polygons) == len(read_surface(out, 1).indices)  # frame 1's mesh, from its clip layer
    particles = bpy.data.objects["Particles"].evaluated_get(depsgraph).evaluated_geometry()
    assert len(particles.instances_pointcloud().points) == len(read_frames(out)["frames"][1]["positions"])


@pytest.mark.slow
def test_render_writes_the_frame_and_refuses_one_the_file_lacks(tmp_path, capsys):
    pytest.importorskip("bpy")
    out = tmp_path / "small.usdc"
    scene = tmp_path / "small.toml"
    scene.write_text(SMALL_2D.format(out=out.as_posix(), frames=1))
    assert main(["run", str(scene), "--quiet"]) == 0
    assert main(["blender", str(out), "--render", "5"]) == 2
    assert "--render 5: frame 5 is not in the file: give one from 0 to 1" in capsys.readouterr().err
    assert main(["blender", str(out), "--render", "1", "--samples", "1"]) == 0
    png = tmp_path / "small_1.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 1000
