"""`warp-mpm-bubbles blender`: each example, imported by Blender's own USD importer (bpy), comes in
with its fps, frame range, particles, surface mesh, materials, a camera and a light. Skipped where
bpy is not installed (pip install -e ".[blender]": Python 3.11, numpy < 2, its own venv)."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from warp_mpm_bubbles.cli import main

try:
    import tomllib
except ImportError:  # Python 3.10
    import tomli as tomllib

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = sorted(p.stem for p in (ROOT / "examples").glob("*.py"))


def test_without_bpy_the_command_says_how_to_install_it(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "bpy", None)  # import bpy fails, as where it is not installed
    assert main(["blender", str(tmp_path / "x.usdc")]) == 2
    assert 'pip install -e ".[blender]"' in capsys.readouterr().err


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
