"""The stage protocol (core/stage.py): the step runs the stages a scene asks for, in one order,
and a stage from outside the package joins the same way (examples/damping_stage.py)."""

import importlib.util
import math
import pathlib
import sys

import numpy as np
import pytest
import warp as wp

from scenes import tank_2d
from warp_mpm_bubbles import Material, Scene, SceneError, Sphere
from warp_mpm_bubbles.core.simulation import Simulation
from warp_mpm_bubbles.core.stage import Stage, register_stage
from warp_mpm_bubbles.stages import BUILTIN_STAGES, STEP_ORDER

wp.config.quiet = True
EXAMPLE = pathlib.Path(__file__).parents[1] / "examples" / "damping_stage.py"


@pytest.fixture(scope="module")
def damping():
    spec = importlib.util.spec_from_file_location("damping_stage", EXAMPLE)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while the file executes
    spec.loader.exec_module(module)  # registers the stage
    return module


def drifting_drop(out, effects=None):
    # No gravity, one drop moving at 1 m/s in a large free-slip box: a uniform field, so the
    # pressure does nothing and only the damping changes the speed.
    scene = tank_2d(cells=32, out=out)
    scene.domain.gravity = (0.0, 0.0)
    scene.shapes = [Sphere("water", center=(0.3, 0.5), radius=0.1, velocity=(1.0, 0.0))]
    scene.effects = dict(effects or {})
    return scene


def test_a_stage_from_outside_runs_only_when_its_scene_asks(tmp_path, damping):
    plain = Simulation(drifting_drop(tmp_path / "a.usdc"), "cpu")
    damped = Simulation(drifting_drop(tmp_path / "b.usdc", {"damping": damping.Damping(rate=2.0)}), "cpu")
    assert plain.effects == [] and damped.effects == ["damping"]
    t = 0.0
    for _ in range(5):
        dt = 0.004
        plain.step(dt)
        damped.step(dt)
        t += dt
    assert "scale_faces" not in plain.launches and damped.launches["scale_faces"] == 5 * 2  # 2 axes
    v_plain = plain.particles_numpy()["velocities"][:, 0].mean()
    v_damped = damped.particles_numpy()["velocities"][:, 0].mean()
    # Uniform translation: each step scales u* by exp(-rate dt) exactly, so the ratio is exp(-rate t).
    print(f"plain {v_plain:.6f}, damped/plain {v_damped / v_plain:.6f} vs exp(-rate t) {math.exp(-2.0 * t):.6f}")
    assert v_plain == pytest.approx(1.0, rel=1e-3)  # measured -4.5e-4: the drop's surface faces
    assert v_damped / v_plain == pytest.approx(math.exp(-2.0 * t), rel=1e-4)
    assert damped.timer.phases_run == ["p2g", "grid", "damping", "pressure", "extend", "g2p"]


def test_an_outside_stage_keys_are_checked_like_the_rest(tmp_path, damping):
    scene = drifting_drop(tmp_path / "c.usdc", {"damping": damping.Damping(rate=-1.0)})
    with pytest.raises(SceneError, match=r"\[effects.damping\].rate"):
        scene.validate()
    d = drifting_drop(tmp_path / "d.usdc").to_dict()
    d["effects"] = {"damping": {"rate": 0.5, "rat": 1}}
    with pytest.raises(SceneError, match="unknown key.*rat"):
        Scene.from_dict(d)


def test_register_stage_refuses_what_it_cannot_run():
    class Nameless(Stage):
        pass

    class Shadow(Stage):
        name = "foam"

    with pytest.raises(TypeError):
        register_stage(Nameless)
    with pytest.raises(ValueError, match="built-in"):
        register_stage(Shadow)


def test_every_built_in_stage_has_a_place_in_the_step_order():
    assert set(STEP_ORDER) == set(BUILTIN_STAGES)


def test_stages_share_hooks_in_step_order(tmp_path):
    # Colliders mark solid cells before the gas labels phases; after g2p, films retract, then the
    # gas vents (its timer line is "vent").
    from warp_mpm_bubbles.scene.effects import Collider

    scene = tank_2d(cells=16, depth=0.6, out=tmp_path / "e.usdc")
    scene.materials["water"] = Material("water", surface_tension=0.072)
    scene.materials["air"] = Material("air", kind="gas")
    scene.shapes.append(Sphere("air", center=(0.5, 0.3), radius=0.12))
    scene.colliders = [Collider("box", center=(0.2, 0.1), size=(0.1, 0.1))]
    sim = Simulation(scene.validate(), "cpu")
    names = [s.name for s in sim.stages]
    assert names == ["colliders", "surface_tension", "gas"]
    assert [s.name for s in sim._hooks["on_cells"]] == ["colliders", "gas"]
    assert [s.name for s in sim._hooks["after_g2p"]] == ["surface_tension", "gas"]
    sim.step(sim.stable_dt())
    assert sim.timer.phases_run == ["p2g", "grid", "tension", "pressure", "extend", "g2p", "vent", "colliders"]
    limits = sim.dt_limits()
    assert set(limits) == {"cfl", "capillary", "gas_expansion"} and sim.stable_dt() == min(limits.values())
    from warp_mpm_bubbles.scene.limits import STEP_FIXES

    assert set(limits) <= set(STEP_FIXES)  # the step guard names each limit's fix
    assert np.isfinite(sim.particles_numpy()["positions"]).all()


def test_the_core_imports_nothing_above_it():
    # The core (the step, the stage protocol and registry) is the lowest layer: the package tells
    # it the built-in stages (warp_mpm_bubbles/stages.py); no import in it, at the top or inside a
    # function, reaches the scene, io, effects or physics, and no module path names them.
    import ast

    core = pathlib.Path(__file__).parents[1] / "warp_mpm_bubbles" / "core"
    above = ("scene", "io", "effects", "physics", "stages", "cli", "diagnostics")
    found = []
    for path in sorted(core.glob("*.py")):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            names = []
            if isinstance(node, ast.ImportFrom):
                names = [("." * node.level) + (node.module or "")] + [
                    f"{'.' * node.level}{a.name}" for a in node.names if not node.module]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.Constant) and isinstance(node.value, str):
                names = [node.value] if node.value.startswith("warp_mpm_bubbles.") else []
            for name in names:
                parts = name.lstrip(".").split(".")
                if name.startswith("..") and parts[0] in above or (
                        parts[0] == "warp_mpm_bubbles" and len(parts) > 1 and parts[1] in above):
                    found.append(f"{path.name}:{node.lineno}: {name}")
    assert found == []
