"""Each kind of particle is its own prototype in the USD file: the liquid, the resolved gas, the foam
and the sub-grid bubbles (a phase of the gas, given a prototype and material of their own, named after
their gas), each instance scaled by its own radius, so a render shows bubbles and foam of many sizes.
On Warp's CPU device."""

from pathlib import Path

import numpy as np
import pytest
import warp as wp
from pxr import Usd, UsdGeom, UsdShade

from benchmarks.cases import subgrid_tank
from warp_mpm_bubbles import Box, Material
from warp_mpm_bubbles.core.grid import PHASE_FOAM, PHASE_GAS, PHASE_LIQUID, PHASE_SUBGRID, sphere_radius
from warp_mpm_bubbles.io.runner import run_scene
from warp_mpm_bubbles.io.usd_materials import look, scene_prototypes
from warp_mpm_bubbles.io.usd_output import INSTANCER, StageWriter, read_frames
from warp_mpm_bubbles.scene.effects import Entrainment, Foam, GasInjector, SubgridBubbles

wp.config.quiet = True
ROOT = Path(__file__).resolve().parents[1]
KINDS = {"water": PHASE_LIQUID, "air": PHASE_GAS, "foam": PHASE_FOAM, "air_subgrid": PHASE_SUBGRID}


def mixed_scene(tmp_path):
    """A 2 cm block thrown into a 3 cm pool (entrained bubbles, log-normal sd 0.4) beside an air stone
    (sub-grid bubbles, median 1 mm, sd 0.4); what reaches the surface becomes foam. 2D, 32 x 32 cells."""
    effects = {"subgrid_bubbles": SubgridBubbles(), "foam": Foam(lifetime=1.0),
               "entrainment": Entrainment(rate=5000.0, min_speed=0.5, bubble_radius_spread=0.4)}
    block = Box("water", min=(0.04, 0.045), max=(0.06, 0.065), velocity=(0.0, -2.0))
    scene = subgrid_tank(tmp_path, depth=0.03, shapes=[block], effects=effects)
    scene.emitters = [GasInjector("air", (0.02, 0.02), rate=200.0, radius=1.0e-3, radius_spread=0.4, spread=0.005)]
    scene.output.fps, scene.output.frames = 50.0, 4
    return scene


def bound_look(stage, target):
    """The material bound to a prototype and its UsdPreviewSurface inputs."""
    material, _ = UsdShade.MaterialBindingAPI(stage.GetPrimAtPath(target)).ComputeBoundMaterial()
    shader = UsdShade.Shader(material.GetSurfaceOutput().GetConnectedSources()[0][0].source.GetPrim())
    return material.GetPath().name, {i.GetBaseName(): i.Get() for i in shader.GetInputs()}


def test_each_kind_is_a_prototype_of_its_own_with_instances_of_many_sizes(tmp_path):
    scene = mixed_scene(tmp_path)
    phases = {}

    def remember(sim):  # what the simulation held when the frame was written, by particle id
        p = sim.particles_numpy()
        phases[sim.frame] = (p["ids"], p["phase"], sphere_radius(p["volume"]))

    run_scene(scene, device="cpu", progress=False, on_frame=remember)
    stage = Usd.Stage.Open(scene.output.path)
    targets = UsdGeom.PointInstancer.Get(stage, INSTANCER).GetPrototypesRel().GetTargets()
    assert [t.name for t in targets] == list(KINDS)  # one prototype per kind, no more
    kinds = ["liquid", "gas", "foam", "subgrid"]
    for target, kind in zip(targets, kinds):  # each with a material of its own, of its kind's look
        name, inputs = bound_look(stage, target)
        assert name == target.name
        assert inputs["opacity"] == pytest.approx(look(kind, (0.0, 0.0, 0.0))["opacity"])
    assert len({bound_look(stage, t)[1]["opacity"] for t in targets}) == 4

    sizes = {name: [] for name in KINDS}
    for f, frame in read_frames(scene.output.path)["frames"].items():
        ids, phase, radius = phases[f]
        order = np.argsort(ids)
        assert np.array_equal(np.sort(frame["ids"]), ids[order])
        at = order[np.searchsorted(ids[order], frame["ids"])]  # the simulation's row of each instance
        for k, (name, ph) in enumerate(KINDS.items()):
            mine = frame["proto_indices"] == k
            assert np.array_equal(mine, phase[at] == ph), (f, name)  # every particle of the kind, only them
            sizes[name].append(frame["scales"][mine, 0])
            if ph in (PHASE_FOAM, PHASE_SUBGRID):  # bubbles: the radius of their own volume
                np.testing.assert_allclose(frame["scales"][mine, 0], radius[at][mine], rtol=1e-6)
    sizes = {name: np.concatenate(s) for name, s in sizes.items()}
    r_out = np.float32(scene.output.particle_radius)
    assert np.all(sizes["water"] == r_out) and np.all(sizes["air"] == r_out)
    for name in ("foam", "air_subgrid"):  # many sizes, spread by the draws: not float noise
        s = sizes[name]
        print(f"{name}: {len(s)} instances, {len(np.unique(s))} distinct scales, {s.min():.3g}..{s.max():.3g} m")
        assert len(np.unique(s)) >= 20 and s.max() > 2.0 * s.min()


