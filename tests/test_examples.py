"""Every example runs, so none rots: each script (examples/*.py) as a user starts it, which also runs
its twin scene file, and each scene file without a script through `run`, for two frames; its .usd
must hold particles in every frame, finite and inside the domain, with each phase the scene seeds,
each collider it declares and each effect it turns on.

The list comes from a glob, not by hand: a new example is run here the moment it is added. A script
that is not a scene file's twin must say which scene it runs with a module-level SCENE string.
"""

import importlib.util
import os
import pathlib
import runpy
import subprocess
import sys

import numpy as np
import pytest

from warp_mpm_bubbles.cli import main
from warp_mpm_bubbles.io.ownership import frames_dir
from warp_mpm_bubbles.io.usd_output import read_frames
from warp_mpm_bubbles.scene.model import load_scene

ROOT = pathlib.Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
SCENE_FILES = sorted(EXAMPLES.glob("*.toml"))
SCRIPTS = sorted(EXAMPLES.glob("*.py"))
# One case per example name: a script and its twin scene file are one run, not two.
EXAMPLE_NAMES = sorted({p.stem for p in SCENE_FILES + SCRIPTS})
FRAMES = 2  # as Warp's own example tests: enough to step, write and reopen every phase
# --quality preview (cfl 1.0: half the steps) is the smallest run every example takes as it is: a
# coarser grid would refuse the scenes whose walls are one cell thick.


def scene_of_script(script: pathlib.Path, tmp_path) -> pathlib.Path:
    """The scene file a script runs: its twin examples/<stem>.toml, or the SCENE string it defines
    (importing it also registers any stage of its own, which the scene may turn on)."""
    twin = script.with_suffix(".toml")
    if twin.exists():
        assert f'with_name("{twin.name}")' in script.read_text(), f"{script.name} does not run its twin {twin.name}"
        return twin
    name = f"example_{script.stem}"
    module = sys.modules.get(name)
    if module is None:  # imported once per process: a stage registers once
        spec = importlib.util.spec_from_file_location(name, script)
        module = sys.modules[name] = importlib.util.module_from_spec(spec)  # dataclasses look it up there
        spec.loader.exec_module(module)  # the __main__ guard keeps it from running
    assert isinstance(getattr(module, "SCENE", None), str), \
        f"{script.name} has no twin .toml and no SCENE string: this test cannot tell what it should write"
    path = tmp_path / f"{script.stem}_scene.toml"
    path.write_text(module.SCENE)
    return path


def check_output(scene_path, out: pathlib.Path):
    """What every example's output must hold after FRAMES frames."""
    from pxr import Usd, UsdGeom

    scene = load_scene(scene_path).validate()
    data = read_frames(out)
    assert sorted(data["frames"]) == list(range(FRAMES + 1))
    stage = Usd.Stage.Open(str(out))
    inst = UsdGeom.PointInstancer.Get(stage, "/World/Particles")
    if inst:  # one prototype per material, in the scene's order (foam comes with its effect), then
        # the sub-grid bubbles' own, one per gas, where the scene has them
        subgrid = [f"{m}_subgrid" for m, mat in scene.materials.items()
                   if mat.kind == "gas" and "subgrid_bubbles" in scene.effects]
        assert [p.name for p in inst.GetPrototypesRel().GetTargets()] == list(scene.materials) + subgrid
    assert stage.GetPrimAtPath("/World/ParticlePoints").IsValid() == (scene.output.format != "instancer")
    colliders = stage.GetPrimAtPath("/World/Colliders")
    assert (len(colliders.GetChildren()) if colliders else 0) == len(scene.colliders)

    d = scene.domain
    size = np.array(list(d.size) + [d.dx] * (3 - len(d.size)))  # a 2D run is a slab one cell thick
    seeded = sorted({list(scene.materials).index(s.material) for s in scene.shapes})
    for f, frame in sorted(data["frames"].items()):
        x = frame["positions"]
        assert len(x) > 0, f"frame {f} has no particles"
        assert np.isfinite(x).all() and np.isfinite(frame["velocities"]).all(), f"frame {f}: NaN or inf"
        assert (x >= -1e-6).all() and (x <= size + 1e-6).all(), \
            f"frame {f}: particles outside the domain {size}: {x.min(axis=0)} .. {x.max(axis=0)}"
        present = set(np.unique(frame["proto_indices"]).tolist())
        assert set(seeded) <= present, f"frame {f}: the seeded phases {seeded} are not all there ({present})"

    # The run's summary names every effect the scene turns on (foam, subgrid_bubbles, colliders, ...).
    log = (frames_dir(out) / "run.log").read_text()
    effects = next(line for line in log.splitlines() if line.strip().startswith("effects:"))
    assert all(name in effects for name in scene.effect_names), (effects, scene.effect_names)


@pytest.mark.parametrize("example", EXAMPLE_NAMES)
def test_example_runs_two_frames(tmp_path, monkeypatch, example):
    """A script is run as a user starts it, which also runs its twin scene file: in this process
    (Warp already started) when it is a twin's thin wrapper, in a process of its own when it defines
    its own scene (and perhaps a stage), so its run uses only what the script itself sets up. A
    scene file without a script: through `run`."""
    script, out = EXAMPLES / f"{example}.py", tmp_path / f"{example}.usdc"
    flags = ["--device", "cpu", "--num-frames", str(FRAMES), "--quality", "preview", "--stage-path", str(out), "--quiet"]
    if not script.exists():
        assert main(["run", str(EXAMPLES / f"{example}.toml"), *flags]) == 0
        check_output(EXAMPLES / f"{example}.toml", out)
        return
    if script.with_suffix(".toml").exists():
        scene = scene_of_script(script, tmp_path)
        monkeypatch.setattr(sys, "argv", [str(script), *flags])
        with pytest.raises(SystemExit) as done:
            runpy.run_path(str(script), run_name="__main__")
        assert done.value.code == 0
    else:
        run = subprocess.run([sys.executable, str(script), *flags], env=dict(os.environ, PYTHONPATH=str(ROOT)),
                             capture_output=True, text=True, timeout=300)
        assert run.returncode == 0, run.stderr
        scene = scene_of_script(script, tmp_path)
    check_output(scene, out)


def test_the_examples_are_found():
    """The glob is not silently empty (a moved folder would leave nothing to run and nothing failing)."""
    assert len(SCENE_FILES) >= 7 and len(SCRIPTS) >= len(SCENE_FILES)