def test_a_scene_without_sub_grid_bubbles_has_one_prototype_per_material(tmp_path):
    scene = subgrid_tank(tmp_path, effects={"foam": Foam()})
    looks, prototype_of = scene_prototypes(scene.validate())
    assert [name for name, _, _ in looks] == list(scene.materials) and prototype_of == []


def test_a_material_named_like_the_sub_grid_prototype_keeps_both_apart(tmp_path):
    scene = subgrid_tank(tmp_path, effects={"subgrid_bubbles": SubgridBubbles()})
    scene.materials["air_subgrid"] = Material("air_subgrid", kind="gas")
    looks, prototype_of = scene_prototypes(scene.validate())
    assert [name for name, _, _ in looks] == ["water", "air", "air_subgrid", "air_subgrid_", "air_subgrid_subgrid"]
    assert prototype_of == [(1, PHASE_SUBGRID), (2, PHASE_SUBGRID)]


def test_the_writer_needs_the_phases_for_prototypes_of_a_phase(tmp_path):
    materials = [("water", (0, 0, 1)), ("air", (1, 1, 1)), ("air_subgrid", (1, 1, 1))]
    with StageWriter(tmp_path / "w.usdc", fps=30, materials=materials, particle_radius=1e-3,
                     prototype_of=[(1, PHASE_SUBGRID)]) as w:
        x = np.zeros((3, 3))
        with pytest.raises(ValueError, match="phase is needed"):
            w.write_frame(0, x, x, np.arange(3), np.array([0, 1, 1]))
        with pytest.raises(ValueError, match="material index outside"):  # the extra one is not a material
            w.write_frame(0, x, x, np.arange(3), np.array([0, 1, 2]), phase=np.zeros(3))
        w.write_frame(0, x, x, np.arange(3), np.array([0, 1, 1]), phase=np.array([0, PHASE_GAS, PHASE_SUBGRID]))
    assert read_frames(tmp_path / "w.usdc")["frames"][0]["proto_indices"].tolist() == [0, 1, 2]
    with pytest.raises(ValueError, match="prototype_of"):
        StageWriter(tmp_path / "v.usdc", fps=30, materials=materials, particle_radius=1e-3, prototype_of=[(2, 3)])


@pytest.mark.parametrize("example", ["beer_3d", "champagne_3d"])
def test_the_beer_and_champagne_examples_write_foam_and_bubbles_of_several_sizes(tmp_path, example):
    """Each runs 8 frames at the preview quality (its bubbles reach the surface within them): its foam
    and its sub-grid bubbles are written as their own prototypes, in several sizes each."""
    from warp_mpm_bubbles.cli import main

    out = tmp_path / f"{example}.usdc"
    scene = ROOT / "examples" / f"{example}.toml"
    assert main(["run", str(scene), "--device", "cpu", "--num-frames", "8", "--quality", "preview",
                 "--stage-path", str(out), "--quiet"]) == 0
    stage = Usd.Stage.Open(str(out))
    names = [t.name for t in UsdGeom.PointInstancer.Get(stage, INSTANCER).GetPrototypesRel().GetTargets()]
    gas = names[1]
    assert names == [names[0], gas, "foam", f"{gas}_subgrid"]
    last = read_frames(out)["frames"][8]
    for k in (2, 3):  # foam, sub-grid bubbles
        s = last["scales"][last["proto_indices"] == k, 0]
        print(f"{example} {names[k]}: {len(s)} instances, {len(np.unique(s))} sizes, {s.min():.3g}..{s.max():.3g} m")
        assert len(np.unique(s)) >= 5 and s.max() > 1.5 * s.min()
